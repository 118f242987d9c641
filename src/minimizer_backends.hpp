#pragma once
// Private glue between minimize() and the backend adapters. No Ceres, NLopt
// or PETSc types here either: each adapter includes its own library.
#include <cstddef>
#include <exception>
#include <functional>
#include <string>
#include <vector>

#include "otfp/minimizer.hpp"

namespace otfp::detail {

// The objective as both backends see it. It counts and times every call of
// Objective::evaluate, enforces the evaluation cap, keeps a copy of the last
// point evaluated (so a backend re-requesting that point, e.g. the start, costs
// no second call), and turns exceptions from the objective into a stored
// failure so that they never unwind through the C/C++ solver libraries.
class TrackedObjective {
 public:
  enum class Status { Ok, NonFinite, Capped, Error };

  TrackedObjective(Objective& objective, int max_evaluations);

  // A solve shared by several processes (minimize_with, collective): whether
  // a request is answered from the cache must be decided by all of them, or
  // one would skip the collective evaluation the others enter. `all(v)` is
  // true iff v is true on every process.
  void set_collective(std::function<bool(bool)> all) { all_ = std::move(all); }

  std::size_t size() const { return n_; }

  // Value (and gradient when non-null) at z, from the cache or one counted
  // call. Capped: the cap is reached and the point is not cached (no call made).
  Status evaluate(const double* z, double* value, double* gradient);

  // Like evaluate() with a gradient, but ignores the cap: for the few points
  // the adapters must know exactly (the returned one), if not cached.
  Status evaluate_uncapped(const double* z, double* value, double* gradient);

  // Objective::stopping_measure; an exception becomes a stored failure and NaN.
  double measure(const double* z, const double* gradient);

  int evaluations() const { return evaluations_; }
  bool cap_reached() const { return evaluations_ >= max_evaluations_; }
  bool refused() const { return refused_; }          // some request was refused by the cap
  int nonfinite_evaluations() const { return nonfinite_; }
  double objective_seconds() const { return objective_seconds_; }
  bool failed() const { return static_cast<bool>(error_); }
  void rethrow_if_failed() const {
    if (error_) std::rethrow_exception(error_);
  }

 private:
  Status call(const double* z, double* value, double* gradient);
  bool cached(const double* z, double* value, double* gradient) const;

  Objective& objective_;
  std::size_t n_;
  int max_evaluations_;
  int evaluations_ = 0;
  int nonfinite_ = 0;
  bool refused_ = false;
  double objective_seconds_ = 0.0;
  std::exception_ptr error_;
  std::function<bool(bool)> all_;
  // Last point with a finite evaluation.
  bool cache_valid_ = false;
  bool cache_has_gradient_ = false;
  double cache_value_ = 0.0;
  std::vector<double> cache_z_, cache_g_;
};

// The start point, already evaluated (finite) and not yet converged.
struct StartPoint {
  double value = 0.0;
  double measure = 0.0;
  std::vector<double> gradient;
};

// What an adapter reports; z then holds the returned point.
struct BackendResult {
  TerminationReason reason = TerminationReason::Failure;
  int iterations = 0;
  double final_value = 0.0;
  double final_measure = 0.0;
  std::string message;
};

using BackendRunner = BackendResult (*)(TrackedObjective&, std::vector<double>&, const StartPoint&,
                                        const MinimizerOptions&);

// The optional backends (TAO) register their runner here; nullptr unregisters.
void set_backend_runner(Backend backend, BackendRunner runner);

// minimize() with a given runner. collective (not null): the objective is
// one process's share of a problem solved together by several (its value and
// stopping measure are already the global ones), and collective(v) is true
// iff v is on every process: the cache is consulted only when all agree, and
// a process with no unknowns still runs the backend. minimize() validates
// the options before; this does not.
MinimizerSummary minimize_with(Objective& objective, std::vector<double>& z, const MinimizerOptions& options,
                               BackendRunner runner, std::function<bool(bool)> collective = {});

BackendResult run_ceres(TrackedObjective& objective, std::vector<double>& z, const StartPoint& start,
                        const MinimizerOptions& options);
BackendResult run_nlopt(TrackedObjective& objective, std::vector<double>& z, const StartPoint& start,
                        const MinimizerOptions& options);

}  // namespace otfp::detail
