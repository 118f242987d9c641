#include "otfp_app/simulation.hpp"

#include <omp.h>
#include <unistd.h>

#include <fmt/format.h>
#include <fmt/ranges.h>

#include <algorithm>
#include <charconv>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <csignal>
#include <deque>
#include <fstream>
#include <iostream>
#include <limits>
#include <map>
#include <numbers>
#include <optional>
#include <regex>

#include "domain_setup.hpp"
#include "otfp/barrier.hpp"
#include "otfp/fractional.hpp"
#include "otfp/images.hpp"
#include "otfp/initial_fill.hpp"
#include "otfp/mass_measure.hpp"
#include "otfp/neighbor_list.hpp"
#include "otfp/density.hpp"
#include "otfp/parameters.hpp"
#include "otfp/run_setup.hpp"
#include "otfp/surface.hpp"
#include "otfp/vtk.hpp"
#include "otfp/particle_io.hpp"
#include "otfp/reference.hpp"
#include "otfp/simulation.hpp"
#include "otfp/stepper.hpp"
#include "otfp/time_step_control.hpp"
#include "otfp_app/series_columns.hpp"
#include "otfp_app/writers.hpp"

#ifndef OTFP_APP_VERSION
#define OTFP_APP_VERSION "unknown"
#endif

namespace otfp::app {

std::string version() { return OTFP_APP_VERSION; }


namespace {

using Clock = std::chrono::steady_clock;
constexpr double kPi = std::numbers::pi;
const std::string kTimingHeader = "step,t,wall_seconds,step_seconds,solver_seconds,list_seconds\n";

// A failure while stepping: exit code 1, files kept.
class RunError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

std::string quoted(const std::string& s) { return "\"" + s + "\""; }

nlohmann::json to_json(const Vec3& v) { return nlohmann::json::array({v[0], v[1], v[2]}); }

template <class T>
nlohmann::json opt(const std::optional<T>& v) {
  return v ? nlohmann::json(*v) : nlohmann::json(nullptr);
}

// Length of [a, b] inside [lo, hi].
double overlap(double a, double b, double lo, double hi) { return std::max(0.0, std::min(b, hi) - std::max(a, lo)); }

std::string hms(double seconds) {
  const long s = std::lround(std::max(0.0, seconds));
  return s >= 3600 ? fmt::format("{}:{:02}:{:02}", s / 3600, (s / 60) % 60, s % 60)
                   : fmt::format("{}:{:02}", s / 60, s % 60);
}

// The analytic reference of diagnostics.reference (otfp/reference.hpp), or null.
std::unique_ptr<Reference> configured_reference(const Config& c, const Derived& d) {
  if (c.diagnostics.reference == "none") return nullptr;
  ReferenceSetup s;
  s.dim = c.run.dim;
  s.kappa = c.physics.kappa;
  s.t_end = c.run.t_end;
  s.center = d.center;
  s.M_inf = d.M_inf;
  s.radius = d.reference_radius.value_or(0.0);
  s.length = d.reference_length.value_or(0.0);
  s.J_inf = d.reference_J_inf;
  s.lo = c.domain.lo;
  s.hi = c.domain.hi;
  s.slab_axis = d.slab_axis;
  s.slab_held_at_hi = d.slab_held_at_hi;
  s.wavenumber = d.mode_wavenumber;
  s.x0 = c.domain.lo[0];
  s.constant_dt = c.run.dt_mode == "fixed" ? d.dt : 0.0;
  s.stepper = stepper_kind_from_string(c.solver.stepper);
  s.time_scheme = time_scheme_from_string(c.solver.time_scheme);
  s.explicit_scheme = explicit_scheme_from_string(c.solver.explicit_scheme);
  return make_reference(c.diagnostics.reference, s);
}

nlohmann::json statistics_json(const ErrorStatistics& e) {
  return {{"measured", e.measured()},
          {"scale", e.scale()},
          {"scale_rule", e.scale_rule()},
          {"max_abs_error", e.max_abs_error()},
          {"l1_time_error", e.l1_time_error()},
          {"mean_abs_error", e.mean_abs_error()},
          {"final_error", e.final_error()},
          {"l1_norm", e.l1_norm()},
          {"l1_norm_reference", e.l1_norm_reference()},
          {"l1_norm_relative_error", e.l1_norm_relative_error()}};
}

// summary.json "reference" (docs/outputs.md).
nlohmann::json reference_json(const Reference& ref) {
  nlohmann::json q = nlohmann::json::array();
  for (const ErrorStatistics& e : ref.statistics()) q.push_back(statistics_json(e));
  nlohmann::json j = {{"curve", ref.name()},
                      {"error_rule", "error = (measured - reference) / scale per row; max_abs_error over rows; "
                                     "l1_time_error = integral of |error| dt (trapezoid); mean_abs_error = "
                                     "l1_time_error / t; l1_norm = integral of the quantity dt (trapezoid)"},
                      {"quantities", q}};
  if (const auto blob = ref.mass_blob_statistics()) j["mass_blob"] = statistics_json(*blob);
  for (const ReferenceEntry& e : ref.summary())
    j[e.key] = std::visit(
        [](auto v) { return std::isfinite(static_cast<double>(v)) ? nlohmann::json(v) : nlohmann::json(nullptr); },
        e.value);
  return j;
}

// Checkpoint state of the driver's running sums (doubles round-trip exactly in JSON).
nlohmann::json measures_state(const StateMeasures& m) {
  return {m.n_particles, m.n_inside, m.n_buffer, m.n_outside, m.mass_total, m.mass_inside, m.mass_with_layer,
          m.polar_inertia, m.polar_inertia_with_layer, m.polar_inertia_total, m.mean_age, m.max_age};
}
StateMeasures measures_from_state(const nlohmann::json& j) {
  StateMeasures m;
  m.n_particles = j.at(0).get<std::int64_t>();
  m.n_inside = j.at(1).get<std::int64_t>();
  m.n_buffer = j.at(2).get<std::int64_t>();
  m.n_outside = j.at(3).get<std::int64_t>();
  double* fields[] = {&m.mass_total, &m.mass_inside, &m.mass_with_layer, &m.polar_inertia, &m.polar_inertia_with_layer,
                      &m.polar_inertia_total, &m.mean_age, &m.max_age};
  for (std::size_t i = 0; i < 8; ++i) *fields[i] = j.at(4 + i).get<double>();
  return m;
}
nlohmann::json l1_state(const L1Norms& l) {
  return {l.mass_rectangle, l.polar_inertia_rectangle, l.mass_inside_trapezoid, l.mass_with_layer_trapezoid,
          l.polar_inertia_inside_trapezoid, l.polar_inertia_with_layer_trapezoid};
}
L1Norms l1_from_state(const nlohmann::json& j) {
  L1Norms l;
  double* fields[] = {&l.mass_rectangle, &l.polar_inertia_rectangle, &l.mass_inside_trapezoid,
                      &l.mass_with_layer_trapezoid, &l.polar_inertia_inside_trapezoid,
                      &l.polar_inertia_with_layer_trapezoid};
  for (std::size_t i = 0; i < 6; ++i) *fields[i] = j.at(i).get<double>();
  return l;
}

// A resume that cannot continue the run: refused before any file is
// touched (exit code 2; RunResult::exit_code kExitRefused).
class ResumeRefused : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// The reference's state in a checkpoint's driver state (refused if it is not
// one of this reference: a nlohmann::json exception or InvalidArgument).
void load_reference_state(Reference& reference, const nlohmann::json& state, const std::filesystem::path& checkpoint) {
  try {
    reference.load_state(state.get<ReferenceState>());
  } catch (const InvalidArgument& e) {
    throw ResumeRefused(fmt::format("checkpoint {}: not written by otfp run (its driver state: {})", checkpoint.string(),
                                    e.what()));
  }
}

// The lines of a run's CSV file (series.csv, timing.csv) up to step k, header
// kept, for a resume to continue. Checked first, so that a resume never
// rewrites a file it cannot read: the header must be the one this
// configuration writes, every row must hold as many fields as the header and
// start with the step, one more than the row before (from step 0), and the
// rows must reach step k (rows after it, of a run killed between
// checkpoints, are dropped).
std::string csv_up_to_step(const std::filesystem::path& file, const std::string& header, std::int64_t k) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(file, ec))
    throw ResumeRefused(fmt::format("{}: {}", file.string(),
                                    std::filesystem::exists(file, ec) ? "not a regular file" : "missing"));
  std::ifstream f(file, std::ios::binary);
  if (!f) throw ResumeRefused(file.string() + ": cannot read");
  const auto fields = [](const std::string& line) { return std::count(line.begin(), line.end(), ',') + 1; };
  std::string line, text;
  std::int64_t line_no = 0, last_step = -1;
  while (std::getline(f, line)) {
    ++line_no;
    if (line_no == 1) {
      if (line + "\n" != header)
        throw ResumeRefused(fmt::format("{}: line 1 is not the header this configuration writes", file.string()));
      text += line + "\n";
      continue;
    }
    const std::string first = line.substr(0, line.find(','));
    std::int64_t step = -1;
    const auto [end, err] = std::from_chars(first.data(), first.data() + first.size(), step);
    if (err != std::errc() || end != first.data() + first.size() || fields(line) != fields(header) ||
        step != last_step + 1)
      throw ResumeRefused(fmt::format("{}: line {} is not the row of step {} ({} fields expected, starting with the "
                                      "step)",
                                      file.string(), line_no, last_step + 1, fields(header)));
    last_step = step;
    if (step <= k) text += line + "\n";
  }
  if (f.bad()) throw ResumeRefused(file.string() + ": cannot read");
  if (line_no == 0) throw ResumeRefused(file.string() + ": empty (no header)");
  if (last_step < k)
    throw ResumeRefused(fmt::format("{}: its rows end at step {}, before the checkpoint's step {} (rows missing)",
                                    file.string(), last_step, k));
  return text;
}

