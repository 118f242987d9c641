#include "otfp/boundary.hpp"
#include "otfp/run_setup.hpp"
#include "otfp/simulation.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <limits>
#include <numbers>
#include <set>
#include <string>
#include <vector>

using namespace otfp;

namespace {

constexpr double kPi = std::numbers::pi;

BoundaryData constant(double v) {
  return [v](const Vec3&, double) { return v; };
}

PatchCondition condition(int patch, PatchKind kind, BoundaryData data = {}, bool is_constant = true) {
  PatchCondition c;
  c.patch = patch;
  c.kind = kind;
  c.data = std::move(data);
  c.data_is_constant = is_constant;
  return c;
}

ProjectionOptions options_with_b(double b) {
  ProjectionOptions o;
  o.layer_b = b;
  return o;
}

// Mass of the particles in a layer cell.
double cell_mass(const ParticleSet& ps, const Domain& d, int patch, double b, LayerPart part) {
  double m = 0.0;
  for (std::size_t p = 0; p < ps.size(); ++p)
    if (d.in_layer_cell(ps.positions()[p], patch, b, part)) m += ps.masses()[p];
  return m;
}

// The call must throw InvalidArgument whose message names `field`.
void expect_invalid(const std::function<void()>& call, const std::string& field) {
  try {
    call();
    ADD_FAILURE() << "no InvalidArgument for " << field;
  } catch (const InvalidArgument& e) {
    EXPECT_NE(std::string(e.what()).find(field), std::string::npos) << "message: " << e.what();
  }
}

}  // namespace

// --------------------------------------------------------------------------- kinds

TEST(BoundaryProjection, KindStringsRoundTrip) {
  for (PatchKind k : {PatchKind::NoFlux, PatchKind::Dirichlet, PatchKind::Neumann})
    EXPECT_EQ(patch_kind_from_string(to_string(k)), k);
  EXPECT_EQ(to_string(PatchKind::NoFlux), "no_flux");
  EXPECT_EQ(to_string(PatchKind::Dirichlet), "dirichlet");
  EXPECT_EQ(to_string(PatchKind::Neumann), "neumann");
}

TEST(BoundaryProjection, DirichletPatchesListsOnlyDirichlet) {
  const auto box = make_box(3, Vec3(0, 0, 0), Vec3(1, 1, 1));
  BoundaryProjection bp(box,
                        {condition(4, PatchKind::Dirichlet, constant(1.0)), condition(0, PatchKind::NoFlux),
                         condition(1, PatchKind::Neumann, constant(-1.0)),
                         condition(2, PatchKind::Dirichlet, constant(2.0))},
                        options_with_b(0.1), 0.01, 0.05);
  EXPECT_EQ(bp.dirichlet_patches(), (std::vector<int>{4, 2}));
  EXPECT_EQ(bp.ledger().size(), 4u);
}

// --------------------------------------------------------------------------- Dirichlet

// docs/method_notes.md#dirichlet-target: unit sphere, n_inf = 1600, b = 0.29. The inner shell holds
// 2.70 volume units, (34) assumes 4 pi b = 3.64.
TEST(BoundaryProjection, DirichletFillsEmptyShellToTarget) {
  const double g = 0.238732, b = 0.29, mp = 1.0 / 1600.0, s = 0.05, dt = 0.01;
  const auto ball = make_ball(3, Vec3::Zero(), 1.0);
  BoundaryProjection bp(ball, {condition(0, PatchKind::Dirichlet, constant(g))}, options_with_b(b), mp, s);

  const double shell = 4.0 / 3.0 * kPi * (1.0 - std::pow(1.0 - b, 3));
  const double target = bp.dirichlet_target_mass(0, dt);
  EXPECT_NEAR(target, g * shell, 1e-12 * g * shell);

  ParticleSet ps(3);
  Rng rng(11);
  const PatchLedger call = bp.apply(ps, 0.0, dt, rng);

  // Floor rule of Sec. 4.2: the cell ends within one particle below the target.
  const double m_int = cell_mass(ps, *ball, 0, b, LayerPart::Interior);
  EXPECT_LE(m_int, target + 1e-9 * mp);
  EXPECT_GT(m_int, target - mp);
  EXPECT_EQ(static_cast<long>(ps.size()), static_cast<long>(std::floor(target / mp)));
  for (std::size_t p = 0; p < ps.size(); ++p) {
    EXPECT_TRUE(ball->in_layer_cell(ps.positions()[p], 0, b, LayerPart::Interior)) << "particle " << p;
    EXPECT_EQ(ps.masses()[p], mp);
    EXPECT_EQ(ps.widths()[p], s);
    EXPECT_EQ(ps.birth_times()[p], dt);
  }
  EXPECT_EQ(call.inserted, static_cast<long>(ps.size()));
  EXPECT_EQ(bp.ledger()[0].inserted, static_cast<long>(ps.size()));
  EXPECT_EQ(bp.ledger()[0].removed, 0);
  EXPECT_NEAR(bp.ledger()[0].mass_inserted, ps.total_mass(), 1e-12);

  // Already at target: a second projection changes nothing.
  const PatchLedger again = bp.apply(ps, dt, dt, rng);
  EXPECT_EQ(again.inserted + again.removed, 0);

  // A target of 1075.83 particles: the floor, not rounding to nearest.
  BoundaryProjection bp2(ball, {condition(0, PatchKind::Dirichlet, constant(0.25))}, options_with_b(b), mp, s);
  const double ratio = bp2.dirichlet_target_mass(0, 0.0) / mp;
  ASSERT_GT(ratio - std::floor(ratio), 0.5);
  ParticleSet ps2(3);
  bp2.apply(ps2, 0.0, 0.0, rng);
  EXPECT_EQ(static_cast<double>(ps2.size()), std::floor(ratio));

  // The paper's (34) over-fills the curved layer by about 36%.
  ProjectionOptions paper = options_with_b(b);
  paper.dirichlet_target = DirichletTarget::PaperEq34;
  BoundaryProjection bp34(ball, {condition(0, PatchKind::Dirichlet, constant(g))}, paper, mp, s);
  const double target34 = bp34.dirichlet_target_mass(0, dt);
  EXPECT_NEAR(target34, g * 4.0 * kPi * b, 1e-12);
  EXPECT_NEAR(target34 / target, 4.0 * kPi * b / shell, 1e-12);
  EXPECT_GT(target34 / target, 1.3);
}

TEST(BoundaryProjection, DirichletEmptiesOverfullLayerToTarget) {
  const double g = 0.238732, b = 0.29, mp = 1.0 / 1600.0;
  const auto ball = make_ball(3, Vec3::Zero(), 1.0);
  BoundaryProjection bp(ball, {condition(0, PatchKind::Dirichlet, constant(g))}, options_with_b(b), mp, 0.05);
  const double target = bp.dirichlet_target_mass(0, 0.0);

  ParticleSet ps(3);
  Rng fill(5);
  const long n_layer = static_cast<long>(2.0 * target / mp);  // twice the target
  std::vector<ParticleId> layer_ids;
  for (long k = 0; k < n_layer; ++k)
    layer_ids.push_back(ps.add(ball->sample_layer_cell(0, b, LayerPart::Interior, fill), 0.05, mp));
  std::vector<ParticleId> core_ids;
  for (int k = 0; k < 500; ++k) {
    Vec3 x = ball->sample_interior(fill);
    while (x.norm() > 0.6) x = ball->sample_interior(fill);
    core_ids.push_back(ps.add(x, 0.05, mp));
  }
  const std::size_t n_before = ps.size();

  Rng rng(6);
  const PatchLedger call = bp.apply(ps, 0.0, 0.0, rng);
  const double m_int = cell_mass(ps, *ball, 0, b, LayerPart::Interior);
  EXPECT_GE(m_int, target - 1e-9 * mp);
  EXPECT_LT(m_int, target + mp);
  EXPECT_EQ(call.inserted, 0);
  EXPECT_EQ(call.removed, static_cast<long>(n_before - ps.size()));
  EXPECT_EQ(bp.ledger()[0].removed, call.removed);
  EXPECT_NEAR(bp.ledger()[0].mass_removed, call.removed * mp, 1e-12);
  EXPECT_GT(call.removed, n_layer / 3);
  for (ParticleId id : core_ids) EXPECT_GE(ps.index_of(id), 0) << "core particle " << id << " was removed";

  // Deletion is random over the cell: survivors are spread over the whole id
  // range, not taken from one end.
  long first_half = 0, second_half = 0;
  for (std::size_t k = 0; k < layer_ids.size(); ++k)
    if (ps.index_of(layer_ids[k]) >= 0) (k < layer_ids.size() / 2 ? first_half : second_half) += 1;
  const double share = static_cast<double>(first_half) / static_cast<double>(first_half + second_half);
  EXPECT_NEAR(share, 0.5, 0.06);
}

