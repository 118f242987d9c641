// Restart (checkpoints, --resume, interruption) and runs that start from a
// particle file (particles.fill = "file").
#include <gtest/gtest.h>
#include <sys/stat.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include "app_test_support.hpp"
#include "otfp_app/cli.hpp"
#include "otfp_app/config.hpp"
#include "otfp_app/simulation.hpp"

namespace fs = std::filesystem;
using namespace otfp::app;
using otfp::test::fresh_dir;
using otfp::test::read_text;

namespace {

const fs::path kExamples = fs::path(OTFP_SOURCE_DIR) / "examples";

// A small sphere run on an exact time grid (dt = 2^-8), so that t_end = k dt
// holds exactly and a run extended to a later t_end keeps its grid.
std::vector<std::string> small_sphere(int steps, bool adaptive) {
  std::vector<std::string> sets = {"particles.n_inf=200", "run.dt=0.00390625",
                                   "run.t_end=" + std::to_string(steps * 0.00390625), "run.vtk_interval=4",
                                   "run.checkpoint_interval=5", "treatment.reservoir_width=0.5"};
  if (adaptive) sets.insert(sets.end(), {"run.dt_mode=adaptive", "solver.time_scheme=bdf2"});
  return sets;
}

RunResult run_config(const std::vector<std::string>& sets, const fs::path& dir, std::int64_t stop_after = 0) {
  RunOptions ro;
  ro.out_dir = dir;
  ro.keep_series = false;
  ro.stop_after_step = stop_after;
  return ConfiguredRun(parse_config_file(kExamples / "sphere_dirichlet.toml", sets)).run(ro);
}

std::vector<std::string> lines_of(const std::string& text) {
  std::vector<std::string> out;
  std::istringstream in(text);
  for (std::string line; std::getline(in, line);) out.push_back(line);
  return out;
}

int cli(const std::vector<std::string>& args, std::string& err) {
  std::vector<const char*> argv = {"otfp"};
  for (const std::string& a : args) argv.push_back(a.c_str());
  std::ostringstream out, e;
  const int code = cli_main(static_cast<int>(argv.size()), argv.data(), out, e);
  err = e.str();
  return code;
}

}  // namespace

// Stopped after step 7 (2 with adaptive steps; as by SIGINT: checkpoint written, status
// "interrupted", exit code 3) and resumed: series.csv and the final particles
// are identical byte for byte to the uninterrupted run, for fixed and
// adaptive steps.
TEST(Restart, InterruptedRunResumesToTheSameSeries) {
  for (const bool adaptive : {false, true}) {
    SCOPED_TRACE(adaptive ? "adaptive BDF2" : "fixed dt");
    const fs::path full = fresh_dir("restart_full"), cut = fresh_dir("restart_cut");
    ASSERT_EQ(run_config(small_sphere(12, adaptive), full).exit_code, 0);
    // Adaptive steps grow: stop early enough to leave steps after the stop.
    const RunResult r = run_config(small_sphere(12, adaptive), cut, adaptive ? 2 : 7);
    ASSERT_EQ(r.exit_code, kExitInterrupted) << r.error;
    EXPECT_EQ(r.status, "interrupted");
    EXPECT_EQ(nlohmann::json::parse(read_text(cut / "summary.json"))["status"], "interrupted");
    EXPECT_TRUE(fs::exists(cut / "checkpoint.bin"));
    EXPECT_FALSE(fs::exists(cut / "particles_final.csv"));
    std::string err;
    ASSERT_EQ(cli({"run", "--resume", cut.string(), "--quiet"}, err), 0) << err;
    EXPECT_EQ(read_text(full / "series.csv"), read_text(cut / "series.csv"));
    EXPECT_EQ(read_text(full / "particles_final.csv"), read_text(cut / "particles_final.csv"));
    EXPECT_EQ(nlohmann::json::parse(read_text(cut / "summary.json"))["status"], "completed");
    fs::remove_all(full);
    fs::remove_all(cut);
  }
}

