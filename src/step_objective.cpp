// The objective of one implicit step in scaled unknowns (src/step_objective.hpp).
#include "step_objective.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>

namespace otfp::detail {

namespace {

// The fold phi of the widths under the bound S (step_objective.hpp).
constexpr double kWidthFold = 0.25;
double fold(double v) { return v <= -kWidthFold ? v : -(v - kWidthFold) * (v - kWidthFold) / (4.0 * kWidthFold); }
double fold_slope(double v) { return v <= -kWidthFold ? 1.0 : -(v - kWidthFold) / (2.0 * kWidthFold); }
double fold_inverse(double t) {  // the branch v <= d, for t <= 0
  return t <= -kWidthFold ? t : kWidthFold - std::sqrt(-4.0 * kWidthFold * t);
}

}  // namespace

StepFunctional serial_step_functional(Functional& f) {
  StepFunctional sf;
  sf.dim = f.dim();
  sf.c_w = f.transport().c_w();
  sf.evaluate = [&f](const std::vector<Vec3>& x, const std::vector<double>& s, Gradient* g) {
    return f.evaluate(x, s, g);
  };
  return sf;
}

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

StepTolerances step_tolerances(const ImplicitOptions& o, double dt, double s_min, double m_min, double mass,
                               const FunctionalParts& before) {
  StepTolerances t;
  t.gradient_tolerance = o.displacement_tolerance * s_min;
  const bool energy_norm = o.stopping_norm == StoppingNorm::Energy;
  // A line search stalls once the decrease it must see is below the round-off
  // of F. With unit curvature in the scaled unknowns that happens at
  // |g_z|^2 ~ eps_F, i.e. at a displacement ~ sqrt(eps_F dt / m). Closer to
  // stationarity than that no solver can certify.
  const double f_scale = std::abs(before.transport) + std::abs(before.entropy) + std::abs(before.barrier) + o.kappa * mass;
  const double eps_f = 64.0 * std::numeric_limits<double>::epsilon() * f_scale;
  // In the energy norm the whole gradient stalls at |g_z|^2 ~ eps_F, an RMS
  // of sqrt(eps_F dt / M); a single particle at its floor shows as that floor
  // over max_norm_factor.
  t.floor_measure = energy_norm ? std::max(std::sqrt(eps_f * dt / std::max(mass, m_min)),
                                           std::sqrt(eps_f * dt / m_min) / o.max_norm_factor)
                                : std::sqrt(eps_f * dt / m_min);
  // Along the stiffest direction (the Hessian in the scaled unknowns is
  // I + (dt/m) D^2 E, largest eigenvalue about 1 + 2 kappa beta dt,
  // docs/method_notes.md) a line search stalls at sqrt(lambda_max) times that
  // floor. A start (or a stalled solve) already below it and below the
  // absolute tolerance is as converged as F can tell: without this a settled
  // state stepped at 1000x the explicit limit looked unconverged to the
  // relative rule and was retried with dt halved three times (51 evaluations
  // per step, no motion; tests/test_reservoir.cpp, SettledStateIsAFixedPoint).
  const double lambda_max = 1.0 + 2.0 * o.kappa * dt / (s_min * s_min);
  t.stall_measure = std::min(t.gradient_tolerance, t.floor_measure * std::sqrt(lambda_max));
  return t;
}

void record_solve(const MinimizerSummary& ms, bool start_ok, const FunctionalParts& before, double f0,
                  StepSummary& summary) {
  summary.reason = start_ok ? ms.reason : TerminationReason::NonFinite;
  summary.iterations += ms.iterations;
  summary.evaluations += ms.evaluations;
  summary.solver_seconds += ms.solver_seconds;
  summary.residual_displacement = ms.final_stopping_measure;
  summary.gradient_tolerance = ms.gradient_tolerance;
  summary.parts_before = before;
  summary.f_before = f0;
}

bool accept_solve(StepObjective& objective, const std::vector<double>& z, bool start_ok, const MinimizerSummary& ms,
                  const StepTolerances& tol, double f0, const FunctionalParts& before, double energy_tolerance,
                  std::vector<Vec3>& x_new, std::vector<double>& s_new, StepSummary& summary) {
  bool ok = start_ok && ms.success;
  if (start_ok && !ms.success && ms.reason == TerminationReason::LineSearchFailure &&
      ms.final_stopping_measure <= std::max({ms.gradient_tolerance, tol.floor_measure, tol.stall_measure})) {
    ok = true;
    summary.message = "converged to the round-off floor of F";
  }
  if (!ok) {
    summary.message = start_ok ? "solver: " + to_string(ms.reason) + (ms.message.empty() ? "" : " (" + ms.message + ")")
                               : "non-finite F at the start of the step";
    return false;
  }
  double f1 = 0.0;
  objective.unpack(z.data(), x_new, s_new);
  ok = objective.evaluate(z.data(), &f1, nullptr);
  summary.parts_after = objective.parts();
  summary.f_after = f1;
  // Energy inequality F(x^{k+1}) <= F(x^k) (+ round-off). Euler: F(x^k) = E(x^k),
  // so E(x^{k+1}) + W^2/(2 dt) <= E(x^k). BDF2 (d_k = x^k - x^{k-1}, c = w^2/(1+2w)):
  // E(x^{k+1}) + a0 m/(2 dt) |d_{k+1} - c d_k|^2 <= E(x^k) + a0 m/(2 dt) c^2 |d_k|^2.
  const double slack = energy_tolerance * (std::abs(f0) + std::abs(before.entropy) + std::abs(before.barrier) + 1e-300);
  if (ok && f1 > f0 + slack) {
    ok = false;
    summary.message = "energy increased: F_after - F_before = " + std::to_string(f1 - f0);
  }
  return ok;
}

StepObjective::StepObjective(Functional& f, const ExternalPotential& ext, const std::vector<Vec3>& x_anchor,
                             const std::vector<double>& s_anchor, const std::vector<double>& m, double dt,
                             bool widths, const std::vector<double>& weights, double s_max)
    : StepObjective(serial_step_functional(f), ext, x_anchor, s_anchor, m, dt, widths, weights, s_max) {}

StepObjective::StepObjective(StepFunctional f, const ExternalPotential& ext, const std::vector<Vec3>& x_anchor,
                             const std::vector<double>& s_anchor, const std::vector<double>& m, double dt,
                             bool widths, const std::vector<double>& weights, double s_max)
    : f_(std::move(f)), ext_(ext), s_ref_(s_anchor), m_(m), dim_(f_.dim), widths_(widths), n_(x_anchor.size()),
      s_max_(widths ? s_max : 0.0) {
  const double c_w = f_.c_w;
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

void StepObjective::pack(const std::vector<Vec3>& x, const std::vector<double>& s, double* z) const {
  for (std::size_t p = 0; p < n_; ++p) {
    for (int k = 0; k < dim_; ++k) z[p * dim_ + k] = scale_x_[p] * x[p][k];
    if (widths_) z[n_ * dim_ + p] = width_unknown(p, s[p]);
  }
}

void StepObjective::unpack(const double* z, std::vector<Vec3>& x, std::vector<double>& s) const {
  for (std::size_t p = 0; p < n_; ++p) {
    for (int k = 0; k < dim_; ++k) x[p][k] = z[p * dim_ + k] / scale_x_[p];
    if (widths_) s[p] = width_of(p, z[n_ * dim_ + p]);
  }
}

bool StepObjective::evaluate(const double* z, double* value, double* gradient) {
  unpack(z, x_, s_);
  bool finite = true;
  for (std::size_t p = 0; p < n_ && finite; ++p)
    finite = x_[p].allFinite() && std::isfinite(s_[p]) && s_[p] > 0.0;
  if (!(f_.all ? f_.all(finite) : finite)) return false;
  parts_ = f_.evaluate(x_, s_, gradient ? &g_ : nullptr);
  if (ext_) {
    double ext = 0.0;
    for (std::size_t p = 0; p < n_; ++p) {
      Vec3 gu = Vec3::Zero();
      ext += m_[p] * ext_(x_[p], gradient ? &gu : nullptr);
      if (gradient) g_.x[p] += m_[p] * gu;
    }
    if (f_.sum) f_.sum(&ext, 1);
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
    bool finite_gradient = true;
    for (std::size_t i = 0; i < num_variables(); ++i)
      if (!std::isfinite(gradient[i])) finite_gradient = false;
    if (!(f_.all ? f_.all(finite_gradient) : finite_gradient)) return false;
  }
  return true;
}

double StepObjective::stopping_measure(const double* z, const double* gradient) const {
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
  if (f_.max) worst = f_.max(worst);
  if (!(max_norm_factor_ > 0.0)) return worst;
  if (f_.sum) {
    double sums[2] = {sum, mass};
    f_.sum(sums, 2);
    sum = sums[0];
    mass = sums[1];
  }
  const double rms = mass > 0.0 ? std::sqrt(sum / mass) : 0.0;
  // A NaN (an overflowing scale) must never read as converged.
  if (!std::isfinite(rms)) return std::numeric_limits<double>::infinity();
  return std::max(rms, worst / max_norm_factor_);
}

double StepObjective::width_of(std::size_t p, double zs) const {
  if (!(s_max_ > 0.0)) return s_ref_[p] * std::exp(zs / scale_s_[p]);
  return std::min(s_max_ * std::exp(fold(u_ref_[p] + zs / scale_b_[p])), s_max_);
}
double StepObjective::width_unknown(std::size_t p, double s) const {
  if (!(s_max_ > 0.0)) return scale_s_[p] * std::log(s / s_ref_[p]);
  return scale_b_[p] * (fold_inverse(std::min(std::log(s / s_max_), 0.0)) - u_ref_[p]);
}

}  // namespace otfp::detail
