// `otfp sweep`: --vary parsing, grid expansion, one process per run with
// failed runs as rows, and runs.csv aggregated from the runs' summary.json.
#include <gtest/gtest.h>

#include <filesystem>
#include <sstream>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "app_test_support.hpp"
#include "otfp_app/config.hpp"
#include "otfp_app/sweep.hpp"

using namespace otfp::app;
using otfp::test::fresh_dir;
using otfp::test::read_csv;
using otfp::test::read_text;
namespace fs = std::filesystem;

namespace {

const fs::path kExamples = fs::path(OTFP_SOURCE_DIR) / "examples";

SweepOptions options(const std::string& tag, std::vector<std::string> vary) {
  SweepOptions o;
  o.config = kExamples / "periodic_cosine.toml";
  o.sets = {"run.t_end=0.002", "particles.n_inf=256", "particles.beta_factor=1"};
  for (const std::string& v : vary) o.axes.push_back(parse_vary(v));
  o.out_dir = fresh_dir(tag);
  o.executable = OTFP_CLI_PATH;
  o.jobs = 2;
  o.progress = false;
  return o;
}

}  // namespace

TEST(Sweep, ParseVarySplitsAtTopLevelCommas) {
  const SweepAxis a = parse_vary("physics.velocity=[1, 0, 0],[0,1,0], [0,0,1]");
  ASSERT_EQ(a.keys, std::vector<std::string>{"physics.velocity"});
  ASSERT_EQ(a.values.size(), 3u);
  EXPECT_EQ(a.values[0][0], "[1, 0, 0]");
  EXPECT_EQ(a.values[2][0], "[0,0,1]");
  const SweepAxis s = parse_vary("solver.stepper=\"implicit\",explicit");
  EXPECT_EQ(s.values[0][0], "\"implicit\"");
  EXPECT_EQ(s.values[1][0], "explicit");
}

TEST(Sweep, ParseVaryLinksKeysWithColons) {
  const SweepAxis a = parse_vary("solver.stepper:solver.backend=implicit:ceres,implicit:nlopt,explicit:ceres");
  ASSERT_EQ(a.keys.size(), 2u);
  ASSERT_EQ(a.values.size(), 3u);
  EXPECT_EQ(a.values[1], (std::vector<std::string>{"implicit", "nlopt"}));
}

TEST(Sweep, ParseVaryRejectsMalformedArguments) {
  for (const char* bad : {"run.dt_factor", "=1,2", "run.dt_factor=1,,2", "run.dt_factor=", "a:b=1:2,3",
                          "physics.velocity=[1,0,0"}) {
    try {
      parse_vary(bad);
      ADD_FAILURE() << "accepted " << bad;
    } catch (const ConfigError& e) {
      EXPECT_EQ(e.key(), "--vary") << bad;
      EXPECT_NE(std::string(e.what()).find("--vary"), std::string::npos) << e.what();
    }
  }
}

TEST(Sweep, ExpandGridIsTheProductWithTheFirstAxisSlowest) {
  const auto grid = expand_grid({parse_vary("a=1,2"), parse_vary("b:c=x:y,u:v,p:q")});
  ASSERT_EQ(grid.size(), 6u);
  EXPECT_EQ(grid[0], (std::vector<std::string>{"1", "x", "y"}));
  EXPECT_EQ(grid[1], (std::vector<std::string>{"1", "u", "v"}));
  EXPECT_EQ(grid[3], (std::vector<std::string>{"2", "x", "y"}));
  EXPECT_EQ(grid[5], (std::vector<std::string>{"2", "p", "q"}));
}

