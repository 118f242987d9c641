#include "otfp_app/cli.hpp"

#include <fcntl.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <csignal>
#include <cstring>

#include <CLI/CLI.hpp>
#include <fmt/format.h>

#include <algorithm>
#include <filesystem>
#include <iostream>
#include <memory>
#include <string>
#include <vector>

#include "otfp_app/config.hpp"
#include "otfp_app/simulation.hpp"
#include "otfp_app/sweep.hpp"
#include "otfp_app/writers.hpp"

namespace otfp::app {

namespace {

constexpr int kRunFailed = 1;
constexpr int kUsage = 2;

// SIGINT/SIGTERM during `otfp run`: finish the current step, write the
// checkpoint and complete files, exit with kExitInterrupted. A second signal
// stops at once, also with kExitInterrupted, after the async-signal-safe
// clean-up: no temporary files, summary.json "interrupted" (writers.hpp).
volatile std::sig_atomic_t g_stop = 0;
char g_kill_message[1024] = {};
extern "C" void on_stop_signal(int) {
  if (g_stop) {
    kill_time_cleanup();
    const std::size_t n = std::strlen(g_kill_message);
    if (n > 0 && ::write(STDERR_FILENO, g_kill_message, n) < 0) {
      // Nothing left to report it to.
    }
    ::_exit(kExitInterrupted);
  }
  g_stop = 1;
}

struct StopSignals {
  struct sigaction old_int {}, old_term {};
  StopSignals() {
    g_stop = 0;
    struct sigaction sa {};
    sa.sa_handler = on_stop_signal;
    sigemptyset(&sa.sa_mask);
    sa.sa_flags = 0;
    sigaction(SIGINT, &sa, &old_int);
    sigaction(SIGTERM, &sa, &old_term);
  }
  ~StopSignals() {
    sigaction(SIGINT, &old_int, nullptr);
    sigaction(SIGTERM, &old_term, nullptr);
  }
  StopSignals(const StopSignals&) = delete;
  StopSignals& operator=(const StopSignals&) = delete;
};

// SIGINT/SIGTERM during `otfp sweep`: every signal is counted and passed on
// to the running runs (the first lets them finish their step, a second stops
// them at once); the sweep starts no more runs and writes runs.csv.
volatile std::sig_atomic_t g_sweep_signal = 0, g_sweep_signals = 0;
extern "C" void on_sweep_signal(int sig) {
  g_sweep_signal = sig;
  g_sweep_signals = g_sweep_signals + 1;
}

struct SweepSignals {
  struct sigaction old_int {}, old_term {};
  SweepSignals() {
    g_sweep_signal = 0;
    g_sweep_signals = 0;
    struct sigaction sa {};
    sa.sa_handler = on_sweep_signal;
    sigemptyset(&sa.sa_mask);
    sa.sa_flags = SA_RESTART;
    sigaction(SIGINT, &sa, &old_int);
    sigaction(SIGTERM, &sa, &old_term);
  }
  ~SweepSignals() {
    sigaction(SIGINT, &old_int, nullptr);
    sigaction(SIGTERM, &old_term, nullptr);
  }
  SweepSignals(const SweepSignals&) = delete;
  SweepSignals& operator=(const SweepSignals&) = delete;
};

// The keys a resumed run may change: where it ends and how it writes.
const char* const kResumeKeys[] = {"run.t_end", "run.max_steps", "run.vtk_interval", "run.checkpoint_interval",
                                   "run.threads", "run.max_particles"};

// Control characters of user text as escapes (one-line messages).
std::string escaped(const std::string& s) {
  std::string out;
  for (const char ch : s) {
    const auto u = static_cast<unsigned char>(ch);
    if (u < 0x20 || u == 0x7f)
      out += fmt::format("\\x{:02x}", u);
    else
      out += ch;
  }
  return out;
}

int error(std::ostream& err, const std::string& message, int code) {
  err << "otfp: error: " << message << "\n";
  return code;
}

// Parses and checks everything; nullptr after printing the error.
std::unique_ptr<ConfiguredRun> load(const std::string& config, const std::vector<std::string>& sets, std::ostream& err,
                                 int& code) {
  try {
    return std::make_unique<ConfiguredRun>(parse_config_file(config, sets));
  } catch (const ConfigError& e) {
    code = error(err, e.what(), kUsage);
  } catch (const std::exception& e) {
    code = error(err, e.what(), kUsage);
  }
  return nullptr;
}

namespace fs = std::filesystem;

// The lock of an output directory: DIR/.otfp.lock, flock(2)ed for the whole
// run, removed at the end. A run killed outright leaves the file but not the
// lock (the kernel drops it with the process), so a stale file stops nobody.
class OutputLock {
 public:
  OutputLock() = default;
  OutputLock(const OutputLock&) = delete;
  OutputLock& operator=(const OutputLock&) = delete;
  ~OutputLock() {
    if (fd_ < 0) return;
    ::unlink(path_.c_str());
    ::close(fd_);
  }
  // "" when taken, else why not.
  std::string acquire(const fs::path& dir) {
    path_ = dir / ".otfp.lock";
    for (int attempt = 0; attempt < 5; ++attempt) {
      const int fd = ::open(path_.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
      if (fd < 0) return std::string("cannot write there: ") + std::strerror(errno);
      if (::flock(fd, LOCK_EX | LOCK_NB) != 0) {
        const int e = errno;
        ::close(fd);
        if (e == EWOULDBLOCK) return "in use by another otfp run (" + path_.string() + " is locked)";
        return std::string("cannot lock ") + path_.string() + ": " + std::strerror(e);
      }
      // The holder before us may have removed the file between our open and
      // our flock: then the lock is on a file nobody else sees; take it again.
      struct stat held {}, named {};
      if (::fstat(fd, &held) == 0 && ::stat(path_.c_str(), &named) == 0 && held.st_ino == named.st_ino &&
          held.st_dev == named.st_dev) {
        fd_ = fd;
        const std::string pid = std::to_string(::getpid()) + "\n";
        if (::ftruncate(fd_, 0) == 0 && ::write(fd_, pid.data(), pid.size()) < 0) {
          // The pid is only informative.
        }
        return "";
      }
      ::close(fd);
    }
    return "cannot lock " + path_.string() + ": it keeps being replaced";
  }

 private:
  int fd_ = -1;
  fs::path path_;
};

// The files an otfp run writes into its directory (simulation.cpp,
// writers.cpp), and the temporary files ("<name>.tmp<pid>") of one killed
// while writing them.
bool is_run_output(const std::string& name) {
  static const char* const fixed[] = {"series.csv",      "timing.csv",          "summary.json",
                                      "config.toml",     "checkpoint.bin",      "particles_final.csv",
                                      "domain.vtp",      "particles.pvd",       "particles_failed.vtp",
                                      "view.py"};
  const auto digits = [](const std::string& t, std::size_t min) {
    return t.size() >= min && std::all_of(t.begin(), t.end(), [](char c) { return c >= '0' && c <= '9'; });
  };
  const auto known = [&](const std::string& n) {
    for (const char* f : fixed)
      if (n == f) return true;
    // particles_NNNNN.vtp: a snapshot (five digits or more).
    const std::string pre = "particles_", post = ".vtp";
    return n.size() > pre.size() + post.size() && n.compare(0, pre.size(), pre) == 0 &&
           n.compare(n.size() - post.size(), post.size(), post) == 0 &&
           digits(n.substr(pre.size(), n.size() - pre.size() - post.size()), 5);
  };
  if (known(name)) return true;
  const std::size_t tmp = name.rfind(".tmp");
  return tmp != std::string::npos && tmp > 0 && digits(name.substr(tmp + 4), 1) && known(name.substr(0, tmp));
}

// The run's output directory, made ready before any work: created (the
// configuration has been accepted) and locked, which also shows that it can
// be written, so that an unusable --out is bad input (exit 2), not a run that
// fails after its initial fill. Then an earlier run there (summary.json,
// series.csv or checkpoint.bin) is refused unless the run resumes it or
// --overwrite clears its files first. Returns why the directory cannot be
// used, or "".
std::string prepare_out_dir(const fs::path& dir, bool resume, bool overwrite, OutputLock& lock) {
  std::error_code ec;
  const bool existed = fs::exists(dir, ec);
  if (ec && ec != std::errc::no_such_file_or_directory) return "cannot use it: " + ec.message();
  if (existed && !fs::is_directory(dir, ec)) return "exists and is not a directory";
  if (!existed) {
    fs::create_directories(dir, ec);
    if (ec) return "cannot create the directory: " + ec.message();
  }
  if (std::string why = lock.acquire(dir); !why.empty()) {
    if (!existed) fs::remove(dir, ec);  // the directory just made, still empty
    return why;
  }
  if (resume) return "";
  std::string earlier;
  for (const char* f : {"summary.json", "series.csv", "checkpoint.bin"})
    if (earlier.empty() && fs::exists(dir / f, ec)) earlier = f;
  if (earlier.empty()) return "";
  if (!overwrite)
    return "holds an earlier otfp run (" + earlier +
           "); pass --overwrite to replace its files, or continue it with otfp run --resume " + dir.string();
  std::vector<fs::path> old_files;
  for (const fs::directory_entry& e : fs::directory_iterator(dir, ec))
    if (is_run_output(e.path().filename().string()) && !e.is_directory()) old_files.push_back(e.path());
  if (ec) return "--overwrite cannot list the directory: " + ec.message();
  for (const fs::path& f : old_files)
    if (!fs::remove(f, ec) && ec) return "--overwrite cannot remove " + f.string() + ": " + ec.message();
  return "";
}

}  // namespace

int cli_main(int argc, const char* const* argv, std::ostream& out, std::ostream& err) {
  CLI::App app{"otfp: optimal-transport finite-particle method for driven mass diffusion"};
  app.set_version_flag("--version", "otfp " + version());
  app.require_subcommand(1);

  std::string config, out_dir, resume_dir;
  std::vector<std::string> sets;
  bool quiet = false, overwrite = false;

  CLI::App* run = app.add_subcommand("run", "run a simulation and write its outputs");
  run->add_option("config", config, "configuration file (TOML)");
  run->add_option("--out,-o", out_dir, "output directory (created if missing)");
  run->add_option("--resume", resume_dir,
                  "continue the run in DIR from its checkpoint (e.g. --set run.t_end=LATER to extend a finished run)");
  run->add_option("--set,-s", sets, "override a key by dotted path, e.g. particles.n_inf=3200 (repeatable)")
      ->allow_extra_args(false)
      ->take_all();
  run->add_flag("--overwrite", overwrite,
                "replace the files of an earlier run in --out (other files are left alone)");
  run->add_flag("--quiet,-q", quiet, "print nothing but errors");

  CLI::App* check = app.add_subcommand("check", "validate a configuration and print the resolved values as JSON");
  check->add_option("config", config, "configuration file (TOML)")->required();
  check->add_option("--set,-s", sets, "override a key by dotted path (repeatable)")
      ->allow_extra_args(false)
      ->take_all();

  CLI::App* sweep = app.add_subcommand("sweep", "run a grid of configurations and aggregate them into runs.csv");
  std::vector<std::string> varies;
  int jobs = 1;
  double timeout = 0.0;
  sweep->add_option("config", config, "base configuration file (TOML)")->required();
  sweep->add_option("--vary,-v", varies, "key=v1,v2,... : values of one key (repeatable; the grid is their product)")
      ->required()
      ->allow_extra_args(false)
      ->take_all();
  sweep->add_option("--out,-o", out_dir, "sweep directory: run_NNN/ per run, runs.csv, sweep.json")->required();
  sweep->add_option("--jobs,-j", jobs, "runs at a time (default 1)");
  sweep->add_option("--timeout", timeout, "seconds per run before it is killed (default 0: none)");
  sweep->add_option("--set,-s", sets, "override a key in every run (repeatable)")->allow_extra_args(false)->take_all();
  sweep->add_flag("--quiet,-q", quiet, "print nothing but errors");

  try {
    app.parse(argc, argv);
  } catch (const CLI::CallForHelp& e) {
    return app.exit(e, out, err);
  } catch (const CLI::CallForAllHelp& e) {
    return app.exit(e, out, err);
  } catch (const CLI::CallForVersion& e) {
    return app.exit(e, out, err);
  } catch (const CLI::ParseError& e) {
    return error(err, std::string(e.what()) + " (try --help)", kUsage);
  }

  if (sweep->parsed()) {
    if (out_dir.empty()) return error(err, "--out = \"\": must be a non-empty path", kUsage);
    try {
      SweepOptions so;
      so.config = config;
      so.sets = sets;
      for (const std::string& v : varies) so.axes.push_back(parse_vary(v));
      so.out_dir = out_dir;
      so.jobs = jobs;
      so.timeout_seconds = timeout;
      so.executable = std::filesystem::read_symlink("/proc/self/exe");
      so.progress = !quiet;
      so.stop_signal = &g_sweep_signal;
      so.stop_count = &g_sweep_signals;
      SweepResult r;
      {
        const SweepSignals signals;
        r = run_sweep(so, err);
      }
      if (r.interrupted) {
        int finished = 0;
        for (const SweepRow& row : r.rows) finished += row.status == "completed" ? 1 : 0;
        return error(err,
                     fmt::format("sweep interrupted by a signal: {} of its runs completed -> {}/runs.csv", finished,
                                 out_dir),
                     kExitInterrupted);
      }
      if (!quiet)
        err << fmt::format("otfp: sweep of {} runs, {} not completed -> {}/runs.csv\n", r.rows.size(), r.failed,
                           out_dir);
      return r.failed == 0 ? 0 : kRunFailed;
    } catch (const ConfigError& e) {
      return error(err, e.what(), kUsage);
    } catch (const std::exception& e) {
      return error(err, e.what(), kUsage);
    }
  }

  if (run->parsed() && run->count("--resume") > 0 && resume_dir.empty())
    return error(err, "--resume = \"\": must be a non-empty path", kUsage);
  const bool resume = run->parsed() && !resume_dir.empty();
  if (run->parsed()) {
    if (resume) {
      if (overwrite)
        return error(err, "--overwrite cannot be combined with --resume (it would delete the run to continue)",
                     kUsage);
      if (!config.empty() || !out_dir.empty())
        return error(err, "--resume DIR takes neither CONFIG nor --out: the run's directory holds both (try --help)",
                     kUsage);
      std::error_code ec;
      if (!std::filesystem::is_regular_file(std::filesystem::path(resume_dir) / "checkpoint.bin", ec) ||
          !std::filesystem::is_regular_file(std::filesystem::path(resume_dir) / "config.toml", ec))
        return error(err, "--resume = \"" + resume_dir + "\": no checkpoint.bin and config.toml of an otfp run there",
                     kUsage);
      for (const std::string& set : sets) {
        const std::string key = set.substr(0, set.find('='));
        bool allowed = false;
        for (const char* k : kResumeKeys) allowed = allowed || key == k;
        if (!allowed)
          return error(err,
                       "--set " + escaped(set) +
                           ": cannot change on --resume (only run.t_end, run.max_steps, run.vtk_interval, "
                           "run.checkpoint_interval, run.threads)",
                       kUsage);
      }
      config = (std::filesystem::path(resume_dir) / "config.toml").string();
      out_dir = resume_dir;
    } else if (run->count("--out") > 0 && out_dir.empty()) {
      return error(err, "--out = \"\": must be a non-empty path", kUsage);
    } else if (config.empty() || out_dir.empty()) {
      return error(err, std::string(config.empty() ? "CONFIG" : "--out") + " is required (or --resume DIR) (try --help)",
                   kUsage);
    }
  }

  int code = 0;
  std::unique_ptr<ConfiguredRun> sim = load(config, sets, err, code);
  if (!sim) return code;

  if (check->parsed()) {
    out << sim->describe().dump(2) << "\n";
    return 0;
  }

  const std::filesystem::path dir(out_dir);
  OutputLock lock;  // held until the run has written its last file
  if (const std::string why = prepare_out_dir(dir, resume, overwrite, lock); !why.empty())
    return error(err, (resume ? "--resume = \"" : "--out = \"") + out_dir + "\": " + why, kUsage);

  RunOptions ro;
  ro.out_dir = dir;
  ro.progress = !quiet && &err == &std::cerr && ::isatty(STDERR_FILENO);
  ro.keep_series = false;
  ro.resume = resume;
  ro.stop_flag = &g_stop;
  // What a second signal cleans up besides write_file_atomic's file: the
  // library's checkpoint temporary file and the lock.
  set_kill_time_paths({dir / fmt::format("checkpoint.bin.tmp{}", ::getpid()), dir / ".otfp.lock"});
  fmt::format_to_n(g_kill_message, sizeof g_kill_message - 1,
                   "otfp: error: stopped by a second signal during a step; continue from the last checkpoint with: "
                   "otfp run --resume {}\n",
                   out_dir);
  RunResult r;
  {
    const StopSignals signals;
    r = sim->run(ro);
  }
  clear_kill_time_state();
  if (r.nothing_to_do) {
    if (!quiet)
      err << fmt::format("otfp: {} is already at step {}, t = {}: nothing to do (extend it with --set run.t_end=...)\n",
                         out_dir, r.last.step, r.last.t);
    return 0;
  }
  if (r.exit_code == kExitInterrupted) return error(err, r.error, kExitInterrupted);
  if (r.exit_code != 0)
    return error(err,
                 r.rows ? fmt::format("{} (the files in {} are complete up to step {}, t = {})", r.error, out_dir,
                                      r.last.step, r.last.t)
                        : fmt::format("{} (before step 0: {} holds no rows)", r.error, out_dir),
                 kRunFailed);
  if (!quiet)
    err << fmt::format("otfp: {} steps to t = {}: n = {}, M/M_inf = {:.4f}, {:.1f} s -> {}\n", r.last.step, r.last.t,
                       r.last.n_particles, r.last.mass_ratio, r.summary.value("wall_seconds", 0.0), out_dir);
  return 0;
}

}  // namespace otfp::app