// A target that depends on x: g = 1 + y on the x- face of the unit cube. The
// cell and the face are symmetric under y -> 1 - y, so the mean of g is 1.5.
TEST(BoundaryProjection, DirichletNonConstantTargetUsesQuadrature) {
  const double b = 0.1;
  const auto box = make_box(3, Vec3(0, 0, 0), Vec3(1, 1, 1));
  const BoundaryData g = [](const Vec3& x, double) { return 1.0 + x.y(); };
  ProjectionOptions o = options_with_b(b);
  o.quadrature_samples = 40000;
  BoundaryProjection bp(box, {condition(0, PatchKind::Dirichlet, g, false)}, o, 0.01, 0.05);
  const double vol = box->layer_cell_volume(0, b, LayerPart::Interior);
  // Standard error of the mean of 1 + y (sd ~ 0.29) with 4e4 points is 1.4e-3.
  EXPECT_NEAR(bp.dirichlet_target_mass(0, 0.0), 1.5 * vol, 6e-3 * vol);
  // Fixed seed: the same target every call.
  EXPECT_EQ(bp.dirichlet_target_mass(0, 0.0), bp.dirichlet_target_mass(0, 0.0));

  o.dirichlet_target = DirichletTarget::PaperEq34;
  BoundaryProjection bp34(box, {condition(0, PatchKind::Dirichlet, g, false)}, o, 0.01, 0.05);
  EXPECT_NEAR(bp34.dirichlet_target_mass(0, 0.0), 1.5 * b, 6e-3 * b);
}

// --------------------------------------------------------------------------- Neumann

// docs/method_notes.md#neumann-carry: 0.37 particles of inflow per step. (50) floors that to 0
// every step; the carried remainder moves 370 particles in 1000 steps.
TEST(BoundaryProjection, NeumannInflowCarriesFractionalRemainder) {
  const double mp = 0.01, dt = 0.01, b = 0.1;
  const auto box = make_box(3, Vec3(0, 0, 0), Vec3(1, 1, 1));
  const double area = box->patch_area(0);
  const double f = -0.37 * mp / (area * dt);  // outward flux < 0: inflow
  BoundaryProjection bp(box, {condition(1, PatchKind::NoFlux), condition(0, PatchKind::Neumann, constant(f))},
                        options_with_b(b), mp, 0.05);

  const double per_step = -f * area * dt / mp;
  ASSERT_NEAR(per_step, 0.37, 1e-12);
  EXPECT_EQ(std::floor(per_step), 0.0);  // what (50) would insert per step

  ParticleSet ps(3);
  Rng rng(21);
  for (int k = 0; k < 1000; ++k) {
    const PatchLedger call = bp.apply(ps, k * dt, dt, rng);
    ASSERT_LE(call.inserted, 1);
    const PatchLedger& led = bp.ledger()[1];
    ASSERT_LT(std::abs(led.mass_inserted - led.flux_integral), mp) << "step " << k;
    ASSERT_LE(std::abs(led.mass_inserted - led.mass_removed + led.carry - led.flux_integral),
              1e-9 * std::max(led.flux_integral, mp))
        << "step " << k;
    ASSERT_EQ(led.removed, 0);
    ASSERT_EQ(led.deficit, 0.0);
    ASSERT_EQ(static_cast<long>(ps.size()), led.inserted);
  }
  EXPECT_NEAR(bp.ledger()[1].flux_integral, 3.7, 1e-9);
  EXPECT_EQ(bp.ledger()[1].inserted, 370);
  EXPECT_EQ(bp.ledger()[0].inserted + bp.ledger()[0].removed, 0);  // the no-flux patch
  // Inserted uniformly in the whole B_l (Algorithm 1, line 18), so the share
  // outside Omega is |B_l^ext| / |B_l| (0.59 here, +-0.025 binomial sd).
  long outside = 0;
  for (std::size_t p = 0; p < ps.size(); ++p) {
    EXPECT_TRUE(box->in_layer_cell(ps.positions()[p], 0, b, LayerPart::Whole)) << "particle " << p;
    if (!box->contains(ps.positions()[p])) ++outside;
  }
  const double ext_share =
      box->layer_cell_volume(0, b, LayerPart::Exterior) / box->layer_cell_volume(0, b, LayerPart::Whole);
  EXPECT_NEAR(static_cast<double>(outside) / static_cast<double>(ps.size()), ext_share, 0.1);
}

// f(x, t) = -(1 + y) t on the x- face: the inflow over [0, 1] is
// int_0^1 1.5 t dt = 0.75. Simpson is exact in t; a left Riemann sum in steps
// of 0.1 would give 0.675.
TEST(BoundaryProjection, NeumannTimeDependentFluxIsIntegratedInTime) {
  const auto box = make_box(3, Vec3(0, 0, 0), Vec3(1, 1, 1));
  const BoundaryData f = [](const Vec3& x, double t) { return -(1.0 + x.y()) * t; };
  ProjectionOptions o = options_with_b(0.1);
  o.quadrature_samples = 40000;
  BoundaryProjection bp(box, {condition(0, PatchKind::Neumann, f, false)}, o, 0.01, 0.05);
  ParticleSet ps(3);
  Rng rng(3);
  for (int k = 0; k < 10; ++k) bp.apply(ps, 0.1 * k, 0.1, rng);
  const PatchLedger& led = bp.ledger()[0];
  EXPECT_NEAR(led.flux_integral, 0.75, 0.75 * 6e-3);
  EXPECT_NEAR(led.mass_inserted - led.mass_removed + led.carry, led.flux_integral, 1e-12);
  EXPECT_EQ(led.inserted, static_cast<long>(ps.size()));
}

// The time quadrature of the flux is Simpson's rule, exact for f quadratic in
// t: f = -3 t^2 (uniform over the x- face, area 1; inflow) brings exactly
// int_a^b 3 t^2 dt = b^3 - a^3 in one step, and 1 over ten steps to t = 1.
// (The test above, with f linear in t, cannot tell Simpson from the midpoint
// or the trapezoid rule, and its spatial Monte Carlo hides small weights.)
TEST(BoundaryProjection, NeumannFluxQuadratureIsExactForQuadraticTime) {
  const auto box = make_box(3, Vec3(0, 0, 0), Vec3(1, 1, 1));
  const BoundaryData f = [](const Vec3&, double t) { return -3.0 * t * t; };
  {
    BoundaryProjection bp(box, {condition(0, PatchKind::Neumann, f, false)}, options_with_b(0.1), 0.01, 0.05);
    ParticleSet ps(3);
    Rng rng(5);
    bp.apply(ps, 0.2, 0.5, rng);
    const double exact = 0.7 * 0.7 * 0.7 - 0.2 * 0.2 * 0.2;  // 0.335
    // (Up to rounding: f is averaged over the quadrature's 200000 points.)
    EXPECT_NEAR(bp.ledger()[0].flux_integral, exact, 1e-10);
  }
  BoundaryProjection bp(box, {condition(0, PatchKind::Neumann, f, false)}, options_with_b(0.1), 0.01, 0.05);
  ParticleSet ps(3);
  Rng rng(6);
  for (int k = 0; k < 10; ++k) bp.apply(ps, 0.1 * k, 0.1, rng);
  const PatchLedger& led = bp.ledger()[0];
  EXPECT_NEAR(led.flux_integral, 1.0, 1e-10);
  EXPECT_NEAR(led.mass_inserted - led.mass_removed + led.carry, led.flux_integral, 1e-12);
  EXPECT_EQ(led.inserted, static_cast<long>(ps.size()));
}

// Outflow of 0.37 particles per step through the x+ face, with only 5
// particles in B_l: the rest is owed, never lost, and paid once particles come.
TEST(BoundaryProjection, NeumannOutflowRecordsDeficitWithoutLosingMass) {
  const double mp = 0.01, dt = 0.01, b = 0.1;
  const auto box = make_box(3, Vec3(0, 0, 0), Vec3(1, 1, 1));
  const double f = 0.37 * mp / (box->patch_area(1) * dt);
  BoundaryProjection bp(box, {condition(1, PatchKind::Neumann, constant(f))}, options_with_b(b), mp, 0.05);

  ParticleSet ps(3);
  Rng fill(8);
  for (int k = 0; k < 5; ++k) ps.add(box->sample_layer_cell(1, b, LayerPart::Interior, fill), 0.05, mp);
  std::vector<ParticleId> core;
  for (int k = 0; k < 100; ++k)
    core.push_back(ps.add(Vec3(fill.uniform(0.3, 0.5), fill.uniform(0.3, 0.5), fill.uniform(0.3, 0.5)), 0.05, mp));
  const long n0 = static_cast<long>(ps.size());

  Rng rng(9);
  for (int k = 0; k < 100; ++k) {
    bp.apply(ps, k * dt, dt, rng);
    const PatchLedger& led = bp.ledger()[0];
    ASSERT_EQ(static_cast<long>(ps.size()), n0 + led.inserted - led.removed) << "step " << k;
    ASSERT_NEAR(led.mass_inserted - led.mass_removed + led.carry, led.flux_integral, 1e-12) << "step " << k;
  }
  const PatchLedger led = bp.ledger()[0];
  EXPECT_EQ(led.removed, 5);
  EXPECT_EQ(led.inserted, 0);
  EXPECT_NEAR(led.flux_integral, -0.37, 1e-12);
  EXPECT_NEAR(led.carry, -0.32, 1e-12);  // 37 particles owed, 5 paid
  EXPECT_EQ(led.deficit, -led.carry);
  for (ParticleId id : core) EXPECT_GE(ps.index_of(id), 0);

  // Particles reach the layer: the debt is paid in one step.
  for (int k = 0; k < 50; ++k) ps.add(box->sample_layer_cell(1, b, LayerPart::Interior, fill), 0.05, mp);
  const long n1 = static_cast<long>(ps.size());
  const PatchLedger call = bp.apply(ps, 100 * dt, dt, rng);
  EXPECT_EQ(call.removed, 32);  // 37.37 owed in total: 37 whole particles
  EXPECT_EQ(bp.ledger()[0].removed, 37);
  EXPECT_EQ(static_cast<long>(ps.size()), n1 - 32);
  EXPECT_EQ(bp.ledger()[0].deficit, 0.0);
  EXPECT_NEAR(bp.ledger()[0].carry, -0.37 * mp, 1e-12);
  EXPECT_EQ(call.deficit, 0.0);
}

