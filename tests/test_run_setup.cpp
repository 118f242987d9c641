// The run set-up of run_setup.hpp: the rules (36)-(40) recomputed here by
// hand, the presets, the field names of its errors, and that the library's
// defaults are the command line's default run.
#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <memory>
#include <string>

#include "otfp/neighbor_list.hpp"
#include "otfp/run_setup.hpp"
#include "otfp_app/simulation.hpp"

namespace {

using namespace otfp;

std::string error_of(const std::function<void()>& f) {
  try {
    f();
  } catch (const InvalidArgument& e) {
    return e.what();
  }
  return "(no error)";
}

TEST(RunSetup, ParametersFollowTheRules) {
  const DomainPtr ball = make_ball(3, Vec3::Zero(), 2.0);
  const std::vector<ConstantBoundaryData> data = {{0, PatchKind::Dirichlet, 0.5}};
  RunSetupOptions o;
  o.n_inf = 1000;
  o.kappa = 0.5;
  o.t_end = 0.3;
  o.length_L = 2.0;
  const RunSetup s = setup_run(*ball, data, o);
  const RunParameters& p = s.parameters;
  const double volume = 4.0 / 3.0 * M_PI * 8.0;
  const double dr = std::cbrt(volume / 1000.0);  // (37), the cube rule
  EXPECT_NEAR(p.volume, volume, 1e-12 * volume);
  EXPECT_NEAR(p.dr, dr, 1e-14);
  EXPECT_NEAR(p.beta, 2.0 / (dr * dr), 1e-9);              // (36)
  EXPECT_NEAR(p.width_s, dr / std::sqrt(2.0), 1e-14);
  EXPECT_NEAR(p.layer_b, std::sqrt(2.0 * dr), 1e-14);      // (38)
  EXPECT_NEAR(p.dt_explicit, dr * dr / 0.5, 1e-14);        // (39)
  EXPECT_NEAR(p.barrier_C, 0.5 / (dr * dr), 1e-9);         // (40)
  const auto n = static_cast<std::int64_t>(std::ceil(0.3 / (dr * dr / 0.5)));
  EXPECT_EQ(p.n_steps, n);
  EXPECT_DOUBLE_EQ(p.dt, 0.3 / static_cast<double>(n));    // the grid ends on t_end
  const double rc = cutoff_radius(p.width_s, o.kernel_tolerance);
  EXPECT_DOUBLE_EQ(p.reservoir_width, rc);                 // one cut-off
  EXPECT_EQ(p.reservoir_sublayers, std::lround(2.0 * rc / dr));  // half a spacing each
  EXPECT_NEAR(p.M_inf, 0.5 * volume, 1e-12);               // g |Omega|
  EXPECT_NEAR(p.particle_mass, 0.5 * volume / 1000.0, 1e-15);
  // The options carry them.
  const SimulationOptions& so = s.options;
  EXPECT_EQ(so.particle_mass, p.particle_mass);
  EXPECT_EQ(so.width_s, p.width_s);
  EXPECT_EQ(so.barrier_stiffness, p.barrier_C);
  EXPECT_EQ(so.projection.dirichlet_mode, DirichletMode::Reservoir);
  EXPECT_EQ(so.projection.reservoir_thickness, rc);
  EXPECT_EQ(so.projection.reservoir_profile, ReservoirProfile::Odd);
  EXPECT_EQ(so.no_flux, NoFluxTreatment::Images);
  EXPECT_EQ(so.implicit.kappa, 0.5);
  EXPECT_EQ(so.implicit.nominal_width, p.width_s);
  EXPECT_EQ(so.time_control.dt_min, 1e-3 * p.dt);
  EXPECT_EQ(so.time_control.dt_max, 0.3);
  EXPECT_NO_THROW(so.validate());
  // Without Dirichlet data there is no band, and a particle mass must be given.
  const std::vector<ConstantBoundaryData> neumann = {{0, PatchKind::Neumann, 1.0}};
  EXPECT_EQ(run_parameters(*ball, neumann, o).reservoir_width, 0.0);
  EXPECT_EQ(error_of([&] { setup_run(*ball, neumann, o); }).rfind("particle_mass = 0: give particle_mass or M_inf", 0),
            0u);
  o.particle_mass = 1e-3;
  EXPECT_EQ(setup_run(*ball, neumann, o).options.particle_mass, 1e-3);
}

// The masses and the fill's count (MassRule, InitialFillRule), each rule
// recomputed by hand on the box [0, 1] x [0, 2] (its x faces have length 2).
TEST(RunSetup, MassAndFillRulesApplyInOrder) {
  const DomainPtr box = make_box(2, Vec3::Zero(), Vec3(1.0, 2.0, 0.0));
  RunSetupOptions o;
  o.n_inf = 800;
  o.t_end = 3.0;
  const double dr = std::sqrt(2.0 / 800.0);  // (37), the cube rule
  // An inlet -f = 0.25 on the x = 0 face over [1, 5], cut to [1, 3] by t_end;
  // an outlet f = 0.1 on x = 1 over [0, 0.5].
  ConstantBoundaryData inlet{0, PatchKind::Neumann, -0.25};
  inlet.t_start = 1.0;
  inlet.t_end = 5.0;
  ConstantBoundaryData outlet{1, PatchKind::Neumann, 0.1};
  outlet.t_end = 0.5;
  const std::vector<ConstantBoundaryData> neumann = {inlet, outlet};
  const double inflow = 0.25 * 2.0 * 2.0 - 0.1 * 2.0 * 0.5;
  RunParameters p = run_parameters(*box, neumann, o);
  EXPECT_NEAR(p.neumann_net_inflow, inflow, 1e-15);
  // No particles at t = 0: the inflow is the mass to come.
  EXPECT_EQ(p.M_inf_rule, MassRule::NeumannInflow);
  EXPECT_NEAR(p.M_inf, inflow, 1e-15);
  EXPECT_EQ(p.fill_count, 0);
  // A drawn fill of a given mass: that mass + the inflow, count mass / m_p.
  o.fill.filled = true;
  o.fill.mass = 2.5;
  p = run_parameters(*box, neumann, o);
  EXPECT_EQ(p.M_inf_rule, MassRule::FillMass);
  EXPECT_NEAR(p.M_inf, 2.5 + inflow, 1e-14);
  EXPECT_NEAR(p.particle_mass, (2.5 + inflow) / 800.0, 1e-16);
  EXPECT_EQ(p.fill_count, std::llround(2.5 / p.particle_mass));
  // Given particles (they replace a drawn fill).
  o.fill = InitialFillRule{};
  o.fill.given_count = 123;
  o.fill.given_mass = 0.75;
  p = run_parameters(*box, neumann, o);
  EXPECT_EQ(p.M_inf_rule, MassRule::GivenParticles);
  EXPECT_NEAR(p.M_inf, 0.75 + inflow, 1e-15);
  EXPECT_EQ(p.fill_count, 123);
  // A particle mass with a fill of a given count: count x m_p + the inflow.
  o.fill = InitialFillRule{};
  o.fill.filled = true;
  o.fill.count = 300;
  o.particle_mass = 0.01;
  p = run_parameters(*box, neumann, o);
  EXPECT_EQ(p.M_inf_rule, MassRule::ParticleMass);
  EXPECT_NEAR(p.M_inf, 300 * 0.01 + inflow, 1e-14);
  EXPECT_EQ(p.particle_mass, 0.01);
  EXPECT_EQ(p.fill_count, 300);
  // A count of 0 is no particles, not "not given"; so is a fill mass of 0.
  o.fill.count = 0;
  p = run_parameters(*box, neumann, o);
  EXPECT_EQ(p.M_inf_rule, MassRule::ParticleMass);
  EXPECT_NEAR(p.M_inf, inflow, 1e-15);
  EXPECT_EQ(p.fill_count, 0);
  o.fill.count.reset();
  o.fill.mass = 0.0;
  p = run_parameters(*box, neumann, o);
  EXPECT_EQ(p.M_inf_rule, MassRule::FillMass);
  EXPECT_EQ(p.fill_count, 0);
  // An outflow only, no fill: n_inf x m_p.
  o.fill = InitialFillRule{};
  p = run_parameters(*box, {outlet}, o);
  EXPECT_EQ(p.M_inf_rule, MassRule::NInfParticleMass);
  EXPECT_NEAR(p.M_inf, 800 * 0.01, 1e-14);
  // Dirichlet data come before every fill rule, a given M_inf before them.
  o.fill.filled = true;
  o.fill.mass = 2.5;
  const std::vector<ConstantBoundaryData> held = {{2, PatchKind::Dirichlet, 0.5}, {3, PatchKind::Dirichlet, 1.5}};
  p = run_parameters(*box, held, o);
  EXPECT_EQ(p.M_inf_rule, MassRule::Dirichlet);
  EXPECT_NEAR(p.M_inf, 1.0 * 2.0, 1e-15);  // (0.5 + 1.5) / 2 x |Omega|
  o.M_inf = 7.0;
  EXPECT_EQ(run_parameters(*box, held, o).M_inf_rule, MassRule::Given);
  EXPECT_EQ(run_parameters(*box, held, o).M_inf, 7.0);
  // No rule: nothing set, and setup_run refuses.
  o = RunSetupOptions{};
  o.fill.filled = true;
  p = run_parameters(*box, {}, o);
  EXPECT_EQ(p.M_inf_rule, MassRule::Unset);
  EXPECT_EQ(p.M_inf, 0.0);
  EXPECT_EQ(p.fill_count, o.n_inf);
  EXPECT_EQ(error_of([&] { setup_run(*box, {}, o); }).rfind("particle_mass = 0: ", 0), 0u);
  // A lattice of spacing ~dr over its box, whatever the fill says.
  o.n_inf = 800;
  o.fill = InitialFillRule{};
  o.fill.lattice = true;
  o.fill.lattice_hi = Vec3(1.0, 2.0, 0.0);
  p = run_parameters(*box, held, o);
  EXPECT_EQ(p.lattice_counts[0], std::llround(1.0 / dr));
  EXPECT_EQ(p.lattice_counts[1], std::llround(2.0 / dr));
  EXPECT_EQ(p.lattice_counts[2], 1);
  EXPECT_EQ(p.fill_count, p.lattice_counts[0] * p.lattice_counts[1]);
  o.fill.lattice_hi = Vec3(1e6, 2.0, 0.0);
  EXPECT_EQ(error_of([&] { run_parameters(*box, held, o); }).rfind("fill.lattice = ", 0), 0u);
  // With a particle mass and no Dirichlet data, M_inf is the lattice's own
  // count x m_p, not n_inf x m_p.
  o.fill.lattice_hi = Vec3(1.0, 2.0, 0.0);
  o.n_inf = 700;
  o.particle_mass = 0.01;
  p = run_parameters(*box, {}, o);
  EXPECT_EQ(p.M_inf_rule, MassRule::ParticleMass);
  EXPECT_EQ(p.fill_count, 19 * 37);  // round(1 / dr) x round(2 / dr), dr = sqrt(2 / 700): 703, not 700
  EXPECT_NEAR(p.M_inf, static_cast<double>(p.fill_count) * 0.01, 1e-14);
  o.fill = InitialFillRule{};
  o.fill.count = -1;
  EXPECT_EQ(error_of([&] { run_parameters(*box, held, o); }).rfind("fill.count = -1: ", 0), 0u);
}

// A fill said two ways, or a count that nothing draws, is refused, not
// silently ignored.
TEST(RunSetup, ContradictoryFillsAreRefused) {
  const DomainPtr box = make_box(2, Vec3::Zero(), Vec3(1.0, 2.0, 0.0));
  RunSetupOptions o;
  o.fill.filled = true;
  o.fill.count = 10;
  o.fill.mass = 2.0;
  EXPECT_EQ(error_of([&] { run_parameters(*box, {}, o); }).rfind("fill.count = 10: give fill.count or fill.mass", 0), 0u);
  o.fill.count.reset();
  o.fill.lattice = true;
  o.fill.lattice_hi = Vec3(1.0, 2.0, 0.0);
  EXPECT_EQ(error_of([&] { run_parameters(*box, {}, o); }).rfind("fill.mass = 2: not used by fill.lattice", 0), 0u);
  o.fill = InitialFillRule{};
  o.fill.count = 10;
  EXPECT_EQ(error_of([&] { run_parameters(*box, {}, o); }).rfind("fill.count = 10: has no effect", 0), 0u);
  o.fill = InitialFillRule{};
  o.fill.filled = true;
  o.fill.given_count = 5;
  EXPECT_EQ(error_of([&] { run_parameters(*box, {}, o); }).rfind("fill.given_count = 5: given particles replace", 0), 0u);
}

TEST(RunSetup, PresetsAreTheDocumentedTreatments) {
  const TreatmentOptions converging = treatment_preset(TreatmentPreset::Converging, 3);
  EXPECT_EQ(converging.no_flux, NoFluxTreatment::Images);
  EXPECT_EQ(converging.dirichlet, DirichletMode::Reservoir);
  EXPECT_EQ(converging.neumann_outflow, NeumannOutflow::NearestParticles);
  EXPECT_EQ(converging.spacing_rule, SpacingRule::Cube);
  const TreatmentOptions papers = treatment_preset(TreatmentPreset::Papers, 3);
  EXPECT_EQ(papers.no_flux, NoFluxTreatment::Barrier);
  EXPECT_EQ(papers.dirichlet, DirichletMode::Layer);
  EXPECT_EQ(papers.reservoir_profile, ReservoirProfile::Uniform);
  EXPECT_EQ(papers.neumann_outflow, NeumannOutflow::Layer);
  EXPECT_EQ(papers.spacing_rule, SpacingRule::SphereRadius);  // Tables 1-3
  EXPECT_EQ(treatment_preset(TreatmentPreset::Papers, 2).spacing_rule, SpacingRule::Cube);
  // The papers' spacing: dr = (3 |Omega| / (4 pi n))^(1/3) = R n^(-1/3) on the unit ball.
  const DomainPtr ball = make_ball(3, Vec3::Zero(), 1.0);
  RunSetupOptions o;
  o.n_inf = 1600;
  o.treatment = papers;
  const RunSetup s = setup_run(*ball, {{0, PatchKind::Dirichlet, 1.0}}, o);
  EXPECT_NEAR(s.parameters.dr, std::cbrt(1.0 / 1600.0), 1e-14);
  EXPECT_EQ(s.parameters.reservoir_width, 0.0);
  EXPECT_EQ(s.options.projection.dirichlet_mode, DirichletMode::Layer);
  EXPECT_EQ(treatment_preset_from_string(to_string(TreatmentPreset::Papers)), TreatmentPreset::Papers);
}

TEST(RunSetup, ErrorsNameTheField) {
  const DomainPtr ball = make_ball(3, Vec3::Zero(), 1.0);
  const std::vector<ConstantBoundaryData> data = {{0, PatchKind::Dirichlet, 1.0}};
  auto first = [&](const std::function<void(RunSetupOptions&)>& change) {
    RunSetupOptions o;
    change(o);
    return error_of([&] { run_parameters(*ball, data, o); });
  };
  EXPECT_EQ(first([](RunSetupOptions& o) { o.n_inf = 0; }).rfind("n_inf = 0: must be >= 1", 0), 0u);
  EXPECT_EQ(first([](RunSetupOptions& o) { o.kappa = -1.0; }).rfind("kappa = -1: ", 0), 0u);
  EXPECT_EQ(first([](RunSetupOptions& o) { o.dt_factor = 1e-12; }).rfind("dt_factor = 1e-12: dt = ", 0), 0u);
  EXPECT_EQ(first([](RunSetupOptions& o) { o.dt = 1e-12; }).rfind("dt = 1e-12: gives 1e+12 steps", 0), 0u);
  EXPECT_EQ(first([](RunSetupOptions& o) { o.barrier_factor = 1e308; }).rfind("barrier_factor = 1e+308: ", 0), 0u);
  EXPECT_EQ(first([](RunSetupOptions& o) { o.treatment.reservoir_width = 0.0; }).rfind("reservoir_width = 0: ", 0),
            0u);
  EXPECT_EQ(first([](RunSetupOptions& o) { o.width.exponent = 3.0; }).rfind("width exponent q = 3: ", 0), 0u);
}

// The command line's run of a configuration that gives only the domain and
// its data is the library's setup_run() with default RunSetupOptions: the
// same numbers, and the same particles after the band fill and one step, to the bit.
TEST(RunSetup, LibraryDefaultsAreTheCliDefaultRun) {
  const std::string text =
      "[domain]\ntype = \"ball\"\nradius = 1.0\n"
      "[[boundary]]\npatch = \"surface\"\nkind = \"dirichlet\"\nvalue = 0.3\n";
  app::ConfiguredRun run(app::parse_config_string(text));
  const DomainPtr ball = make_ball(3, Vec3::Zero(), 1.0);
  const std::vector<ConstantBoundaryData> data = {{0, PatchKind::Dirichlet, 0.3}};
  const RunSetup s = setup_run(*ball, data, RunSetupOptions{});
  const app::Derived& d = run.derived();
  EXPECT_EQ(d.dr, s.parameters.dr);
  EXPECT_EQ(d.width_s, s.parameters.width_s);
  EXPECT_EQ(d.dt, s.parameters.dt);
  EXPECT_EQ(d.n_steps, s.parameters.n_steps);
  EXPECT_EQ(d.barrier_C, s.parameters.barrier_C);
  EXPECT_EQ(d.reservoir_width, s.parameters.reservoir_width);
  EXPECT_EQ(d.reservoir_sublayers, s.parameters.reservoir_sublayers);
  EXPECT_EQ(d.M_inf, s.parameters.M_inf);
  EXPECT_EQ(d.particle_mass, s.parameters.particle_mass);

  std::unique_ptr<Simulation> cli = run.make_simulation();
  Simulation lib(ball, data, s.options);
  lib.start(ParticleSet(3));
  ASSERT_GT(lib.particles().size(), 0u);  // the band is filled at the start
  for (std::int64_t k = 1; k <= 1; ++k) {
    const double t = static_cast<double>(k) * s.parameters.dt;
    cli->advance_to(t);
    lib.advance_to(t);
  }
  const ParticleSet& a = cli->particles();
  const ParticleSet& b = lib.particles();
  ASSERT_EQ(a.size(), b.size());
  EXPECT_EQ(a.ids(), b.ids());
  EXPECT_EQ(a.positions(), b.positions());
  EXPECT_EQ(a.widths(), b.widths());
  EXPECT_EQ(a.masses(), b.masses());
}

}  // namespace
