// What steps and simulations report: FunctionalParts, StepSummary,
// SimulationStep, SimulationLedger, SimulationTotals, StateMeasures.
#include "common.hpp"

#include <string>

#include "otfp/diagnostics.hpp"
#include "otfp/functional.hpp"
#include "otfp/ledger.hpp"
#include "otfp/step_summary.hpp"

#include "bindings.hpp"

namespace otfp::python {

void bind_summaries(py::module_& m) {
  // ---- summaries
  py::class_<FunctionalParts>(m, "FunctionalParts")
      .def_readonly("transport", &FunctionalParts::transport)
      .def_readonly("entropy", &FunctionalParts::entropy)
      .def_readonly("barrier", &FunctionalParts::barrier)
      .def_property_readonly("total", &FunctionalParts::total);
  py::class_<StepSummary>(m, "StepSummary", "What every diffusive step reports.")
      .def_readonly("accepted", &StepSummary::accepted)
      .def_readonly("reason", &StepSummary::reason)
      .def_readonly("message", &StepSummary::message)
      .def_readonly("dt", &StepSummary::dt)
      .def_readonly("substeps", &StepSummary::substeps)
      .def_readonly("halvings", &StepSummary::halvings)
      .def_readonly("rejected_solves", &StepSummary::rejected_solves)
      .def_readonly("f_before", &StepSummary::f_before)
      .def_readonly("f_after", &StepSummary::f_after)
      .def_readonly("parts_before", &StepSummary::parts_before)
      .def_readonly("parts_after", &StepSummary::parts_after)
      .def_readonly("iterations", &StepSummary::iterations)
      .def_readonly("evaluations", &StepSummary::evaluations)
      .def_readonly("residual_displacement", &StepSummary::residual_displacement)
      .def_readonly("list_builds", &StepSummary::list_builds)
      .def_readonly("wall_seconds", &StepSummary::wall_seconds)
      .def_readonly("solver_seconds", &StepSummary::solver_seconds)
      .def_readonly("list_seconds", &StepSummary::list_seconds)
      .def_readonly("gradient_tolerance", &StepSummary::gradient_tolerance)
      .def_readonly("pair_evaluations", &StepSummary::pair_evaluations)
      .def_readonly("inserted", &StepSummary::inserted)
      .def_readonly("removed", &StepSummary::removed)
      .def_readonly("error_estimate", &StepSummary::error_estimate)
      .def_readonly("density_error_estimate", &StepSummary::density_error_estimate)
      .def_readonly("displacement_error_estimate", &StepSummary::displacement_error_estimate)
      .def_readonly("error_order", &StepSummary::error_order)
      .def_readonly("error_rejected", &StepSummary::error_rejected)
      .def("__repr__", [](const StepSummary& s) {
        return "StepSummary(accepted=" + std::string(s.accepted ? "True" : "False") + ", reason=" +
               to_string(s.reason) + ", dt=" + std::to_string(s.dt) + ", F " + std::to_string(s.f_before) + " -> " +
               std::to_string(s.f_after) + ", evaluations=" + std::to_string(s.evaluations) + ")";
      });
  py::class_<SimulationStep>(m, "SimulationStep", "One step of Algorithm 1.")
      .def_readonly("step", &SimulationStep::step)
      .def_readonly("t_start", &SimulationStep::t_start)
      .def_readonly("t_end", &SimulationStep::t_end)
      .def_property_readonly("dt", &SimulationStep::dt)
      .def_readonly("diffusion", &SimulationStep::diffusion)
      .def_readonly("inserted", &SimulationStep::inserted)
      .def_readonly("removed", &SimulationStep::removed)
      .def_readonly("reflected", &SimulationStep::reflected)
      .def_readonly("error_rejections", &SimulationStep::error_rejections)
      .def_readonly("forced_at_dt_min", &SimulationStep::forced_at_dt_min)
      .def_readonly("dt_next", &SimulationStep::dt_next)
      .def_readonly("wall_seconds", &SimulationStep::wall_seconds)
      .def("brief_report", &SimulationStep::brief_report)
      .def("full_report", &SimulationStep::full_report)
      .def("__repr__", &SimulationStep::brief_report);
  py::class_<SimulationLedger>(m, "SimulationLedger", "n(t) = n(0) + inserted - removed, and the same for the mass.")
      .def_readonly("initial_particles", &SimulationLedger::initial_particles)
      .def_readonly("initial_mass", &SimulationLedger::initial_mass)
      .def_readonly("inserted", &SimulationLedger::inserted)
      .def_readonly("removed", &SimulationLedger::removed)
      .def_readonly("mass_inserted", &SimulationLedger::mass_inserted)
      .def_readonly("mass_removed", &SimulationLedger::mass_removed)
      .def_readonly("source_inserted", &SimulationLedger::source_inserted)
      .def_readonly("source_removed", &SimulationLedger::source_removed)
      .def_readonly("reflected", &SimulationLedger::reflected)
      .def("expected_particles", &SimulationLedger::expected_particles)
      .def("expected_mass", &SimulationLedger::expected_mass);
  py::class_<SimulationTotals>(m, "SimulationTotals")
      .def_readonly("iterations", &SimulationTotals::iterations)
      .def_readonly("evaluations", &SimulationTotals::evaluations)
      .def_readonly("rejected_solves", &SimulationTotals::rejected_solves)
      .def_readonly("halvings", &SimulationTotals::halvings)
      .def_readonly("error_rejected_steps", &SimulationTotals::error_rejected_steps)
      .def_readonly("steps_forced_at_dt_min", &SimulationTotals::steps_forced_at_dt_min)
      .def_readonly("step_seconds", &SimulationTotals::step_seconds)
      .def_readonly("solver_seconds", &SimulationTotals::solver_seconds);
  py::class_<StateMeasures>(m, "StateMeasures", "(43)-(44) at one time.")
      .def_readonly("n_particles", &StateMeasures::n_particles)
      .def_readonly("n_inside", &StateMeasures::n_inside)
      .def_readonly("n_buffer", &StateMeasures::n_buffer)
      .def_readonly("n_outside", &StateMeasures::n_outside)
      .def_readonly("mass_total", &StateMeasures::mass_total)
      .def_readonly("mass_inside", &StateMeasures::mass_inside)
      .def_readonly("mass_with_layer", &StateMeasures::mass_with_layer)
      .def_readonly("polar_inertia", &StateMeasures::polar_inertia)
      .def_readonly("polar_inertia_with_layer", &StateMeasures::polar_inertia_with_layer)
      .def_readonly("polar_inertia_total", &StateMeasures::polar_inertia_total)
      .def_readonly("mean_age", &StateMeasures::mean_age)
      .def_readonly("max_age", &StateMeasures::max_age);
}

}  // namespace otfp::python
