// Ceres GradientProblemSolver adapter. Ceres' own stopping tests are switched
// off (tolerances 0 can only fire on an exactly zero gradient or step); the
// common rules (stopping measure, relative change of f, evaluation cap) are
// applied in an IterationCallback at every accepted iterate.
#include <ceres/first_order_function.h>
#include <ceres/gradient_problem.h>
#include <ceres/gradient_problem_solver.h>
#include <ceres/iteration_callback.h>
#include <glog/logging.h>

#include <cmath>
#include <cstdlib>
#include <cstring>
#include <mutex>
#include <string>
#include <vector>

#include "minimizer_backends.hpp"

namespace otfp::detail {

namespace {

using Status = TrackedObjective::Status;

class CeresFunction final : public ceres::FirstOrderFunction {
 public:
  explicit CeresFunction(TrackedObjective& objective) : objective_(objective) {}
  bool Evaluate(const double* parameters, double* cost, double* gradient) const override {
    // false = "invalid point": Ceres' line search backs off. That is what we
    // want for a non-finite value, and harmless once the cap is reached (the
    // callback or the final mapping reports MaxEvaluations).
    return objective_.evaluate(parameters, cost, gradient) == Status::Ok;
  }
  int NumParameters() const override { return static_cast<int>(objective_.size()); }

 private:
  TrackedObjective& objective_;
};

// Sees each accepted iterate. With update_state_every_iteration Ceres puts its
// state-updating callback first, so `parameters` already holds the iterate.
class CeresMonitor final : public ceres::IterationCallback {
 public:
  CeresMonitor(TrackedObjective& objective, const double* parameters, const StartPoint& start,
               const MinimizerOptions& options)
      : objective_(objective),
        parameters_(parameters),
        options_(options),
        x_(parameters, parameters + objective.size()),
        g_(start.gradient),
        value_(start.value),
        measure_(start.measure) {}

  ceres::CallbackReturnType operator()(const ceres::IterationSummary& s) override {
    if (s.iteration == 0 || !s.step_is_successful) return ceres::SOLVER_CONTINUE;
    last_iteration_ = s.iteration;
    const double previous = value_;
    x_.assign(parameters_, parameters_ + objective_.size());
    // Normally a cache hit: Ceres evaluated the gradient at the accepted point last.
    const Status st = objective_.evaluate_uncapped(x_.data(), &value_, g_.data());
    if (st != Status::Ok) {
      stop_ = st == Status::Error ? TerminationReason::Failure : TerminationReason::NonFinite;
      valid_ = false;
      return ceres::SOLVER_ABORT;
    }
    measure_ = objective_.measure(x_.data(), g_.data());
    if (objective_.failed()) {
      stop_ = TerminationReason::Failure;
      return ceres::SOLVER_ABORT;
    }
    if (measure_ <= options_.gradient_tolerance) {
      stop_ = TerminationReason::Converged;
      return ceres::SOLVER_TERMINATE_SUCCESSFULLY;
    }
    if (options_.function_tolerance > 0.0 &&
        std::abs(previous - value_) <= options_.function_tolerance * std::abs(previous)) {
      stop_ = TerminationReason::FunctionTolerance;
      return ceres::SOLVER_TERMINATE_SUCCESSFULLY;
    }
    // Stop now rather than let the next line search be refused point by point.
    if (objective_.cap_reached()) {
      stop_ = TerminationReason::MaxEvaluations;
      return ceres::SOLVER_ABORT;
    }
    return ceres::SOLVER_CONTINUE;
  }

  TerminationReason stop_reason() const { return stop_; }
  int last_iteration() const { return last_iteration_; }
  // The last iterate this callback checked (the start before the first).
  bool matches(const double* z) const {
    return valid_ && std::memcmp(z, x_.data(), x_.size() * sizeof(double)) == 0;
  }
  double value() const { return value_; }
  double measure() const { return measure_; }

