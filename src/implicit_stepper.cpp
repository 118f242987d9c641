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
#include "step_solve.hpp"

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
  std::vector<ParticleId> ids(order.size());
  for (std::size_t i = 0; i < order.size(); ++i) {
    x0[i] = particles.positions()[order[i]];
    s0[i] = particles.widths()[order[i]];
    m[i] = particles.masses()[order[i]];
    ids[i] = particles.ids()[order[i]];
  }
  std::vector<DisplacementHistory> hist = history_.lookup(ids);
  // The serial hooks of the shared solve (src/step_solve.cpp).
  detail::StepSolveHooks hooks;
  hooks.functional = detail::serial_step_functional(functional_);
  hooks.external = &external_;
  hooks.prepare = [this](double h, const std::vector<Vec3>& x_ref, const std::vector<double>& s_ref,
                         const std::vector<double>& mass, const std::vector<double>& weights,
                         const std::vector<Vec3>& x, const std::vector<double>& s) {
    functional_.set_dt(h);
    functional_.set_reference(x_ref, s_ref, mass, weights);
    functional_.rebuild_list(x, s);  // particles may have been added or removed
  };
  hooks.admissible_start = [this](const Vec3& from, const Vec3& to) {
    return detail::admissible_start(functional_.barrier().barrier(), functional_.images().walls(), from, to);
  };
  hooks.minimize = [](Objective& objective, std::vector<double>& z, const MinimizerOptions& mo) {
    return minimize(objective, z, mo);
  };
  hooks.estimate = [this, &ids](const std::vector<Vec3>& x, const std::vector<double>& s,
                                const std::vector<Vec3>& x_new, const std::vector<double>& s_new,
                                const std::vector<double>& mass, const std::vector<DisplacementHistory>& history,
                                double h, double h1, double h2, StepSummary& sum) {
    estimate_local_error(ids, x, s, x_new, s_new, mass, history, h, h1, h2, sum);
  };
  double dt1 = history_.dt1(), dt2 = history_.dt2();
  const int builds_before = functional_.list().build_count();
  const double list_seconds_before = functional_.list().build_seconds();
  const std::uint64_t pairs_before = functional_.entropy().pair_evaluations();
  const bool accepted = detail::step_with_halvings(options_, hooks, x0, s0, m, hist, dt1, dt2, dt, max_error, summary);
  summary.list_builds += functional_.list().build_count() - builds_before;
  summary.list_seconds += functional_.list().build_seconds() - list_seconds_before;
  summary.pair_evaluations += functional_.entropy().pair_evaluations() - pairs_before;
  if (accepted) {
    const Periodicity& per = functional_.periodicity();
    for (auto& p : x0) p = per.wrap(p);
    particles.reorder(order);
    particles.positions() = std::move(x0);
    particles.widths() = std::move(s0);
    // The old history is moved aside, not dropped: undo_last_history_update().
    history_.commit(particles.ids(), hist, dt1, dt2);
  }
  if (!summary.accepted && summary.message.empty()) summary.message = "step rejected";
  summary.wall_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return summary;
}

}  // namespace otfp
