// summary.json of a run (docs/outputs.md).
#include <omp.h>

#include <algorithm>
#include <cmath>
#include <variant>

#include "otfp_app/series_columns.hpp"
#include "run_parts.hpp"

namespace otfp::app::detail {

namespace {

nlohmann::json statistics_json(const ErrorStatistics& e) {
  return {{"measured", e.measured()},
          {"scale", e.scale()},
          {"scale_rule", e.scale_rule()},
          {"max_abs_error", e.max_abs_error()},
          {"l1_time_error", e.l1_time_error()},
          {"mean_abs_error", e.mean_abs_error()},
          {"final_error", e.final_error()},
          {"l1_norm", e.l1_norm()},
          {"l1_norm_reference", e.l1_norm_reference()},
          {"l1_norm_relative_error", e.l1_norm_relative_error()}};
}

// summary.json "reference" (docs/outputs.md).
nlohmann::json reference_json(const Reference& ref) {
  nlohmann::json q = nlohmann::json::array();
  for (const ErrorStatistics& e : ref.statistics()) q.push_back(statistics_json(e));
  nlohmann::json j = {{"curve", ref.name()},
                      {"error_rule", "error = (measured - reference) / scale per row; max_abs_error over rows; "
                                     "l1_time_error = integral of |error| dt (trapezoid); mean_abs_error = "
                                     "l1_time_error / t; l1_norm = integral of the quantity dt (trapezoid)"},
                      {"quantities", q}};
  if (const auto blob = ref.mass_blob_statistics()) j["mass_blob"] = statistics_json(*blob);
  for (const ReferenceEntry& e : ref.summary())
    j[e.key] = std::visit(
        [](auto v) { return std::isfinite(static_cast<double>(v)) ? nlohmann::json(v) : nlohmann::json(nullptr); },
        e.value);
  return j;
}

// summary.json "ledger": the run's and each patch's insertions and removals.
nlohmann::json ledger_json(const ConfiguredRun& run, const otfp::Simulation& sim, const RunSums& sums) {
  nlohmann::json patches = nlohmann::json::array();
  for (const PatchInfo& p : run.patches()) {
    nlohmann::json j = {{"patch", p.name}, {"kind", to_string(p.kind)}};
    PatchLedger l;
    if (p.condition >= 0) l = sim.projection().ledger()[static_cast<std::size_t>(p.condition)];
    j["inserted"] = l.inserted;
    j["removed"] = l.removed;
    j["mass_inserted"] = l.mass_inserted;
    j["mass_removed"] = l.mass_removed;
    j["absorbed"] = l.absorbed;
    j["mass_absorbed"] = l.mass_absorbed;
    j["flux_integral"] = l.flux_integral;
    j["carry"] = l.carry;
    j["deficit"] = l.deficit;
    patches.push_back(j);
  }
  const SimulationLedger& g = sim.ledger();
  return nlohmann::json{{"initial_particles", sums.n0},
                        {"reflected", g.reflected},
                        {"initial_mass", sums.M0},
                        {"inserted", g.inserted},
                        {"removed", g.removed},
                        {"mass_inserted", g.mass_inserted},
                        {"mass_removed", g.mass_removed},
                        {"source", {{"inserted", g.source_inserted},
                                    {"removed", g.source_removed},
                                    {"mass_inserted", g.source_mass_inserted},
                                    {"mass_removed", g.source_mass_removed}}},
                        {"patches", patches}};
}

}  // namespace

nlohmann::json run_summary(const ConfiguredRun& run, const otfp::Simulation& sim, const Reference* reference,
                           const RunSums& sums, double wall_seconds, const std::string& status,
                           const std::string& error, const StepRecord& last) {
  const Config& c = run.config();
  const L1Norms& l1 = sums.l1;
  nlohmann::json j = run.describe();
  j["otfp_version"] = version();
  j["status"] = status;
  j["error"] = error;
  j["config_file"] = c.source;
  j["overrides"] = c.overrides;
  j["seed"] = c.run.seed;
  j["wall_seconds"] = wall_seconds;
  j["threads"] = omp_get_max_threads();
  j["final"] = final_json(last);
  j["l1"] = {{"rule_series", "rectangle sum over k = 0..K of the value at t_k times dt, all particles (46) as printed"},
             {"mass_rectangle", last.l1_mass},
             {"polar_inertia_rectangle", last.l1_polar_inertia},
             {"rule_trapezoid", "trapezoid rule over [0, t]"},
             {"mass_inside_trapezoid", l1.mass_inside_trapezoid},
             {"mass_with_layer_trapezoid", l1.mass_with_layer_trapezoid},
             {"polar_inertia_inside_trapezoid", l1.polar_inertia_inside_trapezoid},
             {"polar_inertia_with_layer_trapezoid", l1.polar_inertia_with_layer_trapezoid}};
  if (reference) j["reference"] = reference_json(*reference);
  j["ledger"] = ledger_json(run, sim, sums);
  const SimulationTotals& tt = sim.totals();
  j["solver_totals"] = {{"iterations", tt.iterations},
                        {"evaluations", tt.evaluations},
                        {"rejected_solves", tt.rejected_solves},
                        {"halvings", tt.halvings},
                        {"error_rejected_steps", tt.error_rejected_steps},
                        {"steps_forced_at_dt_min", tt.steps_forced_at_dt_min},
                        {"dt_min_used", tt.dt_max_used > 0.0 ? nlohmann::json(tt.dt_min_used) : nlohmann::json(nullptr)},
                        {"dt_max_used", tt.dt_max_used > 0.0 ? nlohmann::json(tt.dt_max_used) : nlohmann::json(nullptr)}};
  // Where the diffusion steps spent their time (wall clock, not reproducible).
  j["profile"] = {{"diffusion_step_seconds", tt.step_seconds},
                  {"solver_seconds", tt.solver_seconds},
                  {"neighbor_list_seconds", tt.list_seconds},
                  {"evaluation_seconds", std::max(0.0, tt.step_seconds - tt.solver_seconds - tt.list_seconds)},
                  {"other_seconds", std::max(0.0, wall_seconds - tt.step_seconds)},
                  {"rule", "evaluation = diffusion step - solver - neighbour list (pair sweeps, barrier, sorting); "
                           "other = wall - diffusion steps (projection, advection, source, diagnostics, output)"}};
  return j;
}

}  // namespace otfp::app::detail
