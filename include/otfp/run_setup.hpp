#pragma once
// A run's set-up from its physical inputs: the papers' parameter rules
// (36)-(40) with the step and the barrier, the boundary treatment of a preset,
// the equilibrium mass and the particle mass, and the SimulationOptions that
// `otfp run` builds from them. A C++ or Python caller gets the CLI's run from
// the library alone:
//
//   otfp::RunSetupOptions o;             // the converging treatment, n_inf = 400
//   o.t_end = 1.0;
//   const otfp::RunSetup setup = otfp::setup_run(*ball, boundary, o);
//   otfp::Simulation sim(ball, boundary, setup.options);
//   sim.start(otfp::ParticleSet(3));
//   for (std::int64_t k = 1; k <= setup.parameters.n_steps; ++k)
//     sim.advance_to(static_cast<double>(k) * setup.parameters.dt);  // the CLI's grid t_k = k dt
//
// Every default here is the CLI's: its configuration table reads these structs.
#include <array>
#include <cstdint>
#include <optional>
#include <vector>

#include "otfp/enums.hpp"
#include "otfp/geometry.hpp"
#include "otfp/boundary.hpp"
#include "otfp/implicit_stepper.hpp"
#include "otfp/parameters.hpp"
#include "otfp/simulation.hpp"

