// Internal to the Python module otfp._otfp: the binding functions that
// PYBIND11_MODULE (module.cpp) calls, one per area, in this order. The order
// matters: a class must be registered before a signature or default argument
// that names it (a docstring would show the C++ type name instead).
#pragma once

#include <pybind11/pybind11.h>

namespace otfp::python {

void bind_enums(pybind11::module_& m);               // bind_enums.cpp: the enums, Rng
void bind_particles_geometry(pybind11::module_& m);  // bind_particles_geometry.cpp: ParticleSet, Domain, BoundaryData
void bind_options(pybind11::module_& m);             // bind_options.cpp: the options classes, fill_particles
void bind_summaries(pybind11::module_& m);           // bind_summaries.cpp: what steps and simulations report
void bind_steppers(pybind11::module_& m);            // bind_steppers.cpp: Functional, ImplicitStepper, ExplicitStepper
void bind_simulation(pybind11::module_& m);          // bind_simulation.cpp: Simulation
void bind_references(pybind11::module_& m);          // bind_references.cpp: parameter rules, diagnostics, analytic
void bind_run_setup(pybind11::module_& m);           // bind_run_setup.cpp: presets, RunSetupOptions, setup_run
void bind_config(pybind11::module_& m);              // bind_config.cpp: ConfiguredRun, load_config (needs otfp_app)

}  // namespace otfp::python
