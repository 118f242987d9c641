// Neighbour search: the Verlet list against brute force on random clouds,
// after moves within the skin, after insertions and deletions, with periodic
// images and with different widths; the cut-off comes from the kernel tolerance.
#include <gtest/gtest.h>

#include <omp.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <set>
#include <string>

#include "otfp/density.hpp"
#include "otfp/geometry.hpp"
#include "otfp/neighbor_list.hpp"
#include "test_support.hpp"
#include "../src/isa.hpp"  // internal: to run each kernel build

using namespace otfp;
using otfp::testing::random_cloud;

namespace {

using PairSet = std::set<std::pair<std::uint32_t, std::uint32_t>>;

PairSet list_pairs(const NeighborList& nl) {
  PairSet out;
  for (std::size_t p = 0; p < nl.size(); ++p)
    for (std::uint32_t k = nl.offsets()[p]; k < nl.offsets()[p + 1]; ++k)
      out.emplace(static_cast<std::uint32_t>(p), nl.indices()[k]);
  return out;
}

PairSet brute_pairs(const std::vector<Vec3>& x, double radius, const Periodicity& per) {
  PairSet out;
  for (std::uint32_t p = 0; p < x.size(); ++p)
    for (std::uint32_t q = 0; q < x.size(); ++q)
      if (p != q && per.displacement(x[p], x[q]).norm() <= radius) out.emplace(p, q);
  return out;
}

// The list's definition, by brute force: |x_p - x_q| <= max(R_p, R_q).
PairSet brute_pairs(const NeighborList& nl, const std::vector<Vec3>& x, const std::vector<double>& s,
                    const Periodicity& per) {
  PairSet out;
  for (std::uint32_t p = 0; p < x.size(); ++p)
    for (std::uint32_t q = 0; q < x.size(); ++q)
      if (p != q &&
          per.displacement(x[p], x[q]).norm() <= std::max(nl.particle_radius(s[p]), nl.particle_radius(s[q])))
        out.emplace(p, q);
  return out;
}

// Builds with the given OpenMP thread count and neighbour kernels ("" = the
// default: AVX2 where the CPU has it; "generic": the portable build).
NeighborList build_with(const std::vector<Vec3>& x, const std::vector<double>& s, const Periodicity& per,
                        int threads, const std::string& kernels = "", NeighborOptions o = {}) {
  const int before = omp_get_max_threads();
  omp_set_num_threads(threads);
  detail::set_kernel_isa(kernels == "generic" ? detail::KernelIsa::Generic : detail::KernelIsa::Auto);
  NeighborList nl(o);
  nl.build(x, s, per);
  detail::set_kernel_isa(detail::KernelIsa::Auto);
  omp_set_num_threads(before);
  return nl;
}

// Same rows in the same order.
void expect_identical(const NeighborList& a, const NeighborList& b, const std::string& what) {
  EXPECT_EQ(a.offsets(), b.offsets()) << what;
  EXPECT_EQ(a.indices(), b.indices()) << what;
}

// Each row free of duplicates and of the particle itself.
void expect_clean_rows(const NeighborList& nl, const std::string& what) {
  for (std::size_t p = 0; p < nl.size(); ++p) {
    std::set<std::uint32_t> row;
    for (std::uint32_t k = nl.offsets()[p]; k < nl.offsets()[p + 1]; ++k) {
      EXPECT_NE(nl.indices()[k], p) << what;
      EXPECT_TRUE(row.insert(nl.indices()[k]).second) << what << ": duplicate in row " << p;
    }
  }
}

}  // namespace

TEST(NeighborList, CutoffComesFromKernelTolerance) {
  const double s = 0.1;
  const double rc = cutoff_radius(s, 1e-8);
  EXPECT_NEAR(std::exp(-rc * rc / (s * s)), 1e-8, 1e-20);
  EXPECT_GT(rc, 4.0 * s);  // far beyond 1/sqrt(beta) = s
}