// particles.fill = "file": the particles of a CSV (the columns of
// particles_final.csv) or of one of our .vtp files, wrapped into a periodic
// cell (check_fill_file checks where they are once the buffers are known).
ParticleSet read_fill_file(const Config& c, const DomainPtr& domain) {
  const std::string& file = *c.particles.fill_file;
  ParticleSet ps(c.run.dim);
  try {
    ps = read_particles(file, c.run.dim);
  } catch (const InvalidArgument& e) {
    throw ConfigError("particles.fill_file", std::string("particles.fill_file: ") + e.what());
  }
  for (Vec3& x : ps.positions()) x = domain->wrap(x);
  return ps;
}

// Every particle of the file inside Omega or in the buffer outside a
// Dirichlet patch (a run's final state holds its reservoir band); free space
// takes any point.
void check_fill_file(const Config& c, const otfp::Simulation& sim, const ParticleSet& ps) {
  if (c.domain.type == "free") return;
  for (std::size_t p = 0; p < ps.size(); ++p) {
    const Vec3& x = ps.positions()[p];
    if (region_of(sim.domain(), sim.buffer(), x) == otfp::Region::Elsewhere)
      throw ConfigError("particles.fill_file", quoted(*c.particles.fill_file),
                        fmt::format("particle id {} at ({}, {}, {}) lies outside the domain and its Dirichlet buffers "
                                    "(signed distance {})",
                                    ps.ids()[p], x[0], x[1], x[2], sim.domain().signed_distance(x)));
  }
}

// The library's set-up inputs (run_setup.hpp) from the configuration; L is
// resolved by the caller (particles.length_L or the domain's).
RunSetupOptions run_setup_options(const Config& c, double length_L, bool bounded) {
  RunSetupOptions o;
  o.n_inf = c.particles.n_inf;
  o.kappa = c.physics.kappa;
  o.rho_ref = c.physics.rho_ref;
  o.beta_factor = c.particles.beta_factor;
  o.width = WidthScaling{c.particles.width_exponent, static_cast<std::size_t>(c.particles.width_reference_n)};
  o.length_L = length_L;
  o.layer_b = c.particles.layer_b;
  o.t_end = c.run.t_end;
  o.dt = c.run.dt.value_or(0.0);
  o.dt_factor = c.run.dt_factor;
  o.barrier_factor = c.solver.barrier_factor;
  o.barrier_stiffness = c.solver.barrier_stiffness.value_or(0.0);
  o.kernel_tolerance = c.solver.kernel_tolerance;
  o.bounded = bounded;
  o.stepper = stepper_kind_from_string(c.solver.stepper);
  const TreatmentSection& tr = c.treatment;
  TreatmentOptions& t = o.treatment;
  t.no_flux = no_flux_treatment_from_string(tr.no_flux);
  t.dirichlet = dirichlet_mode_from_string(tr.dirichlet);
  t.reservoir_profile = reservoir_profile_from_string(tr.reservoir_profile);
  t.reservoir_control = reservoir_control_from_string(tr.reservoir_control);
  t.reservoir_width = tr.reservoir_width;
  t.reservoir_sublayers = static_cast<int>(tr.reservoir_sublayers);
  t.reservoir_tolerance = tr.reservoir_tolerance;
  t.reservoir_candidates = static_cast<int>(tr.reservoir_candidates);
  t.neumann_outflow = tr.neumann_outflow == "nearest" ? NeumannOutflow::NearestParticles : NeumannOutflow::Layer;
  t.absorb_stranded = tr.stranded == "absorb";
  t.spacing_rule = spacing_rule_from_string(c.particles.spacing_rule);
  return o;
}

// An InvalidArgument of run_parameters() ("<field> = <value>: <rule>") as a
// ConfigError naming the configuration key of the field.
[[noreturn]] void throw_keyed(const InvalidArgument& e) {
  static const std::vector<std::pair<std::string, std::string>> keys = {
      {"n_inf", "particles.n_inf"},
      {"n", "particles.n_inf"},
      {"kappa", "physics.kappa"},
      {"rho_ref", "physics.rho_ref"},
      {"beta_factor", "particles.beta_factor"},
      {"width exponent q", "particles.width_exponent"},
      {"width reference n", "particles.width_reference_n"},
      {"length_L", "particles.length_L"},
      {"layer_b", "particles.layer_b"},
      {"t_end", "run.t_end"},
      {"dt", "run.dt"},
      {"dt_factor", "run.dt_factor"},
      {"barrier_factor", "solver.barrier_factor"},
      {"barrier_stiffness", "solver.barrier_stiffness"},
      {"kernel_tolerance", "solver.kernel_tolerance"},
      {"reservoir_width", "treatment.reservoir_width"},
      {"reservoir_sublayers", "treatment.reservoir_sublayers"},
      {"reservoir_tolerance", "treatment.reservoir_tolerance"},
      {"reservoir_candidates", "treatment.reservoir_candidates"},
  };
  const std::string what = e.what();
  for (const auto& [field, key] : keys)
    if (what.rfind(field + " = ", 0) == 0) {
      // The rule may name other fields: those of the step and the barrier by their keys as well.
      std::string rule = what.substr(field.size());
      for (const char* name : {"kappa", "t_end", "dt_factor", "barrier_factor"})
        rule = std::regex_replace(rule, std::regex(std::string("\\b") + name + "\\b"),
                                  std::string(name == std::string("kappa")            ? "physics."
                                              : name == std::string("barrier_factor") ? "solver."
                                                                                      : "run.") +
                                      name);
      throw ConfigError(key, key + rule);
    }
  throw ConfigError("particles", std::string("particles: ") + what);
}

}  // namespace

// Everything that changes while running.
struct ConfiguredRun::State {
  detail::BuiltDomain built;
  std::unique_ptr<otfp::Simulation> sim;  // Algorithm 1
  std::vector<ConstantBoundaryData> data;  // what sim was built from (make_simulation())
  SimulationOptions options;
  std::optional<ParticleSet> file_particles;  // particles.fill = "file": read (and checked) once
};

ConfiguredRun::~ConfiguredRun() = default;

