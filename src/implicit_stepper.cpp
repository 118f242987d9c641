#include <chrono>
#include <cmath>
#include <limits>

#include "otfp/stepper.hpp"

namespace otfp {

std::string to_string(WidthMode m) { return m == WidthMode::Fixed ? "fixed" : "per_particle"; }

WidthMode width_mode_from_string(const std::string& s) {
  if (s == "fixed") return WidthMode::Fixed;
  if (s == "per_particle") return WidthMode::PerParticle;
  throw InvalidArgument("width_mode = '" + s + "': must be one of fixed, per_particle");
}

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
  return f;
}

// The objective in scaled unknowns: z_x = sqrt(m/dt) x makes the transport
// Hessian the identity; widths are z_s = a_p log(s/s^k) with a_p = s^k sqrt(c_w m/dt),
// which keeps s > 0 without bounds (NLopt's bounds slow L-BFGS down, Ceres has
// none) and has unit curvature at s = s^k.
class StepObjective final : public Objective {
 public:
  StepObjective(Functional& f, const ExternalPotential& ext, const std::vector<Vec3>& x_ref,
                const std::vector<double>& s_ref, const std::vector<double>& m, double dt, bool widths)
      : f_(f), ext_(ext), s_ref_(s_ref), m_(m), dim_(f.dim()), widths_(widths), n_(x_ref.size()) {
    const double c_w = f.transport().c_w();
    scale_x_.resize(n_);
    scale_s_.resize(widths ? n_ : 0);
    for (std::size_t p = 0; p < n_; ++p) {
      scale_x_[p] = std::sqrt(m[p] / dt);
      if (widths) scale_s_[p] = s_ref[p] * std::sqrt(c_w * m[p] / dt);
    }
    x_ = x_ref;
    s_ = s_ref;
    disp_x_.resize(n_);
    disp_s_.resize(widths ? n_ : 0);
    for (std::size_t p = 0; p < n_; ++p) {
      disp_x_[p] = dt / m[p];
      if (widths) disp_s_[p] = dt / (c_w * m[p]);
    }
  }

  std::size_t num_variables() const override { return n_ * (dim_ + (widths_ ? 1 : 0)); }

  void pack(const std::vector<Vec3>& x, const std::vector<double>& s, double* z) const {
    for (std::size_t p = 0; p < n_; ++p) {
      for (int k = 0; k < dim_; ++k) z[p * dim_ + k] = scale_x_[p] * x[p][k];
      if (widths_) z[n_ * dim_ + p] = scale_s_[p] * std::log(s[p] / s_ref_[p]);
    }
  }
  void unpack(const double* z, std::vector<Vec3>& x, std::vector<double>& s) const {
    for (std::size_t p = 0; p < n_; ++p) {
      for (int k = 0; k < dim_; ++k) x[p][k] = z[p * dim_ + k] / scale_x_[p];
      if (widths_) s[p] = s_ref_[p] * std::exp(z[n_ * dim_ + p] / scale_s_[p]);
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
        if (widths_) gradient[n_ * dim_ + p] = g_.s[p] * s_[p] / scale_s_[p];
      }
      for (std::size_t i = 0; i < num_variables(); ++i)
        if (!std::isfinite(gradient[i])) return false;
    }
    return true;
  }

  // max |dt/m dF/dx| and max |dt/(c_w m) dF/ds|: how far one gradient step would move a particle.
  double stopping_measure(const double* z, const double* gradient) const override {
    double worst = 0.0;
    for (std::size_t p = 0; p < n_; ++p) {
      for (int k = 0; k < dim_; ++k)
        worst = std::max(worst, std::abs(gradient[p * dim_ + k] * scale_x_[p] * disp_x_[p]));
      if (widths_) {
        const double s = s_ref_[p] * std::exp(z[n_ * dim_ + p] / scale_s_[p]);
        worst = std::max(worst, std::abs(gradient[n_ * dim_ + p] * scale_s_[p] / s * disp_s_[p]));
      }
    }
    return worst;
  }

  const FunctionalParts& parts() const { return parts_; }

 private:
  Functional& f_;
  const ExternalPotential& ext_;
  const std::vector<double>& s_ref_;
  const std::vector<double>& m_;
  int dim_;
  bool widths_;
  std::size_t n_;
  std::vector<double> scale_x_, scale_s_, disp_x_, disp_s_;
  std::vector<Vec3> x_;
  std::vector<double> s_;
  Gradient g_;
  FunctionalParts parts_;
};

}  // namespace