TEST(NeighborList, MatchesBruteForceOnRandomClouds) {
  for (int dim = 1; dim <= 3; ++dim) {
    ParticleSet ps = random_cloud(dim, 1500, -1.0, 1.0, 0.04, 0.4, 1.0, 100 + dim);
    NeighborList nl;
    nl.build(ps.positions(), ps.widths(), Periodicity::none(dim));
    const PairSet expected = brute_pairs(nl, ps.positions(), ps.widths(), Periodicity::none(dim));
    ASSERT_GT(expected.size(), ps.size()) << "cloud too sparse for a meaningful test";
    EXPECT_EQ(list_pairs(nl), expected) << "d=" << dim;
    // The largest radius is that of the widest blob plus the skin.
    double smax = *std::max_element(ps.widths().begin(), ps.widths().end());
    EXPECT_NEAR(nl.cutoff(), cutoff_radius(smax, 1e-8), 1e-15);
  }
}

// drop_pairs_beyond(k): rows below k unchanged, rows from k on keep exactly
// their entries below k, in their order (brute force: the pair set).
TEST(NeighborList, DropPairsBeyondKeepsOnlyPairsWithARowBelow) {
  ParticleSet ps = random_cloud(3, 1200, -1.0, 1.0, 0.05, 0.3, 1.0, 41);
  NeighborList full;
  full.build(ps.positions(), ps.widths(), Periodicity::none(3));
  const std::size_t k = 700;
  NeighborList cut = full;
  cut.drop_pairs_beyond(k);
  PairSet expected;
  for (const auto& [p, q] : list_pairs(full))
    if (p < k || q < k) expected.emplace(p, q);
  EXPECT_EQ(list_pairs(cut), expected);
  EXPECT_LT(cut.num_entries(), full.num_entries());
  for (std::size_t p = 0; p <= k; ++p) EXPECT_EQ(cut.offsets()[p], full.offsets()[p]);
  for (std::size_t p = k; p < full.size(); ++p) {
    std::vector<std::uint32_t> kept;
    for (std::uint32_t e = full.offsets()[p]; e < full.offsets()[p + 1]; ++e)
      if (full.indices()[e] < k) kept.push_back(full.indices()[e]);
    const std::vector<std::uint32_t> row(cut.indices().begin() + cut.offsets()[p],
                                         cut.indices().begin() + cut.offsets()[p + 1]);
    EXPECT_EQ(row, kept) << "row " << p;
  }
  NeighborList same = full;
  same.drop_pairs_beyond(full.size());
  expect_identical(same, full, "rows = size");
}

TEST(NeighborList, PeriodicImagesMatchBruteForce) {
  for (int dim = 1; dim <= 3; ++dim) {
    DomainPtr box = make_periodic_box(dim, Vec3::Constant(-1.0), Vec3::Constant(1.0));
    ParticleSet ps = random_cloud(dim, 1200, -1.0, 1.0, 0.05, 0.2, 1.0, 200 + dim);
    const Periodicity per = Periodicity::from_domain(*box);
    NeighborList nl;
    nl.build(ps.positions(), ps.widths(), per);
    const PairSet expected = brute_pairs(nl, ps.positions(), ps.widths(), per);
    EXPECT_EQ(list_pairs(nl), expected) << "d=" << dim;
    // Some pairs must actually cross the box edge.
    int crossing = 0;
    for (auto [p, q] : expected)
      if ((ps.positions()[p] - ps.positions()[q]).norm() > nl.list_radius()) ++crossing;
    EXPECT_GT(crossing, 0);
  }
}

TEST(NeighborList, SmallPeriodicBoxWithFewCellsHasNoDuplicates) {
  DomainPtr box = make_periodic_box(3, Vec3::Zero(), Vec3::Constant(1.0));
  ParticleSet ps = random_cloud(3, 300, 0.0, 1.0, 0.05, 0.0, 1.0, 9);
  NeighborOptions o;
  o.skin = 0.2;  // radius ~0.41: two cells per axis, where -1 and +1 alias
  NeighborList nl(o);
  nl.build(ps.positions(), ps.widths(), Periodicity::from_domain(*box));
  const PairSet got = list_pairs(nl);
  EXPECT_EQ(got.size(), nl.num_entries()) << "duplicate entries";
  EXPECT_EQ(got, brute_pairs(ps.positions(), nl.list_radius(), Periodicity::from_domain(*box)));
}

