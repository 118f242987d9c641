// The Python module otfp._otfp (re-exported by the package otfp): particle
// sets, domains, the functional (28), the steppers, otfp::Simulation, the
// diagnostics and analytic references, and the command-line tool's TOML
// configurations. docs/python.md describes the API.
//
// Files, one area each (bindings.hpp lists the bind_* functions called below):
//   common.hpp, common.cpp        array conversion and checks, numpy views,
//                                 locks, the options-class helper
//   bind_enums.cpp                the enums, Rng
//   bind_particles_geometry.cpp   ParticleSet, particle files, domains, BoundaryData
//   bind_options.cpp              the options classes, fill_particles
//   bind_summaries.cpp            StepSummary, SimulationStep, ledger, totals, measures
//   bind_steppers.cpp             Functional, ImplicitStepper, ExplicitStepper
//   bind_simulation.cpp           Simulation
//   bind_references.cpp           parameter rules (36)-(40), diagnostics, otfp.analytic
//   bind_run_setup.cpp            treatment presets, RunSetupOptions, setup_run
//   bind_config.cpp               ConfiguredRun, load_config: the only file that
//                                 needs the command-line tool's library otfp_app
//
// Threads: every object whose methods release the GIL (Simulation, the
// steppers, Functional, ConfiguredRun.run, and a ParticleSet while a stepper
// works on it) serialises them with a lock of its own (ObjectLock in
// common.hpp), so that threads sharing an object take turns instead of racing.
//
// Arrays: a ParticleSet's positions, widths, masses, birth times and ids are
// numpy views of its own storage (no copy); while a view is alive the set
// refuses to change size or order (BufferError, as bytearray does), because
// that would move the storage. Everything else (a Simulation's particles,
// gradients, point queries) is returned as a new array.
#include "common.hpp"

#include "otfp/simulation.hpp"
#include "otfp/types.hpp"
#ifdef OTFP_WITH_TAO
#include "otfp/tao.hpp"
#endif

#include "bindings.hpp"

#ifndef OTFP_PYTHON_VERSION
#define OTFP_PYTHON_VERSION "unknown"
#endif

PYBIND11_MODULE(_otfp, m) {
  using namespace otfp::python;
  m.doc() = "otfp: the optimal-transport finite-particle method of driven mass diffusion (C++ core)";
  // One-line messages that name the field: subclasses of ValueError (bad
  // input) and RuntimeError (a step that could not be taken). ConfigError and
  // OutputDirError (ValueError too) are registered by bind_config.
  py::register_exception<otfp::InvalidArgument>(m, "InvalidArgument", PyExc_ValueError);
  py::register_exception<otfp::StepFailure>(m, "StepFailure", PyExc_RuntimeError);
  m.attr("__version__") = OTFP_PYTHON_VERSION;
#ifdef OTFP_WITH_TAO
  otfp::register_tao_backend();  // Backend.Tao
#endif  // the project's version, as `otfp --version` reports it

  // In this order: a class is registered before the signatures that name it.
  bind_enums(m);
  bind_particles_geometry(m);
  bind_options(m);
  bind_summaries(m);
  bind_steppers(m);
  bind_simulation(m);
  bind_references(m);
  bind_run_setup(m);
  bind_config(m);
}
