#include "otfp_app/sweep.hpp"

#include <fcntl.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <fmt/format.h>

#include <cerrno>
#include <algorithm>
#include <chrono>
#include <cstring>
#include <cmath>
#include <fstream>
#include <map>
#include <ostream>
#include <sstream>
#include <stdexcept>
#include <thread>

#include "otfp_app/config.hpp"
#include "otfp_app/series_columns.hpp"
#include "otfp_app/simulation.hpp"
#include "otfp_app/writers.hpp"

extern char** environ;

namespace otfp::app {

namespace {

using Clock = std::chrono::steady_clock;

std::string trim(const std::string& s) {
  const auto a = s.find_first_not_of(" \t");
  if (a == std::string::npos) return "";
  const auto b = s.find_last_not_of(" \t");
  return s.substr(a, b - a + 1);
}

// RFC 4180 field: quoted when it holds a comma, quote or line break.
std::string csv_field(const std::string& s) {
  if (s.find_first_of(",\"\n\r") == std::string::npos) return s;
  std::string out = "\"";
  for (char ch : s) {
    if (ch == '"') out += '"';
    out += ch;
  }
  return out + "\"";
}

// A number from the summary, or an empty field.
std::string field(const nlohmann::json& j, const nlohmann::json::json_pointer& p) {
  if (j.is_null() || !j.contains(p)) return "";
  const nlohmann::json& v = j.at(p);
  if (v.is_number_integer()) return fmt::format("{}", v.get<long long>());
  if (v.is_number()) return fmt::format("{}", v.get<double>());
  if (v.is_string()) return csv_field(v.get<std::string>());
  return "";
}

// summary.json's "final" entry of a column of series.csv (series_columns.hpp).
std::string final_pointer(const std::string& column) {
  for (const SeriesColumn& c : series_columns())
    if (c.in_final && column == c.name) return "/final/" + column;
  throw std::logic_error("runs.csv: no column " + column + " in summary.json's \"final\"");
}

// The summary figures of runs.csv: (column, JSON pointer into summary.json).
// Reference quantities: ref_* is the first (M/M_inf, second moment or mode
// amplitude), ref2_* the polar inertia where the reference has one.
const std::vector<std::pair<std::string, std::string>>& summary_columns() {
  static const std::vector<std::pair<std::string, std::string>> cols = {
      {"dim", "/config/run/dim"},
      {"n_inf", "/config/particles/n_inf"},
      {"dr", "/derived/dr"},
      {"beta", "/derived/beta"},
      {"dt", "/derived/dt"},
      {"dt_explicit", "/derived/dt_explicit"},
      {"steps", final_pointer("step")},
      {"t_final", final_pointer("t")},
      {"n_particles", final_pointer("n_particles")},
      {"n_inside", final_pointer("n_inside")},
      {"mass_total", final_pointer("mass_total")},
      {"mass_ratio", final_pointer("mass_ratio")},
      {"polar_inertia_ratio", final_pointer("polar_inertia_ratio")},
      {"iterations", "/solver_totals/iterations"},
      {"evaluations", "/solver_totals/evaluations"},
      {"rejected_solves", "/solver_totals/rejected_solves"},
      {"halvings", "/solver_totals/halvings"},
      {"inserted", "/ledger/inserted"},
      {"removed", "/ledger/removed"},
      {"l1_mass", "/l1/mass_rectangle"},
      {"l1_polar_inertia", "/l1/polar_inertia_rectangle"},
      {"l1_mass_inside", "/l1/mass_inside_trapezoid"},
      {"l1_polar_inertia_inside", "/l1/polar_inertia_inside_trapezoid"},
      {"reference", "/reference/curve"},
      {"ref_quantity", "/reference/quantities/0/measured"},
      {"ref_max_abs_error", "/reference/quantities/0/max_abs_error"},
      {"ref_mean_abs_error", "/reference/quantities/0/mean_abs_error"},
      {"ref_final_error", "/reference/quantities/0/final_error"},
      {"ref_l1_norm_relative_error", "/reference/quantities/0/l1_norm_relative_error"},
      {"ref2_quantity", "/reference/quantities/1/measured"},
      {"ref2_max_abs_error", "/reference/quantities/1/max_abs_error"},
      {"ref2_mean_abs_error", "/reference/quantities/1/mean_abs_error"},
      {"ref2_l1_norm_relative_error", "/reference/quantities/1/l1_norm_relative_error"},
      {"growth_ratio", "/reference/growth_ratio"},
      {"rate_ratio", "/reference/rate_ratio"},
      {"rate_ratio_time_discrete", "/reference/rate_ratio_time_discrete"},
      {"mass_blob_ratio", final_pointer("mass_blob_ratio")},
      {"blob_max_abs_error", "/reference/mass_blob/max_abs_error"},
      {"blob_mean_abs_error", "/reference/mass_blob/mean_abs_error"},
      {"blob_final_error", "/reference/mass_blob/final_error"},
  };
  return cols;
}

std::string read_text(const std::filesystem::path& p) {
  std::ifstream in(p);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

// The last "otfp: error: ..." line of a run's log, without the prefix.
std::string error_from_log(const std::filesystem::path& log) {
  std::istringstream in(read_text(log));
  std::string line, last, last_error;
  while (std::getline(in, line)) {
    if (line.empty()) continue;
    last = line;
    if (line.rfind("otfp: error: ", 0) == 0) last_error = line.substr(13);
  }
  return last_error.empty() ? last : last_error;
}

struct Running {
  pid_t pid = -1;
  Clock::time_point start;
};

}  // namespace

namespace {

// Splits at `sep` outside [...], {...} and quotes; throws on an empty part.
std::vector<std::string> split_top(const std::string& text, char sep, const std::string& whole) {
  std::vector<std::string> parts;
  std::string cur;
  int depth = 0;
  char quote = 0;
  for (char ch : text) {
    if (quote) {
      if (ch == quote) quote = 0;
    } else if (ch == '"' || ch == '\'') {
      quote = ch;
    } else if (ch == '[' || ch == '{') {
      ++depth;
    } else if (ch == ']' || ch == '}') {
      --depth;
    } else if (ch == sep && depth == 0) {
      parts.push_back(trim(cur));
      cur.clear();
      continue;
    }
    cur += ch;
  }
  parts.push_back(trim(cur));
  if (quote || depth != 0) throw ConfigError("--vary", "\"" + whole + "\"", "has an unclosed bracket or quote");
  for (const std::string& p : parts)
    if (p.empty()) throw ConfigError("--vary", "\"" + whole + "\"", "has an empty key or value");
  return parts;
}

}  // namespace

SweepAxis parse_vary(const std::string& text) {
  const auto eq = text.find('=');
  if (eq == std::string::npos || eq == 0)
    throw ConfigError("--vary", "\"" + text + "\"", "must be key=v1,v2,... (e.g. run.dt_factor=0.5,1,2)");
  SweepAxis axis;
  axis.keys = split_top(text.substr(0, eq), ':', text);
  for (const std::string& point : split_top(text.substr(eq + 1), ',', text)) {
    std::vector<std::string> v = axis.keys.size() == 1 ? std::vector<std::string>{point} : split_top(point, ':', text);
    if (v.size() != axis.keys.size())
      throw ConfigError("--vary", "\"" + text + "\"",
                        fmt::format("value \"{}\" has {} parts for {} keys (separate them with ':')", point, v.size(),
                                    axis.keys.size()));
    axis.values.push_back(std::move(v));
  }
  return axis;
}

std::vector<std::vector<std::string>> expand_grid(const std::vector<SweepAxis>& axes) {
  // At most kMaxSweepRuns points (run_0000 ... run_9999), checked before
  // the grid is built: three axes of 300 values would be 2.7e7 rows.
  double runs = 1.0;
  std::string sizes;
  for (const SweepAxis& a : axes) {
    runs *= static_cast<double>(a.values.size());
    sizes += (sizes.empty() ? "" : " x ") + std::to_string(a.values.size());
  }
  if (runs > static_cast<double>(kMaxSweepRuns))
    throw ConfigError("--vary", fmt::format("{} = {:.0f} runs", sizes, runs),
                      fmt::format("must give at most {} runs", kMaxSweepRuns));
  std::vector<std::vector<std::string>> grid(1);
  for (const SweepAxis& a : axes) {
    std::vector<std::vector<std::string>> next;
    for (const auto& g : grid)
      for (const auto& v : a.values) {
        next.push_back(g);
        next.back().insert(next.back().end(), v.begin(), v.end());
      }
    grid = std::move(next);
  }
  return grid;
}

std::string runs_csv_header(const std::vector<SweepAxis>& axes) {
  std::string h = "index,dir";
  for (const SweepAxis& a : axes)
    for (const std::string& k : a.keys) {
      h += ',';
      h += csv_field(k);
    }
  h += ",status,exit_code,error,wall_seconds";
  for (const auto& [col, ptr] : summary_columns()) {
    h += ',';
    h += col;
  }
  return h + "\n";
}

std::string runs_csv_row(const SweepRow& row) {
  std::string line = fmt::format("{},{}", row.index, csv_field(row.dir));
  for (const std::string& v : row.values) {
    line += ',';
    line += csv_field(v);
  }
  line += fmt::format(",{},{},{},{}", row.status, row.exit_code, csv_field(row.error), row.wall_seconds);
  for (const auto& [col, ptr] : summary_columns()) {
    line += ',';
    line += field(row.summary, nlohmann::json::json_pointer(ptr));
  }
  return line + "\n";
}

SweepResult run_sweep(const SweepOptions& o, std::ostream& err) {
  if (o.axes.empty()) throw ConfigError("--vary", "(missing)", "give at least one --vary key=v1,v2,...");
  if (o.jobs < 1 || o.jobs > 256) throw ConfigError("--jobs", std::to_string(o.jobs), "must be in [1, 256]");
  if (!(o.timeout_seconds >= 0.0) || !std::isfinite(o.timeout_seconds))
    throw ConfigError("--timeout", fmt::format("{}", o.timeout_seconds), "must be >= 0 seconds (0: none)");
  if (o.out_dir.empty()) throw ConfigError("--out", "(missing)", "required: the sweep directory");
  std::error_code ec;
  if (std::filesystem::exists(o.out_dir, ec) && !std::filesystem::is_directory(o.out_dir, ec))
    throw ConfigError("--out", "\"" + o.out_dir.string() + "\"", "exists and is not a directory");
  if (::access(o.executable.c_str(), X_OK) != 0)
    throw ConfigError("executable", "\"" + o.executable.string() + "\"", "is not an executable otfp binary");
  expand_grid(o.axes);  // its size is checked before the values are
  std::vector<std::string> keys;
  for (const SweepAxis& a : o.axes)
    for (const std::string& k : a.keys) {
      if (std::find(keys.begin(), keys.end(), k) != keys.end())
        throw ConfigError("--vary", k, "is varied twice (give all its values in one --vary)");
      keys.push_back(k);
    }

  // The base configuration must parse, and every varied key must exist; a
  // value out of range only fails its own runs (rows with status "invalid").
  parse_config_file(o.config, o.sets);
  for (const SweepAxis& a : o.axes)
    for (const auto& point : a.values)
      for (std::size_t k = 0; k < a.keys.size(); ++k) {
        std::vector<std::string> sets = o.sets;
        sets.push_back(a.keys[k] + "=" + point[k]);
        try {
          parse_config_file(o.config, sets);
        } catch (const ConfigError& e) {
          const std::string what = e.what();
          if (what.find("unknown key") != std::string::npos || what.find("unknown section") != std::string::npos)
            throw ConfigError("--vary", a.keys[k] + ": " + what);
        }
      }

  const auto grid = expand_grid(o.axes);
  const int width = grid.size() > 1000 ? 4 : 3;
  std::filesystem::create_directories(o.out_dir);
  {
    nlohmann::json axes = nlohmann::json::array();
    for (const SweepAxis& a : o.axes) axes.push_back({{"keys", a.keys}, {"values", a.values}});
    const nlohmann::json j = {{"config", std::filesystem::absolute(o.config).string()},
                              {"sets", o.sets},
                              {"axes", axes},
                              {"runs", grid.size()},
                              {"jobs", o.jobs},
                              {"timeout_seconds", o.timeout_seconds}};
    write_file_atomic(o.out_dir / "sweep.json", j.dump(2) + "\n");
  }

  SweepResult result;
  result.rows.resize(grid.size());
  std::vector<char> done(grid.size(), 0);
  auto write_csv = [&] {
    std::string text = runs_csv_header(o.axes);
    for (std::size_t i = 0; i < grid.size(); ++i)
      if (done[i]) text += runs_csv_row(result.rows[i]);
    write_file_atomic(o.out_dir / "runs.csv", text);
  };
  write_csv();

  auto launch = [&](std::size_t i) {
    SweepRow& row = result.rows[i];
    row.index = static_cast<int>(i);
    row.dir = fmt::format("run_{:0{}d}", i, width);
    row.values = grid[i];
    const std::filesystem::path dir = o.out_dir / row.dir;
    std::filesystem::create_directories(dir);
    std::filesystem::remove(dir / "summary.json", ec);
    // The run directories are the sweep's own: a sweep run again replaces their runs.
    std::vector<std::string> args = {o.executable.string(), "run",       o.config.string(), "--out",
                                     dir.string(),          "--overwrite", "--quiet"};
    for (const std::string& s : o.sets) args.insert(args.end(), {"--set", s});
    for (std::size_t k = 0; k < keys.size(); ++k) args.insert(args.end(), {"--set", keys[k] + "=" + grid[i][k]});
    std::vector<char*> argv;
    for (std::string& a : args) argv.push_back(a.data());
    argv.push_back(nullptr);
    posix_spawn_file_actions_t fa;
    posix_spawn_file_actions_init(&fa);
    const std::string log = (dir / "otfp.log").string();
    posix_spawn_file_actions_addopen(&fa, STDOUT_FILENO, log.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    posix_spawn_file_actions_adddup2(&fa, STDOUT_FILENO, STDERR_FILENO);
    // Each run in its own process group: a Ctrl-C at the terminal reaches the
    // sweep only, which forwards it once (a run stops at the second signal).
    // The runs start with the default SIGINT/SIGTERM actions and none blocked.
    posix_spawnattr_t attr;
    posix_spawnattr_init(&attr);
    sigset_t none, defaults;
    sigemptyset(&none);
    sigemptyset(&defaults);
    sigaddset(&defaults, SIGINT);
    sigaddset(&defaults, SIGTERM);
    posix_spawnattr_setsigmask(&attr, &none);
    posix_spawnattr_setsigdefault(&attr, &defaults);
    posix_spawnattr_setpgroup(&attr, 0);
    posix_spawnattr_setflags(&attr, POSIX_SPAWN_SETPGROUP | POSIX_SPAWN_SETSIGMASK | POSIX_SPAWN_SETSIGDEF);
    // OTFP_SWEEP_PID: the run asks for SIGTERM when this process dies (a
    // sweep killed outright must not leave its runs running; cli.cpp).
    std::vector<std::string> env_text;
    for (char** e = environ; *e; ++e)
      if (std::string(*e).rfind("OTFP_SWEEP_PID=", 0) != 0) env_text.emplace_back(*e);
    env_text.push_back("OTFP_SWEEP_PID=" + std::to_string(::getpid()));
    std::vector<char*> envp;
    for (std::string& e : env_text) envp.push_back(e.data());
    envp.push_back(nullptr);
    pid_t pid = -1;
    const int rc = posix_spawn(&pid, argv[0], &fa, &attr, argv.data(), envp.data());
    posix_spawnattr_destroy(&attr);
    posix_spawn_file_actions_destroy(&fa);
    if (rc != 0) throw std::runtime_error(fmt::format("cannot start {}: {}", argv[0], std::strerror(rc)));
    return Running{pid, Clock::now()};
  };

  bool stopping = false;  // a signal came: start nothing more
  int forwarded = 0;      // signals passed on to the running runs
  auto finish = [&](std::size_t i, const Running& r, pid_t waited, int wstatus, bool timed_out) {
    const int saved_errno = errno;
    SweepRow& row = result.rows[i];
    row.wall_seconds = std::chrono::duration<double>(Clock::now() - r.start).count();
    const std::filesystem::path dir = o.out_dir / row.dir;
    if (std::filesystem::exists(dir / "summary.json")) {
      try {
        row.summary = nlohmann::json::parse(read_text(dir / "summary.json"));
      } catch (const std::exception&) {
        row.summary = nullptr;
      }
    }
    if (timed_out) {
      row.summary = nullptr;  // it still says "running": no figures
      row.status = "timeout";
      row.exit_code = -1;
      row.error = fmt::format("killed after the --timeout of {} s", o.timeout_seconds);
    } else if (waited < 0) {
      row.status = "crashed";
      row.exit_code = -1;
      row.error = fmt::format("waitpid failed: {}", std::strerror(saved_errno));
    } else if (WIFEXITED(wstatus)) {
      row.exit_code = WEXITSTATUS(wstatus);
      row.status = row.exit_code == 0   ? "completed"
                   : row.exit_code == 2 ? "invalid"
                   : row.exit_code == kExitInterrupted ? "interrupted"
                                                       : "failed";
      if (row.exit_code != 0) row.error = error_from_log(dir / "otfp.log");
    } else if (stopping && WIFSIGNALED(wstatus) &&
               (WTERMSIG(wstatus) == SIGINT || WTERMSIG(wstatus) == SIGTERM)) {
      // Killed by a signal the sweep forwarded (the second one).
      row.status = "interrupted";
      row.exit_code = -1;
      row.error = fmt::format("stopped by signal {} (forwarded by the sweep)", WTERMSIG(wstatus));
    } else {
      row.status = "crashed";
      row.exit_code = -1;
      row.error = fmt::format("terminated by signal {}", WIFSIGNALED(wstatus) ? WTERMSIG(wstatus) : 0);
    }
    if (row.status != "completed") ++result.failed;
    done[i] = 1;
    write_csv();
    if (o.progress) {
      std::string vals;
      for (std::size_t k = 0; k < keys.size(); ++k) vals += (k ? ", " : "") + keys[k] + "=" + row.values[k];
      int finished = 0;
      for (char dn : done) finished += dn;
      err << fmt::format("[{}/{}] {} {} {:.1f} s ({}){}\n", finished, grid.size(), row.dir, row.status,
                         row.wall_seconds, vals, row.error.empty() ? "" : ": " + row.error);
    }
  };

  std::map<std::size_t, Running> running;
  // If anything below throws (a run cannot be started, runs.csv cannot be
  // written), no child is left running or unreaped.
  struct Reaper {
    std::map<std::size_t, Running>& r;
    ~Reaper() {
      for (auto& [i, run] : r) {
        ::kill(run.pid, SIGKILL);
        int st = 0;
        ::waitpid(run.pid, &st, 0);
      }
    }
  } reaper{running};
  // Children must stay waitable even if SIGCHLD was inherited as ignored.
  ::signal(SIGCHLD, SIG_DFL);
  std::size_t next = 0;
  while ((next < grid.size() && !stopping) || !running.empty()) {
    // A signal: no more runs; the running ones get each signal the sweep gets.
    const int signals = o.stop_count ? static_cast<int>(*o.stop_count) : 0;
    if (signals > forwarded) {
      stopping = true;
      result.interrupted = true;
      const int sig = o.stop_signal && *o.stop_signal ? static_cast<int>(*o.stop_signal) : SIGTERM;
      for (auto& [i, run] : running) ::kill(run.pid, sig);
      forwarded = signals;
    }
    while (!stopping && next < grid.size() && running.size() < static_cast<std::size_t>(o.jobs)) {
      running[next] = launch(next);
      ++next;
    }
    bool any = false;
    for (auto it = running.begin(); it != running.end();) {
      int wstatus = 0;
      const pid_t w = ::waitpid(it->second.pid, &wstatus, WNOHANG);
      const int wait_errno = errno;
      const bool timed_out =
          w == 0 && o.timeout_seconds > 0.0 &&
          std::chrono::duration<double>(Clock::now() - it->second.start).count() > o.timeout_seconds;
      if (timed_out) {
        ::kill(it->second.pid, SIGKILL);
        ::waitpid(it->second.pid, &wstatus, 0);
      }
      if (w != 0 || timed_out) {
        errno = wait_errno;
        finish(it->first, it->second, w, wstatus, timed_out);
        it = running.erase(it);
        any = true;
      } else {
        ++it;
      }
    }
    if (!any) std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  return result;
}

}  // namespace otfp::app