// A finished run extended with --set run.t_end=LATER equals the run made to
// LATER at once; resuming without a later t_end changes nothing.
TEST(Restart, FinishedRunExtendsToTheSameSeries) {
  const fs::path full = fresh_dir("extend_full"), part = fresh_dir("extend_part");
  ASSERT_EQ(run_config(small_sphere(10, false), full).exit_code, 0);
  ASSERT_EQ(run_config(small_sphere(5, false), part).exit_code, 0);
  const std::string before = read_text(part / "series.csv");
  std::string err;
  ASSERT_EQ(cli({"run", "--resume", part.string(), "--quiet"}, err), 0) << err;
  EXPECT_EQ(read_text(part / "series.csv"), before) << "nothing to do";
  ASSERT_EQ(cli({"run", "--resume", part.string(), "--quiet", "--set", "run.t_end=" + std::to_string(10 * 0.00390625)},
                err),
            0)
      << err;
  EXPECT_EQ(read_text(full / "series.csv"), read_text(part / "series.csv"));
  EXPECT_EQ(read_text(full / "particles_final.csv"), read_text(part / "particles_final.csv"));
  fs::remove_all(full);
  fs::remove_all(part);
}

// A resumed run keeps the step of the run it continues: with dt from
// run.dt_factor (dt0 = 0.1 dr^2 = 0.007368 here) a run to t_end = 0.0075
// takes 2 steps of 0.00375; extended to 0.0225 it goes on with 4 steps of
// 0.00375 (not 3 of 0.005, which the raw dt0 gives).
TEST(Restart, ExtendedRunKeepsItsStep) {
  const fs::path dir = fresh_dir("extend_dt");
  const std::string config = (kExamples / "free_space_heat.toml").string();
  std::string err;
  ASSERT_EQ(cli({"run", config, "--out", dir.string(), "--quiet", "--set", "run.t_end=0.0075"}, err), 0) << err;
  auto rows = otfp::test::read_csv(dir / "series.csv");
  ASSERT_EQ(rows.size(), 3u);
  const double dt = std::stod(rows[1].at("dt"));
  EXPECT_EQ(dt, 0.0075 / 2);
  ASSERT_EQ(cli({"run", "--resume", dir.string(), "--quiet", "--set", "run.t_end=0.0225"}, err), 0) << err;
  rows = otfp::test::read_csv(dir / "series.csv");
  ASSERT_EQ(rows.size(), 7u) << "4 more steps of the run's dt";
  for (std::size_t k = 3; k < rows.size(); ++k) EXPECT_NEAR(std::stod(rows[k].at("dt")), dt, 1e-15 * dt) << k;
  EXPECT_EQ(std::stod(rows.back().at("t")), 0.0225);
  fs::remove_all(dir);
}

// A run killed between checkpoints has rows after its last checkpoint: the
// resumed run takes them again from the checkpoint, so the series is still
// the uninterrupted one (no duplicate, no missing row).
TEST(Restart, RowsAfterTheLastCheckpointAreTakenAgain) {
  const fs::path full = fresh_dir("kill_full"), cut = fresh_dir("kill_cut");
  ASSERT_EQ(run_config(small_sphere(12, false), full).exit_code, 0);
  ASSERT_EQ(run_config(small_sphere(12, false), cut, 5).exit_code, kExitInterrupted);
  // What a SIGKILL after step 7 leaves: the rows of steps 6 and 7 without a checkpoint.
  const std::vector<std::string> rows = lines_of(read_text(full / "series.csv"));
  {
    std::ofstream f(cut / "series.csv", std::ios::app);
    f << rows[7] << "\n" << rows[8] << "\n";  // rows[0] is the header
  }
  std::string err;
  ASSERT_EQ(cli({"run", "--resume", cut.string(), "--quiet"}, err), 0) << err;
  EXPECT_EQ(read_text(full / "series.csv"), read_text(cut / "series.csv"));
  fs::remove_all(full);
  fs::remove_all(cut);
}