// Inlet on cap_a and an outlet disc on cap_b with the same mass rate. Between
// projections the particles are redistributed uniformly (a stand-in for
// diffusion), so the outlet always has particles. Total mass must stay within
// the two carried remainders of its initial value.
TEST(BoundaryProjection, MixedInflowOutflowConservesMassOnCylinder) {
  const double mp = 0.001, dt = 0.01, b = 0.1, rate = 0.6 * mp / dt;
  const auto cyl = make_with_subpatches(make_cylinder(Vec3(0, 0, 0), Vec3(0, 0, 2), 0.5),
                                        {SubPatch{2, Vec3(0, 0, 2), 0.25, "outlet"}});
  const int outlet = cyl->patch_by_name("outlet");
  ASSERT_EQ(outlet, 3);
  const double f_in = -rate / cyl->patch_area(1), f_out = rate / cyl->patch_area(outlet);
  BoundaryProjection bp(cyl,
                        {condition(0, PatchKind::NoFlux), condition(1, PatchKind::Neumann, constant(f_in)),
                         condition(2, PatchKind::NoFlux), condition(outlet, PatchKind::Neumann, constant(f_out))},
                        options_with_b(b), mp, 0.05);

  ParticleSet ps(3);
  Rng rng(17);
  for (int k = 0; k < 2000; ++k) ps.add(cyl->sample_interior(rng), 0.05, mp);
  const double m0 = ps.total_mass();
  for (int k = 0; k < 300; ++k) {
    for (Vec3& x : ps.positions()) x = cyl->sample_interior(rng);
    const PatchLedger call = bp.apply(ps, k * dt, dt, rng);
    ASSERT_EQ(call.deficit, 0.0) << "step " << k;
    ASSERT_LE(std::abs(ps.total_mass() - m0), 2.0 * mp + 1e-9) << "step " << k;
  }
  const PatchLedger& in = bp.ledger()[1];
  const PatchLedger& out = bp.ledger()[3];
  EXPECT_NEAR(in.flux_integral, 1.8 * mp * 100, 1e-9);  // 0.6 particles x 300 steps
  EXPECT_NEAR(out.flux_integral, -in.flux_integral, 1e-9);
  EXPECT_NEAR(in.inserted, 180, 1);
  EXPECT_NEAR(out.removed, 180, 1);
  EXPECT_EQ(in.removed, 0);
  EXPECT_EQ(out.inserted, 0);
}

// --------------------------------------------------------------------------- input checks

TEST(BoundaryProjection, BadInputNamesTheField) {
  const auto box = make_box(3, Vec3(0, 0, 0), Vec3(1, 1, 1));
  const ProjectionOptions ok = options_with_b(0.1);
  auto build = [&](std::vector<PatchCondition> cs, ProjectionOptions o = options_with_b(0.1), double mp = 0.01,
                   double s = 0.05, DomainPtr d = nullptr) {
    BoundaryProjection bp(d ? d : box, std::move(cs), o, mp, s);
  };

  expect_invalid([] { patch_kind_from_string("robin"); }, "boundary.kind = 'robin'");
  expect_invalid([] { patch_kind_from_string("robin"); }, "must be one of no_flux, dirichlet, neumann");
  expect_invalid([&] { build({condition(6, PatchKind::NoFlux)}); }, "boundary.patch");
  expect_invalid([&] { build({condition(-1, PatchKind::NoFlux)}); }, "boundary.patch");
  expect_invalid([&] { build({condition(2, PatchKind::Neumann, constant(1.0)), condition(2, PatchKind::NoFlux)}); },
                 "more than once");
  expect_invalid([&] { build({condition(0, PatchKind::Dirichlet)}); }, "boundary.data");
  expect_invalid([&] { build({condition(0, PatchKind::Neumann)}); }, "boundary.data");
  for (double b : {0.0, -0.1, std::numeric_limits<double>::quiet_NaN(), std::numeric_limits<double>::infinity()})
    expect_invalid([&] { build({}, options_with_b(b)); }, "boundary.layer_b");
  ProjectionOptions few = ok;
  few.quadrature_samples = 999;
  expect_invalid([&] { build({}, few); }, "boundary.quadrature_samples");
  expect_invalid([&] { build({}, ok, 0.0); }, "boundary.particle_mass");
  expect_invalid([&] { build({}, ok, 0.01, -1.0); }, "boundary.width_s");
  expect_invalid([&] { BoundaryProjection bp(nullptr, {}, ok, 0.01, 0.05); }, "boundary.domain");
  // A periodic box has no patches at all.
  expect_invalid([&] { build({condition(0, PatchKind::NoFlux)}, ok, 0.01, 0.05,
                             make_periodic_box(3, Vec3(0, 0, 0), Vec3(1, 1, 1))); },
                 "boundary.patch");

  BoundaryProjection bp(box, {condition(0, PatchKind::Neumann, constant(-1.0))}, ok, 0.01, 0.05);
  ParticleSet flat(2);
  Rng rng(1);
  expect_invalid([&] { bp.apply(flat, 0.0, 0.1, rng); }, "particle dim");
  ParticleSet ps(3);
  expect_invalid([&] { bp.apply(ps, 0.0, -0.1, rng); }, "dt");
  expect_invalid([&] { bp.dirichlet_target_mass(0, 0.0); }, "must be dirichlet");
  expect_invalid([&] { bp.dirichlet_target_mass(5, 0.0); }, "boundary condition index");
  // A NoFlux patch needs no data.
  EXPECT_NO_THROW(build({condition(3, PatchKind::NoFlux)}));
}

// =========================================================================== issue 10 options

namespace {

ProjectionOptions reservoir_options(DomainPtr ext, double w, int sublayers) {
  ProjectionOptions o = options_with_b(0.1);
  o.dirichlet_mode = DirichletMode::Reservoir;
  o.reservoir_domain = std::move(ext);
  o.reservoir_thickness = w;
  o.reservoir_sublayers = sublayers;
  o.reservoir_control = ReservoirControl::Exact;  // these tests are of the exact counts (tests/test_reservoir.cpp: quiet)
  return o;
}

// Sublayer of a point at depth sd outside Omega, computed independently of the
// library: j with sd in (j w / K, (j + 1) w / K], -1 outside the band.
int sublayer_index(double sd, double w, int K) {
  if (!(sd > 0.0) || sd > w) return -1;
  for (int j = 0; j < K; ++j)
    if (sd <= w * (j + 1) / K) return j;
  return K - 1;
}

// Counts per sublayer of the unit-ball reservoir (sd = |x| - R).
std::vector<long> ball_sublayer_counts(const ParticleSet& ps, double R, double w, int K) {
  std::vector<long> n(static_cast<std::size_t>(K), 0);
  for (const Vec3& x : ps.positions()) {
    const int j = sublayer_index(x.norm() - R, w, K);
    if (j >= 0) ++n[static_cast<std::size_t>(j)];
  }
  return n;
}

double shell_volume(double r0, double r1) { return 4.0 / 3.0 * kPi * (r1 * r1 * r1 - r0 * r0 * r0); }

}  // namespace

TEST(BoundaryProjection, OptionStringsRoundTrip) {
  for (NeumannOutflow m : {NeumannOutflow::Layer, NeumannOutflow::NearestParticles})
    EXPECT_EQ(neumann_outflow_from_string(to_string(m)), m);
  for (DirichletMode m : {DirichletMode::Layer, DirichletMode::Reservoir})
    EXPECT_EQ(dirichlet_mode_from_string(to_string(m)), m);
  EXPECT_EQ(to_string(NeumannOutflow::NearestParticles), "nearest_particles");
  EXPECT_EQ(to_string(DirichletMode::Reservoir), "reservoir");
  const ProjectionOptions d;
  EXPECT_EQ(d.neumann_outflow, NeumannOutflow::Layer);
  EXPECT_EQ(d.dirichlet_mode, DirichletMode::Layer);
  EXPECT_FALSE(d.absorb_exterior);
}

