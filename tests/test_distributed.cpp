// DistributedFunctional against the serial Functional, and
// DistributedImplicitStepper against the serial TAO step (otfp::mpi). Run by
// ctest under mpiexec with 1, 2 and 3 ranks (Distributed.Np1/Np2/Np3): every
// rank builds the same global cloud, owns the particles a decomposition gives
// it, and compares with the serial computation done (by every rank) on the
// whole cloud.
#include <gtest/gtest.h>
#include <mpi.h>

#include <algorithm>
#include <functional>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include <unistd.h>

#include "otfp/decomposition.hpp"
#include "otfp/distributed_functional.hpp"
#include "otfp/distributed_explicit_stepper.hpp"
#include "otfp/distributed_stepper.hpp"
#include "otfp/functional.hpp"
#include "otfp/geometry.hpp"
#include "otfp/images.hpp"
#include "otfp/implicit_stepper.hpp"
#include "otfp/mpi.hpp"
#include "otfp/mpi_distribution.hpp"
#include "otfp/run_setup.hpp"
#include "otfp/simulation.hpp"
#include "otfp/tao.hpp"

namespace {

using namespace otfp;

struct Cloud {
  int dim = 3;
  std::vector<Vec3> x;
  std::vector<double> s, m;
};

Cloud ball_cloud(int dim, std::size_t n, std::uint64_t seed, bool varied_widths) {
  Cloud c;
  c.dim = dim;
  Rng rng(seed);
  DomainPtr ball = make_ball(dim, Vec3::Zero(), 1.0);
  const double s0 = 0.6 * std::pow(1.0 / static_cast<double>(n), 1.0 / dim);
  for (std::size_t i = 0; i < n; ++i) {
    c.x.push_back(0.9 * ball->sample_interior(rng));
    c.s.push_back(varied_widths ? s0 * rng.uniform(0.8, 1.25) : s0);
    c.m.push_back(rng.uniform(0.5, 1.5) / static_cast<double>(n));
  }
  return c;
}

Cloud periodic_cloud(int dim, std::size_t n, std::uint64_t seed) {
  Cloud c;
  c.dim = dim;
  Rng rng(seed);
  const double s0 = 0.7 * std::pow(1.0 / static_cast<double>(n), 1.0 / dim);
  for (std::size_t i = 0; i < n; ++i) {
    Vec3 y = Vec3::Zero();
    for (int k = 0; k < dim; ++k) y[k] = rng.uniform();
    c.x.push_back(y);
    c.s.push_back(s0);
    c.m.push_back(1.0 / static_cast<double>(n));
  }
  return c;
}

enum class Split { Slabs, Random };

std::vector<int> owners(const Cloud& c, Split split, std::uint64_t seed) {
  const int ranks = world_size();
  if (split == Split::Slabs) return partition_slabs(c.x, 0, ranks);
  Rng rng(seed);
  std::vector<int> o(c.x.size());
  for (auto& r : o) r = static_cast<int>(rng.below(static_cast<std::uint64_t>(ranks)));
  return o;
}

template <class T>
std::vector<T> mine(const std::vector<T>& all, const std::vector<int>& owner) {
  std::vector<T> out;
  for (std::size_t p = 0; p < all.size(); ++p)
    if (owner[p] == world_rank()) out.push_back(all[p]);
  return out;
}

FunctionalOptions options(bool widths) {
  FunctionalOptions o;
  o.dt = 2e-3;
  o.kappa = 1.0;
  o.rho_ref = 1.0;
  o.optimise_widths = widths;
  return o;
}

// The configuration a step would evaluate: the reference moved by a smooth
// field of amplitude `shift` (relative to the widths), widths changed a little.
void displace(Cloud& c, double shift) {
  for (std::size_t p = 0; p < c.x.size(); ++p) {
    for (int k = 0; k < c.dim; ++k) c.x[p][k] += shift * c.s[p] * std::sin(3.0 * c.x[p][(k + 1) % c.dim] + k);
    c.s[p] *= 1.0 + 0.1 * shift * std::cos(2.0 * c.x[p][0]);
  }
}

struct Compared {
  double f_rel = 0.0, g_rel = 0.0;
};

// F and this rank's gradient entries against the serial ones, after the
// reference evaluation and after each displacement of `shifts`.
std::vector<Compared> compare(const Cloud& reference, Split split, bool widths, const Barrier& barrier,
                              const Periodicity& per, const std::vector<double>& shifts,
                              const std::vector<MirrorWallPtr>& walls = {}) {
  const std::vector<int> owner = owners(reference, split, 99);
  Functional serial(reference.dim, options(widths), barrier, per);
  DistributedFunctional dist(reference.dim, options(widths), barrier, per);
  if (!walls.empty()) {
    serial.set_images(WallImages(walls));
    dist.set_images(WallImages(walls));
  }
  serial.set_reference(reference.x, reference.s, reference.m);
  dist.set_reference(mine(reference.x, owner), mine(reference.s, owner), mine(reference.m, owner));
  std::vector<Compared> out;
  Cloud c = reference;
  for (std::size_t step = 0; step <= shifts.size(); ++step) {
    if (step > 0) displace(c, shifts[step - 1]);
    Gradient gs, gd;
    const FunctionalParts fs = serial.evaluate(c.x, c.s, &gs);
    const FunctionalParts fd = dist.evaluate(mine(c.x, owner), mine(c.s, owner), &gd);
    Compared r;
    r.f_rel = std::abs(fd.total() - fs.total()) / std::abs(fs.total());
    double g_scale = 0.0, g_diff = 0.0;
    std::size_t i = 0;
    for (std::size_t p = 0; p < c.x.size(); ++p) {
      g_scale = std::max(g_scale, gs.x[p].norm());
      if (owner[p] != world_rank()) continue;
      g_diff = std::max(g_diff, (gd.x[i] - gs.x[p]).norm());
      if (widths) g_diff = std::max(g_diff, std::abs(gd.s[i] - gs.s[p]));
      ++i;
    }
    EXPECT_EQ(i, gd.x.size());
    r.g_rel = g_diff / g_scale;
    // The worst rank's figure, so that every rank asserts the same thing.
    MPI_Allreduce(MPI_IN_PLACE, &r.g_rel, 1, MPI_DOUBLE, MPI_MAX, MPI_COMM_WORLD);
    out.push_back(r);
  }
  return out;
}

void expect_round_off(const std::vector<Compared>& results) {
  double f_worst = 0.0, g_worst = 0.0;
  for (const Compared& r : results) {
    f_worst = std::max(f_worst, r.f_rel);
    g_worst = std::max(g_worst, r.g_rel);
  }
  if (world_rank() == 0)
    std::printf("  %d ranks: |F - F_serial| / |F| <= %.2g, max |g - g_serial| / max |g_serial| <= %.2g\n",
                world_size(), f_worst, g_worst);
  for (std::size_t k = 0; k < results.size(); ++k) {
    EXPECT_LT(results[k].f_rel, 1e-12) << "evaluation " << k;
    EXPECT_LT(results[k].g_rel, 1e-12) << "evaluation " << k;
  }
}

}  // namespace

TEST(DistributedFunctional, MatchesSerialOnSlabs3D) {
  const Cloud c = ball_cloud(3, 1500, 3, false);
  DomainPtr ball = make_ball(3, Vec3::Zero(), 1.0);
  // 0.05 widths: the list is kept; 2 widths: it (and the ghost sets) are rebuilt.
  expect_round_off(compare(c, Split::Slabs, false, Barrier(ball, 100.0), Periodicity::none(3), {0.05, 2.0}));
}

TEST(DistributedFunctional, MatchesSerialOnSlabs2DWithWidths) {
  const Cloud c = ball_cloud(2, 800, 4, true);
  DomainPtr ball = make_ball(2, Vec3::Zero(), 1.0);
  expect_round_off(compare(c, Split::Slabs, true, Barrier(ball, 100.0), Periodicity::none(2), {0.05, 2.0}));
}

TEST(DistributedFunctional, MatchesSerialOnRandomAssignments) {
  for (int dim : {1, 2, 3}) {
    SCOPED_TRACE(dim);
    const Cloud c = ball_cloud(dim, dim == 1 ? 200 : 600, 5 + dim, true);
    expect_round_off(compare(c, Split::Random, dim == 3, Barrier(), Periodicity::none(dim), {0.3, 2.0}));
  }
}

TEST(DistributedFunctional, MatchesSerialAcrossPeriodicFaces) {
  for (int dim : {2, 3}) {
    SCOPED_TRACE(dim);
    const Cloud c = periodic_cloud(dim, dim == 2 ? 700 : 1500, 7);
    Periodicity per = Periodicity::none(dim);
    for (int k = 0; k < dim; ++k) per.period[k] = 1.0;
    // Slabs along x: the first and the last rank are neighbours across x = 0.
    expect_round_off(compare(c, Split::Slabs, false, Barrier(), per, {0.05, 2.0}));
  }
}

