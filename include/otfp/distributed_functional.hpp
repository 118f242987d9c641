#pragma once
// The functional (28) of a particle set spread over the ranks of the MPI
// world (component otfp::mpi, docs/distributed.md). Each rank holds the
// particles it owns; the blobs of other ranks that come within reach of its
// own ("ghosts") are exchanged through a PETSc star forest (PetscSF) before
// each evaluation, and the gradient each rank computes for its ghosts is
// summed back into their owners. F and its gradient equal the serial
// Functional's on the union of the ranks' particles, up to the order of
// floating-point sums, for any assignment of particles to ranks (tested on
// slabs and on random assignments with 1, 2 and 3 ranks). Which rank owns
// which particle is the caller's (otfp/decomposition.hpp).
//
// A Barrier, periodic axes and image blobs at mirrored walls (set_images)
// are supported.
#include <cstddef>
#include <cstdint>
#include <memory>
#include <vector>

#include "otfp/functional.hpp"
#include "otfp/step_summary.hpp"

namespace otfp {


// What the halo exchanges cost, summed over this rank's evaluations.
struct ExchangeStats {
  int rebuilds = 0;             // ghost sets and neighbour lists built
  std::size_t ghosts = 0;       // ghosts at the last rebuild
  double bytes_sent = 0.0;      // by this rank, forward (ghost data) and back (ghost gradients)
  double seconds = 0.0;         // wall time in the exchanges and global sums
  double list_seconds = 0.0;    // wall time of this rank's neighbour-list builds
  int evaluations = 0;
};

class DistributedFunctional {
 public:
  // Collective over the world. The options are those of Functional.
  DistributedFunctional(int dim, FunctionalOptions options, Barrier barrier = {}, Periodicity periodicity = {});
  ~DistributedFunctional();
  DistributedFunctional(const DistributedFunctional&) = delete;
  DistributedFunctional& operator=(const DistributedFunctional&) = delete;

  // This rank's owned particles: reference configuration (x^k, s^k),
  // masses and transport weights (Functional::set_reference; empty: 1).
  // Not collective; the next evaluation (collective) rebuilds the ghosts.
  void set_reference(const std::vector<Vec3>& x_ref, const std::vector<double>& s_ref, const std::vector<double>& m,
                     std::vector<double> transport_weights = {});

  // F at this rank's (x, s) and everyone else's (collective): the parts are
  // sums over all ranks; grad (if not null) is the gradient with respect to
  // this rank's own particles. The ghosts and the neighbour list are rebuilt
  // when any particle anywhere has moved more than half the skin since the
  // last build (or a width has left its margin), as the serial list is.
  FunctionalParts evaluate(const std::vector<Vec3>& x, const std::vector<double>& s, Gradient* grad);

  // Force (27)'s velocity -(kappa grad rho / rho + grad Psi) at this rank's
  // particles, rho summed over every rank's blobs and the images
  // (collective; Functional::explicit_velocity). Masses and widths are those
  // of set_reference().
  void explicit_velocity(const std::vector<Vec3>& x, const std::vector<double>& s, std::vector<Vec3>& v);

  // Image blobs at mirrored walls, as Functional::set_images: each rank
  // mirrors its own particles and its ghosts (the serial selection rule).
  void set_images(WallImages images);
  const WallImages& images() const;

  void set_dt(double dt);  // the transport term's step (> 0)
  std::size_t owned() const;
  const ExchangeStats& exchange() const;
  std::uint64_t pair_evaluations() const;  // this rank's pair-kernel evaluations (EntropyTerm::pair_evaluations)
  // A step's share of the work since `list_seconds_before` and
  // `pairs_before` (this rank's exchange().list_seconds and
  // pair_evaluations() when it began) into summary.list_seconds (the
  // slowest rank's: the step's wall time waits for it) and
  // summary.pair_evaluations (all ranks'). Collective.
  void add_step_work(double list_seconds_before, std::uint64_t pairs_before, StepSummary& summary) const;
  const NeighborList& list() const;  // over this rank's particles, then its ghosts, then images
  std::size_t ghosts() const;        // ghosts of the last build (list rows owned() ... owned() + ghosts())

  // Per-particle data of the owners at the ghosts of the last build
  // (collective): own holds k values per owned particle; the result k per
  // ghost, in the list's ghost order.
  std::vector<double> ghost_values(const std::vector<double>& own, int k);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace otfp
