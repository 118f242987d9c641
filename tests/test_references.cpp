// Analytic references: the library's objects (otfp/reference.hpp: error
// statistics, the decay-rate fit, each reference's columns against the
// analytic functions, their state round trip), and what `otfp run` writes:
// the cosine and lattice fills, the measured quantities (blob second moment,
// mode amplitude) computed independently from particles_final.csv, the error
// columns and statistics, and a resumed run's reference.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <map>
#include <memory>
#include <numbers>
#include <string>
#include <utility>
#include <variant>
#include <vector>

#include "app_test_support.hpp"
#include "otfp/analytic.hpp"
#include "otfp/diagnostics.hpp"
#include "otfp/reference.hpp"
#include "otfp_app/config.hpp"
#include "otfp_app/simulation.hpp"

using namespace otfp::app;
using otfp::StepRecord;
using otfp::test::fresh_dir;
using otfp::test::read_csv;
namespace fs = std::filesystem;

namespace {

const fs::path kExamples = fs::path(OTFP_SOURCE_DIR) / "examples";

RunResult run_example(const std::string& name, const std::vector<std::string>& sets, const fs::path& out = {}) {
  ConfiguredRun sim(parse_config_file(kExamples / name, sets));
  RunOptions o;
  o.out_dir = out;
  return sim.run(o);
}

double number(const std::map<std::string, std::string>& row, const std::string& col) {
  return std::stod(row.at(col));
}

}  // namespace

// The lattice cosine fill samples 1 + a cos(k x) by the inverse cumulative
// density at cell centres: its blob mode amplitude is a exp(-k^2 s^2 / 4) up to
// the midpoint rule's O((k dr)^2) error, and the lattice has round(1/dr)^d points.
TEST(References, LatticeCosineFillHasTheRequestedAmplitude) {
  const RunResult r = run_example("periodic_cosine.toml", {"run.max_steps=1"});
  ASSERT_EQ(r.exit_code, 0) << r.error;
  EXPECT_EQ(r.series.front().n_particles, 1024);
  const double k = 2.0 * std::numbers::pi, s = r.summary["derived"]["width_s"].get<double>();
  const double expected = 0.5 * std::exp(-0.25 * k * k * s * s);
  const StepRecord& first = r.series.front();
  ASSERT_EQ(first.reference_values.size(), 3u);
  EXPECT_NEAR(first.reference_values[0], expected, 2e-3 * expected);
}

// Random arrangement: the same amplitude within the sampling noise
// sqrt(2 / n) = 0.044 (3 sigma: 0.13).
TEST(References, RandomCosineFillHasTheRequestedAmplitude) {
  const RunResult r = run_example("periodic_cosine.toml", {"run.max_steps=1", "particles.fill_arrangement=random"});
  ASSERT_EQ(r.exit_code, 0) << r.error;
  const double k = 2.0 * std::numbers::pi, s = r.summary["derived"]["width_s"].get<double>();
  EXPECT_NEAR(r.series.front().reference_values[0], 0.5 * std::exp(-0.25 * k * k * s * s), 0.13);
}

// With wide blobs (beta dr^2 = 1/2) on a lattice the mode decays at the
// diffusion rate kappa k^2 (measured: ratio 1.006 at this size); 5% band.
// The summary's fitted rate is checked against a fit done here.
TEST(References, CosineModeDecaysAtTheDiffusionRate) {
  const RunResult r = run_example("periodic_cosine.toml", {"run.t_end=0.02", "particles.beta_factor=0.5"});
  ASSERT_EQ(r.exit_code, 0) << r.error;
  const auto& ref = r.summary["reference"];
  const double lambda = 4.0 * std::numbers::pi * std::numbers::pi;
  EXPECT_NEAR(ref["kappa_k2"].get<double>(), lambda, 1e-12);
  double st = 0, sy = 0, stt = 0, sty = 0, m = 0;
  for (const StepRecord& row : r.series) {
    const double a = row.reference_values[0];
    if (!(a > 0.05 * r.series.front().reference_values[0])) break;
    st += row.t;
    sy += std::log(a);
    stt += row.t * row.t;
    sty += row.t * std::log(a);
    ++m;
  }
  const double rate = -(m * sty - st * sy) / (m * stt - st * st);
  EXPECT_NEAR(ref["fitted_rate"].get<double>(), rate, 1e-9 * rate);
  EXPECT_NEAR(ref["rate_ratio"].get<double>(), 1.0, 0.05);
  // Per row: reference = a(0) exp(-kappa k^2 t), error = (a - reference) / a(0).
  const double a0 = r.series.front().reference_values[0];
  for (const StepRecord& row : r.series) {
    EXPECT_NEAR(row.reference_values[1], a0 * std::exp(-lambda * row.t), 1e-14);
    EXPECT_NEAR(row.reference_values[2], (row.reference_values[0] - row.reference_values[1]) / a0, 1e-14);
  }
}