// Values that are finite but would fail at step 0 (an infinite advected
// position, a source that multiplies the particles past any limit, boundary
// data asking for more particles than the run may hold, a centre so far away
// that squared distances overflow) are refused before any work.
void ConfiguredRun::check_magnitudes(const std::vector<ConstantBoundaryData>& data) const {
  const Config& c = config_;
  const Derived& d = derived_;
  // Plain loops over the dim axes (GCC 12 warns about Eigen's head(dim) here).
  const Aabb box = domain_->bounding_box();
  auto length = [&](const Vec3& a, const Vec3& b) {
    double s2 = 0.0;
    for (int k = 0; k < c.run.dim; ++k) s2 += (a[k] - b[k]) * (a[k] - b[k]);
    return std::sqrt(s2);
  };
  const double far = 1e6 * std::max(length(box.hi, box.lo), d.dr);  // how far from the domain a point may be
  const Vec3 mid(0.5 * (box.lo[0] + box.hi[0]), 0.5 * (box.lo[1] + box.hi[1]), 0.5 * (box.lo[2] + box.hi[2]));
  auto vec = [](const Vec3& v) { return fmt::format("[{}, {}, {}]", v[0], v[1], v[2]); };
  auto point_near = [&](const char* key, const std::optional<Vec3>& p) {
    if (p && !(length(*p, mid) <= far))
      throw ConfigError(key, vec(*p),
                        fmt::format("must lie within 1e6 domain sizes ({:.4g}) of the domain's centre", far));
  };
  point_near("diagnostics.center", c.diagnostics.center);
  point_near("particles.fill_center", c.particles.fill_center);
  if (c.particles.fill == "gaussian" && !(c.particles.fill_sigma <= far))
    throw ConfigError("particles.fill_sigma", fmt::format("{}", c.particles.fill_sigma),
                      fmt::format("must be at most 1e6 domain sizes ({:.4g})", far));
  const double speed = length(c.physics.velocity, Vec3::Zero());
  if (!(speed * c.run.t_end <= far))
    throw ConfigError("physics.velocity", vec(c.physics.velocity),
                      fmt::format("moves the particles {:.4g} over run.t_end = {}: at most 1e6 domain sizes ({:.4g})",
                                  speed * c.run.t_end, c.run.t_end, far));
  const double s_dt = std::abs(c.physics.source_rate) * d.dt;
  if (!(s_dt <= 36.0))
    throw ConfigError("physics.source_rate", fmt::format("{}", c.physics.source_rate),
                      fmt::format("|s| dt = {:.4g} (dt = {:.4g}): must be at most 36 (one step multiplies the mass by "
                                  "exp(s dt))",
                                  s_dt, d.dt));
  // Particles the data ask for: g over the layer (|A| x max(b, w)), or the
  // inflow -f |A| over the run, in particles of mass m_p.
  const double depth = std::max(d.layer_b, d.reservoir_width);
  for (const ConstantBoundaryData& b : data) {
    const double area = domain_->patch_area(b.patch);
    const double t_on = b.kind == PatchKind::Neumann
                            ? std::max(0.0, std::min(b.t_end, c.run.t_end) - std::min(b.t_start, c.run.t_end))
                            : 0.0;
    const double wanted = b.kind == PatchKind::Dirichlet ? std::abs(b.value) * area * depth / d.particle_mass
                                                         : std::max(0.0, -b.value) * area * t_on / d.particle_mass;
    if (!(wanted <= static_cast<double>(d.max_particles))) {
      std::size_t index = 0;
      for (std::size_t i = 0; i < c.boundary.size(); ++i)
        if (detail::resolve_patch(state_->built, c.boundary[i].patch) == b.patch) index = i;
      throw ConfigError(
          fmt::format("boundary[{}].value", index), fmt::format("{}", b.value),
          fmt::format("asks for about {:.4g} particles of mass {:.4g} on patch '{}' ({}): more than {} (run.max_particles)",
                      wanted,
                      d.particle_mass, domain_->patch_name(b.patch),
                      b.kind == PatchKind::Dirichlet ? "g x area x layer depth / m_p" : "-f x area x time on / m_p",
                      d.max_particles));
    }
  }
}

