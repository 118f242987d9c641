// The run driver and the `otfp` command: physics checks at small sizes, the
// mass ledger, determinism, the output files, and the real binary's exit codes.
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <set>
#include <numbers>
#include <sstream>
#include <string>
#include <vector>

#include "app_test_support.hpp"
#include "otfp_app/config.hpp"
#include "otfp_app/simulation.hpp"

using namespace otfp;
using namespace otfp::app;
using otfp::StepRecord;
namespace fs = std::filesystem;

namespace {

const fs::path kSource = OTFP_SOURCE_DIR;
const fs::path kExamples = kSource / "examples";

using otfp::test::fresh_dir;
using otfp::test::read_text;

RunResult run_config(Config config, const fs::path& out = {}) {
  ConfiguredRun sim(std::move(config));
  RunOptions o;
  o.out_dir = out;
  return sim.run(o);
}

RunResult run_example(const std::string& name, const std::vector<std::string>& sets, const fs::path& out = {}) {
  return run_config(parse_config_file(kExamples / name, sets), out);
}

// Runs the real binary; returns its exit code, stderr in `err`.
int run_binary(const std::string& args, std::string& err) {
  const fs::path err_file = fresh_dir("stderr");
  const std::string cmd = std::string(OTFP_CLI_PATH) + " " + args + " >" + err_file.string() + ".out 2>" +
                          err_file.string();
  const int status = std::system(cmd.c_str());
  err = read_text(err_file) + read_text(err_file.string() + ".out");
  fs::remove(err_file);
  fs::remove(err_file.string() + ".out");
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

std::vector<std::string> lines_of(const std::string& text) {
  std::vector<std::string> out;
  std::istringstream in(text);
  for (std::string l; std::getline(in, l);) out.push_back(l);
  return out;
}

// name="value" pairs of one tag (no std::regex: GCC 12 warns inside it under sanitizers).
std::map<std::string, std::string> attributes(const std::string& tag) {
  std::map<std::string, std::string> a;
  for (std::size_t eq = tag.find("=\""); eq != std::string::npos; eq = tag.find("=\"", eq + 1)) {
    std::size_t start = eq;
    while (start > 0 && (std::isalnum(static_cast<unsigned char>(tag[start - 1])) || tag[start - 1] == '_')) --start;
    const std::size_t close = tag.find('"', eq + 2);
    if (close == std::string::npos) break;
    a[tag.substr(start, eq - start)] = tag.substr(eq + 2, close - eq - 2);
    eq = close;
  }
  return a;
}

// Minimal XML well-formedness of a tag sequence: every element closes in order.
// Returns "" if well formed, else what went wrong.
std::string check_tags(const std::string& xml) {
  std::vector<std::string> stack;
  std::size_t i = 0;
  while ((i = xml.find('<', i)) != std::string::npos) {
    const std::size_t j = xml.find('>', i);
    if (j == std::string::npos) return "unterminated tag";
    const std::string tag = xml.substr(i + 1, j - i - 1);
    i = j + 1;
    if (tag.empty()) return "empty tag";
    if (tag[0] == '?') {
      if (tag.back() != '?') return "bad processing instruction";
      continue;
    }
    if (tag[0] == '/') {
      if (stack.empty() || stack.back() != tag.substr(1)) return "unbalanced </" + tag.substr(1) + ">";
      stack.pop_back();
      continue;
    }
    if (tag.back() == '/') continue;
    stack.push_back(tag.substr(0, tag.find_first_of(" \t\n")));
  }
  return stack.empty() ? "" : "unclosed <" + stack.back() + ">";
}

}  // namespace

// Sphere of radius 1 held at g on its surface, initially empty (Sec. 5.1),
// n_inf = 400 (m_p = M_inf / 400), implicit stepper, t in [0, 2] (Crank's curve
// is at 0.9999 by t = 1). Tolerances and why:
//  * The projection fills the interior layer cell B^int (thickness b = sqrt(R dr)
//    = 0.37) to its target mass in the first step, a fraction f_b = 1 - (1 - b)^3
//    = 0.75 of M_inf, which Crank's curve only reaches at t ~ 0.1: a built-in
//    excess max(0, f_b - Crank(t)), computed below.
//  * After that M_inside = (mass of B^int, pinned to its target within m_p) +
//    (mass of the core r < R - b, ~25% of the volume, ~100 particles). Counting
//    noise of the core is ~sqrt(100)/400 = 0.025 of M_inf; with m_p = 0.0025
//    that gives the 0.03 allowed on top of the layer excess in the mean
//    deviation, and the 0.1 band (4 sigma) for the filled state.
//  * The filling must never lag Crank's curve by more than 0.1 M_inf: the exact
//    gradient fills on Crank's time scale (docs/method_notes.md#effective-diffusivity; the force (27) of
//    the explicit scheme lags far more).
// Crank 6.20 summed here independently of otfp::analytic.
double crank_sphere_series(double t) {
  if (!(t > 0.0)) return 0.0;
  double s = 0.0;
  for (int n = 1; n < 1000000; ++n) {
    const double term = std::exp(-n * n * M_PI * M_PI * t) / (static_cast<double>(n) * n);
    s += term;
    if (term < 1e-20) break;
  }
  return 1.0 - 6.0 / (M_PI * M_PI) * s;
}

TEST(Cli, SphereDirichletFillsAlongCranksCurve) {
  const RunResult r =
      run_example("sphere_dirichlet.toml", {"run.t_end=2", "run.vtk_interval=0", "treatment.preset=papers"});
  ASSERT_EQ(r.exit_code, 0) << r.error;
  const double b = r.summary["derived"]["layer_b"].get<double>();
  const double f_b = 1.0 - std::pow(1.0 - b, 3);
  double dev = 0.0, layer_excess = 0.0, max_dev = 0.0, blob_dev = 0.0;
  int rows = 0;
  for (const StepRecord& s : r.series) {
    if (s.step == 0) continue;
    const double crank = crank_sphere_series(s.t);
    ASSERT_TRUE(s.reference.has_value());
    EXPECT_NEAR(*s.reference, crank, 1e-14);
    dev += std::abs(s.mass_ratio - crank);
    max_dev = std::max(max_dev, std::abs(s.mass_ratio - crank));
    ASSERT_EQ(s.reference_values.size(), 4u);  // mass ratio and polar inertia, each reference and error
    EXPECT_NEAR(s.reference_values[1], s.mass_ratio - crank, 1e-14);
    // M_rho: the blob density integrated over the ball (closed form), against the same curve.
    ASSERT_TRUE(s.error_mass_blob.has_value());
    EXPECT_NEAR(*s.error_mass_blob, s.mass_blob_ratio - crank, 1e-14);
    EXPECT_NEAR(s.mass_blob_ratio, s.mass_blob / r.summary["derived"]["M_inf"].get<double>(), 1e-15);
    EXPECT_LE(s.mass_blob, s.mass_total * (1.0 + 1e-14));
    EXPECT_GE(s.mass_blob, 0.0);
    blob_dev += std::abs(s.mass_blob_ratio - crank);
    layer_excess += std::max(0.0, f_b - crank);
    ++rows;
    EXPECT_GE(s.mass_ratio, crank - 0.1) << "lags Crank at t = " << s.t;
    if (s.t >= 1.0) {
      EXPECT_NEAR(s.mass_ratio, 1.0, 0.1) << "t = " << s.t;
    }
  }
  dev /= rows;
  layer_excess /= rows;
  EXPECT_LE(dev, layer_excess + 0.03) << "mean |M/M_inf - Crank| = " << dev << ", layer excess " << layer_excess;
  std::cout << "[ info ] mean |M/M_inf - Crank| = " << dev << " (layer excess " << layer_excess << ")\n";
  std::cout << "[ info ] mean |M_rho/M_inf - Crank| = " << blob_dev / rows << "\n";
  // The summary reports the same largest deviation.
  EXPECT_NEAR(r.summary["reference"]["quantities"][0]["max_abs_error"].get<double>(), max_dev, 1e-12);
  // M_rho's error statistics sit beside quantities[] (which keeps mass ratio, polar inertia).
  ASSERT_TRUE(r.summary["reference"].contains("mass_blob"));
  EXPECT_EQ(r.summary["reference"]["mass_blob"]["measured"], "mass_blob_ratio");
  EXPECT_EQ(r.summary["reference"]["quantities"].size(), 2u);
  EXPECT_EQ(r.summary["derived"]["mass_blob_method"], "closed_form");
  EXPECT_DOUBLE_EQ(r.summary["final"]["mass_blob"].get<double>(), r.last.mass_blob);
}

// Issue 15: solver.max_width_factor reaches the library in units of the
// run's s0 (derived.width_s): the optimised widths stay at or below it, and
// the widest press against it (unbounded they reach 3-6 s0 here).
TEST(Cli, MaxWidthFactorBoundsTheWidthsOfARun) {
  const fs::path out = fresh_dir("max_width_factor");
  const RunResult r = run_example("sphere_dirichlet.toml",
                                  {"particles.n_inf=100", "run.t_end=0.1", "run.vtk_interval=0",
                                   "solver.width_mode=per_particle", "solver.max_width_factor=1.5"},
                                  out);
  ASSERT_EQ(r.exit_code, 0) << r.error;
  const double s0 = r.summary["derived"]["width_s"].get<double>();
  double widest = 0.0;
  for (const auto& row : otfp::test::read_csv(out / "particles_final.csv"))
    widest = std::max(widest, std::stod(row.at("width_s")));
  EXPECT_LE(widest, 1.5 * s0 * (1.0 + 1e-12));
  EXPECT_GT(widest, 1.4 * s0);
  fs::remove_all(out);
}

// The default treatment (the odd reservoir outside the surface, the true
// spacing): the reservoir is filled at t = 0 and counted as step 0's
// insertions, nothing of it is inside Omega then (M(0) = 0), the filling never
// lags Crank by more than the papers' 0.1 bound above, and no particle leaves
// Omega extended by the band.
TEST(Cli, SphereDirichletReservoirIsFullFromTheStart) {
  const RunResult r = run_example("sphere_dirichlet.toml", {"particles.n_inf=150", "run.t_end=0.3", "run.vtk_interval=0"});
  ASSERT_EQ(r.exit_code, 0) << r.error;
  EXPECT_EQ(r.summary["config"]["treatment"]["dirichlet"], "reservoir");
  const StepRecord& s0 = r.series.front();
  EXPECT_EQ(s0.step, 0);
  EXPECT_GT(s0.inserted, 0);
  EXPECT_EQ(s0.n_particles, s0.inserted);
  EXPECT_EQ(s0.inserted_total, s0.inserted);
  EXPECT_EQ(s0.mass_inside, 0.0);
  // An empty interior: the odd profile holds the band at 2 g, so its mass is about 2 g |band|.
  const double g = 0.238732, w = r.summary["derived"]["reservoir_width"].get<double>();
  const double band = 4.0 / 3.0 * M_PI * (std::pow(1.0 + w, 3) - 1.0);
  EXPECT_NEAR(s0.mass_total, 2.0 * g * band, 0.05 * 2.0 * g * band);
  for (const StepRecord& s : r.series) {
    EXPECT_EQ(s.n_outside, 0) << "t = " << s.t;
    if (s.step == 0) continue;
    EXPECT_GE(s.mass_ratio, crank_sphere_series(s.t) - 0.1) << "lags Crank at t = " << s.t;
  }
}

// Pipe with equal inflow and outflow (outflow mild enough that the outlet cell
// always holds the particles to remove, so no deficit): the total mass may
// differ from its initial value only by what the two Neumann ledgers still owe,
// less than one particle mass each and of opposite sign, so |M(t) - M(0)| < m_p;
// the inflow moved equals the integral of f within m_p.
TEST(Cli, PipeWithEqualFluxesKeepsItsMass) {
  const std::string text = R"(
[run]
t_end = 1.0
seed = 3
vtk_interval = 0
[domain]
type = "cylinder"
end_a = [0.0, 0.0, 0.0]
end_b = [2.0, 0.0, 0.0]
radius = 0.5
[[domain.subpatch]]
name = "outlet"
on = "cap_b"
radius = 0.25
[particles]
n_inf = 300
spacing_rule = "sphere_radius"
beta_factor = 1.0
length_L = 0.5
fill = "uniform"
fill_mass = 1000.0
[[boundary]]
patch = "cap_a"
kind = "neumann"
value = -50.0
[[boundary]]
patch = "outlet"
kind = "neumann"
value = 200.0
)";
  const RunResult r = run_config(parse_config_string(text));
  ASSERT_EQ(r.exit_code, 0) << r.error;
  const double mp = r.summary["derived"]["particle_mass"].get<double>();
  const double M0 = r.series.front().mass_total;
  EXPECT_NEAR(M0, 1000.0, 1e-9);
  for (const StepRecord& s : r.series) EXPECT_LT(std::abs(s.mass_total - M0), mp) << "t = " << s.t;
  const double flux = 50.0 * std::numbers::pi * 0.25;  // inflow = outflow per unit time
  const auto& patches = r.summary["ledger"]["patches"];
  bool saw_inlet = false, saw_outlet = false;
  for (const auto& p : patches) {
    if (p["patch"] == "cap_a") {
      saw_inlet = true;
      EXPECT_NEAR(p["flux_integral"].get<double>(), flux * 1.0, 1e-9);
      EXPECT_LT(std::abs(p["mass_inserted"].get<double>() - flux), mp);
      EXPECT_GT(p["inserted"].get<long>(), 5);
    }
    if (p["patch"] == "outlet") {
      saw_outlet = true;
      EXPECT_NEAR(p["flux_integral"].get<double>(), -flux, 1e-9);
      EXPECT_LT(std::abs(p["mass_removed"].get<double>() - flux), mp);
      EXPECT_EQ(p["deficit"].get<double>(), 0.0);
    }
  }
  EXPECT_TRUE(saw_inlet && saw_outlet);
}

