#include <chrono>
#include <cstdio>
#include <cmath>
#include <algorithm>
#include <stdexcept>
#include <limits>
#include <string>

#include "otfp/implicit_stepper.hpp"

#include "otfp/density.hpp"

namespace otfp {

void ImplicitOptions::validate() const {
  minimizer.validate();
  require(std::isfinite(displacement_tolerance) && displacement_tolerance > 0.0, "displacement_tolerance",
          displacement_tolerance, "must be finite and > 0");
  require(relative_tolerance >= 0.0 && relative_tolerance <= 1.0, "relative_tolerance", relative_tolerance,
          "must be in [0, 1] (0: absolute rule only)");
  require(std::isfinite(kappa) && kappa > 0.0, "kappa", kappa, "must be finite and > 0");
  require(std::isfinite(rho_ref) && rho_ref > 0.0, "rho_ref", rho_ref, "must be finite and > 0");
  require(max_halvings >= 0 && max_halvings <= 20, "max_halvings", max_halvings, "must be in [0, 20]");
  require(std::isfinite(energy_tolerance) && energy_tolerance >= 0.0, "energy_tolerance", energy_tolerance,
          "must be finite and >= 0");
  require(std::isfinite(error_smoothing) && error_smoothing >= 0.0 && error_smoothing <= 3.0, "error_smoothing",
          error_smoothing, "must be in [0, 3] widths (the neighbour list reaches about 4.3 widths)");
  require(std::isfinite(max_norm_factor) && max_norm_factor >= 1.0, "max_norm_factor", max_norm_factor,
          "must be finite and >= 1");
  require(std::isfinite(width_skin) && width_skin >= 0.0, "width_skin", width_skin, "must be finite and >= 0");
  require(max_width_factor == 0.0 || (std::isfinite(max_width_factor) && max_width_factor > 1.0), "max_width_factor",
          max_width_factor, "must be 0 (off) or finite and > 1");
  require(max_width_factor == 0.0 || (std::isfinite(nominal_width) && nominal_width > 0.0), "nominal_width",
          nominal_width, "must be finite and > 0 when max_width_factor is set");
  require(std::isfinite(max_width_factor * nominal_width), "max_width_factor", max_width_factor,
          "x nominal_width must be finite");
  neighbor.validate();
}

namespace {

FunctionalOptions functional_options(const ImplicitOptions& o) {
  FunctionalOptions f;
  f.kappa = o.kappa;
  f.rho_ref = o.rho_ref;
  f.width_metric = o.width_metric;
  f.optimise_widths = o.width_mode == WidthMode::PerParticle;
  f.neighbor = o.neighbor;
  f.width_skin = o.width_skin;
  return f;
}

// The objective in scaled unknowns: z_x = sqrt(a m/dt) x makes the transport
// Hessian the identity (a: the transport weight, 1 for Euler, (1+2w)/(1+w)
// for BDF2); widths are z_s = b_p log(s/s^k) with b_p = s^k sqrt(c_w a m/dt),
// which keeps s > 0 without bounds (NLopt's bounds slow L-BFGS down, Ceres has
// none) and has unit curvature at s = s^k. s_anchor = s^k, the widths at the
// start of the step (for BDF2 the functional's reference is s_hat instead).
//
// With an upper bound S on the widths (max_width_factor) the widths go
// through a fold in log s: log(s/S) = phi(v), phi(v) = v for v <= -d and
// -(v - d)^2/(4d) above (C1, d = kWidthFold), with z_s = b'_p (v - v^k). phi
// is the log map below S e^-d, reaches its maximum 0 (s = S) at the finite
// v = d and falls again beyond, so a width held by the bound is a stationary
// point at finite z (a logistic map reaches S only as z -> infinity, and the
// minimiser, chasing it, stalls: Ceres' relative step norm underflows).
// b'_p = b_p phi'(v^k) (at least b_p/2) keeps unit curvature at s^k below the
// fold. F itself is unchanged (a change of unknowns, not a penalty or a
// clamp), so a step still only lowers F and the energy inequality holds.
constexpr double kWidthFold = 0.25;
double fold(double v) { return v <= -kWidthFold ? v : -(v - kWidthFold) * (v - kWidthFold) / (4.0 * kWidthFold); }
double fold_slope(double v) { return v <= -kWidthFold ? 1.0 : -(v - kWidthFold) / (2.0 * kWidthFold); }
double fold_inverse(double t) {  // the branch v <= d, for t <= 0
  return t <= -kWidthFold ? t : kWidthFold - std::sqrt(-4.0 * kWidthFold * t);
}

class StepObjective final : public Objective {
 public:
  StepObjective(Functional& f, const ExternalPotential& ext, const std::vector<Vec3>& x_anchor,
                const std::vector<double>& s_anchor, const std::vector<double>& m, double dt, bool widths,
                const std::vector<double>& weights, double s_max)
      : f_(f), ext_(ext), s_ref_(s_anchor), m_(m), dim_(f.dim()), widths_(widths), n_(x_anchor.size()),
        s_max_(widths ? s_max : 0.0) {
    const double c_w = f.transport().c_w();
    c_w_ = c_w;
    scale_x_.resize(n_);
    scale_s_.resize(widths ? n_ : 0);
    disp_x_.resize(n_);
    disp_s_.resize(widths ? n_ : 0);
    for (std::size_t p = 0; p < n_; ++p) {
      const double am = weights.empty() ? m[p] : weights[p] * m[p];
      scale_x_[p] = std::sqrt(am / dt);
      if (widths) scale_s_[p] = s_anchor[p] * std::sqrt(c_w * am / dt);
      disp_x_[p] = dt / am;
      if (widths) disp_s_[p] = dt / (c_w * am);
    }
    if (s_max_ > 0.0) {
      scale_b_.resize(n_);
      u_ref_.resize(n_);
      for (std::size_t p = 0; p < n_; ++p) {
        require(s_anchor[p] <= s_max_, "max_width_factor", s_max_,
                "x nominal_width (the bound, shown) must not be below a width at the start of a step (found " +
                    std::to_string(s_anchor[p]) + ")");
        u_ref_[p] = fold_inverse(std::log(s_anchor[p] / s_max_));
        scale_b_[p] = scale_s_[p] * std::max(fold_slope(u_ref_[p]), 0.5);
      }
    }
    x_ = x_anchor;
    s_ = s_anchor;
  }

