// The `otfp` binary on bad paths and bad input (issue 13): what it refuses
// before any work, and the exit codes 2 (bad input), 1 (failed run) and
// 3 (interrupted).
#include <gtest/gtest.h>
#include <fcntl.h>
#include <sys/file.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "app_test_support.hpp"

namespace fs = std::filesystem;
using otfp::test::fresh_dir;
using otfp::test::read_text;

namespace {

const fs::path kSource = OTFP_SOURCE_DIR;
const fs::path kExamples = kSource / "examples";
const std::string kExample = (kExamples / "sphere_dirichlet.toml").string();
// A run of a few steps that takes well under a second.
const std::string kShort = " --quiet --set run.max_steps=2 --set particles.n_inf=100";

// Runs the real binary with `args` (shell words); returns its exit code,
// stdout + stderr in `output`.
int run_binary(const std::string& args, std::string& output) {
  const fs::path file = fresh_dir("robust_out");
  const std::string cmd = std::string(OTFP_CLI_PATH) + " " + args + " >" + file.string() + " 2>&1";
  const int status = std::system(cmd.c_str());
  output = read_text(file);
  fs::remove(file);
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

long lines(const std::string& text) { return static_cast<long>(std::count(text.begin(), text.end(), '\n')); }

bool contains(const std::string& text, const std::string& part) { return text.find(part) != std::string::npos; }

}  // namespace

// CONFIG must be a readable regular file: a directory or a file that fails to
// read (/proc/self/mem) used to read as an empty configuration and run the
// defaults with exit code 0.
TEST(CliRobustness, ConfigMustBeAReadableRegularFile) {
  const fs::path out = fresh_dir("robust_config");
  std::string text;
  for (const std::string& config : {kExamples.string(), std::string("/proc/self/mem")}) {
    SCOPED_TRACE(config);
    EXPECT_EQ(run_binary("run " + config + " --out " + out.string() + " --quiet", text), 2);
    EXPECT_EQ(text.rfind("otfp: error: cannot read CONFIG: " + config + ": ", 0), 0u) << text;
    EXPECT_EQ(lines(text), 1) << text;
    EXPECT_FALSE(fs::exists(out)) << "nothing may be written for a bad CONFIG";
    EXPECT_EQ(run_binary("check " + config, text), 2);
    EXPECT_EQ(text.rfind("otfp: error: cannot read CONFIG: " + config + ": ", 0), 0u) << text;
    EXPECT_EQ(lines(text), 1) << text;
  }
  EXPECT_EQ(run_binary("run " + kExamples.string() + " --out " + out.string(), text), 2);
  EXPECT_TRUE(contains(text, "not a regular file")) << text;
  const std::string missing = (kExamples / "no_such_file.toml").string();
  EXPECT_EQ(run_binary("check " + missing, text), 2);
  EXPECT_TRUE(contains(text, missing) && contains(text, "No such file")) << text;
  EXPECT_EQ(lines(text), 1) << text;
}

// --out "" is refused, and an --out that cannot be written (below a regular
// file: fails even for root; a read-only directory when not root) is found
// before any work (exit 2), not after the initial fill (exit 1).
TEST(CliRobustness, OutMustBeAWritableNonEmptyPath) {
  std::string text;
  EXPECT_EQ(run_binary("run " + kExample + " --out ''" + kShort, text), 2);
  EXPECT_EQ(text.rfind("otfp: error: --out", 0), 0u) << text;
  EXPECT_TRUE(contains(text, "must be a non-empty path")) << text;
  EXPECT_EQ(lines(text), 1) << text;
  EXPECT_EQ(run_binary("run --resume ''", text), 2);
  EXPECT_EQ(text, "otfp: error: --resume = \"\": must be a non-empty path\n");
  EXPECT_EQ(run_binary("sweep " + kExample + " --vary run.t_end=0.1 --out ''" + kShort, text), 2);
  EXPECT_EQ(text.rfind("otfp: error: --out", 0), 0u) << text;
  EXPECT_TRUE(contains(text, "must be a non-empty path")) << text;

  const fs::path base = fresh_dir("robust_out_base");
  fs::create_directories(base);
  const fs::path file = base / "somefile";
  std::ofstream(file) << "not a directory\n";
  const fs::path below_file = file / "out";
  EXPECT_EQ(run_binary("run " + kExample + " --out " + below_file.string() + kShort, text), 2);
  EXPECT_EQ(text.rfind("otfp: error: --out = \"" + below_file.string() + "\": ", 0), 0u) << text;
  EXPECT_EQ(lines(text), 1) << text;
  EXPECT_EQ(read_text(file), "not a directory\n");

  if (::geteuid() != 0) {  // permission bits do not stop root
    const fs::path ro = base / "readonly";
    fs::create_directories(ro);
    fs::permissions(ro, fs::perms::owner_read | fs::perms::owner_exec);
    EXPECT_EQ(run_binary("run " + kExample + " --out " + (ro / "out").string() + kShort, text), 2);
    EXPECT_EQ(lines(text), 1) << text;
    EXPECT_EQ(run_binary("run " + kExample + " --out " + ro.string() + kShort, text), 2);
    EXPECT_EQ(lines(text), 1) << text;
    fs::permissions(ro, fs::perms::owner_all);
    EXPECT_TRUE(fs::is_empty(ro));
  }
  fs::remove_all(base);
}

// A directory that holds an earlier run is refused unless --overwrite (which
// clears the old outputs, and only those) or --resume; a lock file keeps a
// second run out of a directory in use.
TEST(CliRobustness, OutputDirectoryDiscipline) {
  const fs::path dir = fresh_dir("robust_discipline");
  std::string text;
  ASSERT_EQ(run_binary("run " + kExample + " --out " + dir.string() + kShort, text), 0) << text;
  EXPECT_FALSE(fs::exists(dir / ".otfp.lock")) << "the lock is removed at the end";
  const std::string summary = read_text(dir / "summary.json");

  // Again into the same directory: refused, nothing touched.
  EXPECT_EQ(run_binary("run " + kExample + " --out " + dir.string() + kShort, text), 2);
  EXPECT_EQ(text.rfind("otfp: error: --out = \"" + dir.string() + "\": ", 0), 0u) << text;
  EXPECT_TRUE(contains(text, "--overwrite") && contains(text, "--resume")) << text;
  EXPECT_EQ(lines(text), 1) << text;
  EXPECT_EQ(read_text(dir / "summary.json"), summary);
  EXPECT_FALSE(fs::exists(dir / ".otfp.lock"));
  EXPECT_EQ(run_binary("run --resume " + dir.string() + " --overwrite --quiet", text), 2);
  EXPECT_TRUE(contains(text, "--overwrite")) << text;
  EXPECT_EQ(lines(text), 1) << text;

  // --overwrite clears the old outputs (stale snapshots and temporary files
  // too) and leaves unknown files alone.
  std::ofstream(dir / "notes.txt") << "mine\n";
  std::ofstream(dir / "particles_00077.vtp") << "stale snapshot\n";
  std::ofstream(dir / "summary.json.tmp4242") << "stale temporary\n";
  std::ofstream(dir / "particles.csv") << "not an otfp output name\n";
  ASSERT_EQ(run_binary("run " + kExample + " --out " + dir.string() + kShort + " --overwrite", text), 0) << text;
  EXPECT_EQ(read_text(dir / "notes.txt"), "mine\n");
  EXPECT_TRUE(fs::exists(dir / "particles.csv"));
  EXPECT_FALSE(fs::exists(dir / "particles_00077.vtp"));
  EXPECT_FALSE(fs::exists(dir / "summary.json.tmp4242"));
  EXPECT_TRUE(fs::exists(dir / "summary.json") && fs::exists(dir / "series.csv") && fs::exists(dir / "checkpoint.bin"));
  EXPECT_NE(read_text(dir / "particles.pvd").find("particles_00000.vtp"), std::string::npos);
  EXPECT_EQ(read_text(dir / "particles.pvd").find("particles_00077.vtp"), std::string::npos);

  // A directory in use (its lock held, here by this process) is refused.
  {
    const int fd = ::open((dir / ".otfp.lock").c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
    ASSERT_GE(fd, 0);
    ASSERT_EQ(::flock(fd, LOCK_EX | LOCK_NB), 0);
    EXPECT_EQ(run_binary("run " + kExample + " --out " + dir.string() + kShort + " --overwrite", text), 2);
    EXPECT_EQ(text.rfind("otfp: error: --out = \"" + dir.string() + "\": ", 0), 0u) << text;
    EXPECT_TRUE(contains(text, "another otfp run")) << text;
    EXPECT_EQ(lines(text), 1) << text;
    EXPECT_EQ(run_binary("run --resume " + dir.string() + " --quiet --set run.max_steps=3", text), 2);
    EXPECT_TRUE(contains(text, "another otfp run")) << text;
    ::close(fd);
  }
  // A stale lock file (a killed run's, not locked) does not stop a run.
  ASSERT_TRUE(fs::exists(dir / ".otfp.lock"));
  EXPECT_EQ(run_binary("run --resume " + dir.string() + " --quiet --set run.max_steps=3", text), 0) << text;
  EXPECT_FALSE(fs::exists(dir / ".otfp.lock"));
  fs::remove_all(dir);

  // A non-empty directory without an earlier run is fine.
  fs::create_directories(dir);
  std::ofstream(dir / "notes.txt") << "mine\n";
  EXPECT_EQ(run_binary("run " + kExample + " --out " + dir.string() + kShort, text), 0) << text;
  fs::remove_all(dir);
}

// A sweep run again into its own directory reruns every point.
TEST(CliRobustness, SweepRerunsIntoItsDirectory) {
  const fs::path dir = fresh_dir("robust_sweep");
  std::string text;
  const std::string args = "sweep " + kExample + " --vary run.max_steps=1,2 --out " + dir.string() +
                           " --set particles.n_inf=100 --quiet";
  for (int pass = 0; pass < 2; ++pass) {
    SCOPED_TRACE(pass);
    EXPECT_EQ(run_binary(args, text), 0) << text;
    const auto rows = otfp::test::read_csv(dir / "runs.csv");
    ASSERT_EQ(rows.size(), 2u);
    for (const auto& row : rows) EXPECT_EQ(row.at("status"), "completed") << row.at("error");
  }
  fs::remove_all(dir);
}
