// ImplicitStepper: one step of (28) (implicit Euler or variational BDF2),
// retried with halved substeps on a failed solve. The objective in scaled
// unknowns and its stopping measure are src/step_objective.cpp; the history
// of displacements, the predictor and the local error estimate are
// src/implicit_history.cpp.
#include <chrono>
#include <cstdio>
#include <cmath>
#include <algorithm>
#include <stdexcept>
#include <limits>
#include <string>

#include "otfp/implicit_stepper.hpp"

#include "otfp/density.hpp"
#include "step_objective.hpp"

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

using detail::functional_options;

ImplicitStepper::StepProblem ImplicitStepper::step_problem(const ParticleSet& particles, double dt) {
  require(std::isfinite(dt) && dt > 0.0, "dt", dt, "must be finite and > 0");
  require(particles.dim() == dim_, "particles dim", particles.dim(),
          "must equal the stepper's dim " + std::to_string(dim_));
  functional_.set_dt(dt);
  functional_.set_reference(particles.positions(), particles.widths(), particles.masses());
  functional_.rebuild_list(particles.positions(), particles.widths());
  const double s_max = options_.max_width_factor > 0.0 ? options_.max_width_factor * options_.nominal_width : 0.0;
  auto obj = std::make_unique<detail::OwnedStepObjective>(functional_, external_, particles.positions(),
                                                          particles.widths(), particles.masses(), dt,
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
  detail::StepObjective objective(functional_, external_, x, s, m, dt, widths, weights, s_max);
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

  double m_min = m.empty() ? 1.0 : m[0], mass = 0.0;
  for (double v : m) {
    m_min = std::min(m_min, v);
    mass += v;
  }
  const detail::StepTolerances tol = detail::step_tolerances(options_, dt, s_min, m_min, mass, before);
  mo.gradient_tolerance = tol.gradient_tolerance;
  const double floor_measure = tol.floor_measure, stall_measure = tol.stall_measure;
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
  detail::record_solve(ms, start_ok, before, f0, summary);

  std::vector<Vec3> x_new = x;
  std::vector<double> s_new = s;
  const bool ok = detail::accept_solve(objective, z, start_ok, ms, tol, f0, before, options_.energy_tolerance, x_new,
                                       s_new, summary);
  summary.list_builds += functional_.list().build_count() - builds_before;
  summary.list_seconds += functional_.list().build_seconds() - list_seconds_before;
  summary.pair_evaluations += functional_.entropy().pair_evaluations() - pairs_before;
  if (!ok) return false;

  // The local error estimate (Milne's device, src/implicit_history.cpp).
  estimate_local_error(x, s, x_new, s_new, m, hist, dt, dt1, dt2, summary);

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
