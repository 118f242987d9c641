#include "otfp/boundary.hpp"

#include <gtest/gtest.h>

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

// METHOD-NOTES 2.7: unit sphere, n_inf = 1600, b = 0.29. The inner shell holds
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

// METHOD-NOTES 2.6: 0.37 particles of inflow per step. (50) floors that to 0
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