// Image blobs: each rank mirrors its own particles and its ghosts. Plane
// walls of a box close to the cloud on every side (images of order 1 to 3 at
// edges and corners), and the sphere wall of a ball (the reservoir band's
// back face), on slabs and on random assignments; the shifts keep and
// rebuild the list.
TEST(DistributedFunctional, MatchesSerialWithImageBlobs) {
  for (int dim : {2, 3}) {
    SCOPED_TRACE(dim);
    const Cloud c = ball_cloud(dim, dim == 2 ? 700 : 1500, 12 + dim, dim == 2);
    const double h = 0.8;  // the box [-h, h]^d cuts into the ball of radius 0.9
    Cloud in_box = c;
    for (auto& y : in_box.x)
      for (int k = 0; k < dim; ++k) y[k] = std::clamp(y[k], -0.97 * h, 0.97 * h);
    std::vector<MirrorWallPtr> planes;
    for (int k = 0; k < dim; ++k) {
      Vec3 n = Vec3::Zero();
      n[k] = 1.0;
      planes.push_back(make_plane_wall(h * n, n));
      planes.push_back(make_plane_wall(-h * n, -n));
    }
    DomainPtr box = make_box(dim, Vec3::Constant(-h), Vec3::Constant(h));
    for (Split split : {Split::Slabs, Split::Random})
      expect_round_off(compare(in_box, split, dim == 2, Barrier(box, 100.0), Periodicity::none(dim), {0.05, 2.0},
                               planes));
    const std::vector<MirrorWallPtr> sphere{make_sphere_wall(dim, Vec3::Zero(), 0.93)};
    DomainPtr ball = make_ball(dim, Vec3::Zero(), 0.93);
    for (Split split : {Split::Slabs, Split::Random})
      expect_round_off(compare(c, split, dim == 2, Barrier(ball, 100.0), Periodicity::none(dim), {0.05, 2.0}, sphere));
    // An obstacle (the domain outside a ball): its images bring blobs nearer
    // the far side, and the ghosts reach three list radii.
    Cloud around = c;
    for (auto& y : around.x)
      if (y.norm() < 0.25) y = (0.25 + 0.5 * y.norm()) * (y.norm() > 0.0 ? Vec3(y / y.norm()) : Vec3::UnitX());
    const std::vector<MirrorWallPtr> obstacle{make_sphere_wall(dim, Vec3::Zero(), 0.2, WallSide::DomainOutside)};
    for (Split split : {Split::Slabs, Split::Random})
      expect_round_off(compare(around, split, dim == 2, Barrier(), Periodicity::none(dim), {0.05, 2.0}, obstacle));
  }
}

// Force (27)'s velocity over the ranks (explicit_velocity: rho and grad rho
// at the owned particles from own, ghost and image blobs) against the
// serial Functional's, on slabs and on random assignments, with the sphere
// wall of a reservoir band's back face and a barrier: at the reference (a
// new ghost set), at positions moved by 0.05 widths (the ghosts kept, their
// positions sent again) and after a shift of 2 widths.
TEST(DistributedFunctional, ExplicitVelocityMatchesSerial) {
  for (int dim : {2, 3}) {
    SCOPED_TRACE(dim);
    Cloud c = ball_cloud(dim, dim == 2 ? 700 : 1500, 21 + dim, false);
    const std::vector<MirrorWallPtr> sphere{make_sphere_wall(dim, Vec3::Zero(), 0.93)};
    const Barrier barrier(make_ball(dim, Vec3::Zero(), 0.93), 100.0);
    for (Split split : {Split::Slabs, Split::Random}) {
      const std::vector<int> owner = owners(c, split, 99);
      Functional serial(dim, options(false), barrier, Periodicity::none(dim));
      DistributedFunctional dist(dim, options(false), barrier, Periodicity::none(dim));
      serial.set_images(WallImages(sphere));
      dist.set_images(WallImages(sphere));
      Cloud moved = c;
      for (double shift : {0.0, 0.05, 2.0}) {
        displace(moved, shift);
        if (shift != 0.05) {
          serial.set_reference(moved.x, moved.s, moved.m);
          dist.set_reference(mine(moved.x, owner), mine(moved.s, owner), mine(moved.m, owner));
        }
        const int builds = dist.exchange().rebuilds;
        std::vector<Vec3> vs, vd;
        serial.explicit_velocity(moved.x, moved.s, vs);
        dist.explicit_velocity(mine(moved.x, owner), mine(moved.s, owner), vd);
        double scale = 0.0, diff = 0.0;
        std::size_t i = 0;
        for (std::size_t p = 0; p < moved.x.size(); ++p) {
          scale = std::max(scale, vs[p].norm());
          if (owner[p] != world_rank()) continue;
          diff = std::max(diff, (vd[i] - vs[p]).norm());
          ++i;
        }
        EXPECT_EQ(i, vd.size());
        double rel = diff / scale;
        MPI_Allreduce(MPI_IN_PLACE, &rel, 1, MPI_DOUBLE, MPI_MAX, MPI_COMM_WORLD);
        if (world_rank() == 0)
          std::printf("  %d ranks, d = %d: max |v - v_serial| / max |v_serial| = %.2g\n", world_size(), dim, rel);
        // Round-off (2e-16 to 4e-16 measured), except where a pair between
        // r_c and r_c + skin is in one list and not the other: a kernel
        // value below the tolerance (1e-8), which grad rho / rho magnifies
        // at the cloud's thin edge (measured once 2.4e-11, 3 ranks, 3-D).
        EXPECT_LT(rel, 1e-9);
        EXPECT_EQ(dist.exchange().rebuilds - builds, shift == 0.05 ? 0 : 1) << "shift " << shift;
      }
    }
  }
}

// Slabs are local: a rank's ghosts are a fraction of the others' particles,
// and the exchange is counted.
TEST(DistributedFunctional, SlabGhostsAreAFractionOfTheCloud) {
  const Cloud c = ball_cloud(3, 4000, 8, false);
  const std::vector<int> owner = partition_slabs(c.x, 0, world_size());
  DistributedFunctional dist(3, options(false));
  dist.set_reference(mine(c.x, owner), mine(c.s, owner), mine(c.m, owner));
  Gradient g;
  dist.evaluate(mine(c.x, owner), mine(c.s, owner), &g);
  const ExchangeStats& st = dist.exchange();
  EXPECT_EQ(st.rebuilds, 1);
  EXPECT_EQ(st.evaluations, 1);
  const std::size_t others = c.x.size() - dist.owned();
  if (world_size() == 1) {
    EXPECT_EQ(st.ghosts, 0u);
  } else {
    EXPECT_GT(st.ghosts, 0u);
    EXPECT_LT(static_cast<double>(st.ghosts), 0.7 * static_cast<double>(others));
    EXPECT_GT(st.bytes_sent, 0.0);
  }
}

TEST(DistributedFunctional, PartitionSlabsBalancesCounts) {
  Cloud c = ball_cloud(3, 1001, 9, false);
  for (int ranks : {1, 2, 3, 7}) {
    const std::vector<int> o = partition_slabs(c.x, 1, ranks);
    std::vector<int> count(static_cast<std::size_t>(ranks), 0);
    for (int r : o) ++count[static_cast<std::size_t>(r)];
    const auto [lo, hi] = std::minmax_element(count.begin(), count.end());
    EXPECT_LE(*hi - *lo, 1) << ranks << " ranks";
    // Ordered along the axis: a lower rank's particles lie below a higher rank's.
    for (std::size_t p = 0; p < c.x.size(); ++p)
      for (std::size_t q = 0; q < c.x.size(); q += 37)
        if (o[p] < o[q]) {
          EXPECT_LE(c.x[p][1], c.x[q][1]);
        }
  }
}

// ---------------------------------------------------------------- migration

