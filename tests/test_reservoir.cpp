// The quiet control of the Dirichlet reservoir (src/reservoir.cpp,
// ProjectionOptions::reservoir_control = Quiet; the exact counts are tested in
// test_boundary.cpp): its placement density against the O(n^2) sum, the fill
// at the start, corrections only beyond the tolerance and where the density
// is lowest, no random numbers, and a settled state that is a fixed point of
// the whole step at 1x ... 1000x the explicit limit.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <memory>
#include <iostream>
#include <numbers>
#include <vector>

#include "../src/placement_density.hpp"  // internal: checked against the O(n^2) sum
#include "otfp/density.hpp"
#include "otfp/images.hpp"
#include "otfp/neighbor_list.hpp"
#include "otfp/parameters.hpp"
#include "otfp/simulation.hpp"

using namespace otfp;

namespace {

// A domain held at g on one Dirichlet patch, with the converging treatment of
// `otfp run` (true spacing, beta dr^2 = 2, image blobs at the other walls, the
// odd reservoir one cut-off deep with half a spacing per sublayer, filled at
// t = 0) and the quiet control; M_inf = 1, so m_p = 1 / n_inf.
struct Held {
  DomainPtr domain;
  int patch = 0;
  double g = 0.0;
  PaperParameters pp;
  SimulationOptions options;
  Held(DomainPtr d, int dirichlet_patch, std::size_t n_inf) : domain(std::move(d)), patch(dirichlet_patch) {
    const int dim = domain->dim();
    g = 1.0 / domain->volume();
    pp = paper_parameters(domain->volume(), n_inf, dim, 1.0, 1.0, 2.0);
    options.particle_mass = 1.0 / static_cast<double>(n_inf);
    options.width_s = pp.width_s;
    options.barrier_stiffness = pp.barrier_C;
    options.no_flux = NoFluxTreatment::Images;
    ProjectionOptions& po = options.projection;
    po.layer_b = pp.layer_b;
    po.dirichlet_mode = DirichletMode::Reservoir;
    po.reservoir_profile = ReservoirProfile::Odd;
    po.reservoir_control = ReservoirControl::Quiet;
    po.reservoir_thickness = cutoff_radius(pp.width_s, 1e-8);
    po.reservoir_sublayers = std::max(1, static_cast<int>(std::lround(2.0 * po.reservoir_thickness / pp.dr)));
    options.fill_reservoir_at_start = true;
    options.implicit.kappa = 1.0;
    options.implicit.rho_ref = 1.0;
  }
  std::unique_ptr<Simulation> make() const {
    return std::make_unique<Simulation>(domain, std::vector<ConstantBoundaryData>{{patch, PatchKind::Dirichlet, g}},
                                        options);
  }
};

Held disc() { return Held(make_ball(2, Vec3::Zero(), 1.0), 0, 150); }
// The unit square held at g on x = 0 (patch 0 of make_box: "x-"), no flux elsewhere.
Held square() { return Held(make_box(2, Vec3(0, 0, 0), Vec3(1, 1, 0)), 0, 150); }

double max_displacement(const ParticleSet& a, const ParticleSet& b) {
  // Ids are kept through the spatial sorting of a step; match by id.
  std::vector<std::pair<ParticleId, Vec3>> pa, pb;
  for (std::size_t p = 0; p < a.size(); ++p) pa.emplace_back(a.ids()[p], a.positions()[p]);
  for (std::size_t p = 0; p < b.size(); ++p) pb.emplace_back(b.ids()[p], b.positions()[p]);
  auto by_id = [](const auto& u, const auto& v) { return u.first < v.first; };
  std::sort(pa.begin(), pa.end(), by_id);
  std::sort(pb.begin(), pb.end(), by_id);
  double worst = 0.0;
  for (std::size_t i = 0; i < std::min(pa.size(), pb.size()); ++i) {
    EXPECT_EQ(pa[i].first, pb[i].first);
    worst = std::max(worst, (pa[i].second - pb[i].second).norm());
  }
  return worst;
}

bool same_stream(const Rng::State& a, const Rng::State& b) {
  return std::equal(std::begin(a.s), std::end(a.s), std::begin(b.s)) && a.has_spare == b.has_spare;
}

}  // namespace

