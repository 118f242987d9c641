#include "otfp_app/cli.hpp"

#include <sys/prctl.h>
#include <unistd.h>

#include <csignal>
#include <cstdlib>
#include <cstring>

#include <CLI/CLI.hpp>
#include <fmt/format.h>

#include <filesystem>
#include <iostream>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "otfp_app/config.hpp"
#include "otfp_app/out_dir.hpp"
#include "otfp_app/simulation.hpp"
#include "otfp_app/sweep.hpp"
#include "otfp_app/writers.hpp"
#ifdef OTFP_WITH_TAO
#include "otfp/tao.hpp"
#endif

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


// One line: control characters anywhere in the message (a path with a
// newline, say) are escaped.
int error(std::ostream& err, const std::string& message, int code) {
  err << "otfp: error: " << one_line(message) << "\n";
  return code;
}


// The nearest of `names` to `word` if it is close (at most 2 edits, or a third of its length), else "".
std::string nearest(const std::string& word, const std::vector<std::string>& names) {
  std::string best;
  std::size_t best_d = std::max<std::size_t>(2, word.size() / 3) + 1;
  for (const std::string& n : names)
    if (const std::size_t d = edit_distance(word, n); d < best_d) {
      best = n;
      best_d = d;
    }
  return best;
}

// Parses and checks everything; nullptr after printing the error. A
// configuration's errors come from the arguments and files alone, the same
// on every rank, and go to `err`; any other to `err_any_rank`.
std::unique_ptr<ConfiguredRun> load(const std::string& config, const std::vector<std::string>& sets, std::ostream& err,
                                    std::ostream& err_any_rank, int& code) {
  try {
    return std::make_unique<ConfiguredRun>(parse_config_file(config, sets));
  } catch (const ConfigError& e) {
    code = error(err, e.what(), kUsage);
  } catch (const std::exception& e) {
    code = error(err_any_rank, e.what(), kUsage);
  }
  return nullptr;
}

}  // namespace