TEST(NeighborList, RejectsPeriodicBoxSmallerThanTwiceTheRadius) {
  DomainPtr box = make_periodic_box(2, Vec3::Zero(), Vec3::Constant(0.3));
  ParticleSet ps = random_cloud(2, 10, 0.0, 0.3, 0.05, 0.0, 1.0, 3);
  NeighborList nl;
  EXPECT_THROW(nl.build(ps.positions(), ps.widths(), Periodicity::from_domain(*box)), InvalidArgument);
}

TEST(NeighborList, StaysValidForMovesWithinHalfTheSkin) {
  const int dim = 3;
  ParticleSet ps = random_cloud(dim, 2000, 0.0, 1.0, 0.03, 0.3, 1.0, 42);
  NeighborList nl;
  nl.build(ps.positions(), ps.widths(), Periodicity::none(dim));
  const PairSet built = list_pairs(nl);
  Rng rng(4);
  auto x = ps.positions();
  for (auto& p : x) {
    Vec3 dir(rng.normal(), rng.normal(), rng.normal());
    p += (0.49 * nl.skin() * rng.uniform()) * dir.normalized();
  }
  EXPECT_FALSE(nl.needs_rebuild(x, ps.widths()));
  // Every pair now inside its cut-off is still in the list.
  const auto& s0 = ps.widths();
  const double tol = nl.options().kernel_tolerance;
  for (std::uint32_t p = 0; p < x.size(); ++p)
    for (std::uint32_t q = 0; q < x.size(); ++q)
      if (p != q && (x[p] - x[q]).norm() <= cutoff_radius(std::max(s0[p], s0[q]), tol)) {
        EXPECT_TRUE(built.count({p, q})) << p << "," << q;
      }
  // Widening blobs by less than what is left of the skin keeps the list valid, too.
  {
    auto s = ps.widths();
    for (auto& v : s) v += 0.01 * nl.skin() / std::sqrt(std::log(1.0 / tol));
    EXPECT_FALSE(nl.needs_rebuild(x, s));
  }
  // Moving one particle by more than half the skin asks for a rebuild.
  x = ps.positions();
  x[17] += Vec3(0.51 * nl.skin(), 0.0, 0.0);
  EXPECT_TRUE(nl.needs_rebuild(x, ps.widths()));
  // With per-pair radii a narrow blob that grows matters too, even while it
  // stays narrower than the widest: its cut-off growth alone uses up the skin.
  {
    auto s = ps.widths();
    const std::size_t narrow = static_cast<std::size_t>(std::min_element(s.begin(), s.end()) - s.begin());
    const double smax = *std::max_element(s.begin(), s.end());
    s[narrow] += 1.01 * nl.skin() / std::sqrt(std::log(1.0 / tol));
    ASSERT_LT(s[narrow], smax);
    EXPECT_TRUE(nl.needs_rebuild(ps.positions(), s));
  }
  // So does widening a blob enough to grow the cut-off past the skin.
  auto s = ps.widths();
  x = ps.positions();
  s[3] = *std::max_element(s.begin(), s.end()) * 1.5;
  EXPECT_TRUE(nl.needs_rebuild(x, s));
}