// Particles given to ranks at random move to a balanced layout: none is lost
// or repeated, each lands on the rank of its region with its width, mass,
// birth time and id, the counts are equal to one particle per cut, and F
// over the new layout is the serial F.
void expect_migration_keeps_every_particle(bool bisection) {
  const Cloud c = ball_cloud(3, 2000, 31, true);
  Rng birth_rng(4);
  std::vector<double> birth(c.x.size());
  for (auto& b : birth) b = birth_rng.uniform();
  const std::vector<int> random_owner = owners(c, Split::Random, 77);
  ParticleSet mine_set(3);
  for (std::size_t p = 0; p < c.x.size(); ++p)
    if (random_owner[p] == world_rank())
      mine_set.add_with_id(static_cast<ParticleId>(p), c.x[p], c.s[p], c.m[p], birth[p]);

  SlabLayout slabs;
  BisectionLayout tree;
  if (bisection)
    tree = balanced_bisection(mine_set.positions(), 3);
  else
    slabs = balanced_slabs(mine_set.positions(), 0);
  const Layout& layout = bisection ? static_cast<const Layout&>(tree) : slabs;
  ASSERT_EQ(layout.ranks(), world_size());
  const std::size_t sent = migrate(mine_set, layout);
  if (world_size() == 1) {
    EXPECT_EQ(sent, 0u);
  }

  int count = static_cast<int>(mine_set.size()), lo = count, hi = count, total = count;
  MPI_Allreduce(MPI_IN_PLACE, &lo, 1, MPI_INT, MPI_MIN, MPI_COMM_WORLD);
  MPI_Allreduce(MPI_IN_PLACE, &hi, 1, MPI_INT, MPI_MAX, MPI_COMM_WORLD);
  MPI_Allreduce(MPI_IN_PLACE, &total, 1, MPI_INT, MPI_SUM, MPI_COMM_WORLD);
  EXPECT_EQ(total, static_cast<int>(c.x.size()));
  EXPECT_LE(hi - lo, bisection ? 2 : 1);  // bisection: one particle per level of cuts
  // Every id once over the ranks.
  std::vector<int> seen(c.x.size(), 0);
  for (std::size_t i = 0; i < mine_set.size(); ++i) {
    const auto p = static_cast<std::size_t>(mine_set.ids()[i]);
    ASSERT_LT(p, c.x.size());
    ++seen[p];
    EXPECT_EQ(layout.owner(mine_set.positions()[i]), world_rank());
    EXPECT_EQ(mine_set.positions()[i], c.x[p]);
    EXPECT_EQ(mine_set.widths()[i], c.s[p]);
    EXPECT_EQ(mine_set.masses()[i], c.m[p]);
    EXPECT_EQ(mine_set.birth_times()[i], birth[p]);
  }
  MPI_Allreduce(MPI_IN_PLACE, seen.data(), static_cast<int>(seen.size()), MPI_INT, MPI_SUM, MPI_COMM_WORLD);
  EXPECT_EQ(std::count(seen.begin(), seen.end(), 1), static_cast<long>(c.x.size()));

  Functional serial(3, options(false));
  serial.set_reference(c.x, c.s, c.m);
  DistributedFunctional dist(3, options(false));
  dist.set_reference(mine_set.positions(), mine_set.widths(), mine_set.masses());
  const double fs = serial.evaluate(c.x, c.s, nullptr).total();
  const double fd = dist.evaluate(mine_set.positions(), mine_set.widths(), nullptr).total();
  EXPECT_LT(std::abs(fd - fs), 1e-12 * std::abs(fs));
}

TEST(Decomposition, MigrationToBalancedSlabsKeepsEveryParticle) { expect_migration_keeps_every_particle(false); }
TEST(Decomposition, MigrationToABalancedBisectionKeepsEveryParticle) { expect_migration_keeps_every_particle(true); }

// The bisection cuts the longest side of each node's box: a cloud twice as
// long in y as in x and z is cut across y first; the leaves' shares are equal.
TEST(Decomposition, BisectionCutsTheLongestSideIntoEqualShares) {
  Rng rng(12);
  std::vector<Vec3> all(3000);
  for (auto& y : all) y = Vec3(rng.uniform(), 2.0 * rng.uniform(), rng.uniform());
  std::vector<Vec3> mine_x;
  for (std::size_t p = 0; p < all.size(); ++p)
    if (static_cast<int>(p % static_cast<std::size_t>(world_size())) == world_rank()) mine_x.push_back(all[p]);
  const BisectionLayout tree = balanced_bisection(mine_x, 3);
  EXPECT_EQ(tree.ranks(), world_size());
  if (world_size() > 1) {
    EXPECT_EQ(tree.nodes[0].axis, 1);
  }
  std::vector<int> count(static_cast<std::size_t>(world_size()), 0);
  for (const Vec3& y : all) ++count[static_cast<std::size_t>(tree.owner(y))];
  for (int r = 0; r < world_size(); ++r)
    EXPECT_NEAR(count[static_cast<std::size_t>(r)], static_cast<double>(all.size()) / world_size(), 2.0) << r;
}

TEST(Decomposition, BisectionOwnerDescendsTheTree) {
  BisectionLayout tree;
  tree.nodes.resize(5);
  tree.nodes[0] = {0, 0.5, 1, 2, -1};   // x < 0.5: node 1 (rank 0); else node 2
  tree.nodes[1] = {0, 0.0, -1, -1, 0};
  tree.nodes[2] = {2, 0.25, 3, 4, -1};  // z < 0.25: rank 1; else rank 2
  tree.nodes[3] = {0, 0.0, -1, -1, 1};
  tree.nodes[4] = {0, 0.0, -1, -1, 2};
  EXPECT_EQ(tree.ranks(), 3);
  EXPECT_EQ(tree.owner(Vec3(0.1, 9.0, 9.0)), 0);
  EXPECT_EQ(tree.owner(Vec3(0.5, 0.0, 0.0)), 1);
  EXPECT_EQ(tree.owner(Vec3(0.9, 0.0, 0.25)), 2);
}

TEST(Decomposition, SlabOwnerFollowsTheCuts) {
  SlabLayout layout;
  layout.axis = 1;
  layout.cuts = {0.0, 0.5};
  EXPECT_EQ(layout.owner(Vec3(9.0, -1.0, 0.0)), 0);
  EXPECT_EQ(layout.owner(Vec3(0.0, 0.0, 0.0)), 1);  // a cut belongs to the slab above it
  EXPECT_EQ(layout.owner(Vec3(0.0, 0.49, 0.0)), 1);
  EXPECT_EQ(layout.owner(Vec3(0.0, 0.5, 0.0)), 2);
  EXPECT_EQ(layout.owner(Vec3(0.0, 7.0, 0.0)), 2);
}

// ---------------------------------------------------------------- the step