// A checkpoint of the state at step 0 (no stepper history; every byte but a
// few hundred is particle records) loads back into a Simulation built from
// the same configuration, for both steppers: the particle records are 56
// bytes, and a count bound of one record per 64 bytes refused them.
TEST(Restart, StepZeroCheckpointRoundTrips) {
  for (const std::string stepper : {"implicit", "explicit"}) {
    SCOPED_TRACE(stepper);
    const ConfiguredRun run(parse_config_file(kExamples / "free_space_heat.toml", {"solver.stepper=" + stepper}));
    const auto a = run.make_simulation();
    ASSERT_EQ(a->particles().size(), 400u);
    const fs::path file = fresh_dir("step0_" + stepper);
    a->save_checkpoint(file, "extra");
    const auto b = run.make_simulation();
    b->advance(run.derived().dt);  // a different state, which the load replaces
    std::string extra;
    ASSERT_NO_THROW(b->load_checkpoint(file, &extra));
    EXPECT_EQ(extra, "extra");
    EXPECT_EQ(b->step_count(), 0);
    EXPECT_EQ(b->time(), 0.0);
    EXPECT_EQ(b->particles().positions(), a->particles().positions());
    EXPECT_EQ(b->particles().ids(), a->particles().ids());
    EXPECT_EQ(b->particles().next_id(), a->particles().next_id());
    // And both continue alike.
    a->advance(run.derived().dt);
    b->advance(run.derived().dt);
    EXPECT_EQ(b->particles().positions(), a->particles().positions());
    fs::remove(file);
  }
}

// The library refuses a checkpoint of another setup (here rho_ref) naming the
// field, whatever its caller does; options a caller may change (the
// particle limit) do not matter. checkpoint_extra() reads the caller's data
// alone.
TEST(Restart, LibraryRefusesACheckpointOfAnotherSetup) {
  const ConfiguredRun one(parse_config_file(kExamples / "free_space_heat.toml", {"run.max_particles=5000"}));
  const ConfiguredRun two(parse_config_file(kExamples / "free_space_heat.toml", {"physics.rho_ref=2"}));
  const ConfiguredRun three(parse_config_file(kExamples / "free_space_heat.toml", {"run.max_particles=7000"}));
  const auto a = one.make_simulation();
  a->advance(one.derived().dt);
  const fs::path file = fresh_dir("setup_ckpt");
  a->save_checkpoint(file, "mine");
  EXPECT_EQ(otfp::Simulation::checkpoint_extra(file), "mine");
  const auto b = two.make_simulation();
  try {
    b->load_checkpoint(file);
    ADD_FAILURE() << "a checkpoint of rho_ref = 1 loaded into rho_ref = 2";
  } catch (const otfp::InvalidArgument& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find("implicit.rho_ref = 1 in the file, 2 here"), std::string::npos) << msg;
    EXPECT_EQ(msg.find('\n'), std::string::npos) << msg;
  }
  EXPECT_EQ(b->step_count(), 0) << "state kept";
  const auto c = three.make_simulation();
  EXPECT_NO_THROW(c->load_checkpoint(file));
  EXPECT_EQ(c->step_count(), 1);
  fs::remove(file);
}

// load_checkpoint on a FIFO (blocks) or a device (never ends) refuses at once.
TEST(Restart, CheckpointMustBeARegularFile) {
  const ConfiguredRun run(parse_config_file(kExamples / "free_space_heat.toml", {}));
  const auto sim = run.make_simulation();
  const fs::path fifo = fresh_dir("ckpt_fifo");
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  for (const fs::path& path : {fs::path("/dev/zero"), fifo, fs::temp_directory_path()}) {
    try {
      sim->load_checkpoint(path);
      ADD_FAILURE() << path;
    } catch (const otfp::InvalidArgument& e) {
      EXPECT_NE(std::string(e.what()).find("not a regular file"), std::string::npos) << e.what();
    }
    EXPECT_THROW(otfp::Simulation::checkpoint_extra(path), otfp::InvalidArgument);
  }
  fs::remove(fifo);
}

