#pragma once
// A Simulation over the ranks of the MPI world (component otfp::mpi,
// docs/distributed.md): the RunDistribution of otfp/run_distribution.hpp on
// MPI and PETSc.
//
//   auto sim = otfp::Simulation(domain, boundary, options,
//                               std::make_shared<otfp::MpiDistribution>());
//   sim.start(my_share);            // any split over the ranks, even all on rank 0
//   sim.run(control, &observer);    // the library's one time loop, on every rank
//
// - Diffusion: DistributedImplicitStepper (TAO on the world), or
//   DistributedExplicitStepper for an explicit Simulation, with the image
//   blobs of the Simulation's mirrored walls.
// - Boundary projection: every rank gathers the particles the projection
//   reads (BoundaryProjection::reads: those near the boundary), in id order,
//   and applies the same projection with the same random numbers to them;
//   each rank then drops its removed particles and keeps the inserted ones
//   whose position it owns. The result is the serial projection's on the
//   union, on any rank count (the random deletions are drawn by id). The
//   gathered set is O(surface), not O(n); with outlets that take the nearest
//   particles anywhere (NearestParticles) it is every particle.
// - Redistribution: particles migrate to the rank whose region holds them
//   after every step; the regions are a recursive bisection of the particles
//   (balanced_bisection), recomputed when the largest rank's count exceeds
//   the mean by rebalance_tolerance.
#include <cstdint>
#include <memory>
#include <vector>

#include "otfp/decomposition.hpp"
#include "otfp/distributed_explicit_stepper.hpp"
#include "otfp/distributed_stepper.hpp"
#include "otfp/run_distribution.hpp"

namespace otfp {

struct MpiDistributionOptions {
  double rebalance_tolerance = 0.1;  // new regions when max count > (1 + this) x mean count (>= 0)
  void validate() const;             // throws InvalidArgument naming the field
};

// What the distribution did, on this rank.
struct MpiDistributionStats {
  std::int64_t projections = 0;       // project() calls
  std::int64_t gathered = 0;          // particles gathered for the last projection (all ranks')
  std::int64_t migrated_out = 0;      // particles this rank sent to others (all steps)
  std::int64_t rebalances = 0;        // regions recomputed
  double projection_seconds = 0.0;    // in project(), gathering included
  double redistribution_seconds = 0.0;
};

class MpiDistribution final : public RunDistribution {
 public:
  explicit MpiDistribution(MpiDistributionOptions options = {});  // collective (starts MPI and PETSc if need be)
  ~MpiDistribution() override;

  void configure(int dim, const ImplicitOptions& options, const Barrier& barrier, const Periodicity& periodicity,
                 const std::vector<MirrorWallPtr>& walls) override;
  void configure_explicit(int dim, const ExplicitOptions& options, const Barrier& barrier,
                          const Periodicity& periodicity, const std::vector<MirrorWallPtr>& walls) override;
  StepSummary diffuse(ParticleSet& owned, double dt, double max_error) override;
  void reset_history() override;
  void undo_last_history_update() override;
  HistoryState local_history() const override;
  void restore_history(const HistoryState& state) override;
  HistoryState gathered_history() override;
  PatchLedger project(BoundaryProjection& projection, ParticleSet& owned, double t, double dt, Rng& rng,
                      std::int64_t max_particles) override;
  void redistribute(ParticleSet& owned) override;
  ParticleSet gather(const ParticleSet& owned) override;  // all_particles(owned)
  bool root() const override;                             // rank 0
  ParticleSet nearby(const ParticleSet& owned, double radius, const Periodicity& periodicity) override;
  double max(double v) override;
  double sum(double v) override;
  void sum(double* v, int n) override;
  std::int64_t sum(std::int64_t v) override;
  std::vector<std::int64_t> all_gather(const std::vector<std::int64_t>& mine) override;

  const MpiDistributionStats& stats() const { return stats_; }
  const ExchangeStats& exchange() const;  // the diffusive steps' halo exchanges
  int rank() const override;
  int size() const override;

 private:
  DistributedImplicitStepper& stepper() const;
  MpiDistributionOptions options_;
  int dim_ = 3;
  std::unique_ptr<DistributedImplicitStepper> stepper_;
  std::unique_ptr<DistributedExplicitStepper> explicit_stepper_;  // instead of stepper_ (no history)
  std::unique_ptr<BisectionLayout> layout_;
  MpiDistributionStats stats_;
};

// The union of every rank's share, in id order, on every rank (collective;
// O(n) memory per rank: for tests, output and checkpoints of modest runs).
ParticleSet all_particles(const ParticleSet& owned);

}  // namespace otfp