// The free-space second moment includes each blob's own variance d s^2 / 2:
// recomputed from particles_final.csv with per-particle widths (which change).
TEST(References, FreeSpaceSecondMomentCountsTheBlobWidths) {
  const fs::path dir = fresh_dir("ref_free");
  const RunResult r = run_example("free_space_heat.toml",
                                  {"run.dim=2", "particles.n_inf=60", "run.max_steps=4", "run.vtk_interval=0",
                                   "solver.width_mode=per_particle"},
                                  dir);
  ASSERT_EQ(r.exit_code, 0) << r.error;
  const auto particles = read_csv(dir / "particles_final.csv");
  ASSERT_EQ(particles.size(), 60u);
  double S = 0.0, smin = 1e300, smax = 0.0;
  for (const auto& p : particles) {
    const double x = number(p, "x"), y = number(p, "y"), s = number(p, "width_s");
    S += number(p, "mass") * (x * x + y * y + s * s);  // d s^2 / 2 with d = 2
    smin = std::min(smin, s);
    smax = std::max(smax, s);
  }
  EXPECT_GT(smax, smin);  // the widths did change
  EXPECT_NEAR(r.last.reference_values[0], S, 1e-12 * S);
  const auto series = read_csv(dir / "series.csv");
  EXPECT_NEAR(number(series.back(), "second_moment"), S, 1e-12 * S);
  // Reference: S(0) + 2 d kappa M t.
  const double M = r.last.mass_total;
  EXPECT_NEAR(r.last.reference_values[1], r.series.front().reference_values[0] + 4.0 * M * r.last.t, 1e-12 * S);
  fs::remove_all(dir);
}

// Box with one Dirichlet face: Crank's slab for the mass, and the polar-inertia
// reference that tends to the uniform box's J_inf (about the centre:
// M (4 + 1 + 1) / 12 = 500 for the 2 x 1 x 1 box with M = 1000).
TEST(References, SlabPolarInertiaReferenceTendsToTheUniformBox) {
  // The reference does not depend on the treatment: the papers' is the cheaper one here.
  const RunResult r =
      run_example("box_mixed.toml", {"run.t_end=200", "run.dt=100", "run.vtk_interval=0", "treatment.preset=papers"});
  ASSERT_EQ(r.exit_code, 0) << r.error;
  ASSERT_EQ(r.last.reference_values.size(), 4u);
  EXPECT_NEAR(r.last.reference_values[0], otfp::analytic::crank_slab_uptake(200.0 / 4.0), 1e-15);
  EXPECT_NEAR(r.last.reference_values[2], 500.0, 1e-6);
  EXPECT_NEAR(r.summary["derived"]["reference_J_inf"].get<double>(), 500.0, 1e-9);
  const auto& q = r.summary["reference"]["quantities"];
  ASSERT_EQ(q.size(), 2u);
  EXPECT_EQ(q[1]["measured"], "polar_inertia");
  // Error statistics over the rows: max |error| and the final error agree with the rows.
  double max_err = 0.0;
  for (const StepRecord& row : r.series) max_err = std::max(max_err, std::abs(row.reference_values[1]));
  EXPECT_DOUBLE_EQ(q[0]["max_abs_error"].get<double>(), max_err);
  EXPECT_DOUBLE_EQ(q[0]["final_error"].get<double>(), r.last.reference_values[1]);
}

