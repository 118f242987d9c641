#include "otfp/minimizer.hpp"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <string>

#include "minimizer_backends.hpp"
#include "otfp/types.hpp"

namespace otfp {

namespace {

using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

// The optional backends' runners (TAO), set by their component. Atomic: a
// program may register while another thread validates options.
std::atomic<detail::BackendRunner> tao_runner{nullptr};

}  // namespace

bool algorithm_offered(Backend b, Algorithm a) {
  switch (a) {
    case Algorithm::Lbfgs: return true;
    case Algorithm::Bfgs:
    case Algorithm::NonlinearCg: return b == Backend::Ceres;
    case Algorithm::TruncatedNewton:
    case Algorithm::Var2:
    case Algorithm::Mma: return b == Backend::Nlopt;
  }
  return false;
}

std::string offered_algorithms(Backend b) {
  switch (b) {
    case Backend::Ceres: return "lbfgs, bfgs, nonlinear_cg";
    case Backend::Nlopt: return "lbfgs, tnewton, var2, mma";
    case Backend::Tao: return "lbfgs";
  }
  return "";
}

bool backend_available(Backend b) {
  return b == Backend::Ceres || b == Backend::Nlopt || (b == Backend::Tao && tao_runner.load() != nullptr);
}

namespace detail {
void set_backend_runner(Backend backend, BackendRunner runner) {
  require(backend == Backend::Tao, "backend", to_string(backend), "only optional backends (tao) are registered");
  tao_runner.store(runner);
}
}  // namespace detail

// ---------------------------------------------------------------- Objective

double Objective::stopping_measure(const double* /*z*/, const double* gradient) const {
  if (gradient == nullptr) return std::numeric_limits<double>::infinity();
  double worst = 0.0;
  const std::size_t n = num_variables();
  for (std::size_t i = 0; i < n; ++i) {
    const double a = std::abs(gradient[i]);
    // A NaN component must not vanish in std::max: report it.
    if (std::isnan(a)) return a;
    worst = std::max(worst, a);
  }
  return worst;
}

// ---------------------------------------------------------------- strings

// ---------------------------------------------------------------- options

void MinimizerOptions::validate() const {
  require(std::isfinite(gradient_tolerance) && gradient_tolerance > 0.0, "solver.gradient_tolerance",
          gradient_tolerance, "must be finite and > 0");
  require(relative_gradient_tolerance >= 0.0 && relative_gradient_tolerance <= 1.0,
          "solver.relative_gradient_tolerance", relative_gradient_tolerance, "must be in [0, 1] (0 disables it)");
  require(std::isfinite(start_tolerance) && start_tolerance >= 0.0, "solver.start_tolerance", start_tolerance,
          "must be finite and >= 0");
  require(std::isfinite(gradient_tolerance_floor) && gradient_tolerance_floor >= 0.0, "solver.gradient_tolerance_floor",
          gradient_tolerance_floor, "must be finite and >= 0");
  require(std::isfinite(function_tolerance) && function_tolerance >= 0.0, "solver.function_tolerance",
          function_tolerance, "must be finite and >= 0 (0 disables it)");
  require(max_iterations >= 1, "solver.max_iterations", max_iterations, "must be >= 1");
  require(max_evaluations >= 1, "solver.max_evaluations", max_evaluations, "must be >= 1");
  require(lbfgs_memory >= 1, "solver.lbfgs_memory", lbfgs_memory, "must be >= 1");
  require(backend == Backend::Ceres || backend == Backend::Nlopt || backend == Backend::Tao, "solver.backend",
          static_cast<double>(static_cast<int>(backend)), "unknown backend");
  require(backend_available(backend), "solver.backend", to_string(backend),
          "not available in this program (TAO needs a build with OTFP_WITH_MPI=ON, PETSc found, and "
          "otfp::register_tao_backend() called)");
  require(algorithm_offered(backend, algorithm), "solver.algorithm", to_string(algorithm),
          "not offered by backend '" + to_string(backend) + "' (allowed: " + offered_algorithms(backend) + ")");
}

// ---------------------------------------------------------------- TrackedObjective

namespace detail {

TrackedObjective::TrackedObjective(Objective& objective, int max_evaluations)
    : objective_(objective), n_(objective.num_variables()), max_evaluations_(max_evaluations) {}

bool TrackedObjective::cached(const double* z, double* value, double* gradient) const {
  // Bitwise equality: the backends re-request exactly the same point.
  bool hit = cache_valid_ && !(gradient != nullptr && !cache_has_gradient_) &&
             !(n_ > 0 && std::memcmp(z, cache_z_.data(), n_ * sizeof(double)) != 0);
  if (all_) hit = all_(hit);
  if (!hit) return false;
  *value = cache_value_;
  if (gradient != nullptr) std::copy(cache_g_.begin(), cache_g_.end(), gradient);
  return true;
}

TrackedObjective::Status TrackedObjective::call(const double* z, double* value, double* gradient) {
  if (error_) return Status::Error;
  ++evaluations_;
  const auto t0 = Clock::now();
  bool ok = false;
  try {
    ok = objective_.evaluate(z, value, gradient);
  } catch (...) {
    error_ = std::current_exception();
  }
  objective_seconds_ += seconds_since(t0);
  if (error_) return Status::Error;
  // Trust but check: a "finite" report with a NaN value would poison both backends.
  if (!ok || !std::isfinite(*value)) {
    ++nonfinite_;
    return Status::NonFinite;
  }
  cache_valid_ = true;
  cache_has_gradient_ = gradient != nullptr;
  cache_value_ = *value;
  cache_z_.assign(z, z + n_);
  if (gradient != nullptr) cache_g_.assign(gradient, gradient + n_);
  return Status::Ok;
}

TrackedObjective::Status TrackedObjective::evaluate(const double* z, double* value, double* gradient) {
  if (error_) return Status::Error;
  if (cached(z, value, gradient)) return Status::Ok;
  if (cap_reached()) {
    refused_ = true;
    return Status::Capped;
  }
  return call(z, value, gradient);
}

TrackedObjective::Status TrackedObjective::evaluate_uncapped(const double* z, double* value, double* gradient) {
  if (error_) return Status::Error;
  if (cached(z, value, gradient)) return Status::Ok;
  return call(z, value, gradient);
}

double TrackedObjective::measure(const double* z, const double* gradient) {
  if (error_) return std::numeric_limits<double>::quiet_NaN();
  try {
    return objective_.stopping_measure(z, gradient);
  } catch (...) {
    error_ = std::current_exception();
    return std::numeric_limits<double>::quiet_NaN();
  }
}

}  // namespace detail

// ---------------------------------------------------------------- minimize

MinimizerSummary minimize(Objective& objective, std::vector<double>& z, const MinimizerOptions& options) {
  options.validate();
  detail::BackendRunner runner = nullptr;
  switch (options.backend) {
    case Backend::Ceres: runner = detail::run_ceres; break;
    case Backend::Nlopt: runner = detail::run_nlopt; break;
    case Backend::Tao: runner = tao_runner.load(); break;
  }
  require(runner != nullptr, "solver.backend", to_string(options.backend), "not available in this program");
  return detail::minimize_with(objective, z, options, runner);
}

namespace detail {

MinimizerSummary minimize_with(Objective& objective, std::vector<double>& z, const MinimizerOptions& options_in,
                               BackendRunner runner, std::function<bool(bool)> collective) {
  MinimizerOptions options = options_in;  // the relative rule sets gradient_tolerance after the start point
  const std::size_t n = objective.num_variables();
  const bool shared = static_cast<bool>(collective);
  require(z.size() == n, "z.size()", static_cast<double>(z.size()),
          "must equal objective.num_variables() = " + std::to_string(n));

  const auto t0 = Clock::now();
  detail::TrackedObjective tracked(objective, options.max_evaluations);
  if (shared) tracked.set_collective(std::move(collective));
  MinimizerSummary summary;
  auto finish = [&]() {
    summary.success = summary.reason == TerminationReason::Converged ||
                      summary.reason == TerminationReason::FunctionTolerance;
    summary.evaluations = tracked.evaluations();
    summary.total_seconds = seconds_since(t0);
    summary.solver_seconds = std::max(0.0, summary.total_seconds - tracked.objective_seconds());
    return summary;
  };

  detail::StartPoint start;
  // One element at least: a null gradient pointer means "value only", and a
  // process with no unknowns of a shared solve still wants the gradient
  // (its collective parts).
  start.gradient.assign(std::max<std::size_t>(n, 1), 0.0);
  const auto status = tracked.evaluate(z.data(), &start.value, start.gradient.data());
  tracked.rethrow_if_failed();
  if (status != detail::TrackedObjective::Status::Ok) {
    const double nan = std::numeric_limits<double>::quiet_NaN();
    summary.reason = TerminationReason::NonFinite;
    summary.initial_value = summary.final_value = summary.final_stopping_measure = nan;
    summary.message = "objective is not finite at the start point";
    return finish();
  }
  start.measure = tracked.measure(z.data(), start.gradient.data());
  tracked.rethrow_if_failed();
  summary.initial_value = start.value;
  if (options.relative_gradient_tolerance > 0.0 && start.measure > 0.0)
    options.gradient_tolerance =
        std::max(std::min(options.gradient_tolerance, options.relative_gradient_tolerance * start.measure),
                 options.gradient_tolerance_floor);
  summary.gradient_tolerance = options.gradient_tolerance;

  // (A rank with no unknowns still takes part in a collective solve.)
  if (start.measure <= std::max(options.gradient_tolerance, options.start_tolerance) || (n == 0 && !shared)) {
    summary.reason = TerminationReason::Converged;
    summary.final_value = start.value;
    summary.final_stopping_measure = start.measure;
    summary.message = "stopping measure already within tolerance at the start point";
    return finish();
  }

  const std::vector<double> z_start = z;
  detail::BackendResult r;
  try {
    r = runner(tracked, z, start, options);
  } catch (...) {
    z = z_start;  // a half-finished run leaves no trace
    throw;
  }
  if (tracked.failed()) {
    z = z_start;
    tracked.rethrow_if_failed();
  }

  // Safety net: never hand back a point worse than (or not as finite as) the start.
  if (!(std::isfinite(r.final_value) && r.final_value <= start.value)) {
    z = z_start;
    r.final_value = start.value;
    r.final_measure = start.measure;
    r.iterations = 0;
  }
  summary.reason = r.reason;
  // The common rule decides whatever the backend said: a returned point that
  // meets the tolerance is converged, and one that does not is not.
  if (r.final_measure <= options.gradient_tolerance) {
    summary.reason = TerminationReason::Converged;
  } else if (summary.reason == TerminationReason::Converged) {
    summary.reason = TerminationReason::Failure;
    char buf[128];
    std::snprintf(buf, sizeof(buf), " (the backend stopped as converged where the stopping measure is %.3g > %.3g)",
                  r.final_measure, options.gradient_tolerance);
    r.message += buf;
  }
  summary.iterations = r.iterations;
  summary.final_value = r.final_value;
  summary.final_stopping_measure = r.final_measure;
  summary.message = r.message;
  return finish();
}

}  // namespace detail

}  // namespace otfp
