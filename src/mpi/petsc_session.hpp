#pragma once
// PETSc (and through it MPI) for the otfp::mpi component: initialised once
// per process on first use, finalised at exit. Internal to src/mpi/.
#include <petscsys.h>

#include <mutex>

namespace otfp::detail {

// Initialises PETSc unless the program did it itself (then its settings stay
// as they are), without PETSc's or Open MPI's signal handlers. Throws
// std::runtime_error if PETSc cannot start.
void ensure_petsc();

// Throws std::runtime_error naming `what` for a nonzero PETSc error code.
void petsc_check(PetscErrorCode ierr, const char* what);

// Debian's PETSc is built without thread safety: every PETSc call of the
// component holds this lock. Recursive: a distributed solve's objective
// (inside TAO, under the lock) evaluates the distributed functional.
std::recursive_mutex& petsc_mutex();

// PETSC_COMM_WORLD, MPI and PETSc started if need be. The caller holds
// petsc_mutex() for its MPI calls (MPI_THREAD_SERIALIZED).
MPI_Comm world_comm();

}  // namespace otfp::detail

#include "../minimizer_backends.hpp"

namespace otfp::detail {

// The TAO backend on PETSC_COMM_WORLD, for a solve shared by all ranks
// (minimize_with(..., run_tao_world, true); src/mpi/minimizer_tao.cpp).
BackendResult run_tao_world(TrackedObjective& objective, std::vector<double>& z, const StartPoint& start,
                            const MinimizerOptions& options);

}  // namespace otfp::detail