namespace otfp {

// The boundary treatment (docs/boundaries.md). The in-class defaults are the
// converging preset's; treatment_preset() gives either preset.
struct TreatmentOptions {
  NoFluxTreatment no_flux = NoFluxTreatment::Images;           // walls without data: image blobs (and the barrier)
  DirichletMode dirichlet = DirichletMode::Reservoir;          // Dirichlet patches: the band outside, or Sec. 4.2's layer
  ReservoirProfile reservoir_profile = ReservoirProfile::Odd;  // reservoir: 2 g minus the interior's mirror, or g
  ReservoirControl reservoir_control = ProjectionOptions{}.reservoir_control;  // reservoir: tolerance band + placement, or exact counts
  double reservoir_width = 1.0;       // reservoir: band thickness w in units of the kernel cut-off r_c (> 0)
  int reservoir_sublayers = 0;        // reservoir: sublayers of the band; 0: round(2 w / dr), half a spacing each
  double reservoir_tolerance = ProjectionOptions{}.reservoir_tolerance;  // reservoir, quiet: correct a sublayer beyond this deficit (particles)
  int reservoir_candidates = ProjectionOptions{}.reservoir_candidates;  // reservoir, quiet: fixed candidate points per target particle
  double reservoir_integral = 10.0;   // reservoir, quiet: integral action's tau in band diffusion times w^2 / kappa (0: off)
  double reservoir_group_target = ProjectionOptions{}.reservoir_group_target;  // reservoir, quiet: sublayers held together up to this target (particles)
  NeumannOutflow neumann_outflow = NeumannOutflow::NearestParticles;  // outlets: B_l only, or beyond when it runs empty
  bool absorb_stranded = false;       // layer: remove particles stranded beyond a Dirichlet face
  SpacingRule spacing_rule = SpacingRule::Cube;  // how dr follows from |Omega| and n_inf (37)
  void validate() const;              // throws InvalidArgument naming the field
};

// The choices of a preset in dimension `dim` (the papers' spacing rule is the
// sphere radius of Tables 1-3 in 3-D only).
TreatmentOptions treatment_preset(TreatmentPreset preset, int dim);

// The particles at t = 0 (the CLI's particles.fill* keys): how many, and so,
// where nothing else sets it, the equilibrium mass M_inf.
struct InitialFillRule {
  bool filled = false;              // particles drawn at t = 0 (false: none, unless `lattice` or given ones)
  bool lattice = false;             // a cell-centred lattice over [lattice_lo, lattice_hi]: round(edge / dr) per axis
  bool staggered = false;           // the lattice staggered (FillOptions::staggered): 2-D an even count along y, 3-D bcc cells of 2^(1/3) dr
  Vec3 lattice_lo = Vec3::Zero();   // the lattice's box
  Vec3 lattice_hi = Vec3::Zero();
  std::optional<std::int64_t> count;  // particles of a drawn fill (>= 0); absent: mass / m_p if mass is given, else n_inf
  std::optional<double> mass;         // total mass of a drawn fill (>= 0); absent: not given
  std::int64_t given_count = -1;    // particles given as such (read from a file): how many; -1: none
  double given_mass = 0.0;          // and their total mass
  // Throws InvalidArgument naming the field (as fill.<field>): count and mass
  // exclude each other and need a drawn fill that is not a lattice; given
  // particles exclude a drawn fill. The lattice's box is checked by
  // run_parameters on the used axes.
  void validate() const;
};

// Which rule set M_inf (the first that applies, in this order).
enum class MassRule {
  Given,          // RunSetupOptions::M_inf
  Dirichlet,      // area-weighted mean Dirichlet g x |Omega|
  GivenParticles, // the given particles' mass + the net Neumann inflow over [0, t_end]
  FillMass,       // fill.mass + the net Neumann inflow
  ParticleMass,   // (the lattice's count, else fill.count, else n_inf; 0 without a fill) x particle_mass + the net Neumann inflow
  NInfParticleMass,  // n_inf x particle_mass, where the rule above gives <= 0
  NeumannInflow,  // no particles at t = 0: the net Neumann inflow (> 0)
  Unset           // none applies: M_inf and particle_mass stay 0
};

// The physical inputs of a run.
struct RunSetupOptions {
  std::int64_t n_inf = 400;       // particles at equilibrium: sets the spacing dr (37) (>= 1)
  double kappa = 1.0;             // diffusivity (> 0)
  double rho_ref = 1.0;           // reference density of the entropy (> 0)
  double beta_factor = 2.0;       // c of beta = c / dr^2 (36) (> 0)
  WidthScaling width;             // width exponent q and its reference n (q = 1: the papers' rule)
  double length_L = 1.0;          // specimen length L of b = sqrt(L dr) (38) (> 0)
  double layer_b = 0.0;           // the layer b itself; 0: sqrt(L dr)
  double t_end = 1.0;             // horizon: the step divides it evenly (> 0)
  double dt = 0.0;                // the step before it is fitted to t_end; 0: dt_factor x dt_explicit
  double dt_factor = 1.0;         // dt in units of dt_explicit = dr^2 / kappa (39) (> 0)
  double barrier_factor = 1.0;    // C = barrier_factor / dt_explicit (40) (> 0)
  double barrier_stiffness = 0.0; // C itself; 0: the barrier_factor rule
  double kernel_tolerance = ImplicitOptions{}.neighbor.kernel_tolerance;  // the cut-off r_c: list and band
  double M_inf = 0.0;             // equilibrium mass; 0: area-weighted mean Dirichlet g x |Omega|
  double particle_mass = 0.0;     // m_p; 0: M_inf / n_inf
  bool bounded = true;            // false: free space (the domain only measures)
  StepperKind stepper = StepperKind::Implicit;  // the diffusive step
  TreatmentOptions treatment;     // the converging preset unless changed
  InitialFillRule fill;           // the particles at t = 0 (none unless changed)
  void validate() const;          // throws InvalidArgument naming the field
};

// The numbers the rules give.
struct RunParameters {
  double volume = 0.0;               // |Omega|
  double dr = 0.0;                   // spacing by the treatment's rule (37)
  double beta = 0.0;                 // (36): beta_factor / dr^2 (q = 1), otherwise 1 / width_s^2
  double width_s = 0.0;              // s = beta^-1/2
  double width_reference_dr = 0.0;   // spacing at width.reference_n
  double true_spacing = 0.0;         // (|Omega| / n_inf)^(1/d), whatever the rule
  double layer_b = 0.0;              // (38) or the given b
  double dt_explicit = 0.0;          // (39): dr^2 / kappa
  double dt = 0.0;                   // the step: t_end / n_steps
  std::int64_t n_steps = 0;          // ceil(t_end / dt) of the unfitted step (<= 1e9)
  double barrier_C = 0.0;            // (40) or the given C
  double reservoir_width = 0.0;      // band w (0: no reservoir: no Dirichlet patch, or the layer)
  int reservoir_sublayers = 0;       // sublayers of the band
  double neumann_net_inflow = 0.0;   // integral over [0, t_end] of the inflow -f |A_l| of every Neumann patch
  double M_inf = 0.0;                // equilibrium mass (0: no rule sets it)
  MassRule M_inf_rule = MassRule::Unset;  // the rule that set M_inf
  double particle_mass = 0.0;        // m_p (0 while M_inf is)
  std::int64_t fill_count = 0;       // particles at t = 0: the lattice's, the given ones', or the fill's
  std::array<std::int64_t, 3> lattice_counts{1, 1, 1};  // fill.lattice: cells per axis (points: lattice_point_count)
};

// (36)-(40), the step, the band, the masses and the fill's count for
// `boundary` on `domain`. Throws InvalidArgument naming the RunSetupOptions
// field at fault. An M_inf that no rule sets (or that is not finite and > 0)
// leaves particle_mass 0 unless it is given, and a fill given by its mass
// then has no count (fill_count 0): setup_run() refuses a particle mass of
// 0; the CLI takes M_inf = 1 where no rule applies.
RunParameters run_parameters(const Domain& domain, const std::vector<ConstantBoundaryData>& boundary,
                             const RunSetupOptions& options);

// The Simulation's options for these parameters: masses, width, barrier, the
// treatment's projection and walls, kappa and rho_ref, the kernel tolerance
// and the adaptive controller's bounds (dt_min = 1e-3 dt, dt_max = t_end);
// the solver's own options keep their library defaults.
SimulationOptions simulation_options(const RunParameters& parameters, const RunSetupOptions& options);

struct RunSetup {
  RunParameters parameters;
  SimulationOptions options;
};
RunSetup setup_run(const Domain& domain, const std::vector<ConstantBoundaryData>& boundary,
                   const RunSetupOptions& options);

}  // namespace otfp