// Intermediate time (tau = kappa t / L^2 = 0.05, the profile is a boundary
// layer) and an off-centre polar-inertia centre: the slab reference against
// a quadrature done here, of Crank 4.17 summed here (independent of
// otfp::analytic and of the tool's Simpson rule): midpoint rule, 20000 cells.
TEST(References, SlabPolarInertiaReferenceAtAnIntermediateTime) {
  const RunResult r = run_example("box_mixed.toml", {"run.t_end=0.2", "run.dt=0.2", "run.vtk_interval=0",
                                                     "diagnostics.center=[0.3, 0.2, 0.9]", "treatment.preset=papers"});
  ASSERT_EQ(r.exit_code, 0) << r.error;
  ASSERT_EQ(r.last.reference_values.size(), 4u);
  const double L = 2.0, tau = 0.2 / (L * L);
  auto density = [&](double xi) {  // rho/g at depth xi from the held face x = 0
    double s = 0.0;
    for (int k = 0; k < 2000; ++k) {
      const double o = 2.0 * k + 1.0;
      s += ((k % 2) ? -1.0 : 1.0) / o * std::exp(-o * o * M_PI * M_PI * tau / 4.0) * std::cos(o * M_PI * (L - xi) / (2.0 * L));
    }
    return 1.0 - 4.0 / M_PI * s;
  };
  // J = g * integral over the box of rho/g |x - c|^2; g |Omega| = M_inf = 1000, |Omega| = 2.
  const double g = 500.0, cy = 0.2, cz = 0.9;
  const double transverse = (1.0 / 12.0 + (0.5 - cy) * (0.5 - cy)) + (1.0 / 12.0 + (0.5 - cz) * (0.5 - cz));
  const int cells = 20000;
  double J = 0.0;
  for (int i = 0; i < cells; ++i) {
    const double x = (i + 0.5) * L / cells;
    J += density(x) * ((x - 0.3) * (x - 0.3) + transverse) * (L / cells);
  }
  J *= g;  // cross-section area 1
  EXPECT_NEAR(r.last.reference_values[2], J, 1e-6 * J);
  EXPECT_GT(J, 0.0);
  EXPECT_LT(J, 0.9 * r.summary["derived"]["reference_J_inf"].get<double>());  // far from the uniform limit
}

// The cosine reference needs the periodic box and the cosine fill.
TEST(References, CosineModeNeedsPeriodicBoxAndCosineFill) {
  EXPECT_THROW(parse_config_file(kExamples / "periodic_cosine.toml", {"particles.fill=uniform"}), ConfigError);
  EXPECT_THROW(parse_config_file(kExamples / "sphere_dirichlet.toml", {"diagnostics.reference=cosine_mode"}),
               ConfigError);
  EXPECT_THROW(parse_config_file(kExamples / "periodic_cosine.toml", {"particles.fill_amplitude=1"}), ConfigError);
  EXPECT_THROW(parse_config_file(kExamples / "periodic_cosine.toml", {"particles.fill_count=10"}), ConfigError);
  EXPECT_THROW(parse_config_file(kExamples / "periodic_cosine.toml", {"particles.fill_amplitude=0"}), ConfigError);
}

// ---- The library's reference objects