// The pipe of Sec. 5.3 at its paper fluxes: the papers' outlet owes most of
// its outflow and the mass grows; outlets that take the nearest particles and
// images at the walls keep the total mass on the analytic balance (equal
// inflow and outflow: constant) with nothing owed and no particle outside.
TEST(Cli, PipeOutletsDeliverWithTheNearestRule) {
  const std::vector<std::string> common = {"particles.n_inf=300", "run.t_end=0.2", "run.vtk_interval=0"};
  auto with = [&](std::vector<std::string> extra) {
    extra.insert(extra.end(), common.begin(), common.end());
    return run_example("pipe_neumann.toml", extra);
  };
  const RunResult papers = with({"treatment.preset=papers"});
  const RunResult best = with({});  // the default preset
  ASSERT_EQ(papers.exit_code, 0) << papers.error;
  ASSERT_EQ(best.exit_code, 0) << best.error;
  auto outlet_deficit = [](const RunResult& r) {
    for (const auto& p : r.summary["ledger"]["patches"])
      if (p["patch"] == "outlet") return p["deficit"].get<double>();
    return -1.0;
  };
  const double mp = best.summary["derived"]["particle_mass"].get<double>();
  EXPECT_GT(outlet_deficit(papers), 10.0 * mp);
  EXPECT_GT(papers.last.mass_total, 1000.0 + 10.0 * mp);
  EXPECT_EQ(outlet_deficit(best), 0.0);
  for (const StepRecord& s : best.series) {
    EXPECT_LT(std::abs(s.mass_total - 1000.0), mp) << "t = " << s.t;
    EXPECT_EQ(s.n_outside, 0) << "t = " << s.t;
  }
  EXPECT_EQ(best.summary["derived"]["mirrored_walls"].get<int>(), 3);
}