// --------------------------------------------------------------------------- reservoir

// Unit ball, Dirichlet surface, band of w = 0.15 in K = 3 sublayers of 0.05.
// Targets from the exact shell volumes; the first call fills each sublayer to
// floor(X_j) (carry 0) with particles only in the band.
TEST(BoundaryProjection, ReservoirHoldsEachSublayerAtItsTarget) {
  const double R = 1.0, w = 0.15, g = 0.238732, mp = 1.0 / 1600.0, s = 0.05, dt = 0.01;
  const int K = 3;
  const auto ball = make_ball(3, Vec3::Zero(), R);
  BoundaryProjection bp(ball, {condition(0, PatchKind::Dirichlet, constant(g))},
                        reservoir_options(make_ball(3, Vec3::Zero(), R + w), w, K), mp, s);
  ASSERT_EQ(bp.reservoir_sublayer_count(0), K);
  EXPECT_EQ(bp.reservoir_volume_rule(0), "exterior_shell");
  std::vector<double> X(K);
  for (int j = 0; j < K; ++j) {
    const double vol = shell_volume(R + w * j / K, R + w * (j + 1) / K);
    EXPECT_NEAR(bp.reservoir_sublayer_volume(0, j), vol, 1e-12 * vol) << "sublayer " << j;
    X[static_cast<std::size_t>(j)] = g * vol / mp;
    EXPECT_NEAR(bp.reservoir_target_count(0, j, dt), X[static_cast<std::size_t>(j)], 1e-9);
  }

  ParticleSet ps(3);
  Rng rng(41);
  const PatchLedger call = bp.apply(ps, 0.0, dt, rng);
  const std::vector<long> n = ball_sublayer_counts(ps, R, w, K);
  long sum = 0;
  for (int j = 0; j < K; ++j) {
    const auto jj = static_cast<std::size_t>(j);
    EXPECT_EQ(n[jj], static_cast<long>(std::floor(X[jj]))) << "sublayer " << j;
    EXPECT_LT(std::abs(static_cast<double>(n[jj]) - X[jj]), 1.0);
    EXPECT_NEAR(bp.reservoir_carry(0, j), X[jj] - std::floor(X[jj]), 1e-9);
    sum += n[jj];
  }
  for (std::size_t p = 0; p < ps.size(); ++p) {
    const double r = ps.positions()[p].norm();
    ASSERT_GT(r, R) << "particle " << p << " inside Omega";
    ASSERT_LE(r, R + w) << "particle " << p << " beyond the band";
    ASSERT_EQ(ps.birth_times()[p], dt);
  }
  EXPECT_EQ(sum, static_cast<long>(ps.size()));
  EXPECT_EQ(call.inserted, sum);
  EXPECT_EQ(bp.ledger()[0].inserted, sum);
  EXPECT_EQ(bp.ledger()[0].removed, 0);
  EXPECT_NEAR(bp.ledger()[0].mass_inserted, ps.total_mass(), 1e-12);
  // The band is filled evenly: the outer sublayer is the largest, and the
  // count per unit volume is g / m_p in each.
  for (int j = 0; j < K; ++j)
    EXPECT_NEAR(n[static_cast<std::size_t>(j)] * mp / bp.reservoir_sublayer_volume(0, j), g,
                mp / bp.reservoir_sublayer_volume(0, j));
}

// Integer targets (box face, exact slabs of 0.1 x 1 x 1, g = 0.5, m_p = 1e-3:
// 50 particles each): once filled, apply() without motion changes nothing.
// Non-integer targets (ball): each call changes a sublayer by at most one
// particle and the count averaged over calls is X_j (error diffusion).
TEST(BoundaryProjection, ReservoirRepeatedApplyWithoutMotion) {
  {
    const double w = 0.3;
    const auto box = make_box(3, Vec3(0, 0, 0), Vec3(1, 1, 1));
    const auto ext = make_box(3, Vec3(-w, 0, 0), Vec3(1, 1, 1));
    BoundaryProjection bp(box, {condition(0, PatchKind::Dirichlet, constant(0.5))}, reservoir_options(ext, w, 3),
                          1e-3, 0.05);
    ParticleSet ps(3);
    Rng rng(3);
    EXPECT_EQ(bp.apply(ps, 0.0, 0.1, rng).inserted, 150);
    for (int k = 1; k <= 10; ++k) {
      const PatchLedger call = bp.apply(ps, 0.1 * k, 0.1, rng);
      EXPECT_EQ(call.inserted, 0) << "call " << k;
      EXPECT_EQ(call.removed, 0) << "call " << k;
    }
    EXPECT_EQ(ps.size(), 150u);
  }
  const double R = 1.0, w = 0.15, g = 0.238732, mp = 1.0 / 1600.0;
  const int K = 3, calls = 200;
  const auto ball = make_ball(3, Vec3::Zero(), R);
  BoundaryProjection bp(ball, {condition(0, PatchKind::Dirichlet, constant(g))},
                        reservoir_options(make_ball(3, Vec3::Zero(), R + w), w, K), mp, 0.05);
  ParticleSet ps(3);
  Rng rng(5);
  bp.apply(ps, 0.0, 0.0, rng);
  std::vector<long> prev = ball_sublayer_counts(ps, R, w, K);
  std::vector<double> mean(K, 0.0);
  for (int k = 0; k < calls; ++k) {
    bp.apply(ps, 0.0, 0.0, rng);
    const std::vector<long> n = ball_sublayer_counts(ps, R, w, K);
    for (std::size_t j = 0; j < static_cast<std::size_t>(K); ++j) {
      ASSERT_LE(std::abs(n[j] - prev[j]), 1) << "call " << k << " sublayer " << j;
      mean[j] += static_cast<double>(n[j]) / calls;
    }
    prev = n;
  }
  for (int j = 0; j < K; ++j)
    EXPECT_NEAR(mean[static_cast<std::size_t>(j)], bp.reservoir_target_count(0, j, 0.0), 1.0 / calls + 1e-9)
        << "sublayer " << j;
}

// Beyond Omega_ext on a Dirichlet patch: absorbed and counted. Outside a
// no-flux wall (the barrier's business) and in the band: kept.
TEST(BoundaryProjection, ReservoirAbsorbsParticlesBeyondItsDomain) {
  const double w = 0.3, mp = 1e-3;
  const auto box = make_box(3, Vec3(0, 0, 0), Vec3(1, 1, 1));
  const auto ext = make_box(3, Vec3(-w, 0, 0), Vec3(1, 1, 1));
  BoundaryProjection bp(box, {condition(2, PatchKind::NoFlux), condition(0, PatchKind::Dirichlet, constant(0.5))},
                        reservoir_options(ext, w, 3), mp, 0.05);
  ParticleSet ps(3);
  const ParticleId beyond = ps.add(Vec3(-0.4, 0.5, 0.5), 0.05, mp);
  const ParticleId beside = ps.add(Vec3(-0.2, -0.05, 0.5), 0.05, 2.0 * mp);  // outside ext's y- side, patch x-
  const ParticleId wall = ps.add(Vec3(0.5, -0.05, 0.5), 0.05, mp);           // outside the no-flux y- wall
  const ParticleId band = ps.add(Vec3(-0.15, 0.5, 0.5), 0.05, mp);           // sublayer 1
  Rng rng(7);
  const PatchLedger call = bp.apply(ps, 0.0, 0.1, rng);
  EXPECT_LT(ps.index_of(beyond), 0);
  EXPECT_LT(ps.index_of(beside), 0);
  EXPECT_GE(ps.index_of(wall), 0);
  EXPECT_GE(ps.index_of(band), 0);
  EXPECT_EQ(call.absorbed, 2);
  EXPECT_NEAR(call.mass_absorbed, 3.0 * mp, 1e-15);
  EXPECT_EQ(call.removed, 2);  // absorbed ones are part of removed
  EXPECT_EQ(bp.ledger()[1].absorbed, 2);
  EXPECT_EQ(bp.ledger()[1].removed, 2);
  EXPECT_NEAR(bp.ledger()[1].mass_removed, 3.0 * mp, 1e-15);
  EXPECT_EQ(bp.ledger()[0].removed + bp.ledger()[0].inserted, 0);
  EXPECT_EQ(call.inserted, 149);  // 150 targeted, one already there
  EXPECT_EQ(ps.size(), 151u);
}

