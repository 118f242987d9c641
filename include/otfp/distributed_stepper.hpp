#pragma once
// One implicit step (28) of a particle set spread over the ranks of the MPI
// world (component otfp::mpi, docs/distributed.md): the unknowns of each
// rank's particles are its share of one MPI Vec, F and its gradient come from
// a DistributedFunctional, and TAO (LMVM) minimises on PETSC_COMM_WORLD with
// the serial stepper's scaled unknowns and stopping rule (the same thresholds,
// taken over all ranks). A serial step with solver.backend = "tao" solves the
// same problem with the same optimiser.
//
// The serial stepper's options: implicit Euler or variational BDF2, the
// predictor, fixed or per-particle widths, either stopping norm, the local
// error estimate (either measure), a Barrier and periodic axes; the solve is
// the serial one (src/step_solve.cpp). Each rank keeps the history of the
// particles it owns (StepHistory); the caller moves entries with their
// particles (history()). Refused (InvalidArgument naming the field): a
// backend other than TAO. A failed solve is retried as 2, 4, ... substeps
// (max_halvings) and accepted positions are wrapped into a periodic box, as
// serially. Ignored: sort_particles; there is no external potential. Image
// blobs: functional().set_images().
//
// One distributed step (or functional evaluation) per process at a time:
// two threads of one process running collectives on the same world would
// interleave them differently on different ranks.
#include <limits>
#include <memory>

#include "otfp/distributed_functional.hpp"
#include "otfp/implicit_stepper.hpp"
#include "otfp/step_history.hpp"

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
  // max_error: as ImplicitStepper::step (a step whose global error estimate
  // exceeds it is not taken; error_rejected, the history kept).
  StepSummary step(ParticleSet& owned, double dt, double max_error = std::numeric_limits<double>::infinity());

  // This rank's share of the history (its own particles' entries).
  StepHistory& history();

  const ExchangeStats& exchange() const;
  DistributedFunctional& functional();
  const ImplicitOptions& options() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace otfp
