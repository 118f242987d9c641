#include "otfp/time_step_control.hpp"

#include <algorithm>
#include <cmath>

#include "otfp/types.hpp"

namespace otfp {

void TimeStepControlOptions::validate() const {
  require(std::isfinite(tolerance) && tolerance > 0.0, "time_tolerance", tolerance, "must be finite and > 0");
  require(std::isfinite(safety) && safety > 0.0 && safety <= 1.0, "safety", safety, "must be in (0, 1]");
  require(std::isfinite(max_growth) && max_growth >= 1.0, "max_growth", max_growth, "must be finite and >= 1");
  require(std::isfinite(max_shrink) && max_shrink > 0.0 && max_shrink < 1.0, "max_shrink", max_shrink,
          "must be in (0, 1)");
  require(std::isfinite(dt_min) && dt_min >= 0.0, "dt_min", dt_min, "must be finite and >= 0");
  require(dt_max > 0.0 && dt_max >= dt_min, "dt_max", dt_max, "must be > 0 and >= dt_min");
}

TimeStepController::TimeStepController(TimeStepControlOptions options) : options_((options.validate(), options)) {}

double TimeStepController::error_limit(double dt) const {
  return dt <= options_.dt_min * (1.0 + 1e-12) ? std::numeric_limits<double>::infinity() : options_.tolerance;
}

TimeStepDecision TimeStepController::decide(double dt, double error_estimate, int order) const {
  require(std::isfinite(dt) && dt > 0.0, "dt", dt, "must be finite and > 0");
  require(order >= 1 || std::isnan(error_estimate), "order", order, "must be >= 1 with an error estimate");
  const auto& o = options_;
  auto clamp = [&](double h) { return std::min(std::max(h, o.dt_min), o.dt_max); };
  TimeStepDecision d;
  if (std::isnan(error_estimate)) {
    d.dt_next = clamp(dt);
    return d;
  }
  // err ~ C dt^(p+1): the step that would give err = tolerance, times the safety factor.
  const double factor = error_estimate > 0.0
                            ? o.safety * std::pow(o.tolerance / error_estimate, 1.0 / (order + 1.0))
                            : o.max_growth;
  d.accept = error_estimate <= o.tolerance;
  if (!d.accept && dt <= o.dt_min * (1.0 + 1e-12)) {
    d.accept = true;
    d.forced = true;
  }
  const double lo = o.max_shrink, hi = d.accept ? o.max_growth : 1.0;
  d.dt_next = clamp(dt * std::min(std::max(factor, lo), hi));
  return d;
}

}  // namespace otfp
