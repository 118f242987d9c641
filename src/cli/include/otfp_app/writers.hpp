#pragma once
// Output files: atomic whole-file writes and append-only CSV rows. The VTK
// documents (vtp_document, pvd_document) are the library's otfp/vtk.hpp,
// included here so that otfp::app code keeps calling them unqualified.
#include <cstdint>
#include <filesystem>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "otfp/particles.hpp"
#include "otfp/vtk.hpp"

namespace otfp::app {

// Writes `content` to a temporary file next to `path`, then renames it over
// `path`: readers see the old or the new file, never a partial one.
void write_file_atomic(const std::filesystem::path& path, std::string_view content);

// A text file that grows by whole lines: created atomically with its header,
// then every append() is one write(2) on an O_APPEND descriptor, so a killed
// run leaves only complete lines. A short or failed write (a full disk, a
// file-size limit) cuts the file back to its last complete append and throws
// ("... cut back to its last complete row").
class AppendFile {
 public:
  AppendFile() = default;
  AppendFile(const std::filesystem::path& path, std::string_view header);
  ~AppendFile();
  AppendFile(AppendFile&& other) noexcept;
  AppendFile& operator=(AppendFile&& other) noexcept;
  AppendFile(const AppendFile&) = delete;
  AppendFile& operator=(const AppendFile&) = delete;
  void append(std::string_view lines);
  bool is_open() const { return fd_ >= 0; }
  // Bytes in the file after the last complete append; truncate(size) cuts
  // it back (e.g. a row whose partner row in another file failed).
  std::uint64_t size() const { return size_; }
  void truncate(std::uint64_t size);

 private:
  int fd_ = -1;
  std::filesystem::path path_;
  std::uint64_t size_ = 0;
};

// A run stopped outright by a signal (a second SIGINT/SIGTERM while a step is
// still running) cannot unwind; a handler calls kill_time_cleanup(), which is
// async-signal-safe (open, write, rename, unlink on prepared buffers): it
// removes the temporary file write_file_atomic is writing, if any, and the
// paths given to set_kill_time_paths (e.g. the checkpoint's temporary file,
// the lock file), and puts the last summary given to set_kill_time_summary
// in place of the summary file.
void set_kill_time_paths(std::vector<std::filesystem::path> paths);
void set_kill_time_summary(const std::filesystem::path& path, std::string content);
void clear_kill_time_state();
void kill_time_cleanup() noexcept;

// Region flag of a particle in the VTK output and the counts.
enum Region : std::int32_t { kInside = 0, kBuffer = 1, kElsewhere = 2 };

}  // namespace otfp::app