// Particles inside Omega, even at the surface or deep in the papers' layer,
// are never moved, removed or counted, whatever the reservoir holds.
TEST(BoundaryProjection, ReservoirNeverTouchesParticlesInsideOmega) {
  const double R = 1.0, w = 0.15, mp = 1.0 / 1600.0;
  const auto ball = make_ball(3, Vec3::Zero(), R);
  BoundaryProjection bp(ball, {condition(0, PatchKind::Dirichlet, constant(0.238732))},
                        reservoir_options(make_ball(3, Vec3::Zero(), R + w), w, 3), mp, 0.05);
  ParticleSet ps(3);
  Rng fill(9);
  std::vector<ParticleId> ids;
  std::vector<Vec3> where;
  for (int k = 0; k < 3000; ++k) {  // three times the band's target, all inside
    Vec3 x = ball->sample_interior(fill);
    if (k % 3 == 0) x *= R / x.norm();  // on the surface itself (sd = 0 up to round-off)
    if (ball->signed_distance(x) > 0.0) x *= 1.0 - 1e-15;
    ids.push_back(ps.add(x, 0.05, mp));
    where.push_back(x);
  }
  Rng rng(10);
  for (int k = 0; k < 3; ++k) {
    const PatchLedger call = bp.apply(ps, 0.0, 0.0, rng);
    EXPECT_EQ(call.removed, 0);
  }
  for (std::size_t k = 0; k < ids.size(); ++k) {
    const std::ptrdiff_t p = ps.index_of(ids[k]);
    ASSERT_GE(p, 0) << "particle " << k << " removed";
    ASSERT_EQ(ps.positions()[static_cast<std::size_t>(p)], where[k]);
  }
}

// Random motion between calls (a stand-in for diffusion): particles leave the
// band inward (inflow), outward (absorbed) and between sublayers. Each call
// sets sublayer j to T_j with sum over calls of T_j = sum of X_j - r_j(end),
// so the mean band mass equals g |band| within K m_p / calls: no drift.
TEST(BoundaryProjection, ReservoirMeanBandMassHasNoDrift) {
  const double R = 1.0, w = 0.15, g = 0.238732, mp = 1.0 / 1600.0, sigma = 0.02;
  const int K = 3, calls = 300;
  const auto ball = make_ball(3, Vec3::Zero(), R);
  BoundaryProjection bp(ball, {condition(0, PatchKind::Dirichlet, constant(g))},
                        reservoir_options(make_ball(3, Vec3::Zero(), R + w), w, K), mp, 0.05);
  ParticleSet ps(3);
  Rng rng(12), motion(13);
  bp.apply(ps, 0.0, 0.0, rng);
  std::vector<double> mean(K, 0.0);
  double band_mass_mean = 0.0;
  for (int k = 0; k < calls; ++k) {
    for (Vec3& x : ps.positions()) x += sigma * Vec3(motion.normal(), motion.normal(), motion.normal());
    bp.apply(ps, 0.0, 0.0, rng);
    const std::vector<long> n = ball_sublayer_counts(ps, R, w, K);
    for (std::size_t j = 0; j < static_cast<std::size_t>(K); ++j) {
      mean[j] += static_cast<double>(n[j]) / calls;
      band_mass_mean += static_cast<double>(n[j]) * mp / calls;
    }
    for (const Vec3& x : ps.positions()) ASSERT_LE(x.norm(), R + w);
  }
  double X_total = 0.0;
  for (int j = 0; j < K; ++j) {
    const double X = bp.reservoir_target_count(0, j, 0.0);
    X_total += X;
    EXPECT_NEAR(mean[static_cast<std::size_t>(j)], X, 1.0 / calls + 1e-9) << "sublayer " << j;
  }
  EXPECT_NEAR(band_mass_mean, g * shell_volume(R, R + w), K * mp / calls + 1e-9);
  EXPECT_NEAR(X_total * mp, g * shell_volume(R, R + w), 1e-12);
  const PatchLedger& led = bp.ledger()[0];
  EXPECT_GT(led.absorbed, 0);
  EXPECT_GE(led.removed, led.absorbed);
  EXPECT_NEAR(ps.total_mass(), led.mass_inserted - led.mass_removed, 1e-9);
  long inside = 0;
  for (const Vec3& x : ps.positions())
    if (x.norm() <= R) ++inside;
  EXPECT_GT(inside, 100);  // the inflow stays in Omega
}

// Sublayer volumes: exact slabs for a box face extended straight out, exact
// shells for a ball in a ball, Monte Carlo for a cylinder's lateral band
// (the exterior layer volume includes the rim torus, which the extended
// cylinder does not contain).
TEST(BoundaryProjection, ReservoirSublayerVolumesPerGeometry) {
  {
    const double w = 0.12;
    const Vec3 lo(0, 0, 0), hi(2, 1, 0.5);
    const auto box = make_box(3, lo, hi);
    Vec3 ext_lo = lo;
    ext_lo.x() -= w;
    BoundaryProjection bp(box, {condition(0, PatchKind::Dirichlet, constant(1.0))},
                          reservoir_options(make_box(3, ext_lo, hi), w, 4), 1e-3, 0.05);
    EXPECT_EQ(bp.reservoir_volume_rule(0), "slab");
    for (int j = 0; j < 4; ++j) EXPECT_NEAR(bp.reservoir_sublayer_volume(0, j), 0.5 * w / 4, 1e-14);
    // The same face in 2D: the "area" is the side length 1.
    const auto sq = make_box(2, lo, hi);
    BoundaryProjection bp2(sq, {condition(0, PatchKind::Dirichlet, constant(1.0))},
                           reservoir_options(make_box(2, ext_lo, hi), w, 2), 1e-3, 0.05);
    EXPECT_EQ(bp2.reservoir_volume_rule(0), "slab");
    for (int j = 0; j < 2; ++j) EXPECT_NEAR(bp2.reservoir_sublayer_volume(0, j), w / 2, 1e-14);
  }
  {
    const double R = 0.7, w = 0.2;
    const auto disc = make_ball(2, Vec3(0.1, 0.2, 0), R);
    BoundaryProjection bp(disc, {condition(0, PatchKind::Dirichlet, constant(1.0))},
                          reservoir_options(make_ball(2, Vec3(0.1, 0.2, 0), R + w), w, 2), 1e-3, 0.05);
    EXPECT_EQ(bp.reservoir_volume_rule(0), "exterior_shell");
    EXPECT_NEAR(bp.reservoir_sublayer_volume(0, 0), kPi * ((R + 0.1) * (R + 0.1) - R * R), 1e-12);
    EXPECT_NEAR(bp.reservoir_sublayer_volume(0, 1), kPi * ((R + w) * (R + w) - (R + 0.1) * (R + 0.1)), 1e-12);
  }
  {
    const double R = 0.5, L = 2.0, w = 0.1;
    const auto cyl = make_cylinder(Vec3(0, 0, 0), Vec3(0, 0, L), R);
    BoundaryProjection bp(cyl, {condition(0, PatchKind::Dirichlet, constant(1.0))},
                          reservoir_options(make_cylinder(Vec3(0, 0, 0), Vec3(0, 0, L), R + w), w, 2), 1e-3, 0.05);
    EXPECT_EQ(bp.reservoir_volume_rule(0), "monte_carlo");
    // Annuli of length L. Sampling box 1.2 x 1.2 x 2 = 2.88 with 1e6 points:
    // standard error about 9e-4 for each of the two sublayers.
    for (int j = 0; j < 2; ++j) {
      const double r0 = R + w * j / 2, r1 = R + w * (j + 1) / 2;
      EXPECT_NEAR(bp.reservoir_sublayer_volume(0, j), kPi * (r1 * r1 - r0 * r0) * L, 4e-3) << "sublayer " << j;
    }
  }
}

// reservoir_sublayers = 0: about one particle spacing (m_p / g)^(1/d) each.
TEST(BoundaryProjection, ReservoirAutomaticSublayersAboutOneSpacing) {
  const double R = 1.0, w = 0.15, g = 0.238732;
  const auto ball = make_ball(3, Vec3::Zero(), R);
  const auto ext = make_ball(3, Vec3::Zero(), R + w);
  for (double mp : {1.0 / 1600.0, 1.0 / 20000.0, 1.0 / 200000.0}) {
    BoundaryProjection bp(ball, {condition(0, PatchKind::Dirichlet, constant(g))}, reservoir_options(ext, w, 0), mp,
                          0.05);
    const double spacing = std::cbrt(mp / g);
    EXPECT_EQ(bp.reservoir_sublayer_count(0), std::max(1L, std::lround(w / spacing))) << "m_p " << mp;
  }
  BoundaryProjection zero(ball, {condition(0, PatchKind::Dirichlet, constant(0.0))}, reservoir_options(ext, w, 0),
                          1e-3, 0.05);
  EXPECT_EQ(zero.reservoir_sublayer_count(0), 1);
}

// --------------------------------------------------------------------------- Neumann outlets

namespace {

// Pipe of Sec. 5.3 in miniature: outlet disc of radius 0.25 at the centre of cap_b (z = 2).
DomainPtr pipe() {
  return make_with_subpatches(make_cylinder(Vec3(0, 0, 0), Vec3(0, 0, 2), 0.5),
                              {SubPatch{2, Vec3(0, 0, 2), 0.25, "outlet"}});
}

// Exact distance from x (inside the pipe) to the outlet disc.
double distance_to_outlet(const Vec3& x) {
  const double rho = std::hypot(x.x(), x.y());
  return std::hypot(2.0 - x.z(), std::max(0.0, rho - 0.25));
}

ProjectionOptions nearest_options() {
  ProjectionOptions o = options_with_b(0.1);
  o.neumann_outflow = NeumannOutflow::NearestParticles;
  return o;
}

}  // namespace

