// The `otfp` binary on bad paths and bad input (issue 13): what it refuses
// before any work, and the exit codes 2 (bad input), 1 (failed run) and
// 3 (interrupted).
#include <gtest/gtest.h>
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