 private:
  TrackedObjective& objective_;
  const double* parameters_;
  const MinimizerOptions& options_;
  std::vector<double> x_, g_;
  double value_, measure_;
  bool valid_ = true;
  int last_iteration_ = 0;
  TerminationReason stop_ = TerminationReason::Failure;
};

// Ceres logs through glog, and glog writes to stderr until the program calls
// google::InitGoogleLogging (e.g. "Restarting non-linear conjugate gradients"
// at WARNING level even with logging_type = SILENT). A library must not print:
// unless the host program set glog up itself or chose a level through the
// GLOG_minloglevel environment variable, only FATAL messages get through.
void quiet_glog_once() {
  static std::once_flag once;
  std::call_once(once, [] {
    if (google::IsGoogleLoggingInitialized() || std::getenv("GLOG_minloglevel") != nullptr) return;
    if (FLAGS_minloglevel < google::GLOG_FATAL) FLAGS_minloglevel = google::GLOG_FATAL;
  });
}

ceres::LineSearchDirectionType direction(Algorithm a) {
  switch (a) {
    case Algorithm::Bfgs: return ceres::BFGS;
    case Algorithm::NonlinearCg: return ceres::NONLINEAR_CONJUGATE_GRADIENT;
    default: return ceres::LBFGS;
  }
}

}  // namespace

BackendResult run_ceres(TrackedObjective& objective, std::vector<double>& z, const StartPoint& start,
                        const MinimizerOptions& options) {
  quiet_glog_once();
  ceres::GradientProblemSolver::Options co;
  co.line_search_direction_type = direction(options.algorithm);
  co.line_search_type = ceres::WOLFE;  // required by (L-)BFGS, best for CG
  // Polak-Ribiere: 1.1-3.5x fewer evaluations than Ceres' default Fletcher-Reeves
  // on the quadratic and Rosenbrock test problems here (n = 20, 200).
  co.nonlinear_conjugate_gradient_type = ceres::POLAK_RIBIERE;
  co.max_lbfgs_rank = options.lbfgs_memory;
  co.use_approximate_eigenvalue_bfgs_scaling = options.approximate_eigenvalue_scaling;
  co.max_num_iterations = options.max_iterations;
  co.gradient_tolerance = 0.0;
  co.function_tolerance = 0.0;
  co.parameter_tolerance = 0.0;
  co.logging_type = ceres::SILENT;
  co.minimizer_progress_to_stdout = false;
  co.update_state_every_iteration = true;
  CeresMonitor monitor(objective, z.data(), start, options);
  co.callbacks.push_back(&monitor);

  BackendResult r;
  std::string invalid;
  if (!co.IsValid(&invalid)) {
    r.reason = TerminationReason::Failure;
    r.message = "ceres options rejected: " + invalid;
    r.final_value = start.value;
    r.final_measure = start.measure;
    return r;
  }

  ceres::GradientProblem problem(new CeresFunction(objective));  // takes ownership
  ceres::GradientProblemSolver::Summary cs;
  ceres::Solve(co, problem, z.data(), &cs);
  r.message = cs.message;

  // z is Ceres' last accepted iterate; the line search never accepts an increase.
  if (monitor.matches(z.data())) {
    r.final_value = monitor.value();
    r.final_measure = monitor.measure();
    r.iterations = monitor.last_iteration();
  } else {
    // Ceres stopped on its own test right after accepting a step the callback never saw.
    r.iterations = monitor.last_iteration() + 1;
    std::vector<double> g(z.size());
    if (objective.evaluate_uncapped(z.data(), &r.final_value, g.data()) == Status::Ok) {
      r.final_measure = objective.measure(z.data(), g.data());
    } else {
      r.final_value = std::nan("");  // minimize() falls back to the start point
      r.final_measure = std::nan("");
    }
  }

  switch (cs.termination_type) {
    case ceres::USER_SUCCESS:
    case ceres::USER_FAILURE:
      r.reason = monitor.stop_reason();
      break;
    case ceres::NO_CONVERGENCE:
      r.reason = TerminationReason::MaxIterations;
      break;
    case ceres::CONVERGENCE:  // only an exactly zero gradient or step: stalled
    case ceres::FAILURE:      // line search or direction failure
    default:
      if (objective.refused())
        r.reason = TerminationReason::MaxEvaluations;
      else if (r.iterations == 0 && objective.nonfinite_evaluations() > 0)
        r.reason = TerminationReason::NonFinite;  // nothing finite beyond the start
      else
        r.reason = TerminationReason::LineSearchFailure;
      break;
  }
  return r;
}

}  // namespace otfp::detail