// 7.3 particles owed in one step, 3 particles in B_l: those 3 go first, then
// the 4 nearest the disc (brute force with the exact distance to the disc).
TEST(BoundaryProjection, NeumannNearestParticlesRemovesNearestBeyondEmptyLayer) {
  const double mp = 1e-3, dt = 0.01, b = 0.1;
  const auto d = pipe();
  const int outlet = d->patch_by_name("outlet");
  const double f = 7.3 * mp / (d->patch_area(outlet) * dt);
  BoundaryProjection bp(d, {condition(outlet, PatchKind::Neumann, constant(f))}, nearest_options(), mp, 0.05);

  ParticleSet ps(3);
  Rng fill(21);
  std::vector<ParticleId> layer;
  for (int k = 0; k < 3; ++k)
    layer.push_back(ps.add(d->sample_layer_cell(outlet, b, LayerPart::Interior, fill), 0.05, mp));
  std::vector<ParticleId> rest;
  while (rest.size() < 600) {
    const Vec3 x = d->sample_interior(fill);
    if (x.z() < 1.8) rest.push_back(ps.add(x, 0.05, mp));
  }
  std::vector<double> dist_before(static_cast<std::size_t>(ps.next_id()), 0.0);
  for (std::size_t p = 0; p < ps.size(); ++p)
    dist_before[static_cast<std::size_t>(ps.ids()[p])] = distance_to_outlet(ps.positions()[p]);

  Rng rng(22);
  const PatchLedger call = bp.apply(ps, 0.0, dt, rng);
  EXPECT_EQ(call.removed, 7);
  EXPECT_EQ(call.deficit, 0.0);
  EXPECT_NEAR(bp.ledger()[0].carry, -0.3 * mp, 1e-12);
  for (ParticleId id : layer) EXPECT_LT(ps.index_of(id), 0) << "B_l particle " << id << " kept";
  double farthest_removed = 0.0, nearest_kept = std::numeric_limits<double>::infinity();
  int removed_rest = 0;
  for (ParticleId id : rest) {
    const double dist = dist_before[static_cast<std::size_t>(id)];
    if (ps.index_of(id) < 0) {
      ++removed_rest;
      farthest_removed = std::max(farthest_removed, dist);
    } else {
      nearest_kept = std::min(nearest_kept, dist);
    }
  }
  EXPECT_EQ(removed_rest, 4);
  // The 4 removed are the 4 nearest, up to the point-cloud error of the
  // distance for particles off the disc's axis (<< the gaps between them).
  EXPECT_LE(farthest_removed, nearest_kept + 2e-3);
  std::vector<double> sorted;
  for (ParticleId id : rest) sorted.push_back(dist_before[static_cast<std::size_t>(id)]);
  std::sort(sorted.begin(), sorted.end());
  EXPECT_NEAR(farthest_removed, sorted[3], 2e-3);
  const PatchLedger& led = bp.ledger()[0];
  EXPECT_NEAR(led.mass_inserted - led.mass_removed + led.carry, led.flux_integral, 1e-12);
}

// 0.37 particles of outflow per step and no particle ever in B_l: the carry
// stays in (-m_p, m_p) while particles exist, the ledger balances, and once
// all are gone the debt is reported.
TEST(BoundaryProjection, NeumannNearestParticlesCarryStaysBoundedUntilEmpty) {
  const double mp = 1e-3, dt = 0.01;
  const auto d = pipe();
  const int outlet = d->patch_by_name("outlet");
  const double f = 0.37 * mp / (d->patch_area(outlet) * dt);
  BoundaryProjection bp(d, {condition(outlet, PatchKind::Neumann, constant(f))}, nearest_options(), mp, 0.05);
  ParticleSet ps(3);
  Rng fill(31);
  while (ps.size() < 30) {
    const Vec3 x = d->sample_interior(fill);
    if (x.z() < 1.0) ps.add(x, 0.05, mp);
  }
  Rng rng(32);
  int k = 0;
  for (; k < 200 && !ps.empty(); ++k) {
    const PatchLedger call = bp.apply(ps, k * dt, dt, rng);
    const PatchLedger& led = bp.ledger()[0];
    ASSERT_NEAR(led.mass_inserted - led.mass_removed + led.carry, led.flux_integral, 1e-12) << "step " << k;
    ASSERT_EQ(static_cast<long>(ps.size()), 30 - led.removed) << "step " << k;
    if (!ps.empty()) {
      ASSERT_GT(led.carry, -mp) << "step " << k;
      ASSERT_LT(led.carry, mp) << "step " << k;
      ASSERT_EQ(led.deficit, 0.0) << "step " << k;
      ASSERT_EQ(call.deficit, 0.0) << "step " << k;
    }
  }
  ASSERT_TRUE(ps.empty());
  EXPECT_EQ(k, 82);  // the 30th particle is owed after ceil(30 / 0.37) = 82 steps
  for (int j = 0; j < 10; ++j) bp.apply(ps, (k + j) * dt, dt, rng);
  const PatchLedger& led = bp.ledger()[0];
  EXPECT_NEAR(led.flux_integral, -0.37 * mp * (k + 10), 1e-12);
  EXPECT_NEAR(led.carry, led.flux_integral + 30 * mp, 1e-12);
  EXPECT_GE(led.deficit, mp);
  EXPECT_EQ(led.deficit, -led.carry);

  // No particles at all from the start: the whole outflow is owed and reported.
  const double f_empty = 2.5 * mp / (d->patch_area(outlet) * dt);
  BoundaryProjection empty(d, {condition(outlet, PatchKind::Neumann, constant(f_empty))}, nearest_options(), mp, 0.05);
  ParticleSet none(3);
  const PatchLedger call = empty.apply(none, 0.0, dt, rng);
  EXPECT_EQ(call.removed, 0);
  EXPECT_NEAR(call.deficit, 2.5 * mp, 1e-15);
  EXPECT_NEAR(empty.ledger()[0].carry, -2.5 * mp, 1e-15);
}

// While B_l supplies the outflow, NearestParticles is the papers' rule draw
// for draw: the same particles leave.
TEST(BoundaryProjection, NeumannNearestParticlesEqualsLayerWhileLayerSuffices) {
  const double mp = 1e-3, dt = 0.01, b = 0.1;
  const auto d = pipe();
  const int outlet = d->patch_by_name("outlet");
  const double f = 2.6 * mp / (d->patch_area(outlet) * dt);
  ParticleSet start(3);
  Rng fill(41);
  for (int k = 0; k < 300; ++k) start.add(d->sample_layer_cell(outlet, b, LayerPart::Interior, fill), 0.05, mp);
  for (int k = 0; k < 300; ++k) start.add(d->sample_interior(fill), 0.05, mp);
  ParticleSet a = start, c = start;
  BoundaryProjection layer(d, {condition(outlet, PatchKind::Neumann, constant(f))}, options_with_b(b), mp, 0.05);
  BoundaryProjection nearest(d, {condition(outlet, PatchKind::Neumann, constant(f))}, nearest_options(), mp, 0.05);
  Rng ra(42), rc(42);
  for (int k = 0; k < 20; ++k) {
    layer.apply(a, k * dt, dt, ra);
    nearest.apply(c, k * dt, dt, rc);
  }
  EXPECT_EQ(layer.ledger()[0].removed, 52);
  EXPECT_EQ(a.ids(), c.ids());
  EXPECT_EQ(a.positions(), c.positions());
  EXPECT_EQ(layer.ledger()[0].carry, nearest.ledger()[0].carry);
}

// --------------------------------------------------------------------------- absorb_exterior