// An explicit-stepper run's checkpoint resumes through the CLI, and the
// resumed series equals the run made at once.
TEST(Restart, ExplicitRunResumes) {
  const fs::path full = fresh_dir("explicit_full"), part = fresh_dir("explicit_part");
  const std::string config = (kExamples / "free_space_heat.toml").string();
  std::string err;
  ASSERT_EQ(cli({"run", config, "--out", full.string(), "--quiet", "--set", "solver.stepper=explicit", "--set",
                 "run.max_steps=6"},
                err),
            0)
      << err;
  ASSERT_EQ(cli({"run", config, "--out", part.string(), "--quiet", "--set", "solver.stepper=explicit", "--set",
                 "run.max_steps=3"},
                err),
            0)
      << err;
  ASSERT_EQ(cli({"run", "--resume", part.string(), "--quiet", "--set", "run.max_steps=6"}, err), 0) << err;
  EXPECT_EQ(read_text(full / "series.csv"), read_text(part / "series.csv"));
  EXPECT_EQ(read_text(full / "particles_final.csv"), read_text(part / "particles_final.csv"));
  fs::remove_all(full);
  fs::remove_all(part);
}

// --resume refuses, with one line and exit code 2, what it cannot continue.
TEST(Restart, ResumeRefusesWhatItCannotContinue) {
  const fs::path dir = fresh_dir("resume_bad");
  ASSERT_EQ(run_config(small_sphere(3, false), dir).exit_code, 0);
  std::string err;
  struct Bad {
    std::vector<std::string> args;
    std::string starts;
  };
  const std::vector<Bad> bad = {
      {{"run", "--resume", dir.string(), "--set", "solver.backend=nlopt"}, "otfp: error: --set solver.backend=nlopt:"},
      {{"run", "--resume", (dir / "nothing").string()}, "otfp: error: --resume = "},
      {{"run", (kExamples / "sphere_dirichlet.toml").string(), "--resume", dir.string()}, "otfp: error: --resume DIR"},
      {{"run", "--out", dir.string()}, "otfp: error: CONFIG is required"},
  };
  for (const Bad& b : bad) {
    EXPECT_EQ(cli(b.args, err), 2) << b.starts;
    EXPECT_EQ(err.rfind(b.starts, 0), 0u) << err;
    EXPECT_EQ(std::count(err.begin(), err.end(), '\n'), 1) << err;
  }
  // The refusal of a --set lists every key a resume may change.
  cli(bad[0].args, err);
  for (const std::string& key : resume_keys()) EXPECT_NE(err.find(key), std::string::npos) << key << " in " << err;
  fs::remove_all(dir);
}

namespace {

// Every file of a directory and its bytes.
std::map<std::string, std::string> files_of(const fs::path& dir) {
  std::map<std::string, std::string> out;
  for (const fs::directory_entry& e : fs::directory_iterator(dir)) out[e.path().filename().string()] = read_text(e.path());
  return out;
}

void rewrite(const fs::path& file, const std::string& bytes) {
  std::ofstream f(file, std::ios::binary | std::ios::trunc);
  f << bytes;
}

}  // namespace

