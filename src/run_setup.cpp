#include "otfp/run_setup.hpp"
#include "otfp/initial_fill.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>

#include "otfp/types.hpp"

namespace otfp {
namespace {
std::string shown(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.6g", v);
  return buf;
}
}  // namespace

void TreatmentOptions::validate() const {
  require(std::isfinite(reservoir_width) && reservoir_width > 0.0, "reservoir_width", reservoir_width,
          "must be finite and > 0");
  require(reservoir_sublayers >= 0, "reservoir_sublayers", reservoir_sublayers,
          "must be >= 0 (0: round(2 w / dr))");
  require(std::isfinite(reservoir_tolerance) && reservoir_tolerance >= 0.0, "reservoir_tolerance",
          reservoir_tolerance, "must be finite and >= 0");
  require(reservoir_candidates >= 1, "reservoir_candidates", reservoir_candidates, "must be >= 1");
  require(std::isfinite(reservoir_integral) && reservoir_integral >= 0.0, "reservoir_integral", reservoir_integral,
          "must be finite and >= 0 (0: no integral action)");
  require(std::isfinite(reservoir_group_target) && reservoir_group_target >= 1.0, "reservoir_group_target",
          reservoir_group_target, "must be finite and >= 1 (particles)");
}

TreatmentOptions treatment_preset(TreatmentPreset preset, int dim) {
  TreatmentOptions t;  // the converging preset
  if (preset == TreatmentPreset::Papers) {
    t.no_flux = NoFluxTreatment::Barrier;
    t.dirichlet = DirichletMode::Layer;
    t.reservoir_profile = ReservoirProfile::Uniform;
    t.neumann_outflow = NeumannOutflow::Layer;
    t.spacing_rule = dim == 3 ? SpacingRule::SphereRadius : SpacingRule::Cube;
  }
  return t;
}

void InitialFillRule::validate() const {
  if (count) require(*count >= 0, "fill.count", static_cast<double>(*count), "must be >= 0");
  if (mass) require(std::isfinite(*mass) && *mass >= 0.0, "fill.mass", *mass, "must be finite and >= 0");
  require(given_count >= -1, "fill.given_count", static_cast<double>(given_count), "must be >= 0, or -1 for none");
  require(std::isfinite(given_mass) && given_mass >= 0.0, "fill.given_mass", given_mass, "must be finite and >= 0");
  // One source of the count: a fill given both ways, or a count that no
  // drawn fill uses, would only seem to have been applied.
  require(!(count && mass), "fill.count", static_cast<double>(count.value_or(0)),
          "give fill.count or fill.mass, not both");
  const char* field = count ? "fill.count" : "fill.mass";
  const double value = count ? static_cast<double>(*count) : mass.value_or(0.0);
  require(!(lattice && (count || mass)), field, value,
          "not used by fill.lattice (the lattice of spacing dr sets the count)");
  require(filled || lattice || !(count || mass), field, value,
          "has no effect: fill.filled is false (no particles are drawn)");
  require(lattice || !staggered, "fill.staggered", 1.0, "needs fill.lattice");
  require(given_count < 0 || !(filled || lattice), "fill.given_count", static_cast<double>(given_count),
          "given particles replace a drawn fill: fill.filled and fill.lattice must be false");
}

void RunSetupOptions::validate() const {
  require(n_inf >= 1, "n_inf", static_cast<double>(n_inf), "must be >= 1");
  require(std::isfinite(kappa) && kappa > 0.0, "kappa", kappa, "must be finite and > 0");
  require(std::isfinite(rho_ref) && rho_ref > 0.0, "rho_ref", rho_ref, "must be finite and > 0");
  require(std::isfinite(beta_factor) && beta_factor > 0.0, "beta_factor", beta_factor, "must be finite and > 0");
  width.validate();
  require(std::isfinite(length_L) && length_L > 0.0, "length_L", length_L, "must be finite and > 0");
  require(std::isfinite(layer_b) && layer_b >= 0.0, "layer_b", layer_b, "must be finite and >= 0 (0: sqrt(L dr))");
  require(std::isfinite(t_end) && t_end > 0.0, "t_end", t_end, "must be finite and > 0");
  require(std::isfinite(dt) && dt >= 0.0, "dt", dt, "must be finite and >= 0 (0: dt_factor x dt_explicit)");
  require(std::isfinite(dt_factor) && dt_factor > 0.0, "dt_factor", dt_factor, "must be finite and > 0");
  require(std::isfinite(barrier_factor) && barrier_factor > 0.0, "barrier_factor", barrier_factor,
          "must be finite and > 0");
  require(std::isfinite(barrier_stiffness) && barrier_stiffness >= 0.0, "barrier_stiffness", barrier_stiffness,
          "must be finite and >= 0 (0: barrier_factor / dt_explicit)");
  require(kernel_tolerance > 0.0 && kernel_tolerance < 1.0, "kernel_tolerance", kernel_tolerance, "must be in (0, 1)");
  require(std::isfinite(M_inf) && M_inf >= 0.0, "M_inf", M_inf, "must be finite and >= 0 (0: set by the first mass rule that applies, MassRule)");
  require(std::isfinite(particle_mass) && particle_mass >= 0.0, "particle_mass", particle_mass,
          "must be finite and >= 0 (0: M_inf / n_inf)");
  treatment.validate();
  fill.validate();
}

RunParameters run_parameters(const Domain& domain, const std::vector<ConstantBoundaryData>& boundary,
                             const RunSetupOptions& o) {
  o.validate();
  const int dim = domain.dim();
  const auto n_inf = static_cast<std::size_t>(o.n_inf);
  RunParameters p;
  p.volume = domain.volume();
  // (36)-(40) by the treatment's spacing rule and the width exponent.
  const PaperParameters pp =
      paper_parameters(p.volume, n_inf, dim, o.length_L, o.kappa, o.beta_factor, o.treatment.spacing_rule, o.width);
  p.dr = pp.dr;
  p.beta = pp.beta;
  p.width_s = pp.width_s;
  p.width_reference_dr = pp.dr_ref;
  p.true_spacing = spacing(p.volume, n_inf, dim);
  p.layer_b = o.layer_b > 0.0 ? o.layer_b : pp.layer_b;
  p.dt_explicit = pp.dt_explicit;

  // The step: dt (or dt_factor dt_explicit) shortened so that n_steps of it
  // end on t_end exactly (the grid t_k = k dt).
  const double dt0 = o.dt > 0.0 ? o.dt : o.dt_factor * p.dt_explicit;
  const double steps = std::ceil(o.t_end / dt0 * (1.0 - 1e-12));
  require(steps <= 1e9, o.dt > 0.0 ? "dt" : "dt_factor", o.dt > 0.0 ? o.dt : o.dt_factor,
          (o.dt > 0.0 ? std::string("gives ")
                      : "dt = dt_factor dr^2 / kappa = " + shown(dt0) + " (kappa = " + shown(o.kappa) +
                            ", dr = " + shown(p.dr) + ") gives ") +
              shown(steps) + " steps to t_end = " + shown(o.t_end) + " (more than 1e9)");
  p.n_steps = std::max<std::int64_t>(1, static_cast<std::int64_t>(steps));
  p.dt = o.t_end / static_cast<double>(p.n_steps);
  p.barrier_C = o.barrier_stiffness > 0.0 ? o.barrier_stiffness : o.barrier_factor / p.dt_explicit;
  require(std::isfinite(p.barrier_C) && p.barrier_C > 0.0, "barrier_factor", o.barrier_factor,
          "gives the barrier stiffness C = barrier_factor / dt_explicit = " + shown(p.barrier_C) +
              ": must be finite and > 0");

  // The reservoir band: w = reservoir_width r_c, half a spacing per sublayer.
  const bool any_dirichlet = std::any_of(boundary.begin(), boundary.end(), [](const ConstantBoundaryData& b) {
    return b.kind == PatchKind::Dirichlet;
  });
  if (o.treatment.dirichlet == DirichletMode::Reservoir && any_dirichlet) {
    p.reservoir_width = o.treatment.reservoir_width * cutoff_radius(p.width_s, o.kernel_tolerance);
    p.reservoir_sublayers = o.treatment.reservoir_sublayers > 0
                                ? o.treatment.reservoir_sublayers
                                : std::max(1, static_cast<int>(std::lround(2.0 * p.reservoir_width / p.dr)));
  }

  // Net Neumann inflow over [0, t_end] (f is the outward flux: inflow is -f).
  for (const ConstantBoundaryData& b : boundary)
    if (b.kind == PatchKind::Neumann)
      p.neumann_net_inflow += -b.value * domain.patch_area(b.patch) *
                              std::max(0.0, std::min(o.t_end, b.t_end) - std::max(0.0, b.t_start));

  // The lattice's count (spacing ~dr over its box), needed by the mass rules.
  const InitialFillRule& f = o.fill;
  if (f.lattice) {
    for (int k = 0; k < dim; ++k)
      require(std::isfinite(f.lattice_lo[k]) && std::isfinite(f.lattice_hi[k]) && f.lattice_lo[k] <= f.lattice_hi[k],
              "fill.lattice_hi", f.lattice_hi[k], "must be finite and >= fill.lattice_lo on every used axis");
    // Cells of the spacing dr, one point each; staggered in 3-D (bcc, two
    // points per cell) cells of 2^(1/3) dr, and in 2-D an even number of
    // rows (the pattern repeats every two).
    const bool bcc = f.staggered && dim == 3;
    const double cell = bcc ? std::cbrt(2.0) * p.dr : p.dr;
    auto cells = [&](int k) {
      double c = std::max(1.0, std::round((f.lattice_hi[k] - f.lattice_lo[k]) / cell));
      if (f.staggered && dim == 2 && k == 1) c = std::max(2.0, 2.0 * std::round(0.5 * c));
      return c;
    };
    double total = bcc ? 2.0 : 1.0;  // in double first: an extreme box must not overflow the count
    for (int k = 0; k < dim; ++k) total *= cells(k);
    require(total <= 1e8, "fill.lattice", total, "lattice points: at most 1e8");
    for (int k = 0; k < dim; ++k) p.lattice_counts[static_cast<std::size_t>(k)] = std::llround(cells(k));
    p.fill_count = lattice_point_count(dim, p.lattice_counts, f.staggered);
  }

  // M_inf: the first rule that applies (MassRule).
  double ga = 0.0, area = 0.0;
  for (const ConstantBoundaryData& b : boundary)
    if (b.kind == PatchKind::Dirichlet) {
      ga += b.value * domain.patch_area(b.patch);
      area += domain.patch_area(b.patch);
    }
  auto set_mass = [&p](MassRule rule, double m) {
    p.M_inf_rule = rule;
    p.M_inf = m;
  };
  if (o.M_inf > 0.0) {
    set_mass(MassRule::Given, o.M_inf);
  } else if (area > 0.0) {
    set_mass(MassRule::Dirichlet, ga / area * p.volume);
  } else if (f.given_count >= 0) {
    set_mass(MassRule::GivenParticles, f.given_mass + p.neumann_net_inflow);
  } else if (f.filled && f.mass) {
    set_mass(MassRule::FillMass, *f.mass + p.neumann_net_inflow);
  } else if (o.particle_mass > 0.0) {
    const double n0 = f.lattice  ? static_cast<double>(p.fill_count)
                      : f.filled ? static_cast<double>(f.count.value_or(o.n_inf))
                                 : 0.0;
    set_mass(MassRule::ParticleMass, n0 * o.particle_mass + p.neumann_net_inflow);
    if (!(p.M_inf > 0.0)) set_mass(MassRule::NInfParticleMass, static_cast<double>(o.n_inf) * o.particle_mass);
  } else if (!f.filled && !f.lattice && p.neumann_net_inflow > 0.0) {
    set_mass(MassRule::NeumannInflow, p.neumann_net_inflow);
  }
  if (o.particle_mass > 0.0)
    p.particle_mass = o.particle_mass;
  else if (p.M_inf > 0.0 && std::isfinite(p.M_inf))
    p.particle_mass = p.M_inf / static_cast<double>(n_inf);

  // The other fills' counts: the given particles, or the fill's own count,
  // mass or n_inf.
  if (f.lattice) {
    // counted above
  } else if (f.given_count >= 0) {
    p.fill_count = f.given_count;
  } else if (f.filled) {
    if (f.count) {
      p.fill_count = *f.count;
    } else if (f.mass) {
      // Without a particle mass there is no count (setup_run refuses m_p = 0).
      if (p.particle_mass > 0.0) {
        const double n = *f.mass / p.particle_mass;
        require(n <= 1e18, "fill.mass", *f.mass,
                "gives " + shown(n) + " particles of mass m_p = " + shown(p.particle_mass) + " (more than 1e18)");
        p.fill_count = std::llround(n);
      }
    } else {
      p.fill_count = o.n_inf;
    }
  }
  return p;
}

SimulationOptions simulation_options(const RunParameters& p, const RunSetupOptions& o) {
  SimulationOptions so;
  so.particle_mass = p.particle_mass;
  so.width_s = p.width_s;
  so.bounded = o.bounded;
  so.barrier_stiffness = p.barrier_C;
  so.no_flux = o.treatment.no_flux;
  ProjectionOptions& po = so.projection;
  po.layer_b = p.layer_b;
  po.neumann_outflow = o.treatment.neumann_outflow;
  po.absorb_exterior = o.treatment.dirichlet == DirichletMode::Layer && o.treatment.absorb_stranded;
  if (p.reservoir_width > 0.0) {
    po.dirichlet_mode = DirichletMode::Reservoir;
    po.reservoir_thickness = p.reservoir_width;
    po.reservoir_sublayers = p.reservoir_sublayers;
    po.reservoir_profile = o.treatment.reservoir_profile;
    po.reservoir_control = o.treatment.reservoir_control;
    po.reservoir_tolerance = o.treatment.reservoir_tolerance;
    po.reservoir_candidates = o.treatment.reservoir_candidates;
    // tau in the band's own diffusion time w^2 / kappa.
    po.reservoir_integral_time = o.treatment.reservoir_integral * p.reservoir_width * p.reservoir_width / o.kappa;
    po.reservoir_group_target = o.treatment.reservoir_group_target;
  }
  so.fill_reservoir_at_start = true;
  so.stepper = o.stepper;
  ImplicitOptions& io = so.implicit;
  io.nominal_width = p.width_s;  // the per-particle bound is max_width_factor x the run's s0
  io.kappa = o.kappa;
  io.rho_ref = o.rho_ref;
  io.neighbor.kernel_tolerance = o.kernel_tolerance;
  ExplicitOptions& eo = so.explicit_options;
  eo.kappa = o.kappa;
  eo.rho_ref = o.rho_ref;
  eo.neighbor.kernel_tolerance = o.kernel_tolerance;
  TimeStepControlOptions& tco = so.time_control;
  tco.dt_min = 1e-3 * p.dt;
  tco.dt_max = std::max(o.t_end, tco.dt_min);
  return so;
}

RunSetup setup_run(const Domain& domain, const std::vector<ConstantBoundaryData>& boundary,
                   const RunSetupOptions& options) {
  RunSetup s;
  s.parameters = run_parameters(domain, boundary, options);
  require(s.parameters.particle_mass > 0.0, "particle_mass", s.parameters.particle_mass,
          "give particle_mass or M_inf (no mass rule sets M_inf here: no Dirichlet data > 0, given particles, fill mass or Neumann inflow)");
  s.options = simulation_options(s.parameters, options);
  return s;
}

}  // namespace otfp
