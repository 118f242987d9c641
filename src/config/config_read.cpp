// Reading a configuration: the TOML file or string, its structure checked
// against the table of keys, the --set overrides applied (config_overrides.cpp),
// the typed Config read with the treatment preset's defaults, then validated
// (config_validate.cpp).
#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <fmt/format.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <set>

#include "config_toml.hpp"

namespace otfp::app {

namespace config_detail {

// "unknown key" with the closest known key of the same table, if any is close.
std::string unknown_key_rule(const std::string& prefix, const std::string& key) {
  std::string best;
  std::size_t best_d = 3;  // suggest only near misses
  for (const Field& k : fields()) {
    if (k.path.compare(0, prefix.size(), prefix) != 0) continue;
    const std::string rest = k.path.substr(prefix.size());
    if (rest.find('.') != std::string::npos) continue;
    const std::size_t d = edit_distance(rest, key);
    if (d < best_d) {
      best_d = d;
      best = rest;
    }
  }
  return best.empty() ? std::string("unknown key") : "unknown key (did you mean '" + best + "'?)";
}

std::string format_node(const toml::node& n) {
  if (auto s = n.as_string()) return quoted(s->get());
  if (auto i = n.as_integer()) return std::to_string(i->get());
  if (auto f = n.as_floating_point()) {
    // A float stays a float in messages: 3.0, not 3 (which reads as an integer).
    std::string t = format_double(f->get());
    if (t.find_first_not_of("-0123456789") == std::string::npos) t += ".0";
    return t;
  }
  if (auto b = n.as_boolean()) return b->get() ? "true" : "false";
  if (auto a = n.as_array()) {
    std::string out = "[";
    for (std::size_t i = 0; i < a->size(); ++i) out += (i ? ", " : "") + format_node(*a->get(i));
    return out + "]";
  }
  if (n.is_table()) return "{...}";
  return "(a date or time)";
}

// A kind-checked number (an integer or a float) as a double. toml++'s
// value<double>() refuses an integer beyond 2^53 (not exactly a double): an
// integer key value is rounded to the nearest double instead, as the float
// literal with the same digits would be.
double number_of(const toml::node& n) {
  if (const auto* i = n.as_integer()) return static_cast<double>(i->get());
  return n.as_floating_point()->get();
}

std::string kind_rule(const Field& spec) {
  switch (spec.kind) {
    case Kind::Int: return "must be an integer";
    case Kind::Float: return "must be a number";
    case Kind::String:
      return spec.choices.empty() ? "must be a string" : "must be one of " + join(spec.choices);
    case Kind::Point: return "must be an array of 1 to 3 finite numbers";
  }
  return "invalid";
}

// Checks one value against its key's kind; `key` is the display name,
// `given` the value as the user wrote it (--set), if known.
void check_kind(const toml::node& n, const Field& spec, const std::string& key, const std::string& given) {
  const std::string shown = given.empty() ? format_node(n) : given;
  switch (spec.kind) {
    case Kind::Int:
      if (!n.is_integer()) throw ConfigError(key, shown, kind_rule(spec));
      return;
    case Kind::Float:
      if (n.is_integer()) return;
      if (!n.is_floating_point()) throw ConfigError(key, shown, kind_rule(spec));
      if (!std::isfinite(n.as_floating_point()->get())) throw ConfigError(key, shown, "must be finite");
      return;
    case Kind::String:
      if (!n.is_string()) throw ConfigError(key, shown, kind_rule(spec));
      if (!spec.choices.empty() &&
          std::find(spec.choices.begin(), spec.choices.end(), n.as_string()->get()) == spec.choices.end())
        throw ConfigError(key, shown, kind_rule(spec));
      return;
    case Kind::Point: {
      const toml::array* a = n.as_array();
      if (!a || a->empty() || a->size() > 3) throw ConfigError(key, shown, kind_rule(spec));
      for (const toml::node& e : *a) {
        if (e.is_integer()) continue;
        if (!e.is_floating_point() || !std::isfinite(e.as_floating_point()->get()))
          throw ConfigError(key, shown, kind_rule(spec));
      }
      return;
    }
  }
}

}  // namespace config_detail

namespace {

using namespace config_detail;
namespace fs = std::filesystem;

// Keys of one table `t` whose schema paths start with `prefix` ("run.", "boundary[].").
void check_table(const toml::table& t, const std::string& prefix, const std::string& display_prefix) {
  for (auto&& [k, v] : t) {
    const std::string key(k.str());
    const std::string display = display_prefix + key;
    if (prefix == "domain." && key == "subpatch") {
      const toml::array* a = v.as_array();
      if (!a || !a->is_array_of_tables())
        throw ConfigError(display, format_node(v), "must be an array of tables ([[domain.subpatch]])");
      for (std::size_t i = 0; i < a->size(); ++i)
        check_table(*a->get(i)->as_table(), "domain.subpatch[].", fmt::format("domain.subpatch[{}].", i));
      continue;
    }
    const Field* spec = find_spec(prefix + key);
    if (!spec) throw ConfigError(display, format_node(v), unknown_key_rule(prefix, key));
    check_kind(v, *spec, display);
  }
}

void check_structure(const toml::table& root) {
  for (auto&& [k, v] : root) {
    const std::string key(k.str());
    if (key == "boundary") {
      const toml::array* a = v.as_array();
      if (!a || !(a->empty() || a->is_array_of_tables()))
        throw ConfigError(key, format_node(v), "must be an array of tables ([[boundary]])");
      for (std::size_t i = 0; i < a->size(); ++i)
        check_table(*a->get(i)->as_table(), "boundary[].", fmt::format("boundary[{}].", i));
      continue;
    }
    if (std::find(kSections.begin(), kSections.end(), key) == kSections.end()) {
      std::string rule = "unknown section (allowed: " + join(kSections) + ")";
      throw ConfigError(key, format_node(v), rule);
    }
    if (!v.is_table()) throw ConfigError(key, format_node(v), "must be a table ([" + key + "])");
    check_table(*v.as_table(), key + ".", key + ".");
  }
}

// ------------------------------------------------------------------ typed read

const toml::table* section(const toml::table& root, const std::string& name) { return root[name].as_table(); }

// A (kind-checked) TOML value as the Value of its key.
Value node_value(const toml::node& n, Kind kind) {
  switch (kind) {
    case Kind::Int: return n.as_integer()->get();
    case Kind::Float: return number_of(n);
    case Kind::String: return n.as_string()->get();
    case Kind::Point: {
      Vec3 p = Vec3::Zero();  // missing components are 0
      const toml::array& a = *n.as_array();
      for (std::size_t i = 0; i < a.size() && i < 3; ++i) p[static_cast<int>(i)] = number_of(*a.get(i));
      return p;
    }
  }
  return {};
}

// The TOML table that holds the keys of `scope` entry i.
const toml::table* table_of(const toml::table& root, const Field& f, std::size_t i) {
  switch (f.scope) {
    case Scope::Section: return section(root, f.section);
    case Scope::SubPatch: {
      const toml::table* d = section(root, "domain");
      return d ? (*d)["subpatch"][i].as_table() : nullptr;
    }
    case Scope::Boundary: return root["boundary"][i].as_table();
  }
  return nullptr;
}

const toml::node* given(const toml::table& root, const Field& f, std::size_t i) {
  const toml::table* t = table_of(root, f, i);
  return t ? t->get(f.key) : nullptr;
}

void read_key(const toml::table& root, const Field& f, Config& c) {
  for (std::size_t i = 0; i < entries(c, f.scope); ++i)
    if (const toml::node* n = given(root, f, i)) f.set(c, i, node_value(*n, f.kind), display_name(f, i));
}

// "papers": Sec. 4.2 of the 2025 paper (barrier, the b-thick Dirichlet layer,
// outlets that take only from B_l) and, in 3-D, the sphere-radius spacing rule
// of Tables 1-3. "converging": what study 5 measured best (images, the odd
// reservoir, outlets that reach the nearest particles, the true spacing).
void apply_treatment_preset(Config& c) {
  TreatmentSection& t = c.treatment;
  const TreatmentOptions o = treatment_preset(t.preset, c.run.dim);
  t.no_flux = o.no_flux;
  t.dirichlet = o.dirichlet;
  t.reservoir_profile = o.reservoir_profile;
  t.neumann_outflow = o.neumann_outflow;
  t.absorb_stranded = o.absorb_stranded;
  c.particles.spacing_rule = o.spacing_rule;
}

// `base`: the directory relative paths are taken from.
Config to_config(const toml::table& root, const fs::path& base) {
  Config c;
  if (const toml::table* d = section(root, "domain"))
    if (const toml::array* a = (*d)["subpatch"].as_array()) c.domain.subpatches.resize(a->size());
  if (const toml::array* a = root["boundary"].as_array()) c.boundary.resize(a->size());
  // treatment.preset (and run.dim, which it reads) first: the preset sets the
  // defaults that the other keys may override, wherever they stand.
  read_key(root, *find_spec("run.dim"), c);
  read_key(root, *find_spec("treatment.preset"), c);
  apply_treatment_preset(c);
  for (const Field& f : fields()) read_key(root, f, c);

  ParticlesSection& p = c.particles;
  if (p.fill_file) {
    fs::path file(*p.fill_file);
    if (file.is_relative()) file = base / file;
    p.fill_file = file.lexically_normal().string();
  }
  if (p.fill == Fill::File)
    for (const Field& f : fields()) {
      static const std::set<std::string> other_fills = {
          "particles.fill_count", "particles.fill_mass",      "particles.fill_center", "particles.fill_sigma",
          "particles.fill_arrangement", "particles.fill_amplitude", "particles.fill_mode"};
      if (!other_fills.count(f.path)) continue;
      if (const toml::node* n = given(root, f, 0))
        throw ConfigError(f.path, shown(node_value(*n, f.kind)),
                          "does not apply to particles.fill = \"file\" (the file gives the particles; remove it)");
    }
  return c;
}

Config finish(toml::table& root, const std::vector<std::string>& overrides, const std::string& source,
              const fs::path& base) {
  check_structure(root);
  for (const std::string& o : overrides) apply_override(root, o);
  Config c = to_config(root, base);
  c.source = source;
  c.overrides = overrides;
  validate(c);
  return c;
}

std::string parse_error_text(const toml::parse_error& e, const std::string& source) {
  const auto& b = e.source().begin;
  return fmt::format("{}:{}:{}: TOML syntax error: {}", source, b.line, b.column, e.description());
}

Config parse_text(std::string_view toml_text, const std::vector<std::string>& overrides, const std::string& source,
                  const fs::path& base) {
  toml::table root;
  try {
    root = toml::parse(toml_text, source);
  } catch (const toml::parse_error& e) {
    throw ConfigError("config", parse_error_text(e, source));
  }
  return finish(root, overrides, source, base);
}

}  // namespace

Config parse_config_file(const std::filesystem::path& file, const std::vector<std::string>& overrides) {
  // A directory, a device or a file that fails to read (/proc/self/mem) must
  // not read as an empty configuration (all defaults): POSIX calls, whose
  // errors are not swallowed as the stream's are.
  const auto fail = [&](const std::string& why) {
    return ConfigError("config", "cannot read CONFIG: " + file.string() + ": " + why);
  };
  const int fd = ::open(file.c_str(), O_RDONLY | O_CLOEXEC | O_NONBLOCK);
  if (fd < 0) throw fail(std::strerror(errno));
  struct stat st {};
  if (::fstat(fd, &st) != 0) {
    const std::string why = std::strerror(errno);
    ::close(fd);
    throw fail(why);
  }
  if (!S_ISREG(st.st_mode)) {
    ::close(fd);
    throw fail(S_ISDIR(st.st_mode) ? "not a regular file (a directory)" : "not a regular file");
  }
  std::string text;
  char buf[65536];
  for (;;) {
    const ssize_t n = ::read(fd, buf, sizeof buf);
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) {
      const std::string why = std::strerror(errno);
      ::close(fd);
      throw fail(why);
    }
    if (n == 0) break;
    text.append(buf, static_cast<std::size_t>(n));
  }
  ::close(fd);
  return parse_text(text, overrides, file.string(), fs::absolute(file).parent_path());
}

Config parse_config_string(std::string_view toml_text, const std::vector<std::string>& overrides,
                           const std::string& source) {
  return parse_text(toml_text, overrides, source, fs::current_path());
}

// Levenshtein distance, for "did you mean" hints.
std::size_t edit_distance(const std::string& a, const std::string& b) {
  std::vector<std::size_t> row(b.size() + 1);
  for (std::size_t j = 0; j <= b.size(); ++j) row[j] = j;
  for (std::size_t i = 1; i <= a.size(); ++i) {
    std::size_t diag = row[0];
    row[0] = i;
    for (std::size_t j = 1; j <= b.size(); ++j) {
      const std::size_t up = row[j];
      row[j] = std::min({row[j] + 1, row[j - 1] + 1, diag + (a[i - 1] == b[j - 1] ? 0 : 1)});
      diag = up;
    }
  }
  return row[b.size()];
}

}  // namespace otfp::app