// A flux window ending inside a step still moves exactly int f dA dt (the 2023
// injection stops at T0): the driver hands the projection the step average.
// The same with adaptive steps (BDF2), whose sizes vary from step to step.
TEST(Cli, NeumannWindowIntegratesExactly) {
  for (const bool adaptive : {false, true}) {
    std::vector<std::string> sets = {"run.t_end=0.5", "boundary.orifice.t_end=0.3123", "run.vtk_interval=0"};
    if (adaptive) {
      sets.insert(sets.end(), {"run.dt_mode=adaptive", "solver.time_scheme=bdf2", "run.time_tolerance=0.05"});
    }
    const RunResult r = run_example("sphere_injection.toml", sets);
    ASSERT_EQ(r.exit_code, 0) << r.error;
    const double mp = r.summary["derived"]["particle_mass"].get<double>();
    const double area = std::numbers::pi * 0.25 * 0.25;
    const double want = 40.743665 * area * 0.3123;
    bool found = false;
    for (const auto& p : r.summary["ledger"]["patches"])
      if (p["patch"] == "orifice") {
        found = true;
        EXPECT_NEAR(p["flux_integral"].get<double>(), want, 1e-9 * want) << "adaptive " << adaptive;
        EXPECT_LT(std::abs(p["mass_inserted"].get<double>() - want), mp) << "adaptive " << adaptive;
      }
    EXPECT_TRUE(found);
    std::set<double> steps;
    for (const StepRecord& s : r.series) {
      // Nothing enters in a step that starts after the window closes.
      if (s.step > 0 && s.t - s.dt > 0.3123) {
        EXPECT_EQ(s.inserted, 0) << "t = " << s.t;
      }
      if (s.step > 0) steps.insert(s.dt);
    }
    if (adaptive) {
      EXPECT_GT(steps.size(), 2u) << "the steps must vary";
    }
  }
}

