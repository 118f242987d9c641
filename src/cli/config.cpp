#include "otfp_app/config.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <fmt/format.h>

#include <algorithm>
#include <charconv>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <functional>
#include <initializer_list>
#include <limits>
#include <set>
#include <sstream>
#include <type_traits>
#include <variant>
#include <toml++/toml.h>

#include "otfp/boundary.hpp"
#include "otfp/explicit_stepper.hpp"
#include "otfp/implicit_stepper.hpp"
#include "otfp/minimizer.hpp"

namespace otfp::app {

namespace {
// A message is one line whatever it echoes (a patch name "a\nb" given in the
// file, a sub-patch name inside a list of patches): control characters become
// \xHH. Idempotent on text already escaped (it holds none).
std::string one_line(std::string s) {
  std::string out;
  for (const char ch : s) {
    const auto u = static_cast<unsigned char>(ch);
    if (u < 0x20 || u == 0x7f)
      out += fmt::format("\\x{:02x}", u);
    else
      out += ch;
  }
  return out;
}
}  // namespace

ConfigError::ConfigError(const std::string& key, const std::string& value, const std::string& rule)
    : std::runtime_error(one_line(key + " = " + value + ": " + rule)), key_(key) {}
ConfigError::ConfigError(const std::string& key, const std::string& message)
    : std::runtime_error(one_line(message)), key_(key) {}

namespace {

namespace fs = std::filesystem;

// ------------------------------------------------------------------ values

enum class Kind { Int, Float, String, Point };

// The value of one key: absent (an optional key not given), an integer, a
// number, a string or a point.
using Value = std::variant<std::monostate, std::int64_t, double, std::string, Vec3>;

std::string format_double(double v) {
  if (std::isnan(v)) return "nan";
  if (std::isinf(v)) return v > 0 ? "inf" : "-inf";
  return fmt::format("{}", v);
}
std::string shown(double v) { return format_double(v); }
std::string shown(const Vec3& v) {
  return "[" + format_double(v[0]) + ", " + format_double(v[1]) + ", " + format_double(v[2]) + "]";
}
// Control characters as escapes (\n, \t, \r, \xHH), so that an echoed value
// keeps an error message on one line and shows what was given.
std::string escaped(const std::string& s) {
  std::string out;
  for (const char ch : s) {
    const auto u = static_cast<unsigned char>(ch);
    if (ch == '\n')
      out += "\\n";
    else if (ch == '\t')
      out += "\\t";
    else if (ch == '\r')
      out += "\\r";
    else if (u < 0x20 || u == 0x7f)
      out += fmt::format("\\x{:02x}", u);
    else
      out += ch;
  }
  return out;
}
bool has_control_character(const std::string& s) {
  return std::any_of(s.begin(), s.end(), [](char ch) {
    const auto u = static_cast<unsigned char>(ch);
    return u < 0x20 || u == 0x7f;
  });
}
std::string quoted(const std::string& s) {
  // Appended piece by piece: GCC 12 warns (-Wrestrict, a false positive) on "\"" + t + "\"" at -O3.
  std::string out(1, '"');
  out.append(escaped(s));
  out.push_back('"');
  return out;
}
std::string shown(const Value& v) {
  if (const auto* i = std::get_if<std::int64_t>(&v)) return std::to_string(*i);
  if (const auto* d = std::get_if<double>(&v)) return shown(*d);
  if (const auto* s = std::get_if<std::string>(&v)) return quoted(*s);
  if (const auto* p = std::get_if<Vec3>(&v)) return shown(*p);
  return "(absent)";
}

// Required keys of an array of tables are "missing" while empty (strings) or NaN (numbers).
bool is_missing(const Value& v) {
  if (const auto* s = std::get_if<std::string>(&v)) return s->empty();
  if (const auto* d = std::get_if<double>(&v)) return std::isnan(*d);
  return std::holds_alternative<std::monostate>(v);
}

// Member types <-> Value.
template <class T> struct KindOf;
template <> struct KindOf<int> { static constexpr Kind value = Kind::Int; };
template <> struct KindOf<std::int64_t> { static constexpr Kind value = Kind::Int; };
template <> struct KindOf<double> { static constexpr Kind value = Kind::Float; };
template <> struct KindOf<std::string> { static constexpr Kind value = Kind::String; };
template <> struct KindOf<Vec3> { static constexpr Kind value = Kind::Point; };
template <class T> struct KindOf<std::optional<T>> { static constexpr Kind value = KindOf<T>::value; };

template <class T> struct IsOptional : std::false_type {};
template <class T> struct IsOptional<std::optional<T>> : std::true_type {};

Value to_value(int v) { return std::int64_t{v}; }
Value to_value(std::int64_t v) { return v; }
Value to_value(double v) { return v; }
Value to_value(const std::string& v) { return v; }
Value to_value(const Vec3& v) { return v; }
template <class T>
Value to_value(const std::optional<T>& v) {
  return v ? to_value(*v) : Value{};
}

// `v` has the kind of the member (the parser checked it).
void assign(const Value& v, std::int64_t& out, const std::string&) { out = std::get<std::int64_t>(v); }
void assign(const Value& v, double& out, const std::string&) { out = std::get<double>(v); }
void assign(const Value& v, std::string& out, const std::string&) { out = std::get<std::string>(v); }
void assign(const Value& v, Vec3& out, const std::string&) { out = std::get<Vec3>(v); }
void assign(const Value& v, int& out, const std::string& display) {
  const std::int64_t i = std::get<std::int64_t>(v);
  if (i < std::numeric_limits<int>::min() || i > std::numeric_limits<int>::max())
    throw ConfigError(display, std::to_string(i), "out of range");
  out = static_cast<int>(i);
}
template <class T>
void assign(const Value& v, std::optional<T>& out, const std::string& display) {
  if (std::holds_alternative<std::monostate>(v)) {
    out.reset();
    return;
  }
  T x{};
  assign(v, x, display);
  out = x;
}

// ------------------------------------------------------------------ rules

// The range rule of one key: lo < v (or <=) and v < hi (or <=). The message
// names the side that is broken ("must be > 0", "must be <= 1000") unless
// `text` is the message for either side; `above` replaces the upper one.
struct Rule {
  double lo = -std::numeric_limits<double>::infinity();
  double hi = std::numeric_limits<double>::infinity();
  bool lo_open = false, hi_open = false;
  std::string text;
  std::string above;
  std::string doc;                          // short form (docs/configuration.md); generated when empty
  std::function<bool(const Config&)> when;  // the rule holds only where this is true (default: always)

