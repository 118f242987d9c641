// PETSc's process state for the otfp::mpi component (src/mpi/petsc_session.hpp).
#include "petsc_session.hpp"

#include <csignal>
#include <cstdlib>
#include <iterator>
#include <stdexcept>
#include <string>

#include "otfp/mpi.hpp"
#include "otfp/tao.hpp"

namespace otfp::detail {

std::recursive_mutex& petsc_mutex() {
  static std::recursive_mutex m;
  return m;
}

void petsc_check(PetscErrorCode ierr, const char* what) {
  if (ierr != 0)
    throw std::runtime_error(std::string("PETSc: ") + what + " failed (error " + std::to_string(ierr) + ")");
}

void ensure_petsc() {
  PetscBool initialized = PETSC_FALSE;
  petsc_check(PetscInitialized(&initialized), "PetscInitialized");
  if (initialized) return;
  // Without PETSc's signal handlers: they would replace the sanitizers' and
  // the command-line tool's own.
  petsc_check(PetscOptionsSetValue(nullptr, "-no_signal_handler", nullptr), "PetscOptionsSetValue");
  // Open MPI's initialisation (inside PETSc's) installs its own SIGSEGV and
  // SIGBUS handlers: the process's dispositions are put back as they were.
  const int signals[] = {SIGSEGV, SIGBUS, SIGFPE, SIGILL, SIGABRT, SIGINT, SIGTERM};
  struct sigaction saved[std::size(signals)];
  for (std::size_t i = 0; i < std::size(signals); ++i) sigaction(signals[i], nullptr, &saved[i]);
  // MPI as PETSc starts it: calls from any thread, one at a time (every
  // call of the component holds petsc_mutex()); PETSc's default, FUNNELED,
  // allows the main thread only, and serial TAO solves may run in others.
  PETSC_MPI_THREAD_REQUIRED = MPI_THREAD_SERIALIZED;
  const PetscErrorCode ierr = PetscInitializeNoArguments();
  for (std::size_t i = 0; i < std::size(signals); ++i) sigaction(signals[i], &saved[i], nullptr);
  petsc_check(ierr, "PetscInitializeNoArguments");
  // Errors come back as codes (turned into exceptions by petsc_check), with
  // no traceback printed on stderr.
  petsc_check(PetscPushErrorHandler(PetscReturnErrorHandler, nullptr), "PetscPushErrorHandler");
  std::atexit([] {
    PetscBool finalized = PETSC_TRUE;
    if (PetscFinalized(&finalized) == 0 && !finalized) PetscFinalize();
  });
}

MPI_Comm world_comm() {
  ensure_petsc();
  return PETSC_COMM_WORLD;
}

}  // namespace otfp::detail

namespace otfp {

std::string petsc_version() {
  return "PETSc " + std::to_string(PETSC_VERSION_MAJOR) + "." + std::to_string(PETSC_VERSION_MINOR) + "." +
         std::to_string(PETSC_VERSION_SUBMINOR);
}

int world_rank() {
  const std::lock_guard<std::recursive_mutex> lock(detail::petsc_mutex());
  detail::ensure_petsc();
  int rank = 0;
  MPI_Comm_rank(PETSC_COMM_WORLD, &rank);
  return rank;
}

int world_size() {
  const std::lock_guard<std::recursive_mutex> lock(detail::petsc_mutex());
  detail::ensure_petsc();
  int size = 1;
  MPI_Comm_size(PETSC_COMM_WORLD, &size);
  return size;
}

}  // namespace otfp
