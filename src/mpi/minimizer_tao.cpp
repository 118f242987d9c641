// TAO adapter (PETSc 3.18): TAOLMVM, PETSc's limited-memory BFGS with a
// More-Thuente line search, on a sequential Vec. The library's stopping rule
// replaces TAO's own tests: a convergence test of ours checks
// Objective::stopping_measure at every accepted iterate, as the other
// adapters do, so that the three backends stop at the same tolerance.
//
// The objective callback tracks the best finite point (as the NLopt adapter
// does): when a run is cut short (evaluation cap, an exception in the
// objective) the callback returns an error code, TAO unwinds, and the best
// point is what is returned. A non-finite point is answered with a finite
// value above the best one (see objective_and_gradient), which the line
// search backs off from.
//
// PETSc is not thread-safe in Debian's build (no PETSC_HAVE_THREADSAFETY):
// TAO solves are serialised by one process-wide mutex. The objective itself
// may still use OpenMP inside a solve.
#include <petscsys.h>
#include <petsctao.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <mutex>
#include <stdexcept>
#include <string>
#include <vector>

#include "../minimizer_backends.hpp"
#include "otfp/tao.hpp"
#include "petsc_session.hpp"

namespace otfp::detail {

namespace {

using Status = TrackedObjective::Status;

void check(PetscErrorCode ierr, const char* what) { petsc_check(ierr, what); }

struct VecHandle {
  Vec v = nullptr;
  ~VecHandle() {
    if (v != nullptr) VecDestroy(&v);
  }
};
struct TaoHandle {
  Tao t = nullptr;
  ~TaoHandle() {
    if (t != nullptr) TaoDestroy(&t);
  }
};

enum class Stop { None, Capped, Error };

struct TaoRun {
  TrackedObjective* objective = nullptr;
  const MinimizerOptions* options = nullptr;
  Stop stop = Stop::None;
  // Best (lowest finite value) point evaluated with its gradient; starts as the start point.
  std::vector<double> best_x;
  double best_value = 0.0;
  double best_measure = 0.0;
  bool converged = false;
  bool function_tolerance = false;
  double last_value = 0.0;  // f at the previous accepted iterate (function_tolerance)
};

// Stands for the gradient of a rank with no unknowns (never read).
const double kEmptyGradient = 0.0;

// A nonzero return unwinds TaoSolve; run.stop says why.
constexpr PetscErrorCode kStopCode = PETSC_ERR_USER;

PetscErrorCode objective_and_gradient(Tao /*tao*/, Vec x, PetscReal* f, Vec g, void* data) {
  auto& run = *static_cast<TaoRun*>(data);
  const PetscScalar* xx = nullptr;
  PetscScalar* gg = nullptr;
  PetscErrorCode ierr = VecGetArrayRead(x, &xx);
  if (ierr != 0) return ierr;
  ierr = VecGetArray(g, &gg);
  if (ierr != 0) {
    VecRestoreArrayRead(x, &xx);
    return ierr;
  }
  const std::size_t n = run.objective->size();
  // A rank with no unknowns of a shared solve may see null arrays; a null
  // gradient would mean "value only" to the objective.
  double empty = 0.0;
  double* grad = n > 0 ? gg : &empty;
  double value = 0.0;
  const Status st = run.objective->evaluate(xx, &value, grad);
  if (st == Status::Ok) {
    *f = value;
    if (value < run.best_value) {
      run.best_value = value;
      run.best_x.assign(xx, xx + n);
      run.best_measure = run.objective->measure(xx, grad);
      if (run.objective->failed()) run.stop = Stop::Error;
    }
  } else {
    // TAO's More-Thuente line search cannot back off from +inf (its cubic
    // step becomes NaN and the search fails at the first point outside the
    // objective's domain). It is given a finite value above the current
    // iterate's (where the line search started) instead, with a zero
    // gradient: never accepted (no sufficient decrease), it brackets the
    // step, and the search shortens it as Ceres' does. (Measured from the
    // best point seen instead, a trial point of the same search could have
    // lowered it enough for the placeholder to pass.)
    *f = run.last_value + std::max(1.0, std::abs(run.last_value));
    for (std::size_t i = 0; i < n; ++i) gg[i] = 0.0;
    if (st == Status::Capped) run.stop = Stop::Capped;
    if (st == Status::Error) run.stop = Stop::Error;
  }
  VecRestoreArray(g, &gg);
  VecRestoreArrayRead(x, &xx);
  return run.stop == Stop::None ? PetscErrorCode(0) : kStopCode;
}

// Replaces TAO's default test: ours at each accepted iterate, plus the caps.
PetscErrorCode convergence_test(Tao tao, void* data) {
  auto& run = *static_cast<TaoRun*>(data);
  TaoConvergedReason reason = TAO_CONTINUE_ITERATING;
  PetscErrorCode ierr = TaoGetConvergedReason(tao, &reason);
  if (ierr != 0) return ierr;
  if (reason != TAO_CONTINUE_ITERATING) return 0;  // the line search failed: TAO's verdict stands
  PetscInt iterations = 0;
  PetscReal f = 0.0, gnorm = 0.0, cnorm = 0.0, xdiff = 0.0;
  ierr = TaoGetSolutionStatus(tao, &iterations, &f, &gnorm, &cnorm, &xdiff, &reason);
  if (ierr != 0) return ierr;
  Vec x = nullptr, g = nullptr;
  ierr = TaoGetSolution(tao, &x);
  if (ierr != 0) return ierr;
  ierr = TaoGetGradient(tao, &g, nullptr, nullptr);
  if (ierr != 0) return ierr;
  const PetscScalar* xx = nullptr;
  const PetscScalar* gg = nullptr;
  VecGetArrayRead(x, &xx);
  VecGetArrayRead(g, &gg);
  const double measure = run.objective->measure(xx, run.objective->size() > 0 ? gg : &kEmptyGradient);
  const bool converged = measure <= run.options->gradient_tolerance;
  if (converged) {
    // The point returned is TAO's converged iterate, not the lowest value
    // seen: a trial point of an earlier line search may have the same F to
    // round-off and a stopping measure far above the tolerance.
    run.best_x.assign(xx, xx + run.objective->size());
    run.best_value = f;
    run.best_measure = measure;
  }
  VecRestoreArrayRead(g, &gg);
  VecRestoreArrayRead(x, &xx);
  if (run.objective->failed()) {
    run.stop = Stop::Error;
    return kStopCode;
  }
  const double ftol = run.options->function_tolerance;
  if (converged) {
    run.converged = true;
    return TaoSetConvergedReason(tao, TAO_CONVERGED_USER);
  }
  if (iterations > 0 && ftol > 0.0 && std::abs(run.last_value - f) <= ftol * std::abs(run.last_value)) {
    run.function_tolerance = true;
    return TaoSetConvergedReason(tao, TAO_CONVERGED_USER);
  }
  run.last_value = f;
  if (iterations >= run.options->max_iterations) return TaoSetConvergedReason(tao, TAO_DIVERGED_MAXITS);
  return 0;
}

// On PETSC_COMM_SELF (the serial backend) or PETSC_COMM_WORLD (a
// distributed solve: z is this rank's share, the objective's value and
// measure are global, and every rank runs this in lockstep).
BackendResult run_tao_on(MPI_Comm comm, TrackedObjective& objective, std::vector<double>& z, const StartPoint& start,
                         const MinimizerOptions& options) {
  const std::lock_guard<std::recursive_mutex> lock(petsc_mutex());
  ensure_petsc();
  if (z.size() > static_cast<std::size_t>(std::numeric_limits<PetscInt>::max()))
    throw std::runtime_error("PETSc/TAO: " + std::to_string(z.size()) + " unknowns exceed PetscInt");
  const auto n = static_cast<PetscInt>(z.size());

  TaoRun run;
  run.objective = &objective;
  run.options = &options;
  run.best_x = z;
  run.best_value = start.value;
  run.best_measure = start.measure;
  run.last_value = start.value;

  VecHandle x;
  if (comm == PETSC_COMM_SELF)
    check(VecCreateSeq(PETSC_COMM_SELF, n, &x.v), "VecCreateSeq");
  else
    check(VecCreateMPI(comm, n, PETSC_DETERMINE, &x.v), "VecCreateMPI");
  {
    PetscScalar* xx = nullptr;
    check(VecGetArray(x.v, &xx), "VecGetArray");
    std::copy(z.begin(), z.end(), xx);
    check(VecRestoreArray(x.v, &xx), "VecRestoreArray");
  }
  // The L-BFGS memory: TAOLMVM's matrix (options prefix "tao_lmvm_") takes it
  // from the options database only, read by TaoSetFromOptions. Options from
  // PETSC_OPTIONS are read there too (-tao_ls_type, -tao_view, ...); the
  // settings below override the ones the library owns.
  const std::string memory = std::to_string(options.lbfgs_memory);
  check(PetscOptionsSetValue(nullptr, "-tao_lmvm_mat_lmvm_hist_size", memory.c_str()), "PetscOptionsSetValue");
  TaoHandle tao;
  check(TaoCreate(comm, &tao.t), "TaoCreate");
  check(TaoSetType(tao.t, TAOLMVM), "TaoSetType");
  check(TaoSetFromOptions(tao.t), "TaoSetFromOptions");
  check(TaoSetSolution(tao.t, x.v), "TaoSetSolution");
  check(TaoSetObjectiveAndGradient(tao.t, nullptr, objective_and_gradient, &run), "TaoSetObjectiveAndGradient");
  check(TaoSetConvergenceTest(tao.t, convergence_test, &run), "TaoSetConvergenceTest");
  check(TaoSetMaximumIterations(tao.t, options.max_iterations), "TaoSetMaximumIterations");
  // A backstop: the tracker enforces the cap on objective calls.
  check(TaoSetMaximumFunctionEvaluations(tao.t, options.max_evaluations), "TaoSetMaximumFunctionEvaluations");

  BackendResult r;
  const PetscErrorCode solved = TaoSolve(tao.t);
  // (The evaluation cap also unwinds TaoSolve with an error code, but every
  // rank reaches it at the same evaluation: a normal end, MaxEvaluations.)
  if (comm != PETSC_COMM_SELF && (run.stop == Stop::Error || (solved != 0 && run.stop == Stop::None))) {
    // One rank's error (an exception in its share of the objective, a PETSc
    // failure) leaves the others inside a collective: the world is aborted,
    // as MPI codes do, with the reason on stderr.
    std::string why = "TaoSolve failed (PETSc error " + std::to_string(solved) + ")";
    if (run.stop == Stop::Error) {
      try {
        objective.rethrow_if_failed();
      } catch (const std::exception& e) {
        why = e.what();
      } catch (...) {
        why = "an exception in the objective";
      }
    }
    int rank = 0;
    MPI_Comm_rank(comm, &rank);
    std::fprintf(stderr, "otfp: error: rank %d: distributed solve: %s (aborting all ranks)\n", rank, why.c_str());
    std::fflush(stderr);
    MPI_Abort(comm, 1);
  }
  TaoConvergedReason reason = TAO_CONTINUE_ITERATING;
  TaoGetConvergedReason(tao.t, &reason);
  PetscInt iterations = 0;
  TaoGetIterationNumber(tao.t, &iterations);
  // TAO counts the iteration whose line search failed; the other backends do not.
  if (reason == TAO_DIVERGED_LS_FAILURE && iterations > 0) --iterations;
  r.iterations = static_cast<int>(iterations);
  r.message = "tao reason " + std::to_string(static_cast<int>(reason));

  z = run.best_x;
  r.final_value = run.best_value;
  r.final_measure = run.best_measure;
  if (run.stop == Stop::Error) {
    r.reason = TerminationReason::Failure;  // minimize() rethrows the objective's exception
  } else if (run.stop == Stop::Capped || reason == TAO_DIVERGED_MAXFCN) {
    r.reason = TerminationReason::MaxEvaluations;
  } else if (solved != 0) {
    r.reason = TerminationReason::Failure;
    r.message = "TaoSolve failed (PETSc error " + std::to_string(solved) + ")";
  } else if (run.converged) {
    r.reason = TerminationReason::Converged;
  } else if (run.function_tolerance) {
    r.reason = TerminationReason::FunctionTolerance;
  } else if (reason == TAO_DIVERGED_MAXITS) {
    r.reason = TerminationReason::MaxIterations;
  } else if (reason == TAO_DIVERGED_LS_FAILURE) {
    r.reason = objective.nonfinite_evaluations() > 0 && run.best_value == start.value
                   ? TerminationReason::NonFinite
                   : TerminationReason::LineSearchFailure;
    if (objective.nonfinite_evaluations() > 0)
      r.message += " (objective not finite at " + std::to_string(objective.nonfinite_evaluations()) + " trial points)";
  } else {
    r.reason = TerminationReason::Failure;
  }
  return r;
}

BackendResult run_tao(TrackedObjective& objective, std::vector<double>& z, const StartPoint& start,
                      const MinimizerOptions& options) {
  return run_tao_on(PETSC_COMM_SELF, objective, z, start, options);
}

}  // namespace

BackendResult run_tao_world(TrackedObjective& objective, std::vector<double>& z, const StartPoint& start,
                            const MinimizerOptions& options) {
  return run_tao_on(PETSC_COMM_WORLD, objective, z, start, options);
}

}  // namespace otfp::detail

namespace otfp {

void register_tao_backend() { detail::set_backend_runner(Backend::Tao, detail::run_tao); }


}  // namespace otfp