  std::size_t num_variables() const override { return n_ * (dim_ + (widths_ ? 1 : 0)); }

  void pack(const std::vector<Vec3>& x, const std::vector<double>& s, double* z) const {
    for (std::size_t p = 0; p < n_; ++p) {
      for (int k = 0; k < dim_; ++k) z[p * dim_ + k] = scale_x_[p] * x[p][k];
      if (widths_) z[n_ * dim_ + p] = width_unknown(p, s[p]);
    }
  }
  void unpack(const double* z, std::vector<Vec3>& x, std::vector<double>& s) const {
    for (std::size_t p = 0; p < n_; ++p) {
      for (int k = 0; k < dim_; ++k) x[p][k] = z[p * dim_ + k] / scale_x_[p];
      if (widths_) s[p] = width_of(p, z[n_ * dim_ + p]);
    }
  }

  bool evaluate(const double* z, double* value, double* gradient) override {
    unpack(z, x_, s_);
    for (std::size_t p = 0; p < n_; ++p)
      if (!x_[p].allFinite() || !std::isfinite(s_[p]) || !(s_[p] > 0.0)) return false;
    parts_ = f_.evaluate(x_, s_, gradient ? &g_ : nullptr);
    double ext = 0.0;
    if (ext_) {
      for (std::size_t p = 0; p < n_; ++p) {
        Vec3 gu = Vec3::Zero();
        ext += m_[p] * ext_(x_[p], gradient ? &gu : nullptr);
        if (gradient) g_.x[p] += m_[p] * gu;
      }
      parts_.barrier += ext;
    }
    *value = parts_.total();
    if (!std::isfinite(*value)) return false;
    if (gradient) {
      for (std::size_t p = 0; p < n_; ++p) {
        for (int k = 0; k < dim_; ++k) gradient[p * dim_ + k] = g_.x[p][k] / scale_x_[p];
        if (widths_)
          gradient[n_ * dim_ + p] =
              s_max_ > 0.0 ? g_.s[p] * s_[p] * fold_slope(u_ref_[p] + z[n_ * dim_ + p] / scale_b_[p]) / scale_b_[p]
                           : g_.s[p] * s_[p] / scale_s_[p];
      }
      for (std::size_t i = 0; i < num_variables(); ++i)
        if (!std::isfinite(gradient[i])) return false;
    }
    return true;
  }

  // The gradient step d_p = dt/m dF/dx (and dt/(c_w m) dF/ds): how far one
  // gradient step would move particle p. With the bound the width part is
  // |dt/(c_w m) dF/ds| phi'(v) b'/b: the same below the fold, zero where the
  // bound holds a width (dF/ds < 0 there).
  //   Max:    max_p |d_p| (componentwise);
  //   Energy: max(RMS, max / max_norm_factor), RMS = sqrt(sum_p m_p (|d_p|^2 +
  //           c_w d_s,p^2) / M), the norm of the transport term in which the
  //           step's error is measured: with the Hessian in the scaled
  //           unknowns >= I, RMS bounds the M-weighted RMS distance to the
  //           solution of the step (docs/stepper.md).
  double stopping_measure(const double* z, const double* gradient) const override {
    double worst = 0.0, sum = 0.0, mass = 0.0;
    for (std::size_t p = 0; p < n_; ++p) {
      double d2 = 0.0;
      for (int k = 0; k < dim_; ++k) {
        const double d = gradient[p * dim_ + k] * scale_x_[p] * disp_x_[p];
        worst = std::max(worst, std::abs(d));
        d2 += d * d;
      }
      if (widths_) {
        const double s = width_of(p, z[n_ * dim_ + p]);
        const double scale = s_max_ > 0.0 ? scale_b_[p] : scale_s_[p];
        const double d = gradient[n_ * dim_ + p] * scale / s * disp_s_[p];
        worst = std::max(worst, std::abs(d));
        d2 += c_w_ * d * d;
      }
      sum += m_[p] * d2;
      mass += m_[p];
    }
    if (!(max_norm_factor_ > 0.0)) return worst;
    const double rms = mass > 0.0 ? std::sqrt(sum / mass) : 0.0;
    // A NaN (an overflowing scale) must never read as converged.
    if (!std::isfinite(rms)) return std::numeric_limits<double>::infinity();
    return std::max(rms, worst / max_norm_factor_);
  }
  // Energy norm: the factor by which the max-norm may exceed the tolerance (0: Max norm).
  void set_max_norm_factor(double f) { max_norm_factor_ = f; }

  const FunctionalParts& parts() const { return parts_; }

