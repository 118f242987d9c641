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
// either stopping norm, a Barrier and periodic axes. Not yet: BDF2, the
// predictor, the error estimate, halving of a failed step, image blobs, an
// external potential (ImplicitOptions naming them are refused).
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
  StepSummary step(ParticleSet& owned, double dt);

  const ExchangeStats& exchange() const;
  const ImplicitOptions& options() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace otfp
