// The papers' parameter rules (36)-(40), the diagnostics, the analytic
// references (submodule otfp.analytic) and the reference objects
// (otfp/reference.hpp: Reference, make_reference, ErrorStatistics, decay_rate_fit).
#include "common.hpp"

#include <memory>
#include <mutex>
#include <string>
#include <variant>
#include <vector>

#include "otfp/analytic.hpp"
#include "otfp/diagnostics.hpp"
#include "otfp/enums.hpp"
#include "otfp/neighbor_list.hpp"
#include "otfp/parameters.hpp"
#include "otfp/reference.hpp"
#include "otfp/run_record.hpp"
#include "otfp/series_layout.hpp"

#include "bindings.hpp"

namespace otfp::python {

void bind_references(py::module_& m) {
  // ---- the papers' parameter rules (36)-(40)
  py::class_<PaperParameters>(m, "PaperParameters", "(36)-(40): spacing, width, layer, explicit limit, barrier.")
      .def_readonly("dr", &PaperParameters::dr)
      .def_readonly("beta", &PaperParameters::beta)
      .def_readonly("width_s", &PaperParameters::width_s)
      .def_readonly("layer_b", &PaperParameters::layer_b)
      .def_readonly("dt_explicit", &PaperParameters::dt_explicit)
      .def_readonly("barrier_C", &PaperParameters::barrier_C)
      .def("__repr__", [](const PaperParameters& p) {
        return "PaperParameters(dr=" + std::to_string(p.dr) + ", width_s=" + std::to_string(p.width_s) +
               ", layer_b=" + std::to_string(p.layer_b) + ", dt_explicit=" + std::to_string(p.dt_explicit) +
               ", barrier_C=" + std::to_string(p.barrier_C) + ")";
      });
  m.def("paper_parameters",
        [](double volume, std::size_t n, int dim, double length_L, double kappa, double beta_factor) {
          return paper_parameters(volume, n, dim, length_L, kappa, beta_factor);
        },
        py::arg("volume"), py::arg("n"), py::arg("dim"), py::arg("length_L"), py::arg("kappa"),
        py::arg("beta_factor") = 2.0, "The papers' rules for n particles in |Omega| = volume (cube spacing rule).");
  m.def("cutoff_radius", &cutoff_radius, py::arg("width_s"), py::arg("kernel_tolerance"),
        "Distance at which a blob's kernel falls to kernel_tolerance of its peak.");

  // ---- diagnostics and references
  m.def("blob_second_moment", &blob_second_moment, py::arg("particles"), py::arg("center"));
  m.def("cosine_mode_amplitude", &cosine_mode_amplitude, py::arg("particles"), py::arg("wavenumber"), py::arg("x0"));
  py::module_ an = m.def_submodule("analytic", "Analytic references (Crank, free space, cosine mode).");
  an.def("crank_sphere_uptake", py::vectorize(&analytic::crank_sphere_uptake), py::arg("kappa_t_over_R2"));
  an.def("crank_slab_uptake", py::vectorize(&analytic::crank_slab_uptake), py::arg("kappa_t_over_L2"));
  an.def("crank_sphere_polar_inertia", py::vectorize(&analytic::crank_sphere_polar_inertia), py::arg("kappa_t_over_R2"));
  an.def("crank_slab_density", py::vectorize(&analytic::crank_slab_density), py::arg("kappa_t_over_L2"),
         py::arg("depth_over_L"));
  an.def("free_space_variance_growth", py::vectorize(&analytic::free_space_variance_growth), py::arg("kappa"),
         py::arg("t"));
  an.def("cosine_mode_decay", py::vectorize(&analytic::cosine_mode_decay), py::arg("kappa"), py::arg("wavenumber"),
         py::arg("t"));
  Options<analytic::SlabBox>(an, "SlabBox", "The box of crank_slab_polar_inertia.")
      .field("dim", &analytic::SlabBox::dim, "1, 2 or 3")
      .field("lo", &analytic::SlabBox::lo, "box corner")
      .field("hi", &analytic::SlabBox::hi, "box corner")
      .field("axis", &analytic::SlabBox::axis, "normal of the held face")
      .field("held_at_hi", &analytic::SlabBox::held_at_hi, "the held face is x = hi")
      .field("length", &analytic::SlabBox::length, "L")
      .field("center", &analytic::SlabBox::center, "centre of the polar inertia")
      .field("M_inf", &analytic::SlabBox::M_inf, "g |Omega|")
      .done();
  an.def("crank_slab_polar_inertia",
         [](double tau, const analytic::SlabBox& slab, int intervals) {
           return analytic::crank_slab_polar_inertia(tau, slab, intervals);
         },
         py::arg("kappa_t_over_L2"), py::arg("slab"), py::arg("intervals") = 512);
  an.def("time_discrete_rate",
         [](py::object scheme, double lambda, double dt) {
           const std::string name = py::str(scheme);
           if (py::isinstance<ExplicitScheme>(scheme) || name == "euler27" || name == "rk4" || name == "euler_exact")
             return analytic::time_discrete_rate(scheme.cast<ExplicitScheme>(), lambda, dt);
           return analytic::time_discrete_rate(scheme.cast<TimeScheme>(), lambda, dt);
         },
         py::arg("scheme"), py::arg("lam"), py::arg("dt"),
         "Decay rate of exp(-lam t) under the time scheme alone (TimeScheme or ExplicitScheme, or its name).");

  // ---- reference objects (what `otfp run` writes for diagnostics.reference)
  py::class_<ErrorStatistics>(m, "ErrorStatistics",
                              "Running statistics of error = (measured - reference) / scale, trapezoid rule in time.")
      .def(py::init<std::string, double, std::string>(), py::arg("measured") = "", py::arg("scale") = 1.0,
           py::arg("scale_rule") = "")
      .def("add", &ErrorStatistics::add, py::arg("t"), py::arg("measured"), py::arg("reference"),
           "Adds the row at time t; returns its error.")
      .def_property_readonly("measured", &ErrorStatistics::measured)
      .def_property_readonly("scale", &ErrorStatistics::scale)
      .def_property_readonly("scale_rule", &ErrorStatistics::scale_rule)
      .def_property_readonly("started", &ErrorStatistics::started)
      .def_property_readonly("t_first", &ErrorStatistics::t_first)
      .def_property_readonly("t_last", &ErrorStatistics::t_last)
      .def_property_readonly("max_abs_error", &ErrorStatistics::max_abs_error)
      .def_property_readonly("l1_time_error", &ErrorStatistics::l1_time_error)
      .def_property_readonly("mean_abs_error", &ErrorStatistics::mean_abs_error)
      .def_property_readonly("final_error", &ErrorStatistics::final_error)
      .def_property_readonly("l1_norm", &ErrorStatistics::l1_norm)
      .def_property_readonly("l1_norm_reference", &ErrorStatistics::l1_norm_reference)
      .def_property_readonly("l1_norm_relative_error", &ErrorStatistics::l1_norm_relative_error)
      .def("state", &ErrorStatistics::state)
      .def("load_state", &ErrorStatistics::load_state, py::arg("state"));
  m.def("decay_rate_fit", &decay_rate_fit, py::arg("t"), py::arg("a"),
        "Minus the least-squares slope of log a against t (nan for fewer than 3 samples).");
  Options<ReferenceSetup>(m, "ReferenceSetup", "What make_reference sets a reference up with.")
      .field("dim", &ReferenceSetup::dim, "1, 2 or 3")
      .field("kappa", &ReferenceSetup::kappa, "diffusivity")
      .field("t_end", &ReferenceSetup::t_end, "end of the run (free_space: the error scale)")
      .field("center", &ReferenceSetup::center, "centre of the polar inertia and second moment")
      .field("M_inf", &ReferenceSetup::M_inf, "crank_*: the mass ratios are M / M_inf")
      .field("radius", &ReferenceSetup::radius, "crank_sphere: R")
      .field("length", &ReferenceSetup::length, "crank_slab: L")
      .field("J_inf", &ReferenceSetup::J_inf, "crank_*: analytic steady polar inertia (None: no polar inertia)")
      .field("lo", &ReferenceSetup::lo, "crank_slab: box corner")
      .field("hi", &ReferenceSetup::hi, "crank_slab: box corner")
      .field("slab_axis", &ReferenceSetup::slab_axis, "crank_slab: normal of the held face")
      .field("slab_held_at_hi", &ReferenceSetup::slab_held_at_hi, "crank_slab: the held face is x = hi")
      .field("wavenumber", &ReferenceSetup::wavenumber, "cosine_mode: k")
      .field("x0", &ReferenceSetup::x0, "cosine_mode: origin of the mode along x")
      .field("constant_dt", &ReferenceSetup::constant_dt, "cosine_mode: the constant step (0: none)")
      .field("stepper", &ReferenceSetup::stepper, "cosine_mode: implicit or explicit")
      .field("time_scheme", &ReferenceSetup::time_scheme, "cosine_mode: implicit scheme")
      .field("explicit_scheme", &ReferenceSetup::explicit_scheme, "cosine_mode: explicit scheme")
      .done();
  py::class_<ReferenceRow>(m, "ReferenceRow", "One row of a reference: values per column.")
      .def_readonly("values", &ReferenceRow::values)
      .def_readonly("reference", &ReferenceRow::reference)
      .def_readonly("error_mass_blob", &ReferenceRow::error_mass_blob);
  using PyReference = Locked<Reference>;
  py::class_<PyReference>(m, "Reference", "An analytic reference (make_reference).")
      .def_property_readonly("name", [](PyReference& r) { return r.object->name(); })
      .def_property_readonly("columns", [](PyReference& r) { return r.object->columns(); })
      .def_property_readonly("has_mass_blob_error", [](PyReference& r) { return r.object->has_mass_blob_error(); })
      .def("row",
           [](PyReference& r, double t, const StateMeasures* measures, double mass_blob, const ParticleSet* particles,
              double initial_mass) {
             auto held = r.lock.hold();
             ReferenceSample s;
             s.t = t;
             if (measures) s.measures = *measures;
             s.mass_blob = mass_blob;
             s.particles = particles;
             s.initial_mass = initial_mass;
             return r.object->row(s);
           },
           py::arg("t"), py::arg("measures") = nullptr, py::arg("mass_blob") = 0.0, py::arg("particles") = nullptr,
           py::arg("initial_mass") = 0.0,
           "The row at time t (rows in time order, the first at the start): measures from Simulation.measure, "
           "mass_blob from Simulation.blob_mass (crank_*), particles (free_space, cosine_mode), initial_mass "
           "(free_space).")
      .def("statistics",
           [](PyReference& r) {
             auto held = r.lock.hold();
             return r.object->statistics();
           })
      .def("mass_blob_statistics",
           [](PyReference& r) {
             auto held = r.lock.hold();
             return r.object->mass_blob_statistics();
           })
      .def("summary",
           [](PyReference& r) {
             auto held = r.lock.hold();
             py::dict d;
             for (const ReferenceEntry& e : r.object->summary())
               d[py::str(e.key)] = std::visit([](auto v) { return py::cast(v); }, e.value);
             return d;
           },
           "Its own entries of summary.json's reference (a dict).")
      .def("save_state",
           [](PyReference& r) {
             auto held = r.lock.hold();
             return r.object->save_state();
           })
      .def("load_state",
           [](PyReference& r, const ReferenceState& state) {
             auto held = r.lock.hold();
             r.object->load_state(state);
           },
           py::arg("state"));
  m.def("reference_names", &reference_names);
  m.def("make_reference",
        [](const std::string& name, const ReferenceSetup& setup) {
          return std::make_unique<PyReference>(make_reference(name, setup));
        },
        py::arg("name"), py::arg("setup"), "crank_sphere, crank_slab, free_space or cosine_mode (reference_names()).");
  m.def(
      "complete_reference_geometry",
      [](const std::string& name, const PyDomain& domain, const std::vector<int>& dirichlet_patches,
         ReferenceSetup setup) {
        if (!domain) throw InvalidArgument("domain: required");
        complete_reference_geometry(name, *domain, dirichlet_patches, setup);
        return setup;
      },
      py::arg("name"), py::arg("domain"), py::arg("dirichlet_patches"), py::arg("setup"),
      "The setup with the Crank references' radius, slab depth and J_inf filled from the domain (a copy).");

  // ---- the rows of series.csv (run_record.hpp, series_layout.hpp)
  py::class_<StepRecord>(m, "StepRecord", "One row of series.csv and timing.csv (RunRecorder.record).")
      .def_readonly("step", &StepRecord::step)
      .def_readonly("t", &StepRecord::t)
      .def_readonly("reference_values", &StepRecord::reference_values)
      .def(
          "as_dict",
          [](const StepRecord& r) {
            py::dict d;
            for (const std::vector<SeriesColumn>* table : {&series_columns(), &timing_columns()})
              for (const SeriesColumn& c : *table) switch (c.kind) {
                  case ColumnKind::Integer: d[c.name] = r.*(c.integer); break;
                  case ColumnKind::Number: d[c.name] = r.*(c.number); break;
                  case ColumnKind::OptionalNumber: d[c.name] = py::cast(r.*(c.optional)); break;
                }
            return d;
          },
          "Every column of series.csv and timing.csv by name (absent values None); the reference's are "
          "reference_values.");
  py::class_<RecorderOptions>(m, "RecorderOptions", "What the rows are measured against.")
      .def(py::init<>())
      .def_readwrite("center", &RecorderOptions::center, "centre of the polar inertia (44)")
      .def_readwrite("M_inf", &RecorderOptions::M_inf, "mass_ratio = mass_inside / M_inf")
      .def_readwrite("J_inf", &RecorderOptions::J_inf, "polar_inertia_ratio = polar_inertia / J_inf (None: no column)")
      .def("validate", &RecorderOptions::validate);
  // The recorder reads the simulation and feeds the reference: each call
  // holds the three locks (the recorder's, then the simulation's, then the
  // reference's), so rows from several threads take turns.
  struct PyRecorder {
    PySimulation* sim = nullptr;
    PyReference* reference = nullptr;
    std::unique_ptr<RunRecorder> object;
    ObjectLock lock;
  };
  py::class_<PyRecorder>(m, "RunRecorder",
                         "The rows otfp run writes, from a Simulation after each step (SeriesLayout writes them).")
      .def(py::init([](PySimulation& sim, const RecorderOptions& options, PyReference* reference) {
             auto r = std::make_unique<PyRecorder>();
             r->sim = &sim;
             r->reference = reference;
             r->object = std::make_unique<RunRecorder>(*sim.object, options, reference ? reference->object.get() : nullptr);
             return r;
           }),
           py::arg("simulation"), py::arg("options"), py::arg("reference") = nullptr, py::keep_alive<1, 2>(),
           py::keep_alive<1, 4>())
      .def(
          "record",
          [](PyRecorder& r, std::int64_t step, double t, const StepSummary* summary, std::int64_t inserted,
             std::int64_t removed) {
            // The simulation's lock first, as its run_until holds it while an
            // observer records: then the recorder's, then the reference's.
            auto sim = r.sim->lock.hold();
            auto own = r.lock.hold();
            std::unique_lock<std::recursive_mutex> ref;
            if (r.reference) ref = r.reference->lock.hold();
            return (*r.object)(step, t, summary, inserted, removed);
          },
          py::arg("step"), py::arg("t"), py::arg("summary") = nullptr, py::arg("inserted") = 0, py::arg("removed") = 0,
          "The row of step `step` ending at t (rows in time order; summary: the step's diffusion, None for row 0).")
      .def(
          "set_initial",
          [](PyRecorder& r, const ParticleSet& particles) {
            auto own = r.lock.hold();
            r.object->set_initial(particles);
          },
          py::arg("particles"),
          "The particles given to Simulation.start (their count and mass; default: row 0's whole state).")
      .def_property(
          "step_dt", [](PyRecorder& r) { return r.object->step_dt; },
          [](PyRecorder& r, double dt) {
            auto own = r.lock.hold();
            r.object->step_dt = dt;
          },
          "the step being taken (fixed: the grid's dt; adaptive: its own length)")
      .def_property(
          "step_rejections", [](PyRecorder& r) { return r.object->step_rejections; },
          [](PyRecorder& r, std::int64_t n) {
            auto own = r.lock.hold();
            r.object->step_rejections = n;
          },
          "adaptive: tries rejected before the step being recorded");
  py::class_<SeriesLayout>(m, "SeriesLayout", "The columns of one run's series.csv: its header and rows.")
      .def(py::init<bool, bool, std::vector<std::string>>(), py::arg("has_j_inf"), py::arg("has_mass_blob_error"),
           py::arg("reference_columns") = std::vector<std::string>{})
      .def_static("timing", &SeriesLayout::timing, "timing.csv's columns")
      .def_property_readonly("header", &SeriesLayout::header)
      .def("row", &SeriesLayout::row, py::arg("record"), "the CSV line of a StepRecord (RuntimeError if a value is not finite: nothing non-finite is written)");
}

}  // namespace otfp::python
