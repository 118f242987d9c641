#pragma once
// Step-size control for the implicit stepper (docs/stepper.md): the error
// estimate of each step (StepSummary::error_estimate, the error committed in
// the step, in blob widths) against a tolerance, with the standard
// controller dt_new = dt * safety * (tolerance / error)^(1/(p+1)).
#include <limits>

namespace otfp {

struct TimeStepControlOptions {
  double tolerance = 1e-2;      // largest accepted error estimate per step (RMS over particles, in widths s)
  double safety = 0.9;          // factor below the step the estimate asks for
  double max_growth = 2.0;      // largest dt_new / dt
  double max_shrink = 0.2;      // smallest dt_new / dt
  double dt_min = 0.0;          // smallest step: a step at dt_min is accepted whatever its error (counted)
  double dt_max = std::numeric_limits<double>::infinity();  // largest step
  void validate() const;        // throws InvalidArgument naming the field
};

struct TimeStepDecision {
  bool accept = true;           // the step just taken may stand
  bool forced = false;          // accepted only because dt was already dt_min
  double dt_next = 0.0;         // the step to take next (or to retry with, if !accept)
};

class TimeStepController {
 public:
  explicit TimeStepController(TimeStepControlOptions options = {});
  // After a step of length dt with the given error estimate of a scheme of
  // order p (1: Euler, 2: BDF2). A NaN estimate (no history yet) accepts and
  // keeps dt (clamped to the bounds).
  TimeStepDecision decide(double dt, double error_estimate, int order) const;
  // The limit to pass to ImplicitStepper::step(..., max_error) for a step of
  // length dt: the tolerance, or infinity at dt_min (nothing smaller to try).
  double error_limit(double dt) const;
  const TimeStepControlOptions& options() const { return options_; }

 private:
  TimeStepControlOptions options_;
};

}  // namespace otfp