namespace {

ImplicitOptions tao_step_options(WidthMode widths) {
  ImplicitOptions o;
  o.minimizer.backend = Backend::Tao;
  o.width_mode = widths;
  o.kappa = 1.0;
  o.rho_ref = 1.0;
  o.sort_particles = false;  // the serial set keeps the global order, for the comparison
  return o;
}

struct StepComparison {
  double dx = 0.0;         // largest |x_dist - x_serial| over all particles, in widths
  double moved = 0.0;      // largest displacement of the serial steps, in widths
  double f_rel = 0.0;      // |F_after| difference, relative
  int serial_evaluations = 0, distributed_evaluations = 0;
  std::uint64_t serial_pairs = 0, distributed_pairs = 0;  // pair-kernel evaluations (all ranks')
  double list_seconds = 0.0;                              // the distributed steps' list builds
  int list_builds = 0;
  bool all_accepted = true;
  double estimate_rel = 0.0;  // largest relative difference of the error estimates (each measure)
  int estimates = 0;          // steps with an error estimate (finite on both)
};

// `steps` implicit Euler steps of a clustered ball (it spreads, so the ghost
// sets are rebuilt) by the serial TAO stepper and by the distributed one.
// The whole cloud as one set (in global order), this rank's share of it,
// and the global index of each of its particles.
struct SplitSets {
  ParticleSet serial, mine;
  std::vector<std::size_t> global;
};

SplitSets split_sets(const Cloud& c, const std::vector<int>& owner) {
  SplitSets out{ParticleSet(c.dim), ParticleSet(c.dim), {}};
  for (std::size_t p = 0; p < c.x.size(); ++p) {
    // One id per particle in both (the error estimate's probes are chosen by id).
    out.serial.add_with_id(static_cast<ParticleId>(p), c.x[p], c.s[p], c.m[p]);
    if (owner[p] == world_rank()) {
      out.mine.add_with_id(static_cast<ParticleId>(p), c.x[p], c.s[p], c.m[p]);
      out.global.push_back(p);
    }
  }
  return out;
}

// The largest distance, over all ranks, between a rank's particles and the
// same particles of the serial set, in widths s0.
double largest_difference(const SplitSets& sets, double s0) {
  double dx = 0.0;
  for (std::size_t i = 0; i < sets.global.size(); ++i)
    dx = std::max(dx, (sets.mine.positions()[i] - sets.serial.positions()[sets.global[i]]).norm() / s0);
  MPI_Allreduce(MPI_IN_PLACE, &dx, 1, MPI_DOUBLE, MPI_MAX, MPI_COMM_WORLD);
  return dx;
}

StepComparison compare_steps(int dim, std::size_t n, WidthMode widths, int steps, Split split,
                              const std::function<void(ImplicitOptions&)>& tweak = {}) {
  register_tao_backend();
  Cloud c = ball_cloud(dim, n, 21, widths == WidthMode::PerParticle);
  for (auto& y : c.x) y *= 0.6;  // a dense core: F moves the particles by several widths
  DomainPtr ball = make_ball(dim, Vec3::Zero(), 1.0);
  SplitSets sets = split_sets(c, owners(c, split, 5));
  ParticleSet& serial = sets.serial;
  ParticleSet& mine_set = sets.mine;
  const double s0 = c.s[0];
  const double dt = 2.0 * s0 * s0;  // a few times the explicit limit
  ImplicitOptions o = tao_step_options(widths);
  if (tweak) tweak(o);
  ImplicitStepper one(dim, o, Barrier(ball, 100.0));
  DistributedImplicitStepper many(dim, o, Barrier(ball, 100.0));
  StepComparison r;
  const std::vector<Vec3> start = serial.positions();
  for (int k = 0; k < steps; ++k) {
    const StepSummary a = one.step(serial, dt);
    const StepSummary b = many.step(mine_set, dt);
    r.all_accepted = r.all_accepted && a.accepted && b.accepted;
    r.serial_evaluations += a.evaluations;
    r.distributed_evaluations += b.evaluations;
    r.serial_pairs += a.pair_evaluations;
    r.distributed_pairs += b.pair_evaluations;
    r.list_seconds += b.list_seconds;
    r.list_builds += b.list_builds;
    r.f_rel = std::max(r.f_rel, std::abs(a.f_after - b.f_after) / std::abs(a.f_after));
    const double ea[4] = {a.error_estimate, a.displacement_error_estimate, a.density_error_estimate,
                          a.particle_error_estimate};
    const double eb[4] = {b.error_estimate, b.displacement_error_estimate, b.density_error_estimate,
                          b.particle_error_estimate};
    for (int i = 0; i < 4; ++i) {
      EXPECT_EQ(std::isfinite(ea[i]), std::isfinite(eb[i])) << "step " << k << ", estimate " << i;
      if (std::isfinite(ea[i]) && std::isfinite(eb[i]))
        r.estimate_rel = std::max(r.estimate_rel, std::abs(ea[i] - eb[i]) / std::abs(ea[i]));
    }
    if (std::isfinite(ea[0]) && std::isfinite(eb[0])) ++r.estimates;
    EXPECT_EQ(a.bdf2_particles, b.bdf2_particles);
    EXPECT_EQ(a.predicted_particles, b.predicted_particles);
  }
  r.dx = largest_difference(sets, s0);
  for (std::size_t p = 0; p < c.x.size(); ++p) r.moved = std::max(r.moved, (serial.positions()[p] - start[p]).norm() / s0);
  if (world_rank() == 0)
    std::printf("  %d ranks, %d-D, %d steps: particles moved up to %.3g widths; distributed - serial: %.2g widths, "
                "F %.2g, error estimates %.2g (%d steps with one); evaluations %d (serial) and %d (distributed), "
                "pair evaluations %llu and %llu, %d list builds in %.3g s\n",
                world_size(), dim, steps, r.moved, r.dx, r.f_rel, r.estimate_rel, r.estimates, r.serial_evaluations,
                r.distributed_evaluations, static_cast<unsigned long long>(r.serial_pairs),
                static_cast<unsigned long long>(r.distributed_pairs), r.list_builds, r.list_seconds);
  return r;
}

// The same iterations on every rank count; the reductions' order differs
// from the serial sums, and the solver's iterations amplify that round-off.
// Measured (1-3 ranks): fixed widths 1e-13 to 1.3e-12 widths and F 3e-15;
// per-particle widths (3 steps of ~55 LMVM iterations in worse-conditioned
// unknowns) 2e-8 to 4e-8 widths and F 5e-11. Both are 1e4 and more below the
// solver's own tolerance (1e-3 widths): the two runs solve the same problem
// with the same optimiser.
void expect_same_steps(const StepComparison& r, double dx_bound, double f_bound) {
  EXPECT_TRUE(r.all_accepted);
  EXPECT_GT(r.moved, 0.5) << "the steps must move the particles";
  EXPECT_EQ(r.serial_evaluations, r.distributed_evaluations);
  EXPECT_LT(r.dx, dx_bound);
  EXPECT_LT(r.f_rel, f_bound);
  // The summaries count the work: on one rank the serial stepper's pair
  // evaluations exactly; on more, also the ghost rows' pairs with own
  // particles (measured 8-32% more on 2-3 ranks).
  if (world_size() == 1)
    EXPECT_EQ(r.serial_pairs, r.distributed_pairs);
  else
    EXPECT_GT(r.distributed_pairs, r.serial_pairs);
  EXPECT_GT(r.list_builds, 0);
  EXPECT_GT(r.list_seconds, 0.0);
}

}  // namespace

TEST(DistributedImplicitStepper, MatchesTheSerialTaoStep3D) {
  expect_same_steps(compare_steps(3, 1200, WidthMode::Fixed, 3, Split::Slabs), 1e-10, 1e-12);
}

TEST(DistributedImplicitStepper, MatchesTheSerialTaoStep2DWithWidths) {
  expect_same_steps(compare_steps(2, 600, WidthMode::PerParticle, 3, Split::Slabs), 1e-6, 1e-9);
}

TEST(DistributedImplicitStepper, MatchesTheSerialTaoStepOnARandomAssignment) {
  expect_same_steps(compare_steps(2, 500, WidthMode::Fixed, 2, Split::Random), 1e-10, 1e-12);
}

// A run of several steps with the particles migrating between ranks after
// each (a new balanced bisection every step, as the counts drift): free-space
// spreading of a dense cloud, against the serial TAO run, particle by
// particle (by id).
TEST(DistributedImplicitStepper, StepsWithMigrationMatchTheSerialRun) {
  register_tao_backend();
  const int dim = 3, steps = 5;
  Cloud c = ball_cloud(dim, 900, 41, false);
  for (auto& y : c.x) y *= 0.5;
  ParticleSet serial(dim), mine_set(dim);
  const std::vector<int> owner = owners(c, Split::Random, 3);
  for (std::size_t p = 0; p < c.x.size(); ++p) {
    serial.add_with_id(static_cast<ParticleId>(p), c.x[p], c.s[p], c.m[p]);
    if (owner[p] == world_rank()) mine_set.add_with_id(static_cast<ParticleId>(p), c.x[p], c.s[p], c.m[p]);
  }
  const double s0 = c.s[0], dt = 3.0 * s0 * s0;
  ImplicitStepper one(dim, tao_step_options(WidthMode::Fixed));
  DistributedImplicitStepper many(dim, tao_step_options(WidthMode::Fixed));
  std::size_t moved_between_ranks = 0;
  for (int k = 0; k < steps; ++k) {
    ASSERT_TRUE(one.step(serial, dt).accepted);
    ASSERT_TRUE(many.step(mine_set, dt).accepted);
    moved_between_ranks += migrate(mine_set, balanced_bisection(mine_set.positions(), dim));
  }
  unsigned long long sent = moved_between_ranks;
  MPI_Allreduce(MPI_IN_PLACE, &sent, 1, MPI_UNSIGNED_LONG_LONG, MPI_SUM, MPI_COMM_WORLD);
  if (world_size() > 1) {
    EXPECT_GT(sent, 0u) << "the first migration sends the random assignment's particles to their regions";
  }
  double dx = 0.0, spread = 0.0;
  for (std::size_t i = 0; i < mine_set.size(); ++i) {
    const auto p = static_cast<std::size_t>(mine_set.ids()[i]);
    dx = std::max(dx, (mine_set.positions()[i] - serial.positions()[p]).norm() / s0);
  }
  for (std::size_t p = 0; p < c.x.size(); ++p) spread = std::max(spread, (serial.positions()[p] - c.x[p]).norm() / s0);
  MPI_Allreduce(MPI_IN_PLACE, &dx, 1, MPI_DOUBLE, MPI_MAX, MPI_COMM_WORLD);
  if (world_rank() == 0)
    std::printf("  %d ranks, %d steps with migration (%llu particles moved between ranks): particles moved up to "
                "%.3g widths; distributed - serial: %.2g widths\n",
                world_size(), steps, sent, spread, dx);
  EXPECT_GT(spread, 1.0);
  // Measured with 2 and 3 ranks: 2.2e-10 widths (1.4e-11 in length, 3e-11 of
  // the cloud's radius): the reductions' round-off, amplified over five
  // solves, 1e6 below the solver's tolerance (1e-3 widths).
  EXPECT_LT(dx, 1e-8);
}

