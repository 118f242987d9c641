#pragma once
// The pieces of ConfiguredRun::run() (src/cli/run.cpp): the rows
// (run_rows.cpp), summary.json (run_summary.cpp), the run's files
// (run_files.cpp) and the checks of a resume (run_resume.cpp).
#include <chrono>
#include <cstdint>
#include <deque>
#include <filesystem>
#include <functional>
#include <map>
#include <memory>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>

#include "otfp/mass_measure.hpp"
#include "otfp/reference.hpp"
#include "otfp/run_record.hpp"
#include "otfp/simulation.hpp"
#include "otfp_app/simulation.hpp"
#include "otfp_app/writers.hpp"

namespace otfp::app::detail {

using Clock = std::chrono::steady_clock;

// A failure while stepping: exit code 1, files kept.
class RunError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// A resume that cannot continue the run: refused before any file is
// touched (exit code 2; RunResult::exit_code kExitRefused).
class ResumeRefused : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// Seconds since the run started.
class WallClock {
 public:
  double operator()() const { return std::chrono::duration<double>(Clock::now() - start_).count(); }

 private:
  Clock::time_point start_ = Clock::now();
};

// The analytic reference of diagnostics.reference (otfp/reference.hpp), or null.
std::unique_ptr<Reference> configured_reference(const Config& c, const Derived& d);

// The progress line on stderr (at most five a second, and the final one).
class ProgressLine {
 public:
  ProgressLine(const Config& c, const Derived& d, const otfp::Simulation& sim, const WallClock& wall, bool on);
  void show(const StepRecord& r, bool final_line);
  bool on() const { return on_; }

 private:
  const Config& c_;
  const Derived& d_;
  const otfp::Simulation& sim_;
  const WallClock& wall_;
  bool on_;
  Clock::time_point last_ = Clock::now() - std::chrono::seconds(1);
  // (wall, progress) at the recent progress lines: the ETA uses the rate over
  // the last ~20 of them (a few seconds), not the average since the start,
  // which the first steps (filling, the first solves) skew.
  std::deque<std::pair<double, double>> recent_;
};

// summary.json (docs/outputs.md) of the run as it stands.
nlohmann::json run_summary(const ConfiguredRun& run, const otfp::Simulation& sim, const Reference* reference,
                           const RunSums& sums, double wall_seconds, const std::string& status,
                           const std::string& error, const StepRecord& last);

// The files of a run in its directory (none when it is empty): series.csv
// and timing.csv row by row, the snapshots and particles.pvd, config.toml,
// domain.vtp, view.py and summary.json (the kill-time one too).
class RunFiles {
 public:
  using Summary = std::function<nlohmann::json(const std::string& status, const std::string& error,
                                               const StepRecord& last)>;
  RunFiles(const ConfiguredRun& run, const otfp::Simulation& sim, std::filesystem::path out, bool kill_summary,
           Summary summary);
  bool active() const { return !out_.empty(); }
  const std::filesystem::path& dir() const { return out_; }
  // A new run: every file but the rows and snapshots, summary "running".
  void create(const std::string& series_header, const std::string& timing_header);
  // A resumed run: the rows up to the checkpoint, summary "running".
  void reopen(const std::string& series_text, const std::string& timing_text, const StepRecord& last);
  // A row in both files or in neither, and its snapshot if due.
  void append(const std::string& series_line, const std::string& timing_line, const StepRecord& r, bool snapshot,
              const std::vector<std::int32_t>& region);
  // The summary.json a second signal leaves behind (kill_time_cleanup), from
  // the last row written (`have_row`) or before the first one.
  void arm_kill_summary(const StepRecord& r, bool have_row);
  // The same after a row: rendered at most twice a second, and for the first row.
  void rearm_kill_summary(const StepRecord& r);
  // checkpoint.bin: the library's state and the driver's (driver_state()).
  void write_checkpoint(const nlohmann::json& driver);
  void write_summary(const nlohmann::json& summary);
  void write_final_particles(const std::vector<std::int32_t>& region);
  // The state the failing step started from, for inspection (best effort).
  void write_failed_particles(const Derived& d, double t) noexcept;

  std::vector<std::pair<double, std::string>> snapshots;  // (t, file) of particles.pvd
  std::int64_t last_snapshot = -1;

 private:
  void snapshot(const StepRecord& r, const std::vector<std::int32_t>& region);
  void distributed_snapshot(const StepRecord& r, const std::vector<std::int32_t>& region);
  void write_domain_surface();
  const ConfiguredRun& run_;
  const otfp::Simulation& sim_;
  std::filesystem::path out_;
  bool root_;  // writes the files (a distributed run's rank 0); every rank writes its snapshot pieces
  bool kill_summary_;
  Summary summary_;
  AppendFile series_, timing_;
  Clock::time_point kill_summary_time_{};
};

// The driver state a checkpoint keeps next to the library's.
nlohmann::json driver_state(const RunRecorder& rows, const Reference* reference, const RunFiles& files,
                            const StepRecord& last, const std::map<std::string, std::string>& fingerprint);

// What a resume continues from, read and checked before any file is touched.
struct ResumeStart {
  bool nothing_to_do = false;  // the checkpoint is already at run.t_end
  StepRecord last;             // step, t, mass ratio and count of the checkpoint's row
  std::string series_text, timing_text;  // the files up to the checkpoint's step
};
// Loads checkpoint.bin of `files.dir()` into sim, rows, reference and files
// after checking it against the configuration (`fingerprint`); throws
// ResumeRefused.
ResumeStart read_resume(otfp::Simulation& sim, RunRecorder& rows, Reference* reference, RunFiles& files,
                        const RunControl& control, const Config& c, const std::string& series_header,
                        const std::string& timing_header, const std::map<std::string, std::string>& fingerprint);

}  // namespace otfp::app::detail
