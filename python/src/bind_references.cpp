// The papers' parameter rules (36)-(40), the diagnostics, and the analytic
// references (submodule otfp.analytic).
#include "common.hpp"

#include <string>

#include "otfp/analytic.hpp"
#include "otfp/diagnostics.hpp"
#include "otfp/enums.hpp"
#include "otfp/neighbor_list.hpp"
#include "otfp/parameters.hpp"

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
}

}  // namespace otfp::python
