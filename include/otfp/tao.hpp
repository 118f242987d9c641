#pragma once
// The TAO backend of minimize() (Backend::Tao), from the optional otfp::mpi
// component: built with OTFP_WITH_MPI=ON where PETSc 3.18 and MPI are found,
// linked as otfp::mpi. No PETSc type appears here.
//
// A program that links otfp::mpi calls register_tao_backend() once (the otfp
// command-line tool and the Python module do it at start); from then on
// backend_available(Backend::Tao) is true and solver.backend = "tao" runs
// TAO's LMVM with the library's own stopping rule. PETSc is initialised at
// the first TAO solve (unless the program initialised it already) without
// PETSc's signal handlers, and finalised at exit.
#include <string>

namespace otfp {

// Makes Backend::Tao available to minimize() in this process. Idempotent and
// thread-safe.
void register_tao_backend();

// "PETSc 3.18.5" (the version this component was built against).
std::string petsc_version();

}  // namespace otfp