  bool has_lo() const { return std::isfinite(lo); }
  bool has_hi() const { return std::isfinite(hi); }
  bool empty() const { return !has_lo() && !has_hi(); }
  std::string lower_message() const { return fmt::format("must be {} {}", lo_open ? ">" : ">=", format_double(lo)); }
  std::string upper_message() const {
    return above.empty() ? fmt::format("must be {} {}", hi_open ? "<" : "<=", format_double(hi)) : above;
  }
  std::string short_form() const {
    if (!doc.empty()) return doc;
    if (has_lo() && has_hi())
      return fmt::format("in {}{}, {}{}", lo_open ? "(" : "[", format_double(lo), format_double(hi), hi_open ? ")" : "]");
    if (has_lo()) return fmt::format("{} {}", lo_open ? ">" : ">=", format_double(lo));
    if (has_hi()) return fmt::format("{} {}", hi_open ? "<" : "<=", format_double(hi));
    return "";
  }
  // "" if x obeys the rule, else the message.
  std::string broken_by(double x) const {
    const bool low = has_lo() && !(lo_open ? x > lo : x >= lo);
    const bool high = has_hi() && !(hi_open ? x < hi : x <= hi);
    if (!low && !high) return "";
    if (!text.empty()) return text;
    return low ? lower_message() : upper_message();
  }
};

Rule greater(double lo) {
  Rule r;
  r.lo = lo;
  r.lo_open = true;
  return r;
}
Rule at_least(double lo) {
  Rule r;
  r.lo = lo;
  return r;
}
// [lo, hi] with "(" / ")" for open ends, e.g. interval('(', 0, 2, ']', "must be in (0, 2] ...").
Rule interval(char open, double lo, double hi, char close, std::string text = "") {
  Rule r;
  r.lo = lo;
  r.hi = hi;
  r.lo_open = open == '(';
  r.hi_open = close == ')';
  r.text = std::move(text);
  return r;
}

// ------------------------------------------------------------------ the table

// Where a key's member lives: a section of Config, or entry i of an array of tables.
enum class Scope { Section, SubPatch, Boundary };

template <class O> struct Owner;
template <> struct Owner<RunSection> {
  static constexpr Scope scope = Scope::Section;
  template <class C> static auto& of(C& c, std::size_t) { return c.run; }
};
template <> struct Owner<DomainSection> {
  static constexpr Scope scope = Scope::Section;
  template <class C> static auto& of(C& c, std::size_t) { return c.domain; }
};
template <> struct Owner<SubPatchSpec> {
  static constexpr Scope scope = Scope::SubPatch;
  template <class C> static auto& of(C& c, std::size_t i) { return c.domain.subpatches[i]; }
};
template <> struct Owner<ParticlesSection> {
  static constexpr Scope scope = Scope::Section;
  template <class C> static auto& of(C& c, std::size_t) { return c.particles; }
};
template <> struct Owner<PhysicsSection> {
  static constexpr Scope scope = Scope::Section;
  template <class C> static auto& of(C& c, std::size_t) { return c.physics; }
};
template <> struct Owner<BoundarySpec> {
  static constexpr Scope scope = Scope::Boundary;
  template <class C> static auto& of(C& c, std::size_t i) { return c.boundary[i]; }
};
template <> struct Owner<SolverSection> {
  static constexpr Scope scope = Scope::Section;
  template <class C> static auto& of(C& c, std::size_t) { return c.solver; }
};
template <> struct Owner<TreatmentSection> {
  static constexpr Scope scope = Scope::Section;
  template <class C> static auto& of(C& c, std::size_t) { return c.treatment; }
};
template <> struct Owner<DiagnosticsSection> {
  static constexpr Scope scope = Scope::Section;
  template <class C> static auto& of(C& c, std::size_t) { return c.diagnostics; }
};

// One key: its path, kind, member of Config, default, choices and rule.
struct Field {
  std::string path;     // "run.dim", "boundary[].kind", "domain.subpatch[].name"
  std::string section;  // "run", "boundary", "domain" (subpatches: the domain's array "subpatch")
  std::string key;      // "dim", "kind", "name"
  Scope scope = Scope::Section;
  Kind kind = Kind::Float;
  bool optional = false;             // a std::optional member: absent unless given
  std::string required;              // array keys that must be given: the rule shown when missing
  std::vector<std::string> choices;  // allowed strings (empty: any)
  Rule rule;
  Value fallback;  // the member's in-class default
  std::function<Value(const Config&, std::size_t)> get;
  std::function<void(Config&, std::size_t, const Value&, const std::string&)> set;
  std::function<bool(const Config&, std::size_t)> in_toml;  // to_toml writes the key only where true (default: always)