// n(t) = n(0) + inserted - removed for a few steps of every example, with the
// implicit and the explicit stepper (and, on the box, NLopt and RK4): each is
// one key away.
TEST(Cli, LedgerHoldsForEveryExampleAndStepper) {
  int examples = 0;
  for (const auto& entry : fs::directory_iterator(kExamples)) {
    if (entry.path().extension() != ".toml") continue;
    ++examples;
    // Both stepper families on every example; the other backend and RK4 on the
    // box (reservoir and images), which keeps the test cheap under ASan.
    std::vector<std::vector<std::string>> variants = {{}, {"solver.stepper=explicit"}};
    if (entry.path().filename() == "box_mixed.toml") {
      variants.push_back({"solver.backend=nlopt"});
      variants.push_back({"solver.stepper=explicit", "solver.explicit_scheme=rk4"});
    }
    for (const std::vector<std::string>& variant : variants) {
      // A half-width reservoir band (the default one holds ~7x the sphere's
      // particles at n_inf = 400 and its first steps cost ~100 evaluations);
      // the ledger does not depend on the width.
      std::vector<std::string> sets = {"run.max_steps=2", "run.vtk_interval=0", "treatment.reservoir_width=0.5"};
      sets.insert(sets.end(), variant.begin(), variant.end());
      SCOPED_TRACE(entry.path().filename().string() + (variant.empty() ? "" : " " + variant.back()));
      const RunResult r = run_config(parse_config_file(entry.path(), sets));
      ASSERT_EQ(r.exit_code, 0) << r.error;
      ASSERT_EQ(r.series.size(), 3u);
      // n(0) before step 0's insertions (the reservoir is filled at t = 0): the initial fill.
      const std::int64_t n0 = r.summary["derived"]["fill_count"].get<std::int64_t>();
      double l1 = 0.0;
      const double dt = r.summary["derived"]["dt"].get<double>();
      for (const StepRecord& s : r.series) {
        EXPECT_EQ(s.n_particles, n0 + s.inserted_total - s.removed_total) << "step " << s.step;
        EXPECT_EQ(s.n_particles, s.n_inside + s.n_buffer + s.n_outside);
        EXPECT_LE(s.mass_inside, s.mass_with_layer + 1e-12);
        EXPECT_LE(s.mass_with_layer, s.mass_total + 1e-12);
        l1 += s.mass_total * dt;
        EXPECT_NEAR(s.l1_mass, l1, 1e-12 * std::max(1.0, l1));
      }
    }
  }
  EXPECT_GE(examples, 6);
}

// The free-space example in every dimension.
TEST(Cli, FreeSpaceRunsInOneTwoAndThreeDimensions) {
  for (int dim : {1, 2, 3}) {
    const RunResult r = run_example("free_space_heat.toml",
                                    {"run.dim=" + std::to_string(dim), "run.max_steps=5", "particles.n_inf=100"});
    ASSERT_EQ(r.exit_code, 0) << "d = " << dim << ": " << r.error;
    // No boundary: every particle is inside, the mass is constant, the cloud spreads.
    EXPECT_EQ(r.last.n_inside, 100);
    EXPECT_NEAR(r.last.mass_total, r.series.front().mass_total, 1e-12);
    EXPECT_GT(r.last.polar_inertia, r.series.front().polar_inertia);
    // No boundary: M_rho is the total mass.
    EXPECT_NEAR(r.last.mass_blob, r.last.mass_total, 1e-12 * r.last.mass_total);
  }
}

// Advection and source steps (Algorithm 1, lines 2-3) in a periodic box: the
// source s doubles mass at rate s by random copies, so M(T) ~ M(0) exp(s T).
// With ~500 copies the relative standard deviation is ~sqrt(500)/1000 = 2%;
// 10% is a 4.5 sigma bound.
TEST(Cli, PeriodicBoxWithAdvectionAndSource) {
  const RunResult r = run_example("free_space_heat.toml",
                                  {"domain.type=periodic_box", "domain.lo=[-2, -2, -2]", "domain.hi=[2, 2, 2]",
                                   "particles.fill=uniform", "particles.n_inf=1000", "physics.velocity=[1, 0.5, 0]",
                                   "physics.source_rate=2", "run.t_end=0.2", "run.vtk_interval=0"});
  ASSERT_EQ(r.exit_code, 0) << r.error;
  const StepRecord& first = r.series.front();
  EXPECT_EQ(r.last.n_inside, r.last.n_particles);  // everything stays in the fundamental cell
  EXPECT_EQ(r.last.n_particles, first.n_particles + r.last.inserted_total - r.last.removed_total);
  EXPECT_NEAR(r.last.mass_total / first.mass_total, std::exp(2.0 * 0.2), 0.1 * std::exp(2.0 * 0.2));
  EXPECT_EQ(r.summary["ledger"]["source"]["inserted"].get<long>(), r.last.inserted_total);
  EXPECT_NEAR(r.last.mass_blob, r.last.mass_total, 1e-12 * r.last.mass_total);  // periodic: every blob counts
  EXPECT_EQ(r.summary["derived"]["mass_blob_method"], "total");
}