// A resume that cannot continue the run is refused before anything is
// written: the directory stays byte for byte as it was (no summary.json
// rewritten as "failed", no particles_failed.vtp), exit code 2, one line
// naming the file and what is wrong with it.
TEST(Restart, RefusedResumeLeavesTheRunUntouched) {
  const fs::path dir = fresh_dir("resume_untouched");
  ASSERT_EQ(run_config(small_sphere(3, false), dir).exit_code, 0);
  const std::map<std::string, std::string> pristine = files_of(dir);
  const std::string ckpt = pristine.at("checkpoint.bin"), series = pristine.at("series.csv");
  struct Case {
    std::string what;
    std::function<void()> damage;
    std::string t_end;
    std::vector<std::string> mentions;
  };
  const std::string later = "run.t_end=" + std::to_string(6 * 0.00390625);
  const std::vector<Case> cases = {
      {"truncated checkpoint", [&] { rewrite(dir / "checkpoint.bin", ckpt.substr(0, ckpt.size() - 100)); }, later,
       {"checkpoint.bin", "checksum"}},
      {"flipped bit", [&] { std::string b = ckpt; b[b.size() / 2] ^= 0x01; rewrite(dir / "checkpoint.bin", b); },
       later, {"checkpoint.bin", "checksum"}},
      {"t_end before the checkpoint", [] {}, "run.t_end=0.005", {"run.t_end = 0.005", "checkpoint.bin", "t = "}},
      {"garbage row in series.csv",
       [&] { rewrite(dir / "series.csv", series.substr(0, series.find('\n') + 1) + "garbage\n" +
                                          series.substr(series.find('\n') + 1)); },
       later, {"series.csv", "line 2"}},
      {"garbage row at the end of series.csv", [&] { rewrite(dir / "series.csv", series + "1,2\n"); }, later,
       {"series.csv", "line " + std::to_string(std::count(series.begin(), series.end(), '\n') + 1)}},
      {"rows missing in series.csv", [&] { rewrite(dir / "series.csv", series.substr(0, series.rfind('\n', series.size() - 2) + 1)); },
       later, {"series.csv", "before the checkpoint's step"}},
      {"missing series.csv", [&] { fs::remove(dir / "series.csv"); }, later, {"series.csv"}},
      {"missing timing.csv", [&] { fs::remove(dir / "timing.csv"); }, later, {"timing.csv"}},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.what);
    for (const auto& [name, bytes] : pristine) rewrite(dir / name, bytes);
    c.damage();
    const std::map<std::string, std::string> before = files_of(dir);
    std::string err;
    EXPECT_EQ(cli({"run", "--resume", dir.string(), "--quiet", "--set", c.t_end}, err), 2) << err;
    EXPECT_EQ(std::count(err.begin(), err.end(), '\n'), 1) << err;
    EXPECT_EQ(err.rfind("otfp: error: ", 0), 0u) << err;
    for (const std::string& m : c.mentions) EXPECT_NE(err.find(m), std::string::npos) << m << " in " << err;
    EXPECT_TRUE(files_of(dir) == before) << "the run's directory changed";
  }
  // Put back, the run continues.
  for (const auto& [name, bytes] : pristine) rewrite(dir / name, bytes);
  std::string err;
  EXPECT_EQ(cli({"run", "--resume", dir.string(), "--quiet", "--set", later}, err), 0) << err;
  fs::remove_all(dir);
}