namespace {

// Samples of a made-up run: measures, M_rho and particles that change with t.
otfp::ReferenceSample sample_at(double t, otfp::ParticleSet& particles) {
  for (std::size_t p = 0; p < particles.size(); ++p) {
    // Spread about x = 0: the mode amplitude along x (k = 2 pi) is > 0 and falls.
    const double q = static_cast<double>(p);
    particles.positions()[p][0] = 0.03 * (q - 2.0) * (1.0 + 5.0 * t) + 0.01 * std::sin(3.0 * t + q);
    particles.positions()[p][1] = 0.3 * static_cast<double>(p % 2) + 0.1 * t;
    particles.widths()[p] = 0.05 * (1.0 + t);
  }
  otfp::ReferenceSample s;
  s.t = t;
  s.measures.mass_total = particles.total_mass();
  s.measures.mass_inside = 0.8 * (1.0 - std::exp(-2.0 * t));
  s.measures.polar_inertia = 0.3 * (1.0 - std::exp(-1.5 * t));
  s.mass_blob = 0.75 * (1.0 - std::exp(-2.1 * t));
  s.particles = &particles;
  s.initial_mass = 1.0;
  return s;
}

otfp::ParticleSet some_particles() {
  otfp::ParticleSet ps(2);
  for (int p = 0; p < 5; ++p) ps.add(otfp::Vec3::Zero(), 0.05, 0.2);
  return ps;
}

// A setup every reference accepts: a slab box [0, 2] x [0, 1] held at x = 0,
// the radius of a ball, a cosine mode of wavelength 1, constant implicit Euler steps.
otfp::ReferenceSetup full_setup() {
  otfp::ReferenceSetup s;
  s.dim = 2;
  s.kappa = 0.5;
  s.t_end = 1.0;
  s.center = otfp::Vec3(0.9, 0.4, 0.0);
  s.M_inf = 1.0;
  s.radius = 1.0;
  s.length = 2.0;
  s.J_inf = 0.4;
  s.lo = otfp::Vec3::Zero();
  s.hi = otfp::Vec3(2.0, 1.0, 0.0);
  s.slab_axis = 0;
  s.wavenumber = 2.0 * std::numbers::pi;
  s.constant_dt = 0.01;
  return s;
}

std::vector<std::pair<std::string, std::string>> summary_text(const otfp::Reference& ref) {
  std::vector<std::pair<std::string, std::string>> out;
  for (const otfp::ReferenceEntry& e : ref.summary())
    out.emplace_back(e.key, std::visit([](auto v) { return std::to_string(v); }, e.value));
  for (const otfp::ErrorStatistics& e : ref.statistics())
    for (double v : e.state()) out.emplace_back(e.measured(), std::to_string(v));
  return out;
}

}  // namespace

// Three rows by hand: (t, measured, reference) = (0, 1, 1), (1, 3, 1),
// (3, 0, 2) with scale 2 give errors 0, 1, -1; |error| integrates to
// 1/2 (trapezoid) + 1 (exact across the sign change: two triangles of area 1/2).
TEST(ReferenceObjects, ErrorStatisticsByHand) {
  otfp::ErrorStatistics e("q", 2.0, "two");
  EXPECT_FALSE(e.started());
  EXPECT_EQ(e.add(0.0, 1.0, 1.0), 0.0);
  EXPECT_EQ(e.add(1.0, 3.0, 1.0), 1.0);
  EXPECT_EQ(e.add(3.0, 0.0, 2.0), -1.0);
  EXPECT_TRUE(e.started());
  EXPECT_EQ(e.measured(), "q");
  EXPECT_EQ(e.scale_rule(), "two");
  EXPECT_EQ(e.max_abs_error(), 1.0);
  EXPECT_EQ(e.final_error(), -1.0);
  EXPECT_EQ(e.l1_time_error(), 1.5);
  EXPECT_EQ(e.mean_abs_error(), 0.5);
  EXPECT_EQ(e.l1_norm(), 0.5 * (1 + 3) * 1 + 0.5 * (3 + 0) * 2);       // 5
  EXPECT_EQ(e.l1_norm_reference(), 0.5 * (1 + 1) * 1 + 0.5 * (1 + 2) * 2);  // 4
  EXPECT_EQ(e.l1_norm_relative_error(), 0.25);
  EXPECT_EQ(e.t_first(), 0.0);
  EXPECT_EQ(e.t_last(), 3.0);
  // One row: no time, mean 0; no reference integral: relative error 0.
  otfp::ErrorStatistics one("q", 1.0, "");
  one.add(2.0, 0.0, 0.0);
  EXPECT_EQ(one.mean_abs_error(), 0.0);
  EXPECT_EQ(one.l1_norm_relative_error(), 0.0);
  // The state continues the sums exactly.
  otfp::ErrorStatistics copy("q", 1.0, "two");
  copy.load_state(e.state());
  EXPECT_EQ(copy.scale(), 2.0);
  EXPECT_EQ(copy.add(4.5, 0.7, 0.1), e.add(4.5, 0.7, 0.1));
  EXPECT_EQ(copy.state(), e.state());
  EXPECT_THROW(copy.load_state({1.0, 2.0}), otfp::InvalidArgument);
}

