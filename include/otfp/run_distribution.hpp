#pragma once
// How one Simulation runs over several processes, each holding a share of
// the particles (docs/distributed.md). The serial library only defines the
// interface; the component otfp::mpi implements it on MPI and PETSc
// (otfp/mpi_distribution.hpp: MpiDistribution). A Simulation given one
// keeps its single time loop and hands it the three steps that need the
// other processes' particles - the diffusive step, the boundary projection
// and the redistribution of particles - and the global sums of its ledger
// checks. Everything else (advection, reflection at mirrored walls, the
// ledger, the time grid) runs on each process's share as it runs serially.
#include <cstdint>
#include <vector>

#include "otfp/barrier.hpp"
#include "otfp/boundary.hpp"
#include "otfp/explicit_stepper.hpp"
#include "otfp/images.hpp"
#include "otfp/implicit_stepper.hpp"
#include "otfp/particles.hpp"
#include "otfp/step_history.hpp"
#include "otfp/step_summary.hpp"

namespace otfp {

class RunDistribution {
 public:
  virtual ~RunDistribution() = default;

  // Once, from the Simulation's constructor: the diffusive step's problem
  // (the options, the barrier, periodic axes and the mirrored walls whose
  // image blobs the functional sums). Throws InvalidArgument naming the
  // field for what a distributed step cannot do.
  virtual void configure(int dim, const ImplicitOptions& options, const Barrier& barrier,
                         const Periodicity& periodicity, const std::vector<MirrorWallPtr>& walls) = 0;
  // The same for the explicit step (instead of configure()); diffuse() then
  // takes explicit steps (max_error ignored) and the history is empty. A
  // distribution that cannot step explicitly throws InvalidArgument.
  virtual void configure_explicit(int dim, const ExplicitOptions& options, const Barrier& barrier,
                                  const Periodicity& periodicity, const std::vector<MirrorWallPtr>& walls);

  // The diffusive step (implicit, or explicit after configure_explicit) of
  // the union of the shares, on this process's share (collective; accepted
  // or refused on every process alike). max_error: as ImplicitStepper::step
  // (infinity: no error control; ignored by the explicit step).
  virtual StepSummary diffuse(ParticleSet& owned, double dt, double max_error) = 0;

  // The step's history (otfp/step_history.hpp) of this process's particles;
  // redistribute() moves each entry with its particle. As ImplicitStepper's:
  virtual void reset_history() = 0;
  virtual void undo_last_history_update() = 0;
  virtual HistoryState local_history() const = 0;               // this process's entries
  virtual void restore_history(const HistoryState& state) = 0;  // this process's entries (InvalidArgument if bad)
  // Every process's entries, sorted by id, on every process (collective).
  virtual HistoryState gathered_history() = 0;

  // projection.apply(union, t, dt, rng) as a serial run would do it: every
  // process's projection state, `rng` and returned ledger advance alike, and
  // this share loses the particles the projection removes and gains the
  // inserted ones this process owns. `max_particles` is the global cap.
  virtual PatchLedger project(BoundaryProjection& projection, ParticleSet& owned, double t, double dt, Rng& rng,
                              std::int64_t max_particles) = 0;

  // Each particle to the process that owns its position (after a step and
  // at the start; collective).
  virtual void redistribute(ParticleSet& owned) = 0;

  // The union of the shares, in id order, on every process (collective;
  // checkpoints), and whether this process is the one that writes files.
  virtual ParticleSet gather(const ParticleSet& owned) = 0;
  virtual bool root() const = 0;
  virtual int rank() const = 0;  // this process's index, 0 ... size() - 1
  virtual int size() const = 0;  // the number of processes

  // The other processes' particles within `radius` of this process's (of
  // their bounding box; periodic axes by the nearest image), for sums over
  // neighbours such as the blob density at the particles (collective).
  virtual ParticleSet nearby(const ParticleSet& owned, double radius, const Periodicity& periodicity) = 0;

  // The largest value over the processes (collective).
  virtual double max(double v) = 0;

  // Sums over the processes (collective).
  virtual double sum(double v) = 0;
  virtual void sum(double* v, int n) = 0;  // each of v[0 ... n) in place
  virtual std::int64_t sum(std::int64_t v) = 0;
  // Every process's values, concatenated in process order (collective).
  virtual std::vector<std::int64_t> all_gather(const std::vector<std::int64_t>& mine) = 0;
};

}  // namespace otfp
