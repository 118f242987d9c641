// The configuration as the library's set-up inputs (RunSetupOptions), and
// the library's set-up errors, which name library fields, as ConfigErrors
// naming configuration keys.
#include "setup_keys.hpp"

#include <fmt/format.h>

#include <cctype>
#include <string>
#include <utility>
#include <vector>

namespace otfp::app::detail {

namespace {

// `text` with each whole word `name` (not part of a longer identifier)
// prefixed by `section`.
std::string with_keys(const std::string& text, const std::string& name, const std::string& section) {
  auto word = [](char ch) { return std::isalnum(static_cast<unsigned char>(ch)) || ch == '_' || ch == '.'; };
  std::string out;
  std::size_t at = 0;
  for (std::size_t i = text.find(name); i != std::string::npos; i = text.find(name, i + name.size())) {
    const bool starts = i == 0 || !word(text[i - 1]), ends = i + name.size() == text.size() || !word(text[i + name.size()]);
    if (!(starts && ends)) continue;
    out += text.substr(at, i - at) + section + name;
    at = i + name.size();
  }
  return out + text.substr(at);
}

}  // namespace

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
  o.M_inf = c.diagnostics.M_inf.value_or(0.0);
  o.particle_mass = c.particles.mass.value_or(0.0);
  const ParticlesSection& pa = c.particles;
  InitialFillRule& f = o.fill;
  f.filled = pa.fill != Fill::Empty && pa.fill != Fill::File;  // a file's particles are given ones
  f.lattice = pa.fill_arrangement != Arrangement::Random;
  f.staggered = pa.fill_arrangement == Arrangement::StaggeredLattice;
  f.lattice_lo = c.domain.lo;
  f.lattice_hi = c.domain.hi;
  f.count = pa.fill_count;
  f.mass = pa.fill_mass;
  o.bounded = bounded;
  o.stepper = c.solver.stepper;
  const TreatmentSection& tr = c.treatment;
  TreatmentOptions& t = o.treatment;
  t.no_flux = tr.no_flux;
  t.dirichlet = tr.dirichlet;
  t.reservoir_profile = tr.reservoir_profile;
  t.reservoir_control = tr.reservoir_control;
  t.reservoir_width = tr.reservoir_width;
  t.reservoir_sublayers = static_cast<int>(tr.reservoir_sublayers);
  t.reservoir_tolerance = tr.reservoir_tolerance;
  t.reservoir_candidates = static_cast<int>(tr.reservoir_candidates);
  t.reservoir_integral = tr.reservoir_integral;
  t.reservoir_group_target = tr.reservoir_group;
  t.neumann_outflow = tr.neumann_outflow;
  t.absorb_stranded = tr.absorb_stranded;
  t.spacing_rule = c.particles.spacing_rule;
  return o;
}

[[noreturn]] void throw_keyed(const InvalidArgument& e, const Config& c) {
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
      {"reservoir_integral", "treatment.reservoir_integral"},
      {"reservoir_group_target", "treatment.reservoir_group"},
      {"M_inf", "diagnostics.M_inf"},
      {"particle_mass", "particles.mass"},
      {"fill.count", "particles.fill_count"},
      {"fill.mass", "particles.fill_mass"},
      {"fill.given_count", "particles.fill_file"},
      {"fill.given_mass", "particles.fill_file"},
      {"fill.lattice_hi", "domain.hi"},
  };
  const std::string what = e.what();
  const std::string lattice = "fill.lattice = ";
  if (what.rfind(lattice, 0) == 0)  // the lattice's size, not a value of the key
    throw ConfigError("particles.fill_arrangement", fmt::format("\"{}\"", to_string(c.particles.fill_arrangement)),
                      fmt::format("gives {:.3g} lattice points (at most 1e8)",
                                  std::stod(what.substr(lattice.size(), what.find(':') - lattice.size()))));
  for (const auto& [field, key] : keys)
    if (what.rfind(field + " = ", 0) == 0) {
      // The rule may name other fields: those of the step and the barrier by their keys as well.
      std::string rule = what.substr(field.size());
      for (const auto& [name, section] : {std::pair<std::string, std::string>{"kappa", "physics."},
                                          {"t_end", "run."}, {"dt_factor", "run."}, {"barrier_factor", "solver."}})
        rule = with_keys(rule, name, section);
      throw ConfigError(key, key + rule);
    }
  throw ConfigError("particles", std::string("particles: ") + what);
}

}  // namespace otfp::app::detail