// Exact exponential data give their rate back; too few samples give NaN.
TEST(ReferenceObjects, DecayRateFitRecoversAKnownRate) {
  std::vector<double> t, a;
  for (int i = 0; i <= 40; ++i) {
    t.push_back(0.0125 * i);
    a.push_back(0.7 * std::exp(-3.25 * t.back()));
  }
  EXPECT_NEAR(otfp::decay_rate_fit(t, a), 3.25, 1e-12);
  EXPECT_TRUE(std::isnan(otfp::decay_rate_fit({0.0, 1.0}, {1.0, 0.5})));
  EXPECT_NEAR(otfp::decay_rate_fit({0.0, 1.0, 2.0}, {1.0, 0.5, 0.25}), std::log(2.0), 1e-15);
  EXPECT_THROW(otfp::decay_rate_fit({0.0, 1.0, 2.0}, {1.0, 0.5}), otfp::InvalidArgument);
  EXPECT_THROW(otfp::decay_rate_fit({0.0, 1.0, 2.0}, {1.0, 0.0, 0.5}), otfp::InvalidArgument);
}

TEST(ReferenceObjects, RegisteredNames) {
  EXPECT_EQ(otfp::reference_names(), (std::vector<std::string>{"crank_sphere", "crank_slab", "free_space", "cosine_mode"}));
  for (const std::string& name : otfp::reference_names())
    EXPECT_EQ(otfp::make_reference(name, full_setup())->name(), name);
  EXPECT_THROW(otfp::make_reference("crank_cylinder", full_setup()), otfp::InvalidArgument);
  otfp::ReferenceSetup bad = full_setup();
  bad.radius = 0.0;
  EXPECT_THROW(otfp::make_reference("crank_sphere", bad), otfp::InvalidArgument);
  bad = full_setup();
  bad.slab_axis = -1;  // a polar inertia without its box
  EXPECT_THROW(otfp::make_reference("crank_slab", bad), otfp::InvalidArgument);
  bad.J_inf.reset();
  EXPECT_EQ(otfp::make_reference("crank_slab", bad)->columns().size(), 2u);
  bad = full_setup();
  bad.wavenumber = 0.0;
  EXPECT_THROW(otfp::make_reference("cosine_mode", bad), otfp::InvalidArgument);
}

// Crank's sphere and slab: the columns are analytic.hpp's curves, the errors
// (measured - reference) / scale, and error_mass_blob M_rho / M_inf - M_ref / M_inf.
TEST(ReferenceObjects, CrankColumnsAreTheAnalyticCurves) {
  using namespace otfp::analytic;
  otfp::ParticleSet ps = some_particles();
  for (const bool sphere : {true, false}) {
    SCOPED_TRACE(sphere ? "sphere" : "slab");
    otfp::ReferenceSetup setup = full_setup();
    setup.M_inf = 2.0;
    const auto ref = otfp::make_reference(sphere ? "crank_sphere" : "crank_slab", setup);
    EXPECT_EQ(ref->columns(), (std::vector<std::string>{"reference_mass_ratio", "error_mass_ratio",
                                                        "reference_polar_inertia", "error_polar_inertia"}));
    EXPECT_TRUE(ref->has_mass_blob_error());
    for (const double t : {0.0, 0.05, 0.3}) {
      const otfp::ReferenceSample s = sample_at(t, ps);
      const otfp::ReferenceRow row = ref->row(s);
      const double L = sphere ? 1.0 : 2.0, tau = 0.5 * t / (L * L);
      const double m = sphere ? crank_sphere_uptake(tau) : crank_slab_uptake(tau);
      SlabBox box;
      box.dim = 2;
      box.lo = setup.lo;
      box.hi = setup.hi;
      box.length = 2.0;
      box.center = setup.center;
      box.M_inf = 2.0;
      const double j = sphere ? 0.4 * crank_sphere_polar_inertia(tau) : t > 0.0 ? crank_slab_polar_inertia(tau, box) : 0.0;
      ASSERT_EQ(row.values.size(), 4u);
      EXPECT_EQ(row.values[0], m);
      EXPECT_EQ(row.values[1], s.measures.mass_inside / 2.0 - m);
      EXPECT_EQ(row.values[2], j);
      EXPECT_EQ(row.values[3], (s.measures.polar_inertia - j) / 0.4);
      EXPECT_EQ(row.reference, m);
      ASSERT_TRUE(row.error_mass_blob);
      EXPECT_EQ(*row.error_mass_blob, s.mass_blob / 2.0 - m);
    }
    const auto stats = ref->statistics();
    ASSERT_EQ(stats.size(), 2u);
    EXPECT_EQ(stats[0].measured(), "mass_ratio");
    EXPECT_EQ(stats[1].measured(), "polar_inertia");
    EXPECT_EQ(stats[1].scale(), 0.4);
    ASSERT_TRUE(ref->mass_blob_statistics());
    EXPECT_EQ(ref->mass_blob_statistics()->measured(), "mass_blob_ratio");
    EXPECT_TRUE(ref->summary().empty());
  }
}

