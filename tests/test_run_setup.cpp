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
