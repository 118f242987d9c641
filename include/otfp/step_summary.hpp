#pragma once
// StepSummary: what every diffusive step reports, for the implicit
// variational step (implicit_stepper.hpp) and the explicit baselines
// (explicit_stepper.hpp) alike. The options of each stepper, with their
// enums (WidthMode, TimeScheme, Predictor; ExplicitScheme), live with the
// stepper they configure; TerminationReason is the minimiser's
// (minimizer.hpp), FunctionalParts and WidthMetric the functional's (functional.hpp).
#include <cstdint>
#include <limits>
#include <string>

#include "otfp/functional.hpp"
#include "otfp/minimizer.hpp"

namespace otfp {

// What every step reports.
struct StepSummary {
  bool accepted = false;                    // false: the state was left untouched
  TerminationReason reason = TerminationReason::Converged;  // of the last solve
  std::string message;                      // why a step was rejected or retried
  double dt = 0.0;                          // the step requested
  int substeps = 1;                         // 2^halvings substeps of dt / 2^halvings were taken
  int halvings = 0;                         // how often a failed solve was retried with dt/2
  int rejected_solves = 0;                  // failed solves (each is retried or reported)
  double f_before = 0.0, f_after = 0.0;     // F at the warm start and at the result (last substep)
  FunctionalParts parts_before, parts_after;
  int iterations = 0;                       // summed over substeps
  int evaluations = 0;                      // value+gradient evaluations, summed
  double residual_displacement = 0.0;       // final stopping measure: largest dt/m |dF/dx| left (a length)
  int list_builds = 0;                      // neighbour-list builds during the step
  double wall_seconds = 0.0;
  double solver_seconds = 0.0;              // time inside the optimiser itself
  double gradient_tolerance = 0.0;          // stopping threshold used (implicit: after the relative rule)
  double list_seconds = 0.0;                // time in neighbour-list builds
  std::uint64_t pair_evaluations = 0;
  long inserted = 0, removed = 0;           // particles, filled by source/projection steps
  // Local time-error estimate (implicit stepper): mass-weighted RMS over the
  // particles with enough history of |e_p| / s_p, e_p the Milne estimate of
  // the step's local error (order 1: Euler, 2: BDF2) averaged over the
  // particle's neighbourhood (ImplicitOptions::error_smoothing); NaN when no particle has the history it
  // needs (first steps, docs/stepper.md). Largest over substeps.
  // error_estimate is the one ImplicitOptions::error_measure selects: the
  // density's (relative) or the displacement's (in widths); both are reported.
  double error_estimate = std::numeric_limits<double>::quiet_NaN();
  double density_error_estimate = std::numeric_limits<double>::quiet_NaN();       // smoothed density, relative to its mean
  double displacement_error_estimate = std::numeric_limits<double>::quiet_NaN();  // smoothed displacement, in widths
  double particle_error_estimate = std::numeric_limits<double>::quiet_NaN();      // displacement without the average
  int error_order = 0;                      // order of the scheme the estimate belongs to
  bool error_rejected = false;              // rejected because error_estimate > the caller's limit
  long bdf2_particles = 0;                  // particles stepped with the BDF2 form (last substep)
  long predicted_particles = 0;             // particles started from the extrapolation (last substep)
  double f_start = 0.0;                     // F at the solver's start point (== f_before without a predictor)
};

}  // namespace otfp