// Free space: the blob second moment against S(0) + 2 d kappa M(0) t, the
// error scaled by 2 d kappa M t_end; the summary's growth ratio.
TEST(ReferenceObjects, FreeSpaceColumnsAreTheSecondMomentAndItsGrowth) {
  otfp::ParticleSet ps = some_particles();
  const otfp::ReferenceSetup setup = full_setup();
  const auto ref = otfp::make_reference("free_space", setup);
  EXPECT_EQ(ref->columns(), (std::vector<std::string>{"second_moment", "reference_second_moment", "error_second_moment"}));
  EXPECT_FALSE(ref->has_mass_blob_error());
  EXPECT_TRUE(ref->statistics().empty()) << "listed from the first row on";
  double S0 = 0.0, S = 0.0;
  const double M = ps.total_mass(), scale = 2.0 * 2 * 0.5 * M * 1.0;
  for (const double t : {0.0, 0.1, 0.25}) {
    const otfp::ReferenceRow row = ref->row(sample_at(t, ps));
    S = otfp::blob_second_moment(ps, setup.center);
    if (t == 0.0) S0 = S;
    const double rs = S0 + 2.0 * 2 * 0.5 * 1.0 * t;  // M(0) = initial_mass = 1
    ASSERT_EQ(row.values.size(), 3u);
    EXPECT_EQ(row.values[0], S);
    EXPECT_EQ(row.values[1], rs);
    EXPECT_EQ(row.values[2], (S - rs) / scale);
    EXPECT_EQ(row.reference, rs);
    EXPECT_FALSE(row.error_mass_blob);
  }
  ASSERT_EQ(ref->statistics().size(), 1u);
  EXPECT_EQ(ref->statistics()[0].scale(), scale);
  const auto summary = ref->summary();
  ASSERT_EQ(summary.size(), 1u);
  EXPECT_EQ(summary[0].key, "growth_ratio");
  EXPECT_EQ(std::get<double>(summary[0].value), (S - S0) / (2.0 * 2 * 0.5 * 1.0 * 0.25));
}

