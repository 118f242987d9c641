#include "otfp_app/config.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <limits>
#include <set>
#include <sstream>
#include <toml++/toml.h>

namespace otfp::app {

ConfigError::ConfigError(const std::string& key, const std::string& value, const std::string& rule)
    : std::runtime_error(key + " = " + value + ": " + rule), key_(key) {}
ConfigError::ConfigError(const std::string& key, const std::string& message)
    : std::runtime_error(message), key_(key) {}

namespace {

// ------------------------------------------------------------------ schema

enum class Kind { Int, Float, String, Point };

struct KeySpec {
  std::string path;                  // "run.dim", "boundary[].kind", "domain.subpatch[].name"
  Kind kind;
  std::vector<std::string> choices;  // allowed strings (empty: any)
};

const std::vector<KeySpec>& schema() {
  static const std::vector<KeySpec> keys = {
      {"run.dim", Kind::Int, {}},
      {"run.t_end", Kind::Float, {}},
      {"run.dt", Kind::Float, {}},
      {"run.dt_factor", Kind::Float, {}},
      {"run.seed", Kind::Int, {}},
      {"run.max_steps", Kind::Int, {}},
      {"run.dt_mode", Kind::String, {"fixed", "adaptive"}},
      {"run.time_tolerance", Kind::Float, {}},
      {"run.dt_min", Kind::Float, {}},
      {"run.dt_max", Kind::Float, {}},
      {"run.vtk_interval", Kind::Int, {}},
      {"run.threads", Kind::Int, {}},
      {"domain.type", Kind::String, {"ball", "box", "cylinder", "periodic_box", "square_pipe_obstacle", "free"}},
      {"domain.center", Kind::Point, {}},
      {"domain.radius", Kind::Float, {}},
      {"domain.lo", Kind::Point, {}},
      {"domain.hi", Kind::Point, {}},
      {"domain.end_a", Kind::Point, {}},
      {"domain.end_b", Kind::Point, {}},
      {"domain.obstacle_center", Kind::Point, {}},
      {"domain.obstacle_radius", Kind::Float, {}},
      {"domain.obstacle_axis", Kind::String, {"x", "y", "z"}},
      {"domain.subpatch[].name", Kind::String, {}},
      {"domain.subpatch[].on", Kind::String, {}},
      {"domain.subpatch[].center", Kind::Point, {}},
      {"domain.subpatch[].radius", Kind::Float, {}},
      {"particles.n_inf", Kind::Int, {}},
      {"particles.mass", Kind::Float, {}},
      {"particles.spacing_rule", Kind::String, {"cube", "sphere_radius"}},
      {"particles.beta_factor", Kind::Float, {}},
      {"particles.width_exponent", Kind::Float, {}},
      {"particles.width_reference_n", Kind::Int, {}},
      {"particles.layer_b", Kind::Float, {}},
      {"particles.length_L", Kind::Float, {}},
      {"particles.dirichlet_target", Kind::String, {"cell_integral", "paper_eq34"}},
      {"particles.fill", Kind::String, {"empty", "uniform", "gaussian", "cosine"}},
      {"particles.fill_arrangement", Kind::String, {"random", "lattice"}},
      {"particles.fill_amplitude", Kind::Float, {}},
      {"particles.fill_mode", Kind::Int, {}},
      {"particles.fill_count", Kind::Int, {}},
      {"particles.fill_mass", Kind::Float, {}},
      {"particles.fill_center", Kind::Point, {}},
      {"particles.fill_sigma", Kind::Float, {}},
      {"physics.kappa", Kind::Float, {}},
      {"physics.rho_ref", Kind::Float, {}},
      {"physics.velocity", Kind::Point, {}},
      {"physics.source_rate", Kind::Float, {}},
      {"boundary[].patch", Kind::String, {}},
      {"boundary[].kind", Kind::String, {"dirichlet", "neumann", "no_flux"}},
      {"boundary[].value", Kind::Float, {}},
      {"boundary[].t_start", Kind::Float, {}},
      {"boundary[].t_end", Kind::Float, {}},
      {"solver.stepper", Kind::String, {"implicit", "explicit"}},
      {"solver.backend", Kind::String, {"ceres", "nlopt"}},
      {"solver.algorithm", Kind::String, {"lbfgs", "bfgs", "nonlinear_cg", "tnewton", "var2", "mma"}},
      {"solver.explicit_scheme", Kind::String, {"euler27", "rk4", "euler_exact"}},
      {"solver.width_mode", Kind::String, {"fixed", "per_particle"}},
      {"solver.width_metric", Kind::String, {"as_printed", "exact"}},
      {"solver.time_scheme", Kind::String, {"euler", "bdf2"}},
      {"solver.predictor", Kind::String, {"none", "extrapolate", "damped"}},
      {"solver.error_smoothing", Kind::Float, {}},
      {"solver.displacement_tolerance", Kind::Float, {}},
      {"solver.relative_tolerance", Kind::Float, {}},
      {"solver.max_iterations", Kind::Int, {}},
      {"solver.max_evaluations", Kind::Int, {}},
      {"solver.lbfgs_memory", Kind::Int, {}},
      {"solver.max_halvings", Kind::Int, {}},
      {"solver.energy_tolerance", Kind::Float, {}},
      {"solver.barrier_factor", Kind::Float, {}},
      {"solver.barrier_stiffness", Kind::Float, {}},
      {"solver.kernel_tolerance", Kind::Float, {}},
      {"solver.skin_factor", Kind::Float, {}},
      {"treatment.preset", Kind::String, {"converging", "papers"}},
      {"treatment.no_flux", Kind::String, {"barrier", "images"}},
      {"treatment.dirichlet", Kind::String, {"layer", "reservoir"}},
      {"treatment.reservoir_width", Kind::Float, {}},
      {"treatment.reservoir_sublayers", Kind::Int, {}},
      {"treatment.reservoir_profile", Kind::String, {"uniform", "odd"}},
      {"treatment.neumann_outflow", Kind::String, {"layer", "nearest"}},
      {"treatment.stranded", Kind::String, {"keep", "absorb"}},
      {"diagnostics.center", Kind::Point, {}},
      {"diagnostics.M_inf", Kind::Float, {}},
      {"diagnostics.J_inf", Kind::Float, {}},
      {"diagnostics.reference", Kind::String, {"none", "crank_sphere", "crank_slab", "free_space", "cosine_mode"}},
      {"diagnostics.reference_radius", Kind::Float, {}},
      {"diagnostics.reference_length", Kind::Float, {}},
  };
  return keys;
}

const std::vector<std::string> kSections = {"run", "domain", "particles", "physics", "boundary", "solver",
                                            "treatment", "diagnostics"};

const KeySpec* find_spec(const std::string& path) {
  for (const KeySpec& k : schema())
    if (k.path == path) return &k;
  return nullptr;
}

std::string join(const std::vector<std::string>& v, const char* sep = ", ") {
  std::string out;
  for (std::size_t i = 0; i < v.size(); ++i) out += (i ? sep : "") + v[i];
  return out;
}

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

// "unknown key" with the closest known key of the same table, if any is close.
std::string unknown_key_rule(const std::string& prefix, const std::string& key) {
  std::string best;
  std::size_t best_d = 3;  // suggest only near misses
  for (const KeySpec& k : schema()) {
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

std::string format_double(double v) {
  if (std::isnan(v)) return "nan";
  if (std::isinf(v)) return v > 0 ? "inf" : "-inf";
  return fmt::format("{}", v);
}

std::string format_node(const toml::node& n) {
  if (auto s = n.as_string()) return "\"" + s->get() + "\"";
  if (auto i = n.as_integer()) return std::to_string(i->get());
  if (auto f = n.as_floating_point()) return format_double(f->get());
  if (auto b = n.as_boolean()) return b->get() ? "true" : "false";
  if (auto a = n.as_array()) {
    std::string out = "[";
    for (std::size_t i = 0; i < a->size(); ++i) out += (i ? ", " : "") + format_node(*a->get(i));
    return out + "]";
  }
  if (n.is_table()) return "{...}";
  return "(a date or time)";
}

std::string kind_rule(const KeySpec& spec) {
  switch (spec.kind) {
    case Kind::Int: return "must be an integer";
    case Kind::Float: return "must be a number";
    case Kind::String:
      return spec.choices.empty() ? "must be a string" : "must be one of " + join(spec.choices);
    case Kind::Point: return "must be an array of 1 to 3 finite numbers";
  }
  return "invalid";
}

// Checks one value against its key's kind; `key` is the display name.
void check_kind(const toml::node& n, const KeySpec& spec, const std::string& key) {
  const std::string shown = format_node(n);
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
    const KeySpec* spec = find_spec(prefix + key);
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

// ------------------------------------------------------------------ --set

bool all_digits(const std::string& s) {
  return !s.empty() && std::all_of(s.begin(), s.end(), [](char c) { return c >= '0' && c <= '9'; });
}

std::vector<std::string> split_path(std::string path) {
  // a[1].b -> a.1.b
  for (char& c : path)
    if (c == '[') c = '.';
  path.erase(std::remove(path.begin(), path.end(), ']'), path.end());
  std::vector<std::string> out;
  std::string cur;
  for (char c : path) {
    if (c == '.') {
      out.push_back(cur);
      cur.clear();
    } else {
      cur += c;
    }
  }
  out.push_back(cur);
  return out;
}

// The element of an array of tables addressed by an index (== size appends)
// or by the value of `name_key` (a missing name appends a new entry with it).
toml::table& select_entry(toml::array& arr, const std::string& sel, const std::string& name_key,
                          const std::string& array_key, const std::string& assignment, std::size_t& index) {
  if (all_digits(sel)) {
    const std::size_t i = std::stoul(sel);
    if (i > arr.size())
      throw ConfigError(array_key + "[" + sel + "]", assignment,
                        fmt::format("index out of range (there are {} entries; {} appends one)", arr.size(),
                                    arr.size()));
    if (i == arr.size()) arr.push_back(toml::table{});
    index = i;
    return *arr.get(i)->as_table();
  }
  for (std::size_t i = 0; i < arr.size(); ++i) {
    toml::table& t = *arr.get(i)->as_table();
    if (auto s = t[name_key].value<std::string>(); s && *s == sel) {
      index = i;
      return t;
    }
  }
  arr.push_back(toml::table{{name_key, sel}});
  index = arr.size() - 1;
  return *arr.back().as_table();
}

toml::array& array_of_tables(toml::table& parent, const std::string& key, const std::string& display) {
  if (!parent.contains(key)) parent.insert(key, toml::array{});
  toml::array* a = parent[key].as_array();
  if (!a || !(a->empty() || a->is_array_of_tables()))
    throw ConfigError(display, format_node(*parent.get(key)), "must be an array of tables");
  return *a;
}

void apply_override(toml::table& root, const std::string& assignment) {
  const auto eq = assignment.find('=');
  if (eq == std::string::npos || eq == 0)
    throw ConfigError("--set", "\"" + assignment + "\"", "must have the form key=value");
  const std::string path = assignment.substr(0, eq);
  const std::string text = assignment.substr(eq + 1);
  const std::vector<std::string> seg = split_path(path);
  for (const std::string& s : seg)
    if (s.empty()) throw ConfigError(path, "\"" + text + "\"", "malformed key path");

  toml::table* target = nullptr;
  std::string spec_path, display;
  const std::string& section = seg[0];
  if (section == "boundary") {
    if (seg.size() != 3)
      throw ConfigError(path, "\"" + text + "\"", "must be boundary.<index or patch name>.<key>");
    std::size_t idx = 0;
    target = &select_entry(array_of_tables(root, "boundary", "boundary"), seg[1], "patch", "boundary", text, idx);
    spec_path = "boundary[]." + seg[2];
    display = fmt::format("boundary[{}].{}", idx, seg[2]);
  } else if (std::find(kSections.begin(), kSections.end(), section) != kSections.end()) {
    if (!root.contains(section)) root.insert(section, toml::table{});
    toml::table* sec = root[section].as_table();
    if (!sec) throw ConfigError(section, format_node(*root.get(section)), "must be a table");
    if (section == "domain" && seg.size() >= 2 && seg[1] == "subpatch") {
      if (seg.size() != 4)
        throw ConfigError(path, "\"" + text + "\"", "must be domain.subpatch.<index or name>.<key>");
      std::size_t idx = 0;
      target = &select_entry(array_of_tables(*sec, "subpatch", "domain.subpatch"), seg[2], "name",
                             "domain.subpatch", text, idx);
      spec_path = "domain.subpatch[]." + seg[3];
      display = fmt::format("domain.subpatch[{}].{}", idx, seg[3]);
    } else {
      if (seg.size() != 2) throw ConfigError(path, "\"" + text + "\"", "unknown key");
      target = sec;
      spec_path = path;
      display = path;
    }
  } else {
    throw ConfigError(path, "\"" + text + "\"", "unknown section (allowed: " + join(kSections) + ")");
  }
  const KeySpec* spec = find_spec(spec_path);
  if (!spec) {
    const std::string prefix = spec_path.substr(0, spec_path.rfind('.') + 1);
    throw ConfigError(display, "\"" + text + "\"", unknown_key_rule(prefix, spec_path.substr(prefix.size())));
  }
  const std::string key = spec_path.substr(spec_path.rfind('.') + 1);

  // The value is a TOML inline value; a bare word is accepted for string keys.
  toml::table parsed;
  bool ok = true;
  try {
    parsed = toml::parse("v = " + text);
  } catch (const toml::parse_error&) {
    ok = false;
  }
  if (!ok || !parsed.contains("v")) {
    if (spec->kind != Kind::String)
      throw ConfigError(display, "\"" + text + "\"", "not a TOML value; " + kind_rule(*spec));
    parsed = toml::table{{"v", text}};
  }
  const toml::node& n = *parsed.get("v");
  check_kind(n, *spec, display);
  switch (spec->kind) {
    case Kind::Int: target->insert_or_assign(key, n.as_integer()->get()); break;
    case Kind::Float: target->insert_or_assign(key, n.value<double>().value()); break;
    case Kind::String: target->insert_or_assign(key, n.as_string()->get()); break;
    case Kind::Point: {
      toml::array a;
      for (const toml::node& e : *n.as_array()) a.push_back(e.value<double>().value());
      target->insert_or_assign(key, std::move(a));
      break;
    }
  }
}

// ------------------------------------------------------------------ typed read

// Reads the keys of one (already kind-checked) table.
class Reader {
 public:
  Reader(const toml::table* t, std::string display_prefix) : t_(t), prefix_(std::move(display_prefix)) {}

  template <class T>
  void get(const char* key, T& out) const {
    if (!t_) return;
    const toml::node* n = t_->get(key);
    if (!n) return;
    read(*n, key, out);
  }
  template <class T>
  void get(const char* key, std::optional<T>& out) const {
    if (!t_) return;
    const toml::node* n = t_->get(key);
    if (!n) return;
    T v{};
    read(*n, key, v);
    out = v;
  }
  void get(const char* key, int& out) const {
    std::int64_t v = out;
    get(key, v);
    if (v < std::numeric_limits<int>::min() || v > std::numeric_limits<int>::max())
      throw ConfigError(prefix_ + key, std::to_string(v), "out of range");
    out = static_cast<int>(v);
  }

 private:
  void read(const toml::node& n, const char*, std::int64_t& out) const { out = n.as_integer()->get(); }
  void read(const toml::node& n, const char*, double& out) const { out = n.value<double>().value(); }
  void read(const toml::node& n, const char*, std::string& out) const { out = n.as_string()->get(); }
  void read(const toml::node& n, const char*, Vec3& out) const {
    out = Vec3::Zero();
    const toml::array& a = *n.as_array();
    for (std::size_t i = 0; i < a.size() && i < 3; ++i) out[static_cast<int>(i)] = a.get(i)->value<double>().value();
  }
  const toml::table* t_;
  std::string prefix_;
};

const toml::table* section(const toml::table& root, const char* name) { return root[name].as_table(); }

// "papers": Sec. 4.2 of the 2025 paper (barrier, the b-thick Dirichlet layer,
// outlets that take only from B_l) and, in 3-D, the sphere-radius spacing rule
// of Tables 1-3. "converging": what study 5 measured best (images, the odd
// reservoir, outlets that reach the nearest particles, the true spacing).
void apply_treatment_preset(Config& c) {
  TreatmentSection& t = c.treatment;
  const bool papers = t.preset == "papers";
  t.no_flux = papers ? "barrier" : "images";
  t.dirichlet = papers ? "layer" : "reservoir";
  t.reservoir_profile = papers ? "uniform" : "odd";
  t.neumann_outflow = papers ? "layer" : "nearest";
  t.stranded = "keep";
  c.particles.spacing_rule = papers && c.run.dim == 3 ? "sphere_radius" : "cube";
}

Config to_config(const toml::table& root) {
  Config c;
  {
    Reader r(section(root, "run"), "run.");
    r.get("dim", c.run.dim);
    r.get("t_end", c.run.t_end);
    r.get("dt", c.run.dt);
    r.get("dt_factor", c.run.dt_factor);
    r.get("seed", c.run.seed);
    r.get("max_steps", c.run.max_steps);
    r.get("dt_mode", c.run.dt_mode);
    r.get("time_tolerance", c.run.time_tolerance);
    r.get("dt_min", c.run.dt_min);
    r.get("dt_max", c.run.dt_max);
    r.get("vtk_interval", c.run.vtk_interval);
    r.get("threads", c.run.threads);
  }
  {
    const toml::table* d = section(root, "domain");
    Reader r(d, "domain.");
    r.get("type", c.domain.type);
    r.get("center", c.domain.center);
    r.get("radius", c.domain.radius);
    r.get("lo", c.domain.lo);
    r.get("hi", c.domain.hi);
    r.get("end_a", c.domain.end_a);
    r.get("end_b", c.domain.end_b);
    r.get("obstacle_center", c.domain.obstacle_center);
    r.get("obstacle_radius", c.domain.obstacle_radius);
    r.get("obstacle_axis", c.domain.obstacle_axis);
    if (d)
      if (const toml::array* a = (*d)["subpatch"].as_array())
        for (std::size_t i = 0; i < a->size(); ++i) {
          Reader s(a->get(i)->as_table(), fmt::format("domain.subpatch[{}].", i));
          SubPatchSpec sp;
          sp.radius = std::numeric_limits<double>::quiet_NaN();  // required: NaN marks "absent"
          s.get("name", sp.name);
          s.get("on", sp.on);
          s.get("center", sp.center);
          s.get("radius", sp.radius);
          c.domain.subpatches.push_back(sp);
        }
  }
  // treatment.preset first: it sets the defaults that the keys below may override.
  {
    Reader r(section(root, "treatment"), "treatment.");
    r.get("preset", c.treatment.preset);
    apply_treatment_preset(c);
  }
  {
    Reader r(section(root, "particles"), "particles.");
    r.get("n_inf", c.particles.n_inf);
    r.get("mass", c.particles.mass);
    r.get("spacing_rule", c.particles.spacing_rule);
    r.get("beta_factor", c.particles.beta_factor);
    r.get("width_exponent", c.particles.width_exponent);
    r.get("width_reference_n", c.particles.width_reference_n);
    r.get("layer_b", c.particles.layer_b);
    r.get("length_L", c.particles.length_L);
    r.get("dirichlet_target", c.particles.dirichlet_target);
    r.get("fill", c.particles.fill);
    r.get("fill_count", c.particles.fill_count);
    r.get("fill_mass", c.particles.fill_mass);
    r.get("fill_center", c.particles.fill_center);
    r.get("fill_sigma", c.particles.fill_sigma);
    r.get("fill_arrangement", c.particles.fill_arrangement);
    r.get("fill_amplitude", c.particles.fill_amplitude);
    r.get("fill_mode", c.particles.fill_mode);
  }
  {
    Reader r(section(root, "physics"), "physics.");
    r.get("kappa", c.physics.kappa);
    r.get("rho_ref", c.physics.rho_ref);
    r.get("velocity", c.physics.velocity);
    r.get("source_rate", c.physics.source_rate);
  }
  if (const toml::array* a = root["boundary"].as_array())
    for (std::size_t i = 0; i < a->size(); ++i) {
      Reader r(a->get(i)->as_table(), fmt::format("boundary[{}].", i));
      BoundarySpec b;
      r.get("patch", b.patch);
      r.get("kind", b.kind);
      r.get("value", b.value);
      r.get("t_start", b.t_start);
      r.get("t_end", b.t_end);
      c.boundary.push_back(b);
    }
  {
    Reader r(section(root, "solver"), "solver.");
    SolverSection& s = c.solver;
    r.get("stepper", s.stepper);
    r.get("backend", s.backend);
    r.get("algorithm", s.algorithm);
    r.get("explicit_scheme", s.explicit_scheme);
    r.get("width_mode", s.width_mode);
    r.get("width_metric", s.width_metric);
    r.get("time_scheme", s.time_scheme);
    r.get("predictor", s.predictor);
    r.get("error_smoothing", s.error_smoothing);
    r.get("displacement_tolerance", s.displacement_tolerance);
    r.get("relative_tolerance", s.relative_tolerance);
    r.get("max_iterations", s.max_iterations);
    r.get("max_evaluations", s.max_evaluations);
    r.get("lbfgs_memory", s.lbfgs_memory);
    r.get("max_halvings", s.max_halvings);
    r.get("energy_tolerance", s.energy_tolerance);
    r.get("barrier_factor", s.barrier_factor);
    r.get("barrier_stiffness", s.barrier_stiffness);
    r.get("kernel_tolerance", s.kernel_tolerance);
    r.get("skin_factor", s.skin_factor);
  }
  {
    Reader r(section(root, "treatment"), "treatment.");
    TreatmentSection& t = c.treatment;
    r.get("preset", t.preset);
    r.get("no_flux", t.no_flux);
    r.get("dirichlet", t.dirichlet);
    r.get("reservoir_width", t.reservoir_width);
    r.get("reservoir_sublayers", t.reservoir_sublayers);
    r.get("reservoir_profile", t.reservoir_profile);
    r.get("neumann_outflow", t.neumann_outflow);
    r.get("stranded", t.stranded);
  }
  {
    Reader r(section(root, "diagnostics"), "diagnostics.");
    r.get("center", c.diagnostics.center);
    r.get("M_inf", c.diagnostics.M_inf);
    r.get("J_inf", c.diagnostics.J_inf);
    r.get("reference", c.diagnostics.reference);
    r.get("reference_radius", c.diagnostics.reference_radius);
    r.get("reference_length", c.diagnostics.reference_length);
  }
  return c;
}

// ------------------------------------------------------------------ validation

std::string shown(double v) { return format_double(v); }
std::string shown(const Vec3& v) {
  return "[" + format_double(v[0]) + ", " + format_double(v[1]) + ", " + format_double(v[2]) + "]";
}
std::string quoted(const std::string& s) { return "\"" + s + "\""; }

void positive(double v, const std::string& key) {
  if (!(v > 0.0)) throw ConfigError(key, shown(v), "must be > 0");
}
void non_negative(double v, const std::string& key) {
  if (!(v >= 0.0)) throw ConfigError(key, shown(v), "must be >= 0");
}
template <class I>
void at_least(I v, I lo, const std::string& key) {
  if (v < lo) throw ConfigError(key, std::to_string(v), "must be >= " + std::to_string(lo));
}

bool offered(const std::string& backend, const std::string& algorithm) {
  if (algorithm == "lbfgs") return true;
  if (backend == "ceres") return algorithm == "bfgs" || algorithm == "nonlinear_cg";
  return algorithm == "tnewton" || algorithm == "var2" || algorithm == "mma";
}

void validate(const Config& c) {
  const RunSection& r = c.run;
  if (r.dim < 1 || r.dim > 3) throw ConfigError("run.dim", std::to_string(r.dim), "must be 1, 2 or 3");
  positive(r.t_end, "run.t_end");
  if (r.dt) positive(*r.dt, "run.dt");
  positive(r.dt_factor, "run.dt_factor");
  at_least<std::int64_t>(r.seed, 0, "run.seed");
  at_least<std::int64_t>(r.max_steps, 0, "run.max_steps");
  positive(r.time_tolerance, "run.time_tolerance");
  if (r.dt_min) non_negative(*r.dt_min, "run.dt_min");
  if (r.dt_max) positive(*r.dt_max, "run.dt_max");
  if (r.dt_min && r.dt_max && *r.dt_max < *r.dt_min)
    throw ConfigError("run.dt_max", shown(*r.dt_max), fmt::format("must be >= run.dt_min = {}", shown(*r.dt_min)));
  if (r.dt_mode == "adaptive" && c.solver.stepper != "implicit")
    throw ConfigError("run.dt_mode", quoted(r.dt_mode),
                      "needs solver.stepper = \"implicit\" (the explicit schemes have no error estimate)");
  at_least<std::int64_t>(r.vtk_interval, 0, "run.vtk_interval");
  if (r.threads < 0 || r.threads > 4096)
    throw ConfigError("run.threads", std::to_string(r.threads), "must be in [0, 4096] (0: OpenMP default)");

  const DomainSection& d = c.domain;
  const std::string& type = d.type;
  if (type == "ball" || type == "cylinder") positive(d.radius, "domain.radius");
  if (type == "box" || type == "periodic_box" || type == "square_pipe_obstacle" || type == "free") {
    for (int k = 0; k < r.dim; ++k)
      if (!(d.hi[k] > d.lo[k]))
        throw ConfigError("domain.hi", shown(d.hi),
                          fmt::format("must exceed domain.lo = {} in every used axis (axis {} gives zero volume)",
                                      shown(d.lo), "xyz"[k]));
  }
  if (type == "cylinder") {
    if (r.dim != 3) throw ConfigError("domain.type", quoted(type), "needs run.dim = 3");
    if (!((d.end_b - d.end_a).norm() > 0.0))
      throw ConfigError("domain.end_b", shown(d.end_b), "must differ from domain.end_a (zero length)");
  }
  if (type == "square_pipe_obstacle") {
    if (r.dim < 2) throw ConfigError("domain.type", quoted(type), "needs run.dim = 2 or 3");
    if (d.obstacle_radius) positive(*d.obstacle_radius, "domain.obstacle_radius");
    if (r.dim == 2 && d.obstacle_axis != "z")
      throw ConfigError("domain.obstacle_axis", quoted(d.obstacle_axis), "must be \"z\" in 2D (a disc obstacle)");
  }
  std::set<std::string> sub_names;
  for (std::size_t i = 0; i < d.subpatches.size(); ++i) {
    const SubPatchSpec& s = d.subpatches[i];
    const std::string p = fmt::format("domain.subpatch[{}].", i);
    if (s.name.empty()) throw ConfigError(p + "name", "(missing)", "required, a non-empty patch name");
    if (!sub_names.insert(s.name).second) throw ConfigError(p + "name", quoted(s.name), "duplicate sub-patch name");
    if (s.on.empty()) throw ConfigError(p + "on", "(missing)", "required: the name of the patch it lies on");
    if (std::isnan(s.radius)) throw ConfigError(p + "radius", "(missing)", "required, > 0");
    positive(s.radius, p + "radius");
  }

  const ParticlesSection& pa = c.particles;
  at_least<std::int64_t>(pa.n_inf, 1, "particles.n_inf");
  if (pa.mass) positive(*pa.mass, "particles.mass");
  if (pa.spacing_rule == "sphere_radius" && r.dim != 3)
    throw ConfigError("particles.spacing_rule", quoted(pa.spacing_rule), "needs run.dim = 3 (use \"cube\")");
  positive(pa.beta_factor, "particles.beta_factor");
  if (!(pa.width_exponent > 0.0 && pa.width_exponent <= 2.0))
    throw ConfigError("particles.width_exponent", shown(pa.width_exponent),
                      "must be in (0, 2] (s = s_rule(dr) (dr / dr_ref)^(q - 1); 1: the papers' fixed beta dr^2)");
  at_least<std::int64_t>(pa.width_reference_n, 1, "particles.width_reference_n");
  non_negative(pa.layer_b, "particles.layer_b");
  non_negative(pa.length_L, "particles.length_L");
  if (pa.fill_count && pa.fill_mass)
    throw ConfigError("particles.fill_count", std::to_string(*pa.fill_count),
                      "give either particles.fill_count or particles.fill_mass, not both");
  if (pa.fill == "empty" && (pa.fill_count || pa.fill_mass))
    throw ConfigError(pa.fill_count ? "particles.fill_count" : "particles.fill_mass",
                      pa.fill_count ? std::to_string(*pa.fill_count) : shown(*pa.fill_mass),
                      "needs particles.fill = \"uniform\", \"gaussian\" or \"cosine\"");
  if (pa.fill_count) at_least<std::int64_t>(*pa.fill_count, 0, "particles.fill_count");
  if (pa.fill_mass) non_negative(*pa.fill_mass, "particles.fill_mass");
  positive(pa.fill_sigma, "particles.fill_sigma");
  if (!(pa.fill_amplitude >= 0.0 && pa.fill_amplitude < 1.0))
    throw ConfigError("particles.fill_amplitude", shown(pa.fill_amplitude), "must be in [0, 1) (density 1 + a cos(k x) > 0)");
  at_least<std::int64_t>(pa.fill_mode, 1, "particles.fill_mode");
  const bool box_shaped = type == "box" || type == "periodic_box" || type == "free";
  if (pa.fill == "cosine" && !box_shaped)
    throw ConfigError("particles.fill", "\"cosine\"", "needs domain.type = \"periodic_box\", \"box\" or \"free\"");
  if (pa.fill_arrangement == "lattice") {
    if (pa.fill != "uniform" && pa.fill != "cosine")
      throw ConfigError("particles.fill_arrangement", "\"lattice\"", "needs particles.fill = \"uniform\" or \"cosine\"");
    if (!box_shaped)
      throw ConfigError("particles.fill_arrangement", "\"lattice\"",
                        "needs domain.type = \"periodic_box\", \"box\" or \"free\"");
    if (pa.fill_count || pa.fill_mass)
      throw ConfigError(pa.fill_count ? "particles.fill_count" : "particles.fill_mass",
                        pa.fill_count ? std::to_string(*pa.fill_count) : shown(*pa.fill_mass),
                        "not used by fill_arrangement = \"lattice\" (the lattice of spacing dr sets the count)");
  }

  positive(c.physics.kappa, "physics.kappa");
  positive(c.physics.rho_ref, "physics.rho_ref");

  std::set<std::string> patches;
  for (std::size_t i = 0; i < c.boundary.size(); ++i) {
    const BoundarySpec& b = c.boundary[i];
    const std::string p = fmt::format("boundary[{}].", i);
    if (b.patch.empty()) throw ConfigError(p + "patch", "(missing)", "required: the name of a domain patch");
    if (!patches.insert(b.patch).second)
      throw ConfigError(p + "patch", quoted(b.patch), "patch already has a [[boundary]] entry");
    if (b.kind.empty()) throw ConfigError(p + "kind", "(missing)", "required: one of dirichlet, neumann, no_flux");
    if (b.kind == "no_flux" && b.value)
      throw ConfigError(p + "value", shown(*b.value), "not used by kind \"no_flux\" (remove it)");
    if (b.kind != "no_flux" && !b.value)
      throw ConfigError(p + "value", "(missing)",
                        b.kind == "dirichlet" ? "required: the boundary density g (>= 0)"
                                              : "required: the outward mass flux f (< 0 is inflow)");
    if (b.kind == "dirichlet") non_negative(*b.value, p + "value");
    non_negative(b.t_start, p + "t_start");
    if (b.t_end && !(*b.t_end > b.t_start))
      throw ConfigError(p + "t_end", shown(*b.t_end), "must be > t_start = " + shown(b.t_start));
    if (b.kind != "neumann" && (b.t_start != 0.0 || b.t_end))
      throw ConfigError(p + (b.t_end ? "t_end" : "t_start"), shown(b.t_end ? *b.t_end : b.t_start),
                        "activity windows are only supported for kind \"neumann\"");
  }

  const SolverSection& s = c.solver;
  if (!offered(s.backend, s.algorithm))
    throw ConfigError("solver.algorithm", quoted(s.algorithm),
                      "not offered by solver.backend = \"" + s.backend + "\" (allowed: " +
                          (s.backend == "ceres" ? "lbfgs, bfgs, nonlinear_cg" : "lbfgs, tnewton, var2, mma") + ")");
  if (s.width_mode == "per_particle" && s.stepper != "implicit")
    throw ConfigError("solver.width_mode", quoted(s.width_mode), "needs solver.stepper = \"implicit\"");
  if (s.time_scheme != "euler" && s.stepper != "implicit")
    throw ConfigError("solver.time_scheme", quoted(s.time_scheme),
                      "needs solver.stepper = \"implicit\" (explicit schemes: solver.explicit_scheme)");
  if (!(s.error_smoothing >= 0.0 && s.error_smoothing <= 3.0))
    throw ConfigError("solver.error_smoothing", shown(s.error_smoothing),
                      "must be in [0, 3] widths (the neighbour list reaches about 4.3 widths)");
  if (s.predictor != "none" && s.stepper != "implicit")
    throw ConfigError("solver.predictor", quoted(s.predictor), "needs solver.stepper = \"implicit\"");
  positive(s.displacement_tolerance, "solver.displacement_tolerance");
  if (!(s.relative_tolerance >= 0.0 && s.relative_tolerance <= 1.0))
    throw ConfigError("solver.relative_tolerance", shown(s.relative_tolerance), "must be in [0, 1] (0: absolute rule only)");
  at_least<std::int64_t>(s.max_iterations, 1, "solver.max_iterations");
  at_least<std::int64_t>(s.max_evaluations, 1, "solver.max_evaluations");
  at_least<std::int64_t>(s.lbfgs_memory, 1, "solver.lbfgs_memory");
  if (s.max_halvings < 0 || s.max_halvings > 20)
    throw ConfigError("solver.max_halvings", std::to_string(s.max_halvings), "must be in [0, 20]");
  if (s.max_iterations > std::numeric_limits<int>::max())
    throw ConfigError("solver.max_iterations", std::to_string(s.max_iterations), "out of range");
  if (s.max_evaluations > std::numeric_limits<int>::max())
    throw ConfigError("solver.max_evaluations", std::to_string(s.max_evaluations), "out of range");
  if (s.lbfgs_memory > 1000) throw ConfigError("solver.lbfgs_memory", std::to_string(s.lbfgs_memory), "must be <= 1000");
  non_negative(s.energy_tolerance, "solver.energy_tolerance");
  positive(s.barrier_factor, "solver.barrier_factor");
  if (s.barrier_stiffness) positive(*s.barrier_stiffness, "solver.barrier_stiffness");
  if (!(s.kernel_tolerance > 0.0 && s.kernel_tolerance < 1.0))
    throw ConfigError("solver.kernel_tolerance", shown(s.kernel_tolerance), "must be in (0, 1)");
  positive(s.skin_factor, "solver.skin_factor");

  const DiagnosticsSection& g = c.diagnostics;
  const TreatmentSection& t = c.treatment;
  positive(t.reservoir_width, "treatment.reservoir_width");
  if (t.reservoir_width > 10.0)
    throw ConfigError("treatment.reservoir_width", fmt::format("{}", t.reservoir_width),
                      "must be <= 10 (kernel cut-offs)");
  if (t.reservoir_sublayers < 0 || t.reservoir_sublayers > 1000)
    throw ConfigError("treatment.reservoir_sublayers", std::to_string(t.reservoir_sublayers),
                      "must be in [0, 1000] (0: about one spacing per sublayer)");
  if (g.M_inf) positive(*g.M_inf, "diagnostics.M_inf");
  if (g.J_inf) positive(*g.J_inf, "diagnostics.J_inf");
  if (g.reference_radius) positive(*g.reference_radius, "diagnostics.reference_radius");
  if (g.reference_length) positive(*g.reference_length, "diagnostics.reference_length");
  // cos(k (x - lo)) with k = 2 pi m / L is a mode of the periodic box and,
  // its slope vanishing at both ends, of a closed box (no-flux walls only).
  if (g.reference == "cosine_mode" && (type != "periodic_box" && type != "box"))
    throw ConfigError("diagnostics.reference", "\"cosine_mode\"",
                      "needs domain.type = \"periodic_box\" or a closed \"box\", and particles.fill = \"cosine\"");
  if (g.reference == "cosine_mode" && pa.fill != "cosine")
    throw ConfigError("diagnostics.reference", "\"cosine_mode\"", "needs particles.fill = \"cosine\"");
  if (g.reference == "cosine_mode" && type == "box")
    for (std::size_t i = 0; i < c.boundary.size(); ++i)
      if (c.boundary[i].kind != "no_flux")
        throw ConfigError(fmt::format("boundary[{}].kind", i), quoted(c.boundary[i].kind),
                          "diagnostics.reference = \"cosine_mode\" on a box needs every wall no-flux (a closed box)");
  if (g.reference == "cosine_mode" && !(pa.fill_amplitude > 0.0))
    throw ConfigError("particles.fill_amplitude", shown(pa.fill_amplitude),
                      "must be > 0 with diagnostics.reference = \"cosine_mode\" (the mode to follow)");
}

Config finish(toml::table& root, const std::vector<std::string>& overrides, const std::string& source) {
  check_structure(root);
  for (const std::string& o : overrides) apply_override(root, o);
  Config c = to_config(root);
  c.source = source;
  c.overrides = overrides;
  validate(c);
  return c;
}

std::string parse_error_text(const toml::parse_error& e, const std::string& source) {
  const auto& b = e.source().begin;
  return fmt::format("{}:{}:{}: TOML syntax error: {}", source, b.line, b.column, e.description());
}

}  // namespace

Config parse_config_file(const std::filesystem::path& file, const std::vector<std::string>& overrides) {
  std::ifstream in(file, std::ios::binary);
  if (!in) throw ConfigError("config", "\"" + file.string() + "\"", "cannot open the configuration file");
  std::ostringstream text;
  text << in.rdbuf();
  return parse_config_string(text.str(), overrides, file.string());
}

Config parse_config_string(std::string_view toml_text, const std::vector<std::string>& overrides,
                           const std::string& source) {
  toml::table root;
  try {
    root = toml::parse(toml_text, source);
  } catch (const toml::parse_error& e) {
    throw ConfigError("config", parse_error_text(e, source));
  }
  return finish(root, overrides, source);
}

std::vector<std::string> schema_keys() {
  std::vector<std::string> out;
  for (const KeySpec& k : schema()) out.push_back(k.path);
  return out;
}

std::string to_toml(const Config& c) {
  auto point = [](const Vec3& v) { return toml::array{v[0], v[1], v[2]}; };
  toml::table root;
  toml::table run{{"dim", c.run.dim},
                  {"t_end", c.run.t_end},
                  {"dt_factor", c.run.dt_factor},
                  {"seed", c.run.seed},
                  {"max_steps", c.run.max_steps},
                  {"dt_mode", c.run.dt_mode},
                  {"time_tolerance", c.run.time_tolerance},
                  {"vtk_interval", c.run.vtk_interval},
                  {"threads", c.run.threads}};
  if (c.run.dt) run.insert("dt", *c.run.dt);
  if (c.run.dt_min) run.insert("dt_min", *c.run.dt_min);
  if (c.run.dt_max) run.insert("dt_max", *c.run.dt_max);
  root.insert("run", std::move(run));

  const DomainSection& d = c.domain;
  toml::table dom{{"type", d.type},       {"center", point(d.center)}, {"radius", d.radius},
                  {"lo", point(d.lo)},     {"hi", point(d.hi)},         {"end_a", point(d.end_a)},
                  {"end_b", point(d.end_b)}, {"obstacle_axis", d.obstacle_axis}};
  if (d.obstacle_center) dom.insert("obstacle_center", point(*d.obstacle_center));
  if (d.obstacle_radius) dom.insert("obstacle_radius", *d.obstacle_radius);
  if (!d.subpatches.empty()) {
    toml::array subs;
    for (const SubPatchSpec& s : d.subpatches) {
      toml::table t{{"name", s.name}, {"on", s.on}, {"radius", s.radius}};
      if (s.center) t.insert("center", point(*s.center));
      subs.push_back(std::move(t));
    }
    dom.insert("subpatch", std::move(subs));
  }
  root.insert("domain", std::move(dom));

  const ParticlesSection& p = c.particles;
  toml::table par{{"n_inf", p.n_inf},
                  {"spacing_rule", p.spacing_rule},
                  {"beta_factor", p.beta_factor},
                  {"width_exponent", p.width_exponent},
                  {"width_reference_n", p.width_reference_n},
                  {"layer_b", p.layer_b},
                  {"length_L", p.length_L},
                  {"dirichlet_target", p.dirichlet_target},
                  {"fill", p.fill},
                  {"fill_sigma", p.fill_sigma},
                  {"fill_arrangement", p.fill_arrangement},
                  {"fill_amplitude", p.fill_amplitude},
                  {"fill_mode", p.fill_mode}};
  if (p.mass) par.insert("mass", *p.mass);
  if (p.fill_count) par.insert("fill_count", *p.fill_count);
  if (p.fill_mass) par.insert("fill_mass", *p.fill_mass);
  if (p.fill_center) par.insert("fill_center", point(*p.fill_center));
  root.insert("particles", std::move(par));

  root.insert("physics", toml::table{{"kappa", c.physics.kappa},
                                     {"rho_ref", c.physics.rho_ref},
                                     {"velocity", point(c.physics.velocity)},
                                     {"source_rate", c.physics.source_rate}});
  if (!c.boundary.empty()) {
    toml::array bs;
    for (const BoundarySpec& b : c.boundary) {
      toml::table t{{"patch", b.patch}, {"kind", b.kind}};
      if (b.value) t.insert("value", *b.value);
      if (b.kind == "neumann") t.insert("t_start", b.t_start);
      if (b.t_end) t.insert("t_end", *b.t_end);
      bs.push_back(std::move(t));
    }
    root.insert("boundary", std::move(bs));
  }
  const SolverSection& s = c.solver;
  toml::table sol{{"stepper", s.stepper},
                  {"backend", s.backend},
                  {"algorithm", s.algorithm},
                  {"explicit_scheme", s.explicit_scheme},
                  {"width_mode", s.width_mode},
                  {"width_metric", s.width_metric},
                  {"time_scheme", s.time_scheme},
                  {"predictor", s.predictor},
                  {"error_smoothing", s.error_smoothing},
                  {"displacement_tolerance", s.displacement_tolerance},
                  {"relative_tolerance", s.relative_tolerance},
                  {"max_iterations", s.max_iterations},
                  {"max_evaluations", s.max_evaluations},
                  {"lbfgs_memory", s.lbfgs_memory},
                  {"max_halvings", s.max_halvings},
                  {"energy_tolerance", s.energy_tolerance},
                  {"barrier_factor", s.barrier_factor},
                  {"kernel_tolerance", s.kernel_tolerance},
                  {"skin_factor", s.skin_factor}};
  if (s.barrier_stiffness) sol.insert("barrier_stiffness", *s.barrier_stiffness);
  root.insert("solver", std::move(sol));
  const TreatmentSection& tr = c.treatment;
  root.insert("treatment", toml::table{{"preset", tr.preset},
                                       {"no_flux", tr.no_flux},
                                       {"dirichlet", tr.dirichlet},
                                       {"reservoir_width", tr.reservoir_width},
                                       {"reservoir_sublayers", tr.reservoir_sublayers},
                                       {"reservoir_profile", tr.reservoir_profile},
                                       {"neumann_outflow", tr.neumann_outflow},
                                       {"stranded", tr.stranded}});
  const DiagnosticsSection& g = c.diagnostics;
  toml::table dia{{"reference", g.reference}};
  if (g.center) dia.insert("center", point(*g.center));
  if (g.M_inf) dia.insert("M_inf", *g.M_inf);
  if (g.J_inf) dia.insert("J_inf", *g.J_inf);
  if (g.reference_radius) dia.insert("reference_radius", *g.reference_radius);
  if (g.reference_length) dia.insert("reference_length", *g.reference_length);
  root.insert("diagnostics", std::move(dia));
  std::ostringstream os;
  os << root;
  return os.str();
}

}  // namespace otfp::app
