#include "otfp_app/cli.hpp"

#include <unistd.h>

#include <CLI/CLI.hpp>
#include <fmt/format.h>

#include <filesystem>
#include <iostream>
#include <memory>
#include <string>
#include <vector>

#include "otfp_app/config.hpp"
#include "otfp_app/simulation.hpp"

namespace otfp::app {

namespace {

constexpr int kRunFailed = 1;
constexpr int kUsage = 2;

int error(std::ostream& err, const std::string& message, int code) {
  err << "otfp: error: " << message << "\n";
  return code;
}

// Parses and checks everything; nullptr after printing the error.
std::unique_ptr<Simulation> load(const std::string& config, const std::vector<std::string>& sets, std::ostream& err,
                                 int& code) {
  try {
    return std::make_unique<Simulation>(parse_config_file(config, sets));
  } catch (const ConfigError& e) {
    code = error(err, e.what(), kUsage);
  } catch (const std::exception& e) {
    code = error(err, e.what(), kUsage);
  }
  return nullptr;
}

}  // namespace

int cli_main(int argc, const char* const* argv, std::ostream& out, std::ostream& err) {
  CLI::App app{"otfp: optimal-transport finite-particle method for driven mass diffusion"};
  app.set_version_flag("--version", "otfp " + version());
  app.require_subcommand(1);

  std::string config, out_dir;
  std::vector<std::string> sets;
  bool quiet = false;

  CLI::App* run = app.add_subcommand("run", "run a simulation and write its outputs");
  run->add_option("config", config, "configuration file (TOML)")->required();
  run->add_option("--out,-o", out_dir, "output directory (created if missing)")->required();
  run->add_option("--set,-s", sets, "override a key by dotted path, e.g. particles.n_inf=3200 (repeatable)")
      ->allow_extra_args(false)
      ->take_all();
  run->add_flag("--quiet,-q", quiet, "print nothing but errors");

  CLI::App* check = app.add_subcommand("check", "validate a configuration and print the resolved values as JSON");
  check->add_option("config", config, "configuration file (TOML)")->required();
  check->add_option("--set,-s", sets, "override a key by dotted path (repeatable)")
      ->allow_extra_args(false)
      ->take_all();

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

  int code = 0;
  std::unique_ptr<Simulation> sim = load(config, sets, err, code);
  if (!sim) return code;

  if (check->parsed()) {
    out << sim->describe().dump(2) << "\n";
    return 0;
  }

  const std::filesystem::path dir(out_dir);
  std::error_code ec;
  if (std::filesystem::exists(dir, ec) && !std::filesystem::is_directory(dir, ec))
    return error(err, "--out = \"" + out_dir + "\": exists and is not a directory", kUsage);

  RunOptions ro;
  ro.out_dir = dir;
  ro.progress = !quiet && &err == &std::cerr && ::isatty(STDERR_FILENO);
  ro.keep_series = false;
  const RunResult r = sim->run(ro);
  if (r.exit_code != 0)
    return error(err,
                 fmt::format("{} (the files in {} are complete up to step {}, t = {})", r.error, out_dir, r.last.step,
                             r.last.t),
                 kRunFailed);
  if (!quiet)
    err << fmt::format("otfp: {} steps to t = {}: n = {}, M/M_inf = {:.4f}, {:.1f} s -> {}\n", r.last.step, r.last.t,
                       r.last.n_particles, r.last.mass_ratio, r.summary.value("wall_seconds", 0.0), out_dir);
  return 0;
}

}  // namespace otfp::app
