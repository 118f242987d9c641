#pragma once
// The output directory of an `otfp run` (the command line and the Python
// module's ConfiguredRun.run share it): its lock and the refusal of an
// earlier run's directory.
#include <filesystem>
#include <string>
#include <string_view>

namespace otfp::app {

// The lock of an output directory: DIR/.otfp.lock, flock(2)ed for the whole
// run, removed at the end. A run killed outright leaves the file but not the
// lock (the kernel drops it with the process), so a stale file stops nobody.
class OutputLock {
 public:
  OutputLock() = default;
  OutputLock(const OutputLock&) = delete;
  OutputLock& operator=(const OutputLock&) = delete;
  ~OutputLock();
  // "" when taken, else why not.
  std::string acquire(const std::filesystem::path& dir);

 private:
  int fd_ = -1;
  std::filesystem::path path_;
};

// The run's output directory, made ready before any work: created (the
// configuration has been accepted) and locked, which also shows that it can
// be written, so that an unusable --out is bad input (exit 2), not a run that
// fails after its initial fill. Then an earlier run there (summary.json,
// series.csv or checkpoint.bin) is refused unless the run resumes it or
// --overwrite clears its files first. Returns why the directory cannot be
// used, or "". `overwrite_name`: how the caller spells the overwrite option
// in the messages (the Python module's is "overwrite=True").
std::string prepare_out_dir(const std::filesystem::path& dir, bool resume, bool overwrite, OutputLock& lock,
                            std::string_view overwrite_name = "--overwrite");

}  // namespace otfp::app
