// The quiet control of the Dirichlet reservoir (src/reservoir.cpp,
// ProjectionOptions::reservoir_control = Quiet; the exact counts are tested in
// test_boundary.cpp): its placement density against the O(n^2) sum, the fill
// at the start, corrections only beyond the tolerance and where the density
// is lowest, no random numbers, and a settled state that is a fixed point of
// the whole step at 1x ... 1000x the explicit limit.
#include <gtest/gtest.h>
#include <omp.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <memory>
#include <iostream>
#include <numbers>
#include <vector>

#include "../src/placement_density.hpp"  // internal: checked against the O(n^2) sum
#include "otfp/density.hpp"
#include "otfp/images.hpp"
#include "otfp/mass_measure.hpp"
#include "otfp/neighbor_list.hpp"
#include "otfp/parameters.hpp"
#include "otfp/run_setup.hpp"
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
    // The integral action as setup_run() sets it: tau = 10 w^2 / kappa.
    po.reservoir_integral_time = TreatmentOptions{}.reservoir_integral * po.reservoir_thickness * po.reservoir_thickness;
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

// The reservoir's Monte Carlo volumes and candidate points, and the quiet
// control's densities at the band's particles and candidates, are computed on
// the OpenMP threads (src/reservoir.cpp, src/reservoir_quiet.cpp). The sphere
// of the example (3-D ball, n_inf = 400), filled at the start and stepped
// twice from empty (its band sheds a few hundred particles a step, each
// sublayer holding well over the 64 points from which the densities are
// shared out), must give the same particles, bit for bit, on one thread and
// on two.
TEST(QuietReservoir, SameParticlesOnOneThreadAndOnTwo) {
  Held s(make_ball(3, Vec3::Zero(), 1.0), 0, 400);
  s.options.stepper = StepperKind::Explicit;
  s.options.explicit_options.kappa = 1.0;
  s.options.explicit_options.rho_ref = 1.0;
  auto run = [&](int threads) {
    const int saved = omp_get_max_threads();
    omp_set_num_threads(threads);
    auto sim = s.make();
    sim->start(ParticleSet(3), 0.0);
    long removed = 0;
    for (int k = 0; k < 2; ++k) removed += sim->advance(s.pp.dt_explicit).removed;
    omp_set_num_threads(saved);
    EXPECT_GE(removed, 64) << "the band should shed particles, so that the removals' densities are computed";
    return sim->particles();
  };
  const ParticleSet one = run(1), two = run(2);
  ASSERT_EQ(one.size(), two.size());
  ASSERT_GT(one.size(), 1000u);
  for (std::size_t p = 0; p < one.size(); ++p) {
    ASSERT_EQ(one.ids()[p], two.ids()[p]) << p;
    ASSERT_EQ(one.positions()[p], two.positions()[p]) << "particle " << one.ids()[p];
  }
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

// A crowd: particles added to one sublayer of a filled band (the square's
// band is groups of several sublayers; a blob spans about three of them)
// are taken out again in full: the group's correction is shared among its
// sublayers by their own excess, and a sublayer asked for more than it can
// give passes the rest on. Where they leave is the rule's (largest excess
// of the blob density over its target): in a band filled by the projection
// alone, not relaxed by steps, that is partly at its side walls, not only
// at the crowd, so the test counts and does not locate.
TEST(QuietReservoir, CrowdIsTakenOutInFull) {
  const Held s = square();
  const double g = s.g, m = s.options.particle_mass;
  const double w = s.options.projection.reservoir_thickness;
  const int K = s.options.projection.reservoir_sublayers;
  ASSERT_GE(K, 4);
  const auto ext = make_box(2, Vec3(-w, 0, 0), Vec3(1, 1, 0));
  ProjectionOptions po = s.options.projection;
  po.reservoir_domain = ext;
  BoundaryProjection bp(s.domain, {PatchCondition{0, PatchKind::Dirichlet, [g](const Vec3&, double) { return g; }, true}},
                        po, m, s.pp.width_s);
  bp.set_mirror_walls(mirror_walls(*ext));
  ParticleSet ps(2);
  Rng rng(9);
  for (int pass = 0; pass < 10; ++pass) {
    const PatchLedger l = bp.apply(ps, 0.0, 0.0, rng);
    if (pass > 0 && l.inserted == 0 && l.removed == 0) break;
  }
  // The crowd: six particles along the middle of sublayer 2, y in [0.3, 0.7].
  const int j = 2, crowd = 6;
  const double depth = (j + 0.5) * w / K;
  for (int k = 0; k < crowd; ++k) ps.add(Vec3(-depth, 0.3 + 0.08 * k, 0.0), s.pp.width_s, m);
  const PatchLedger out = bp.apply(ps, 0.0, 0.0, rng);
  EXPECT_EQ(out.inserted, 0);
  EXPECT_GE(out.removed, crowd - 2);
  EXPECT_LE(out.removed, crowd + 2);
  // Nothing more to do: the next call changes nothing.
  const PatchLedger after = bp.apply(ps, 0.0, 0.0, rng);
  EXPECT_EQ(after.inserted + after.removed, 0);
}

namespace {
// Fills from empty with 40 steps of h, then steps of factor x h until a step
// inserts and removes nothing and costs at most 3 evaluations (30 at most).
// Settled: ten steps in a row at factor x h that insert, remove and move
// nothing. One quiet step is not enough: the reservoir's integral action may
// still be winding up towards its particle (a few steps at gain 1).
void settle(Simulation& sim, double h, double factor) {
  for (int k = 0; k < 40; ++k) sim.advance(h);
  int quiet = 0;
  for (int k = 0; k < 80 && quiet < 10; ++k) {
    const SimulationStep st = sim.advance(factor * h);
    quiet = st.inserted == 0 && st.removed == 0 && st.diffusion.evaluations <= 3 ? quiet + 1 : 0;
  }
  ASSERT_EQ(quiet, 10) << "not settled in 80 steps";
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

namespace {

// A 1-D slab [0, 1] held at g on x = 0 (the reservoir's integral action
// over tau = integral_time w^2 / kappa), its interior started at 0.9 g.
struct Slab {
  Held s{make_box(1, Vec3(0, 0, 0), Vec3(1, 0, 0)), 0, 50};
  double dt = 0.0;
  explicit Slab(double integral_time) {
    const double w = s.options.projection.reservoir_thickness;
    s.options.projection.reservoir_integral_time = integral_time * w * w;  // kappa = 1
    dt = 10.0 * s.pp.dt_explicit;
  }
  std::unique_ptr<Simulation> start() const {
    ParticleSet fill(1);
    const int n0 = 45;  // 0.9 g |Omega| / m_p
    for (int i = 0; i < n0; ++i) fill.add(Vec3((i + 0.5) / n0, 0, 0), s.pp.width_s, s.options.particle_mass);
    auto sim = s.make();
    sim->start(fill, 0.0);
    return sim;
  }
  void run_to(Simulation& sim, double t) const {
    while (sim.time() < t - 0.5 * dt) sim.advance(dt);
  }
  static double mass_inside(const Simulation& sim) {
    double m = 0.0;
    const ParticleSet& ps = sim.particles();
    for (std::size_t p = 0; p < ps.size(); ++p)
      m += ps.masses()[p] * gaussian_in_interval(ps.positions()[p][0], ps.widths()[p], 0.0, 1.0);
    return m;
  }
};

}  // namespace

// The slab's band of about four particles must feed the interior the
// missing tenth. Within its tolerance of one particle the tolerance rule
// alone lets the band rest up to a quarter short, and the slab settles ~10%
// low; the integral action keeps inserting until the deficit averages to
// zero, and the slab settles at g |Omega| within its quantum of one particle
// (0.02). The steady state is known exactly: rho = g, M = g |Omega| = 1.
// T = 2: the slab's slowest mode, exp(-kappa (pi / 2)^2 t), is down to 0.7%.
TEST(QuietReservoir, IntegralActionLeavesNoRestingDeficit) {
  const auto settle = [](double integral_time) {
    const Slab slab(integral_time);
    auto sim = slab.start();
    slab.run_to(*sim, 2.0);
    return Slab::mass_inside(*sim);
  };
  const double with_integral = settle(10.0);
  const double tolerance_only = settle(0.0);
  EXPECT_NEAR(with_integral, 1.0, 0.02);
  EXPECT_LT(tolerance_only, 0.97) << "the tolerance rule alone leaves the deficit (else this case tests nothing)";
}

// The integral lives in the projection's state: a checkpoint mid-way
// continues bit for bit.
TEST(QuietReservoir, IntegralActionResumesBitForBit) {
  const Slab slab(10.0);
  auto a = slab.start();
  slab.run_to(*a, 0.5);
  double owed = 0.0;
  for (int j = 0; j < a->projection().reservoir_sublayer_count(0); ++j) owed += std::abs(a->projection().reservoir_carry(0, j));
  EXPECT_GT(owed, 0.0) << "the checkpoint holds a part of a particle owed";
  const std::string file = (std::filesystem::temp_directory_path() / "otfp_integral_resume.ckpt").string();
  a->save_checkpoint(file, "");
  slab.run_to(*a, 1.0);
  auto b = slab.s.make();
  b->load_checkpoint(file, nullptr);
  slab.run_to(*b, 1.0);
  std::filesystem::remove(file);
  ASSERT_EQ(a->particles().size(), b->particles().size());
  EXPECT_GT(a->ledger().inserted, 4) << "the band was fed after the fill";
  EXPECT_EQ(max_displacement(a->particles(), b->particles()), 0.0);
  for (int j = 0; j < a->projection().reservoir_sublayer_count(0); ++j)
    EXPECT_EQ(a->projection().reservoir_carry(0, j), b->projection().reservoir_carry(0, j)) << "sublayer " << j;
}
