// Analytic references written by `otfp run`: the cosine and lattice fills,
// the measured quantities (blob second moment, mode amplitude) computed
// independently from particles_final.csv, the error columns and statistics.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <numbers>
#include <string>
#include <vector>

#include "app_test_support.hpp"
#include "otfp/analytic.hpp"
#include "otfp_app/config.hpp"
#include "otfp_app/simulation.hpp"

using namespace otfp::app;
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
