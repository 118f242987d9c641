#pragma once
// Unconstrained gradient-based minimisation with run-time selectable
// backends: Ceres Solver (GradientProblemSolver), NLopt, and PETSc's TAO
// (from the optional otfp::mpi component). No backend library's types appear
// here; the adapters live in src/ and are linked privately.
#include <cstddef>
#include <string>
#include <vector>
#include "otfp/enums.hpp"

namespace otfp {

// Objective f(z) with gradient, in the solver's (already scaled) variables.
class Objective {
 public:
  virtual ~Objective() = default;
  virtual std::size_t num_variables() const = 0;
  // Returns false if f or its gradient is not finite at z (the point is
  // rejected). `gradient` may be null: then only the value is wanted.
  virtual bool evaluate(const double* z, double* value, double* gradient) = 0;
  // Common stopping measure, the same for both backends: the objective decides
  // how the raw gradient is scaled (the stepper uses a displacement: the
  // position gradient divided by m_p/dt). Returns the scaled max-norm.
  virtual double stopping_measure(const double* z, const double* gradient) const;
};

struct MinimizerOptions {
  Backend backend = Backend::Ceres;                // which library runs the minimisation
  Algorithm algorithm = Algorithm::Lbfgs;          // must be offered by the backend
  double gradient_tolerance = 1e-6;                // stop when Objective::stopping_measure <= this
  double relative_gradient_tolerance = 0.0;        // ... or <= this x its value at the start, if smaller (0: off)
  double gradient_tolerance_floor = 0.0;           // the relative rule never asks for less than this
  double start_tolerance = 0.0;                    // a start whose measure is <= this is returned converged (0: off)
  double function_tolerance = 0.0;                 // relative change of f to stop at (0: off)
  int max_iterations = 1000;                       // iteration cap (Ceres' default of 50 is too low)
  int max_evaluations = 5000;                      // cap on value+gradient evaluations
  int lbfgs_memory = 10;                           // L-BFGS history length (both backends)
  bool approximate_eigenvalue_scaling = true;      // Ceres use_approximate_eigenvalue_bfgs_scaling
  // Throws InvalidArgument naming the offending field.
  void validate() const;
};

struct MinimizerSummary {
  TerminationReason reason = TerminationReason::Failure;
  bool success = false;         // true only for Converged or FunctionTolerance
  double initial_value = 0.0;
  double final_value = 0.0;
  double final_stopping_measure = 0.0;
  double gradient_tolerance = 0.0;  // the threshold used (after the relative rule)
  int iterations = 0;
  int evaluations = 0;          // value+gradient evaluations requested by the backend
  double solver_seconds = 0.0;  // wall time inside the backend minus time inside the objective
  double total_seconds = 0.0;
  std::string message;          // backend's own message
};

// Whether `backend` offers `algorithm` (validate() checks it), and the names
// it offers, for messages.
bool algorithm_offered(Backend backend, Algorithm algorithm);
std::string offered_algorithms(Backend backend);

// Ceres and NLopt always; TAO once the otfp::mpi component has registered it
// (register_tao_backend(), otfp/tao.hpp). minimize() with a backend that is
// not available throws InvalidArgument naming solver.backend.
bool backend_available(Backend backend);

// Minimises the objective from z (in place). On return z holds the best point
// found (even when not successful; callers decide whether to accept it).
MinimizerSummary minimize(Objective& objective, std::vector<double>& z, const MinimizerOptions& options);

}  // namespace otfp