// A solve that fails is retried as 2, 4, ... substeps, as the serial
// stepper does, with the same outcome (here the evaluation cap is below
// what the whole step needs and above what its halves need, as a serial
// probe finds); and accepted
// positions are wrapped into the periodic box (a cloud next to the face
// x = 1 spreads across it).
TEST(DistributedImplicitStepper, HalvesAFailedStepAndWrapsAsTheSerialStepperDoes) {
  register_tao_backend();
  const int dim = 2;
  const Cloud c = periodic_cloud(dim, 600, 31);
  Periodicity per = Periodicity::none(dim);
  for (int k = 0; k < dim; ++k) per.period[k] = 1.0;
  ParticleSet serial(dim), mine_set(dim);
  const std::vector<int> owner = owners(c, Split::Slabs, 0);
  std::vector<Vec3> start;
  for (std::size_t p = 0; p < c.x.size(); ++p) {
    Vec3 y = c.x[p];
    y[0] = 0.85 + 0.25 * (y[0] - 0.5);  // [0.725, 0.975)
    start.push_back(y);
    serial.add_with_id(static_cast<ParticleId>(p), y, c.s[p], c.m[p]);
    if (owner[p] == world_rank()) mine_set.add_with_id(static_cast<ParticleId>(p), y, c.s[p], c.m[p]);
  }
  const double dt = 10.0 * c.s[0] * c.s[0];
  ImplicitOptions o = tao_step_options(WidthMode::Fixed);
  o.max_halvings = 3;
  {
    // The cap halfway between what the whole step and its halves need (a
    // serial probe), so that round-off moving a count by a few cannot
    // decide the outcome.
    ParticleSet whole_set = serial, half_set = serial;
    ImplicitStepper whole(dim, o, Barrier(), per), halves(dim, o, Barrier(), per);
    const StepSummary full = whole.step(whole_set, dt);
    const StepSummary h1 = halves.step(half_set, 0.5 * dt);
    const StepSummary h2 = halves.step(half_set, 0.5 * dt);
    ASSERT_TRUE(full.accepted && full.halvings == 0 && h1.accepted && h2.accepted);
    const int half_need = std::max(h1.evaluations, h2.evaluations);
    ASSERT_GE(full.evaluations - half_need, 8) << full.evaluations << " against " << half_need;
    o.minimizer.max_evaluations = (full.evaluations + half_need) / 2;
  }
  ImplicitStepper one(dim, o, Barrier(), per);
  DistributedImplicitStepper many(dim, o, Barrier(), per);
  int halvings = 0;
  for (int k = 0; k < 4; ++k) {
    const StepSummary a = one.step(serial, dt);
    const StepSummary b = many.step(mine_set, dt);
    ASSERT_TRUE(a.accepted && b.accepted) << "step " << k;
    EXPECT_EQ(a.halvings, b.halvings) << "step " << k;
    EXPECT_EQ(a.rejected_solves, b.rejected_solves) << "step " << k;
    halvings += b.halvings;
  }
  EXPECT_GT(halvings, 0) << "the cap must make the first step halve";
  long long wrapped = 0;  // particles that crossed the face x = 1 (their x fell by more than half the box)
  for (std::size_t p = 0; p < serial.size(); ++p)
    if (start[static_cast<std::size_t>(serial.ids()[p])][0] - serial.positions()[p][0] > 0.5) ++wrapped;
  double dx = 0.0;
  bool inside = true;
  for (std::size_t i = 0; i < mine_set.size(); ++i) {
    const Vec3& y = mine_set.positions()[i];
    for (int k = 0; k < dim; ++k) inside = inside && y[k] >= 0.0 && y[k] < 1.0;
    const std::ptrdiff_t p = serial.index_of(mine_set.ids()[i]);
    dx = std::max(dx, per.displacement(y, serial.positions()[static_cast<std::size_t>(p)]).norm());
  }
  MPI_Allreduce(MPI_IN_PLACE, &dx, 1, MPI_DOUBLE, MPI_MAX, MPI_COMM_WORLD);
  EXPECT_TRUE(inside);
  EXPECT_GT(wrapped, 0) << "some particles must have crossed the face";
  // These steps take 100-300 LMVM iterations (a crowded cloud, 10 explicit
  // steps long): the order of the sums changes the iterates enough for the
  // two solves to stop at different points within the stopping rule's
  // resolution (1e-3 widths). Measured: 0 (1 rank), 3e-3 and 5e-3 widths
  // (2 and 3 ranks). The bound: the rule's resolution, 1e-2 widths.
  const double s0 = c.s[0];
  EXPECT_LT(dx, 1e-2 * s0);
  if (world_rank() == 0)
    std::printf("  %d ranks: %d halvings in 4 steps, %lld particles wrapped; distributed - serial %.2g widths\n",
                world_size(), halvings, wrapped, dx / s0);
}

// Ranks with no particles, and a rank whose only particle is too far from
// the others to move (its gradient is exactly zero: its unknowns do not
// change between evaluations), still take part in every collective: the
// first hung in the first version (a null gradient pointer meant "value
// only" on the empty rank), the second deadlocked on the evaluation cache
// (found by review). Both now end as the serial step does.
TEST(DistributedImplicitStepper, EmptyAndStillRanksTakePartInTheSolve) {
  register_tao_backend();
  const int dim = 2;
  Cloud c = ball_cloud(dim, 300, 51, false);
  for (auto& y : c.x) y *= 0.5;
  // One far-away particle, its kernel beyond every cut-off.
  c.x.push_back(Vec3(50.0, 50.0, 0.0));
  c.s.push_back(c.s[0]);
  c.m.push_back(c.m[0]);
  const std::size_t far = c.x.size() - 1;
  for (int layout = 0; layout < 2; ++layout) {
    SCOPED_TRACE(layout == 0 ? "everything on rank 0" : "the far particle alone on the last rank");
    std::vector<int> owner(c.x.size(), 0);
    if (layout == 1) owner[far] = world_size() - 1;
    SplitSets sets = split_sets(c, owner);
    ParticleSet& serial = sets.serial;
    ParticleSet& mine_set = sets.mine;
    const double dt = 2.0 * c.s[0] * c.s[0];
    ImplicitStepper one(dim, tao_step_options(WidthMode::Fixed));
    DistributedImplicitStepper many(dim, tao_step_options(WidthMode::Fixed));
    const StepSummary a = one.step(serial, dt);
    const StepSummary b = many.step(mine_set, dt);
    EXPECT_TRUE(a.accepted) << a.message;
    EXPECT_TRUE(b.accepted) << b.message;
    EXPECT_EQ(a.evaluations, b.evaluations);
    const double dx = largest_difference(sets, c.s[0]);
    EXPECT_LT(dx, 1e-9);
    if (owner[far] == world_rank()) {
      EXPECT_EQ(mine_set.positions()[mine_set.size() - 1], c.x[far]) << "the far particle has nothing to move it";
    }
  }
}

// The evaluation cap ends a shared solve on every rank at the same
// evaluation: the step is refused (MaxEvaluations) everywhere, the particles
// stay, and the next step runs.
TEST(DistributedImplicitStepper, TheEvaluationCapEndsTheSolveOnEveryRank) {
  register_tao_backend();
  Cloud c = ball_cloud(2, 400, 61, false);
  for (auto& y : c.x) y *= 0.5;
  const std::vector<int> owner = owners(c, Split::Slabs, 0);
  ParticleSet mine_set(2);
  for (std::size_t p = 0; p < c.x.size(); ++p)
    if (owner[p] == world_rank()) mine_set.add(c.x[p], c.s[p], c.m[p]);
  const std::vector<Vec3> before = mine_set.positions();
  ImplicitOptions o = tao_step_options(WidthMode::Fixed);
  o.minimizer.max_evaluations = 4;
  DistributedImplicitStepper capped(2, o);
  const StepSummary s = capped.step(mine_set, 3.0 * c.s[0] * c.s[0]);
  EXPECT_FALSE(s.accepted);
  EXPECT_EQ(s.reason, TerminationReason::MaxEvaluations) << s.message;
  EXPECT_EQ(mine_set.positions(), before);
  DistributedImplicitStepper free_to_run(2, tao_step_options(WidthMode::Fixed));
  EXPECT_TRUE(free_to_run.step(mine_set, 3.0 * c.s[0] * c.s[0]).accepted);
}

// A width above the bound on one rank only: every rank throws, none waits.
TEST(DistributedImplicitStepper, ARefusalOnOneRankIsEveryRanks) {
  register_tao_backend();
  ImplicitOptions o = tao_step_options(WidthMode::PerParticle);
  o.max_width_factor = 2.0;
  o.nominal_width = 0.1;
  DistributedImplicitStepper many(2, o);
  ParticleSet mine_set(2);
  Rng rng(static_cast<std::uint64_t>(world_rank()) + 3);
  for (int i = 0; i < 20; ++i) mine_set.add(Vec3(rng.uniform(), rng.uniform(), 0.0), 0.1, 0.05);
  if (world_rank() == world_size() - 1) mine_set.widths()[0] = 0.5;  // above 2 x 0.1
  EXPECT_THROW(many.step(mine_set, 1e-3), InvalidArgument);
  mine_set.widths()[0] = 0.1;
  EXPECT_TRUE(many.step(mine_set, 1e-3).accepted);
}

TEST(DistributedImplicitStepper, RefusesABackendOtherThanTao) {
  ImplicitOptions o = tao_step_options(WidthMode::Fixed);
  o.minimizer.backend = Backend::Ceres;
  try {
    DistributedImplicitStepper s(3, o);
    ADD_FAILURE() << "the Ceres backend was accepted";
  } catch (const InvalidArgument& e) {
    EXPECT_NE(std::string(e.what()).find("minimizer.backend"), std::string::npos) << e.what();
  }
}

// Variational BDF2 with the damped predictor, and the local error estimate
// (both measures are computed every step; Milne's device needs the history
// of each particle): the steps, their error estimates, the BDF2 and
// predicted counts equal the serial TAO stepper's. The density estimate's
// probes are chosen by id, its blobs within the smoothed kernel's reach
// sent between ranks; the displacement estimate's smoothing takes the
// ghosts' errors from their owners.
TEST(DistributedImplicitStepper, Bdf2PredictorAndErrorEstimatesMatchTheSerialStepper) {
  for (ErrorMeasure measure : {ErrorMeasure::Displacement, ErrorMeasure::Density}) {
    SCOPED_TRACE(to_string(measure));
    const StepComparison r = compare_steps(3, 1200, WidthMode::Fixed, 4, Split::Slabs, [&](ImplicitOptions& o) {
      o.time_scheme = TimeScheme::Bdf2;
      o.predictor = Predictor::Damped;
      o.error_measure = measure;
    });
    expect_same_steps(r, 1e-9, 1e-12);
    EXPECT_GE(r.estimates, 2) << "BDF2's estimate needs two steps of history";
    // Measured (1-3 ranks): the estimates agree to about 1e-13 (the sums'
    // order): the same estimate, not an approximation of it.
    EXPECT_LT(r.estimate_rel, 1e-9);
  }
}