// The cell-list evaluation with images equals the plain sum over the
// particles and every image blob (the functional's choice of images), at
// points inside, in the band and next to the walls.
TEST(QuietReservoir, PlacementDensityMatchesTheAllPairsSum) {
  for (const Held& s : {disc(), square()}) {
    auto sim = s.make();
    sim->start(ParticleSet(s.domain->dim()), 0.0);
    sim->advance(s.pp.dt_explicit);  // some particles inside, the band partly drained
    const ParticleSet& ps = sim->particles();
    const MirrorWallPtr back = mirror_walls(*sim->reservoir_domain()).front();
    const std::vector<MirrorWallPtr> walls = mirror_walls(*sim->reservoir_domain());
    const detail::PlacementDensity density(ps, walls, 1e-12);
    ASSERT_GT(density.blobs().size(), ps.size()) << "images near the walls";
    // Independent sum: every blob, no cut-off.
    ParticleSet all(s.domain->dim());
    for (std::size_t b = 0; b < density.blobs().size(); ++b)
      all.add(density.blobs()[b], density.widths()[b], density.masses()[b]);
    Rng rng(5);
    std::vector<Vec3> points;
    const Aabb box = sim->reservoir_domain()->bounding_box();
    while (points.size() < 300) {
      Vec3 y = Vec3::Zero();
      for (int k = 0; k < s.domain->dim(); ++k) y[k] = rng.uniform(box.lo[k], box.hi[k]);
      if (sim->reservoir_domain()->signed_distance(y) <= 0.0) points.push_back(y);
    }
    std::vector<double> exact;
    blob_density_all_pairs(all, points, Periodicity::none(s.domain->dim()), exact, nullptr);
    double scale = 0.0;
    for (double v : exact) scale = std::max(scale, v);
    for (std::size_t i = 0; i < points.size(); ++i)
      EXPECT_NEAR(density.at(points[i]), exact[i], 1e-10 * scale) << "point " << i;
    // The images are those of the walls: a blob at the back wall is mirrored onto itself.
    (void)back;
  }
}

// From an empty domain the band is filled to the odd profile's 2 g: each
// sublayer gets round(2 g |sublayer| / m_p) particles (annuli of the disc
// computed here), and nothing lands inside Omega.
TEST(QuietReservoir, FillsTheBandToTwiceGAtTheStart) {
  const Held s = disc();
  auto sim = s.make();
  sim->start(ParticleSet(2), 0.0);
  const double w = s.options.projection.reservoir_thickness;
  const int K = s.options.projection.reservoir_sublayers;
  std::vector<long> count(static_cast<std::size_t>(K), 0);
  for (const Vec3& x : sim->particles().positions()) {
    const double depth = x.norm() - 1.0;
    ASSERT_GT(depth, 0.0) << "a particle inside Omega at the start";
    ASSERT_LE(depth, w + 1e-12);
    ++count[static_cast<std::size_t>(std::min(K - 1, static_cast<int>(depth / w * K)))];
  }
  for (int j = 0; j < K; ++j) {
    const double r0 = 1.0 + w * j / K, r1 = 1.0 + w * (j + 1) / K;
    const double want = 2.0 * s.g * std::numbers::pi * (r1 * r1 - r0 * r0) / s.options.particle_mass;
    EXPECT_LE(std::abs(static_cast<double>(count[static_cast<std::size_t>(j)]) - want), 1.0) << "sublayer " << j;
  }
  EXPECT_EQ(sim->initial_step().inserted, static_cast<long>(sim->particles().size()));
}

