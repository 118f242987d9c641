// Validation of a read Config: every key's own rule from the table, then the
// rules that combine keys. Each broken rule is one ConfigError.
#include <filesystem>
#include <set>
#include <string>
#include <system_error>

#include "config_table.hpp"
#include "otfp/minimizer.hpp"

namespace otfp::app::config_detail {

namespace {

namespace fs = std::filesystem;

// Required keys of an array of tables are "missing" while empty (strings) or NaN (numbers).
bool is_missing(const Value& v) {
  if (const auto* s = std::get_if<std::string>(&v)) return s->empty();
  if (const auto* d = std::get_if<double>(&v)) return std::isnan(*d);
  return std::holds_alternative<std::monostate>(v);
}

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


}  // namespace

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
  const bool implicit = c.solver.stepper == StepperKind::Implicit;
  if (r.dt_mode == DtMode::Adaptive && !implicit)
    throw ConfigError("run.dt_mode", "\"adaptive\"",
                      "needs solver.stepper = \"implicit\" (the explicit schemes have no error estimate)");

  const DomainSection& d = c.domain;
  const DomainType type = d.type;
  const bool box_shaped = type == DomainType::Box || type == DomainType::PeriodicBox || type == DomainType::Free;
  if (box_shaped || type == DomainType::SquarePipeObstacle) {
    for (int k = 0; k < r.dim; ++k)
      if (!(d.hi[k] > d.lo[k]))
        throw ConfigError("domain.hi", shown(d.hi),
                          fmt::format("must exceed domain.lo = {} in every used axis (axis {} gives zero volume)",
                                      shown(d.lo), "xyz"[k]));
  }
  if (type == DomainType::Cylinder) {
    if (r.dim != 3) throw ConfigError("domain.type", "\"cylinder\"", "needs run.dim = 3");
    if (!((d.end_b - d.end_a).norm() > 0.0))
      throw ConfigError("domain.end_b", shown(d.end_b), "must differ from domain.end_a (zero length)");
  }
  if (type == DomainType::SquarePipeObstacle) {
    if (r.dim < 2) throw ConfigError("domain.type", "\"square_pipe_obstacle\"", "needs run.dim = 2 or 3");
    if (r.dim == 2 && d.obstacle_axis != Axis::Z)
      throw ConfigError("domain.obstacle_axis", quoted(to_string(d.obstacle_axis)), "must be \"z\" in 2D (a disc obstacle)");
  }
  std::set<std::string> sub_names;
  for (std::size_t i = 0; i < d.subpatches.size(); ++i) {
    const SubPatchSpec& s = d.subpatches[i];
    if (!sub_names.insert(s.name).second)
      throw ConfigError(fmt::format("domain.subpatch[{}].name", i), quoted(s.name), "duplicate sub-patch name");
  }

  const ParticlesSection& pa = c.particles;
  if (pa.spacing_rule == SpacingRule::SphereRadius && r.dim != 3)
    throw ConfigError("particles.spacing_rule", "\"sphere_radius\"", "needs run.dim = 3 (use \"cube\")");
  if (pa.fill == Fill::File && !pa.fill_file)
    throw ConfigError("particles.fill_file", "(missing)", "required with particles.fill = \"file\"");
  if (pa.fill != Fill::File && pa.fill_file)
    throw ConfigError("particles.fill_file", quoted(*pa.fill_file),
                      "needs particles.fill = \"file\" (particles.fill = " + quoted(to_string(pa.fill)) + ")");
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
  if (pa.fill == Fill::Empty && (pa.fill_count || pa.fill_mass))
    throw ConfigError(pa.fill_count ? "particles.fill_count" : "particles.fill_mass",
                      pa.fill_count ? std::to_string(*pa.fill_count) : shown(*pa.fill_mass),
                      "needs particles.fill = \"uniform\", \"gaussian\" or \"cosine\"");
  if (pa.fill == Fill::Cosine && !box_shaped)
    throw ConfigError("particles.fill", "\"cosine\"", "needs domain.type = \"periodic_box\", \"box\" or \"free\"");
  if (pa.fill_arrangement != Arrangement::Random) {
    // Appended, not "\"" + ... + "\"": GCC 12's -Wrestrict misfires on that.
    std::string value(1, '"');
    value += to_string(pa.fill_arrangement);
    value += '"';
    if (pa.fill != Fill::Uniform && pa.fill != Fill::Cosine)
      throw ConfigError("particles.fill_arrangement", value, "needs particles.fill = \"uniform\" or \"cosine\"");
    if (!box_shaped)
      throw ConfigError("particles.fill_arrangement", value, "needs domain.type = \"periodic_box\", \"box\" or \"free\"");
    if (pa.fill_count || pa.fill_mass)
      throw ConfigError(pa.fill_count ? "particles.fill_count" : "particles.fill_mass",
                        pa.fill_count ? std::to_string(*pa.fill_count) : shown(*pa.fill_mass),
                        std::string("not used by fill_arrangement = ").append(value).append(
                            " (the lattice of spacing dr sets the count)"));
  }