  Field& with(Rule r) {
    rule = std::move(r);
    return *this;
  }
  Field& one_of(std::vector<std::string> c) {
    choices = std::move(c);
    return *this;
  }
  Field& needed(std::string rule_when_missing) {
    required = std::move(rule_when_missing);
    return *this;
  }
  Field& written_if(std::function<bool(const Config&, std::size_t)> f) {
    in_toml = std::move(f);
    return *this;
  }
};

template <class O, class M>
Field key(std::string path, M O::*member) {
  Field f;
  f.path = std::move(path);
  f.scope = Owner<O>::scope;
  const std::size_t dot = f.path.rfind('.');
  f.key = f.path.substr(dot + 1);
  f.section = f.path.substr(0, f.path.find_first_of(".["));
  f.kind = KindOf<M>::value;
  f.optional = IsOptional<M>::value;
  f.fallback = to_value(O{}.*member);
  f.get = [member](const Config& c, std::size_t i) { return to_value(Owner<O>::of(c, i).*member); };
  f.set = [member](Config& c, std::size_t i, const Value& v, const std::string& display) {
    assign(v, Owner<O>::of(c, i).*member, display);
  };
  return f;
}

// The names of a library enum, in the order given.
template <class E>
std::vector<std::string> names(std::initializer_list<E> values) {
  std::vector<std::string> out;
  for (E e : values) out.push_back(to_string(e));
  return out;
}

bool domain_is(const Config& c, std::initializer_list<const char*> types) {
  for (const char* t : types)
    if (c.domain.type == t) return true;
  return false;
}

const std::vector<Field>& fields() {
  static const std::vector<Field> table = [] {
    Rule dim = interval('[', 1, 3, ']', "must be 1, 2 or 3");
    dim.doc = "1, 2 or 3";
    Rule radius = greater(0);
    radius.when = [](const Config& c) { return domain_is(c, {"ball", "cylinder"}); };
    Rule obstacle_radius = greater(0);
    obstacle_radius.when = [](const Config& c) { return domain_is(c, {"square_pipe_obstacle"}); };
    Rule solver_cap = at_least(1);  // the library's caps are int
    solver_cap.hi = std::numeric_limits<int>::max();
    solver_cap.above = "out of range";
    solver_cap.doc = ">= 1";
    Rule reservoir_width = interval('(', 0, 10, ']');
    reservoir_width.above = "must be <= 10 (kernel cut-offs)";
    const auto neumann_only = [](const Config& c, std::size_t i) { return c.boundary[i].kind == "neumann"; };
    // fill = "file": the file gives the particles, the keys of the other fills do not apply.
    const auto not_from_file = [](const Config& c, std::size_t) { return c.particles.fill != "file"; };

    return std::vector<Field>{
        key("run.dim", &RunSection::dim).with(dim),
        key("run.t_end", &RunSection::t_end).with(greater(0)),
        key("run.dt", &RunSection::dt).with(greater(0)),
        key("run.dt_factor", &RunSection::dt_factor).with(greater(0)),
        key("run.seed", &RunSection::seed).with(at_least(0)),
        key("run.max_steps", &RunSection::max_steps).with(at_least(0)),
        key("run.dt_mode", &RunSection::dt_mode).one_of({"fixed", "adaptive"}),
        key("run.time_tolerance", &RunSection::time_tolerance).with(greater(0)),
        key("run.dt_min", &RunSection::dt_min).with(greater(0)),
        key("run.dt_max", &RunSection::dt_max).with(greater(0)),
        key("run.vtk_interval", &RunSection::vtk_interval).with(at_least(0)),
        key("run.checkpoint_interval", &RunSection::checkpoint_interval).with(at_least(0)),
        key("run.max_particles", &RunSection::max_particles).with(at_least(0)),
        key("run.threads", &RunSection::threads).with(interval('[', 0, 4096, ']', "must be in [0, 4096] (0: OpenMP default)")),
        key("domain.type", &DomainSection::type)
            .one_of({"ball", "box", "cylinder", "periodic_box", "square_pipe_obstacle", "free"}),
        key("domain.center", &DomainSection::center),
        key("domain.radius", &DomainSection::radius).with(radius),
        key("domain.lo", &DomainSection::lo),
        key("domain.hi", &DomainSection::hi),
        key("domain.end_a", &DomainSection::end_a),
        key("domain.end_b", &DomainSection::end_b),
        key("domain.obstacle_center", &DomainSection::obstacle_center),
        key("domain.obstacle_radius", &DomainSection::obstacle_radius).with(obstacle_radius),
        key("domain.obstacle_axis", &DomainSection::obstacle_axis).one_of({"x", "y", "z"}),
        key("domain.subpatch[].name", &SubPatchSpec::name).needed("required, a non-empty patch name"),
        key("domain.subpatch[].on", &SubPatchSpec::on).needed("required: the name of the patch it lies on"),
        key("domain.subpatch[].center", &SubPatchSpec::center),
        key("domain.subpatch[].radius", &SubPatchSpec::radius).needed("required, > 0").with(greater(0)),
        key("particles.n_inf", &ParticlesSection::n_inf).with(at_least(1)),
        key("particles.mass", &ParticlesSection::mass).with(greater(0)),
        key("particles.spacing_rule", &ParticlesSection::spacing_rule).one_of(names({SpacingRule::Cube, SpacingRule::SphereRadius})),
        key("particles.beta_factor", &ParticlesSection::beta_factor).with(greater(0)),
        key("particles.width_exponent", &ParticlesSection::width_exponent)
            .with(interval('(', 0, 2, ']',
                           "must be in (0, 2] (s = s_rule(dr) (dr / dr_ref)^(q - 1); 1: the papers' fixed beta dr^2)")),
        key("particles.width_reference_n", &ParticlesSection::width_reference_n).with(at_least(1)),
        key("particles.layer_b", &ParticlesSection::layer_b).with(at_least(0)),
        key("particles.length_L", &ParticlesSection::length_L).with(at_least(0)),
        key("particles.dirichlet_target", &ParticlesSection::dirichlet_target).one_of(names({DirichletTarget::CellIntegral, DirichletTarget::PaperEq34})),
        key("particles.fill", &ParticlesSection::fill).one_of({"empty", "uniform", "gaussian", "cosine", "file"}),
        key("particles.fill_file", &ParticlesSection::fill_file),
        key("particles.fill_arrangement", &ParticlesSection::fill_arrangement)
            .one_of({"random", "lattice"})
            .written_if(not_from_file),
        key("particles.fill_amplitude", &ParticlesSection::fill_amplitude)
            .with(interval('[', 0, 1, ')', "must be in [0, 1) (density 1 + a cos(k x) > 0)"))
            .written_if(not_from_file),
        key("particles.fill_mode", &ParticlesSection::fill_mode).with(at_least(1)).written_if(not_from_file),
        key("particles.fill_count", &ParticlesSection::fill_count).with(at_least(0)),
        key("particles.fill_mass", &ParticlesSection::fill_mass).with(at_least(0)),
        key("particles.fill_center", &ParticlesSection::fill_center),
        key("particles.fill_sigma", &ParticlesSection::fill_sigma).with(greater(0)).written_if(not_from_file),
        key("physics.kappa", &PhysicsSection::kappa).with(greater(0)),
        key("physics.rho_ref", &PhysicsSection::rho_ref).with(greater(0)),
        key("physics.velocity", &PhysicsSection::velocity),
        key("physics.source_rate", &PhysicsSection::source_rate),
        key("boundary[].patch", &BoundarySpec::patch).needed("required: the name of a domain patch"),
        key("boundary[].kind", &BoundarySpec::kind)
            .one_of(names({PatchKind::Dirichlet, PatchKind::Neumann, PatchKind::NoFlux}))
            .needed("required: one of dirichlet, neumann, no_flux"),
        key("boundary[].value", &BoundarySpec::value),
        key("boundary[].t_start", &BoundarySpec::t_start).with(at_least(0)).written_if(neumann_only),
        key("boundary[].t_end", &BoundarySpec::t_end),
        key("solver.stepper", &SolverSection::stepper).one_of({"implicit", "explicit"}),
        key("solver.backend", &SolverSection::backend).one_of(names({Backend::Ceres, Backend::Nlopt})),
        key("solver.algorithm", &SolverSection::algorithm)
            .one_of(names({Algorithm::Lbfgs, Algorithm::Bfgs, Algorithm::NonlinearCg, Algorithm::TruncatedNewton,
                           Algorithm::Var2, Algorithm::Mma})),
        key("solver.explicit_scheme", &SolverSection::explicit_scheme)
            .one_of(names({ExplicitScheme::EulerForce27, ExplicitScheme::Rk4Force27, ExplicitScheme::EulerExactGradient})),
        key("solver.width_mode", &SolverSection::width_mode).one_of(names({WidthMode::Fixed, WidthMode::PerParticle})),
        key("solver.width_metric", &SolverSection::width_metric).one_of(names({WidthMetric::AsPrinted, WidthMetric::ExactGaussian})),
        key("solver.time_scheme", &SolverSection::time_scheme).one_of(names({TimeScheme::Euler, TimeScheme::Bdf2})),
        key("solver.predictor", &SolverSection::predictor)
            .one_of(names({Predictor::None, Predictor::Extrapolate, Predictor::Damped})),
        key("solver.error_measure", &SolverSection::error_measure)
            .one_of(names({ErrorMeasure::Density, ErrorMeasure::Displacement})),
        key("solver.stopping_norm", &SolverSection::stopping_norm)
            .one_of(names({StoppingNorm::Energy, StoppingNorm::Max})),
        key("solver.max_norm_factor", &SolverSection::max_norm_factor).with(at_least(1)),
        key("solver.error_smoothing", &SolverSection::error_smoothing)
            .with(interval('[', 0, 3, ']', "must be in [0, 3] widths (the neighbour list reaches about 4.3 widths)")),
        key("solver.displacement_tolerance", &SolverSection::displacement_tolerance).with(greater(0)),
        key("solver.relative_tolerance", &SolverSection::relative_tolerance)
            .with(interval('[', 0, 1, ']', "must be in [0, 1] (0: absolute rule only)")),
        key("solver.max_iterations", &SolverSection::max_iterations).with(solver_cap),
        key("solver.max_evaluations", &SolverSection::max_evaluations).with(solver_cap),
        key("solver.lbfgs_memory", &SolverSection::lbfgs_memory).with(interval('[', 1, 1000, ']')),
        key("solver.max_halvings", &SolverSection::max_halvings).with(interval('[', 0, 20, ']', "must be in [0, 20]")),
        key("solver.energy_tolerance", &SolverSection::energy_tolerance).with(at_least(0)),
        key("solver.barrier_factor", &SolverSection::barrier_factor).with(greater(0)),
        key("solver.barrier_stiffness", &SolverSection::barrier_stiffness).with(greater(0)),
        key("solver.kernel_tolerance", &SolverSection::kernel_tolerance).with(interval('(', 0, 1, ')', "must be in (0, 1)")),
        key("solver.skin_factor", &SolverSection::skin_factor).with(greater(0)),
        key("solver.max_width_factor", &SolverSection::max_width_factor)
            .with(interval('[', 0, 1e6, ']', "must be 0 (off) or in (1, 1e6]")),
        key("treatment.preset", &TreatmentSection::preset).one_of({"converging", "papers"}),
        key("treatment.no_flux", &TreatmentSection::no_flux).one_of({"barrier", "images"}),
        key("treatment.dirichlet", &TreatmentSection::dirichlet)
            .one_of(names({DirichletMode::Layer, DirichletMode::Reservoir})),
        key("treatment.reservoir_width", &TreatmentSection::reservoir_width).with(reservoir_width),
        key("treatment.reservoir_sublayers", &TreatmentSection::reservoir_sublayers)
            .with(interval('[', 0, 1000, ']', "must be in [0, 1000] (0: about one spacing per sublayer)")),
        key("treatment.reservoir_profile", &TreatmentSection::reservoir_profile)
            .one_of(names({ReservoirProfile::Uniform, ReservoirProfile::Odd})),
        key("treatment.reservoir_control", &TreatmentSection::reservoir_control)
            .one_of(names({ReservoirControl::Quiet, ReservoirControl::Exact})),
        key("treatment.reservoir_tolerance", &TreatmentSection::reservoir_tolerance)
            .with(interval('[', 0.5, 1e6, ']', "must be in [0.5, 1000000] (particles)")),
        key("treatment.reservoir_candidates", &TreatmentSection::reservoir_candidates)
            .with(interval('[', 1, 1000, ']', "must be in [1, 1000] (candidate points per target particle)")),
        key("treatment.neumann_outflow", &TreatmentSection::neumann_outflow).one_of({"layer", "nearest"}),
        key("treatment.stranded", &TreatmentSection::stranded).one_of({"keep", "absorb"}),
        key("diagnostics.center", &DiagnosticsSection::center),
        key("diagnostics.M_inf", &DiagnosticsSection::M_inf).with(greater(0)),
        key("diagnostics.J_inf", &DiagnosticsSection::J_inf).with(greater(0)),
        key("diagnostics.reference", &DiagnosticsSection::reference)
            .one_of({"none", "crank_sphere", "crank_slab", "free_space", "cosine_mode"}),
        key("diagnostics.reference_radius", &DiagnosticsSection::reference_radius).with(greater(0)),
        key("diagnostics.reference_length", &DiagnosticsSection::reference_length).with(greater(0)),
    };
  }();
  return table;
}

const std::vector<std::string> kSections = {"run", "domain", "particles", "physics", "boundary", "solver",
                                            "treatment", "diagnostics"};

const Field* find_spec(const std::string& path) {
  for (const Field& k : fields())
    if (k.path == path) return &k;
  return nullptr;
}

std::string join(const std::vector<std::string>& v, const char* sep = ", ") {
  std::string out;
  for (std::size_t i = 0; i < v.size(); ++i) out += (i ? sep : "") + v[i];
  return out;
}


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
void check_kind(const toml::node& n, const Field& spec, const std::string& key, const std::string& given = "") {
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
    std::size_t i = 0;
    const auto [end, ec] = std::from_chars(sel.data(), sel.data() + sel.size(), i);
    if (ec != std::errc() || end != sel.data() + sel.size() || i > arr.size())
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

// A --set key: section.key, boundary.<index or patch>.key,
// domain.subpatch.<index or name>.key, with boundary[...] and subpatch[...]
// as the bracket forms; segments of letters, digits, '_', '+' and '-'.
bool well_formed_key(const std::string& path) {
  const auto word = [](char ch) {
    return (ch >= 'a' && ch <= 'z') || (ch >= 'A' && ch <= 'Z') || (ch >= '0' && ch <= '9') || ch == '_' ||
           ch == '+' || ch == '-';
  };
  std::size_t i = 0;
  for (;;) {
    const std::size_t start = i;
    while (i < path.size() && word(path[i])) ++i;
    if (i == start) return false;
    if (i < path.size() && path[i] == '[') {
      const std::string seg = path.substr(start, i - start);
      if (seg != "boundary" && seg != "subpatch") return false;
      const std::size_t sel = ++i;
      while (i < path.size() && word(path[i])) ++i;
      if (i == sel || i == path.size() || path[i] != ']') return false;
      ++i;
    }
    if (i == path.size()) return true;
    if (path[i] != '.') return false;
    ++i;
  }
}

void apply_override(toml::table& root, const std::string& assignment) {
  const auto eq = assignment.find('=');
  if (eq == std::string::npos || eq == 0)
    throw ConfigError("--set", quoted(assignment), "must have the form key=value");
  const std::string path = assignment.substr(0, eq);
  const std::string text = assignment.substr(eq + 1);
  if (!well_formed_key(path))
    throw ConfigError(escaped(path), quoted(text),
                      "malformed key (the forms are section.key, boundary.<index or patch>.key or "
                      "boundary[<index>].key, domain.subpatch.<index or name>.key)");
  if (has_control_character(text))
    throw ConfigError(path, quoted(text), "must not contain control characters (newline, tab, ...)");
  const std::vector<std::string> seg = split_path(path);
  for (const std::string& s : seg)
    if (s.empty()) throw ConfigError(path, quoted(text), "malformed key path");

  toml::table* target = nullptr;
  std::string spec_path, display;
  const std::string& section = seg[0];
  if (section == "boundary") {
    if (seg.size() != 3)
      throw ConfigError(path, quoted(text), "must be boundary.<index or patch name>.<key>");
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
        throw ConfigError(path, quoted(text), "must be domain.subpatch.<index or name>.<key>");
      std::size_t idx = 0;
      target = &select_entry(array_of_tables(*sec, "subpatch", "domain.subpatch"), seg[2], "name",
                             "domain.subpatch", text, idx);
      spec_path = "domain.subpatch[]." + seg[3];
      display = fmt::format("domain.subpatch[{}].{}", idx, seg[3]);
    } else {
      if (seg.size() != 2) throw ConfigError(path, quoted(text), "unknown key");
      target = sec;
      spec_path = path;
      display = path;
    }
  } else {
    throw ConfigError(path, quoted(text), "unknown section (allowed: " + join(kSections) + ")");
  }
  const Field* spec = find_spec(spec_path);
  if (!spec) {
    const std::string prefix = spec_path.substr(0, spec_path.rfind('.') + 1);
    throw ConfigError(display, quoted(text), unknown_key_rule(prefix, spec_path.substr(prefix.size())));
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
      throw ConfigError(display, quoted(text), "not a TOML value; " + kind_rule(*spec));
    parsed = toml::table{{"v", text}};
  }
  const toml::node& n = *parsed.get("v");
  // Numbers are echoed as written (3.0, 1e3), not as read back.
  check_kind(n, *spec, display, spec->kind == Kind::Int || spec->kind == Kind::Float ? text : "");
  switch (spec->kind) {
    case Kind::Int: target->insert_or_assign(key, n.as_integer()->get()); break;
    case Kind::Float: target->insert_or_assign(key, number_of(n)); break;
    case Kind::String: target->insert_or_assign(key, n.as_string()->get()); break;
    case Kind::Point: {
      toml::array a;
      for (const toml::node& e : *n.as_array()) a.push_back(number_of(e));
      target->insert_or_assign(key, std::move(a));
      break;
    }
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

// How many entries a key of this scope has in `c` (a section key: one).
std::size_t entries(const Config& c, Scope scope) {
  switch (scope) {
    case Scope::Section: return 1;
    case Scope::SubPatch: return c.domain.subpatches.size();
    case Scope::Boundary: return c.boundary.size();
  }
  return 0;
}

// The name of key `f` of entry i in messages: "run.dim", "boundary[0].kind".
std::string display_name(const Field& f, std::size_t i) {
  switch (f.scope) {
    case Scope::Section: return f.path;
    case Scope::SubPatch: return fmt::format("domain.subpatch[{}].{}", i, f.key);
    case Scope::Boundary: return fmt::format("boundary[{}].{}", i, f.key);
  }
  return f.path;
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
  const bool papers = t.preset == "papers";
  t.no_flux = papers ? "barrier" : "images";
  t.dirichlet = papers ? "layer" : "reservoir";
  t.reservoir_profile = papers ? "uniform" : "odd";
  t.neumann_outflow = papers ? "layer" : "nearest";
  t.stranded = "keep";
  c.particles.spacing_rule = papers && c.run.dim == 3 ? "sphere_radius" : "cube";
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
  if (p.fill == "file")
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

// ------------------------------------------------------------------ validation

// Every key's own rule (and the required keys of the arrays of tables).
void check_rules(const Config& c) {
  const auto check = [&c](const Field& f, std::size_t i) {
    const std::string name = display_name(f, i);
    const Value v = f.get(c, i);
    if (!f.required.empty() && is_missing(v)) throw ConfigError(name, "(missing)", f.required);
    if (f.rule.empty() || (f.rule.when && !f.rule.when(c))) return;
    double x = 0.0;
    if (const auto* n = std::get_if<std::int64_t>(&v))
      x = static_cast<double>(*n);
    else if (const auto* d = std::get_if<double>(&v))
      x = *d;
    else
      return;  // absent
    const std::string broken = f.rule.broken_by(x);
    if (!broken.empty()) throw ConfigError(name, shown(v), broken);
  };
  for (const Field& f : fields())
    if (f.scope == Scope::Section) check(f, 0);
  // The arrays of tables entry by entry.
  for (const Scope scope : {Scope::SubPatch, Scope::Boundary})
    for (std::size_t i = 0; i < entries(c, scope); ++i)
      for (const Field& f : fields())
        if (f.scope == scope) check(f, i);
}

bool offered(const std::string& backend, const std::string& algorithm) {
  if (algorithm == "lbfgs") return true;
  if (backend == "ceres") return algorithm == "bfgs" || algorithm == "nonlinear_cg";
  return algorithm == "tnewton" || algorithm == "var2" || algorithm == "mma";
}

// The rules that combine keys (each key's own rule is in the table).
void validate(const Config& c) {
  check_rules(c);

  const RunSection& r = c.run;
  // A floor a tiny tolerance can reach: more than 1e9 steps, and t + dt_min
  // may not advance t at all (exit 1 "dt = 0" after the files were written).
  if (r.dt_min && !(*r.dt_min >= 1e-9 * r.t_end))
    throw ConfigError("run.dt_min", shown(*r.dt_min),
                      fmt::format("must be >= 1e-9 x run.t_end = {} (at most 1e9 steps)", shown(1e-9 * r.t_end)));
  if (r.dt_min && r.dt_max && *r.dt_max < *r.dt_min)
    throw ConfigError("run.dt_max", shown(*r.dt_max), fmt::format("must be >= run.dt_min = {}", shown(*r.dt_min)));
  if (r.dt_mode == "adaptive" && c.solver.stepper != "implicit")
    throw ConfigError("run.dt_mode", quoted(r.dt_mode),
                      "needs solver.stepper = \"implicit\" (the explicit schemes have no error estimate)");

  const DomainSection& d = c.domain;
  const std::string& type = d.type;
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
    if (r.dim == 2 && d.obstacle_axis != "z")
      throw ConfigError("domain.obstacle_axis", quoted(d.obstacle_axis), "must be \"z\" in 2D (a disc obstacle)");
  }
  std::set<std::string> sub_names;
  for (std::size_t i = 0; i < d.subpatches.size(); ++i) {
    const SubPatchSpec& s = d.subpatches[i];
    if (!sub_names.insert(s.name).second)
      throw ConfigError(fmt::format("domain.subpatch[{}].name", i), quoted(s.name), "duplicate sub-patch name");
  }

  const ParticlesSection& pa = c.particles;
  if (pa.spacing_rule == "sphere_radius" && r.dim != 3)
    throw ConfigError("particles.spacing_rule", quoted(pa.spacing_rule), "needs run.dim = 3 (use \"cube\")");
  if (pa.fill == "file" && !pa.fill_file)
    throw ConfigError("particles.fill_file", "(missing)", "required with particles.fill = \"file\"");
  if (pa.fill != "file" && pa.fill_file)
    throw ConfigError("particles.fill_file", quoted(*pa.fill_file),
                      "needs particles.fill = \"file\" (particles.fill = " + quoted(pa.fill) + ")");
  if (pa.fill_file && !fs::is_regular_file(*pa.fill_file)) {
    std::error_code ec;
    const fs::file_status st = fs::status(*pa.fill_file, ec);
    const std::string what = !fs::exists(st)                                       ? ""
                             : fs::is_directory(st)                                 ? "a directory"
                             : fs::is_fifo(st)                                      ? "a FIFO"
                             : fs::is_character_file(st) || fs::is_block_file(st) ? "a device"
                                                                                    : "not a regular file";
    throw ConfigError("particles.fill_file", quoted(*pa.fill_file),
                      what.empty() ? "no such file (a relative path is taken from the configuration file's directory)"
                                   : "is " + what + ", not a particle file (.csv or .vtp)");
  }
  if (pa.fill_count && pa.fill_mass)
    throw ConfigError("particles.fill_count", std::to_string(*pa.fill_count),
                      "give either particles.fill_count or particles.fill_mass, not both");
  if (pa.fill == "empty" && (pa.fill_count || pa.fill_mass))
    throw ConfigError(pa.fill_count ? "particles.fill_count" : "particles.fill_mass",
                      pa.fill_count ? std::to_string(*pa.fill_count) : shown(*pa.fill_mass),
                      "needs particles.fill = \"uniform\", \"gaussian\" or \"cosine\"");
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

  std::set<std::string> patches;
  for (std::size_t i = 0; i < c.boundary.size(); ++i) {
    const BoundarySpec& b = c.boundary[i];
    const std::string p = fmt::format("boundary[{}].", i);
    if (!patches.insert(b.patch).second)
      throw ConfigError(p + "patch", quoted(b.patch), "patch already has a [[boundary]] entry");
    if (b.kind == "no_flux" && b.value)
      throw ConfigError(p + "value", shown(*b.value), "not used by kind \"no_flux\" (remove it)");
    if (b.kind != "no_flux" && !b.value)
      throw ConfigError(p + "value", "(missing)",
                        b.kind == "dirichlet" ? "required: the boundary density g (>= 0)"
                                              : "required: the outward mass flux f (< 0 is inflow)");
    if (b.kind == "dirichlet" && !(*b.value >= 0.0)) throw ConfigError(p + "value", shown(*b.value), "must be >= 0");
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
  if (s.max_width_factor != 0.0 && !(s.max_width_factor > 1.0))
    throw ConfigError("solver.max_width_factor", shown(s.max_width_factor), "must be 0 (off) or in (1, 1e6]");
  if (s.max_width_factor != 0.0 && s.width_mode != "per_particle")
    throw ConfigError("solver.max_width_factor", shown(s.max_width_factor),
                      "needs solver.width_mode = \"per_particle\" (fixed widths have no bound to keep)");
  if (s.time_scheme != "euler" && s.stepper != "implicit")
    throw ConfigError("solver.time_scheme", quoted(s.time_scheme),
                      "needs solver.stepper = \"implicit\" (explicit schemes: solver.explicit_scheme)");
  if (s.predictor != "none" && s.stepper != "implicit")
    throw ConfigError("solver.predictor", quoted(s.predictor), "needs solver.stepper = \"implicit\"");

  const DiagnosticsSection& g = c.diagnostics;
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

toml::array toml_point(const Vec3& v) { return toml::array{v[0], v[1], v[2]}; }
nlohmann::json json_point(const Vec3& v) { return nlohmann::json::array({v[0], v[1], v[2]}); }

// Adds key `f` of entry i to the TOML table `t` (absent values are left out).
void put(toml::table& t, const Field& f, const Value& v) {
  if (const auto* n = std::get_if<std::int64_t>(&v)) t.insert_or_assign(f.key, *n);
  if (const auto* d = std::get_if<double>(&v)) t.insert_or_assign(f.key, *d);
  if (const auto* s = std::get_if<std::string>(&v)) t.insert_or_assign(f.key, *s);
  if (const auto* p = std::get_if<Vec3>(&v)) t.insert_or_assign(f.key, toml_point(*p));
}

nlohmann::json json_value(const Value& v) {
  if (const auto* n = std::get_if<std::int64_t>(&v)) return *n;
  if (const auto* d = std::get_if<double>(&v)) return *d;
  if (const auto* s = std::get_if<std::string>(&v)) return *s;
  if (const auto* p = std::get_if<Vec3>(&v)) return json_point(*p);
  return nullptr;
}

const char* type_name(Kind k) {
  switch (k) {
    case Kind::Int: return "integer";
    case Kind::Float: return "number";
    case Kind::String: return "string";
    case Kind::Point: return "point";
  }
  return "";
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

std::vector<std::string> schema_keys() {
  std::vector<std::string> out;
  for (const Field& f : fields()) out.push_back(f.path);
  return out;
}

const std::vector<KeyInfo>& schema() {
  static const std::vector<KeyInfo> keys = [] {
    std::vector<KeyInfo> out;
    for (const Field& f : fields()) {
      KeyInfo k;
      k.path = f.path;
      k.type = type_name(f.kind);
      k.optional = f.optional;
      k.required = !f.required.empty();
      k.default_value = k.required ? nlohmann::json(nullptr) : json_value(f.fallback);
      k.choices = f.choices;
      k.rule = f.rule.short_form();
      out.push_back(std::move(k));
    }
    return out;
  }();
  return keys;
}

std::string to_toml(const Config& c) {
  toml::table root;
  toml::array subpatches, boundaries;
  for (std::size_t i = 0; i < c.domain.subpatches.size(); ++i) subpatches.push_back(toml::table{});
  for (std::size_t i = 0; i < c.boundary.size(); ++i) boundaries.push_back(toml::table{});
  for (const Field& f : fields())
    for (std::size_t i = 0; i < entries(c, f.scope); ++i) {
      if (f.in_toml && !f.in_toml(c, i)) continue;
      switch (f.scope) {
        case Scope::Section:
          if (!root.contains(f.section)) root.insert(f.section, toml::table{});
          put(*root[f.section].as_table(), f, f.get(c, i));
          break;
        case Scope::SubPatch: put(*subpatches.get(i)->as_table(), f, f.get(c, i)); break;
        case Scope::Boundary: put(*boundaries.get(i)->as_table(), f, f.get(c, i)); break;
      }
    }
  if (!subpatches.empty()) root["domain"].as_table()->insert("subpatch", std::move(subpatches));
  if (!boundaries.empty()) root.insert("boundary", std::move(boundaries));
  std::ostringstream os;
  os << root;
  return os.str();
}

nlohmann::json config_to_json(const Config& c) {
  nlohmann::json j = nlohmann::json::object();
  j["boundary"] = nlohmann::json::array();
  j["domain"]["subpatch"] = nlohmann::json::array();
  for (std::size_t i = 0; i < c.domain.subpatches.size(); ++i) j["domain"]["subpatch"].push_back(nlohmann::json::object());
  for (std::size_t i = 0; i < c.boundary.size(); ++i) j["boundary"].push_back(nlohmann::json::object());
  for (const Field& f : fields())
    for (std::size_t i = 0; i < entries(c, f.scope); ++i) {
      const nlohmann::json v = json_value(f.get(c, i));
      switch (f.scope) {
        case Scope::Section: j[f.section][f.key] = v; break;
        case Scope::SubPatch: j["domain"]["subpatch"][i][f.key] = v; break;
        case Scope::Boundary: j["boundary"][i][f.key] = v; break;
      }
    }
  return j;
}

const std::vector<std::string>& resume_keys() {
  static const std::vector<std::string> keys = {"run.t_end",   "run.max_steps", "run.vtk_interval",
                                                "run.checkpoint_interval", "run.threads", "run.max_particles"};
  return keys;
}

namespace {
void flatten(const nlohmann::json& j, const std::string& path, std::map<std::string, std::string>& out) {
  if (j.is_object()) {
    for (const auto& [k, v] : j.items()) flatten(v, path.empty() ? k : path + "." + k, out);
  } else if (j.is_array() && !j.empty() && j.front().is_object()) {  // arrays of tables; points stay values
    for (std::size_t i = 0; i < j.size(); ++i) flatten(j[i], path + "[" + std::to_string(i) + "]", out);
  } else {
    out[path] = j.dump();
  }
}
}  // namespace

std::map<std::string, std::string> config_fingerprint(const Config& config) {
  std::map<std::string, std::string> out;
  flatten(config_to_json(parse_config_string(to_toml(config), {}, config.source)), "", out);
  for (const std::string& k : resume_keys()) out.erase(k);
  return out;
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