ImplicitStepper::ImplicitStepper(int dim, ImplicitOptions options, Barrier barrier, Periodicity periodicity)
    : dim_(dim),
      options_((options.validate(), options)),
      functional_(dim, functional_options(options), std::move(barrier), periodicity) {}

bool ImplicitStepper::solve(std::vector<Vec3>& x, std::vector<double>& s, const std::vector<double>& m, double dt,
                            StepSummary& summary) {
  functional_.set_dt(dt);
  functional_.set_reference(x, s, m);
  const int builds_before = functional_.list().build_count();
  const double list_seconds_before = functional_.list().build_seconds();
  const std::uint64_t pairs_before = functional_.entropy().pair_evaluations();
  functional_.rebuild_list(x, s);  // particles may have been added or removed

  const bool widths = options_.width_mode == WidthMode::PerParticle;
  StepObjective objective(functional_, external_, x, s, m, dt, widths);
  std::vector<double> z(objective.num_variables());
  objective.pack(x, s, z.data());

  double s_min = s.empty() ? 1.0 : s[0];
  for (double v : s) s_min = std::min(s_min, v);
  MinimizerOptions mo = options_.minimizer;
  mo.gradient_tolerance = options_.displacement_tolerance * s_min;

  double f0 = 0.0;
  const bool start_ok = objective.evaluate(z.data(), &f0, nullptr);
  const FunctionalParts before = objective.parts();

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
  const double floor_measure = std::sqrt(eps_f * dt / m_min);
  // Relative rule (applied by the minimiser at its start point): the first
  // gradient step is the explicit displacement of the step; at small dt the
  // absolute rule alone stops before the solution has moved by much more
  // than the tolerance (under-diffusion, docs/validation.md study 3).
  mo.relative_gradient_tolerance = options_.relative_tolerance;
  mo.gradient_tolerance_floor = floor_measure;

  MinimizerSummary ms;
  if (start_ok) ms = minimize(objective, z, mo);
  summary.reason = start_ok ? ms.reason : TerminationReason::NonFinite;
  summary.iterations += ms.iterations;
  summary.evaluations += ms.evaluations;
  summary.solver_seconds += ms.solver_seconds;
  summary.gradient_norm = ms.final_stopping_measure;
  summary.gradient_tolerance = ms.gradient_tolerance;
  summary.parts_before = before;
  summary.f_before = f0;

  bool ok = start_ok && ms.success;
  if (start_ok && !ms.success && ms.reason == TerminationReason::LineSearchFailure &&
      ms.final_stopping_measure <= std::max(ms.gradient_tolerance, floor_measure)) {
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
    // Energy-dissipation inequality: E(x_{k+1}) + W^2/(2 dt) <= E(x_k) (+ round-off).
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
  if (ok) {
    x = std::move(x_new);
    s = std::move(s_new);
  }
  return ok;
}

StepSummary ImplicitStepper::step(ParticleSet& particles, double dt) {
  require(std::isfinite(dt) && dt > 0.0, "dt", dt, "must be finite and > 0");
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
  for (std::size_t i = 0; i < order.size(); ++i) {
    x0[i] = particles.positions()[order[i]];
    s0[i] = particles.widths()[order[i]];
    m[i] = particles.masses()[order[i]];
  }
  for (int halvings = 0; halvings <= options_.max_halvings; ++halvings) {
    std::vector<Vec3> x = x0;
    std::vector<double> s = s0;
    const int substeps = 1 << halvings;
    const double h = dt / substeps;
    bool ok = true;
    FunctionalParts first_before;
    double first_f = 0.0;
    for (int k = 0; k < substeps && ok; ++k) {
      ok = solve(x, s, m, h, summary);
      if (k == 0) {
        first_before = summary.parts_before;
        first_f = summary.f_before;
      }
    }
    if (ok) {
      summary.accepted = true;
      summary.halvings = halvings;
      summary.substeps = substeps;
      summary.parts_before = first_before;
      summary.f_before = first_f;
      const Periodicity& per = functional_.periodicity();
      for (auto& p : x) p = per.wrap(p);
      particles.reorder(order);
      particles.positions() = std::move(x);
      particles.widths() = std::move(s);
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
