#pragma once
// One explicit step of a particle set spread over the ranks of the MPI world
// (component otfp::mpi, docs/distributed.md): the schemes of ExplicitStepper
// (force (27) with Euler or RK4, or Euler with the exact gradient of (28)),
// each velocity evaluated by a DistributedFunctional (the ghosts within
// reach exchanged first, images at mirrored walls included). Positions equal
// the serial ExplicitStepper's on the union of the ranks' particles, up to
// the order of the sums.
//
// Collective: every rank calls step() with its own particles and the same
// dt. A step whose masses or widths are not finite and > 0 on some rank, or
// whose update is not finite anywhere, is rejected on every rank
// (accepted == false, the particles untouched). Accepted positions are
// wrapped into a periodic box. An error inside the collectives on one rank
// only (a resource limit of the neighbour search) aborts the world
// (MPI_Abort, the reason on stderr), where the serial stepper rejects the
// step. Ignored: sort_particles (each rank keeps its order); there is no
// external potential.
#include <memory>

#include "otfp/distributed_functional.hpp"
#include "otfp/explicit_stepper.hpp"

namespace otfp {

class DistributedExplicitStepper {
 public:
  // Collective.
  DistributedExplicitStepper(int dim, ExplicitOptions options, Barrier barrier = {}, Periodicity periodicity = {});
  ~DistributedExplicitStepper();
  DistributedExplicitStepper(const DistributedExplicitStepper&) = delete;
  DistributedExplicitStepper& operator=(const DistributedExplicitStepper&) = delete;

  // The summary's F and counts are global; its times are this rank's.
  StepSummary step(ParticleSet& owned, double dt);

  DistributedFunctional& functional();
  const ExplicitOptions& options() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace otfp
