#pragma once
// The process's MPI world, from the optional otfp::mpi component (built with
// OTFP_WITH_MPI). MPI and PETSc are initialised on first use (unless the
// program did it itself) and finalised at exit; under `mpirun -np N` the
// world has N ranks, otherwise one. No MPI or PETSc type appears here.
namespace otfp {

int world_rank();  // 0 .. world_size() - 1
int world_size();

}  // namespace otfp