// Cosine mode: the amplitude against a(0) exp(-kappa k^2 t); the summary's
// fitted rate over the rows with a > 0.05 a(0) and the time-discrete rate.
TEST(ReferenceObjects, CosineModeColumnsAndFittedRate) {
  otfp::ParticleSet ps = some_particles();
  const otfp::ReferenceSetup setup = full_setup();
  const auto ref = otfp::make_reference("cosine_mode", setup);
  const double k = setup.wavenumber, lambda = 0.5 * k * k;
  std::vector<double> ts, as;
  double a0 = 0.0;
  for (int i = 0; i <= 4; ++i) {
    const double t = 0.01 * i;
    const otfp::ReferenceRow row = ref->row(sample_at(t, ps));
    const double a = otfp::cosine_mode_amplitude(ps, k, 0.0);
    if (i == 0) a0 = a;
    const double ra = a0 * otfp::analytic::cosine_mode_decay(0.5, k, t);
    ASSERT_EQ(row.values.size(), 3u);
    EXPECT_EQ(row.values[0], a);
    EXPECT_EQ(row.values[1], ra);
    EXPECT_EQ(row.values[2], (a - ra) / std::abs(a0));
    if (a0 > 0.0 && a > 0.05 * a0 && ts.size() == static_cast<std::size_t>(i)) {
      ts.push_back(t);
      as.push_back(a);
    }
  }
  ASSERT_GT(a0, 0.0);
  std::map<std::string, std::variant<double, std::int64_t>> entries;
  for (const otfp::ReferenceEntry& e : ref->summary()) entries[e.key] = e.value;
  EXPECT_EQ(std::get<double>(entries.at("kappa_k2")), lambda);
  EXPECT_EQ(std::get<std::int64_t>(entries.at("rows_fitted")), static_cast<std::int64_t>(ts.size()));
  const double rate = otfp::decay_rate_fit(ts, as);
  EXPECT_EQ(std::get<double>(entries.at("fitted_rate")), rate);
  EXPECT_EQ(std::get<double>(entries.at("rate_ratio")), rate / lambda);
  const double discrete = otfp::analytic::time_discrete_rate(otfp::TimeScheme::Euler, lambda, 0.01);
  EXPECT_EQ(std::get<double>(entries.at("time_discrete_rate")), discrete);
  EXPECT_EQ(std::get<double>(entries.at("rate_ratio_time_discrete")), rate / discrete);
  // Steps that are not constant: no time-discrete rate.
  otfp::ReferenceSetup adaptive = setup;
  adaptive.constant_dt = 0.0;
  for (const otfp::ReferenceEntry& e : otfp::make_reference("cosine_mode", adaptive)->summary())
    if (e.key == "time_discrete_rate" || e.key == "rate_ratio_time_discrete" || e.key == "fitted_rate") {
      EXPECT_TRUE(std::isnan(std::get<double>(e.value))) << e.key;
    }
}

// Every reference saved after some rows and loaded into a new one gives the
// same next rows, statistics and summary bit for bit; a state that lacks an
// entry is refused naming it.
TEST(ReferenceObjects, StateRoundTripGivesIdenticalRows) {
  for (const std::string& name : otfp::reference_names()) {
    SCOPED_TRACE(name);
    otfp::ParticleSet ps = some_particles();
    const auto a = otfp::make_reference(name, full_setup());
    for (int i = 0; i < 4; ++i) a->row(sample_at(0.01 * i, ps));
    const otfp::ReferenceState state = a->save_state();
    const auto b = otfp::make_reference(name, full_setup());
    b->load_state(state);
    EXPECT_EQ(b->save_state(), state);
    for (int i = 4; i < 9; ++i) {
      const otfp::ReferenceRow ra = a->row(sample_at(0.01 * i, ps)), rb = b->row(sample_at(0.01 * i, ps));
      EXPECT_EQ(ra.values, rb.values);
      EXPECT_EQ(ra.reference, rb.reference);
      EXPECT_EQ(ra.error_mass_blob, rb.error_mass_blob);
    }
    EXPECT_EQ(summary_text(*a), summary_text(*b));
    EXPECT_EQ(a->save_state(), b->save_state());
    // Loaded before any row: the first row still sets the initial values.
    const auto fresh = otfp::make_reference(name, full_setup());
    const auto c = otfp::make_reference(name, full_setup());
    c->load_state(fresh->save_state());
    EXPECT_EQ(c->row(sample_at(0.0, ps)).values, fresh->row(sample_at(0.0, ps)).values);
    // A state with an entry missing is refused.
    otfp::ReferenceState broken = state;
    broken.erase(broken.begin());
    try {
      b->load_state(broken);
      ADD_FAILURE() << "accepted a state without " << state.begin()->first;
    } catch (const otfp::InvalidArgument& e) {
      EXPECT_NE(std::string(e.what()).find(state.begin()->first), std::string::npos) << e.what();
    }
  }
}