// The rebuild rule along a trajectory: particles drift in small random steps
// (some pairs head straight for each other) and widths creep up; the list is
// rebuilt only when needs_rebuild() says so. Whenever it says no, every pair
// within its cut-off is in the list (brute force); and the rule is not
// wasteful: while 2 x the largest displacement plus the cut-off growth stays
// below 0.9 x the skin it never asks (a step uses at most ~11 % of it).
TEST(NeighborList, RebuildRuleKeepsEveryPairAlongATrajectory) {
  const int dim = 2;
  ParticleSet ps = random_cloud(dim, 400, 0.0, 1.0, 0.02, 0.3, 1.0, 11);
  auto x = ps.positions();
  auto s = ps.widths();
  // Head-on pairs: partners placed just beyond the list radius on either side.
  NeighborList nl;
  nl.build(x, s, Periodicity::none(dim));
  const double tol = nl.options().kernel_tolerance;
  for (std::size_t p = 0; p < 20; p += 2) {
    x[p + 1] = x[p] + Vec3(nl.particle_radius(std::max(s[p], s[p + 1])) * 1.001, 0.0, 0.0);
  }
  nl.build(x, s, Periodicity::none(dim));
  auto x_build = x;
  auto s_build = s;
  Rng rng(12);
  int rebuilds = 0, checked = 0;
  for (int step = 0; step < 300; ++step) {
    const double h = 0.04 * nl.skin();
    for (std::size_t p = 0; p < x.size(); ++p) {
      if (p < 20)  // the pairs approach each other along x
        x[p] += Vec3(p % 2 ? -h : h, 0.0, 0.0);
      else
        x[p] += h * Vec3(rng.normal(), rng.normal(), 0.0).normalized();
      s[p] *= 1.0 + 2e-3 * rng.uniform();  // the cut-off grows by up to ~3 % of the skin per step
    }
    double disp = 0.0, growth = 0.0;
    for (std::size_t p = 0; p < x.size(); ++p) {
      disp = std::max(disp, (x[p] - x_build[p]).norm());
      growth = std::max(growth, s[p] - s_build[p]);
    }
    const double used = 2.0 * disp + cutoff_radius(growth, tol);
    if (nl.needs_rebuild(x, s)) {
      EXPECT_GT(used, 0.9 * nl.skin()) << "step " << step << ": a rebuild before the skin is used up";
      nl.build(x, s, Periodicity::none(dim));
      x_build = x;
      s_build = s;
      ++rebuilds;
      continue;
    }
    ++checked;
    const PairSet listed = list_pairs(nl);
    for (std::uint32_t p = 0; p < x.size(); ++p)
      for (std::uint32_t q = 0; q < x.size(); ++q)
        if (p != q && (x[p] - x[q]).norm() <= cutoff_radius(std::max(s[p], s[q]), tol)) {
          ASSERT_TRUE(listed.count({p, q})) << "step " << step << ": pair " << p << "," << q << " missing";
        }
  }
  EXPECT_GT(rebuilds, 5);
  EXPECT_GT(checked, 200);
}

TEST(NeighborList, RebuildAfterInsertionsAndDeletionsMatchesBruteForce) {
  const int dim = 2;
  ParticleSet ps = random_cloud(dim, 800, 0.0, 1.0, 0.02, 0.3, 1.0, 77);
  NeighborList nl;
  nl.build(ps.positions(), ps.widths(), Periodicity::none(dim));
  Rng rng(8);
  for (int i = 0; i < 50; ++i) ps.add(Vec3(rng.uniform(), rng.uniform(), 0.0), 0.02, 1.0);
  std::vector<std::size_t> gone;
  for (std::size_t i = 0; i < 800; i += 7) gone.push_back(i);
  ps.remove_indices(gone);
  EXPECT_TRUE(nl.needs_rebuild(ps.positions(), ps.widths()));
  nl.build(ps.positions(), ps.widths(), Periodicity::none(dim));
  EXPECT_EQ(list_pairs(nl), brute_pairs(nl, ps.positions(), ps.widths(), Periodicity::none(dim)));
  EXPECT_EQ(nl.build_count(), 2);
}

// A list that grows from one build to the next holds at most 1/8 more than
// its entries, not what std::vector::resize would reserve (up to twice the
// old size, allocated while the old storage is still held): at n = 1e5 that
// was 400 of the step's 629 MB of heap (docs/performance.md).
TEST(NeighborList, AGrowingListHoldsLittleMoreThanItsEntries) {
  const int dim = 2;
  ParticleSet ps = random_cloud(dim, 800, 0.0, 1.0, 0.02, 0.3, 1.0, 77);
  NeighborList nl;
  nl.build(ps.positions(), ps.widths(), Periodicity::none(dim));
  Rng rng(9);
  for (int round = 0; round < 3; ++round) {
    for (int i = 0; i < 8; ++i) ps.add(Vec3(rng.uniform(), rng.uniform(), 0.0), 0.02, 1.0);
    const std::size_t before = nl.indices().capacity();
    nl.build(ps.positions(), ps.widths(), Periodicity::none(dim));
    const std::size_t entries = nl.num_entries();
    EXPECT_LE(nl.indices().capacity(), entries + entries / 8) << "round " << round;
    EXPECT_GE(nl.indices().capacity(), std::min(before, entries + entries / 8)) << "round " << round;
    EXPECT_EQ(list_pairs(nl), brute_pairs(nl, ps.positions(), ps.widths(), Periodicity::none(dim)));
  }
}

