// NLopt adapter. NLopt has no gradient-norm stop, so the common stopping rule
// is applied inside the objective callback: each new best point is checked and
// NLopt is stopped with force_stop(). The best point is tracked here rather
// than taken from NLopt so that the same rule holds for every algorithm.
//
// A non-finite point is answered with +HUGE_VAL and a zero gradient, not with
// an immediate stop: measured here, the Luksan codes (LBFGS, TNEWTON, VAR2)
// then back off like Ceres' line search does and keep making progress, and
// stop by themselves after a few dozen failures at most; MMA can keep probing
// such points for ever, hence a cap on non-finite evaluations without progress.
#include <nlopt.hpp>

#include <algorithm>
#include <cmath>
#include <new>
#include <stdexcept>
#include <string>
#include <vector>

#include "minimizer_backends.hpp"

namespace otfp::detail {

namespace {

using Status = TrackedObjective::Status;

nlopt::algorithm nlopt_algorithm(Algorithm a) {
  switch (a) {
    case Algorithm::TruncatedNewton: return nlopt::LD_TNEWTON_PRECOND_RESTART;
    case Algorithm::Var2: return nlopt::LD_VAR2;
    case Algorithm::Mma: return nlopt::LD_MMA;
    default: return nlopt::LD_LBFGS;
  }
}

enum class Stop { None, Converged, MaxIterations, MaxEvaluations, NonFinite, Error };

// Non-finite evaluations without a new best point in between after which the
// run is hopeless (MMA may otherwise alternate between them and the best point).
constexpr int kMaxNonfiniteRun = 50;

struct NloptRun {
  TrackedObjective* objective = nullptr;
  const MinimizerOptions* options = nullptr;
  nlopt::opt* opt = nullptr;
  Stop stop = Stop::None;
  // Best (lowest finite value) point so far; starts as the start point.
  std::vector<double> best_x, best_g;
  bool best_has_gradient = true;
  double best_value = 0.0;
  double best_measure = 0.0;
  // NLopt reports no iterations: we count new best points instead.
  int improvements = 0;
  int nonfinite_run = 0;