ConfiguredRun::ConfiguredRun(Config config) : config_(std::move(config)), state_(std::make_unique<State>()) {
  const Config& c = config_;
  const int dim = c.run.dim;
  State& st = *state_;
  st.built = detail::build_domain(c);
  domain_ = st.built.domain;
  free_space_ = st.built.free_space;

  // Patches and their conditions.
  for (int p = 0; p < domain_->num_patches(); ++p) {
    PatchInfo info;
    info.id = p;
    info.name = domain_->patch_name(p);
    info.area = domain_->patch_area(p);
    patches_.push_back(info);
  }
  for (std::size_t i = 0; i < c.boundary.size(); ++i) {
    const BoundarySpec& b = c.boundary[i];
    const int id = domain_->num_patches() > 0 ? detail::resolve_patch(st.built, b.patch) : -1;
    if (id < 0)
      throw ConfigError(fmt::format("boundary[{}].patch", i), quoted(b.patch),
                        "unknown patch (patches: " + detail::patch_names(st.built) + ")");
    for (std::size_t j = 0; j < i; ++j)
      if (detail::resolve_patch(st.built, c.boundary[j].patch) == id)
        throw ConfigError(fmt::format("boundary[{}].patch", i), quoted(b.patch),
                          fmt::format("same patch as boundary[{}]", j));
    PatchInfo& info = patches_[static_cast<std::size_t>(id)];
    info.kind = b.kind;
    info.value = b.value.value_or(0.0);
    info.t_start = b.t_start;
    info.t_end = b.t_end;
  }
  bool any_dirichlet = false, any_layer = false;
  for (const PatchInfo& p : patches_) {
    any_dirichlet = any_dirichlet || p.kind == "dirichlet";
    // The layer b is used by Neumann patches and by Dirichlet patches unless
    // they use the reservoir, whose band width is w instead.
    const bool uses_layer = p.kind == "neumann" || (p.kind == "dirichlet" && c.treatment.dirichlet == "layer");
    any_layer = any_layer || uses_layer;
  }

  // The library's data per patch (no-flux patches have none).
  std::vector<ConstantBoundaryData> data;
  for (PatchInfo& p : patches_) {
    if (p.kind == "no_flux") continue;
    ConstantBoundaryData bd;
    bd.patch = p.id;
    bd.kind = p.kind == "dirichlet" ? PatchKind::Dirichlet : PatchKind::Neumann;
    bd.value = p.value;
    if (bd.kind == PatchKind::Neumann) {
      bd.t_start = p.t_start;
      bd.t_end = p.t_end.value_or(std::numeric_limits<double>::infinity());
    }
    p.condition = static_cast<int>(data.size());
    data.push_back(bd);
  }

  // Spacing, width, layer, time step, barrier (36)-(40) and the band: the
  // library's rules (run_setup.hpp), its fields named by their keys here.
  Derived& d = derived_;
  d.length_L = c.particles.length_L > 0.0 ? c.particles.length_L : st.built.length_L;
  RunSetupOptions ro = run_setup_options(c, d.length_L, !free_space_);
  RunParameters rp;
  try {
    rp = run_parameters(*domain_, data, ro);
  } catch (const InvalidArgument& e) {
    throw_keyed(e);
  }
  d.volume = rp.volume;
  d.dr = rp.dr;
  d.beta = rp.beta;
  d.width_s = rp.width_s;
  d.width_reference_dr = rp.width_reference_dr;
  d.true_spacing = rp.true_spacing;
  d.beta_true_spacing2 = d.beta * d.true_spacing * d.true_spacing;
  d.layer_b = rp.layer_b;
  // Given where nothing uses it, it would only seem to have been applied.
  if (c.particles.layer_b > 0.0 && !any_layer)
    throw ConfigError("particles.layer_b", fmt::format("{}", c.particles.layer_b),
                      fmt::format("has no effect here: no patch uses the boundary layer (it serves Neumann patches, "
                                  "and Dirichlet patches with treatment.dirichlet = \"layer\"; here there is no Neumann "
                                  "patch and treatment.dirichlet = \"{}\"); remove it",
                                  c.treatment.dirichlet));
  if (any_layer && !(d.layer_b < 0.5 * st.built.min_extent))
    throw ConfigError("particles.layer_b",
                      fmt::format("{}{}", d.layer_b, c.particles.layer_b > 0.0 ? "" : " (sqrt(length_L dr))"),
                      fmt::format("must be < half the smallest extent of the domain ({})", 0.5 * st.built.min_extent));
  d.dt_explicit = rp.dt_explicit;
  d.n_steps = rp.n_steps;
  d.dt = rp.dt;
  d.steps_to_run = c.run.max_steps > 0 ? std::min(d.n_steps, c.run.max_steps) : d.n_steps;
  d.barrier_C = rp.barrier_C;
  d.reservoir_width = rp.reservoir_width;
  d.reservoir_sublayers = rp.reservoir_sublayers;

  // Net Neumann inflow over [0, t_end] (f is the outward flux: inflow is -f).
  for (const PatchInfo& p : patches_)
    if (p.kind == "neumann")
      d.neumann_net_inflow += -p.value * p.area *
                              overlap(0.0, c.run.t_end, p.t_start,
                                      p.t_end.value_or(std::numeric_limits<double>::infinity()));

  // M_inf and the particle mass.
  const ParticlesSection& pa = c.particles;
  if (c.diagnostics.M_inf) {
    d.M_inf = *c.diagnostics.M_inf;
    d.M_inf_rule = "diagnostics.M_inf";
  } else if (any_dirichlet) {
    d.M_inf = rp.M_inf;
    d.M_inf_rule = "area-weighted mean Dirichlet g x |Omega|";
  } else if (pa.fill == "file") {
    st.file_particles = read_fill_file(c, domain_);
    d.M_inf = st.file_particles->total_mass() + d.neumann_net_inflow;
    d.M_inf_rule = "mass of particles.fill_file + net Neumann inflow over [0, t_end]";
  } else if (pa.fill != "empty" && pa.fill_mass) {
    d.M_inf = *pa.fill_mass + d.neumann_net_inflow;
    d.M_inf_rule = "particles.fill_mass + net Neumann inflow over [0, t_end]";
  } else if (pa.mass) {
    const double n0 = pa.fill == "empty" ? 0.0 : static_cast<double>(pa.fill_count.value_or(pa.n_inf));
    d.M_inf = n0 * *pa.mass + d.neumann_net_inflow;
    d.M_inf_rule = "initial fill mass + net Neumann inflow over [0, t_end]";
    if (!(d.M_inf > 0.0)) {
      d.M_inf = static_cast<double>(pa.n_inf) * *pa.mass;
      d.M_inf_rule = "particles.n_inf x particles.mass";
    }
  } else if (pa.fill == "empty" && d.neumann_net_inflow > 0.0) {
    d.M_inf = d.neumann_net_inflow;
    d.M_inf_rule = "net Neumann inflow over [0, t_end]";
  } else {
    d.M_inf = 1.0;
    d.M_inf_rule = "default 1";
  }
  if (!(d.M_inf > 0.0) || !std::isfinite(d.M_inf))
    throw ConfigError("diagnostics.M_inf", fmt::format("{} ({})", d.M_inf, d.M_inf_rule),
                      "must be > 0: set diagnostics.M_inf or particles.mass");
  d.particle_mass = pa.mass ? *pa.mass : d.M_inf / static_cast<double>(pa.n_inf);

  if (pa.fill_arrangement == "lattice") {
    // Cell-centred lattice of spacing ~dr: round(edge / dr) points per axis.
    double total = 1.0;  // in double first: an extreme box must not overflow the count
    for (int k = 0; k < dim; ++k) total *= std::max(1.0, std::round((c.domain.hi[k] - c.domain.lo[k]) / d.dr));
    if (!(total <= 1e8))
      throw ConfigError("particles.fill_arrangement", "\"lattice\"",
                        fmt::format("gives {:.3g} lattice points (at most 1e8)", total));
    d.fill_count = 1;
    for (int k = 0; k < dim; ++k) {
      d.lattice_counts[static_cast<std::size_t>(k)] =
          std::max<std::int64_t>(1, std::llround((c.domain.hi[k] - c.domain.lo[k]) / d.dr));
      d.fill_count *= d.lattice_counts[static_cast<std::size_t>(k)];
    }
  } else if (pa.fill == "file") {
    if (!st.file_particles) st.file_particles = read_fill_file(c, domain_);
    d.fill_count = static_cast<std::int64_t>(st.file_particles->size());
  } else if (pa.fill != "empty") {
    if (pa.fill_count) {
      d.fill_count = *pa.fill_count;
    } else if (pa.fill_mass) {
      d.fill_count = std::llround(*pa.fill_mass / d.particle_mass);
    } else {
      d.fill_count = pa.n_inf;
    }
  }
  if (d.fill_count > 100'000'000)
    throw ConfigError(pa.fill_count ? "particles.fill_count" : pa.fill_mass ? "particles.fill_mass" : "particles.n_inf",
                      fmt::format("{} particles", d.fill_count), "must give at most 1e8 particles");
  // Resource limit, before any work: the initial particles and the papers'
  // equilibrium count n_inf must fit (steps that go past it fail at run time).
  d.max_particles = std::min(c.run.max_particles > 0 ? c.run.max_particles : otfp::default_max_particles(),
                             kMaxParticleCount);
  const std::string limit_rule =
      c.run.max_particles > 0
          ? fmt::format("must be at most run.max_particles = {}", d.max_particles)
          : fmt::format("must be at most {} particles (half this machine's memory at {} bytes per particle; "
                        "set run.max_particles to change it)",
                        d.max_particles, kBytesPerParticle);
  if (d.fill_count > d.max_particles)
    throw ConfigError(pa.fill == "file"       ? "particles.fill_file"
                      : pa.fill_count         ? "particles.fill_count"
                      : pa.fill_mass          ? "particles.fill_mass"
                                              : "particles.n_inf",
                      fmt::format("{} initial particles", d.fill_count), limit_rule);
  if (pa.n_inf > d.max_particles) throw ConfigError("particles.n_inf", fmt::format("{}", pa.n_inf), limit_rule);
  // The free-space reference grows by 2 d kappa M t and its error is scaled
  // by that growth over the run: with no particles at t = 0 both are 0.
  if (c.diagnostics.reference == "free_space" && d.fill_count == 0)
    throw ConfigError("particles.fill", quoted(pa.fill),
                      "diagnostics.reference = \"free_space\" needs particles at t = 0 (its growth 2 d kappa M t "
                      "scales with their mass M)");
  if (pa.fill == "cosine") {
    // At least two particle spacings per wavelength: a finer mode cannot be
    // sampled (its measured amplitude is noise about 0, and the error column,
    // scaled by a(0), would not be finite).
    const double length = c.domain.hi[0] - c.domain.lo[0];
    const double most = std::floor(length / (2.0 * d.dr));
    if (static_cast<double>(pa.fill_mode) > most)
      throw ConfigError("particles.fill_mode", fmt::format("{}", pa.fill_mode),
                        fmt::format("must be at most {} (two particle spacings dr = {:.4g} per wavelength along x; "
                                    "raise particles.n_inf for a finer mode)",
                                    most, d.dr));
    d.mode_wavenumber = 2.0 * kPi * static_cast<double>(pa.fill_mode) / length;
  }

  // Diagnostics centre, J_inf, reference curves.
  d.center = c.diagnostics.center ? *c.diagnostics.center : st.built.centroid;
  for (int k = dim; k < 3; ++k) d.center[k] = 0.0;
  if (c.diagnostics.J_inf) {
    d.J_inf = *c.diagnostics.J_inf;
    d.J_inf_rule = "diagnostics.J_inf";
  } else if (!free_space_ && st.built.mean_square_distance) {
    d.J_inf = d.M_inf * st.built.mean_square_distance(d.center);
    d.J_inf_rule = "uniform density M_inf/|Omega| about diagnostics.center";
  }
  const std::string& ref = c.diagnostics.reference;
  if (ref == "crank_sphere") {
    d.reference_radius = c.diagnostics.reference_radius ? c.diagnostics.reference_radius : st.built.ball_radius;
    if (!d.reference_radius)
      throw ConfigError("diagnostics.reference_radius", "(missing)",
                        "required for reference = \"crank_sphere\" on a domain that is not a ball");
    // Polar-inertia reference: a 3D ball about its own centre.
    if (st.built.ball_radius && dim == 3 && (d.center - c.domain.center).norm() <= 1e-12 * *d.reference_radius &&
        std::abs(*d.reference_radius - *st.built.ball_radius) <= 1e-12 * *d.reference_radius)
      d.reference_J_inf = 0.6 * d.M_inf * *d.reference_radius * *d.reference_radius;
  } else if (ref == "crank_slab") {
    d.reference_length = c.diagnostics.reference_length;
    if (!d.reference_length && c.domain.type == "box") {
      int face = -1, count = 0;
      for (const PatchInfo& p : patches_)
        if (p.kind == "dirichlet") {
          face = p.id;
          ++count;
        }
      if (count == 1 && face < 2 * dim) {
        d.reference_length = c.domain.hi[face / 2] - c.domain.lo[face / 2];
        if (!c.diagnostics.reference_length && st.built.mean_square_distance) {
          // Polar-inertia reference: the slab profile across the box.
          d.slab_axis = face / 2;
          d.slab_held_at_hi = face % 2 == 1;
          d.reference_J_inf = d.M_inf * st.built.mean_square_distance(d.center);
        }
      }
    }
    if (!d.reference_length)
      throw ConfigError("diagnostics.reference_length", "(missing)",
                        "required for reference = \"crank_slab\" unless the domain is a box with one Dirichlet face");
  }

  // The library object: projection, barrier, walls and stepper (Algorithm 1).
  rp.M_inf = d.M_inf;
  rp.particle_mass = d.particle_mass;
  SimulationOptions so = simulation_options(rp, ro);
  so.seed = static_cast<std::uint64_t>(c.run.seed);
  so.max_particles = d.max_particles;
  so.projection.dirichlet_target = dirichlet_target_from_string(pa.dirichlet_target);
  const TreatmentSection& tr = c.treatment;
  const SolverSection& s = c.solver;
  NeighborOptions nb;
  nb.kernel_tolerance = s.kernel_tolerance;
  nb.skin = -1.0;
  nb.skin_factor = s.skin_factor;
  if (so.stepper == StepperKind::Implicit) {
    ImplicitOptions& io = so.implicit;
    io.minimizer.backend = backend_from_string(s.backend);
    io.minimizer.algorithm = algorithm_from_string(s.algorithm);
    io.minimizer.max_iterations = static_cast<int>(s.max_iterations);
    io.minimizer.max_evaluations = static_cast<int>(s.max_evaluations);
    io.minimizer.lbfgs_memory = static_cast<int>(s.lbfgs_memory);
    io.displacement_tolerance = s.displacement_tolerance;
    io.relative_tolerance = s.relative_tolerance;
    io.width_mode = width_mode_from_string(s.width_mode);
    io.width_metric = width_metric_from_string(s.width_metric);
    io.time_scheme = time_scheme_from_string(s.time_scheme);
    io.predictor = predictor_from_string(s.predictor);
    io.error_smoothing = s.error_smoothing;
    io.error_measure = error_measure_from_string(s.error_measure);
    io.stopping_norm = stopping_norm_from_string(s.stopping_norm);
    io.max_norm_factor = s.max_norm_factor;
    io.max_width_factor = s.max_width_factor;
    io.neighbor = nb;
    io.max_halvings = static_cast<int>(s.max_halvings);
    io.energy_tolerance = s.energy_tolerance;
  } else {
    ExplicitOptions& eo = so.explicit_options;
    eo.scheme = explicit_scheme_from_string(s.explicit_scheme);
    eo.neighbor = nb;
  }
  so.velocity = c.physics.velocity;
  so.source_rate = c.physics.source_rate;
  // Adaptive dt (run.dt_mode): the controller's bounds; dt_max is at least dt_min.
  TimeStepControlOptions& tco = so.time_control;
  tco.tolerance = c.run.time_tolerance;
  if (c.run.dt_min) tco.dt_min = *c.run.dt_min;  // else the library's 1e-3 dt
  tco.dt_max = std::max(c.run.dt_max ? *c.run.dt_max : c.run.t_end, tco.dt_min);
  check_magnitudes(data);
  try {
    st.data = data;
    st.options = so;
    st.sim = std::make_unique<otfp::Simulation>(domain_, std::move(data), so);
  } catch (const SimulationSetupError& e) {
    using Stage = SimulationSetupError::Stage;
    switch (e.stage()) {
      case Stage::Reservoir:
        throw ConfigError("treatment.dirichlet", "\"reservoir\"", std::string("not available here: ") + e.what());
      case Stage::ReservoirMirror: {
        // The band w = reservoir_width x r_c (r_c from the kernel tolerance)
        // in reservoir_sublayers sublayers: the key at fault is one whose
        // default makes the setup work (tried here, on the error path only);
        // otherwise the band is too wide for this domain and spacing.
        auto band = [&](double tolerance, std::int64_t sublayers) {
          RunSetupOptions r = ro;
          r.kernel_tolerance = tolerance;
          r.treatment.reservoir_sublayers = static_cast<int>(sublayers);
          return run_parameters(*domain_, st.data, r);
        };
        auto works = [&](double tolerance, std::int64_t sublayers) {
          SimulationOptions o = so;
          const RunParameters b = band(tolerance, sublayers);
          o.projection.reservoir_thickness = b.reservoir_width;
          o.projection.reservoir_sublayers = b.reservoir_sublayers;
          o.implicit.neighbor.kernel_tolerance = o.explicit_options.neighbor.kernel_tolerance = tolerance;
          try {
            otfp::Simulation trial(domain_, st.data, o);
            return true;
          } catch (const std::exception&) {
            return false;
          }
        };
        const double default_tolerance = SolverSection{}.kernel_tolerance;
        if (tr.reservoir_sublayers > 0 && works(c.solver.kernel_tolerance, 0))
          throw ConfigError(
              "treatment.reservoir_sublayers", fmt::format("{}", tr.reservoir_sublayers),
              fmt::format("sublayers of {:.4g} (band {:.4g}, spacing dr = {:.4g}) are too thin for the odd profile to "
                          "mirror inside Omega ({}); use fewer (0: round(2 w / dr) = {} works)",
                          d.reservoir_width / static_cast<double>(tr.reservoir_sublayers), d.reservoir_width, d.dr,
                          e.what(), band(c.solver.kernel_tolerance, 0).reservoir_sublayers));
        if (c.solver.kernel_tolerance != default_tolerance && works(default_tolerance, tr.reservoir_sublayers))
          throw ConfigError(
              "solver.kernel_tolerance", fmt::format("{}", c.solver.kernel_tolerance),
              fmt::format("gives the kernel cut-off r_c = {:.4g} ({:.3g} widths) and so a reservoir band of "
                          "treatment.reservoir_width x r_c = {:.4g} that the odd profile cannot mirror inside Omega "
                          "({}); the default {} works",
                          d.reservoir_width / tr.reservoir_width, d.reservoir_width / tr.reservoir_width / d.width_s,
                          d.reservoir_width, e.what(), default_tolerance));
        throw ConfigError("treatment.reservoir_width", fmt::format("{}", tr.reservoir_width),
                          fmt::format("gives a band of {} that the odd profile cannot mirror inside Omega ({}); "
                                      "raise particles.n_inf or lower the width",
                                      d.reservoir_width, e.what()));
      }
      case Stage::Projection:
        throw ConfigError("boundary", std::string("boundary: ") + e.what());
      case Stage::Periodic:
        throw ConfigError("domain.hi", fmt::format("[{}, {}, {}]", c.domain.hi[0], c.domain.hi[1], c.domain.hi[2]),
                          std::string(e.what()) + ": enlarge the box or raise particles.n_inf");
      case Stage::Walls:
        throw ConfigError("treatment.no_flux", "\"" + tr.no_flux + "\"",
                          std::string("walls: ") + e.what() + "; set treatment.no_flux = \"barrier\"");
      case Stage::Stepper:
        break;
    }
    throw ConfigError("solver", std::string("solver: ") + e.what());
  } catch (const InvalidArgument& e) {
    throw ConfigError("solver", std::string("solver: ") + e.what());
  }
  if (st.file_particles) check_fill_file(c, *st.sim, *st.file_particles);
  d.barrier_domain = st.sim->barrier_domain_description();
  d.mirrored_walls = st.sim->mirrored_walls();
}

