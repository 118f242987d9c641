// otfp.Simulation: Algorithm 1, stepped with the GIL released under the
// simulation's own lock.
#include "common.hpp"

#include <filesystem>
#include <string>
#include <vector>

#include "bindings.hpp"

namespace otfp::python {

namespace {

// Thrown by the observer wrapper when the Python observer returns False.
struct StopRequested {};

// An observer's answer: None or True go on, False stops after the step;
// anything else (numpy's bool is a bool) is a mistake, not a truth value.
bool stops(const py::object& r) {
  if (r.is_none()) return false;
  const bool is_bool =
      py::isinstance<py::bool_>(r) || py::isinstance(r, py::module_::import("numpy").attr("bool_"));
  if (!is_bool)
    throw py::type_error("observer returned " + py::str(py::type::of(r).attr("__name__")).cast<std::string>() +
                         ": an observer must return None or True (go on) or False (stop after this step)");
  return !r.cast<bool>();
}

}  // namespace

void bind_simulation(py::module_& m) {
  py::enum_<RunEnd> run_end(m, "RunEnd", "How Simulation.run ended.");
  run_end.value("Completed", RunEnd::Completed).value("MaxSteps", RunEnd::MaxSteps).value("Stopped", RunEnd::Stopped);
  run_end.attr("__str__") =
      py::cpp_function([](RunEnd v) { return to_string(v); }, py::name("__str__"), py::is_method(run_end));
  Options<RunControl>(m, "RunControl", "What Simulation.run steps to and when it stops (the command line's loop).")
      .field("t_end", &RunControl::t_end, "end of the run")
      .field("dt", &RunControl::dt, "fixed steps: the step of a new grid; adaptive: the first try")
      .field("adaptive", &RunControl::adaptive, "advance_adaptive to t_end instead of the grid")
      .field("max_steps", &RunControl::max_steps, "stop after this step number (0: no limit)")
      .field("checkpoint_interval", &RunControl::checkpoint_interval, "on_checkpoint every this many steps")
      .validated()
      .done();
  py::class_<TimeGrid>(m, "TimeGrid", "The grid of fixed steps: t_k = t_origin + (k - k_origin) dt, t_end at k_end.")
      .def_readonly("t_origin", &TimeGrid::t_origin)
      .def_readonly("k_origin", &TimeGrid::k_origin)
      .def_readonly("dt", &TimeGrid::dt)
      .def_readonly("k_end", &TimeGrid::k_end)
      .def_readonly("t_end", &TimeGrid::t_end);

  // ---- Simulation (with its lock: every method waits for a step running in
  // another thread; the observer of run_until may use its own simulation)
  py::class_<PySimulation>(m, "Simulation", "Algorithm 1: advection, source, diffusion, projection, ledger.")
      .def(py::init([](const PyDomain& domain, std::vector<ConstantBoundaryData> boundary,
                       const SimulationOptions& options) {
             if (!domain) throw InvalidArgument("domain: required");
             return std::make_unique<PySimulation>(std::make_unique<Simulation>(domain, std::move(boundary), options));
           }),
           py::arg("domain"), py::arg("boundary"), py::arg("options"))
      .def("start",
           [](PySimulation& s, const ParticleSet& ps, double t0) {
             check_particles(ps, "particles");
             auto held = s.lock.hold();
             s.object->start(ps, t0);
           },
           py::arg("particles"), py::arg("t0") = 0.0,
           "The state at t0 (a copy of the particles); random numbers from options.seed.")
      .def("advance",
           [](PySimulation& s, double dt) {
             auto held = s.lock.hold();
             py::gil_scoped_release release;
             return s.object->advance(dt);
           },
           py::arg("dt"))
      .def("advance_to",
           [](PySimulation& s, double t_end) {
             auto held = s.lock.hold();
             py::gil_scoped_release release;
             return s.object->advance_to(t_end);
           },
           py::arg("t_end"))
      .def("advance_adaptive",
           [](PySimulation& s, double t_limit) {
             auto held = s.lock.hold();
             py::gil_scoped_release release;
             return s.object->advance_adaptive(t_limit);
           },
           py::arg("t_limit"))
      .def("run_until",
           [](PySimulation& s, double t_end, double dt, py::object observer, bool adaptive) {
             auto held = s.lock.hold();
             Simulation::Observer obs;
             if (!observer.is_none())
               obs = [&observer, &s](const Simulation&, const SimulationStep& step) {
                 py::gil_scoped_acquire acquire;
                 py::object r = observer(py::cast(s, py::return_value_policy::reference), py::cast(step));
                 if (stops(r)) throw StopRequested{};
               };
             try {
               py::gil_scoped_release release;
               s.object->run_until(t_end, dt, obs, adaptive);
             } catch (const StopRequested&) {
               return false;
             }
             return true;
           },
           py::arg("t_end"), py::arg("dt"), py::arg("observer") = py::none(), py::arg("adaptive") = false,
           "Steps to t_end (equal steps of at most dt, or adaptive). observer(sim, step) sees every step; "
           "returning False stops after that step. Returns True when t_end was reached.")
      .def("run",
           [](PySimulation& s, const RunControl& control, py::object observer, py::object on_checkpoint) {
             auto held = s.lock.hold();
             RunControl c = control;
             // observer(sim, step) after every step: False ends the run with that step.
             if (!observer.is_none())
               c.stop = [&observer, &s](const SimulationStep& step) {
                 py::gil_scoped_acquire acquire;
                 py::object r = observer(py::cast(s, py::return_value_policy::reference), py::cast(step));
                 return stops(r);
               };
             struct Checkpoints : RunObserver {
               py::object* call = nullptr;
               PySimulation* sim = nullptr;
               void on_step(const Simulation&, const SimulationStep&, bool) override {}
               void on_checkpoint(const Simulation&) override {
                 if (call->is_none()) return;
                 py::gil_scoped_acquire acquire;
                 (*call)(py::cast(*sim, py::return_value_policy::reference));
               }
             } checkpoints;
             checkpoints.call = &on_checkpoint;
             checkpoints.sim = &s;
             py::gil_scoped_release release;
             return s.object->run(c, &checkpoints);
           },
           py::arg("control"), py::arg("observer") = py::none(), py::arg("on_checkpoint") = py::none(),
           "The time loop: fixed steps on the grid kept in checkpoints (time_grid), or adaptive. observer(sim, "
           "step) sees every step and may return False to stop there; on_checkpoint(sim) is called at "
           "control.checkpoint_interval and after the last step. Returns a RunEnd.")
      .def("finished",
           [](PySimulation& s, const RunControl& control) {
             auto held = s.lock.hold();
             return s.object->finished(control);
           },
           py::arg("control"), "run(control) would take no step.")
      .def_property_readonly("time_grid",
                             [](PySimulation& s) {
                               auto held = s.lock.hold();
                               return s.object->time_grid();
                             })
      .def_property_readonly("time",
                             [](PySimulation& s) {
                               auto held = s.lock.hold();
                               return s.object->time();
                             })
      .def_property_readonly("step_count",
                             [](PySimulation& s) {
                               auto held = s.lock.hold();
                               return s.object->step_count();
                             })
      .def_property_readonly("started",
                             [](PySimulation& s) {
                               auto held = s.lock.hold();
                               return s.object->started();
                             })
      .def_property_readonly("next_dt",
                             [](PySimulation& s) {
                               auto held = s.lock.hold();
                               return s.object->next_dt();
                             })
      .def("set_next_dt",
           [](PySimulation& s, double dt) {
             auto held = s.lock.hold();
             s.object->set_next_dt(dt);
           },
           py::arg("dt"))
      .def_property_readonly("particles",
                             [](PySimulation& s) {
                               auto held = s.lock.hold();
                               return ParticleSet(s.object->particles());
                             },
                             "A copy of the particles (the simulation's own change size every step).")
      .def_property_readonly("domain", [](PySimulation& s) { return mutable_domain(s.object->domain_ptr()); })
      .def_property_readonly("options",
                             [](PySimulation& s) {
                               auto held = s.lock.hold();
                               return SimulationOptions(s.object->options());
                             },
                             "A copy of the options.")
      .def_property_readonly("ledger",
                             [](PySimulation& s) {
                               auto held = s.lock.hold();
                               return SimulationLedger(s.object->ledger());
                             })
      .def_property_readonly("totals",
                             [](PySimulation& s) {
                               auto held = s.lock.hold();
                               return SimulationTotals(s.object->totals());
                             })
      .def_property_readonly("initial_step",
                             [](PySimulation& s) {
                               auto held = s.lock.hold();
                               return SimulationStep(s.object->initial_step());
                             })
      .def("full_report",
           [](PySimulation& s) {
             auto held = s.lock.hold();
             return s.object->full_report();
           })
      .def("measure",
           [](PySimulation& s, const Vec3& center) {
             auto held = s.lock.hold();
             std::vector<std::int32_t> region;
             const StateMeasures ms = s.object->measure(center, &region);
             return py::make_tuple(ms, py::array_t<std::int32_t>(static_cast<py::ssize_t>(region.size()), region.data()));
           },
           py::arg("center"), "(StateMeasures, region per particle: 0 inside, 1 buffer, 2 elsewhere)")
      .def("blob_mass",
           [](PySimulation& s) {
             auto held = s.lock.hold();
             return s.object->blob_mass();
           },
           "M_rho: the blob density integrated over Omega, image blobs at mirrored walls included")
      .def("save_checkpoint",
           [](PySimulation& s, const std::filesystem::path& path, const std::string& extra) {
             auto held = s.lock.hold();
             py::gil_scoped_release release;
             s.object->save_checkpoint(path, extra);
           },
           py::arg("path"), py::arg("extra") = std::string())
      .def("load_checkpoint",
           [](PySimulation& s, const std::filesystem::path& path) {
             auto held = s.lock.hold();
             std::string extra;
             {
               py::gil_scoped_release release;
               s.object->load_checkpoint(path, &extra);
             }
             return extra;
           },
           py::arg("path"), "Restores the state (bit for bit); returns the caller's extra string.");
}

}  // namespace otfp::python