TEST(BoundaryProjection, AbsorbExteriorRemovesStrandedParticlesOnlyWhenOn) {
  const double mp = 1e-3, b = 0.1;
  const auto box = make_box(3, Vec3(0, 0, 0), Vec3(1, 1, 1));
  auto populate = [&](ParticleSet& ps) {
    std::vector<ParticleId> ids;
    ids.push_back(ps.add(Vec3(-0.05, 0.5, 0.5), 0.05, mp));  // in B^ext of x-
    ids.push_back(ps.add(Vec3(-0.3, 0.5, 0.5), 0.05, mp));   // beyond the layer, patch x-
    ids.push_back(ps.add(Vec3(0.5, -0.05, 0.5), 0.05, mp));  // outside the no-flux y- wall
    ids.push_back(ps.add(Vec3(0.5, 0.5, 0.5), 0.05, mp));    // inside
    return ids;
  };
  ProjectionOptions on = options_with_b(b);
  on.absorb_exterior = true;
  // g = 0: B^int's target is 0 and it is empty, so only absorption can act.
  BoundaryProjection papers(box, {condition(0, PatchKind::Dirichlet, constant(0.0))}, options_with_b(b), mp, 0.05);
  BoundaryProjection absorbing(box, {condition(0, PatchKind::Dirichlet, constant(0.0))}, on, mp, 0.05);
  Rng rng(51);
  ParticleSet p1(3), p2(3);
  const auto ids1 = populate(p1);
  const auto ids2 = populate(p2);
  const PatchLedger off_call = papers.apply(p1, 0.0, 0.1, rng);
  EXPECT_EQ(off_call.removed + off_call.inserted + off_call.absorbed, 0);
  EXPECT_EQ(p1.size(), 4u);
  const PatchLedger on_call = absorbing.apply(p2, 0.0, 0.1, rng);
  EXPECT_LT(p2.index_of(ids2[0]), 0);
  EXPECT_LT(p2.index_of(ids2[1]), 0);
  EXPECT_GE(p2.index_of(ids2[2]), 0);
  EXPECT_GE(p2.index_of(ids2[3]), 0);
  EXPECT_EQ(on_call.absorbed, 2);
  EXPECT_EQ(on_call.removed, 2);
  EXPECT_NEAR(on_call.mass_absorbed, 2 * mp, 1e-15);
  EXPECT_EQ(absorbing.ledger()[0].absorbed, 2);
  EXPECT_NEAR(absorbing.ledger()[0].mass_removed, 2 * mp, 1e-15);

  // With nothing outside, absorb_exterior does not change the papers' layer
  // projection draw for draw.
  BoundaryProjection a(box, {condition(0, PatchKind::Dirichlet, constant(0.3))}, options_with_b(b), mp, 0.05);
  BoundaryProjection c(box, {condition(0, PatchKind::Dirichlet, constant(0.3))}, on, mp, 0.05);
  ParticleSet qa(3), qc(3);
  Rng ra(52), rc(52);
  for (int k = 0; k < 5; ++k) {
    a.apply(qa, 0.0, 0.1, ra);
    c.apply(qc, 0.0, 0.1, rc);
    for (Vec3& x : qa.positions()) x.x() = std::max(x.x() + 0.02, 1e-3);
    for (Vec3& x : qc.positions()) x.x() = std::max(x.x() + 0.02, 1e-3);
  }
  EXPECT_GT(qa.size(), 0u);
  EXPECT_EQ(qa.positions(), qc.positions());
  EXPECT_EQ(c.ledger()[0].absorbed, 0);
}

// --------------------------------------------------------------------------- checks of the new options

TEST(BoundaryProjection, NewOptionsNameTheFieldWhenInvalid) {
  const auto ball = make_ball(3, Vec3::Zero(), 1.0);
  const auto ext = make_ball(3, Vec3::Zero(), 1.1);
  const std::vector<PatchCondition> dir = {condition(0, PatchKind::Dirichlet, constant(1.0))};
  auto build = [&](const ProjectionOptions& o, DomainPtr d = nullptr) {
    BoundaryProjection bp(d ? d : ball, dir, o, 1e-3, 0.05);
  };
  expect_invalid([] { neumann_outflow_from_string("nearest"); }, "boundary.neumann_outflow = 'nearest'");
  expect_invalid([] { dirichlet_mode_from_string("bath"); }, "boundary.dirichlet_mode = 'bath'");

  ProjectionOptions o = nearest_options();
  o.nearest_surface_points = 8;
  expect_invalid([&] { o.validate(); }, "boundary.nearest_surface_points = 8");

  const ProjectionOptions ok = reservoir_options(ext, 0.1, 2);
  EXPECT_NO_THROW(build(ok));
  ProjectionOptions r = ok;
  r.reservoir_domain = nullptr;
  expect_invalid([&] { build(r); }, "boundary.reservoir_domain");
  for (double w : {0.0, -0.1, std::numeric_limits<double>::quiet_NaN()}) {
    r = ok;
    r.reservoir_thickness = w;
    expect_invalid([&] { build(r); }, "boundary.reservoir_thickness");
  }
  r = ok;
  r.reservoir_sublayers = -1;
  expect_invalid([&] { build(r); }, "boundary.reservoir_sublayers = -1");
  r = ok;
  r.reservoir_volume_samples = 100;
  expect_invalid([&] { build(r); }, "boundary.reservoir_volume_samples = 100");
  r = ok;
  r.absorb_exterior = true;
  expect_invalid([&] { build(r); }, "boundary.absorb_exterior");
  // The reservoir domain must match the domain and leave a band.
  expect_invalid([&] { build(reservoir_options(make_ball(2, Vec3::Zero(), 1.1), 0.1, 2)); },
                 "boundary.reservoir_domain dim");
  expect_invalid([&] { build(reservoir_options(make_ball(3, Vec3::Zero(), 0.9), 0.1, 2)); },
                 "must contain the domain");
  expect_invalid([&] { build(reservoir_options(make_ball(3, Vec3::Zero(), 1.0), 0.1, 2)); }, "is empty");
  expect_invalid([&] { build(reservoir_options(make_ball(3, Vec3::Zero(), 1.0), 0.1, 0)); }, "is empty");
  // The reservoir fields are not looked at in Layer mode.
  ProjectionOptions layer = options_with_b(0.1);
  layer.reservoir_thickness = -1.0;
  EXPECT_NO_THROW(build(layer));
  BoundaryProjection papers(ball, dir, options_with_b(0.1), 1e-3, 0.05);
  expect_invalid([&] { papers.reservoir_sublayer_count(0); },
                 "must be a dirichlet condition with dirichlet_mode = reservoir");
  BoundaryProjection res(ball, dir, ok, 1e-3, 0.05);
  expect_invalid([&] { res.reservoir_sublayer_volume(0, 2); }, "reservoir sublayer");
  expect_invalid([&] { res.reservoir_target_count(1, 0, 0.0); }, "boundary condition index");
}

// Odd profile: a box face (plane: the mirror of each sublayer is the slab at
// the same depth inside). An empty interior doubles the band's density (2 g);
// an interior at g leaves it at g; an interior at 2 g empties it (clamped at 0).
TEST(BoundaryProjection, ReservoirOddProfileMirrorsTheInteriorAboutG) {
  const double w = 0.3, g = 400.0, mp = 1.0, s = 0.03;
  const int K = 3;
  const auto box = make_box(3, Vec3::Zero(), Vec3(2.0, 1.0, 1.0));
  const auto ext = box->extended({0}, w);
  ProjectionOptions o = reservoir_options(ext, w, K);
  o.reservoir_profile = ReservoirProfile::Odd;
  // Sublayer volumes are 0.1 each: X_j = g 0.1 / m_p = 40 particles.
  auto band_counts = [&](double interior_density) {
    BoundaryProjection bp(box, {condition(0, PatchKind::Dirichlet, constant(g))}, o, mp, s);
    ParticleSet ps(3);
    // Interior particles at density interior_density in each mirror slab
    // (depth (j/10, (j+1)/10) inside the face, volume 0.1), at random places.
    Rng place(17);
    const auto per_slab = static_cast<int>(std::lround(interior_density * 0.1 / mp));
    for (int j = 0; j < K; ++j)
      for (int k = 0; k < per_slab; ++k)
        ps.add(Vec3(0.1 * (j + place.uniform(0.01, 0.99)), place.uniform(), place.uniform()), s, mp);
    const std::size_t n_inside = ps.size();
    Rng rng(5);
    bp.apply(ps, 0.0, 0.01, rng);
    long band = 0;
    for (std::size_t p = 0; p < ps.size(); ++p) band += ps.positions()[p][0] < 0.0;
    EXPECT_EQ(ps.size() - static_cast<std::size_t>(band), n_inside) << "interior particles untouched";
    return band;
  };
  EXPECT_EQ(band_counts(0.0), 3 * 80);    // 2 g in each sublayer
  EXPECT_EQ(band_counts(400.0), 3 * 40);  // interior at g: g outside
  EXPECT_EQ(band_counts(600.0), 3 * 20);  // 1.5 g inside: 0.5 g outside
  EXPECT_EQ(band_counts(800.0), 0);       // 2 g inside: nothing outside
  o.reservoir_profile = ReservoirProfile::Uniform;
  EXPECT_EQ(band_counts(0.0), 3 * 40);  // the uniform profile ignores the interior
  EXPECT_EQ(to_string(ReservoirProfile::Odd), "odd");
  EXPECT_EQ(reservoir_profile_from_string("uniform"), ReservoirProfile::Uniform);
  EXPECT_THROW(reservoir_profile_from_string("even"), InvalidArgument);
}