  // Width of particle p for the unknown zs, and the unknown for width s.
  double width_of(std::size_t p, double zs) const {
    if (!(s_max_ > 0.0)) return s_ref_[p] * std::exp(zs / scale_s_[p]);
    return std::min(s_max_ * std::exp(fold(u_ref_[p] + zs / scale_b_[p])), s_max_);
  }
  double width_unknown(std::size_t p, double s) const {
    if (!(s_max_ > 0.0)) return scale_s_[p] * std::log(s / s_ref_[p]);
    return scale_b_[p] * (fold_inverse(std::min(std::log(s / s_max_), 0.0)) - u_ref_[p]);
  }

 private:
  Functional& f_;
  const ExternalPotential& ext_;
  const std::vector<double>& s_ref_;
  const std::vector<double>& m_;
  int dim_;
  bool widths_;
  std::size_t n_;
  double s_max_;  // upper bound on the widths (0: none)
  double c_w_ = 1.0;
  double max_norm_factor_ = 0.0;
  std::vector<double> scale_x_, scale_s_, disp_x_, disp_s_, scale_b_, u_ref_;
  std::vector<Vec3> x_;
  std::vector<double> s_;
  Gradient g_;
  FunctionalParts parts_;
};

// StepObjective with its own copies of the state it refers to (step_problem()).
class OwnedStepObjective final : public Objective {
 public:
  OwnedStepObjective(Functional& f, const ExternalPotential& ext, std::vector<Vec3> x, std::vector<double> s,
                     std::vector<double> m, double dt, bool widths, double s_max)
      : x_(std::move(x)), s_(std::move(s)), m_(std::move(m)), obj_(f, ext, x_, s_, m_, dt, widths, {}, s_max) {}
  std::size_t num_variables() const override { return obj_.num_variables(); }
  bool evaluate(const double* z, double* value, double* gradient) override { return obj_.evaluate(z, value, gradient); }
  double stopping_measure(const double* z, const double* gradient) const override {
    return obj_.stopping_measure(z, gradient);
  }
  std::vector<double> start() const {
    std::vector<double> z(obj_.num_variables());
    obj_.pack(x_, s_, z.data());
    return z;
  }