TEST(BlobDensity, CellListMatchesAllPairs) {
  for (int dim = 1; dim <= 3; ++dim) {
    ParticleSet ps = random_cloud(dim, 1000, -1.0, 1.0, 0.08, 0.4, 0.01, 300 + dim);
    std::vector<Vec3> points;
    Rng rng(5);
    for (int i = 0; i < 200; ++i) {
      Vec3 y = Vec3::Zero();
      for (int k = 0; k < dim; ++k) y[k] = rng.uniform(-1.3, 1.3);
      points.push_back(y);
    }
    std::vector<double> r1, r2;
    std::vector<Vec3> g1, g2;
    blob_density(ps, points, Periodicity::none(dim), 1e-10, r1, &g1);
    blob_density_all_pairs(ps, points, Periodicity::none(dim), r2, &g2);
    double rmax = 0.0, gmax = 0.0;
    for (std::size_t i = 0; i < points.size(); ++i) {
      rmax = std::max(rmax, r2[i]);
      gmax = std::max(gmax, g2[i].norm());
    }
    ASSERT_GT(rmax, 0.0);
    for (std::size_t i = 0; i < points.size(); ++i) {
      EXPECT_NEAR(r1[i], r2[i], 1e-8 * rmax);
      EXPECT_LE((g1[i] - g2[i]).norm(), 1e-7 * gmax);
    }
  }
}

TEST(BlobDensity, IntegratesToTotalMass1D) {
  // The density of (29) carries the particles' mass: a Riemann sum over a wide interval.
  ParticleSet ps = random_cloud(1, 50, -1.0, 1.0, 0.1, 0.5, 0.3, 12);
  std::vector<Vec3> pts;
  const double h = 1e-3;
  for (double t = -3.0; t <= 3.0; t += h) pts.emplace_back(t, 0.0, 0.0);
  std::vector<double> rho;
  blob_density(ps, pts, Periodicity::none(1), 1e-14, rho, nullptr);
  double mass = 0.0;
  for (double v : rho) mass += v * h;
  EXPECT_NEAR(mass, ps.total_mass(), 1e-9 * ps.total_mass());
}

// A cloud blown apart by an unstable explicit step: a few particles very far
// away must not make the cell grid huge (the count is capped near n), and the
// list still equals brute force. Non-finite positions are rejected by name.
TEST(NeighborList, FarFlungParticlesKeepTheGridSmallAndTheListExact) {
  ParticleSet ps = random_cloud(3, 400, -1.0, 1.0, 0.05, 0.1, 1.0, 77);
  ps.positions()[3] = Vec3(1e200, -1e150, 3.0);
  ps.positions()[7] = Vec3(-1e12, 5e11, 1e13);
  NeighborList nl;
  nl.build(ps.positions(), ps.widths(), Periodicity::none(3));
  EXPECT_EQ(list_pairs(nl), brute_pairs(nl, ps.positions(), ps.widths(), Periodicity::none(3)));
  ps.positions()[5] = Vec3(std::nan(""), 0.0, 0.0);
  try {
    nl.build(ps.positions(), ps.widths(), Periodicity::none(3));
    ADD_FAILURE() << "accepted a NaN position";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("particle 5"), std::string::npos) << e.what();
  }
}

// Optimised widths leave a few blobs several times wider than the rest
// (study 2). The list holds each pair within the wider blob's radius, not
// every pair within the widest blob's: equal to brute force, symmetric, and
// far shorter than the widest radius would make it. Periodic boxes too, where
// wide blobs' searches visit every cell along an axis.
TEST(NeighborList, PerPairRadiusWithAFewWideBlobsMatchesBruteForce) {
  for (int dim = 1; dim <= 3; ++dim) {
    for (bool periodic : {false, true}) {
      ParticleSet ps = random_cloud(dim, 1500, 0.0, 2.0, 0.03, 0.2, 1.0, 500 + dim);
      Rng rng(31 + dim);
      for (std::size_t p = 0; p < ps.size(); p += 37) ps.widths()[p] *= rng.uniform(3.0, 6.0);
      DomainPtr box = make_periodic_box(dim, Vec3::Zero(), Vec3::Constant(2.0));
      const Periodicity per = periodic ? Periodicity::from_domain(*box) : Periodicity::none(dim);
      NeighborList nl;
      nl.build(ps.positions(), ps.widths(), per);
      const PairSet got = list_pairs(nl);
      EXPECT_EQ(got.size(), nl.num_entries()) << "duplicate entries, d=" << dim;
      EXPECT_EQ(got, brute_pairs(nl, ps.positions(), ps.widths(), per)) << "d=" << dim << " periodic=" << periodic;
      for (const auto& [p, q] : got) EXPECT_TRUE(got.count({q, p})) << "asymmetric " << p << "," << q;
      const PairSet widest = brute_pairs(ps.positions(), nl.list_radius(), per);
      EXPECT_LT(2 * got.size(), widest.size()) << "d=" << dim;
    }
  }
}

