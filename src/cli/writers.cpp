#include "otfp_app/writers.hpp"

#include <fcntl.h>
#include <unistd.h>

#include <fmt/format.h>

#include <bit>
#include <cerrno>
#include <cstring>
#include <fstream>
#include <stdexcept>

namespace otfp::app {

static_assert(std::endian::native == std::endian::little, "the VTK writer declares LittleEndian data");

namespace {

[[noreturn]] void io_error(const std::string& what, const std::filesystem::path& path) {
  throw std::runtime_error(what + " '" + path.string() + "': " + std::strerror(errno));
}

void write_all(int fd, std::string_view data, const std::filesystem::path& path) {
  while (!data.empty()) {
    const ssize_t n = ::write(fd, data.data(), data.size());
    if (n < 0) {
      if (errno == EINTR) continue;
      io_error("cannot write", path);
    }
    data.remove_prefix(static_cast<std::size_t>(n));
  }
}

template <class T>
void append_block(std::string& out, const std::vector<T>& values) {
  const std::uint64_t bytes = values.size() * sizeof(T);
  out.append(reinterpret_cast<const char*>(&bytes), sizeof bytes);
  if (bytes) out.append(reinterpret_cast<const char*>(values.data()), bytes);
}

}  // namespace

void write_file_atomic(const std::filesystem::path& path, std::string_view content) {
  std::filesystem::path tmp = path;
  tmp += fmt::format(".tmp{}", ::getpid());
  const int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) io_error("cannot create", tmp);
  try {
    write_all(fd, content, tmp);
  } catch (...) {
    ::close(fd);
    ::unlink(tmp.c_str());
    throw;
  }
  if (::close(fd) != 0) io_error("cannot close", tmp);
  if (::rename(tmp.c_str(), path.c_str()) != 0) {
    ::unlink(tmp.c_str());
    io_error("cannot rename onto", path);
  }
}

AppendFile::AppendFile(const std::filesystem::path& path, std::string_view header) : path_(path) {
  write_file_atomic(path, header);
  fd_ = ::open(path.c_str(), O_WRONLY | O_APPEND | O_CLOEXEC);
  if (fd_ < 0) io_error("cannot open", path);
}

AppendFile::~AppendFile() {
  if (fd_ >= 0) ::close(fd_);
}

AppendFile::AppendFile(AppendFile&& other) noexcept : fd_(other.fd_), path_(std::move(other.path_)) {
  other.fd_ = -1;
}

AppendFile& AppendFile::operator=(AppendFile&& other) noexcept {
  if (this != &other) {
    if (fd_ >= 0) ::close(fd_);
    fd_ = other.fd_;
    path_ = std::move(other.path_);
    other.fd_ = -1;
  }
  return *this;
}

void AppendFile::append(std::string_view lines) {
  if (fd_ < 0) throw std::runtime_error("AppendFile: not open");
  write_all(fd_, lines, path_);
}

std::string vtp_document(const ParticleSet& ps, double t, const std::vector<std::int32_t>& region) {
  const std::size_t n = ps.size();
  if (region.size() != n) throw std::invalid_argument("vtp_document: one region flag per particle expected");
  std::vector<double> pos(3 * n), mass(ps.masses()), beta(n), age(n);
  std::vector<std::int64_t> id(ps.ids().begin(), ps.ids().end()), conn(n), offsets(n);
  for (std::size_t p = 0; p < n; ++p) {
    for (int k = 0; k < 3; ++k) pos[3 * p + k] = ps.positions()[p][k];
    beta[p] = ps.beta(p);
    age[p] = t - ps.birth_times()[p];
    conn[p] = static_cast<std::int64_t>(p);
    offsets[p] = static_cast<std::int64_t>(p + 1);
  }

  // Appended blocks: UInt64 byte count, then the raw little-endian values.
  std::string data;
  std::vector<std::uint64_t> offset;
  auto add = [&](const auto& v) {
    offset.push_back(data.size());
    append_block(data, v);
  };
  add(mass);
  add(beta);
  add(age);
  add(id);
  add(region);
  add(pos);
  add(conn);
  add(offsets);

  std::string xml;
  xml += "<?xml version=\"1.0\"?>\n";
  xml += "<VTKFile type=\"PolyData\" version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"UInt64\">\n";
  xml += "  <PolyData>\n";
  xml += "    <FieldData>\n";
  xml += fmt::format(
      "      <DataArray type=\"Float64\" Name=\"TimeValue\" NumberOfTuples=\"1\" format=\"ascii\">{}</DataArray>\n", t);
  xml += "    </FieldData>\n";
  xml += fmt::format(
      "    <Piece NumberOfPoints=\"{0}\" NumberOfVerts=\"{0}\" NumberOfLines=\"0\" NumberOfStrips=\"0\" "
      "NumberOfPolys=\"0\">\n",
      n);
  xml += "      <PointData Scalars=\"age\">\n";
  const char* names[] = {"mass", "beta", "age", "id", "region"};
  const char* types[] = {"Float64", "Float64", "Float64", "Int64", "Int32"};
  for (int i = 0; i < 5; ++i)
    xml += fmt::format("        <DataArray type=\"{}\" Name=\"{}\" format=\"appended\" offset=\"{}\"/>\n", types[i],
                       names[i], offset[static_cast<std::size_t>(i)]);
  xml += "      </PointData>\n";
  xml += "      <Points>\n";
  xml += fmt::format(
      "        <DataArray type=\"Float64\" Name=\"position\" NumberOfComponents=\"3\" format=\"appended\" "
      "offset=\"{}\"/>\n",
      offset[5]);
  xml += "      </Points>\n";
  xml += "      <Verts>\n";
  xml += fmt::format(
      "        <DataArray type=\"Int64\" Name=\"connectivity\" format=\"appended\" offset=\"{}\"/>\n", offset[6]);
  xml += fmt::format("        <DataArray type=\"Int64\" Name=\"offsets\" format=\"appended\" offset=\"{}\"/>\n",
                     offset[7]);
  xml += "      </Verts>\n";
  xml += "    </Piece>\n";
  xml += "  </PolyData>\n";
  xml += "  <AppendedData encoding=\"raw\">\n   _";
  xml += data;
  xml += "\n  </AppendedData>\n</VTKFile>\n";
  return xml;
}

std::string pvd_document(const std::vector<std::pair<double, std::string>>& entries) {
  std::string xml = "<?xml version=\"1.0\"?>\n";
  xml += "<VTKFile type=\"Collection\" version=\"0.1\" byte_order=\"LittleEndian\">\n  <Collection>\n";
  for (const auto& [t, file] : entries)
    xml += fmt::format("    <DataSet timestep=\"{}\" group=\"\" part=\"0\" file=\"{}\"/>\n", t, file);
  xml += "  </Collection>\n</VTKFile>\n";
  return xml;
}

}  // namespace otfp::app
