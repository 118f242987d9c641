// The run set-up of run_setup.hpp: the treatment presets, the physical inputs
// and the parameters (36)-(40) they give, and the SimulationOptions of
// `otfp run` from the library alone.
#include "common.hpp"

#include <vector>

#include "otfp/parameters.hpp"
#include "otfp/run_setup.hpp"

#include "bindings.hpp"

namespace otfp::python {

void bind_run_setup(py::module_& m) {
  Options<WidthScaling>(m, "WidthScaling", "The width exponent q: s = s_rule(dr) (dr / dr_ref)^(q - 1).")
      .field("exponent", &WidthScaling::exponent, "q in (0, 2]; 1: the papers' fixed beta dr^2")
      .field("reference_n", &WidthScaling::reference_n, "n at which dr_ref is taken (>= 1)")
      .validated()
      .done();
  Options<TreatmentOptions>(m, "TreatmentOptions", "The boundary treatment; the defaults are the converging preset's.")
      .field("no_flux", &TreatmentOptions::no_flux, "barrier | images")
      .field("dirichlet", &TreatmentOptions::dirichlet, "layer | reservoir")
      .field("reservoir_profile", &TreatmentOptions::reservoir_profile, "uniform | odd")
      .field("reservoir_control", &TreatmentOptions::reservoir_control, "quiet | exact")
      .field("reservoir_width", &TreatmentOptions::reservoir_width, "band thickness in kernel cut-offs r_c")
      .field("reservoir_sublayers", &TreatmentOptions::reservoir_sublayers, "0: round(2 w / dr)")
      .field("reservoir_tolerance", &TreatmentOptions::reservoir_tolerance, "quiet: deficit corrected (particles)")
      .field("reservoir_candidates", &TreatmentOptions::reservoir_candidates, "quiet: candidate points per particle")
      .field("reservoir_integral", &TreatmentOptions::reservoir_integral, "quiet: integral action's tau in w^2/kappa (0: off)")
      .field("reservoir_group_target", &TreatmentOptions::reservoir_group_target, "quiet: sublayers held together up to this target")
      .field("neumann_outflow", &TreatmentOptions::neumann_outflow, "layer | nearest_particles")
      .field("absorb_stranded", &TreatmentOptions::absorb_stranded, "layer: remove particles beyond a Dirichlet face")
      .field("spacing_rule", &TreatmentOptions::spacing_rule, "cube | sphere_radius")
      .validated()
      .done();
  m.def("treatment_preset", &treatment_preset, py::arg("preset"), py::arg("dim"),
        "The TreatmentOptions of a preset (converging | papers) in dimension dim.");
  Options<InitialFillRule>(m, "InitialFillRule", "The particles at t = 0: how many, and so M_inf where nothing else sets it.")
      .field("filled", &InitialFillRule::filled, "particles drawn at t = 0")
      .field("lattice", &InitialFillRule::lattice, "a lattice of spacing ~dr over [lattice_lo, lattice_hi]")
      .field("staggered", &InitialFillRule::staggered, "the lattice staggered: 2-D rows shifted by half a cell, 3-D bcc")
      .field("lattice_lo", &InitialFillRule::lattice_lo, "the lattice's box")
      .field("lattice_hi", &InitialFillRule::lattice_hi, "the lattice's box")
      .field("count", &InitialFillRule::count, "particles of a drawn fill; None: mass / m_p if mass is given, else n_inf; 0: none")
      .field("mass", &InitialFillRule::mass, "total mass of a drawn fill; None: not given; 0: no particles")
      .field("given_count", &InitialFillRule::given_count, "given particles (a file): how many; -1: none")
      .field("given_mass", &InitialFillRule::given_mass, "their total mass")
      .validated()
      .done();
  py::enum_<MassRule>(m, "MassRule", "Which rule set M_inf (the first that applies).")
      .value("Given", MassRule::Given)
      .value("Dirichlet", MassRule::Dirichlet)
      .value("GivenParticles", MassRule::GivenParticles)
      .value("FillMass", MassRule::FillMass)
      .value("ParticleMass", MassRule::ParticleMass)
      .value("NInfParticleMass", MassRule::NInfParticleMass)
      .value("NeumannInflow", MassRule::NeumannInflow)
      .value("Unset", MassRule::Unset);
  Options<RunSetupOptions>(m, "RunSetupOptions", "The physical inputs of a run (run_setup.hpp).")
      .field("n_inf", &RunSetupOptions::n_inf, "particles at equilibrium: the spacing (37)")
      .field("kappa", &RunSetupOptions::kappa, "diffusivity")
      .field("rho_ref", &RunSetupOptions::rho_ref, "reference density")
      .field("beta_factor", &RunSetupOptions::beta_factor, "c of beta = c / dr^2 (36)")
      .field("width", &RunSetupOptions::width, "WidthScaling")
      .field("length_L", &RunSetupOptions::length_L, "L of b = sqrt(L dr) (38)")
      .field("layer_b", &RunSetupOptions::layer_b, "b itself; 0: sqrt(L dr)")
      .field("t_end", &RunSetupOptions::t_end, "horizon: the step divides it evenly")
      .field("dt", &RunSetupOptions::dt, "the step before fitting; 0: dt_factor x dt_explicit")
      .field("dt_factor", &RunSetupOptions::dt_factor, "dt in units of dt_explicit (39)")
      .field("barrier_factor", &RunSetupOptions::barrier_factor, "C = barrier_factor / dt_explicit (40)")
      .field("barrier_stiffness", &RunSetupOptions::barrier_stiffness, "C itself; 0: the barrier_factor rule")
      .field("kernel_tolerance", &RunSetupOptions::kernel_tolerance, "the cut-off r_c: list and band")
      .field("M_inf", &RunSetupOptions::M_inf, "equilibrium mass; 0: area-weighted Dirichlet g x |Omega|")
      .field("particle_mass", &RunSetupOptions::particle_mass, "m_p; 0: M_inf / n_inf")
      .field("bounded", &RunSetupOptions::bounded, "False: free space")
      .field("stepper", &RunSetupOptions::stepper, "implicit | explicit")
      .field("treatment", &RunSetupOptions::treatment, "TreatmentOptions")
      .field("fill", &RunSetupOptions::fill, "InitialFillRule")
      .validated()
      .done();
  py::class_<RunParameters>(m, "RunParameters", "What the rules (36)-(40) give for a run.")
      .def_readonly("volume", &RunParameters::volume)
      .def_readonly("dr", &RunParameters::dr)
      .def_readonly("beta", &RunParameters::beta)
      .def_readonly("width_s", &RunParameters::width_s)
      .def_readonly("width_reference_dr", &RunParameters::width_reference_dr)
      .def_readonly("true_spacing", &RunParameters::true_spacing)
      .def_readonly("layer_b", &RunParameters::layer_b)
      .def_readonly("dt_explicit", &RunParameters::dt_explicit)
      .def_readonly("dt", &RunParameters::dt)
      .def_readonly("n_steps", &RunParameters::n_steps)
      .def_readonly("barrier_C", &RunParameters::barrier_C)
      .def_readonly("reservoir_width", &RunParameters::reservoir_width)
      .def_readonly("reservoir_sublayers", &RunParameters::reservoir_sublayers)
      .def_readonly("neumann_net_inflow", &RunParameters::neumann_net_inflow)
      .def_readonly("M_inf", &RunParameters::M_inf)
      .def_readonly("M_inf_rule", &RunParameters::M_inf_rule)
      .def_readonly("particle_mass", &RunParameters::particle_mass)
      .def_readonly("fill_count", &RunParameters::fill_count)
      .def_readonly("lattice_counts", &RunParameters::lattice_counts);
  py::class_<RunSetup>(m, "RunSetup", "parameters (RunParameters) and options (SimulationOptions) of a run.")
      .def_readonly("parameters", &RunSetup::parameters)
      .def_readonly("options", &RunSetup::options);
  m.def(
      "setup_run",
      [](const PyDomain& domain, const std::vector<ConstantBoundaryData>& boundary, const RunSetupOptions& options) {
        if (!domain) throw InvalidArgument("domain: required");
        return setup_run(*domain, boundary, options);
      },
      py::arg("domain"), py::arg("boundary"), py::arg("options") = RunSetupOptions{},
      "The parameters (36)-(40) and the SimulationOptions `otfp run` builds for these inputs.");
}

}  // namespace otfp::python