// Adaptive dt with advection and a source: tries rejected by the error test
// are undone (particles, random numbers, source ledger), the steps vary and
// end on t_end, and the particle and mass ledgers hold at every step (the run
// throws otherwise). A tight tolerance forces rejections.
TEST(Cli, AdaptiveDtUndoesRejectedTriesAndKeepsTheLedger) {
  const RunResult r = run_example(
      "free_space_heat.toml",
      {"domain.type=periodic_box", "domain.lo=[-2, -2, -2]", "domain.hi=[2, 2, 2]", "particles.fill=uniform",
       "particles.n_inf=1000", "physics.velocity=[1, 0.5, 0]", "physics.source_rate=2", "run.t_end=0.3",
       "run.vtk_interval=0", "run.dt_mode=adaptive", "solver.time_scheme=bdf2", "run.time_tolerance=3e-4",
       "run.dt_factor=0.1"});
  ASSERT_EQ(r.exit_code, 0) << r.error;
  ASSERT_GE(r.series.size(), 5u);
  double t = 0.0, dt_lo = 1e300, dt_hi = 0.0;
  long rejected = 0;
  for (std::size_t i = 1; i < r.series.size(); ++i) {
    const StepRecord& row = r.series[i];
    EXPECT_NEAR(row.t, t + row.dt, 1e-12);
    t = row.t;
    dt_lo = std::min(dt_lo, row.dt);
    dt_hi = std::max(dt_hi, row.dt);
    rejected += row.rejected_steps;
    // BDF2's estimate needs two steps of history.
    EXPECT_EQ(row.error_estimate.has_value(), i >= 3) << "step " << i;
    if (row.error_estimate) {
      EXPECT_LE(*row.error_estimate, 3e-4) << "accepted steps meet the tolerance";
    }
    EXPECT_EQ(row.n_particles, r.series.front().n_particles + row.inserted_total - row.removed_total);
  }
  EXPECT_DOUBLE_EQ(r.last.t, 0.3);
  EXPECT_GT(rejected, 0) << "the tolerance must force rejections";
  EXPECT_LT(dt_lo, dt_hi) << "the step size must adapt";
  EXPECT_EQ(r.summary["solver_totals"]["error_rejected_steps"].get<long>(), rejected);
  EXPECT_EQ(r.summary["ledger"]["source"]["inserted"].get<long>(), r.last.inserted_total);
  // The (46) sums use each step's own dt: the rectangle rule over the rows,
  // the value at t_0 weighted with the first step.
  double l1 = r.series[0].mass_total * r.series[1].dt;
  for (std::size_t i = 1; i < r.series.size(); ++i) l1 += r.series[i].mass_total * r.series[i].dt;
  EXPECT_NEAR(r.last.l1_mass, l1, 1e-12 * l1);
}

// A closed box with image blobs is the even extension of the periodic box:
// the cosine fill 1 + a cos(2 pi x) on a cell-centred lattice is symmetric
// about both walls, so the periodic run and the closed run with images are the
// same particles and must decay at the same rate (to the solver tolerance);
// with the barrier alone the walls change it.
TEST(Cli, ClosedBoxWithImagesDecaysLikeThePeriodicBox) {
  const std::vector<std::string> common = {"particles.n_inf=256", "run.t_end=0.01", "run.vtk_interval=0"};
  auto rate = [&](std::vector<std::string> extra) {
    extra.insert(extra.end(), common.begin(), common.end());
    const RunResult r = run_example("periodic_cosine.toml", extra);
    EXPECT_EQ(r.exit_code, 0) << r.error;
    return r.exit_code == 0 ? r.summary["reference"]["rate_ratio"].get<double>() : 0.0;
  };
  const double periodic = rate({});
  const double images = rate({"domain.type=box", "treatment.no_flux=images"});
  const double barrier = rate({"domain.type=box", "treatment.no_flux=barrier"});
  EXPECT_NEAR(images, periodic, 1e-3 * periodic);
  EXPECT_GT(std::abs(barrier - periodic), 1e-2 * periodic) << "barrier " << barrier << ", periodic " << periodic;
  std::cout << "[ info ] rate / (kappa k^2): periodic " << periodic << ", closed with images " << images
            << ", closed with the barrier " << barrier << "\n";
}

TEST(Cli, SameSeedGivesIdenticalSeriesDifferentSeedDoesNot) {
  const fs::path a = fresh_dir("seed_a"), b = fresh_dir("seed_b"), c = fresh_dir("seed_c");
  // The papers' layer over 15 steps, and the exact reservoir control (random
  // fills from t = 0, a half-width band to keep it cheap) over 1. The quiet
  // control draws no random numbers: from an empty start its run is the same
  // for every seed (Cli.QuietReservoirRunIsTheSameForEverySeed).
  for (const bool papers : {true, false}) {
    std::vector<std::string> sets = {"run.vtk_interval=0"};
    if (papers) {
      sets.insert(sets.end(), {"run.max_steps=15", "treatment.preset=papers"});
    } else {
      sets.insert(sets.end(),
                  {"run.max_steps=1", "treatment.reservoir_width=0.5", "treatment.reservoir_control=exact"});
    }
    std::vector<std::string> other = sets;
    other.push_back("run.seed=2");
    ASSERT_EQ(run_example("sphere_dirichlet.toml", sets, a).exit_code, 0);
    ASSERT_EQ(run_example("sphere_dirichlet.toml", sets, b).exit_code, 0);
    ASSERT_EQ(run_example("sphere_dirichlet.toml", other, c).exit_code, 0);
    const std::string sa = read_text(a / "series.csv"), sb = read_text(b / "series.csv"), sc = read_text(c / "series.csv");
    EXPECT_EQ(lines_of(sa).size(), papers ? 17u : 3u);  // header + steps 0..15 (0..1)
    EXPECT_EQ(sa, sb);
    EXPECT_NE(sa, sc);
    for (const fs::path& p : {a, b, c}) fs::remove_all(p);
  }
}

