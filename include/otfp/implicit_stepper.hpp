#pragma once
// The implicit variational step of the diffusive fractional step: minimise
// (28) with Ceres or NLopt (docs/stepper.md). ImplicitOptions and the enums
// of its options (WidthMode, TimeScheme, Predictor, with their string
// conversions) live here; the report is StepSummary (step_summary.hpp).
#include <cstddef>
#include <limits>
#include <memory>
#include <string>
#include <unordered_map>
#include <utility>
#include <vector>

#include "otfp/external_potential.hpp"
#include "otfp/functional.hpp"
#include "otfp/minimizer.hpp"
#include "otfp/step_history.hpp"
#include "otfp/step_summary.hpp"
#include "otfp/enums.hpp"

namespace otfp {

struct ImplicitOptions {
  MinimizerOptions minimizer;                        // backend, algorithm, caps (gradient_tolerance is set per step)
  double displacement_tolerance = 1e-3;              // stop when max |dt/m dF/dx| <= this x smallest width s
  double relative_tolerance = 1e-2;                  // ... or <= this x the step's first gradient step, if smaller
  WidthMode width_mode = WidthMode::Fixed;           // optimise widths or not
  WidthMetric width_metric = WidthMetric::AsPrinted; // c_w = 1 or d/2
  double kappa = 1.0;                                // diffusivity
  double rho_ref = 1.0;                              // reference density in the entropy
  NeighborOptions neighbor{1e-8, -1.0, 1.0};         // cut-off tolerance; skin = 1 x smallest s
  int max_halvings = 4;                              // retries with dt/2 substeps after a failed solve
  double energy_tolerance = 1e-9;                    // allowed F_after - F_before, relative to |F_before| + |E|
  bool sort_particles = true;                        // reorder particles spatially at each accepted step (ids kept)
  TimeScheme time_scheme = TimeScheme::Euler;        // implicit Euler or variational BDF2
  Predictor predictor = Predictor::None;             // start of each solve
  double error_smoothing = 2.0;                      // error estimate: smoothing length in widths s (0: per particle)
  ErrorMeasure error_measure = ErrorMeasure::Displacement;  // what StepSummary::error_estimate measures (docs/stepper.md)
  StoppingNorm stopping_norm = StoppingNorm::Energy; // norm of the stopping rule's residual (docs/stepper.md)
  double max_norm_factor = 100.0;                    // Energy: the largest particle's residual may be this x the RMS tolerance (>= 1)
  double width_skin = 0.0;                           // PerParticle: list built for widths s (1 + width_skin) (>= 0)
  double max_width_factor = 0.0;                     // PerParticle: s_p <= this x nominal_width (0: off; else > 1)
  double nominal_width = 0.0;                        // the run's nominal width s0 the bound refers to (> 0 if bounded)
  void validate() const;
};

class ImplicitStepper {
 public:
  ImplicitStepper(int dim, ImplicitOptions options, Barrier barrier = {}, Periodicity periodicity = {});
  // One implicit step of length dt from the state in `particles` (throws
  // InvalidArgument for particles of another dimension). On failure
  // (after max_halvings retries) the particles are left exactly as they were.
  // On success they may also be reordered (sort_particles); ids are kept.
  // max_error: a step whose error_estimate exceeds it is not taken
  // (accepted == false, error_rejected == true; the history is kept), so an
  // adaptive caller (TimeStepController) can retry with a smaller dt.
  StepSummary step(ParticleSet& particles, double dt,
                   double max_error = std::numeric_limits<double>::infinity());
  // The stepper remembers each particle's last two diffusive displacements
  // (by id) for the predictor, BDF2 and the error estimate. Call this when the
  // particles were changed in a way that is not a time step (a new set, a restart).
  void reset_history();
  std::size_t history_size() const { return history_.size(); }
  // The history as data (for checkpoints), entries sorted by id; importing
  // it into a stepper built with the same options continues bit for bit.
  using HistoryEntry = otfp::HistoryEntry;
  using HistoryState = otfp::HistoryState;
  HistoryState history_state() const;
  void restore_history(const HistoryState& state);  // throws InvalidArgument for a bad entry
  // Puts back the history (and the last two step sizes) of before the last
  // accepted step(), in O(1): an accepted step moves the old history aside
  // instead of dropping it. For a caller whose own step failed after the
  // diffusive one was accepted (Simulation: the projection or the ledger).
  // Throws std::logic_error unless the history's last change was an accepted
  // step() (not reset_history(), restore_history() or an earlier undo).
  void undo_last_history_update();
  // Where the predictor (options().predictor, or Extrapolate if None) would
  // start a step of length dt, in the order of `particles`: e.g.
  // x + (dt / dt_{k-1}) (x^k - x^{k-1}), pulled back towards x where that would
  // leave the barrier domain or cross a mirrored wall; x itself for particles
  // with no history.
  std::vector<Vec3> predict(const ParticleSet& particles, double dt) const;
  double previous_dt() const { return history_.dt1(); }
  // The objective an Euler step of length dt from `particles` minimises, in
  // the minimiser's scaled unknowns (positions, then widths with
  // PerParticle), and the start z^k: for gradient checks. Uses (and moves the
  // reference of) this stepper's functional.
  struct StepProblem {
    std::unique_ptr<Objective> objective;
    std::vector<double> start;
  };
  StepProblem step_problem(const ParticleSet& particles, double dt);
  void set_external_potential(ExternalPotential u) { external_ = std::move(u); }
  const ImplicitOptions& options() const { return options_; }
  Functional& functional() { return functional_; }
  Barrier& barrier() { return functional_.barrier().barrier(); }

 private:
  // The local error estimates of a solved step from x, s to x_new, s_new
  // (Milne's device), into summary's error fields; ids: the particles'.
  void estimate_local_error(const std::vector<ParticleId>& ids, const std::vector<Vec3>& x,
                            const std::vector<double>& s, const std::vector<Vec3>& x_new,
                            const std::vector<double>& s_new, const std::vector<double>& m,
                            const std::vector<DisplacementHistory>& hist, double dt, double dt1, double dt2,
                            StepSummary& summary) const;
  int dim_;
  ImplicitOptions options_;
  Functional functional_;
  ExternalPotential external_;
  StepHistory history_;
};

}  // namespace otfp