nlohmann::json ConfiguredRun::describe() const {
  const Config& c = config_;
  const Derived& d = derived_;
  // The resolved configuration: every key of the table, defaults filled in.
  const nlohmann::json cfg = config_to_json(c);

  nlohmann::json pj = nlohmann::json::array();
  for (const PatchInfo& pi : patches_)
    pj.push_back({{"id", pi.id},
                  {"name", pi.name},
                  {"area", pi.area},
                  {"kind", pi.kind},
                  {"value", pi.value},
                  {"t_start", pi.t_start},
                  {"t_end", opt(pi.t_end)}});
  nlohmann::json der = {{"volume", d.volume},
                        {"dr", d.dr},
                        {"beta", d.beta},
                        {"width_s", d.width_s},
                        {"width_reference_dr", d.width_reference_dr},
                        {"true_spacing", d.true_spacing},
                        {"beta_true_spacing2", d.beta_true_spacing2},
                        {"mass_blob_method", to_string(blob_mass_method(*domain_))},
                        {"length_L", d.length_L},
                        {"layer_b", d.layer_b},
                        {"dt_explicit", d.dt_explicit},
                        {"dt", d.dt},
                        {"n_steps", d.n_steps},
                        {"steps_to_run", d.steps_to_run},
                        {"barrier_C", d.barrier_C},
                        {"barrier_domain", d.barrier_domain},
                        {"mirrored_walls", d.mirrored_walls},
                        {"reservoir_width", d.reservoir_width},
                        {"reservoir_sublayers", d.reservoir_sublayers},
                        {"particle_mass", d.particle_mass},
                        {"M_inf", d.M_inf},
                        {"M_inf_rule", d.M_inf_rule},
                        {"J_inf", opt(d.J_inf)},
                        {"J_inf_rule", d.J_inf_rule},
                        {"center", to_json(d.center)},
                        {"fill_count", d.fill_count},
                        {"max_particles", d.max_particles},
                        {"neumann_net_inflow", d.neumann_net_inflow},
                        {"reference_radius", opt(d.reference_radius)},
                        {"reference_length", opt(d.reference_length)},
                        {"reference_J_inf", opt(d.reference_J_inf)},
                        {"mode_wavenumber", d.mode_wavenumber},
                        {"lattice_counts", d.lattice_counts},
                        {"patches", pj}};
  return {{"config", cfg}, {"derived", der}};
}

ParticleSet ConfiguredRun::initial_particles(Rng& rng) const {
  const Config& c = config_;
  const Derived& d = derived_;
  ParticleSet fill(c.run.dim);
  if (state_->file_particles) {
    fill = *state_->file_particles;
  } else if (d.fill_count > 0) {  // a lattice is filled whatever particles.fill says
    FillOptions fo;
    fo.shape = c.particles.fill == "empty" ? FillShape::Uniform : fill_shape_from_string(c.particles.fill);
    fo.count = d.fill_count;
    fo.width_s = d.width_s;
    fo.mass = d.particle_mass;
    fo.lattice = c.particles.fill_arrangement == "lattice";
    fo.lattice_counts = d.lattice_counts;
    fo.lo = c.domain.lo;
    fo.hi = c.domain.hi;
    fo.center = c.particles.fill_center.value_or(d.center);
    fo.sigma = c.particles.fill_sigma;
    fo.amplitude = c.particles.fill_amplitude;
    fo.wavenumber = d.mode_wavenumber;
    fill = fill_particles(*domain_, fo, rng);
  }
  return fill;
}