  void halt(Stop why) {
    if (stop == Stop::None) stop = why;
    opt->force_stop();
  }
};

// Raw nlopt::func: no copies of x and g (the std::vector overload copies both).
double nlopt_objective(unsigned n, const double* x, double* grad, void* data) {
  auto& run = *static_cast<NloptRun*>(data);
  double value = HUGE_VAL;
  if (run.stop != Stop::None) {
    // Already stopping; NLopt may still finish its current step.
    if (grad != nullptr) std::fill(grad, grad + n, 0.0);
    return HUGE_VAL;
  }
  const Status st = run.objective->evaluate(x, &value, grad);
  if (st != Status::Ok) {
    // HUGE_VAL and a zero gradient: no NaN enters NLopt's arithmetic.
    if (grad != nullptr) std::fill(grad, grad + n, 0.0);
    if (st == Status::Capped)
      run.halt(Stop::MaxEvaluations);
    else if (st == Status::Error)
      run.halt(Stop::Error);
    else if (++run.nonfinite_run > kMaxNonfiniteRun)
      run.halt(Stop::NonFinite);
    return HUGE_VAL;
  }
  if (value < run.best_value) {
    run.best_value = value;
    run.best_x.assign(x, x + n);
    run.best_has_gradient = grad != nullptr;
    if (grad != nullptr) {
      run.best_g.assign(grad, grad + n);
      run.best_measure = run.objective->measure(x, grad);
      if (run.objective->failed()) {
        run.halt(Stop::Error);
        return value;
      }
    }
    ++run.improvements;
    run.nonfinite_run = 0;
    if (grad != nullptr && run.best_measure <= run.options->gradient_tolerance)
      run.halt(Stop::Converged);
    else if (run.improvements >= run.options->max_iterations)
      run.halt(Stop::MaxIterations);
  }
  return value;
}

}  // namespace

BackendResult run_nlopt(TrackedObjective& objective, std::vector<double>& z, const StartPoint& start,
                        const MinimizerOptions& options) {
  const auto n = static_cast<unsigned>(objective.size());
  nlopt::opt opt(nlopt_algorithm(options.algorithm), n);
  NloptRun run;
  run.objective = &objective;
  run.options = &options;
  run.opt = &opt;
  run.best_x = z;
  run.best_g = start.gradient;
  run.best_value = start.value;
  run.best_measure = start.measure;

  opt.set_min_objective(nlopt_objective, &run);
  // NLopt's default memory is max(1310720/n, 10): 43 at n = 30k, about 3.5x slower.
  opt.set_vector_storage(static_cast<unsigned>(options.lbfgs_memory));
  // A backstop only, the tracker enforces the cap on objective calls. Both
  // counts agree while the only cached request is NLopt's first (the start).
  opt.set_maxeval(options.max_evaluations);
  if (options.function_tolerance > 0.0) opt.set_ftol_rel(options.function_tolerance);

  BackendResult r;
  std::vector<double> x = z;
  double f = 0.0;
  nlopt::result result = nlopt::FAILURE;
  try {
    result = opt.optimize(x, f);
    r.message = "nlopt result " + std::to_string(static_cast<int>(result));
  } catch (const nlopt::forced_stop&) {
    r.message = "nlopt forced stop";
  } catch (const nlopt::roundoff_limited&) {
    result = nlopt::ROUNDOFF_LIMITED;
    r.message = "nlopt roundoff limited";
  } catch (const std::bad_alloc&) {
    throw;
  } catch (const std::exception& e) {
    // NLOPT_FAILURE / INVALID_ARGS: x is not to be trusted, the best point still is.
    r.message = std::string("nlopt failure: ") + e.what();
    result = nlopt::FAILURE;
  }

  z = run.best_x;
  r.final_value = run.best_value;
  r.iterations = run.improvements;
  if (run.best_has_gradient) {
    r.final_measure = run.best_measure;
  } else {
    // The algorithm asked for the value only at its best point: get the gradient now.
    std::vector<double> g(z.size());
    if (objective.evaluate_uncapped(z.data(), &r.final_value, g.data()) == Status::Ok)
      r.final_measure = objective.measure(z.data(), g.data());
    else
      r.final_value = r.final_measure = std::nan("");
  }

  switch (run.stop) {
    case Stop::Converged: r.reason = TerminationReason::Converged; break;
    case Stop::MaxIterations: r.reason = TerminationReason::MaxIterations; break;
    case Stop::MaxEvaluations: r.reason = TerminationReason::MaxEvaluations; break;
    case Stop::Error: r.reason = TerminationReason::Failure; break;
    case Stop::NonFinite:
    case Stop::None:
      if (run.stop == Stop::NonFinite || result <= 0) {
        // NLopt gave up. Non-finite throughout (nothing accepted beyond the
        // start), stuck at the edge of the finite region, or some other failure.
        if (objective.nonfinite_evaluations() > 0) {
          r.reason = run.improvements == 0 ? TerminationReason::NonFinite : TerminationReason::LineSearchFailure;
          r.message += " (objective not finite at " + std::to_string(objective.nonfinite_evaluations()) +
                       " trial points)";
        } else {
          r.reason = result == nlopt::ROUNDOFF_LIMITED ? TerminationReason::LineSearchFailure
                                                        : TerminationReason::Failure;
        }
      } else if (result == nlopt::MAXEVAL_REACHED) {
        r.reason = TerminationReason::MaxEvaluations;
      } else if (result == nlopt::FTOL_REACHED) {
        r.reason = TerminationReason::FunctionTolerance;
      } else {
        // SUCCESS/XTOL_REACHED: one of NLopt's internal tests (e.g. the Luksan
        // codes' tiny step) stopped it: no further progress. minimize() still
        // reports Converged if the stopping measure is met.
        r.reason = TerminationReason::LineSearchFailure;
      }
      break;
  }
  return r;
}

}  // namespace otfp::detail