 private:
  std::vector<Vec3> x_;
  std::vector<double> s_, m_;
  StepObjective obj_;
};

}  // namespace

ImplicitStepper::StepProblem ImplicitStepper::step_problem(const ParticleSet& particles, double dt) {
  require(std::isfinite(dt) && dt > 0.0, "dt", dt, "must be finite and > 0");
  require(particles.dim() == dim_, "particles dim", particles.dim(),
          "must equal the stepper's dim " + std::to_string(dim_));
  functional_.set_dt(dt);
  functional_.set_reference(particles.positions(), particles.widths(), particles.masses());
  functional_.rebuild_list(particles.positions(), particles.widths());
  const double s_max = options_.max_width_factor > 0.0 ? options_.max_width_factor * options_.nominal_width : 0.0;
  auto obj = std::make_unique<OwnedStepObjective>(functional_, external_, particles.positions(), particles.widths(),
                                                  particles.masses(), dt,
                                                  options_.width_mode == WidthMode::PerParticle, s_max);
  StepProblem problem;
  problem.start = obj->start();
  problem.objective = std::move(obj);
  return problem;
}

ImplicitStepper::ImplicitStepper(int dim, ImplicitOptions options, Barrier barrier, Periodicity periodicity)
    : dim_(dim),
      options_((options.validate(), options)),
      functional_(dim, functional_options(options), std::move(barrier), periodicity) {}

void ImplicitStepper::reset_history() {
  history_.clear();
  dt1_ = dt2_ = 0.0;
  previous_history_.clear();
  can_undo_history_ = false;
}

void ImplicitStepper::undo_last_history_update() {
  if (!can_undo_history_)
    throw std::logic_error("ImplicitStepper::undo_last_history_update: the history's last change was not an accepted step");
  history_.swap(previous_history_);
  dt1_ = previous_dt1_;
  dt2_ = previous_dt2_;
  previous_history_.clear();
  can_undo_history_ = false;
}

ImplicitStepper::HistoryState ImplicitStepper::history_state() const {
  HistoryState st;
  st.dt1 = dt1_;
  st.dt2 = dt2_;
  st.entries.reserve(history_.size());
  for (const auto& [id, h] : history_) st.entries.push_back({id, h.d1, h.d2, h.ds1, h.ds2, h.count});
  std::sort(st.entries.begin(), st.entries.end(),
            [](const HistoryEntry& a, const HistoryEntry& b) { return a.id < b.id; });
  return st;
}

void ImplicitStepper::restore_history(const HistoryState& st) {
  require(std::isfinite(st.dt1) && st.dt1 >= 0.0, "history dt1", st.dt1, "must be finite and >= 0");
  require(std::isfinite(st.dt2) && st.dt2 >= 0.0, "history dt2", st.dt2, "must be finite and >= 0");
  std::unordered_map<ParticleId, History> map;
  map.reserve(st.entries.size());
  for (const HistoryEntry& e : st.entries) {
    require(e.count >= 0 && e.count <= 2, "history count of particle " + std::to_string(e.id), e.count,
            "must be 0, 1 or 2");
    require(e.d1.allFinite() && e.d2.allFinite() && std::isfinite(e.ds1) && std::isfinite(e.ds2),
            "history of particle " + std::to_string(e.id), 0.0, "must be finite");
    require(map.emplace(e.id, History{e.d1, e.d2, e.ds1, e.ds2, e.count}).second,
            "history of particle " + std::to_string(e.id), static_cast<double>(e.id), "appears twice");
  }
  history_ = std::move(map);
  dt1_ = st.dt1;
  dt2_ = st.dt2;
  previous_history_.clear();
  can_undo_history_ = false;
}

// The predictor's start for one particle: the extrapolation `to`, or the
// largest of 1/2, 1/4, 1/8 of the way from `from` that is no further outside
// the barrier domain and the mirrored walls than `from` is; else `from`.
Vec3 ImplicitStepper::admissible_start(const Vec3& from, const Vec3& to) const {
  const Barrier& barrier = functional_.barrier().barrier();
  const auto& walls = functional_.images().walls();
  const bool use_barrier = barrier.active();
  if (!use_barrier && walls.empty()) return to;
  auto admissible = [&](const Vec3& y) {
    if (use_barrier && barrier.distance(y) > std::max(0.0, barrier.distance(from))) return false;
    for (const auto& w : walls)
      if (w->distance(y) > std::max(0.0, w->distance(from))) return false;
    return true;
  };
  double f = 1.0;
  for (int k = 0; k < 4; ++k, f *= 0.5) {
    const Vec3 y = from + f * (to - from);
    if (admissible(y)) return y;
  }
  return from;
}

// Linear extrapolation moves a particle by w d1. A mode that decays within
// a step (lambda dt >= 1, the large steps) moves less each step, and linear
// extrapolation overshoots it; Damped scales by the particle's last ratio
// d1.d2 / |d2|^2 (clamped to [0, 1]; linear while only d1 is known).
double ImplicitStepper::predictor_factor(Predictor predictor, const History& h, double omega) {
  if (predictor == Predictor::None || h.count < 1) return 0.0;
  if (predictor == Predictor::Extrapolate || h.count < 2) return omega;
  const double d22 = h.d2.squaredNorm() + h.ds2 * h.ds2;
  if (!(d22 > 0.0)) return 0.0;
  return omega * std::min(std::max((h.d1.dot(h.d2) + h.ds1 * h.ds2) / d22, 0.0), 1.0);
}

std::vector<Vec3> ImplicitStepper::predict(const ParticleSet& particles, double dt) const {
  require(std::isfinite(dt) && dt > 0.0, "dt", dt, "must be finite and > 0");
  std::vector<Vec3> out = particles.positions();
  if (!(dt1_ > 0.0)) return out;
  const double omega = dt / dt1_;
  const Predictor kind = options_.predictor == Predictor::None ? Predictor::Extrapolate : options_.predictor;
  for (std::size_t p = 0; p < out.size(); ++p) {
    const auto it = history_.find(particles.ids()[p]);
    if (it == history_.end()) continue;
    const double g = predictor_factor(kind, it->second, omega);
    if (g > 0.0) out[p] = admissible_start(out[p], out[p] + g * it->second.d1);
  }
  return out;
}

bool ImplicitStepper::solve(std::vector<Vec3>& x, std::vector<double>& s, const std::vector<double>& m,
                            std::vector<History>& hist, double& dt1, double& dt2, double dt, StepSummary& summary) {
  const std::size_t n = x.size();
  const bool widths = options_.width_mode == WidthMode::PerParticle;
  const double omega = dt1 > 0.0 ? dt / dt1 : 0.0;  // dt_k / dt_{k-1}

  // Variational BDF2 (docs/stepper.md): the variable-step BDF2 update
  //   a0 x^{k+1} - (1+w) x^k + w^2/(1+w) x^{k-1} = -dt/m dE/dx(x^{k+1}),
  //   a0 = (1+2w)/(1+w), w = dt_k/dt_{k-1},
  // is the stationarity condition of  a0 m/(2 dt) |x - x_hat|^2 + E(x)  with
  //   x_hat = x^k + w^2/(1+2w) (x^k - x^{k-1}),
  // i.e. (28) with the reference x_hat and transport weight a0 (w = 1: 3/(4 dt),
  // x_hat = (4 x^k - x^{k-1})/3). Particles with no x^{k-1} take the Euler form.
  std::vector<Vec3> x_ref = x;
  std::vector<double> s_ref = s, weights;
  long bdf2_particles = 0;
  if (options_.time_scheme == TimeScheme::Bdf2 && dt1 > 0.0) {
    const double c = omega * omega / (1.0 + 2.0 * omega);
    const double a0 = (1.0 + 2.0 * omega) / (1.0 + omega);
    weights.assign(n, 1.0);
    for (std::size_t p = 0; p < n; ++p) {
      if (hist[p].count < 1) continue;
      x_ref[p] = x[p] + c * hist[p].d1;
      if (widths) s_ref[p] = s[p] + c * hist[p].ds1;
      weights[p] = a0;
      ++bdf2_particles;
    }
    if (bdf2_particles == 0) weights.clear();
  }
  summary.bdf2_particles = bdf2_particles;

  functional_.set_dt(dt);
  functional_.set_reference(x_ref, s_ref, m, weights);
  const int builds_before = functional_.list().build_count();
  const double list_seconds_before = functional_.list().build_seconds();
  const std::uint64_t pairs_before = functional_.entropy().pair_evaluations();
  functional_.rebuild_list(x, s);  // particles may have been added or removed

  const double s_max = options_.max_width_factor > 0.0 ? options_.max_width_factor * options_.nominal_width : 0.0;
  StepObjective objective(functional_, external_, x, s, m, dt, widths, weights, s_max);
  const bool energy_norm = options_.stopping_norm == StoppingNorm::Energy;
  if (energy_norm) objective.set_max_norm_factor(options_.max_norm_factor);
  std::vector<double> z(objective.num_variables());
  objective.pack(x, s, z.data());
  // sqrt(m/dt) overflows for a dt of a few 1e-308: no step can be taken in
  // unknowns that are not finite (the run fails with this message).
  for (double v : z)
    if (!std::isfinite(v)) {
      char buf[64];
      std::snprintf(buf, sizeof(buf), "%.6g", dt);
      summary.message = std::string("dt = ") + buf + " is too small: the scaled unknowns sqrt(m/dt) x overflow";
      summary.reason = TerminationReason::NonFinite;
      return false;
    }

  double s_min = s.empty() ? 1.0 : s[0];
  for (double v : s) s_min = std::min(s_min, v);
  MinimizerOptions mo = options_.minimizer;
  mo.gradient_tolerance = options_.displacement_tolerance * s_min;

  // The anchor x^k: F there is the right-hand side of the energy inequality
  // the step must satisfy (Euler: E(x^k); BDF2: the modified energy, below).
  // The papers' path (Euler, no predictor) starts there and lets the
  // minimiser apply the relative rule; otherwise the rule is measured at the
  // anchor, so that a good start does not make the tolerance stricter.
  const bool papers_path = options_.time_scheme == TimeScheme::Euler && options_.predictor == Predictor::None;
  std::vector<double> g_anchor(papers_path ? 0 : z.size());
  double f0 = 0.0;
  const bool start_ok = objective.evaluate(z.data(), &f0, papers_path ? nullptr : g_anchor.data());
  const FunctionalParts before = objective.parts();
  if (!papers_path) ++summary.evaluations;
  double f_start = f0;

  // A line search stalls once the decrease it must see is below the round-off
  // of F. With unit curvature in the scaled unknowns that happens at
  // |g_z|^2 ~ eps_F, i.e. at a displacement ~ sqrt(eps_F dt / m). Closer to
  // stationarity than that no solver can certify.
  double m_min = m.empty() ? 1.0 : m[0], mass = 0.0;
  for (double v : m) {
    m_min = std::min(m_min, v);
    mass += v;
  }
  const double f_scale =
      std::abs(before.transport) + std::abs(before.entropy) + std::abs(before.barrier) + options_.kappa * mass;
  const double eps_f = 64.0 * std::numeric_limits<double>::epsilon() * f_scale;
  // In the energy norm the whole gradient stalls at |g_z|^2 ~ eps_F, an RMS
  // of sqrt(eps_F dt / M); a single particle at its floor shows as that floor
  // over max_norm_factor.
  const double floor_measure = energy_norm ? std::max(std::sqrt(eps_f * dt / std::max(mass, m_min)),
                                                      std::sqrt(eps_f * dt / m_min) / options_.max_norm_factor)
                                           : std::sqrt(eps_f * dt / m_min);
  // Along the stiffest direction (the Hessian in the scaled unknowns is
  // I + (dt/m) D^2 E, largest eigenvalue about 1 + 2 kappa beta dt,
  // docs/method_notes.md) a line search stalls at sqrt(lambda_max) times that
  // floor. A start (or a stalled solve) already below it and below the
  // absolute tolerance is as converged as F can tell: without this a settled
  // state stepped at 1000x the explicit limit looked unconverged to the
  // relative rule and was retried with dt halved three times (51 evaluations
  // per step, no motion; tests/test_reservoir.cpp, SettledStateIsAFixedPoint).
  const double lambda_max = 1.0 + 2.0 * options_.kappa * dt / (s_min * s_min);
  const double stall_measure = std::min(mo.gradient_tolerance, floor_measure * std::sqrt(lambda_max));
  // Relative rule: the first gradient step is the explicit displacement of
  // the step; at small dt the absolute rule alone stops before the solution
  // has moved by much more than the tolerance (under-diffusion,
  // docs/validation.md study 3).
  if (papers_path) {
    mo.relative_gradient_tolerance = options_.relative_tolerance;
  } else {
    const double measure0 = start_ok ? objective.stopping_measure(z.data(), g_anchor.data()) : 0.0;
    if (options_.relative_tolerance > 0.0 && measure0 > 0.0)
      mo.gradient_tolerance =
          std::max(std::min(mo.gradient_tolerance, options_.relative_tolerance * measure0), floor_measure);
    mo.relative_gradient_tolerance = 0.0;
  }
  mo.gradient_tolerance_floor = floor_measure;
  mo.start_tolerance = stall_measure;

  // Predictor: start from the extrapolated trajectory where that lowers F.
  long predicted = 0;
  if (start_ok && options_.predictor != Predictor::None && dt1 > 0.0) {
    std::vector<Vec3> xp = x;
    std::vector<double> sp = s;
    for (std::size_t p = 0; p < n; ++p) {
      // Particles inserted since the last step (no history) start where they are.
      const double g = predictor_factor(options_.predictor, hist[p], omega);
      if (!(g > 0.0)) continue;
      xp[p] = admissible_start(x[p], x[p] + g * hist[p].d1);
      if (widths) sp[p] = std::max(s[p] + g * hist[p].ds1, 0.5 * s[p]);
      if (widths && s_max > 0.0) sp[p] = std::min(sp[p], s_max);  // inside the bound
      ++predicted;
    }
    if (predicted > 0) {
      std::vector<double> zp(z.size());
      objective.pack(xp, sp, zp.data());
      double fp = 0.0;
      ++summary.evaluations;
      if (objective.evaluate(zp.data(), &fp, nullptr) && fp < f0) {
        z = std::move(zp);
        f_start = fp;
      } else {
        predicted = 0;
      }
    }
  }
  summary.predicted_particles = predicted;
  summary.f_start = f_start;

  MinimizerSummary ms;
  if (start_ok) ms = minimize(objective, z, mo);
  summary.reason = start_ok ? ms.reason : TerminationReason::NonFinite;
  summary.iterations += ms.iterations;
  summary.evaluations += ms.evaluations;
  summary.solver_seconds += ms.solver_seconds;
  summary.residual_displacement = ms.final_stopping_measure;
  summary.gradient_tolerance = ms.gradient_tolerance;
  summary.parts_before = before;
  summary.f_before = f0;

  bool ok = start_ok && ms.success;
  if (start_ok && !ms.success && ms.reason == TerminationReason::LineSearchFailure &&
      ms.final_stopping_measure <= std::max({ms.gradient_tolerance, floor_measure, stall_measure})) {
    ok = true;
    summary.message = "converged to the round-off floor of F";
  }
  std::vector<Vec3> x_new = x;
  std::vector<double> s_new = s;
  if (ok) {
    double f1 = 0.0;
    objective.unpack(z.data(), x_new, s_new);
    ok = objective.evaluate(z.data(), &f1, nullptr);
    summary.parts_after = objective.parts();
    summary.f_after = f1;
    // Energy inequality F(x^{k+1}) <= F(x^k) (+ round-off). Euler: F(x^k) = E(x^k),
    // so E(x^{k+1}) + W^2/(2 dt) <= E(x^k). BDF2 (d_k = x^k - x^{k-1}, c = w^2/(1+2w)):
    // E(x^{k+1}) + a0 m/(2 dt) |d_{k+1} - c d_k|^2 <= E(x^k) + a0 m/(2 dt) c^2 |d_k|^2.
    const double slack =
        options_.energy_tolerance * (std::abs(f0) + std::abs(before.entropy) + std::abs(before.barrier) + 1e-300);
    if (ok && f1 > f0 + slack) {
      ok = false;
      summary.message = "energy increased: F_after - F_before = " + std::to_string(f1 - f0);
    }
  } else {
    summary.message = start_ok ? "solver: " + to_string(ms.reason) + (ms.message.empty() ? "" : " (" + ms.message + ")")
                               : "non-finite F at the start of the step";
  }
  summary.list_builds += functional_.list().build_count() - builds_before;
  summary.list_seconds += functional_.list().build_seconds() - list_seconds_before;
  summary.pair_evaluations += functional_.entropy().pair_evaluations() - pairs_before;
  if (!ok) return false;

  // Local error estimate: the error committed in this step, i.e. the distance
  // from x^{k+1} to the exact solution through x^k, from the difference to the
  // explicit extrapolation of the scheme's order (Milne's device). The
  // history x^{k-1}, x^{k-2} is numerical, and its own errors enter at the
  // same order (docs/stepper.md derives the factors):
  //   Euler (p1 linear through x^{k-1}, x^k):       e = (x^{k+1} - p1) / 2, for any w;
  //   BDF2  (p2 quadratic through x^{k-2}..x^k):    e = (1+w) h^2 / (w (h+h1)(h+h1+h2)) (x^{k+1} - p2)
  // (h = dt, h1 = dt_{k-1}, h2 = dt_{k-2}; 1/3 at constant steps). Checked
  // against the exact one-step error of x' = -lambda x (test_stepper.cpp).
  const bool bdf2 = options_.time_scheme == TimeScheme::Bdf2;
  const int need = bdf2 ? 2 : 1;
  const double h = dt, h1 = dt1, h2 = dt2;
  double factor = 0.0;
  if (!bdf2 && h1 > 0.0)
    factor = 0.5;
  else if (bdf2 && h1 > 0.0 && h2 > 0.0)
    factor = (1.0 + omega) * h * h / (omega * (h + h1) * (h + h1 + h2));
  // Per particle first; then the estimate that controls dt is taken of the
  // error field smoothed over a neighbourhood (Gaussian of standard deviation
  // error_smoothing x s_q, within the neighbour list): the part of a
  // particle's motion that alternates between neighbours is the relaxation
  // of the particle arrangement (damped by both schemes, invisible in the
  // density at the blob scale), not an error of the solution's time evolution
  // (docs/stepper.md).
  std::vector<Vec3> ex(factor > 0.0 ? n : 0, Vec3::Zero());
  std::vector<double> es(ex.size(), 0.0);
  std::vector<char> has(ex.size(), 0);
  for (std::size_t p = 0; p < ex.size(); ++p) {
    const History& H = hist[p];
    if (H.count < need) continue;
    Vec3 pred_x;
    double pred_s;
    if (!bdf2) {
      pred_x = x[p] + omega * H.d1;
      pred_s = s[p] + omega * H.ds1;
    } else {
      // Newton form: p(t) = x^k + v1 (t - t_k) + a (t - t_k)(t - t_{k-1}).
      const Vec3 v1 = H.d1 / h1, v2 = H.d2 / h2;
      const Vec3 acc = (v1 - v2) / (h1 + h2);
      pred_x = x[p] + h * v1 + h * (h + h1) * acc;
      const double w1 = H.ds1 / h1, w2 = H.ds2 / h2;
      pred_s = s[p] + h * w1 + h * (h + h1) * (w1 - w2) / (h1 + h2);
    }
    ex[p] = factor * (x_new[p] - pred_x);
    es[p] = widths ? factor * (s_new[p] - pred_s) : 0.0;
    has[p] = 1;
  }
  // Two blob-density sweeps: only when the estimate is the one asked for.
  const double density_error = factor > 0.0 && options_.error_measure == ErrorMeasure::Density
                                   ? density_error_estimate(x_new, s_new, m, ex, es, has, factor)
                                   : NAN;
  double sum_raw = 0.0, sum_smooth = 0.0, sum_m = 0.0;
  const NeighborList& list = functional_.list();
  const bool list_ok = list.built() && list.size() >= n;
  const Periodicity& per = functional_.periodicity();
  const double smoothing = options_.error_smoothing, smoothing2 = smoothing * smoothing;
  // With the width skin the list holds more pairs; the smoothing keeps to the
  // pairs the list would hold without it (the wider blob's cut-off plus the skin).
  const bool cut_pairs = widths && options_.width_skin > 0.0;
  const double tol = options_.neighbor.kernel_tolerance, skin_plain = list.skin() / (1.0 + options_.width_skin);
  for (std::size_t p = 0; p < ex.size(); ++p) {
    if (!has[p]) continue;
    const double sp2 = s_new[p] * s_new[p];
    sum_raw += m[p] * (ex[p].squaredNorm() + es[p] * es[p]) / sp2;
    double wsum = m[p];
    Vec3 ax = wsum * ex[p];
    double as = wsum * es[p];
    if (list_ok && smoothing > 0.0) {
      for (std::uint32_t k = list.offsets()[p]; k < list.offsets()[p + 1]; ++k) {
        const std::size_t q = list.indices()[k];
        if (q >= n || !has[q]) continue;  // image blobs and particles without an estimate
        const double sq2 = s_new[q] * s_new[q];
        const double r2 = per.displacement(x_new[p], x_new[q]).squaredNorm();
        if (cut_pairs) {
          const double rad = cutoff_radius(std::max(s_new[p], s_new[q]), tol) + skin_plain;
          if (r2 > rad * rad) continue;
        }
        const double w = m[q] * std::exp(-0.5 * r2 / (smoothing2 * sq2));
        wsum += w;
        ax += w * ex[q];
        as += w * es[q];
      }
    }
    ax /= wsum;
    as /= wsum;
    sum_smooth += m[p] * (ax.squaredNorm() + as * as) / sp2;
    sum_m += m[p];
  }
  if (sum_m > 0.0) {
    const double smooth = std::sqrt(sum_smooth / sum_m), raw = std::sqrt(sum_raw / sum_m);
    const double err = options_.error_measure == ErrorMeasure::Density ? density_error : smooth;
    // NaN-aware maxima over substeps.
    if (!(summary.error_estimate >= err)) summary.error_estimate = err;
    if (!(summary.displacement_error_estimate >= smooth)) summary.displacement_error_estimate = smooth;
    if (!(summary.density_error_estimate >= density_error)) summary.density_error_estimate = density_error;
    if (!(summary.particle_error_estimate >= raw)) summary.particle_error_estimate = raw;
    summary.error_order = bdf2 ? 2 : 1;
  }

  // Shift the history: the new diffusive displacement (unwrapped).
  for (std::size_t p = 0; p < n; ++p) {
    History& H = hist[p];
    H.d2 = H.d1;
    H.ds2 = H.ds1;
    H.d1 = x_new[p] - x[p];
    H.ds1 = s_new[p] - s[p];
    H.count = std::min(H.count + 1, 2);
  }
  dt2 = dt1;
  dt1 = dt;
  x = std::move(x_new);
  s = std::move(s_new);
  return true;
}

// The local error of the blob density (ErrorMeasure::Density): the density
// of the step's result minus that of the explicit extrapolation (the same
// Milne factor as the displacement estimate), both smoothed by a Gaussian of
// error_smoothing widths (a blob of width s convolved with it is a blob of
// width s sqrt(1 + c^2)), at the new particle positions; mass-weighted RMS
// relative to the mass-weighted mean density. A permutation of particles, or
// their relaxation at the particle scale, leaves the smoothed density (and
// so the estimate) unchanged: the density ripple of a lattice of spacing
// dr = sqrt(2) s is damped by exp(-pi^2 (1 + c^2)) by the smoothing, below
// 1e-20 at c = 2. Particles without the history the estimate needs enter both
// densities at their new place. NaN when no particle has an estimate.
double ImplicitStepper::density_error_estimate(const std::vector<Vec3>& x_new, const std::vector<double>& s_new,
                                               const std::vector<double>& m, const std::vector<Vec3>& ex,
                                               const std::vector<double>& es, const std::vector<char>& has,
                                               double factor) const {
  const std::size_t n = x_new.size();
  bool any = false;
  for (char h : has) any = any || h;
  if (!any || !(factor > 0.0)) return NAN;
  const double widen = std::sqrt(1.0 + options_.error_smoothing * options_.error_smoothing);
  std::vector<Vec3> x_pred(n);
  std::vector<double> w_new(n), w_pred(n);
  for (std::size_t p = 0; p < n; ++p) {
    // ex = factor (x_new - pred): the prediction is x_new - ex / factor.
    x_pred[p] = has[p] ? Vec3(x_new[p] - ex[p] / factor) : x_new[p];
    w_new[p] = widen * s_new[p];
    const double sp = has[p] && !es.empty() ? s_new[p] - es[p] / factor : s_new[p];
    w_pred[p] = widen * (sp > 0.0 ? sp : s_new[p]);
  }
  const Periodicity& per = functional_.periodicity();
  // The estimate needs a relative precision of about 1e-6 of the density;
  // the kernel's own tolerance where that is tighter.
  const double tol = std::max(options_.neighbor.kernel_tolerance, kErrorKernelTolerance);
  // Probes: every (2^d / 2)-th particle (the particles are in spatial order
  // after sort_particles), about one per 1.6 spacings in 3-D, where the
  // smoothed density varies over 2.2 widths = 1.6 spacings: the same RMS at
  // a quarter of the sweeps' cost.
  const std::size_t stride = dim_ == 3 ? 4 : dim_ == 2 ? 2 : 1;
  std::vector<Vec3> probes;
  std::vector<double> probe_m;
  probes.reserve(n / stride + 1);
  probe_m.reserve(n / stride + 1);
  for (std::size_t p = 0; p < n; p += stride) {
    probes.push_back(x_new[p]);
    probe_m.push_back(m[p]);
  }
  std::vector<double> rho_new, rho_pred;
  blob_density(dim_, x_new, w_new, m, probes, per, tol, rho_new, nullptr);
  blob_density(dim_, x_pred, w_pred, m, probes, per, tol, rho_pred, nullptr);
  double sum = 0.0, mean = 0.0, mass = 0.0;
  for (std::size_t j = 0; j < probes.size(); ++j) {
    const double e = factor * (rho_new[j] - rho_pred[j]);
    sum += probe_m[j] * e * e;
    mean += probe_m[j] * rho_new[j];
    mass += probe_m[j];
  }
  if (!(mass > 0.0) || !(mean > 0.0)) return NAN;
  mean /= mass;
  return std::sqrt(sum / mass) / mean;
}

StepSummary ImplicitStepper::step(ParticleSet& particles, double dt, double max_error) {
  require(std::isfinite(dt) && dt > 0.0, "dt", dt, "must be finite and > 0");
  require(!(max_error <= 0.0), "max_error", max_error, "must be > 0 (infinity: no error control)");
  require(particles.dim() == dim_, "particles dim", particles.dim(),
          "must equal the stepper's dim " + std::to_string(dim_));
  const auto t0 = std::chrono::steady_clock::now();
  StepSummary summary;
  summary.dt = dt;
  // Work on copies, in spatial order for memory locality: a failed solve
  // never overwrites (or reorders) the state.
  std::vector<std::size_t> order(particles.size());
  for (std::size_t i = 0; i < order.size(); ++i) order[i] = i;
  if (options_.sort_particles && !particles.empty()) {
    double s_max = 0.0;
    for (double v : particles.widths()) s_max = std::max(s_max, v);
    order = spatial_order(particles.positions(), dim_, cutoff_radius(s_max, options_.neighbor.kernel_tolerance));
  }
  std::vector<Vec3> x0(order.size());
  std::vector<double> s0(order.size()), m(order.size());
  std::vector<History> hist0(order.size());
  for (std::size_t i = 0; i < order.size(); ++i) {
    x0[i] = particles.positions()[order[i]];
    s0[i] = particles.widths()[order[i]];
    m[i] = particles.masses()[order[i]];
    const auto it = history_.find(particles.ids()[order[i]]);
    if (it != history_.end()) hist0[i] = it->second;
  }
  for (int halvings = 0; halvings <= options_.max_halvings; ++halvings) {
    std::vector<Vec3> x = x0;
    std::vector<double> s = s0;
    std::vector<History> hist = hist0;
    double dt1 = dt1_, dt2 = dt2_;
    const int substeps = 1 << halvings;
    const double h = dt / substeps;
    bool ok = true;
    FunctionalParts first_before;
    double first_f = 0.0, first_start = 0.0;
    summary.error_estimate = summary.particle_error_estimate = std::numeric_limits<double>::quiet_NaN();
    summary.displacement_error_estimate = summary.density_error_estimate = std::numeric_limits<double>::quiet_NaN();
    summary.error_order = 0;
    for (int k = 0; k < substeps && ok; ++k) {
      ok = solve(x, s, m, hist, dt1, dt2, h, summary);
      if (k == 0) {
        first_before = summary.parts_before;
        first_f = summary.f_before;
        first_start = summary.f_start;
      }
    }
    if (ok) {
      summary.halvings = halvings;
      summary.substeps = substeps;
      summary.parts_before = first_before;
      summary.f_before = first_f;
      summary.f_start = first_start;
      if (summary.error_estimate > max_error) {
        // Too inaccurate for the caller: nothing is committed, not even the history.
        summary.error_rejected = true;
        summary.message = "local error estimate " + std::to_string(summary.error_estimate) + " > limit " +
                          std::to_string(max_error);
        break;
      }
      summary.accepted = true;
      const Periodicity& per = functional_.periodicity();
      for (auto& p : x) p = per.wrap(p);
      particles.reorder(order);
      particles.positions() = std::move(x);
      particles.widths() = std::move(s);
      // The old history is moved aside, not dropped: undo_last_history_update().
      previous_history_.swap(history_);
      previous_dt1_ = dt1_;
      previous_dt2_ = dt2_;
      can_undo_history_ = true;
      history_.clear();
      history_.reserve(hist.size());
      for (std::size_t i = 0; i < hist.size(); ++i) history_.emplace(particles.ids()[i], hist[i]);
      dt1_ = dt1;
      dt2_ = dt2;
      break;
    }
    ++summary.rejected_solves;
    summary.halvings = halvings;
  }
  if (!summary.accepted && summary.message.empty()) summary.message = "step rejected";
  summary.wall_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return summary;
}

}  // namespace otfp