// `otfp run` stopped and resumed (its checkpoint holds the reference's state):
// series.csv and summary.json's reference are those of the run made at once,
// for a reference of each kind.
TEST(References, ResumedRunKeepsTheReference) {
  const std::vector<std::pair<std::string, std::vector<std::string>>> runs = {
      {"periodic_cosine.toml", {"run.max_steps=8", "particles.n_inf=256"}},
      {"free_space_heat.toml", {"run.max_steps=8", "run.dim=2", "particles.n_inf=60"}},
      {"box_mixed.toml", {"run.max_steps=6", "run.dt=0.05", "treatment.preset=papers"}},
  };
  for (const auto& [name, sets0] : runs) {
    SCOPED_TRACE(name);
    std::vector<std::string> sets = sets0;
    sets.push_back("run.vtk_interval=0");
    const fs::path full = fresh_dir("ref_resume_full"), cut = fresh_dir("ref_resume_cut");
    const RunResult a = run_example(name, sets, full);
    ASSERT_EQ(a.exit_code, 0) << a.error;
    RunOptions o;
    o.out_dir = cut;
    o.stop_after_step = 3;
    ASSERT_EQ(ConfiguredRun(parse_config_file(kExamples / name, sets)).run(o).exit_code, kExitInterrupted);
    o.stop_after_step = 0;
    o.resume = true;
    const RunResult b = ConfiguredRun(parse_config_file(kExamples / name, sets)).run(o);
    ASSERT_EQ(b.exit_code, 0) << b.error;
    EXPECT_EQ(otfp::test::read_text(full / "series.csv"), otfp::test::read_text(cut / "series.csv"));
    EXPECT_EQ(a.summary.at("reference").dump(), b.summary.at("reference").dump());
    fs::remove_all(full);
    fs::remove_all(cut);
  }
}

// What the Crank references read from the domain: the ball's radius and
// (3/5) M R^2 about its centre; a box's depth across its one held face and
// M_inf times its mean squared distance (the box's own closed form).
TEST(ReferenceObjects, CrankGeometryFromTheDomain) {
  const otfp::DomainPtr ball = otfp::make_ball(3, otfp::Vec3(0.5, 0, 0), 2.0);
  otfp::ReferenceSetup s;
  s.center = otfp::Vec3(0.5, 0, 0);
  s.M_inf = 3.0;
  otfp::complete_reference_geometry("crank_sphere", *ball, {0}, s);
  EXPECT_EQ(s.radius, 2.0);
  ASSERT_TRUE(s.J_inf.has_value());
  EXPECT_NEAR(*s.J_inf, 0.6 * 3.0 * 4.0, 1e-14);
  // Off centre: no polar-inertia reference; a given radius is kept.
  otfp::ReferenceSetup off;
  off.center = otfp::Vec3::Zero();
  off.radius = 1.5;
  otfp::complete_reference_geometry("crank_sphere", *ball, {0}, off);
  EXPECT_EQ(off.radius, 1.5);
  EXPECT_FALSE(off.J_inf.has_value());

  // A box held at y = 3 (patch 3): depth 3 along axis 1.
  const otfp::DomainPtr box = otfp::make_box(2, otfp::Vec3(0, 0, 0), otfp::Vec3(2, 3, 0));
  otfp::ReferenceSetup slab;
  slab.dim = 2;
  slab.center = otfp::Vec3(1, 1.5, 0);
  slab.M_inf = 2.0;
  otfp::complete_reference_geometry("crank_slab", *box, {3}, slab);
  EXPECT_EQ(slab.length, 3.0);
  EXPECT_EQ(slab.slab_axis, 1);
  EXPECT_TRUE(slab.slab_held_at_hi);
  ASSERT_TRUE(slab.J_inf.has_value());
  EXPECT_NEAR(*slab.J_inf, 2.0 * (4.0 / 12.0 + 9.0 / 12.0), 1e-14);
  // Two held faces: no slab geometry.
  otfp::ReferenceSetup two;
  two.dim = 2;
  otfp::complete_reference_geometry("crank_slab", *box, {2, 3}, two);
  EXPECT_EQ(two.length, 0.0);
  EXPECT_EQ(two.slab_axis, -1);
  EXPECT_FALSE(two.J_inf.has_value());
  // The set-up's dim left at its default (3) on the 2-D box: refused, not a
  // 3-D answer (face 4 would pass as a face and give a slab of depth 0).
  otfp::ReferenceSetup unset;
  EXPECT_THROW(otfp::complete_reference_geometry("crank_slab", *box, {4}, unset), otfp::InvalidArgument);
  EXPECT_EQ(unset.length, 0.0);
}