TEST(Cli, QuietReservoirRunIsTheSameForEverySeed) {
  const fs::path a = fresh_dir("quiet_seed_a"), b = fresh_dir("quiet_seed_b");
  const std::vector<std::string> sets = {"run.vtk_interval=0", "run.max_steps=2", "treatment.reservoir_width=0.5"};
  std::vector<std::string> other = sets;
  other.push_back("run.seed=2");
  ASSERT_EQ(run_example("sphere_dirichlet.toml", sets, a).exit_code, 0);
  ASSERT_EQ(run_example("sphere_dirichlet.toml", other, b).exit_code, 0);
  const std::string sa = read_text(a / "series.csv"), sb = read_text(b / "series.csv");
  EXPECT_EQ(lines_of(sa).size(), 4u);
  // Wall-clock columns are not in series.csv, so the files are equal byte for byte.
  EXPECT_EQ(sa, sb);
  for (const fs::path& p : {a, b}) fs::remove_all(p);
}

TEST(Cli, OutputFilesAreCompleteAndVtkParses) {
  const fs::path dir = fresh_dir("vtk");
  const RunResult r =
      run_example("sphere_dirichlet.toml", {"run.max_steps=10", "run.vtk_interval=4", "treatment.preset=papers"}, dir);
  ASSERT_EQ(r.exit_code, 0) << r.error;

  // series.csv: header with the required columns, one complete row per step.
  const std::vector<std::string> rows = lines_of(read_text(dir / "series.csv"));
  ASSERT_EQ(rows.size(), 12u);
  EXPECT_EQ(rows[0].rfind("step,t,dt,n_particles,mass_total,mass_inside,polar_inertia,inserted,removed,energy,"
                          "iterations,evaluations,",
                          0),
            0u);
  // M_rho and, with the example's crank_sphere reference, its error.
  EXPECT_NE(rows[0].find(",mass_ratio,polar_inertia_ratio,mass_blob,mass_blob_ratio,error_mass_blob,"),
            std::string::npos)
      << rows[0];
  const auto fields = [](const std::string& l) { return std::count(l.begin(), l.end(), ',') + 1; };
  for (const std::string& l : rows) {
    EXPECT_EQ(fields(l), fields(rows[0]));
    EXPECT_EQ(l.find("nan"), std::string::npos);
    EXPECT_EQ(l.find("inf"), std::string::npos);
  }
  std::map<long, long> n_at_step;
  for (std::size_t i = 1; i < rows.size(); ++i) {
    std::istringstream in(rows[i]);
    std::string step, t, dt, n;
    std::getline(in, step, ',');
    std::getline(in, t, ',');
    std::getline(in, dt, ',');
    std::getline(in, n, ',');
    n_at_step[std::stol(step)] = std::stol(n);
  }

  // summary.json.
  const nlohmann::json summary = nlohmann::json::parse(read_text(dir / "summary.json"));
  EXPECT_EQ(summary["status"], "completed");
  EXPECT_EQ(summary["seed"], 1);
  EXPECT_TRUE(summary.contains("config") && summary.contains("derived") && summary.contains("l1") &&
              summary.contains("ledger") && summary.contains("final"));
  EXPECT_EQ(summary["final"]["n_particles"].get<long>(), n_at_step[10]);

  // particles.pvd lists steps 0, 4, 8 and the final step 10.
  const std::string pvd = read_text(dir / "particles.pvd");
  EXPECT_EQ(check_tags(pvd), "");
  std::vector<std::string> files;
  for (std::size_t pos = pvd.find("<DataSet"); pos != std::string::npos; pos = pvd.find("<DataSet", pos + 1))
    files.push_back(attributes(pvd.substr(pos, pvd.find('>', pos) - pos)).at("file"));
  // Only the snapshots: domain.vtp, the boundary surface, is a file of its own
  // (listed here, ParaView drew it opaque over the particles; issue 23).
  ASSERT_EQ(files, (std::vector<std::string>{"particles_00000.vtp", "particles_00004.vtp", "particles_00008.vtp",
                                             "particles_00010.vtp"}));
  const std::string surface = read_text(dir / "domain.vtp");
  EXPECT_NE(surface.find("<Polys>"), std::string::npos);

  for (const std::string& f : files) {
    SCOPED_TRACE(f);
    const std::string doc = read_text(dir / f);
    const std::size_t app = doc.find("<AppendedData encoding=\"raw\">");
    ASSERT_NE(app, std::string::npos);
    const std::size_t start = doc.find('_', app) + 1;  // the raw data begin after the underscore
    const std::string head = doc.substr(0, app);
    const std::string tail = "\n  </AppendedData>\n</VTKFile>\n";
    ASSERT_GE(doc.size(), start + tail.size());
    EXPECT_EQ(doc.substr(doc.size() - tail.size()), tail);
    // The XML around the raw block is well formed.
    EXPECT_EQ(check_tags(head + "<AppendedData encoding=\"raw\">" + tail), "");

    const std::size_t piece = head.find("<Piece ");
    ASSERT_NE(piece, std::string::npos);
    const auto pa = attributes(head.substr(piece, head.find('>', piece) - piece));
    const long n = std::stol(pa.at("NumberOfPoints"));
    const long step = std::stol(f.substr(10, 5));
    EXPECT_EQ(n, n_at_step.at(step));
    EXPECT_EQ(std::stol(pa.at("NumberOfVerts")), n);

    // Each appended array: a UInt64 byte count equal to n x components x size, then the data.
    const std::string data = doc.substr(start, doc.size() - tail.size() - start);
    std::size_t expected_total = 0;
    int arrays = 0;
    for (std::size_t pos = head.find("<DataArray"); pos != std::string::npos; pos = head.find("<DataArray", pos + 1)) {
      const auto a = attributes(head.substr(pos, head.find('>', pos) - pos));
      if (a.count("format") == 0 || a.at("format") != "appended") continue;
      ++arrays;
      const std::size_t off = std::stoul(a.at("offset"));
      const int comps = a.count("NumberOfComponents") ? std::stoi(a.at("NumberOfComponents")) : 1;
      const std::string& type = a.at("type");
      const std::size_t size = type == "Int32" ? 4 : 8;
      ASSERT_LE(off + 8, data.size());
      std::uint64_t bytes = 0;
      std::memcpy(&bytes, data.data() + off, 8);
      EXPECT_EQ(bytes, static_cast<std::uint64_t>(n) * comps * size) << a.at("Name");
      expected_total += 8 + bytes;
    }
    // mass, beta, width_s, age, id, region, density, position, connectivity, offsets.
    EXPECT_EQ(arrays, 10);
    EXPECT_NE(head.find("Name=\"density\""), std::string::npos);
    EXPECT_NE(head.find("Name=\"width_s\""), std::string::npos);
    EXPECT_EQ(data.size(), expected_total);
  }
  fs::remove_all(dir);
}