// With per-particle widths the positions agree to about 4e-8 widths (the
// reductions' round-off amplified by ~55 LMVM iterations a step, as in
// MatchesTheSerialTaoStep2DWithWidths), and the estimate, a difference of
// positions of about 1e-3 widths, inherits it: measured 1e-9 (2 ranks) and
// 3e-5 (3 ranks) relative. (On a random assignment the same steps end up to
// 9e-3 widths apart, the two solves taking 167 and 168-169 iterations: the
// round-off moves a stop across the tolerance; not compared here.)
TEST(DistributedImplicitStepper, EulerEstimateWithWidthsMatchesTheSerialStepper) {
  const StepComparison r = compare_steps(2, 600, WidthMode::PerParticle, 3, Split::Slabs, [](ImplicitOptions& o) {
    o.error_measure = ErrorMeasure::Density;
  });
  expect_same_steps(r, 1e-6, 1e-9);
  EXPECT_GE(r.estimates, 2);
  EXPECT_LT(r.estimate_rel, 1e-3);
}

// ---------------------------------------------------------------- whole runs
// A Simulation over the ranks (MpiDistribution) against the serial run with
// the same options (TAO, the converging preset: the odd quiet reservoir with
// image blobs at the band's back face and at the no-flux walls), from an
// empty domain: every step's diffusion, projection and migration, particle
// by particle (by id), the count and the ledger.
namespace {

struct RunComparison {
  double dx = 0.0;           // largest |x_dist - x_serial|, relative to the domain's size
  bool same_ids = false;     // the same particles (ids) in both
  std::int64_t n = 0;        // the serial run's count at the end
  std::int64_t inserted = 0, removed = 0;  // the serial ledger
  bool same_ledger = false;  // counts equal, masses to round-off
  std::int64_t migrated = 0, rebalances = 0, gathered = 0;
  std::int64_t source_inserted = 0, source_removed = 0;  // the serial ledger's
  int steps = 0;             // steps taken (the serial run's; adaptive: the distributed run's must equal it)
  double dt_rel = 0.0;       // adaptive: largest relative difference of a step's dt
  double dt_max = 0.0;       // adaptive: the serial run's largest step / the first
};

RunComparison compare_runs(const DomainPtr& domain, const std::vector<ConstantBoundaryData>& boundary,
                           std::int64_t n_inf, int steps, TreatmentPreset preset = TreatmentPreset::Converging,
                           double fill = 0.0, const std::function<void(SimulationOptions&)>& tweak = {},
                           bool adaptive = false) {
  register_tao_backend();
  const int dim = domain->dim();
  RunSetupOptions ro;
  ro.n_inf = n_inf;
  ro.treatment = treatment_preset(preset, dim);
  const RunSetup setup = setup_run(*domain, boundary, ro);
  SimulationOptions o = setup.options;
  o.implicit.minimizer.backend = Backend::Tao;
  if (tweak) tweak(o);
  Simulation serial(domain, boundary, o);
  auto distribution = std::make_shared<MpiDistribution>();
  Simulation dist(domain, boundary, o, distribution);
  // Filled at fill x g uniformly at random (0: empty); the ranks' shares a
  // round-robin split, which start() redistributes.
  ParticleSet filled(dim), share(dim);
  if (fill > 0.0) {
    Rng rng(17);
    const auto n = static_cast<std::size_t>(fill * boundary[0].value * domain->volume() / o.particle_mass);
    for (std::size_t p = 0; p < n; ++p) {
      const Vec3 y = domain->sample_interior(rng);
      filled.add(y, o.width_s, o.particle_mass);
      if (static_cast<int>(p % static_cast<std::size_t>(world_size())) == world_rank())
        share.add_with_id(static_cast<ParticleId>(p), y, o.width_s, o.particle_mass);
    }
    share.set_next_id(static_cast<ParticleId>(n));
  }
  serial.start(filled);
  dist.start(share);
  const double dt = setup.parameters.dt;
  RunComparison r;
  if (!adaptive) {
    for (int k = 1; k <= steps; ++k) {
      serial.advance_to(k * dt);
      dist.advance_to(k * dt);
    }
    r.steps = steps;
  } else {
    // Adaptive steps to `steps` dt from a first step of dt: every step's
    // length is the controller's answer to the global error estimate.
    serial.set_next_dt(dt);
    dist.set_next_dt(dt);
    const double t_end = steps * dt;
    while (serial.time() < t_end && r.steps < 200) {
      const SimulationStep a = serial.advance_adaptive(t_end);
      const SimulationStep b = dist.advance_adaptive(t_end);
      const double ha = a.t_end - a.t_start, hb = b.t_end - b.t_start;
      r.dt_rel = std::max(r.dt_rel, std::abs(ha - hb) / ha);
      r.dt_max = std::max(r.dt_max, ha / dt);
      EXPECT_EQ(a.error_rejections, b.error_rejections) << "step " << a.step;
      ++r.steps;
    }
    EXPECT_EQ(dist.step_count(), serial.step_count());
  }
  const ParticleSet a = serial.particles();
  const ParticleSet b = all_particles(dist.particles());
  r.n = static_cast<std::int64_t>(a.size());
  r.same_ids = a.size() == b.size();
  const Aabb box = domain->bounding_box();
  const double size = (box.hi - box.lo).norm();
  for (std::size_t p = 0; r.same_ids && p < a.size(); ++p) {
    const std::ptrdiff_t q = b.index_of(a.ids()[p]);
    if (q < 0) {
      r.same_ids = false;
      break;
    }
    r.dx = std::max(r.dx, (a.positions()[p] - b.positions()[static_cast<std::size_t>(q)]).norm() / size);
  }
  // The measures of the run, over all ranks (collective), against the serial ones.
  const Vec3 centre = 0.5 * (box.lo + box.hi);
  const StateMeasures ma = serial.measure(centre), mb = dist.measure(centre);
  EXPECT_EQ(ma.n_particles, mb.n_particles);
  EXPECT_EQ(ma.n_inside, mb.n_inside);
  EXPECT_EQ(ma.n_buffer, mb.n_buffer);
  EXPECT_NEAR(ma.mass_inside, mb.mass_inside, 1e-12 * ma.mass_total);
  EXPECT_NEAR(ma.polar_inertia, mb.polar_inertia, 1e-8 * ma.polar_inertia_total);
  EXPECT_NEAR(ma.mean_age, mb.mean_age, 1e-12 * (ma.max_age + 1.0));
  EXPECT_EQ(ma.max_age, mb.max_age);
  EXPECT_NEAR(serial.blob_mass(), dist.blob_mass(), 1e-8 * ma.mass_total);
  const SimulationLedger& la = serial.ledger();
  const SimulationLedger& lb = dist.ledger();
  r.inserted = la.inserted;
  r.removed = la.removed;
  r.source_inserted = la.source_inserted;
  r.source_removed = la.source_removed;
  r.same_ledger = la.inserted == lb.inserted && la.removed == lb.removed && la.reflected == lb.reflected &&
                  la.source_inserted == lb.source_inserted && la.source_removed == lb.source_removed &&
                  la.initial_particles == lb.initial_particles &&
                  std::abs(la.mass_inserted - lb.mass_inserted) <= 1e-12 * la.mass_inserted &&
                  std::abs(la.mass_removed - lb.mass_removed) <= 1e-12 * std::max(la.mass_removed, 1e-300);
  if (!r.same_ledger && world_rank() == 0)
    std::printf("  ledger: inserted %lld / %lld, removed %lld / %lld, reflected %lld / %lld, initial %lld / %lld, "
                "mass inserted %.17g / %.17g, removed %.17g / %.17g\n",
                static_cast<long long>(la.inserted), static_cast<long long>(lb.inserted),
                static_cast<long long>(la.removed), static_cast<long long>(lb.removed),
                static_cast<long long>(la.reflected), static_cast<long long>(lb.reflected),
                static_cast<long long>(la.initial_particles), static_cast<long long>(lb.initial_particles),
                la.mass_inserted, lb.mass_inserted, la.mass_removed, lb.mass_removed);
  r.migrated = distribution->stats().migrated_out;
  MPI_Allreduce(MPI_IN_PLACE, &r.migrated, 1, MPI_INT64_T, MPI_SUM, MPI_COMM_WORLD);
  r.rebalances = distribution->stats().rebalances;
  r.gathered = distribution->stats().gathered;
  if (world_rank() == 0)
    std::printf("  %d ranks, %d steps (largest dt %.3g x the first, dt differs by %.2g): %lld particles (+%lld "
                "-%lld), %lld gathered for the last projection, %lld migrated, %lld rebalances; distributed - serial: "
                "%.2g of the domain's size\n",
                world_size(), r.steps, r.dt_max, r.dt_rel, static_cast<long long>(r.n), static_cast<long long>(r.inserted),
                static_cast<long long>(r.removed), static_cast<long long>(r.gathered),
                static_cast<long long>(r.migrated), static_cast<long long>(r.rebalances), r.dx);
  return r;
}

void expect_same_run(const RunComparison& r, double dx_bound = 1e-9) {
  EXPECT_TRUE(r.same_ids);
  EXPECT_TRUE(r.same_ledger);
  EXPECT_GT(r.inserted, 0);
  // Measured over 10 steps (1-3 ranks): 4e-15 to 2.8e-10 of the domain's
  // size, where the serial run stored in another order (not sorted
  // spatially) differed from itself by 3e-14 to 8.8e-12 (measured
  // 2026-12-02, no longer run: it cost a third of the suite): the order of
  // the sums, amplified by ~15 LMVM iterations a step; 1e4 below the
  // solver's tolerance (1e-3 widths).
  EXPECT_LT(r.dx, dx_bound);
  if (world_size() > 1) {
    EXPECT_GT(r.migrated, 0);
  }
}

}  // namespace

