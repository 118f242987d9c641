#pragma once
// Output files: atomic whole-file writes, append-only CSV rows, and VTK XML
// PolyData (.vtp, raw appended binary) with its ParaView collection (.pvd).
#include <cstdint>
#include <filesystem>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "otfp/particles.hpp"

namespace otfp::app {

// Writes `content` to a temporary file next to `path`, then renames it over
// `path`: readers see the old or the new file, never a partial one.
void write_file_atomic(const std::filesystem::path& path, std::string_view content);

// A text file that grows by whole lines: created atomically with its header,
// then every append() is one write(2) on an O_APPEND descriptor, so a killed
// run leaves only complete lines.
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

 private:
  int fd_ = -1;
  std::filesystem::path path_;
};

// Region flag of a particle in the VTK output and the counts.
enum Region : std::int32_t { kInside = 0, kBuffer = 1, kElsewhere = 2 };

// VTK XML PolyData of the particles at time t: points, one vertex cell per
// particle, point data mass, beta, age = t - birth, id, region.
std::string vtp_document(const ParticleSet& particles, double t, const std::vector<std::int32_t>& region);

// ParaView collection of (time, file name) entries.
std::string pvd_document(const std::vector<std::pair<double, std::string>>& entries);

}  // namespace otfp::app
