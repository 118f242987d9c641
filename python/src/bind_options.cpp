// The options classes (read/write fields listed in _fields, validate()) and
// the initial fill.
#include "common.hpp"

#include "otfp/boundary.hpp"
#include "otfp/explicit_stepper.hpp"
#include "otfp/functional.hpp"
#include "otfp/implicit_stepper.hpp"
#include "otfp/initial_fill.hpp"
#include "otfp/minimizer.hpp"
#include "otfp/neighbor_list.hpp"
#include "otfp/time_step_control.hpp"

#include "bindings.hpp"

namespace otfp::python {

void bind_options(py::module_& m) {
  // ---- options
  Options<NeighborOptions>(m, "NeighborOptions", "Cut-off tolerance and skin of the neighbour list.")
      .field("kernel_tolerance", &NeighborOptions::kernel_tolerance, "kernel value at the cut-off, relative to its peak")
      .field("skin", &NeighborOptions::skin, "absolute skin; < 0: skin_factor x smallest width")
      .field("skin_factor", &NeighborOptions::skin_factor, "skin in smallest widths when skin < 0")
      .validated()
      .done();
  Options<MinimizerOptions>(m, "MinimizerOptions", "Backend and caps of the minimiser.")
      .field("backend", &MinimizerOptions::backend, "ceres | nlopt | tao (tao where built with OTFP_WITH_MPI; see backend_available)")
      .field("algorithm", &MinimizerOptions::algorithm, "lbfgs, bfgs, nonlinear_cg (Ceres); tnewton, var2, mma (NLopt)")
      .field("gradient_tolerance", &MinimizerOptions::gradient_tolerance, "set per step by the stepper")
      .field("relative_gradient_tolerance", &MinimizerOptions::relative_gradient_tolerance, "0: off")
      .field("gradient_tolerance_floor", &MinimizerOptions::gradient_tolerance_floor, "floor of the relative rule")
      .field("start_tolerance", &MinimizerOptions::start_tolerance, "a start below this is converged (0: off)")
      .field("function_tolerance", &MinimizerOptions::function_tolerance, "0: off")
      .field("max_iterations", &MinimizerOptions::max_iterations, "iteration cap")
      .field("max_evaluations", &MinimizerOptions::max_evaluations, "evaluation cap")
      .field("lbfgs_memory", &MinimizerOptions::lbfgs_memory, "L-BFGS history")
      .field("approximate_eigenvalue_scaling", &MinimizerOptions::approximate_eigenvalue_scaling, "Ceres only")
      .validated()
      .done();
  Options<FunctionalOptions>(m, "FunctionalOptions", "dt, kappa, rho_ref, width metric of the functional (28).")
      .field("dt", &FunctionalOptions::dt, "time step (> 0)")
      .field("kappa", &FunctionalOptions::kappa, "diffusivity (> 0)")
      .field("rho_ref", &FunctionalOptions::rho_ref, "reference density (> 0)")
      .field("width_metric", &FunctionalOptions::width_metric, "as_printed (c_w = 1) | exact (d/2)")
      .field("optimise_widths", &FunctionalOptions::optimise_widths, "gradient in the widths as well")
      .field("neighbor", &FunctionalOptions::neighbor, "NeighborOptions")
      .field("width_skin", &FunctionalOptions::width_skin, "optimise_widths: list built for widths s (1 + this)")
      .validated()
      .done();
  Options<ImplicitOptions>(m, "ImplicitOptions", "The implicit variational step (28).")
      .field("minimizer", &ImplicitOptions::minimizer, "MinimizerOptions")
      .field("displacement_tolerance", &ImplicitOptions::displacement_tolerance, "stop at max |dt/m dF/dx| <= this x s")
      .field("relative_tolerance", &ImplicitOptions::relative_tolerance, "... or this x the first gradient step")
      .field("width_mode", &ImplicitOptions::width_mode, "fixed | per_particle")
      .field("width_metric", &ImplicitOptions::width_metric, "as_printed | exact")
      .field("kappa", &ImplicitOptions::kappa, "diffusivity")
      .field("rho_ref", &ImplicitOptions::rho_ref, "reference density")
      .field("neighbor", &ImplicitOptions::neighbor, "NeighborOptions")
      .field("max_halvings", &ImplicitOptions::max_halvings, "dt/2 retries after a failed solve")
      .field("energy_tolerance", &ImplicitOptions::energy_tolerance, "allowed rise of F")
      .field("sort_particles", &ImplicitOptions::sort_particles, "reorder spatially each step (ids kept)")
      .field("time_scheme", &ImplicitOptions::time_scheme, "euler | bdf2")
      .field("predictor", &ImplicitOptions::predictor, "none | extrapolate | damped")
      .field("error_smoothing", &ImplicitOptions::error_smoothing, "error estimate smoothing (widths)")
      .field("error_measure", &ImplicitOptions::error_measure, "displacement | density: what error_estimate measures")
      .field("stopping_norm", &ImplicitOptions::stopping_norm, "max | energy: norm of the solve's stopping rule")
      .field("max_norm_factor", &ImplicitOptions::max_norm_factor, "energy norm: largest residual / RMS tolerance (>= 1)")
      .field("width_skin", &ImplicitOptions::width_skin, "per_particle: list built for widths s (1 + this)")
      .field("max_width_factor", &ImplicitOptions::max_width_factor, "per_particle: s <= this x nominal_width (0: off)")
      .field("nominal_width", &ImplicitOptions::nominal_width, "the width s0 the bound refers to")
      .validated()
      .done();
  Options<ExplicitOptions>(m, "ExplicitOptions", "The explicit baselines.")
      .field("scheme", &ExplicitOptions::scheme, "euler27 | rk4 | euler_exact")
      .field("kappa", &ExplicitOptions::kappa, "diffusivity")
      .field("rho_ref", &ExplicitOptions::rho_ref, "reference density")
      .field("neighbor", &ExplicitOptions::neighbor, "NeighborOptions")
      .field("sort_particles", &ExplicitOptions::sort_particles, "reorder spatially each step")
      .validated()
      .done();
  Options<TimeStepControlOptions>(m, "TimeStepControlOptions", "Adaptive steps.")
      .field("tolerance", &TimeStepControlOptions::tolerance, "largest error estimate per step (widths)")
      .field("safety", &TimeStepControlOptions::safety, "safety factor")
      .field("max_growth", &TimeStepControlOptions::max_growth, "largest dt_new / dt")
      .field("max_shrink", &TimeStepControlOptions::max_shrink, "smallest dt_new / dt")
      .field("dt_min", &TimeStepControlOptions::dt_min, "smallest step")
      .field("dt_max", &TimeStepControlOptions::dt_max, "largest step")
      .validated()
      .done();
  Options<ProjectionOptions>(m, "ProjectionOptions", "The boundary-layer projection of Sec. 4.2.")
      .field("layer_b", &ProjectionOptions::layer_b, "half-thickness b")
      .field("dirichlet_target", &ProjectionOptions::dirichlet_target, "cell_integral | paper_eq34")
      .field("quadrature_samples", &ProjectionOptions::quadrature_samples, "Monte Carlo points")
      .field("neumann_outflow", &ProjectionOptions::neumann_outflow, "layer | nearest_particles")
      .field("nearest_surface_points", &ProjectionOptions::nearest_surface_points, "points on A_l")
      .field("dirichlet_mode", &ProjectionOptions::dirichlet_mode, "layer | reservoir")
      .field("reservoir_thickness", &ProjectionOptions::reservoir_thickness, "band width w")
      .field("reservoir_sublayers", &ProjectionOptions::reservoir_sublayers, "0: about one spacing each")
      .field("reservoir_volume_samples", &ProjectionOptions::reservoir_volume_samples, "Monte Carlo points")
      .field("reservoir_profile", &ProjectionOptions::reservoir_profile, "uniform | odd")
      .field("reservoir_control", &ProjectionOptions::reservoir_control, "quiet | exact")
      .field("reservoir_tolerance", &ProjectionOptions::reservoir_tolerance, "quiet: deficit (particles) to act on")
      .field("reservoir_candidates", &ProjectionOptions::reservoir_candidates, "quiet: candidate points per particle")
      .field("reservoir_integral_time", &ProjectionOptions::reservoir_integral_time, "quiet: integral action's tau (0: off)")
      .field("reservoir_group_target", &ProjectionOptions::reservoir_group_target, "quiet: sublayers held together up to this target")
      .field("absorb_exterior", &ProjectionOptions::absorb_exterior, "layer: remove stranded exterior particles")
      .field("draw_by_id", &ProjectionOptions::draw_by_id,
             "random deletions from the candidates in id order (default); False: storage order (serial only)")
      // The reservoir band's domain is built by the Simulation, not given here.
      .validated([](const ProjectionOptions& o) { o.validate(/*require_reservoir_domain=*/false); })
      .done();
  Options<SimulationOptions>(m, "SimulationOptions", "Algorithm 1 (otfp.Simulation).")
      .field("particle_mass", &SimulationOptions::particle_mass, "m_p of inserted particles (> 0)")
      .field("width_s", &SimulationOptions::width_s, "s of inserted particles (> 0)")
      .field("bounded", &SimulationOptions::bounded, "False: free space")
      .field("barrier_stiffness", &SimulationOptions::barrier_stiffness, "C of (40)")
      .field("no_flux", &SimulationOptions::no_flux, "images | barrier")
      .field("projection", &SimulationOptions::projection, "ProjectionOptions")
      .field("fill_reservoir_at_start", &SimulationOptions::fill_reservoir_at_start, "reservoir: fill at step 0")
      .field("stepper", &SimulationOptions::stepper, "implicit | explicit")
      .field("implicit", &SimulationOptions::implicit, "ImplicitOptions")
      .field("explicit_options", &SimulationOptions::explicit_options, "ExplicitOptions")
      .field("velocity", &SimulationOptions::velocity, "uniform advection velocity")
      .field("source_rate", &SimulationOptions::source_rate, "volumetric source rate")
      .field("source_draws_by_id", &SimulationOptions::source_draws_by_id,
             "the source's random numbers per particle id (default); False: one stream in storage order (serial only)")
      .field("time_control", &SimulationOptions::time_control, "TimeStepControlOptions")
      .field("max_error_rejections", &SimulationOptions::max_error_rejections, "adaptive tries per step")
      .field("seed", &SimulationOptions::seed, "random numbers")
      .field("max_particles", &SimulationOptions::max_particles, "a step past it fails; 0: default_max_particles()")
      .validated()
      .done();
  Options<FillOptions>(m, "FillOptions", "Initial particles: uniform, lattice, Gaussian or cosine.")
      .field("shape", &FillOptions::shape, "uniform | gaussian | cosine")
      .field("count", &FillOptions::count, "particles")
      .field("width_s", &FillOptions::width_s, "s of every particle")
      .field("mass", &FillOptions::mass, "m_p of every particle")
      .field("lattice", &FillOptions::lattice, "cell centres of a lattice in [lo, hi]")
      .field("staggered", &FillOptions::staggered, "lattice: 2-D rows shifted by half a cell, 3-D bcc (2 points per cell)")
      .field("lattice_counts", &FillOptions::lattice_counts, "points per axis")
      .field("lo", &FillOptions::lo, "box of the lattice / cosine")
      .field("hi", &FillOptions::hi, "box of the lattice / cosine")
      .field("center", &FillOptions::center, "Gaussian centre")
      .field("sigma", &FillOptions::sigma, "Gaussian standard deviation")
      .field("amplitude", &FillOptions::amplitude, "cosine amplitude a")
      .field("wavenumber", &FillOptions::wavenumber, "cosine k")
      .validated()
      .done();
  m.def("backend_available", &backend_available, py::arg("backend"),
        "Whether this build offers the minimiser backend (Tao: built with OTFP_WITH_MPI).");
  m.def("default_max_particles", &default_max_particles,
        "Half the machine's memory over 2.5 KB per particle: what SimulationOptions.max_particles = 0 means.");
  m.def("fill_particles",
        [](const PyDomain& domain, const FillOptions& o, const py::int_& seed) {
          Rng rng(seed_from(seed));
          return fill_particles(*domain, o, rng);
        },
        py::arg("domain"), py::arg("options"), py::arg("seed") = 1);
  m.def("lattice_point_count", &lattice_point_count, py::arg("dim"), py::arg("counts"), py::arg("staggered") = false,
        "Points of a lattice of `counts` cells per axis: one per cell, two in 3-D when staggered (bcc).");
}

}  // namespace otfp::python