// From an empty ball: after step 1 the band sheds ~300 particles, and the
// solve of step 2 amplifies any round-off difference some 350-550x (the
// serial run, its particles stored unsorted against sorted: 3.8e-13 -> 2.1e-10
// of the domain's size; 2 ranks against 1: 2e-10 -> 7e-8); with the
// stopping rule's bound on the largest particle at 10 instead of 100 it
// stopped elsewhere and amplified 130x and 25x (1.2e-10 -> 3e-9 on 2 ranks;
// measured 2026-12-03; docs/distributed.md). So the bound here is 1e-7:
// still 360x below the solver's resolution (1e-3 widths = 3.6e-5 of the size).
TEST(DistributedSimulation, SphereMatchesTheSerialTaoRun) {
  const DomainPtr ball = make_ball(3, Vec3::Zero(), 1.0);
  expect_same_run(compare_runs(ball, {{0, PatchKind::Dirichlet, 0.238732}}, 400, 10), 1e-7);
}

// The papers' layer: random insertions and deletions (by id), the same
// random numbers on every rank.
TEST(DistributedSimulation, PapersLayerMatchesTheSerialTaoRun) {
  const DomainPtr ball = make_ball(3, Vec3::Zero(), 1.0);
  const RunComparison r =
      compare_runs(ball, {{0, PatchKind::Dirichlet, 0.238732}}, 400, 10, TreatmentPreset::Papers, 1.3);
  expect_same_run(r);
  EXPECT_GT(r.removed, 0);
}

// Filled at g: the projection reads the particles near the Dirichlet face
// only, the rest stay on their ranks.
TEST(DistributedSimulation, BoxMatchesTheSerialTaoRun) {
  const DomainPtr box = make_box(3, Vec3::Zero(), Vec3(2.0, 1.0, 1.0));
  const RunComparison r = compare_runs(box, {{0, PatchKind::Dirichlet, 500.0}}, 400, 10, TreatmentPreset::Converging, 1.0);
  expect_same_run(r);
  EXPECT_LT(r.gathered, r.n);
}

// Adaptive steps with variational BDF2 and the damped predictor (the
// history of each particle moves with it between ranks, and a step's length
// follows the global error estimate): the same steps, the same lengths and
// the same particles as the serial run.
TEST(DistributedSimulation, AdaptiveBdf2MatchesTheSerialTaoRun) {
  const DomainPtr box = make_box(3, Vec3::Zero(), Vec3(2.0, 1.0, 1.0));
  for (ErrorMeasure measure : {ErrorMeasure::Density, ErrorMeasure::Displacement}) {
    SCOPED_TRACE(to_string(measure));
    const RunComparison r = compare_runs(
        box, {{0, PatchKind::Dirichlet, 500.0}}, 400, 12, TreatmentPreset::Converging, 1.0,
        [&](SimulationOptions& o) {
          o.implicit.time_scheme = TimeScheme::Bdf2;
          o.implicit.predictor = Predictor::Damped;
          o.implicit.error_measure = measure;
          o.time_control.tolerance = 1e-2;
        },
        true);
    expect_same_run(r);
    EXPECT_GT(r.dt_max, 1.5) << "the controller must have grown dt";
    EXPECT_LT(r.dt_rel, 1e-6);
  }
}

// A volumetric source (sink here: rate < 0 removes particles; > 0 copies
// them): each particle's draws come from its own stream keyed by its id and
// the step, and copies are numbered in their parents' id order, so the
// distributed run removes and copies the same particles as the serial run.
TEST(DistributedSimulation, AVolumetricSourceMatchesTheSerialTaoRun) {
  const DomainPtr box = make_box(3, Vec3::Zero(), Vec3(2.0, 1.0, 1.0));
  for (double rate : {-3.0, 3.0}) {
    SCOPED_TRACE(rate);
    const RunComparison r = compare_runs(box, {{0, PatchKind::Dirichlet, 500.0}}, 400, 6,
                                         TreatmentPreset::Converging, 1.0,
                                         [&](SimulationOptions& o) { o.source_rate = rate; });
    // The same particles (ids) and ledger. Their positions: measured 1.8e-11
    // to 2.3e-7 of the domain's size (1-3 ranks; 6e-6 widths at most): the
    // copies land on their parents, the solves that separate them take many
    // LMVM iterations, which amplify the sums' round-off; 1e-6 is still 30x
    // below the solver's resolution (1e-3 widths = 3.6e-5 of the size).
    expect_same_run(r, 1e-6);
    EXPECT_GT(rate < 0 ? r.source_removed : r.source_inserted, 50);
  }
}

// The converging preset's setup with the TAO backend.
namespace {
RunSetup tao_setup(const DomainPtr& domain, const std::vector<ConstantBoundaryData>& data, std::int64_t n_inf) {
  register_tao_backend();
  RunSetupOptions ro;
  ro.n_inf = n_inf;
  RunSetup setup = setup_run(*domain, data, ro);
  setup.options.implicit.minimizer.backend = Backend::Tao;
  return setup;
}
}  // namespace

// Checkpoints do not depend on the rank count: one written by a distributed
// run resumes serially (np = N -> 1), and one written by the serial run
// resumes distributed (1 -> N); both end where the uninterrupted serial run
// ends, particle by particle.
namespace {
void expect_resume_on_any_rank_count(bool bdf2) {
  const DomainPtr box = make_box(3, Vec3::Zero(), Vec3(2.0, 1.0, 1.0));
  const std::vector<ConstantBoundaryData> data{{0, PatchKind::Dirichlet, 500.0}};
  const RunSetup setup = tao_setup(box, data, 300);
  SimulationOptions o = setup.options;
  if (bdf2) {
    o.implicit.time_scheme = TimeScheme::Bdf2;
    o.implicit.predictor = Predictor::Damped;
  }
  const double dt = setup.parameters.dt;
  const int half = 4, steps = 8;
  // One name on every rank: rank 0's process id.
  long long tag = static_cast<long long>(::getpid());
  MPI_Bcast(&tag, 1, MPI_LONG_LONG, 0, MPI_COMM_WORLD);
  const std::string dist_file = "/tmp/otfp_test_dist_" + std::to_string(tag) + ".ckpt";
  const std::string serial_file = "/tmp/otfp_test_serial_" + std::to_string(tag) + ".ckpt";

  Simulation reference(box, data, o);
  reference.start(ParticleSet(3));
  for (int k = 1; k <= steps; ++k) {
    reference.advance_to(k * dt);
    if (k == half && world_rank() == 0) reference.save_checkpoint(serial_file);
  }
  MPI_Barrier(MPI_COMM_WORLD);

  Simulation dist(box, data, o, std::make_shared<MpiDistribution>());
  dist.start(ParticleSet(3));
  for (int k = 1; k <= half; ++k) dist.advance_to(k * dt);
  dist.save_checkpoint(dist_file);  // collective: rank 0 writes

  Simulation serial_resumed(box, data, o);  // N -> 1
  serial_resumed.load_checkpoint(dist_file);
  Simulation dist_resumed(box, data, o, std::make_shared<MpiDistribution>());  // 1 -> N
  dist_resumed.load_checkpoint(serial_file);
  EXPECT_EQ(dist_resumed.step_count(), half);
  EXPECT_EQ(dist_resumed.global_size(), static_cast<std::int64_t>(serial_resumed.particles().size()));
  for (int k = half + 1; k <= steps; ++k) {
    serial_resumed.advance_to(k * dt);
    dist_resumed.advance_to(k * dt);
  }
  const ParticleSet& a = reference.particles();
  const double size = std::sqrt(6.0);
  auto largest_difference = [&](const ParticleSet& b) {
    EXPECT_EQ(a.size(), b.size());
    double dx = 0.0;
    for (std::size_t p = 0; p < a.size(); ++p) {
      const std::ptrdiff_t q = b.index_of(a.ids()[p]);
      EXPECT_GE(q, 0) << "particle " << a.ids()[p] << " missing";
      if (q >= 0) dx = std::max(dx, (a.positions()[p] - b.positions()[static_cast<std::size_t>(q)]).norm() / size);
    }
    return dx;
  };
  const double dx_serial = largest_difference(serial_resumed.particles());
  const double dx_dist = largest_difference(all_particles(dist_resumed.particles()));
  EXPECT_EQ(serial_resumed.ledger().inserted, reference.ledger().inserted);
  EXPECT_EQ(dist_resumed.ledger().inserted, reference.ledger().inserted);
  EXPECT_EQ(dist_resumed.ledger().removed, reference.ledger().removed);
  EXPECT_GT(reference.ledger().inserted, 0);
  if (world_rank() == 0)
    std::printf("  %d ranks%s: resumed at step %d of %d: serial from the distributed checkpoint %.2g, distributed "
                "from the serial one %.2g of the domain's size\n",
                world_size(), bdf2 ? ", BDF2 and the predictor" : "", half, steps, dx_serial, dx_dist);
  EXPECT_LT(dx_serial, 1e-9);
  EXPECT_LT(dx_dist, 1e-9);
  MPI_Barrier(MPI_COMM_WORLD);
  if (world_rank() == 0) {
    std::remove(dist_file.c_str());
    std::remove(serial_file.c_str());
  }
}
}  // namespace

