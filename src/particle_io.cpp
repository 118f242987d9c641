#include "otfp/particle_io.hpp"

#include "file_read.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <fmt/format.h>

#include <algorithm>
#include <bit>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstring>
#include <fstream>
#include <iterator>
#include <optional>
#include <sstream>
#include <unordered_map>

namespace otfp {

std::string particles_csv(const ParticleSet& particles, const std::vector<std::int32_t>& region) {
  const std::size_t n = particles.size();
  require(region.empty() || region.size() == n, "particles_csv: region size", static_cast<double>(region.size()),
          fmt::format("must be 0 or the number of particles ({})", n));
  // The bytes of the command-line tool's particles_final.csv.
  std::string text = "id,x,y,z,width_s,beta,mass,birth_time,region\n";
  for (std::size_t p = 0; p < n; ++p) {
    const Vec3& x = particles.positions()[p];
    const double sp = particles.widths()[p];
    text += fmt::format("{},{},{},{},{},{},{},{},{}\n", particles.ids()[p], x[0], x[1], x[2], sp, 1.0 / (sp * sp),
                        particles.masses()[p], particles.birth_times()[p], region.empty() ? 0 : region[p]);
  }
  return text;
}

namespace {

[[noreturn]] void fail(const std::string& where, std::string_view value, const std::string& rule) {
  throw InvalidArgument(fmt::format("{} = '{}': {}", where, value, rule));
}

std::string_view trimmed(std::string_view s) {
  while (!s.empty() && (s.front() == ' ' || s.front() == '\t')) s.remove_prefix(1);
  while (!s.empty() && (s.back() == ' ' || s.back() == '\t' || s.back() == '\r')) s.remove_suffix(1);
  return s;
}

std::optional<double> parse_double(std::string_view s) {
  double v = 0.0;
  const auto [end, ec] = std::from_chars(s.data(), s.data() + s.size(), v);
  if (ec != std::errc() || end != s.data() + s.size() || s.empty()) return std::nullopt;
  return v;
}

// Columns of one particle file before they become a ParticleSet.
struct Columns {
  std::vector<Vec3> x;
  std::vector<double> width, beta, mass, birth;
  std::vector<ParticleId> id;
  bool has_width = false, has_id = false;
};

// Where a value is, for messages: "particle file 'f' line 7 column mass" (CSV,
// lines[i] is the line of particle i) or "particle file 'f' array 'mass' point 3" (VTP).
struct Locator {
  std::string file;
  const std::vector<std::size_t>* lines = nullptr;  // null: a VTP
  std::string at(std::size_t i) const {
    return lines ? fmt::format("line {}", (*lines)[i]) : fmt::format("point {}", i);
  }
  std::string operator()(std::size_t i, const std::string& name) const {
    if (lines) return fmt::format("particle file '{}' {} column {}", file, at(i), name);
    const bool axis = name == "x" || name == "y" || name == "z";
    return fmt::format("particle file '{}' array '{}' {}", file, axis ? "position." + name : name, at(i));
  }
};

ParticleSet build(const Columns& c, int dim, const Locator& where) {
  ParticleSet ps(dim);
  const std::size_t n = c.mass.size();
  ps.reserve(n);
  std::unordered_map<ParticleId, std::size_t> first;  // id -> particle that has it
  static const char* kAxis[3] = {"x", "y", "z"};
  for (std::size_t i = 0; i < n; ++i) {
    for (int k = 0; k < 3; ++k) {
      const double v = c.x[i][k];
      if (!std::isfinite(v)) fail(where(i, kAxis[k]), fmt::format("{}", v), "must be finite");
      if (k >= dim && v != 0.0) fail(where(i, kAxis[k]), fmt::format("{}", v), fmt::format("must be 0 for dim = {}", dim));
    }
    const double m = c.mass[i];
    if (!std::isfinite(m) || m <= 0.0) fail(where(i, "mass"), fmt::format("{}", m), "must be finite and > 0");
    double s = 0.0;
    if (c.has_width) {
      s = c.width[i];
      if (!std::isfinite(s) || s <= 0.0) fail(where(i, "width_s"), fmt::format("{}", s), "must be finite and > 0");
    } else {
      const double b = c.beta[i];
      if (!std::isfinite(b) || b <= 0.0) fail(where(i, "beta"), fmt::format("{}", b), "must be finite and > 0");
      s = 1.0 / std::sqrt(b);
    }
    const double t0 = c.birth.empty() ? 0.0 : c.birth[i];
    if (!std::isfinite(t0)) fail(where(i, "birth_time"), fmt::format("{}", t0), "must be finite");
    if (c.has_id) {
      const ParticleId id = c.id[i];
      if (id < 0) fail(where(i, "id"), fmt::format("{}", id), "must be >= 0");
      if (id > kMaxParticleId) fail(where(i, "id"), fmt::format("{}", id), fmt::format("must be <= 2^62 = {}", kMaxParticleId));
      const auto [it, fresh] = first.emplace(id, i);
      if (!fresh) fail(where(i, "id"), fmt::format("{}", id), "duplicates the id on " + where.at(it->second));
      ps.add_with_id(id, c.x[i], s, m, t0);
    } else {
      ps.add(c.x[i], s, m, t0);
    }
  }
  return ps;
}

ParticleSet read_csv(const std::string& text, const std::string& file, int dim) {
  std::vector<std::pair<std::size_t, std::string_view>> lines;  // (line number, content), blank lines dropped
  std::string_view rest(text);
  for (std::size_t number = 1; !rest.empty(); ++number) {
    const std::size_t eol = rest.find('\n');
    const std::string_view line = trimmed(rest.substr(0, eol));
    rest = eol == std::string_view::npos ? std::string_view() : rest.substr(eol + 1);
    if (!line.empty()) lines.emplace_back(number, line);
  }
  if (lines.empty()) fail("particle file", file, "is empty");

  auto split = [](std::string_view line) {
    std::vector<std::string_view> fields;
    for (;;) {
      const std::size_t comma = line.find(',');
      fields.push_back(trimmed(line.substr(0, comma)));
      if (comma == std::string_view::npos) return fields;
      line.remove_prefix(comma + 1);
    }
  };
  const auto [header_line, header_text] = lines.front();
  const std::vector<std::string_view> header = split(header_text);
  auto column = [&](std::string_view name) -> int {
    for (std::size_t j = 0; j < header.size(); ++j)
      if (header[j] == name) return static_cast<int>(j);
    return -1;
  };
  const std::string header_where = fmt::format("particle file '{}' line {} (header)", file, header_line);
  auto need = [&](const char* name) {
    const int j = column(name);
    if (j < 0) fail(header_where, header_text, fmt::format("has no column '{}'", name));
    return j;
  };
  // A column read twice would be a guess at which one is meant.
  for (const char* name : {"x", "y", "z", "mass", "width_s", "beta", "id", "birth_time"})
    if (std::count(header.begin(), header.end(), std::string_view(name)) > 1)
      fail(header_where, header_text, fmt::format("has the column '{}' twice", name));
  static const char* kAxis[3] = {"x", "y", "z"};
  int jx[3];
  for (int k = 0; k < 3; ++k) jx[k] = k < dim ? need(kAxis[k]) : column(kAxis[k]);
  const int jm = need("mass");
  const int js = column("width_s"), jb = column("beta"), jid = column("id"), jt = column("birth_time");
  if (js < 0 && jb < 0) fail(header_where, header_text, "has no column 'width_s' or 'beta'");

  Columns c;
  c.has_width = js >= 0;
  c.has_id = jid >= 0;
  const std::size_t n = lines.size() - 1;
  c.x.assign(n, Vec3::Zero());
  c.mass.resize(n);
  (c.has_width ? c.width : c.beta).resize(n);
  if (c.has_id) c.id.resize(n);
  if (jt >= 0) c.birth.resize(n);
  std::vector<std::size_t> line_of(n);
  for (std::size_t i = 0; i < n; ++i) line_of[i] = lines[i + 1].first;
  const Locator where{file, &line_of};
  for (std::size_t i = 0; i < n; ++i) {
    const auto [number, text_line] = lines[i + 1];
    const std::vector<std::string_view> f = split(text_line);
    if (f.size() != header.size())
      fail(fmt::format("particle file '{}' line {}", file, number), text_line,
           fmt::format("has {} fields, the header {}", f.size(), header.size()));
    auto number_at = [&](int j) {
      const std::optional<double> v = parse_double(f[static_cast<std::size_t>(j)]);
      if (!v) fail(where(i, std::string(header[static_cast<std::size_t>(j)])), f[static_cast<std::size_t>(j)],
                   "must be a number");
      return *v;
    };
    for (int k = 0; k < 3; ++k)
      if (jx[k] >= 0) c.x[i][k] = number_at(jx[k]);
    c.mass[i] = number_at(jm);
    if (c.has_width)
      c.width[i] = number_at(js);
    else
      c.beta[i] = number_at(jb);
    if (jt >= 0) c.birth[i] = number_at(jt);
    if (c.has_id) {
      const std::string_view s = f[static_cast<std::size_t>(jid)];
      ParticleId id = 0;
      const auto [end, ec] = std::from_chars(s.data(), s.data() + s.size(), id);
      if (s.empty() || ec != std::errc() || end != s.data() + s.size()) fail(where(i, "id"), s, "must be an integer >= 0");
      c.id[i] = id;
    }
  }
  return build(c, dim, where);
}

// Attributes of an XML start tag such as <DataArray type="Float64" Name="mass" ...>.
std::unordered_map<std::string, std::string> attributes(std::string_view tag) {
  std::unordered_map<std::string, std::string> out;
  std::size_t p = 0;
  for (;;) {
    const std::size_t eq = tag.find("=\"", p);
    if (eq == std::string_view::npos) return out;
    std::size_t b = eq;
    while (b > 0 && tag[b - 1] != ' ' && tag[b - 1] != '\n' && tag[b - 1] != '\t') --b;
    const std::size_t close = tag.find('"', eq + 2);
    if (close == std::string_view::npos) return out;
    out.emplace(std::string(tag.substr(b, eq - b)), std::string(tag.substr(eq + 2, close - eq - 2)));
    p = close + 1;
  }
}

ParticleSet read_vtp(const std::string& bytes, const std::string& file, int dim) {
  const std::string head_where = fmt::format("particle file '{}'", file);
  const std::size_t marker = bytes.find("<AppendedData encoding=\"raw\">");
  const std::string_view head = std::string_view(bytes).substr(0, marker);
  const std::size_t vtk = head.find("<VTKFile");
  if (vtk == std::string_view::npos) fail(head_where, "no <VTKFile> element", "must be VTK XML PolyData");
  const auto file_attr = attributes(head.substr(vtk, head.find('>', vtk) - vtk));
  auto expect = [&](const char* key, const char* value) {
    const auto it = file_attr.find(key);
    const std::string got = it == file_attr.end() ? "" : it->second;
    if (got != value) fail(head_where + " VTKFile " + key, got, fmt::format("must be {}", value));
  };
  expect("type", "PolyData");
  expect("byte_order", "LittleEndian");
  expect("header_type", "UInt64");
  const std::size_t piece = head.find("<Piece");
  if (piece == std::string_view::npos) fail(head_where, "no <Piece> element", "must hold one Piece");
  const auto piece_attr = attributes(head.substr(piece, head.find('>', piece) - piece));
  const auto np_it = piece_attr.find("NumberOfPoints");
  const std::string np_text = np_it == piece_attr.end() ? "" : np_it->second;
  std::size_t n = 0;
  {
    const auto [end, ec] = std::from_chars(np_text.data(), np_text.data() + np_text.size(), n);
    if (np_text.empty() || ec != std::errc() || end != np_text.data() + np_text.size())
      fail(head_where + " Piece NumberOfPoints", np_text, "must be an integer >= 0");
    // Before any array is sized by it (n x 24 bytes may wrap around).
    if (n > bytes.size() / 24)
      fail(head_where + " Piece NumberOfPoints", np_text,
           fmt::format("more points than the file's {} bytes can hold (24 bytes of position each)", bytes.size()));
  }

  // Every DataArray declared in the header, by name.
  std::unordered_map<std::string, std::unordered_map<std::string, std::string>> arrays;
  std::optional<double> time;
  for (std::size_t p = head.find("<DataArray"); p != std::string_view::npos; p = head.find("<DataArray", p + 1)) {
    const std::size_t end = head.find('>', p);
    auto attr = attributes(head.substr(p, end - p));
    const std::string name = attr.count("Name") ? attr["Name"] : "";
    if (name == "TimeValue" && end != std::string_view::npos) {
      const std::size_t close = head.find('<', end);
      time = parse_double(trimmed(head.substr(end + 1, close - end - 1)));
    }
    arrays.emplace(name, std::move(attr));
  }
  if (n > 0 && marker == std::string::npos)
    fail(head_where, fmt::format("{} points", n), "must have a raw <AppendedData> section");
  const std::size_t underscore = marker == std::string::npos ? std::string::npos : bytes.find('_', marker);
  const std::size_t start = underscore == std::string::npos ? bytes.size() : underscore + 1;

  // Values of one appended array: n * components values of type `type`.
  auto block = [&](const char* name, const char* type, int components, bool required) -> std::optional<std::string_view> {
    const std::string where = fmt::format("{} array '{}'", head_where, name);
    const auto it = arrays.find(name);
    if (it == arrays.end()) {
      if (required) fail(head_where + " DataArray", name, "is required but missing");
      return std::nullopt;
    }
    const auto& a = it->second;
    const std::string got_type = a.count("type") ? a.at("type") : "";
    if (got_type != type) fail(where + " type", got_type, fmt::format("must be {}", type));
    if (n == 0) return std::string_view();
    const std::string fmt_attr = a.count("format") ? a.at("format") : "";
    if (fmt_attr != "appended") fail(where + " format", fmt_attr, "must be appended");
    std::uint64_t offset = 0;
    const std::string off_text = a.count("offset") ? a.at("offset") : "";
    const auto [end, ec] = std::from_chars(off_text.data(), off_text.data() + off_text.size(), offset);
    if (off_text.empty() || ec != std::errc() || end != off_text.data() + off_text.size())
      fail(where + " offset", off_text, "must be an integer >= 0");
    const std::uint64_t available = bytes.size() - start;
    if (offset > available || available - offset < 8)
      fail(where + " offset", off_text, fmt::format("is past the end of the data ({} bytes): the file is truncated", available));
    std::uint64_t nbytes = 0;
    std::memcpy(&nbytes, bytes.data() + start + offset, 8);
    const std::uint64_t want = static_cast<std::uint64_t>(n) * static_cast<std::uint64_t>(components) * 8u;
    if (nbytes != want)
      fail(where + " byte count", fmt::format("{}", nbytes), fmt::format("must be {} for {} points", want, n));
    if (available - offset - 8 < nbytes)
      fail(where, fmt::format("{} of {} bytes", available - offset - 8, nbytes), "the file is truncated");
    return std::string_view(bytes.data() + start + offset + 8, nbytes);
  };
  auto doubles = [&](std::string_view raw) {
    std::vector<double> v(raw.size() / 8);
    if (!v.empty()) std::memcpy(v.data(), raw.data(), raw.size());
    return v;
  };

  Columns c;
  const std::vector<double> pos = doubles(*block("position", "Float64", 3, true));
  c.x.resize(n);
  for (std::size_t i = 0; i < n; ++i) c.x[i] = Vec3(pos[3 * i], pos[3 * i + 1], pos[3 * i + 2]);
  c.mass = doubles(*block("mass", "Float64", 1, true));
  if (const auto w = block("width_s", "Float64", 1, false)) {
    c.has_width = true;
    c.width = doubles(*w);
  } else if (const auto b = block("beta", "Float64", 1, false)) {
    c.beta = doubles(*b);
  } else {
    fail(head_where, "width_s, beta", "must declare one of these DataArrays");
  }
  if (const auto ids = block("id", "Int64", 1, false)) {
    c.has_id = true;
    c.id.resize(n);
    if (n) std::memcpy(c.id.data(), ids->data(), ids->size());
  }
  if (const auto age = block("age", "Float64", 1, false); age && time) {
    c.birth = doubles(*age);
    for (double& b : c.birth) b = *time - b;
  }
  return build(c, dim, Locator{file, nullptr});
}

}  // namespace

ParticleSet read_particles(const std::filesystem::path& path, int dim) {
  require(dim >= 1 && dim <= 3, "read_particles: dim", dim, "must be 1, 2 or 3");
  const std::string file = path.string();
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) fail("particle file", file, "does not exist");
  if (std::filesystem::is_directory(path, ec)) fail("particle file", file, "is a directory, not a file");
  const std::string ext = path.extension().string();
  if (ext != ".csv" && ext != ".vtp") fail("particle file", file, "must end in .csv or .vtp");
  std::string bytes;
  try {
    bytes = detail::read_regular_file(path);
  } catch (const detail::FileReadError& e) {
    fail("particle file", file, e.what());
  }
  if (trimmed(bytes).find_first_not_of("\n\r\t ") == std::string_view::npos) fail("particle file", file, "is empty");
  return ext == ".csv" ? read_csv(bytes, file, dim) : read_vtp(bytes, file, dim);
}

}  // namespace otfp