// An optimiser moves particles across the edge of a periodic box and the list
// may be rebuilt before anything wraps them: unwrapped positions must give
// the same list as wrapped ones (many cells, so the exact-shift path runs).
TEST(NeighborList, UnwrappedPositionsInAPeriodicBoxMatchBruteForce) {
  for (int dim = 1; dim <= 3; ++dim) {
    DomainPtr box = make_periodic_box(dim, Vec3::Zero(), Vec3::Constant(2.0));
    ParticleSet ps = random_cloud(dim, 1200, -0.4, 2.4, 0.04, 0.2, 1.0, 600 + dim);
    const Periodicity per = Periodicity::from_domain(*box);
    NeighborList nl;
    nl.build(ps.positions(), ps.widths(), per);
    const PairSet got = list_pairs(nl);
    EXPECT_EQ(got, brute_pairs(nl, ps.positions(), ps.widths(), per)) << "d=" << dim;
    int outside = 0;
    for (const auto& y : ps.positions()) outside += (y.head(dim).array() < 0.0).any() || (y.head(dim).array() >= 2.0).any();
    EXPECT_GT(outside, 100);
  }
}

// The search shares candidates among the particles of a cell (those reaching
// at most two cells) and lets the others search alone (wider blobs, or a
// periodic box too small for the shared cells): with a broad spread of widths
// every kind occurs, in 1D, 2D and 3D, open and periodic. Both builds of the
// kernels (AVX2 and generic) and 1 or 2 threads give the same list, row order
// included, and it equals brute force.
TEST(NeighborList, MatchesBruteForceWithVariableWidths) {
  for (int dim = 1; dim <= 3; ++dim) {
    for (bool periodic : {false, true}) {
      const std::size_t n = dim == 1 ? 700 : 1500;
      ParticleSet ps = random_cloud(dim, n, 0.0, 2.0, dim == 3 ? 0.03 : 0.015, 0.6, 1.0, 800 + dim);
      Rng rng(41 + dim);
      for (std::size_t p = 0; p < ps.size(); p += 23) ps.widths()[p] *= rng.uniform(2.0, 5.0);
      DomainPtr box = make_periodic_box(dim, Vec3::Zero(), Vec3::Constant(2.0));
      const Periodicity per = periodic ? Periodicity::from_domain(*box) : Periodicity::none(dim);
      const std::string what = "d=" + std::to_string(dim) + " periodic=" + std::to_string(periodic);
      const NeighborList nl = build_with(ps.positions(), ps.widths(), per, 1);
      EXPECT_EQ(list_pairs(nl), brute_pairs(nl, ps.positions(), ps.widths(), per)) << what;
      expect_clean_rows(nl, what);
      expect_identical(nl, build_with(ps.positions(), ps.widths(), per, 2), what + " 2 threads");
      expect_identical(nl, build_with(ps.positions(), ps.widths(), per, 2, "generic"), what + " generic");
      expect_identical(nl, build_with(ps.positions(), ps.widths(), per, 1, "generic"), what + " generic 1 thread");
    }
  }
}