// The real binary: exit codes, messages, nothing written for bad input,
// complete files when a step fails.
TEST(Cli, BinaryExitCodes) {
  const std::string example = (kExamples / "sphere_dirichlet.toml").string();
  const fs::path dir = fresh_dir("bin");
  std::string err;

  struct Bad {
    std::string args, key;
  };
  const fs::path missing_kind = fs::temp_directory_path() / ("otfp_missing_kind_" + std::to_string(::getpid()) + ".toml");
  {
    std::ofstream f(missing_kind);
    f << "[run]\nt_end = 0.1\n[[boundary]]\npatch = \"surface\"\nvalue = 1.0\n";
  }
  const std::vector<Bad> bad = {
      {example + " --set physics.kappa=-1", "physics.kappa"},
      {example + " --set solver.backend=petsc", "solver.backend"},
      {example + " --set run.dt=0", "run.dt"},
      {example + " --set domain.radius=0", "domain.radius"},
      {missing_kind.string(), "boundary[0].kind"},
  };
  for (const Bad& b : bad) {
    EXPECT_EQ(run_binary("run " + b.args + " --out " + dir.string(), err), 2) << b.args;
    EXPECT_EQ(err.rfind("otfp: error: " + b.key + " = ", 0), 0u) << err;
    EXPECT_EQ(std::count(err.begin(), err.end(), '\n'), 1) << "one line: " << err;
    EXPECT_FALSE(fs::exists(dir)) << b.args;
  }
  fs::remove(missing_kind);

  // A good run with --quiet prints nothing.
  EXPECT_EQ(run_binary("run " + example + " --out " + dir.string() +
                           " --quiet --set run.max_steps=3 --set treatment.reservoir_width=0.5",
                       err),
            0)
      << err;
  EXPECT_EQ(err, "");
  EXPECT_EQ(lines_of(read_text(dir / "series.csv")).size(), 5u);
  fs::remove_all(dir);

  // A step the solver cannot finish (one iteration, no halving): exit code 1,
  // a clear message, and the files complete up to the last good step.
  EXPECT_EQ(run_binary("run " + example + " --out " + dir.string() +
                           " --quiet --set solver.max_iterations=1 --set solver.max_halvings=0",
                       err),
            1);
  EXPECT_NE(err.find("not accepted"), std::string::npos) << err;
  const std::vector<std::string> rows = lines_of(read_text(dir / "series.csv"));
  ASSERT_GE(rows.size(), 2u);
  const std::string csv = read_text(dir / "series.csv");
  EXPECT_EQ(csv.back(), '\n');
  const nlohmann::json summary = nlohmann::json::parse(read_text(dir / "summary.json"));
  EXPECT_EQ(summary["status"], "failed");
  EXPECT_FALSE(summary["error"].get<std::string>().empty());
  EXPECT_EQ(summary["final"]["step"].get<long>() + 2, static_cast<long>(rows.size()));
  fs::remove_all(dir);
}