  std::set<std::string> patches;
  for (std::size_t i = 0; i < c.boundary.size(); ++i) {
    const BoundarySpec& b = c.boundary[i];
    const std::string p = fmt::format("boundary[{}].", i);
    if (!patches.insert(b.patch).second)
      throw ConfigError(p + "patch", quoted(b.patch), "patch already has a [[boundary]] entry");
    const PatchKind kind = *b.kind;  // a required key (check_rules)
    if (kind == PatchKind::NoFlux && b.value)
      throw ConfigError(p + "value", shown(*b.value), "not used by kind \"no_flux\" (remove it)");
    if (kind != PatchKind::NoFlux && !b.value)
      throw ConfigError(p + "value", "(missing)",
                        kind == PatchKind::Dirichlet ? "required: the boundary density g (>= 0)"
                                                     : "required: the outward mass flux f (< 0 is inflow)");
    if (kind == PatchKind::Dirichlet && !(*b.value >= 0.0))
      throw ConfigError(p + "value", shown(*b.value), "must be >= 0");
    if (b.t_end && !(*b.t_end > b.t_start))
      throw ConfigError(p + "t_end", shown(*b.t_end), "must be > t_start = " + shown(b.t_start));
    if (kind != PatchKind::Neumann && (b.t_start != 0.0 || b.t_end))
      throw ConfigError(p + (b.t_end ? "t_end" : "t_start"), shown(b.t_end ? *b.t_end : b.t_start),
                        "activity windows are only supported for kind \"neumann\"");
  }

  const SolverSection& s = c.solver;
  if (!backend_available(s.backend))
    throw ConfigError("solver.backend", quoted(to_string(s.backend)),
                      "not available in this build of otfp (TAO needs OTFP_WITH_MPI=ON with PETSc 3.18 found)");
  if (!algorithm_offered(s.backend, s.algorithm))
    throw ConfigError("solver.algorithm", quoted(to_string(s.algorithm)),
                      "not offered by solver.backend = " + quoted(to_string(s.backend)) + " (allowed: " +
                          offered_algorithms(s.backend) + ")");
  const bool per_particle = s.width_mode == WidthMode::PerParticle;
  if (per_particle && !implicit)
    throw ConfigError("solver.width_mode", "\"per_particle\"", "needs solver.stepper = \"implicit\"");
  if (s.max_width_factor != 0.0 && !(s.max_width_factor > 1.0))
    throw ConfigError("solver.max_width_factor", shown(s.max_width_factor), "must be 0 (off) or in (1, 1e6]");
  if (s.max_width_factor != 0.0 && !per_particle)
    throw ConfigError("solver.max_width_factor", shown(s.max_width_factor),
                      "needs solver.width_mode = \"per_particle\" (fixed widths have no bound to keep)");
  if (s.time_scheme != TimeScheme::Euler && !implicit)
    throw ConfigError("solver.time_scheme", quoted(to_string(s.time_scheme)),
                      "needs solver.stepper = \"implicit\" (explicit schemes: solver.explicit_scheme)");
  if (s.predictor != Predictor::None && !implicit)
    throw ConfigError("solver.predictor", quoted(to_string(s.predictor)), "needs solver.stepper = \"implicit\"");

  const DiagnosticsSection& g = c.diagnostics;
  // cos(k (x - lo)) with k = 2 pi m / L is a mode of the periodic box and,
  // its slope vanishing at both ends, of a closed box (no-flux walls only).
  if (g.reference == "cosine_mode" && (type != DomainType::PeriodicBox && type != DomainType::Box))
    throw ConfigError("diagnostics.reference", "\"cosine_mode\"",
                      "needs domain.type = \"periodic_box\" or a closed \"box\", and particles.fill = \"cosine\"");
  if (g.reference == "cosine_mode" && pa.fill != Fill::Cosine)
    throw ConfigError("diagnostics.reference", "\"cosine_mode\"", "needs particles.fill = \"cosine\"");
  if (g.reference == "cosine_mode" && type == DomainType::Box)
    for (std::size_t i = 0; i < c.boundary.size(); ++i)
      if (c.boundary[i].kind != PatchKind::NoFlux)
        throw ConfigError(fmt::format("boundary[{}].kind", i), quoted(to_string(*c.boundary[i].kind)),
                          "diagnostics.reference = \"cosine_mode\" on a box needs every wall no-flux (a closed box)");
  if (g.reference == "cosine_mode" && !(pa.fill_amplitude > 0.0))
    throw ConfigError("particles.fill_amplitude", shown(pa.fill_amplitude),
                      "must be > 0 with diagnostics.reference = \"cosine_mode\" (the mode to follow)");
}

}  // namespace otfp::app::config_detail
