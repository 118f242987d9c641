// The functional (28) on its own, and the implicit and explicit steppers
// (each with its lock; a step works on a copy of the set, see on_copy).
#include "common.hpp"

#include <limits>
#include <optional>
#include <string>
#include <vector>

#include "otfp/barrier.hpp"
#include "otfp/explicit_stepper.hpp"
#include "otfp/functional.hpp"
#include "otfp/implicit_stepper.hpp"

#include "bindings.hpp"

namespace otfp::python {

namespace {

Barrier make_barrier(const PyDomain& domain, double stiffness) {
  if (!domain || stiffness <= 0.0) return Barrier{};
  return Barrier(domain, stiffness);
}

Periodicity periodicity_of(const PyDomain& domain, int dim) {
  return domain ? Periodicity::from_domain(*domain) : Periodicity::none(dim);
}

int dim_of(const PyDomain& domain, std::optional<int> dim) {
  if (domain) {
    if (dim && *dim != domain->dim())
      throw InvalidArgument("dim = " + std::to_string(*dim) + ": must equal the domain's dim " +
                            std::to_string(domain->dim()));
    return domain->dim();
  }
  if (!dim) throw InvalidArgument("dim: required when no domain is given");
  return *dim;
}

// Functional (28) with its own reference state; evaluate() returns value, parts
// and gradients as arrays.
class PyFunctional {
 public:
  PyFunctional(int dim, const FunctionalOptions& options, const PyDomain& domain, double barrier_stiffness)
      : functional_(dim, options, make_barrier(domain, barrier_stiffness), periodicity_of(domain, dim)) {}

  void set_reference(const py::object& x, const py::object& s, const py::object& m) {
    auto held = lock_.hold();
    x_ref_ = points_from(x, "x_ref");
    const std::size_t n = x_ref_.size();
    s_ref_ = values_from(s, n, "s_ref", true);
    functional_.set_reference(x_ref_, s_ref_, values_from(m, n, "masses", true));
    has_reference_ = true;
  }

  py::dict evaluate(const py::object& x, const py::object& s, bool all_pairs) {
    auto held = lock_.hold();
    if (!has_reference_) throw InvalidArgument("Functional.evaluate: call set_reference() first");
    const std::vector<Vec3> xv = points_from(x, "x");
    if (xv.size() != x_ref_.size())
      throw InvalidArgument("x: must have the reference's " + std::to_string(x_ref_.size()) + " rows");
    const std::vector<double> sv = values_from(s, xv.size(), "s", true);
    Gradient g;
    g.resize(xv.size(), functional_.options().optimise_widths);
    FunctionalParts parts;
    {
      py::gil_scoped_release release;
      parts = all_pairs ? functional_.evaluate_all_pairs(xv, sv, &g) : functional_.evaluate(xv, sv, &g);
    }
    py::dict out;
    out["value"] = parts.total();
    out["transport"] = parts.transport;
    out["entropy"] = parts.entropy;
    out["barrier"] = parts.barrier;
    out["gradient_x"] = points_to(g.x);
    out["gradient_s"] = functional_.options().optimise_widths ? py::object(values_to(g.s)) : py::object(py::none());
    out["density"] = values_to(functional_.entropy().density());
    return out;
  }

 private:
  ObjectLock lock_;
  Functional functional_;
  std::vector<Vec3> x_ref_;
  std::vector<double> s_ref_;
  bool has_reference_ = false;
};

}  // namespace

void bind_steppers(py::module_& m) {
  // ---- functional
  py::class_<PyFunctional>(m, "Functional",
                           "F = T + E + B of (28) for one step from a reference state; gradients in x and s.")
      .def(py::init([](const PyDomain& domain, const FunctionalOptions& options, double barrier_stiffness,
                       std::optional<int> dim) {
             options.validate();
             return std::make_unique<PyFunctional>(dim_of(domain, dim), options, domain, barrier_stiffness);
           }),
           py::arg("domain") = PyDomain{}, py::arg("options") = FunctionalOptions{}, py::arg("barrier_stiffness") = 0.0,
           py::arg("dim") = py::none())
      .def("set_reference", &PyFunctional::set_reference, py::arg("x_ref"), py::arg("s_ref"), py::arg("masses"),
           "The state (x^k, s^k) of the step and the masses.")
      .def("evaluate", &PyFunctional::evaluate, py::arg("x"), py::arg("s"), py::arg("all_pairs") = false,
           "dict: value, transport, entropy, barrier, gradient_x (n, 3), gradient_s (n,) or None, density (n,)");

  // ---- steppers (each with its lock: threads sharing one take turns)
  using PyImplicitStepper = Locked<ImplicitStepper>;
  using PyExplicitStepper = Locked<ExplicitStepper>;
  py::class_<PyImplicitStepper>(m, "ImplicitStepper", "Minimises (28) each step (Ceres or NLopt).")
      .def(py::init([](const PyDomain& domain, const ImplicitOptions& options, double barrier_stiffness,
                       std::optional<int> dim) {
             options.validate();
             return std::make_unique<PyImplicitStepper>(std::make_unique<ImplicitStepper>(
                 dim_of(domain, dim), options, make_barrier(domain, barrier_stiffness),
                 periodicity_of(domain, dim_of(domain, dim))));
           }),
           py::arg("domain") = PyDomain{}, py::arg("options") = ImplicitOptions{}, py::arg("barrier_stiffness") = 0.0,
           py::arg("dim") = py::none())
      .def("step",
           [](PyImplicitStepper& st, ParticleSet& ps, double dt, double max_error) {
             check_particles(ps, "particles");
             auto held = st.lock.hold();
             return on_copy(ps, [&](ParticleSet& w) { return st.object->step(w, dt, max_error); });
           },
           py::arg("particles"), py::arg("dt"), py::arg("max_error") = std::numeric_limits<double>::infinity(),
           "One step of length dt, in place (the GIL is released). A failed step leaves the particles as they were.")
      .def("reset_history",
           [](PyImplicitStepper& st) {
             auto held = st.lock.hold();
             st.object->reset_history();
           })
      .def_property_readonly("options", [](PyImplicitStepper& st) {
        auto held = st.lock.hold();
        return ImplicitOptions(st.object->options());
      }, "A copy of the stepper's options.");
  py::class_<PyExplicitStepper>(m, "ExplicitStepper", "Algorithm 1 line 4 (sign corrected), RK4, or Euler on dF/dx.")
      .def(py::init([](const PyDomain& domain, const ExplicitOptions& options, double barrier_stiffness,
                       std::optional<int> dim) {
             options.validate();
             return std::make_unique<PyExplicitStepper>(std::make_unique<ExplicitStepper>(
                 dim_of(domain, dim), options, make_barrier(domain, barrier_stiffness),
                 periodicity_of(domain, dim_of(domain, dim))));
           }),
           py::arg("domain") = PyDomain{}, py::arg("options") = ExplicitOptions{}, py::arg("barrier_stiffness") = 0.0,
           py::arg("dim") = py::none())
      .def("step",
           [](PyExplicitStepper& st, ParticleSet& ps, double dt) {
             check_particles(ps, "particles");
             auto held = st.lock.hold();
             return on_copy(ps, [&](ParticleSet& w) { return st.object->step(w, dt); });
           },
           py::arg("particles"), py::arg("dt"), "One explicit step, in place (the GIL is released).");
}

}  // namespace otfp::python
