#pragma once
// `otfp sweep`: runs the grid of --vary values of one configuration, each as
// a separate `otfp run` process (a crash or a failed step stays one row), and
// aggregates the runs' summary.json files into runs.csv (docs/outputs.md).
#include <cstddef>
#include <csignal>
#include <filesystem>
#include <iosfwd>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

namespace otfp::app {

// One varied key and its values, e.g. "run.dt_factor=0.25,1,4", or keys
// varied together, e.g. "solver.stepper:solver.backend=implicit:ceres,implicit:nlopt".
struct SweepAxis {
  std::vector<std::string> keys;
  std::vector<std::vector<std::string>> values;  // per point, one TOML inline value (or bare word) per key
};

// Parses "key=v1,v2,..." or "k1:k2=a1:b1,a2:b2": commas and colons inside
// [...] or quotes do not split (physics.velocity=[1,0,0],[0,1,0]).
// Throws ConfigError("--vary", ...).
SweepAxis parse_vary(const std::string& text);

// At most this many runs in a sweep (run_0000 ... run_9999).
constexpr std::size_t kMaxSweepRuns = 10000;
// Every combination, the first axis varying slowest; each entry holds one
// value per key (all keys of all axes, in order). Throws ConfigError
// ("--vary") for more than kMaxSweepRuns points.
std::vector<std::vector<std::string>> expand_grid(const std::vector<SweepAxis>& axes);

struct SweepOptions {
  std::filesystem::path config;       // base configuration
  std::vector<std::string> sets;      // --set overrides applied to every run, before the varied keys
  std::vector<SweepAxis> axes;        // the grid
  std::filesystem::path out_dir;      // DIR: DIR/run_NNN per run, DIR/runs.csv, DIR/sweep.json
  int jobs = 1;                       // runs at a time
  double timeout_seconds = 0.0;       // per run; 0: none
  std::filesystem::path executable;   // the otfp binary that runs each point
  bool progress = true;               // one line per finished run on the error stream
  // Set by a SIGINT/SIGTERM handler (the signal number): the sweep starts no
  // more runs, forwards the signal to the running ones (each of them, again,
  // on every further signal), reaps them and writes runs.csv with the rows it has.
  const volatile std::sig_atomic_t* stop_signal = nullptr;
  const volatile std::sig_atomic_t* stop_count = nullptr;  // signals received so far
};

struct SweepRow {
  int index = 0;
  std::string dir;                   // run directory name under out_dir
  std::vector<std::string> values;   // one per key
  std::string status;                // completed | failed | invalid | timeout | crashed | interrupted
  int exit_code = 0;
  std::string error;
  double wall_seconds = 0.0;
  nlohmann::json summary;            // the run's summary.json (null if none)
};

struct SweepResult {
  std::vector<SweepRow> rows;
  int failed = 0;                    // rows whose status is not "completed"
  bool interrupted = false;          // stopped by a signal (stop_signal): runs.csv holds the runs started
};

// Checks the options (throws ConfigError naming the offending option or key),
// then runs the grid and writes out_dir/runs.csv (rewritten after every
// finished run, rows in grid order) and out_dir/sweep.json.
SweepResult run_sweep(const SweepOptions& options, std::ostream& err);

// The runs.csv header and one row (exposed for tests).
std::string runs_csv_header(const std::vector<SweepAxis>& axes);
std::string runs_csv_row(const SweepRow& row);

}  // namespace otfp::app