// Once the band is filled, another projection without motion changes
// nothing and draws no random number; after particles are taken out of the
// sublayer next to the face, it puts back as many as the deficit asks for,
// into the hole they left.
TEST(QuietReservoir, CorrectsOnlyBeyondItsToleranceAndFillsTheHole) {
  const Held s = square();
  const double g = s.g, m = s.options.particle_mass;
  const double w = s.options.projection.reservoir_thickness;
  const int K = s.options.projection.reservoir_sublayers;
  const auto box = s.domain;
  const auto ext = make_box(2, Vec3(-w, 0, 0), Vec3(1, 1, 0));
  ProjectionOptions po = s.options.projection;
  po.reservoir_domain = ext;
  BoundaryProjection bp(box, {PatchCondition{0, PatchKind::Dirichlet, [g](const Vec3&, double) { return g; }, true}}, po,
                        m, s.pp.width_s);
  bp.set_mirror_walls(mirror_walls(*ext));
  ParticleSet ps(2);
  Rng rng(9);
  bp.apply(ps, 0.0, 0.0, rng);
  // The fill puts each sublayer's count in at once; the deficits measured on
  // the density it leaves are settled by a few more calls (small corrections
  // where the sublayers meet), after which nothing changes.
  int passes = 0;
  for (; passes < 10; ++passes) {
    const PatchLedger l = bp.apply(ps, 0.0, 0.0, rng);
    if (l.inserted == 0 && l.removed == 0) break;
  }
  EXPECT_LT(passes, 5);
  const long filled = bp.ledger()[0].inserted;
  ASSERT_GT(filled, 0);
  const Rng::State before = rng.state();
  const ParticleSet copy = ps;
  const PatchLedger again = bp.apply(ps, 0.0, 0.0, rng);
  EXPECT_EQ(again.inserted, 0);
  EXPECT_EQ(again.removed, 0);
  EXPECT_TRUE(ps.positions() == copy.positions());
  EXPECT_TRUE(same_stream(before, rng.state())) << "the quiet control draws no random numbers";

  // A hole: the particles of sublayer 0 within 2.5 widths of (-w/(2K), 0.5).
  const Vec3 centre(-0.5 * w / K, 0.5, 0.0);
  std::vector<std::size_t> taken;
  for (std::size_t p = 0; p < ps.size(); ++p)
    if ((ps.positions()[p] - centre).norm() < 2.5 * s.pp.width_s) taken.push_back(p);
  ASSERT_GE(taken.size(), 3u);
  std::vector<Vec3> holes;
  for (std::size_t p : taken) holes.push_back(ps.positions()[p]);
  ps.remove_indices(taken);
  {
    // The same projection with a tolerance above every sublayer's deficit
    // leaves the hole as it is.
    ProjectionOptions loose = po;
    loose.reservoir_tolerance = static_cast<double>(taken.size()) + 1.0;
    BoundaryProjection lax(box, {PatchCondition{0, PatchKind::Dirichlet, [g](const Vec3&, double) { return g; }, true}},
                           loose, m, s.pp.width_s);
    lax.set_mirror_walls(mirror_walls(*ext));
    const PatchLedger none = lax.apply(ps, 0.0, 0.0, rng);
    EXPECT_EQ(none.inserted, 0);
    EXPECT_EQ(none.removed, 0);
  }
  const PatchLedger fill = bp.apply(ps, 0.0, 0.0, rng);
  EXPECT_EQ(fill.removed, 0);
  EXPECT_GT(fill.inserted, 0) << taken.size() << " particles taken out";
  EXPECT_GE(fill.inserted, static_cast<long>(taken.size()) - 2);
  EXPECT_LE(fill.inserted, static_cast<long>(taken.size()) + 2);
  EXPECT_TRUE(same_stream(before, rng.state()));
  // The particles put back go into the hole (within a spacing of a taken
  // one), but for at most one: the hole spans several sublayers, and one of
  // them may find a larger deficit elsewhere.
  int outside = 0;
  for (std::size_t p = ps.size() - static_cast<std::size_t>(fill.inserted); p < ps.size(); ++p) {
    double nearest = 1e300;
    for (const Vec3& h : holes) nearest = std::min(nearest, (ps.positions()[p] - h).norm());
    if (nearest >= s.pp.dr) ++outside;
  }
  EXPECT_LE(outside, 1) << fill.inserted << " put back";
  // The ledger counts them.
  EXPECT_EQ(bp.ledger()[0].inserted, filled + fill.inserted);
  EXPECT_EQ(static_cast<long>(ps.size() + taken.size()), bp.ledger()[0].inserted - bp.ledger()[0].removed);
}