// A grid with an invalid value: the bad runs are rows with their error, the
// good ones carry the figures of their own summary.json.
TEST(Sweep, RunsEveryPointAndRecordsFailuresAsRows) {
  SweepOptions o = options("sweep_rows", {"particles.fill_amplitude=0.3,1.5", "solver.stepper=implicit,explicit"});
  std::ostringstream err;
  const SweepResult r = run_sweep(o, err);
  ASSERT_EQ(r.rows.size(), 4u);
  EXPECT_EQ(r.failed, 2);
  const auto rows = read_csv(o.out_dir / "runs.csv");
  ASSERT_EQ(rows.size(), 4u);
  for (std::size_t i = 0; i < rows.size(); ++i) {
    const auto& row = rows[i];
    EXPECT_EQ(row.at("index"), std::to_string(i));
    EXPECT_EQ(row.at("solver.stepper"), i % 2 ? "explicit" : "implicit");
    if (row.at("particles.fill_amplitude") == "1.5") {
      EXPECT_EQ(row.at("status"), "invalid");
      EXPECT_EQ(row.at("exit_code"), "2");
      EXPECT_EQ(row.at("error"), "particles.fill_amplitude = 1.5: must be in [0, 1) (density 1 + a cos(k x) > 0)");
      EXPECT_EQ(row.at("evaluations"), "");
    } else {
      EXPECT_EQ(row.at("status"), "completed");
      const auto summary = nlohmann::json::parse(read_text(o.out_dir / row.at("dir") / "summary.json"));
      EXPECT_EQ(row.at("evaluations"), std::to_string(summary["solver_totals"]["evaluations"].get<long>()));
      EXPECT_EQ(std::stod(row.at("rate_ratio")), summary["reference"]["rate_ratio"].get<double>());
      EXPECT_EQ(std::stod(row.at("ref_max_abs_error")),
                summary["reference"]["quantities"][0]["max_abs_error"].get<double>());
      EXPECT_EQ(row.at("steps"), std::to_string(summary["final"]["step"].get<long>()));
      EXPECT_EQ(summary["config"]["particles"]["fill_amplitude"].get<double>(), 0.3);
    }
  }
  const auto sweep = nlohmann::json::parse(read_text(o.out_dir / "sweep.json"));
  EXPECT_EQ(sweep["runs"].get<int>(), 4);
  fs::remove_all(o.out_dir);
}

// A run over its time limit is killed and recorded, the sweep goes on.
TEST(Sweep, TimeoutKillsTheRunAndRecordsIt) {
  SweepOptions o = options("sweep_timeout", {"run.t_end=0.001,100"});
  o.timeout_seconds = 1.0;
  std::ostringstream err;
  const SweepResult r = run_sweep(o, err);
  ASSERT_EQ(r.rows.size(), 2u);
  EXPECT_EQ(r.rows[0].status, "completed");
  EXPECT_EQ(r.rows[1].status, "timeout");
  EXPECT_EQ(r.failed, 1);
  const auto rows = read_csv(o.out_dir / "runs.csv");
  ASSERT_EQ(rows.size(), 2u);
  EXPECT_EQ(rows[1].at("status"), "timeout");
  fs::remove_all(o.out_dir);
}

// Mistakes in the sweep itself stop it before anything runs.
TEST(Sweep, RejectsUnknownKeysAndBadOptionsBeforeRunning) {
  std::ostringstream err;
  SweepOptions o = options("sweep_bad", {"particles.betafactor=1,2"});
  EXPECT_THROW(run_sweep(o, err), ConfigError);
  EXPECT_FALSE(fs::exists(o.out_dir));
  o = options("sweep_bad", {"run.seed=1,2", "run.seed=3"});
  EXPECT_THROW(run_sweep(o, err), ConfigError);
  o = options("sweep_bad", {"run.seed=1,2"});
  o.jobs = 0;
  EXPECT_THROW(run_sweep(o, err), ConfigError);
  o = options("sweep_bad", {"run.seed=1,2"});
  o.executable = "/nonexistent/otfp";
  EXPECT_THROW(run_sweep(o, err), ConfigError);
  EXPECT_FALSE(fs::exists(o.out_dir));
}

// A grid of more runs than run_NNNN names (10^4) is refused with one line
// before it is built (three axes of 300 values asked for 2.7e7 rows and
// ended in bad_alloc).
TEST(Sweep, GridSizeIsCapped) {
  std::string values;
  for (int i = 0; i < 300; ++i) {
    if (i > 0) values += ',';
    values += std::to_string(i + 1);
  }
  const std::vector<SweepAxis> axes = {parse_vary("run.seed=" + values), parse_vary("particles.n_inf=" + values),
                                       parse_vary("run.max_steps=" + values)};
  try {
    expand_grid(axes);
    ADD_FAILURE() << "a grid of 2.7e7 runs was built";
  } catch (const ConfigError& e) {
    EXPECT_EQ(e.key(), "--vary");
    EXPECT_STREQ(e.what(), "--vary = 300 x 300 x 300 = 27000000 runs: must give at most 10000 runs");
  }
  EXPECT_EQ(expand_grid({parse_vary("run.seed=" + values)}).size(), 300u);
  std::ostringstream err;
  SweepOptions o = options("sweep_huge", {"run.seed=" + values, "particles.n_inf=" + values, "run.max_steps=" + values});
  EXPECT_THROW(run_sweep(o, err), ConfigError);
  EXPECT_FALSE(fs::exists(o.out_dir));
}