// Equal widths (the shared search only) in a uniform cloud, the benchmark's
// set-up at a small size: threads and kernel builds agree exactly.
TEST(NeighborList, EqualWidthsAreIdenticalForThreadsAndKernels) {
  const std::size_t n = 3000;
  const double dr = 1.0 / std::cbrt(static_cast<double>(n));
  ParticleSet ps = random_cloud(3, n, 0.0, 1.0, dr / std::sqrt(2.0), 0.0, 1.0, 4242);
  const NeighborList nl = build_with(ps.positions(), ps.widths(), Periodicity::none(3), 1);
  EXPECT_EQ(list_pairs(nl), brute_pairs(nl, ps.positions(), ps.widths(), Periodicity::none(3)));
  expect_clean_rows(nl, "uniform");
  expect_identical(nl, build_with(ps.positions(), ps.widths(), Periodicity::none(3), 2), "2 threads");
  expect_identical(nl, build_with(ps.positions(), ps.widths(), Periodicity::none(3), 2, "generic"), "generic");
  // A rebuild (buffers sized from the last build) gives the same list again.
  NeighborList again = nl;
  again.build(ps.positions(), ps.widths(), Periodicity::none(3));
  again.build(ps.positions(), ps.widths(), Periodicity::none(3));
  expect_identical(nl, again, "rebuild");
}

// Small periodic boxes: eleven cells a side (the shared search, shifted
// images) and four (the shifts of two cells each side alias: every particle
// searches alone with minimum images), one wider blob among equal ones; pairs
// across the box edge and the list order do not depend on threads or kernels.
TEST(NeighborList, SmallPeriodicBoxesMatchBruteForce) {
  for (int dim = 1; dim <= 3; ++dim) {
    for (double skin : {0.05, 0.3}) {  // R ~0.18 (11 cells a side) and ~0.43 (4 cells: the shifts alias)
      DomainPtr box = make_periodic_box(dim, Vec3::Zero(), Vec3::Constant(1.0));
      ParticleSet ps = random_cloud(dim, dim == 1 ? 60 : 400, 0.0, 1.0, 0.03, 0.0, 1.0, 900 + dim);
      ps.widths()[5] *= 1.5;
      NeighborOptions o;
      o.skin = skin;
      const Periodicity per = Periodicity::from_domain(*box);
      const std::string what = "d=" + std::to_string(dim) + " skin=" + std::to_string(skin);
      const NeighborList nl = build_with(ps.positions(), ps.widths(), per, 1, "", o);
      EXPECT_EQ(list_pairs(nl), brute_pairs(nl, ps.positions(), ps.widths(), per)) << what;
      expect_clean_rows(nl, what);
      expect_identical(nl, build_with(ps.positions(), ps.widths(), per, 2, "", o), what + " 2 threads");
      expect_identical(nl, build_with(ps.positions(), ps.widths(), per, 2, "generic", o), what + " generic");
    }
  }
}

// Coincident particles (distance 0) are neighbours of each other, never of
// themselves; particles on cell and box edges are found from both sides.
TEST(NeighborList, CoincidentAndGridAlignedParticles) {
  for (int dim = 1; dim <= 3; ++dim) {
    std::vector<Vec3> x;
    std::vector<double> s;
    const int m = dim == 3 ? 9 : (dim == 2 ? 25 : 200);
    for (int i = 0; i < m; ++i)
      for (int j = 0; j < (dim >= 2 ? m : 1); ++j)
        for (int k = 0; k < (dim == 3 ? m : 1); ++k) {
          x.emplace_back(i * 0.1, j * 0.1, k * 0.1);
          s.push_back(0.02);
        }
    const std::size_t base = x.size();
    for (std::size_t p = 0; p < base; p += 7) {  // copies on top of every seventh point
      x.push_back(x[p]);
      s.push_back(0.03);
    }
    NeighborOptions o;
    o.skin = 0.1005 - cutoff_radius(0.02, 1e-8);  // R just above the lattice spacing: no ties with brute force
    for (const bool periodic : {false, true}) {
      DomainPtr box = make_periodic_box(dim, Vec3::Zero(), Vec3::Constant(0.1 * m));
      const Periodicity per = periodic ? Periodicity::from_domain(*box) : Periodicity::none(dim);
      const std::string what = "d=" + std::to_string(dim) + " periodic=" + std::to_string(periodic);
      const NeighborList nl = build_with(x, s, per, 1, "", o);
      EXPECT_EQ(list_pairs(nl), brute_pairs(nl, x, s, per)) << what;
      expect_clean_rows(nl, what);
      expect_identical(nl, build_with(x, s, per, 2, "generic", o), what + " generic");
      const PairSet got = list_pairs(nl);
      for (std::size_t p = 0; p < base; p += 7)
        EXPECT_TRUE(got.count({static_cast<std::uint32_t>(p), static_cast<std::uint32_t>(base + p / 7)})) << what;
    }
  }
}