// A checkpoint carries the resolved configuration it was written with; a
// resume whose configuration differs in any key a resume may not change (a
// foreign checkpoint of the same dimension and patch count, or an edited
// DIR/config.toml) is refused naming the key, and changes nothing.
TEST(Restart, ResumeRefusesAnotherConfiguration) {
  const fs::path a = fresh_dir("fingerprint_a"), b = fresh_dir("fingerprint_b");
  ASSERT_EQ(run_config({"particles.n_inf=120", "run.max_steps=2"}, a).exit_code, 0);
  ASSERT_EQ(run_config({"particles.n_inf=150", "run.max_steps=2"}, b).exit_code, 0);
  const std::map<std::string, std::string> pristine = files_of(b);
  fs::copy_file(a / "checkpoint.bin", b / "checkpoint.bin", fs::copy_options::overwrite_existing);
  std::map<std::string, std::string> before = files_of(b);
  std::string err;
  EXPECT_EQ(cli({"run", "--resume", b.string(), "--quiet", "--set", "run.max_steps=4"}, err), 2) << err;
  EXPECT_NE(err.find("particles.n_inf = 150"), std::string::npos) << err;
  EXPECT_NE(err.find("120"), std::string::npos) << err;
  EXPECT_EQ(std::count(err.begin(), err.end(), '\n'), 1) << err;
  EXPECT_TRUE(files_of(b) == before);

  // kappa edited in DIR/config.toml.
  for (const auto& [name, bytes] : pristine) rewrite(b / name, bytes);
  std::string toml = pristine.at("config.toml");
  const std::size_t at = toml.find("kappa = 1");
  ASSERT_NE(at, std::string::npos) << toml;
  rewrite(b / "config.toml", toml.replace(at, 9, "kappa = 2"));
  before = files_of(b);
  EXPECT_EQ(cli({"run", "--resume", b.string(), "--quiet", "--set", "run.max_steps=4"}, err), 2) << err;
  EXPECT_NE(err.find("physics.kappa = 2"), std::string::npos) << err;
  EXPECT_NE(err.find("config.toml"), std::string::npos) << err;
  EXPECT_TRUE(files_of(b) == before);

  // Unchanged, with keys a resume may change, it continues.
  for (const auto& [name, bytes] : pristine) rewrite(b / name, bytes);
  EXPECT_EQ(cli({"run", "--resume", b.string(), "--quiet", "--set", "run.max_steps=4", "--set", "run.threads=2",
                 "--set", "run.max_particles=100000"},
                err),
            0)
      << err;
  fs::remove_all(a);
  fs::remove_all(b);
}

// particles.fill = "file": a run starts from another run's final particles
// (ids, widths, masses and birth times as written), and bad files are
// refused before any output exists.
TEST(FillFile, RunStartsFromTheParticlesOfAFile) {
  const fs::path first = fresh_dir("fill_first"), second = fresh_dir("fill_second");
  const std::vector<std::string> papers = {"particles.n_inf=200", "run.max_steps=3", "treatment.preset=papers"};
  ASSERT_EQ(run_config(papers, first).exit_code, 0);
  const auto final_rows = otfp::test::read_csv(first / "particles_final.csv");
  double mass = 0.0;
  for (const auto& row : final_rows) mass += std::stod(row.at("mass"));
  std::vector<std::string> sets = papers;
  sets.insert(sets.end(), {"particles.fill=file", "particles.fill_file=" + (first / "particles_final.csv").string()});
  ASSERT_EQ(run_config(sets, second).exit_code, 0);
  const auto series = otfp::test::read_csv(second / "series.csv");
  EXPECT_EQ(std::stoul(series.at(0).at("n_particles")), final_rows.size());
  EXPECT_NEAR(std::stod(series.at(0).at("mass_total")), mass, 1e-12 * mass);
  EXPECT_EQ(std::stoul(series.at(0).at("inserted")), 0u);
  fs::remove_all(second);

  // Bad files: exit 2, one line naming particles.fill_file, nothing written.
  const fs::path bad = first / "bad.csv";
  for (const std::string& content : {std::string("id,x,y,z,width_s,mass\n0,0,0,0,-1,0.01\n"),
                                     std::string("id,x,y,z,width_s,mass\n0,5,0,0,0.1,0.01\n"),
                                     std::string("x,y\n0,0\n")}) {
    {
      std::ofstream f(bad);
      f << content;
    }
    std::string err;
    EXPECT_EQ(cli({"run", (kExamples / "sphere_dirichlet.toml").string(), "--out", second.string(), "--set",
                   "particles.fill=file", "--set", "particles.fill_file=" + bad.string()},
                  err),
              2)
        << content;
    EXPECT_EQ(err.rfind("otfp: error: particles.fill_file", 0), 0u) << err;
    EXPECT_EQ(std::count(err.begin(), err.end(), '\n'), 1) << err;
    EXPECT_FALSE(fs::exists(second));
  }
  fs::remove_all(first);
}