// Data that would create particles without end (they used to exhaust the
// memory, loop for ever, or cast 1e300 / m_p to an integer): refused before
// any work when the numbers show it (exit 2, naming the key), otherwise the
// step that would exceed run.max_particles fails the run (exit 1, status
// "failed", one line naming the patch or the source and the count) with
// complete files.
TEST(Cli, ResourceLimitsStopRunawayParticleCreation) {
  const fs::path dir = fresh_dir("limits");
  std::string err;
  auto ex = [](const char* name) { return (kExamples / name).string(); };
  struct Refused {
    const char* example;
    std::string set, message;
  };
  const std::vector<Refused> refused = {
      {"sphere_dirichlet.toml", "particles.n_inf=1000000000", "particles.n_inf = 1000000000: must be at most"},
      {"sphere_injection.toml", "boundary.0.value=-1e12", "boundary[0].value = -1000000000000: asks for about"},
      {"sphere_dirichlet.toml", "boundary.0.value=1e300", "boundary[0].value = 1e+300: asks for about"},
      {"sphere_dirichlet.toml", "physics.source_rate=1e308", "physics.source_rate = 1e+308: |s| dt = "},
      {"sphere_dirichlet.toml", "physics.velocity=[1e308,0,0]", "physics.velocity = [1e+308, 0, 0]: moves"},
      {"sphere_dirichlet.toml", "diagnostics.center=[0,1e300,0]", "diagnostics.center = [0, 1e+300, 0]: must lie"},
  };
  for (const Refused& r : refused) {
    EXPECT_EQ(run_binary("run " + ex(r.example) + " --quiet --out " + dir.string() + " --set " + r.set, err), 2)
        << r.set;
    EXPECT_EQ(err.rfind("otfp: error: " + r.message, 0), 0u) << err;
    EXPECT_EQ(std::count(err.begin(), err.end(), '\n'), 1) << err;
    EXPECT_FALSE(fs::exists(dir / "series.csv"));
  }

  struct Case {
    const char* example;
    std::string set, patch;
  };
  const std::vector<Case> cases = {
      {"sphere_dirichlet.toml", "run.max_particles=2000", "dirichlet patch 0 ('surface')"},  // the band needs more
      {"free_space_heat.toml", "run.max_particles=2000 --set physics.source_rate=100", "the source"},
  };
  for (const Case& c : cases) {
    fs::remove_all(dir);
    EXPECT_EQ(run_binary("run " + ex(c.example) + " --quiet --out " + dir.string() + " --set " + c.set +
                             " --set run.max_steps=20",
                         err),
              1)
        << c.set;
    EXPECT_NE(err.find(c.patch), std::string::npos) << err;
    EXPECT_NE(err.find("more than the limit of"), std::string::npos) << err;
    EXPECT_EQ(std::count(err.begin(), err.end(), '\n'), 1) << err;
    const std::string summary = read_text(dir / "summary.json");
    EXPECT_NE(summary.find("\"status\": \"failed\""), std::string::npos) << c.set;
    const std::string series = read_text(dir / "series.csv");
    ASSERT_FALSE(series.empty());
    EXPECT_EQ(series.back(), '\n');  // whole rows only
    EXPECT_EQ(series.find("nan"), std::string::npos);
  }
  fs::remove_all(dir);
}

// A cosine mode finer than two particle spacings cannot be sampled: its
// amplitude a(0) is noise about 0 and the error column (scaled by a(0)) was
// NaN, failing the run at step 0 after the directory existed. Refused before
// any work now, naming the largest mode the spacing allows.
TEST(Cli, CosineModeFinerThanTheSpacingIsRefused) {
  const fs::path file = kExamples / "periodic_cosine.toml";
  try {
    ConfiguredRun run(parse_config_file(file, {"particles.fill_mode=400"}));
    ADD_FAILURE() << "fill_mode = 400 was accepted";
  } catch (const ConfigError& e) {
    EXPECT_EQ(std::string(e.what()).rfind("particles.fill_mode = 400: must be at most ", 0), 0u) << e.what();
  }
  EXPECT_NO_THROW(ConfiguredRun(parse_config_file(file, {"particles.fill_mode=2"})));
  // The free-space reference without particles at t = 0 (its error scale 2 d kappa M t_end is 0).
  try {
    ConfiguredRun run(parse_config_file(kExamples / "free_space_heat.toml", {"particles.fill=empty"}));
    ADD_FAILURE() << "an empty free-space run was accepted";
  } catch (const ConfigError& e) {
    EXPECT_EQ(std::string(e.what()).rfind("particles.fill = \"empty\": diagnostics.reference", 0), 0u) << e.what();
  }
}

// Options in PETSC_OPTIONS reach TAO (docs/distributed.md): told PETSc's
// default for the LMVM initial Hessian (a diagonal Broyden matrix) the run
// is the default run, told a scalar one it is not.
TEST(Cli, PetscOptionsReachTao) {
  auto series = [](const std::string& petsc_options, const std::string& tag) {
    const fs::path out = fresh_dir(tag);
    const std::string cmd = "PETSC_OPTIONS='" + petsc_options + "' " + std::string(OTFP_CLI_PATH) + " run " +
                            (kExamples / "sphere_dirichlet.toml").string() +
                            " --set solver.backend=tao --set run.t_end=0.05 --out " + out.string() + " >" +
                            out.string() + ".log 2>&1";
    const int status = std::system(cmd.c_str());
    const std::string log = read_text(out.string() + ".log");
    fs::remove(out.string() + ".log");
    if (!(WIFEXITED(status) && WEXITSTATUS(status) == 0)) return "exit " + std::to_string(status) + ": " + log;
    return read_text(out / "series.csv");
  };
  const std::string by_default = series("", "tao_scale_default");
  if (by_default.find("not available") != std::string::npos) GTEST_SKIP() << "built without TAO";
  ASSERT_EQ(by_default.rfind("step,", 0), 0u) << by_default;
  EXPECT_EQ(by_default, series("-tao_lmvm_mat_lmvm_scale_type diagonal", "tao_scale_diagonal"));
  const std::string scalar = series("-tao_lmvm_mat_lmvm_scale_type scalar", "tao_scale_scalar");
  ASSERT_EQ(scalar.rfind("step,", 0), 0u) << scalar;
  EXPECT_NE(by_default, scalar);
}
