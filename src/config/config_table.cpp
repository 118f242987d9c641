// The table of configuration keys (paths, kinds, members of Config, defaults,
// choices and range rules), the values in messages, and what iterates the
// table to write a configuration out: schema(), to_toml, config_to_json,
// config_fingerprint.
#include "config_table.hpp"

#include <algorithm>
#include <initializer_list>
#include <map>
#include <optional>
#include <sstream>
#include <type_traits>
#include <toml++/toml.h>

#include "otfp/boundary.hpp"
#include "otfp/explicit_stepper.hpp"
#include "otfp/implicit_stepper.hpp"
#include "otfp/minimizer.hpp"
#include "otfp/reference.hpp"

namespace otfp::app {

// A message is one line whatever it echoes (a patch name "a\nb" given in the
// file, a sub-patch name inside a list of patches): control characters become
// \xHH. Idempotent on text already escaped (it holds none).
std::string one_line(const std::string& s) {
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

ConfigError::ConfigError(const std::string& key, const std::string& value, const std::string& rule)
    : std::runtime_error(one_line(key + " = " + value + ": " + rule)), key_(key) {}
ConfigError::ConfigError(const std::string& key, const std::string& message)
    : std::runtime_error(one_line(message)), key_(key) {}

std::string to_string(DtMode m) { return m == DtMode::Adaptive ? "adaptive" : "fixed"; }
std::string to_string(DomainType t) {
  switch (t) {
    case DomainType::Ball: return "ball";
    case DomainType::Box: return "box";
    case DomainType::Cylinder: return "cylinder";
    case DomainType::PeriodicBox: return "periodic_box";
    case DomainType::SquarePipeObstacle: return "square_pipe_obstacle";
    case DomainType::Free: return "free";
  }
  return "?";
}
std::string to_string(Axis a) { return std::string(1, "xyz"[static_cast<int>(a)]); }
std::string to_string(Fill f) {
  switch (f) {
    case Fill::Empty: return "empty";
    case Fill::Uniform: return "uniform";
    case Fill::Gaussian: return "gaussian";
    case Fill::Cosine: return "cosine";
    case Fill::File: return "file";
  }
  return "?";
}
std::string to_string(Arrangement a) {
  switch (a) {
    case Arrangement::Random: return "random";
    case Arrangement::Lattice: return "lattice";
    case Arrangement::StaggeredLattice: return "staggered_lattice";
  }
  return "?";
}

namespace config_detail {

// ------------------------------------------------------------------ values

std::string format_double(double v) {
  if (std::isnan(v)) return "nan";
  if (std::isinf(v)) return v > 0 ? "inf" : "-inf";
  return fmt::format("{}", v);
}
std::string shown(double v) { return format_double(v); }
std::string shown(const Vec3& v) {
  return "[" + format_double(v[0]) + ", " + format_double(v[1]) + ", " + format_double(v[2]) + "]";
}
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

std::string join(const std::vector<std::string>& v, const char* sep) {
  std::string out;
  for (std::size_t i = 0; i < v.size(); ++i) out += (i ? sep : "") + v[i];
  return out;
}

namespace {

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

// The in-class defaults of O, built once per type: an O{} inside key() and
// choice() put every section's initialisers into each of their ~55
// instantiations (a third of this file's object code and build time).
template <class O>
const O& defaults_of() {
  static const O defaults{};
  return defaults;
}

// A key of member type M of O: its path split into section and key, its scope.
template <class O, class M>
Field blank(std::string path) {
  Field f;
  f.path = std::move(path);
  f.scope = Owner<O>::scope;
  const std::size_t dot = f.path.rfind('.');
  f.key = f.path.substr(dot + 1);
  f.section = f.path.substr(0, f.path.find_first_of(".["));
  f.optional = IsOptional<M>::value;
  return f;
}

template <class O, class M>
Field key(std::string path, M O::*member) {
  Field f = blank<O, M>(std::move(path));
  f.kind = KindOf<M>::value;
  f.fallback = to_value(defaults_of<O>().*member);
  f.get = [member](const Config& c, std::size_t i) { return to_value(Owner<O>::of(c, i).*member); };
  f.set = [member](Config& c, std::size_t i, const Value& v, const std::string& display) {
    assign(v, Owner<O>::of(c, i).*member, display);
  };
  return f;
}

// The names of a choice in the configuration file, in the order messages list them.
template <class E>
using Names = std::vector<std::pair<E, std::string>>;

// The names of an enum with to_string (the library's, and config.hpp's own).
template <class E>
Names<E> named(std::initializer_list<E> values) {
  Names<E> out;
  for (E e : values) out.emplace_back(e, to_string(e));
  return out;
}

template <class E>
const std::string& name_of(const Names<E>& names, E e) {
  for (const auto& [value, name] : names)
    if (value == e) return name;
  throw std::logic_error("config table: a value with no name");  // every enumerator is listed
}

// A key that is one of `names` in the file and the enum E (or
// std::optional<E>, absent until given) in Config; the table converts both ways.
template <class O, class M, class E>
Field choice(std::string path, M O::*member, Names<E> names) {
  Field f = blank<O, M>(std::move(path));
  f.kind = Kind::String;
  for (const auto& n : names) f.choices.push_back(n.second);
  const auto value_of = [names](const M& m) -> Value {
    if constexpr (IsOptional<M>::value)
      return m ? Value{name_of(names, *m)} : Value{};
    else
      return name_of(names, m);
  };
  f.fallback = value_of(defaults_of<O>().*member);
  f.get = [member, value_of](const Config& c, std::size_t i) { return value_of(Owner<O>::of(c, i).*member); };
  f.set = [member, names](Config& c, std::size_t i, const Value& v, const std::string& display) {
    M& m = Owner<O>::of(c, i).*member;
    if (std::holds_alternative<std::monostate>(v)) {
      m = M{};
      return;
    }
    const std::string& given = std::get<std::string>(v);  // the parser checked that it is one of the names
    for (const auto& [value, name] : names)
      if (name == given) {
        m = value;
        return;
      }
    throw ConfigError(display, quoted(given), "is not one of the names of this key");
  };
  return f;
}

// diagnostics.reference: "none" and the library's references (otfp/reference.hpp).
std::vector<std::string> reference_choices() {
  std::vector<std::string> out = {"none"};
  for (const std::string& name : reference_names()) out.push_back(name);
  return out;
}

bool domain_is(const Config& c, std::initializer_list<DomainType> types) {
  return std::find(types.begin(), types.end(), c.domain.type) != types.end();
}

}  // namespace

const std::vector<Field>& fields() {
  static const std::vector<Field> table = [] {
    Rule dim = interval('[', 1, 3, ']', "must be 1, 2 or 3");
    dim.doc = "1, 2 or 3";
    Rule radius = greater(0);
    radius.when = [](const Config& c) { return domain_is(c, {DomainType::Ball, DomainType::Cylinder}); };
    Rule obstacle_radius = greater(0);
    obstacle_radius.when = [](const Config& c) { return domain_is(c, {DomainType::SquarePipeObstacle}); };
    Rule solver_cap = at_least(1);  // the library's caps are int
    solver_cap.hi = std::numeric_limits<int>::max();
    solver_cap.above = "out of range";
    solver_cap.doc = ">= 1";
    Rule reservoir_width = interval('(', 0, 10, ']');
    reservoir_width.above = "must be <= 10 (kernel cut-offs)";
    const auto neumann_only = [](const Config& c, std::size_t i) { return c.boundary[i].kind == PatchKind::Neumann; };
    // fill = "file": the file gives the particles, the keys of the other fills do not apply.
    const auto not_from_file = [](const Config& c, std::size_t) { return c.particles.fill != Fill::File; };

    return std::vector<Field>{
        key("run.dim", &RunSection::dim).with(dim),
        key("run.t_end", &RunSection::t_end).with(greater(0)),
        key("run.dt", &RunSection::dt).with(greater(0)),
        key("run.dt_factor", &RunSection::dt_factor).with(greater(0)),
        key("run.seed", &RunSection::seed).with(at_least(0)),
        key("run.max_steps", &RunSection::max_steps).with(at_least(0)),
        choice("run.dt_mode", &RunSection::dt_mode, named({DtMode::Fixed, DtMode::Adaptive})),
        key("run.time_tolerance", &RunSection::time_tolerance).with(greater(0)),
        key("run.dt_min", &RunSection::dt_min).with(greater(0)),
        key("run.dt_max", &RunSection::dt_max).with(greater(0)),
        key("run.vtk_interval", &RunSection::vtk_interval).with(at_least(0)),
        key("run.checkpoint_interval", &RunSection::checkpoint_interval).with(at_least(0)),
        key("run.max_particles", &RunSection::max_particles).with(at_least(0)),
        key("run.threads", &RunSection::threads).with(interval('[', 0, 4096, ']', "must be in [0, 4096] (0: OpenMP default)")),
        choice("domain.type", &DomainSection::type,
               named({DomainType::Ball, DomainType::Box, DomainType::Cylinder, DomainType::PeriodicBox,
                      DomainType::SquarePipeObstacle, DomainType::Free})),
        key("domain.center", &DomainSection::center),
        key("domain.radius", &DomainSection::radius).with(radius),
        key("domain.lo", &DomainSection::lo),
        key("domain.hi", &DomainSection::hi),
        key("domain.end_a", &DomainSection::end_a),
        key("domain.end_b", &DomainSection::end_b),
        key("domain.obstacle_center", &DomainSection::obstacle_center),
        key("domain.obstacle_radius", &DomainSection::obstacle_radius).with(obstacle_radius),
        choice("domain.obstacle_axis", &DomainSection::obstacle_axis, named({Axis::X, Axis::Y, Axis::Z})),
        key("domain.subpatch[].name", &SubPatchSpec::name).needed("required, a non-empty patch name"),
        key("domain.subpatch[].on", &SubPatchSpec::on).needed("required: the name of the patch it lies on"),
        key("domain.subpatch[].center", &SubPatchSpec::center),
        key("domain.subpatch[].radius", &SubPatchSpec::radius).needed("required, > 0").with(greater(0)),
        key("particles.n_inf", &ParticlesSection::n_inf).with(at_least(1)),
        key("particles.mass", &ParticlesSection::mass).with(greater(0)),
        choice("particles.spacing_rule", &ParticlesSection::spacing_rule,named({SpacingRule::Cube, SpacingRule::SphereRadius})),
        key("particles.beta_factor", &ParticlesSection::beta_factor).with(greater(0)),
        key("particles.width_exponent", &ParticlesSection::width_exponent)
            .with(interval('(', 0, 2, ']',
                           "must be in (0, 2] (s = s_rule(dr) (dr / dr_ref)^(q - 1); 1: the papers' fixed beta dr^2)")),
        key("particles.width_reference_n", &ParticlesSection::width_reference_n).with(at_least(1)),
        key("particles.layer_b", &ParticlesSection::layer_b).with(at_least(0)),
        key("particles.length_L", &ParticlesSection::length_L).with(at_least(0)),
        choice("particles.dirichlet_target", &ParticlesSection::dirichlet_target,named({DirichletTarget::CellIntegral, DirichletTarget::PaperEq34})),
        choice("particles.fill", &ParticlesSection::fill, named({Fill::Empty, Fill::Uniform, Fill::Gaussian, Fill::Cosine, Fill::File})),
        key("particles.fill_file", &ParticlesSection::fill_file),
        choice("particles.fill_arrangement", &ParticlesSection::fill_arrangement,
               named({Arrangement::Random, Arrangement::Lattice, Arrangement::StaggeredLattice}))
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
        choice("boundary[].kind", &BoundarySpec::kind,
            named({PatchKind::Dirichlet, PatchKind::Neumann, PatchKind::NoFlux}))
            .needed("required: one of dirichlet, neumann, no_flux"),
        key("boundary[].value", &BoundarySpec::value),
        key("boundary[].t_start", &BoundarySpec::t_start).with(at_least(0)).written_if(neumann_only),
        key("boundary[].t_end", &BoundarySpec::t_end),
        choice("solver.stepper", &SolverSection::stepper, named({StepperKind::Implicit, StepperKind::Explicit})),
        choice("solver.backend", &SolverSection::backend,named({Backend::Ceres, Backend::Nlopt, Backend::Tao})),
        choice("solver.algorithm", &SolverSection::algorithm,
            named({Algorithm::Lbfgs, Algorithm::Bfgs, Algorithm::NonlinearCg, Algorithm::TruncatedNewton,
                           Algorithm::Var2, Algorithm::Mma})),
        choice("solver.explicit_scheme", &SolverSection::explicit_scheme,
            named({ExplicitScheme::EulerForce27, ExplicitScheme::Rk4Force27, ExplicitScheme::EulerExactGradient})),
        choice("solver.width_mode", &SolverSection::width_mode,named({WidthMode::Fixed, WidthMode::PerParticle})),
        choice("solver.width_metric", &SolverSection::width_metric,named({WidthMetric::AsPrinted, WidthMetric::ExactGaussian})),
        choice("solver.time_scheme", &SolverSection::time_scheme,named({TimeScheme::Euler, TimeScheme::Bdf2})),
        choice("solver.predictor", &SolverSection::predictor,
            named({Predictor::None, Predictor::Extrapolate, Predictor::Damped})),
        choice("solver.error_measure", &SolverSection::error_measure,
            named({ErrorMeasure::Density, ErrorMeasure::Displacement})),
        choice("solver.stopping_norm", &SolverSection::stopping_norm,
            named({StoppingNorm::Energy, StoppingNorm::Max})),
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
        choice("treatment.preset", &TreatmentSection::preset, named({TreatmentPreset::Converging, TreatmentPreset::Papers})),
        choice("treatment.no_flux", &TreatmentSection::no_flux, named({NoFluxTreatment::Barrier, NoFluxTreatment::Images})),
        choice("treatment.dirichlet", &TreatmentSection::dirichlet,
            named({DirichletMode::Layer, DirichletMode::Reservoir})),
        key("treatment.reservoir_width", &TreatmentSection::reservoir_width).with(reservoir_width),
        key("treatment.reservoir_sublayers", &TreatmentSection::reservoir_sublayers)
            .with(interval('[', 0, 1000, ']', "must be in [0, 1000] (0: about one spacing per sublayer)")),
        choice("treatment.reservoir_profile", &TreatmentSection::reservoir_profile,
            named({ReservoirProfile::Uniform, ReservoirProfile::Odd})),
        choice("treatment.reservoir_control", &TreatmentSection::reservoir_control,
            named({ReservoirControl::Quiet, ReservoirControl::Exact})),
        key("treatment.reservoir_tolerance", &TreatmentSection::reservoir_tolerance)
            .with(interval('[', 0.5, 1e6, ']', "must be in [0.5, 1000000] (particles)")),
        key("treatment.reservoir_integral", &TreatmentSection::reservoir_integral)
            .with(interval('[', 0, 1e6, ']', "must be in [0, 1000000] (band diffusion times w^2 / kappa; 0: off)")),
        key("treatment.reservoir_group", &TreatmentSection::reservoir_group)
            .with(interval('[', 1, 1e9, ']', "must be in [1, 1000000000] (particles)")),
        key("treatment.reservoir_candidates", &TreatmentSection::reservoir_candidates)
            .with(interval('[', 1, 1000, ']', "must be in [1, 1000] (candidate points per target particle)")),
        choice("treatment.neumann_outflow", &TreatmentSection::neumann_outflow,
               Names<NeumannOutflow>{{NeumannOutflow::Layer, "layer"}, {NeumannOutflow::NearestParticles, "nearest"}}),
        choice("treatment.stranded", &TreatmentSection::absorb_stranded, Names<bool>{{false, "keep"}, {true, "absorb"}}),
        key("diagnostics.center", &DiagnosticsSection::center),
        key("diagnostics.M_inf", &DiagnosticsSection::M_inf).with(greater(0)),
        key("diagnostics.J_inf", &DiagnosticsSection::J_inf).with(greater(0)),
        key("diagnostics.reference", &DiagnosticsSection::reference).one_of(reference_choices()),
        key("diagnostics.reference_radius", &DiagnosticsSection::reference_radius).with(greater(0)),
        key("diagnostics.reference_length", &DiagnosticsSection::reference_length).with(greater(0)),
    };
  }();
  return table;
}

const Field* find_spec(const std::string& path) {
  for (const Field& k : fields())
    if (k.path == path) return &k;
  return nullptr;
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

}  // namespace config_detail

using namespace config_detail;

namespace {

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

}  // namespace otfp::app