TEST(DistributedSimulation, ACheckpointResumesOnAnyRankCount) { expect_resume_on_any_rank_count(false); }

// With BDF2 and the predictor the checkpoint holds every particle's history
// (gathered from the ranks; on loading, the root's entries go with the
// particles to their ranks): a resumed run that lost it would take Euler
// steps where the reference takes BDF2 ones.
TEST(DistributedSimulation, ABdf2CheckpointResumesWithItsHistoryOnAnyRankCount) {
  expect_resume_on_any_rank_count(true);
}

// What a distributed run does not do yet is refused by name.
TEST(DistributedSimulation, RefusesWhatItDoesNotDoYet) {
  const DomainPtr box = make_box(3, Vec3::Zero(), Vec3(2.0, 1.0, 1.0));
  const std::vector<ConstantBoundaryData> data{{0, PatchKind::Dirichlet, 500.0}};
  const SimulationOptions o = tao_setup(box, data, 300).options;
  auto expect_refused = [&](const SimulationOptions& bad, const std::string& field) {
    try {
      Simulation sim(box, data, bad, std::make_shared<MpiDistribution>());
      ADD_FAILURE() << field << " was accepted";
    } catch (const InvalidArgument& e) {
      EXPECT_NE(std::string(e.what()).find(field), std::string::npos) << e.what();
    }
  };
  SimulationOptions ceres = o;
  ceres.implicit.minimizer.backend = Backend::Ceres;
  expect_refused(ceres, "backend");
  // Storage-order draws would differ with the rank count: refused, not
  // silently replaced by draws in id order.
  SimulationOptions storage_order = o;
  storage_order.projection.draw_by_id = false;
  expect_refused(storage_order, "projection.draw_by_id");
  SimulationOptions one_stream = o;
  one_stream.source_draws_by_id = false;
  expect_refused(one_stream, "source_draws_by_id");
}

// The explicit schemes over the ranks (DistributedExplicitStepper): force
// (27) with Euler and RK4, Euler with the exact gradient, each velocity from
// every rank's blobs and the images of the reservoir band's back face; the
// same particles, positions and ledger as the serial ExplicitStepper's run.
TEST(DistributedSimulation, ExplicitSchemesMatchTheSerialRun) {
  const DomainPtr ball = make_ball(3, Vec3::Zero(), 1.0);
  for (ExplicitScheme scheme :
       {ExplicitScheme::EulerForce27, ExplicitScheme::Rk4Force27, ExplicitScheme::EulerExactGradient}) {
    SCOPED_TRACE(to_string(scheme));
    const RunComparison r = compare_runs(ball, {{0, PatchKind::Dirichlet, 0.238732}}, 400, 10,
                                         TreatmentPreset::Converging, 0.5, [scheme](SimulationOptions& o) {
                                           o.stepper = StepperKind::Explicit;
                                           o.explicit_options.scheme = scheme;
                                         });
    // The order of the sums (the serial stepper sorts its particles
    // spatially), grown over ten steps at dt_explicit. Measured on 1-3
    // ranks: 1.5e-13 to 4e-12 of the size with force (27), 1.6e-11 to
    // 1e-10 with the exact gradient (study 6 runs that scheme at half this
    // step, near its stability limit). The implicit runs' bound.
    expect_same_run(r);
  }
}

// A pipe: an inlet and an outlet, whose layer gives up particles at random
// (the converging preset, then the nearest ones). With the serial default
// (draw_by_id) the same particles leave as on N ranks, though the serial
// stepper stores them in its own (spatial) order; drawn in storage order
// they would not (this run with draw_by_id = false: 0.096 of the domain's
// size apart on 1-3 ranks, 565 reflections against 547; the square pipe
// example through the tool: 2 of 400 particles differed after two steps on
// 2 ranks against 1). BoundaryProjection.DrawByIdIsIndependentOfStorageOrder
// tests the draw itself.
TEST(DistributedSimulation, OutletsTakeTheSameParticlesOnAnyRankCount) {
  const DomainPtr box = make_box(3, Vec3::Zero(), Vec3(2.0, 1.0, 1.0));
  // Patch 1 (x+) first: compare_runs fills at its value. More in than out:
  // the mass rule takes M_inf from the net inflow.
  const std::vector<ConstantBoundaryData> pipe{{1, PatchKind::Neumann, 40.0}, {0, PatchKind::Neumann, -60.0}};
  const auto explicit_euler = [](SimulationOptions& o) { o.stepper = StepperKind::Explicit; };
  const RunComparison r = compare_runs(box, pipe, 400, 10, TreatmentPreset::Converging, 1.0, explicit_euler);
  expect_same_run(r);
  EXPECT_GT(r.removed, 0);
}

// A step refused on one rank only (a particle of mass 0 there), and a step
// whose update is not finite (dt = 1e308: the positions overflow), are rejected on every rank with
// the particles untouched, and no rank waits in a collective.
TEST(DistributedExplicitStepper, ARefusalOnOneRankIsEveryRanks) {
  const Cloud c = ball_cloud(3, 600, 31, false);
  const std::vector<int> owner = owners(c, Split::Slabs, 99);
  ParticleSet owned(3);
  for (std::size_t p = 0; p < c.x.size(); ++p)
    if (owner[p] == world_rank()) owned.add_with_id(static_cast<ParticleId>(p), c.x[p], c.s[p], c.m[p]);
  DistributedExplicitStepper stepper(3, ExplicitOptions{});
  const ParticleSet before = owned;
  EXPECT_TRUE(stepper.step(owned, 1e-6).accepted);
  owned = before;
  if (world_rank() == world_size() - 1 && owned.size() > 0) owned.masses()[0] = 0.0;
  const ParticleSet bad = owned;
  StepSummary s = stepper.step(owned, 1e-6);
  EXPECT_FALSE(s.accepted);
  EXPECT_EQ(owned.positions(), bad.positions());
  owned = before;
  s = stepper.step(owned, 1e308);
  EXPECT_FALSE(s.accepted);
  EXPECT_EQ(s.reason, TerminationReason::NonFinite);
  EXPECT_EQ(owned.positions(), before.positions());
}

// An explicit run over the ranks refuses adaptive steps, as a serial one
// does (no error estimate).
TEST(DistributedSimulation, ExplicitRunsRefuseAdaptiveSteps) {
  const DomainPtr box = make_box(3, Vec3::Zero(), Vec3(2.0, 1.0, 1.0));
  const std::vector<ConstantBoundaryData> data{{0, PatchKind::Dirichlet, 500.0}};
  SimulationOptions o = tao_setup(box, data, 300).options;
  o.stepper = StepperKind::Explicit;
  Simulation sim(box, data, o, std::make_shared<MpiDistribution>());
  sim.start(ParticleSet(3));
  sim.set_next_dt(1e-4);
  EXPECT_THROW(sim.advance_adaptive(1.0), InvalidArgument);
}

int main(int argc, char** argv) {
  ::testing::InitGoogleTest(&argc, argv);
  const int rank = otfp::world_rank();  // initialises MPI (through PETSc)
  if (rank != 0) {
    // One report, rank 0's; the other ranks' failures still fail the run.
    auto& listeners = ::testing::UnitTest::GetInstance()->listeners();
    delete listeners.Release(listeners.default_result_printer());
  }
  int failed = RUN_ALL_TESTS() != 0 ? 1 : 0;
  MPI_Allreduce(MPI_IN_PLACE, &failed, 1, MPI_INT, MPI_MAX, MPI_COMM_WORLD);
  if (failed && rank != 0) std::fprintf(stderr, "rank %d: some test failed\n", rank);
  return failed;
}