int cli_main(int argc, const char* const* argv, std::ostream& out_any_rank, std::ostream& err_any_rank) {
  // Started by mpirun, every rank parses the same arguments and files and
  // refuses them alike: rank 0 alone prints what follows from them (during
  // the run, rank 0 reports every rank's outcome, below).
  std::ostringstream other_rank;
  const bool first_rank = launched_rank() == 0;
  std::ostream& out = first_rank ? out_any_rank : other_rank;
  std::ostream& err = first_rank ? err_any_rank : other_rank;
#ifdef OTFP_WITH_TAO
  otfp::register_tao_backend();  // solver.backend = "tao"
  const std::string backends = " (solver backends: ceres, nlopt, tao with " + otfp::petsc_version() + ")";
#else
  const std::string backends = " (solver backends: ceres, nlopt)";
#endif
  CLI::App app{"otfp: optimal-transport finite-particle method for driven mass diffusion"};
  app.set_version_flag("--version", "otfp " + version() + backends);
  app.require_subcommand(1);

  std::string config, out_dir, resume_dir;
  std::vector<std::string> sets;
  bool quiet = false, overwrite = false;

  CLI::App* run = app.add_subcommand("run", "run a simulation and write its outputs");
  run->add_option("config", config, "configuration file (TOML)")->type_name("CONFIG");
  run->add_option("--out,-o", out_dir, "output directory (created if missing)")->type_name("DIR");
  run->add_option("--resume", resume_dir,
                  "continue the run in DIR from its checkpoint (e.g. --set run.t_end=LATER to extend a finished run)")
      ->type_name("DIR");
  run->footer(
      "Exit codes: 0 completed; 1 the run failed (the files are complete up to the last good step); 2 bad input "
      "(configuration, paths, --set, a --resume that cannot continue; nothing is written); 3 interrupted by "
      "SIGINT/SIGTERM (checkpoint written; continue with otfp run --resume DIR).");
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

  // A misspelt command: CLI11 would only say that one is required.
  const std::vector<std::string> commands = {"run", "check", "sweep"};
  if (argc > 1 && argv[1][0] != '-' && std::find(commands.begin(), commands.end(), argv[1]) == commands.end()) {
    const std::string near = nearest(argv[1], commands);
    return error(err,
                 std::string("unknown command '") + argv[1] + "' (" + (near.empty() ? "" : "did you mean '" + near + "'? ") +
                     "commands: run, check, sweep)",
                 kUsage);
  }
  try {
    app.parse(argc, argv);
  } catch (const CLI::CallForHelp& e) {
    return app.exit(e, out, err);
  } catch (const CLI::CallForAllHelp& e) {
    return app.exit(e, out, err);
  } catch (const CLI::CallForVersion& e) {
    return app.exit(e, out, err);
  } catch (const CLI::ParseError& e) {
    // An unknown option: name the nearest option of its command.
    std::string hint;
    const std::string first = argc > 1 ? argv[1] : "";
    CLI::App* sub = first == "run" ? run : first == "check" ? check : first == "sweep" ? sweep : nullptr;
    if (sub) {
      std::vector<std::string> options;
      for (const CLI::Option* o : sub->get_options())
        for (const std::string& n : o->get_lnames()) options.push_back("--" + n);
      for (int i = 2; i < argc && hint.empty(); ++i) {
        const std::string arg = std::string(argv[i]).substr(0, std::string(argv[i]).find('='));
        if (arg.rfind("--", 0) != 0 || std::find(options.begin(), options.end(), arg) != options.end()) continue;
        if (const std::string near = nearest(arg, options); !near.empty())
          hint = " (unknown option " + arg + ": did you mean " + near + "?)";
      }
    }
    return error(err, std::string(e.what()) + hint + " (try --help)", kUsage);
  }

  // Started by mpirun on several ranks: `otfp run` is distributed over them
  // (docs/distributed.md); a sweep runs its configurations on one rank.
  if (const int ranks = launched_ranks(); ranks > 1) {
#ifndef OTFP_WITH_TAO
    return error(err,
                 fmt::format("{} ranks: this otfp was built without MPI and PETSc (OTFP_WITH_MPI), so it runs on one "
                             "rank (docs/distributed.md)",
                             ranks),
                 kUsage);
#endif
    if (sweep->parsed())
      return error(err, fmt::format("{} ranks: otfp sweep runs on one rank (run its configurations with mpirun "
                                    "otfp run)",
                                    ranks),
                   kUsage);
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
        // Asked for: a notice, not an error.
        int finished = 0;
        for (const SweepRow& row : r.rows) finished += row.status == "completed" ? 1 : 0;
        err << "otfp: "
            << one_line(fmt::format("sweep interrupted by a signal: {} of its runs completed -> {}/runs.csv", finished,
                                   out_dir))
            << "\n";
        return kExitInterrupted;
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
        const std::vector<std::string>& keys = resume_keys();
        if (std::find(keys.begin(), keys.end(), key) == keys.end()) {
          std::string list;
          for (const std::string& k : keys) list += (list.empty() ? "" : ", ") + k;
          return error(err, "--set " + one_line(set) + ": cannot change on --resume (only " + list + ")", kUsage);
        }
      }
      config = (std::filesystem::path(resume_dir) / "config.toml").string();
      out_dir = resume_dir;
    } else if (run->count("--out") > 0 && out_dir.empty()) {
      return error(err, "--out = \"\": must be a non-empty path", kUsage);
    } else if (config.empty() || out_dir.empty()) {
      // CONFIG first: a missing or bad file is the first thing to fix.
      if (!config.empty()) {
        int code = 0;
        if (!load(config, sets, err, err_any_rank, code)) return code;
      }
      return error(err, std::string(config.empty() ? "CONFIG" : "--out") + " is required (or --resume DIR) (try --help)",
                   kUsage);
    }
  }

  // A run started by `otfp sweep`: SIGTERM (stop after the step, checkpoint)
  // when the sweep dies, even by SIGKILL; if it is already gone, stop now.
  if (run->parsed())
    if (const char* sweep_pid = std::getenv("OTFP_SWEEP_PID")) {
      ::prctl(PR_SET_PDEATHSIG, SIGTERM);
      if (std::to_string(::getppid()) != sweep_pid) {
        err << "otfp: the sweep that started this run (pid " << one_line(sweep_pid) << ") is gone; not started\n";
        return kExitInterrupted;
      }
    }

  int code = 0;
  std::unique_ptr<ConfiguredRun> sim = load(config, sets, err, err_any_rank, code);
  if (!sim) return code;

  // A distributed run: rank 0 writes the files and prints; the outcomes
  // below are every rank's alike.
  const bool root = sim->root_process();
  if (check->parsed()) {
    if (root) out << sim->describe().dump(2) << "\n";
    return 0;
  }

  const std::filesystem::path dir(out_dir);
  OutputLock lock;  // held until the run has written its last file
  std::string why;
  if (root) why = prepare_out_dir(dir, resume, overwrite, lock);
  if (sim->any_process(!why.empty()))
    return root ? error(err, (resume ? "--resume = \"" : "--out = \"") + out_dir + "\": " + why, kUsage) : kUsage;
  if (!root) quiet = true;
  // Other ranks report nothing (their outcome is rank 0's).
  std::ostringstream elsewhere;
  std::ostream& report = root ? err : elsewhere;

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
                   "otfp: stopped by a second signal during a step; continue from the last checkpoint with: "
                   "otfp run --resume {}\n",
                   one_line(out_dir));
  RunResult r;
  {
    const StopSignals signals;
    r = sim->run(ro);
  }
  clear_kill_time_state();
  if (r.nothing_to_do) {
    if (!quiet)
      report << fmt::format("otfp: {} is already at step {}, t = {}: nothing to do (extend it with --set run.t_end=...)\n",
                         one_line(out_dir), r.last.step, r.last.t);
    return 0;
  }
  if (r.exit_code == kExitInterrupted) {
    // Asked for (SIGINT/SIGTERM): a notice, not an error.
    report << "otfp: " << one_line(r.error) << "\n";
    return kExitInterrupted;
  }
  if (r.exit_code == kExitRefused)
    return error(report, "--resume = \"" + one_line(out_dir) + "\": " + r.error + " (nothing in it was changed)", kUsage);
  if (r.exit_code != 0)
    return error(report,
                 r.rows ? fmt::format("{} (the files in {} are complete up to step {}, t = {})", r.error, out_dir,
                                      r.last.step, r.last.t)
                        : fmt::format("{} (before step 0: {} holds no rows)", r.error, out_dir),
                 kRunFailed);
  if (!quiet) {
    // M by centres (43) and M_rho (the blob mass in Omega, images included):
    // in a settled state layers of particles move the first, not the second
    // (docs/boundaries.md, "Counts of centres in a settled state").
    std::string blob;
    if (r.summary.contains("final") && r.summary["final"].contains("mass_blob_ratio") &&
        r.summary["final"]["mass_blob_ratio"].is_number())
      blob = fmt::format(", M_rho/M_inf = {:.4f}", r.summary["final"]["mass_blob_ratio"].get<double>());
    report << fmt::format("otfp: {} steps to t = {}: n = {}, M/M_inf = {:.4f}{}, {:.1f} s -> {}\n", r.last.step, r.last.t,
                       r.last.n_particles, r.last.mass_ratio, blob, r.summary.value("wall_seconds", 0.0),
                       one_line(out_dir));
  }
  return 0;
}

}  // namespace otfp::app
