// The rows of a run (run_record.hpp): the measures (43)-(46) of each step,
// its solver figures and the reference's columns.
#include "otfp/run_record.hpp"

#include <chrono>
#include <cmath>
#include <utility>

namespace otfp {

void RecorderOptions::validate() const {
  require(std::isfinite(M_inf) && M_inf > 0.0, "M_inf", M_inf, "must be finite and > 0");
  if (J_inf) require(std::isfinite(*J_inf) && *J_inf > 0.0, "J_inf", *J_inf, "must be finite and > 0");
  for (int k = 0; k < 3; ++k) require(std::isfinite(center[k]), "center", center[k], "must be finite");
}

RunRecorder::RunRecorder(const Simulation& sim, const RecorderOptions& options, Reference* reference,
                         std::function<double()> wall_seconds)
    : sim_(sim), options_(options), reference_(reference), wall_(std::move(wall_seconds)) {
  options_.validate();
  if (!wall_) {
    const auto start = std::chrono::steady_clock::now();
    wall_ = [start] { return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count(); };
  }
}

void RunRecorder::set_initial(const ParticleSet& particles) {
  sums.n0 = static_cast<std::int64_t>(particles.size());
  sums.M0 = particles.total_mass();
  initial_set_ = true;
}

StepRecord RunRecorder::operator()(std::int64_t step, double t, const StepSummary* sum, std::int64_t ins,
                                   std::int64_t rem) {
  StepRecord r;
  r.step = step;
  r.t = t;
  r.dt = step == 0 ? 0.0 : step_dt;
  // (43)-(44) inside Omega and with the buffer outside the Dirichlet faces.
  const StateMeasures ms = sim_.measure(options_.center, &region_);
  r.n_particles = ms.n_particles;
  r.n_inside = ms.n_inside;
  r.n_buffer = ms.n_buffer;
  r.n_outside = ms.n_outside;
  r.mass_total = ms.mass_total;
  r.mass_inside = ms.mass_inside;
  r.mass_with_layer = ms.mass_with_layer;
  r.polar_inertia = ms.polar_inertia;
  r.polar_inertia_with_layer = ms.polar_inertia_with_layer;
  r.polar_inertia_total = ms.polar_inertia_total;
  r.mean_age = ms.mean_age;
  r.max_age = ms.max_age;
  r.inserted = ins;
  r.removed = rem;
  r.inserted_total = sim_.ledger().inserted;
  r.removed_total = sim_.ledger().removed;
  if (sum) {
    r.energy = sum->f_after;
    r.transport = sum->parts_after.transport;
    r.entropy = sum->parts_after.entropy;
    r.barrier = sum->parts_after.barrier;
    r.residual_displacement = sum->residual_displacement;
    r.iterations = sum->iterations;
    r.evaluations = sum->evaluations;
    r.list_builds = sum->list_builds;
    r.halvings = sum->halvings;
    if (std::isfinite(sum->error_estimate)) r.error_estimate = sum->error_estimate;
    r.rejected_steps = step_rejections;
    r.step_seconds = sum->wall_seconds;
    r.solver_seconds = sum->solver_seconds;
    r.list_seconds = sum->list_seconds;
  }
  if (step == 0 && !initial_set_) {
    sums.n0 = ms.n_particles;
    sums.M0 = ms.mass_total;
    initial_set_ = true;
  }
  // (46a)-(46b) as printed: sum over k = 0..K of the value at t_k times dt, all particles.
  if (step == 0)
    sums.l1.add_first(ms, step_dt);
  else
    sums.l1.add(sums.prev_measures, ms, step_dt);
  sums.prev_measures = ms;
  r.l1_mass = sums.l1.mass_rectangle;
  r.l1_polar_inertia = sums.l1.polar_inertia_rectangle;
  r.mass_ratio = r.mass_inside / options_.M_inf;
  if (options_.J_inf) r.polar_inertia_ratio = r.polar_inertia / *options_.J_inf;
  r.mass_blob = sim_.blob_mass(options_.blob_mass);
  r.mass_blob_ratio = r.mass_blob / options_.M_inf;
  // Analytic reference: measured, reference, error (scaled) per row.
  if (reference_) {
    ReferenceSample sample;
    sample.t = t;
    sample.measures = ms;
    sample.mass_blob = r.mass_blob;
    // A distributed run's particles are shares: the reference reads all.
    ParticleSet gathered;
    const bool gather = sim_.distributed() && reference_->uses_particles();
    if (gather) gathered = sim_.gathered_particles();
    sample.particles = gather ? &gathered : &sim_.particles();
    sample.initial_mass = sums.M0;
    ReferenceRow row = reference_->row(sample);
    r.reference_values = std::move(row.values);
    r.reference = row.reference;
    r.error_mass_blob = row.error_mass_blob;
  }
  r.wall_seconds = wall_();
  return r;
}

}  // namespace otfp