// ---------------------------------------------------------------- reads
// apply() on the particles it reads() (in their
// storage order) does what it does on all of them: the same ledger, random
// numbers, removals and insertions, and the deeper particles untouched. A
// distributed run relies on it (it projects the gathered near-boundary
// particles). The state is a short run's, thinned near the boundary so that
// the projection has work to do.
namespace {

struct DepthComparison {
  bool same = true;
  long acted = 0;          // inserted + removed on all particles
  std::size_t left_out = 0;  // particles the projection does not read
};

bool same_state(const Rng& a, const Rng& b) {
  const Rng::State sa = a.state(), sb = b.state();
  return std::equal(sa.s, sa.s + 4, sb.s);
}

DepthComparison compare_within_depth(const DomainPtr& domain, const std::vector<ConstantBoundaryData>& boundary,
                                     RunSetupOptions ro, int steps, bool cut_at_band_width = false) {
  const int dim = domain->dim();
  const RunSetup setup = setup_run(*domain, boundary, ro);
  Simulation sim(domain, boundary, setup.options);
  // Filled at the Dirichlet value, uniformly at random: particles at every depth.
  ParticleSet fill(dim);
  Rng rng(11);
  const auto n = static_cast<std::size_t>(boundary[0].value * domain->volume() / setup.options.particle_mass);
  for (std::size_t p = 0; p < n; ++p)
    fill.add(domain->sample_interior(rng), setup.options.width_s, setup.options.particle_mass);
  sim.start(fill);
  for (int k = 0; k < steps; ++k) sim.advance(setup.parameters.dt);
  ParticleSet all = sim.particles();
  std::vector<std::size_t> thin;
  for (std::size_t p = 0; p < all.size(); ++p)
    if (std::abs(domain->signed_distance(all.positions()[p])) < 0.5 * setup.parameters.dr && all.ids()[p] % 2 == 0)
      thin.push_back(p);
  all.remove_indices(thin);
  double s_max = 0.0;
  for (double s : all.widths()) s_max = std::max(s_max, s);
  // cut_at_band_width: also leave out what lies deeper than the band's
  // width w inside Omega, a test of the test.
  const double cut = cut_at_band_width ? setup.parameters.reservoir_width : std::numeric_limits<double>::infinity();
  ParticleSet near(dim);
  for (std::size_t p = 0; p < all.size(); ++p)
    if (sim.projection().reads(all.positions()[p], s_max) && domain->signed_distance(all.positions()[p]) > -cut)
      near.add_with_id(all.ids()[p], all.positions()[p], all.widths()[p], all.masses()[p], all.birth_times()[p]);
  near.set_next_id(all.next_id());
  DepthComparison r;
  r.left_out = all.size() - near.size();
  const ParticleSet deep_before = all;
  BoundaryProjection a = sim.projection(), b = sim.projection();
  Rng ra(7), rb(7);
  const PatchLedger la = a.apply(all, sim.time(), setup.parameters.dt, ra);
  const PatchLedger lb = b.apply(near, sim.time(), setup.parameters.dt, rb);
  r.acted = la.inserted + la.removed;
  r.same = la.inserted == lb.inserted && la.removed == lb.removed && la.mass_inserted == lb.mass_inserted &&
           la.mass_removed == lb.mass_removed && la.absorbed == lb.absorbed && same_state(ra, rb) &&
           all.size() - near.size() == r.left_out && all.next_id() == near.next_id();
  for (std::size_t i = 0; r.same && i < near.size(); ++i) {
    const std::ptrdiff_t p = all.index_of(near.ids()[i]);
    r.same = p >= 0 && all.positions()[static_cast<std::size_t>(p)] == near.positions()[i] &&
             all.widths()[static_cast<std::size_t>(p)] == near.widths()[i];
  }
  return r;
}

RunSetupOptions depth_run(TreatmentPreset preset, int dim, std::int64_t n_inf) {
  RunSetupOptions ro;
  ro.n_inf = n_inf;
  ro.t_end = 1.0;
  ro.treatment = treatment_preset(preset, dim);
  return ro;
}

}  // namespace

TEST(BoundaryProjection, ProjectsTheParticlesItReadsAsItProjectsAll) {
  const std::vector<ConstantBoundaryData> sphere_data{{0, PatchKind::Dirichlet, 0.238732}};
  const std::vector<ConstantBoundaryData> box_data{{0, PatchKind::Dirichlet, 500.0}};
  DomainPtr ball = make_ball(3, Vec3::Zero(), 1.0);
  DomainPtr box = make_box(3, Vec3::Zero(), Vec3(2.0, 1.0, 1.0));
  DomainPtr square = make_box(2, Vec3::Zero(), Vec3(1.0, 1.0, 0.0));
  const std::vector<ConstantBoundaryData> square_data{{0, PatchKind::Dirichlet, 400.0}, {1, PatchKind::Neumann, 5.0}};
  struct Case {
    const char* name;
    DomainPtr domain;
    std::vector<ConstantBoundaryData> data;
    RunSetupOptions ro;
  };
  // (The sphere's quiet reservoir reads the whole ball below n_inf ~ 3000.)
  std::vector<Case> cases{{"box, quiet reservoir", box, box_data, depth_run(TreatmentPreset::Converging, 3, 1000)},
                          {"sphere, papers' layer", ball, sphere_data, depth_run(TreatmentPreset::Papers, 3, 300)},
                          {"square, layer and an outlet", square, square_data, depth_run(TreatmentPreset::Papers, 2, 300)}};
  Case exact{"box, exact reservoir", box, box_data, depth_run(TreatmentPreset::Converging, 3, 1000)};
  exact.ro.treatment.reservoir_control = ReservoirControl::Exact;
  cases.push_back(exact);
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    const DepthComparison r = compare_within_depth(c.domain, c.data, c.ro, 3);
    EXPECT_TRUE(r.same);
    EXPECT_GT(r.acted, 0) << "the projection must have work to do";
    EXPECT_GT(r.left_out, 0u) << "the depth must leave the interior out";
  }
  // Without the blobs beyond depth w, whose tails reach the quiet
  // reservoir's mirror sublayers, the comparison sees a difference.
  EXPECT_FALSE(compare_within_depth(box, box_data, depth_run(TreatmentPreset::Converging, 3, 1000), 3, true).same);
}

TEST(BoundaryProjection, ReadsEverythingWhenOutletsTakeTheNearestParticles) {
  DomainPtr square = make_box(2, Vec3::Zero(), Vec3(1.0, 1.0, 0.0));
  ProjectionOptions po;
  po.neumann_outflow = NeumannOutflow::NearestParticles;
  PatchCondition outlet;
  outlet.patch = 1;
  outlet.kind = PatchKind::Neumann;
  outlet.data = [](const Vec3&, double) { return 1.0; };
  BoundaryProjection nearest(square, {outlet}, po, 1.0, 0.05);
  const Vec3 middle(0.5, 0.5, 0.0);
  EXPECT_TRUE(nearest.reads(middle, 0.05));
  po.neumann_outflow = NeumannOutflow::Layer;
  BoundaryProjection layer(square, {outlet}, po, 1.0, 0.05);
  EXPECT_FALSE(layer.reads(middle, 0.05));
  EXPECT_TRUE(layer.reads(Vec3(0.5 * po.layer_b, 0.5, 0.0), 0.05));
}

// draw_by_id: the papers' random deletions choose the same particles
// whatever the order the particles are stored in.
TEST(BoundaryProjection, DrawByIdIsIndependentOfStorageOrder) {
  DomainPtr ball = make_ball(3, Vec3::Zero(), 1.0);
  const std::vector<ConstantBoundaryData> data{{0, PatchKind::Dirichlet, 0.2}};
  RunSetupOptions ro = depth_run(TreatmentPreset::Papers, 3, 300);
  RunSetup setup = setup_run(*ball, data, ro);
  Simulation sim(ball, data, setup.options);
  sim.start(ParticleSet(3));
  for (int k = 0; k < 3; ++k) sim.advance(setup.parameters.dt);
  // Over-full: every particle of B_l^int doubled (new ids), so that the layer deletes.
  ParticleSet a = sim.particles();
  const std::size_t n = a.size();
  for (std::size_t p = 0; p < n; ++p)
    if (ball->signed_distance(a.positions()[p]) > -setup.parameters.layer_b)
      a.add(a.positions()[p] * 0.999, a.widths()[p], a.masses()[p]);
  std::vector<std::size_t> reversed(a.size());
  for (std::size_t i = 0; i < reversed.size(); ++i) reversed[i] = reversed.size() - 1 - i;
  auto removed_ids = [&](bool by_id, bool reverse) {
    ProjectionOptions po = sim.projection().options();
    ParticleSet set = a;
    if (reverse) set.reorder(reversed);
    BoundaryProjection proj = sim.projection();
    Rng rng(3);
    std::set<ParticleId> before(set.ids().begin(), set.ids().end());
    po.draw_by_id = by_id;  // the default is true
    proj = BoundaryProjection(ball, proj.conditions(), po, setup.options.particle_mass, setup.options.width_s);
    const PatchLedger l = proj.apply(set, sim.time(), setup.parameters.dt, rng);
    EXPECT_GT(l.removed, 0);
    for (ParticleId id : set.ids()) before.erase(id);
    return before;
  };
  EXPECT_EQ(removed_ids(true, false), removed_ids(true, true));
  EXPECT_NE(removed_ids(false, false), removed_ids(false, true)) << "storage order decides the papers' draws";
}