std::unique_ptr<otfp::Simulation> ConfiguredRun::make_simulation() const {
  auto sim = std::make_unique<otfp::Simulation>(domain_, state_->data, state_->options);
  Rng rng(static_cast<std::uint64_t>(config_.run.seed));  // the stream run() uses
  ParticleSet fill = initial_particles(rng);
  sim->start(std::move(fill), rng, 0.0);
  return sim;
}

RunResult ConfiguredRun::run(const RunOptions& options) {
  const Config& c = config_;
  const Derived& d = derived_;
  State& st = *state_;
  const int dim = c.run.dim;
  if (c.run.threads > 0) omp_set_num_threads(c.run.threads);
  const auto wall0 = Clock::now();
  auto wall = [&] { return std::chrono::duration<double>(Clock::now() - wall0).count(); };

  RunResult result;
  Rng rng(static_cast<std::uint64_t>(c.run.seed));
  otfp::Simulation& sim = *st.sim;
  const ParticleSet& particles = sim.particles();
  const std::filesystem::path& out = options.out_dir;
  const bool write = !out.empty();
  AppendFile series_file, timing_file;
  std::vector<std::pair<double, std::string>> snapshots;
  std::int64_t last_snapshot = -1;

  // The analytic reference: its columns, rows, error statistics and state (docs/outputs.md).
  const std::unique_ptr<Reference> reference = configured_reference(c, d);
  // Column layout of series.csv (fixed by the configuration, not by the run).
  const SeriesLayout layout(d.J_inf.has_value(), reference && reference->has_mass_blob_error(),
                            reference ? reference->columns() : std::vector<std::string>{});
  const std::string& header = layout.header();
  // Closed forms cost ~0.1 us per particle (disc and cylinder ~3 us near the
  // wall); the quadrature path (square_pipe_obstacle) runs 4 x 4 normal lines
  // per blob near a wall instead of the library's 10 x 10 (6x cheaper, about
  // 1e-3 of the near-wall blob mass either way, docs/outputs.md).
  BlobMassOptions blob_options;
  blob_options.hermite_nodes = 4;

  std::int64_t n0 = 0;
  double M0 = 0.0;
  // (46): the rectangle sums go into the series, the trapezoid sums into summary.json.
  L1Norms l1;
  StateMeasures prev_measures;
  // The step being taken (fixed: d.dt, as (46) is summed; adaptive: its own
  // length) and the tries the error test rejected before it.
  double step_dt = d.dt;
  std::int64_t step_rejections = 0;
  StepRecord prev;
  std::vector<std::int32_t> region;

  auto diagnostics = [&](std::int64_t step, double t, const StepSummary* sum, long ins, long rem) {
    StepRecord r;
    r.step = step;
    r.t = t;
    r.dt = step == 0 ? 0.0 : step_dt;
    // (43)-(44) inside Omega and with the buffer outside the Dirichlet faces.
    const StateMeasures ms = sim.measure(d.center, &region);
    r.n_particles = ms.n_particles;
    r.n_inside = ms.n_inside;
    r.n_buffer = ms.n_buffer;
    r.n_outside = ms.n_outside;
    r.mass_total = ms.mass_total;
    r.mass_inside = ms.mass_inside;
    r.mass_with_layer = ms.mass_with_layer;
    r.polar_inertia = ms.polar_inertia;
    r.polar_inertia_with_layer = ms.polar_inertia_with_layer;
    r.polar_inertia_total = ms.polar_inertia_total;
    r.mean_age = ms.mean_age;
    r.max_age = ms.max_age;
    r.inserted = ins;
    r.removed = rem;
    r.inserted_total = sim.ledger().inserted;
    r.removed_total = sim.ledger().removed;
    if (sum) {
      r.energy = sum->f_after;
      r.transport = sum->parts_after.transport;
      r.entropy = sum->parts_after.entropy;
      r.barrier = sum->parts_after.barrier;
      r.residual_displacement = sum->residual_displacement;
      r.iterations = sum->iterations;
      r.evaluations = sum->evaluations;
      r.list_builds = sum->list_builds;
      r.halvings = sum->halvings;
      if (std::isfinite(sum->error_estimate)) r.error_estimate = sum->error_estimate;
      r.rejected_steps = step_rejections;
      r.step_seconds = sum->wall_seconds;
      r.solver_seconds = sum->solver_seconds;
      r.list_seconds = sum->list_seconds;
    }
    // (46a)-(46b) as printed: sum over k = 0..K of the value at t_k times dt, all particles.
    if (step == 0)
      l1.add_first(ms, step_dt);
    else
      l1.add(prev_measures, ms, step_dt);
    prev_measures = ms;
    r.l1_mass = l1.mass_rectangle;
    r.l1_polar_inertia = l1.polar_inertia_rectangle;
    r.mass_ratio = r.mass_inside / d.M_inf;
    if (d.J_inf) r.polar_inertia_ratio = r.polar_inertia / *d.J_inf;
    r.mass_blob = sim.blob_mass(blob_options);
    r.mass_blob_ratio = r.mass_blob / d.M_inf;
    // Analytic reference: measured, reference, error (scaled) per row.
    if (reference) {
      ReferenceSample sample;
      sample.t = t;
      sample.measures = ms;
      sample.mass_blob = r.mass_blob;
      sample.particles = &particles;
      sample.initial_mass = M0;
      ReferenceRow row = reference->row(sample);
      r.reference_values = std::move(row.values);
      r.reference = row.reference;
      r.error_mass_blob = row.error_mass_blob;
    }
    r.wall_seconds = wall();
    return r;
  };

  auto snapshot = [&](const StepRecord& r) {
    if (!write || last_snapshot == r.step) return;
    for (const Vec3& x : particles.positions())
      if (!x.allFinite()) throw RunError(fmt::format("non-finite particle position at step {}", r.step));
    const std::string name = fmt::format("particles_{:05d}.vtp", r.step);
    // The blob density (29) at each particle (images across mirrored walls not included).
    std::vector<double> rho;
    if (!particles.empty())
      blob_density(particles, particles.positions(),
                   domain_->is_periodic() ? Periodicity::from_domain(*domain_) : Periodicity::none(dim),
                   c.solver.kernel_tolerance, rho, nullptr);
    write_file_atomic(out / name, vtp_document(particles, r.t, region, rho));
    snapshots.emplace_back(r.t, name);
    write_file_atomic(out / "particles.pvd", pvd_document(snapshots));
    last_snapshot = r.step;
  };

  auto ledger_json = [&]() {
    nlohmann::json patches = nlohmann::json::array();
    for (const PatchInfo& p : patches_) {
      nlohmann::json j = {{"patch", p.name}, {"kind", p.kind}};
      PatchLedger l;
      if (p.condition >= 0) l = sim.projection().ledger()[static_cast<std::size_t>(p.condition)];
      j["inserted"] = l.inserted;
      j["removed"] = l.removed;
      j["mass_inserted"] = l.mass_inserted;
      j["mass_removed"] = l.mass_removed;
      j["absorbed"] = l.absorbed;
      j["mass_absorbed"] = l.mass_absorbed;
      j["flux_integral"] = l.flux_integral;
      j["carry"] = l.carry;
      j["deficit"] = l.deficit;
      patches.push_back(j);
    }
    const SimulationLedger& g = sim.ledger();
    return nlohmann::json{{"initial_particles", n0},
                          {"reflected", g.reflected},
                          {"initial_mass", M0},
                          {"inserted", g.inserted},
                          {"removed", g.removed},
                          {"mass_inserted", g.mass_inserted},
                          {"mass_removed", g.mass_removed},
                          {"source", {{"inserted", g.source_inserted},
                                      {"removed", g.source_removed},
                                      {"mass_inserted", g.source_mass_inserted},
                                      {"mass_removed", g.source_mass_removed}}},
                          {"patches", patches}};
  };

  auto summary = [&](const std::string& status, const std::string& error, const StepRecord& last) {
    nlohmann::json j = describe();
    j["otfp_version"] = version();
    j["status"] = status;
    j["error"] = error;
    j["config_file"] = c.source;
    j["overrides"] = c.overrides;
    j["seed"] = c.run.seed;
    j["wall_seconds"] = wall();
    j["threads"] = omp_get_max_threads();
    j["final"] = final_json(last);
    j["l1"] = {{"rule_series", "rectangle sum over k = 0..K of the value at t_k times dt, all particles (46) as printed"},
               {"mass_rectangle", last.l1_mass},
               {"polar_inertia_rectangle", last.l1_polar_inertia},
               {"rule_trapezoid", "trapezoid rule over [0, t]"},
               {"mass_inside_trapezoid", l1.mass_inside_trapezoid},
               {"mass_with_layer_trapezoid", l1.mass_with_layer_trapezoid},
               {"polar_inertia_inside_trapezoid", l1.polar_inertia_inside_trapezoid},
               {"polar_inertia_with_layer_trapezoid", l1.polar_inertia_with_layer_trapezoid}};
    if (reference) j["reference"] = reference_json(*reference);
    j["ledger"] = ledger_json();
    const SimulationTotals& tt = sim.totals();
    j["solver_totals"] = {{"iterations", tt.iterations},
                          {"evaluations", tt.evaluations},
                          {"rejected_solves", tt.rejected_solves},
                          {"halvings", tt.halvings},
                          {"error_rejected_steps", tt.error_rejected_steps},
                          {"steps_forced_at_dt_min", tt.steps_forced_at_dt_min},
                          {"dt_min_used", tt.dt_max_used > 0.0 ? nlohmann::json(tt.dt_min_used) : nlohmann::json(nullptr)},
                          {"dt_max_used", tt.dt_max_used > 0.0 ? nlohmann::json(tt.dt_max_used) : nlohmann::json(nullptr)}};
    // Where the diffusion steps spent their time (wall clock, not reproducible).
    j["profile"] = {{"diffusion_step_seconds", tt.step_seconds},
                    {"solver_seconds", tt.solver_seconds},
                    {"neighbor_list_seconds", tt.list_seconds},
                    {"evaluation_seconds", std::max(0.0, tt.step_seconds - tt.solver_seconds - tt.list_seconds)},
                    {"other_seconds", std::max(0.0, wall() - tt.step_seconds)},
                    {"rule", "evaluation = diffusion step - solver - neighbour list (pair sweeps, barrier, sorting); "
                             "other = wall - diffusion steps (projection, advection, source, diagnostics, output)"}};
    return j;
  };

  // domain.vtp: the boundary of Omega and, where there is one, the outer
  // surface of the buffer over the Dirichlet patches (its cells carry patch
  // id + the number of patches). A coarse display mesh in a file of its own:
  // listed in particles.pvd, ParaView would draw it opaque over the
  // particles. view.py (ParaView) shows the particles with it translucent.
  auto write_domain_surface = [&](const std::filesystem::path& dir) {
    bool surface = false;
    if (!free_space_) {
      const int cells = dim == 3 ? 12 : 256;  // the sphere with its buffer: ~7k triangles, 0.14 MB
      SurfaceMesh mesh = boundary_surface(*domain_, 0.0, cells);
      std::vector<int> dirichlet;
      for (const PatchInfo& p : patches_)
        if (p.kind == "dirichlet") dirichlet.push_back(p.id);
      const double buffer = sim.buffer().buffer_width;
      if (!dirichlet.empty() && buffer > 0.0) {
        const SurfaceMesh outer = boundary_surface(*domain_, buffer, cells, dirichlet);
        const auto base = static_cast<std::int64_t>(mesh.points.size());
        mesh.points.insert(mesh.points.end(), outer.points.begin(), outer.points.end());
        for (std::int64_t i : outer.cells) mesh.cells.push_back(base + i);
        for (int patch : outer.patch) mesh.patch.push_back(patch + domain_->num_patches());
      }
      surface = mesh.num_cells() > 0;
      if (surface) write_file_atomic(dir / "domain.vtp", surface_vtp(mesh));
    }
    write_file_atomic(dir / "view.py", paraview_script("particles.pvd", surface ? "domain.vtp" : "",
                                                       std::filesystem::absolute(dir).string()));
  };

  const bool progress = options.progress;
  auto last_progress = Clock::now() - std::chrono::seconds(1);
  // (wall, progress) at the recent progress lines: the ETA uses the rate over
  // the last ~20 of them (a few seconds), not the average since the start,
  // which the first steps (filling, the first solves) skew.
  std::deque<std::pair<double, double>> recent;
  auto show_progress = [&](const StepRecord& r, bool final_line) {
    if (!progress) return;
    const auto now = Clock::now();
    if (!final_line && now - last_progress < std::chrono::milliseconds(200)) return;
    last_progress = now;
    // Adaptive dt: the number of steps is not known; time is.
    const bool by_time = c.run.dt_mode == "adaptive";
    const double done = by_time ? r.t : static_cast<double>(r.step);
    const double total = by_time ? c.run.t_end : static_cast<double>(d.steps_to_run);
    recent.emplace_back(wall(), done);
    if (recent.size() > 20) recent.pop_front();
    const double dw = recent.back().first - recent.front().first, dp = recent.back().second - recent.front().second;
    const double eta = dp > 0.0 ? dw / dp * std::max(0.0, total - done) : 0.0;
    const double its = r.step > 0 ? static_cast<double>(sim.totals().iterations) / static_cast<double>(r.step) : 0.0;
    std::fprintf(stderr, "\rstep %lld/%s  t=%.4g  n=%lld  M/M_inf=%.4f  it/step=%.1f  ETA %s   ",
                 static_cast<long long>(r.step),
                 c.run.dt_mode == "adaptive" ? "?" : std::to_string(d.steps_to_run).c_str(), r.t,
                 static_cast<long long>(r.n_particles), r.mass_ratio, its, hms(eta).c_str());
    if (final_line) std::fputc('\n', stderr);
    std::fflush(stderr);
  };

  StepRecord last;
  bool interrupted = false;
  std::chrono::steady_clock::time_point kill_summary_time{};
  // The summary.json a second signal leaves behind (kill_time_cleanup), from
  // the last row written (`have_row`) or before the first one.
  auto arm_kill_summary = [&](const StepRecord& r, bool have_row) {
    if (!write || !options.stop_flag) return;
    const std::string why =
        have_row ? fmt::format("stopped by a second signal during a step after step {} (t = {}); the files are "
                               "complete up to step {} at least; continue from the last checkpoint, if one was "
                               "written, with: otfp run --resume {}",
                               r.step, r.t, r.step, out.string())
                 : std::string("stopped by a second signal before the first row was written");
    set_kill_time_summary(out / "summary.json", summary("interrupted", why, r).dump(2) + "\n");
  };
  try {
    auto emit = [&](const StepRecord& r, bool final_row) {
      const std::string line = layout.row(r);
      if (write) {
        // A row is in both files or in neither (a full disk fails either write).
        const std::uint64_t series_size = series_file.size();
        series_file.append(line);
        try {
          timing_file.append(fmt::format("{},{},{},{},{},{}\n", r.step, r.t, r.wall_seconds, r.step_seconds,
                                         r.solver_seconds, r.list_seconds));
        } catch (...) {
          series_file.truncate(series_size);
          throw;
        }
        if (r.step == 0 || final_row || (c.run.vtk_interval > 0 && r.step % c.run.vtk_interval == 0)) snapshot(r);
      }
      if (options.keep_series) result.series.push_back(r);
      prev = r;
      last = r;
      result.rows = true;
      show_progress(r, final_row);
      // Rendered at most twice a second, and for the first row.
      const auto now = std::chrono::steady_clock::now();
      if (r.step == 0 || now - kill_summary_time >= std::chrono::milliseconds(500)) {
        kill_summary_time = now;
        arm_kill_summary(r, true);
      }
    };

    // The library's time loop: fixed steps on its grid t_k = k dt (kept in the
    // checkpoint: a resumed run keeps its grid when its dt is unchanged, and
    // its step when run.t_end moved), or the adaptive controller.
    RunControl control;
    control.t_end = c.run.t_end;
    control.dt = d.dt;
    control.adaptive = c.run.dt_mode == "adaptive";
    control.max_steps = c.run.max_steps;
    control.checkpoint_interval = c.run.checkpoint_interval;
    control.stop = [&](const SimulationStep& s) {
      return (options.stop_flag && *options.stop_flag) ||
             (options.stop_after_step > 0 && s.step >= options.stop_after_step);
    };
    const std::filesystem::path checkpoint_file = out / "checkpoint.bin";
    // The configuration the checkpoints are written with (a resume must match it).
    const std::map<std::string, std::string> fingerprint = write ? config_fingerprint(c) : std::map<std::string, std::string>{};
    // The driver's running sums, kept in the checkpoint next to the library state.
    auto driver_state = [&]() {
      nlohmann::json js;
      js["l1"] = l1_state(l1);
      js["prev_measures"] = measures_state(prev_measures);
      js["reference"] = reference ? nlohmann::json(reference->save_state()) : nlohmann::json::object();
      js["snapshots"] = snapshots;
      js["last_snapshot"] = last_snapshot;
      js["n0"] = n0;
      js["M0"] = M0;
      js["last_step"] = last.step;
      js["last_t"] = last.t;
      js["last_mass_ratio"] = last.mass_ratio;
      js["last_n"] = last.n_particles;
      js["config"] = fingerprint;
      return js;
    };
    auto write_checkpoint = [&]() {
      if (write) sim.save_checkpoint(checkpoint_file, driver_state().dump());
    };

    if (!options.resume) {
      ParticleSet fill = initial_particles(rng);
      n0 = static_cast<std::int64_t>(fill.size());
      M0 = fill.total_mass();

      if (write) {
        std::filesystem::create_directories(out);
        series_file = AppendFile(out / "series.csv", header);
        timing_file = AppendFile(out / "timing.csv", kTimingHeader);
        write_file_atomic(out / "config.toml", to_toml(c));
        arm_kill_summary(StepRecord{}, false);
        write_domain_surface(out);
        write_file_atomic(out / "summary.json", summary("running", "", StepRecord{}).dump(2) + "\n");
      }

      // Algorithm 1 runs in the library; the reservoir (if any) is filled
      // before the first step, counted as step 0's insertions.
      sim.start(std::move(fill), rng, 0.0);
      emit(diagnostics(0, 0.0, nullptr, sim.initial_step().inserted, sim.initial_step().removed), false);
    } else {
      // Everything the resume needs is read and checked before any file is
      // touched: a refused resume leaves the run's directory as it was.
      std::string series_text, timing_text;
      try {
        // The driver's data first: a checkpoint of another configuration is
        // refused naming the key (the library would name its own field).
        nlohmann::json js;
        try {
          js = nlohmann::json::parse(otfp::Simulation::checkpoint_extra(checkpoint_file));
        } catch (const nlohmann::json::exception& e) {
          throw ResumeRefused(fmt::format("checkpoint {}: not written by otfp run (its driver state: {})",
                                          checkpoint_file.string(), e.what()));
        } catch (const std::exception& e) {
          throw ResumeRefused(e.what());
        }
        // The checkpoint's configuration against this one, key by key.
        if (!js.contains("config") || !js["config"].is_object())
          throw ResumeRefused(fmt::format("checkpoint {}: holds no configuration to compare with (written by an "
                                          "older otfp?)",
                                          checkpoint_file.string()));
        std::map<std::string, std::string> theirs;
        try {
          theirs = js["config"].get<std::map<std::string, std::string>>();
        } catch (const nlohmann::json::exception& e) {
          throw ResumeRefused(fmt::format("checkpoint {}: its configuration is unreadable ({})",
                                          checkpoint_file.string(), e.what()));
        }
        if (theirs != fingerprint) {
          std::vector<std::string> differ;
          auto shown = [](const std::map<std::string, std::string>& m, const std::string& k) {
            const auto it = m.find(k);
            return it == m.end() ? std::string("(absent)") : it->second;
          };
          for (const auto& [k, v] : fingerprint)
            if (shown(theirs, k) != v)
              differ.push_back(fmt::format("{} = {} (the checkpoint's: {})", k, v, shown(theirs, k)));
          for (const auto& [k, v] : theirs)
            if (!fingerprint.count(k)) differ.push_back(fmt::format("{} = (absent) (the checkpoint's: {})", k, v));
          const std::size_t more = differ.size() > 3 ? differ.size() - 3 : 0;
          differ.resize(std::min<std::size_t>(differ.size(), 3));
          std::string list;
          for (const std::string& x : differ) list += (list.empty() ? "" : "; ") + x;
          if (more > 0) list += fmt::format("; and {} more", more);
          throw ResumeRefused(fmt::format("{} differs from the run that wrote {}: {} (only {} may change on --resume, "
                                          "with --set)",
                                          (out / "config.toml").string(), checkpoint_file.string(), list,
                                          fmt::join(resume_keys(), ", ")));
        }
        try {
          sim.load_checkpoint(checkpoint_file);
        } catch (const std::exception& e) {
          throw ResumeRefused(e.what());
        }
        try {
          l1 = l1_from_state(js.at("l1"));
          prev_measures = measures_from_state(js.at("prev_measures"));
          if (reference) load_reference_state(*reference, js.at("reference"), checkpoint_file);
          snapshots = js.at("snapshots").get<std::vector<std::pair<double, std::string>>>();
          last_snapshot = js.at("last_snapshot").get<std::int64_t>();
          n0 = js.at("n0").get<std::int64_t>();
          M0 = js.at("M0").get<double>();
          last.step = js.at("last_step").get<std::int64_t>();
          last.t = js.at("last_t").get<double>();
          last.mass_ratio = js.at("last_mass_ratio").get<double>();
          last.n_particles = js.at("last_n").get<std::int64_t>();
        } catch (const nlohmann::json::exception& e) {
          throw ResumeRefused(fmt::format("checkpoint {}: not written by otfp run (its driver state: {})",
                                          checkpoint_file.string(), e.what()));
        }
        const std::int64_t k_done = sim.step_count();
        if (!(c.run.t_end >= sim.time()))
          throw ResumeRefused(fmt::format("run.t_end = {}: must be >= the time t = {} of {} (step {})", c.run.t_end,
                                          sim.time(), checkpoint_file.string(), k_done));
        if (!(sim.time_grid().dt > 0.0) && !control.adaptive)
          throw ResumeRefused(fmt::format("checkpoint {}: holds no grid of steps (written by an older otfp?)",
                                          checkpoint_file.string()));
        step_dt = sim.grid_for(control).dt;
        if (sim.finished(control)) {
          result.status = "completed";
          result.nothing_to_do = true;
          result.last = last;
          return result;
        }
        // The rows after the checkpoint (a run killed between checkpoints) are taken again.
        series_text = csv_up_to_step(out / "series.csv", header, k_done);
        timing_text = csv_up_to_step(out / "timing.csv", kTimingHeader, k_done);
      } catch (const ResumeRefused& e) {
        result.status = "refused";
        result.error = e.what();
        result.exit_code = kExitRefused;
        return result;
      }
      result.rows = true;  // the rows up to the checkpoint
      series_file = AppendFile(out / "series.csv", series_text);
      timing_file = AppendFile(out / "timing.csv", timing_text);
      arm_kill_summary(last, true);
      write_file_atomic(out / "summary.json", summary("running", "", last).dump(2) + "\n");
    }
    // Each step's row (the row of a stopped run's last step is final: snapshot
    // and progress line), and the checkpoints at the run's cadence.
    struct Observer : RunObserver {
      std::function<void(const SimulationStep&, bool)> row;
      std::function<void()> checkpoint;
      void on_step(const otfp::Simulation&, const SimulationStep& step, bool last_step) override { row(step, last_step); }
      void on_checkpoint(const otfp::Simulation&) override { checkpoint(); }
    } observer;
    observer.row = [&](const SimulationStep& step, bool last_step) {
      step_dt = control.adaptive ? step.dt() : sim.time_grid().dt;
      step_rejections = step.error_rejections;
      emit(diagnostics(step.step, step.t_end, &step.diffusion, static_cast<long>(step.inserted),
                       static_cast<long>(step.removed)),
           last_step);
    };
    observer.checkpoint = write_checkpoint;
    interrupted = sim.run(control, &observer) == RunEnd::Stopped;
    if (interrupted) {
      result.status = "interrupted";
      result.error = fmt::format("interrupted after step {} (t = {}); continue with: otfp run --resume {}", last.step,
                                 last.t, out.string());
      result.exit_code = kExitInterrupted;
    } else {
      // Final particles as CSV (widths for histograms, positions for profiles).
      if (write) write_file_atomic(out / "particles_final.csv", particles_csv(particles, region));
      result.status = "completed";
      result.exit_code = 0;
    }
  } catch (const std::exception& e) {
    result.status = "failed";
    result.error = e.what();
    result.exit_code = 1;
    if (progress) std::fputc('\n', stderr);
    // The state the failing step started from (the library puts it back), for
    // inspection; not part of particles.pvd.
    if (write) {
      try {
        bool finite = true;
        for (const Vec3& x : particles.positions()) finite = finite && x.allFinite();
        if (finite) {
          std::vector<std::int32_t> flags;
          sim.measure(d.center, &flags);
          std::filesystem::create_directories(out);
          write_file_atomic(out / "particles_failed.vtp", vtp_document(particles, last.t, flags));
        }
      } catch (const std::exception&) {
        // Best effort: the error being reported matters more.
      }
    }
  }
  result.last = last;
  result.summary = summary(result.status, result.error, last);
  if (write) {
    try {
      std::filesystem::create_directories(out);
      write_file_atomic(out / "summary.json", result.summary.dump(2) + "\n");
    } catch (const std::exception& e) {
      if (result.exit_code == 0) {
        result.status = "failed";
        result.error = e.what();
        result.exit_code = 1;
      } else {
        std::error_code ec;
        result.error += std::filesystem::exists(out / "summary.json", ec)
                            ? fmt::format("; summary.json could not be updated either ({}): it may still say "
                                          "\"running\"",
                                          e.what())
                            : fmt::format("; summary.json could not be written either ({}): there is no summary.json",
                                          e.what());
      }
    }
  }
  return result;
}

}  // namespace otfp::app
