#pragma once
// One implicit step (28) of a particle set spread over the ranks of the MPI
// world (component otfp::mpi, docs/distributed.md): the unknowns of each
// rank's particles are its share of one MPI Vec, F and its gradient come from
// a DistributedFunctional, and TAO (LMVM) minimises on PETSC_COMM_WORLD with
// the serial stepper's scaled unknowns and stopping rule (the same thresholds,
// taken over all ranks). A serial step with solver.backend = "tao" solves the
// same problem with the same optimiser.
//
// Today: implicit Euler without predictor, fixed or per-particle widths,
// either stopping norm, a Barrier and periodic axes. Refused (InvalidArgument
// naming the field): a backend other than TAO, BDF2, a predictor. A failed
// solve is retried as 2, 4, ... substeps (max_halvings) and accepted
// positions are wrapped into a periodic box, as serially. Not yet, and
// ignored: the error estimate (NaN), sort_particles; there is no external
// potential. Image blobs: functional().set_images().
//
// One distributed step (or functional evaluation) per process at a time:
// two threads of one process running collectives on the same world would
// interleave them differently on different ranks.
#include <memory>

#include "otfp/distributed_functional.hpp"
#include "otfp/implicit_stepper.hpp"

namespace otfp {

class DistributedImplicitStepper {
 public:
  // Collective. options.minimizer.backend must be Backend::Tao.
  DistributedImplicitStepper(int dim, ImplicitOptions options, Barrier barrier = {}, Periodicity periodicity = {});
  ~DistributedImplicitStepper();
  DistributedImplicitStepper(const DistributedImplicitStepper&) = delete;
  DistributedImplicitStepper& operator=(const DistributedImplicitStepper&) = delete;

  // Collective: every rank passes its own particles and the same dt. Moves
  // them (and their widths) by one step; on a failed solve (the same verdict
  // on every rank) they are left as they were and summary.accepted is false.
  // The summary's F, measures and counts are global; its times are this rank's.
  // Particles one rank refuses (a width above the bound) make every rank
  // throw InvalidArgument before any work; an error inside the solve on one
  // rank only (an exception in its share of F) aborts the world (MPI_Abort)
  // with the reason on stderr, as the other ranks wait in a collective.
  StepSummary step(ParticleSet& owned, double dt);

  const ExchangeStats& exchange() const;
  DistributedFunctional& functional();
  const ImplicitOptions& options() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace otfp
