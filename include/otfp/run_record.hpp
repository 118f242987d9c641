#pragma once
// A run's rows as a library call: what `otfp run` writes to series.csv and
// timing.csv (docs/outputs.md). RunRecorder measures a Simulation's state
// after each step, (43)-(46) and the blob density's mass, the step's
// solver figures and the analytic reference's columns, into a StepRecord;
// SeriesLayout writes the records as CSV rows. A C++ or Python caller gets
// the command line's series.csv from an observer:
//
//   otfp::RunRecorder rows(sim, options, reference.get());  // center, M_inf, J_inf
//   rows.step_dt = dt;                 // the grid's step: (46) sums with it from row 0
//   rows.set_initial(fill);            // the particles given to sim.start(fill)
//   sim.start(fill);
//   const otfp::SeriesLayout layout(options.J_inf.has_value(), reference && reference->has_mass_blob_error(),
//                                   reference ? reference->columns() : std::vector<std::string>{});
//   const otfp::SimulationStep& s0 = sim.initial_step();
//   out << layout.header() << layout.row(rows(0, 0.0, nullptr, s0.inserted, s0.removed));
//   otfp::Observer observer;
//   observer.row = [&](const otfp::SimulationStep& s, bool) {
//     rows.step_dt = adaptive ? s.dt() : sim.time_grid().dt;  // a fixed grid's dt, not t_k - t_{k-1}
//     out << layout.row(rows(s.step, s.t_end, &s.diffusion, s.inserted, s.removed));
//   };
#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "otfp/diagnostics.hpp"
#include "otfp/mass_measure.hpp"
#include "otfp/reference.hpp"
#include "otfp/simulation.hpp"
#include "otfp/step_summary.hpp"

namespace otfp {

// Diagnostics of one step (row of series.csv).
struct StepRecord {
  std::int64_t step = 0;
  double t = 0.0, dt = 0.0;
  std::int64_t n_particles = 0, n_inside = 0, n_buffer = 0, n_outside = 0;
  double mass_total = 0.0, mass_inside = 0.0, mass_with_layer = 0.0;
  double polar_inertia = 0.0, polar_inertia_with_layer = 0.0, polar_inertia_total = 0.0;
  std::int64_t inserted = 0, removed = 0, inserted_total = 0, removed_total = 0;
  double energy = 0.0, transport = 0.0, entropy = 0.0, barrier = 0.0, residual_displacement = 0.0;
  std::int64_t iterations = 0, evaluations = 0, list_builds = 0, halvings = 0;
  std::optional<double> error_estimate;           // local time-error estimate of the accepted step (in widths)
  std::int64_t rejected_steps = 0;                // adaptive dt: tries rejected by the error test before this step
  double mean_age = 0.0, max_age = 0.0;
  double l1_mass = 0.0, l1_polar_inertia = 0.0;  // running (46a)-(46b), rectangle rule, all particles
  double mass_ratio = 0.0;                        // mass_inside / M_inf
  double mass_blob = 0.0;                         // M_rho: the blob density integrated over Omega
  double mass_blob_ratio = 0.0;                   // mass_blob / M_inf
  std::optional<double> error_mass_blob;          // mass_blob_ratio - Crank's M/M_inf (crank_* references)
  std::optional<double> polar_inertia_ratio;      // polar_inertia / J_inf
  std::optional<double> reference;                // the primary reference value (first reference column)
  std::vector<double> reference_values;           // the reference columns of series.csv, in order
  // Timing: kept out of series.csv so that it is reproducible byte for byte.
  double wall_seconds = 0.0, step_seconds = 0.0, solver_seconds = 0.0, list_seconds = 0.0;
};

// The running sums next to a Simulation's state (a checkpoint keeps them).
struct RunSums {
  L1Norms l1;  // (46): the rectangle sums go into the rows, the trapezoid sums into a summary
  StateMeasures prev_measures;
  std::int64_t n0 = 0;  // initial particles and mass
  double M0 = 0.0;
};

struct RecorderOptions {
  Vec3 center = Vec3::Zero();   // centre of the polar inertia (44)
  double M_inf = 1.0;           // mass_ratio = mass_inside / M_inf (> 0)
  std::optional<double> J_inf;  // polar_inertia_ratio = polar_inertia / J_inf, where given
  // The blob density's mass M_rho. The quadrature path (domains without a
  // closed form) runs 4 x 4 normal lines per blob near a wall instead of
  // the library's 10 x 10: 6x cheaper, about 1e-3 of the near-wall blob mass
  // either way (docs/outputs.md); closed forms cost ~0.1 us per particle.
  BlobMassOptions blob_mass = [] {
    BlobMassOptions o;
    o.hermite_nodes = 4;
    return o;
  }();
  void validate() const;  // throws InvalidArgument naming the field
};

// The rows of a run, one call per row, in time order (the running sums (46)
// and the reference's statistics follow them).
class RunRecorder {
 public:
  // `reference` (may be null) and `sim` must outlive the recorder;
  // `wall_seconds` gives the row's wall_seconds (default: since construction).
  RunRecorder(const Simulation& sim, const RecorderOptions& options, Reference* reference = nullptr,
              std::function<double()> wall_seconds = {});
  // The row of step `step` ending at t; `summary` is the diffusive step's
  // (null for row 0), `inserted` and `removed` the step's counts.
  StepRecord operator()(std::int64_t step, double t, const StepSummary* summary, std::int64_t inserted,
                        std::int64_t removed);
  // Each particle's region of the last row (0 inside, 1 buffer, 2 outside).
  const std::vector<std::int32_t>& region() const { return region_; }
  // The initial particles (before Simulation::start adds a reservoir band):
  // their count and mass are sums.n0 and sums.M0 (the free-space reference's
  // growth 2 d kappa M t uses M0). Without it, row 0 takes the whole state's.
  void set_initial(const ParticleSet& particles);

  RunSums sums;
  // The step being taken (fixed: the grid's dt, as (46) is summed; adaptive:
  // its own length) and the tries the error test rejected before it.
  double step_dt = 0.0;
  std::int64_t step_rejections = 0;

 private:
  const Simulation& sim_;
  RecorderOptions options_;
  Reference* reference_;
  std::function<double()> wall_;
  std::vector<std::int32_t> region_;
  bool initial_set_ = false;
};

}  // namespace otfp