namespace {
// Fills from empty with 40 steps of h, then steps of factor x h until a step
// inserts and removes nothing and costs at most 3 evaluations (30 at most).
void settle(Simulation& sim, double h, double factor) {
  for (int k = 0; k < 40; ++k) sim.advance(h);
  for (int k = 0; k < 30; ++k) {
    const SimulationStep st = sim.advance(factor * h);
    if (st.inserted == 0 && st.removed == 0 && st.diffusion.evaluations <= 3) break;
  }
}
}  // namespace

// A settled state (the disc and the square at g, relaxed with steps of 1000x
// the explicit limit until a step moves nothing) is a fixed point: steps of
// 1x, 10x, 100x and 1000x insert and remove nothing, move no particle by
// more than the solver's tolerance, and cost at most 5 evaluations.
TEST(QuietReservoir, SettledStateIsAFixedPoint) {
  for (const Held& s : {disc(), square()}) {
    auto sim = s.make();
    sim->start(ParticleSet(2), 0.0);
    const double h = s.pp.dt_explicit;
    settle(*sim, h, 1000.0);
    const double tolerance = s.options.implicit.displacement_tolerance * s.pp.width_s;
    for (const double factor : {1.0, 10.0, 100.0, 1000.0}) {
      const ParticleSet before = sim->particles();
      const SimulationStep st = sim->advance(factor * h);
      EXPECT_EQ(st.inserted, 0) << factor << "x";
      EXPECT_EQ(st.removed, 0) << factor << "x";
      EXPECT_LE(st.diffusion.evaluations, 5) << factor << "x";
      EXPECT_EQ(sim->particles().size(), before.size());
      EXPECT_LE(max_displacement(before, sim->particles()), tolerance) << factor << "x";
    }
  }
}

// Issue 25 item 3: once the density stops changing, adaptive steps grow
// geometrically. The settled disc and square, stepped with advance_adaptive
// from 1x the explicit limit: the error estimate of a step that moves nothing
// is zero, so each step grows dt by the controller's max_growth (2) until
// dt_max (here 4000x, the step it was settled with: settled with 1000x
// steps, the first step beyond 2000x still relaxes the arrangement, 33-63
// evaluations, once), every step is accepted at the first try, inserts and
// removes nothing, and costs at most 5 evaluations.
TEST(QuietReservoir, SettledStateTakesGeometricallyGrowingAdaptiveSteps) {
  for (Held s : {disc(), square()}) {
    s.options.time_control.dt_max = 4000.0 * s.pp.dt_explicit;
    auto sim = s.make();
    sim->start(ParticleSet(2), 0.0);
    const double h = s.pp.dt_explicit;
    settle(*sim, h, 4000.0);
    // Two steps at 1x to give the estimate its history.
    sim->advance(h);
    sim->advance(h);
    sim->set_next_dt(h);
    const double growth = TimeStepControlOptions{}.max_growth, dt_max = 4000.0 * h;
    double expected = h;
    for (int k = 0; k < 14; ++k) {
      const SimulationStep st = sim->advance_adaptive(1e300);
      ASSERT_TRUE(st.diffusion.accepted) << st.diffusion.message;
      EXPECT_EQ(st.error_rejections, 0) << "step " << k;
      EXPECT_NEAR(st.t_end - st.t_start, expected, 1e-9 * expected) << "step " << k;
      EXPECT_EQ(st.inserted + st.removed, 0) << "step " << k;
      EXPECT_LE(st.diffusion.evaluations, 5) << "step " << k;
      expected = std::min(expected * growth, dt_max);
      if (k == 13) {
        EXPECT_EQ(sim->next_dt(), dt_max);
      }
    }
  }
}
