// ParticleSet (its arrays numpy views of its own storage), the particle files,
// the domains and the constant boundary data on their patches.
#include "common.hpp"

#include <cmath>
#include <string>
#include <type_traits>
#include <vector>

#include "otfp/particle_io.hpp"

#include "bindings.hpp"

namespace otfp::python {

namespace {

// A numpy view of one of a set's arrays, counted in exports() while it lives.
struct ViewBase {
  py::object owner;  // keeps the set alive
  const ParticleSet* set;
};

template <class T>
py::array view_of(py::object owner, const ParticleSet& set, T* data, std::vector<py::ssize_t> shape, bool writable) {
  auto* base = new ViewBase{owner, &set};
  ++exports()[&set];
  py::capsule cap(base, [](void* p) {
    auto* b = static_cast<ViewBase*>(p);
    if (--exports()[b->set] == 0) exports().erase(b->set);
    delete b;
  });
  std::vector<py::ssize_t> strides;
  py::ssize_t stride = sizeof(T);
  for (auto it = shape.rbegin(); it != shape.rend(); ++it) {
    strides.insert(strides.begin(), stride);
    stride *= *it;
  }
  py::array a(py::dtype::of<T>(), shape, strides, data, cap);
  if (!writable) a.attr("flags").attr("writeable") = false;
  return a;
}

// A scalar for one point (1-D input), else an array over the points.
template <class F>
py::object per_point(const py::object& points, F f) {
  const std::vector<Vec3> x = points_from(points, "points");
  if (real_array(points, "points").ndim() == 1) return py::cast(f(x[0]));
  using R = decltype(f(x[0]));
  if constexpr (std::is_same_v<R, Vec3>) {
    std::vector<Vec3> out(x.size());
    for (std::size_t i = 0; i < x.size(); ++i) out[i] = f(x[i]);
    return points_to(out);
  } else {
    py::array_t<R> out(static_cast<py::ssize_t>(x.size()));
    auto w = out.template mutable_unchecked<1>();
    for (std::size_t i = 0; i < x.size(); ++i) w(static_cast<py::ssize_t>(i)) = f(x[i]);
    return out;
  }
}

}  // namespace

void bind_particles_geometry(py::module_& m) {
  // ---- particles
  py::class_<ParticleSet>(m, "ParticleSet",
                          "Gaussian blobs in d = 1, 2, 3. positions (n, 3), widths s = beta^-1/2, masses, "
                          "birth_times and ids are numpy views of the set's storage.")
      .def(py::init<int>(), py::arg("dim") = 3)
      .def(py::init([](int dim, const py::object& x, const py::object& s, const py::object& mass) {
             require(dim >= 1 && dim <= 3, "dim", dim, "must be 1, 2 or 3");
             const std::vector<Vec3> xv = points_from(x, "positions", dim);
             const std::vector<double> sv = values_from(s, xv.size(), "widths", true);
             const std::vector<double> mv = values_from(mass, xv.size(), "masses", true);
             ParticleSet ps(dim);
             ps.reserve(xv.size());
             for (std::size_t i = 0; i < xv.size(); ++i) ps.add(xv[i], sv[i], mv[i]);
             return ps;
           }),
           py::arg("dim"), py::arg("positions"), py::arg("widths"), py::arg("masses"),
           "A set from arrays: positions (n, d), widths s (n,), masses (n,); ids 0 .. n-1.")
      .def_property_readonly("dim", &ParticleSet::dim)
      .def("__len__", &ParticleSet::size)
      .def_property_readonly(
          "positions",
          [](py::object self) {
            auto& ps = self.cast<ParticleSet&>();
            return view_of(self, ps, ps.positions().empty() ? nullptr : ps.positions()[0].data(),
                           {static_cast<py::ssize_t>(ps.size()), 3}, true);
          },
          "(n, 3) view; columns beyond dim stay 0")
      .def_property_readonly("widths",
                             [](py::object self) {
                               auto& ps = self.cast<ParticleSet&>();
                               return view_of(self, ps, ps.widths().data(), {static_cast<py::ssize_t>(ps.size())}, true);
                             })
      .def_property_readonly("masses",
                             [](py::object self) {
                               auto& ps = self.cast<ParticleSet&>();
                               return view_of(self, ps, ps.masses().data(), {static_cast<py::ssize_t>(ps.size())}, true);
                             })
      .def_property_readonly("birth_times",
                             [](py::object self) {
                               auto& ps = self.cast<ParticleSet&>();
                               return view_of(self, ps, ps.birth_times().data(),
                                              {static_cast<py::ssize_t>(ps.size())}, true);
                             })
      .def_property_readonly("ids",
                             [](py::object self) {
                               auto& ps = self.cast<ParticleSet&>();
                               return view_of(self, ps, const_cast<ParticleId*>(ps.ids().data()),
                                              {static_cast<py::ssize_t>(ps.size())}, false);
                             })
      .def("ages", [](const ParticleSet& ps, double t) {
        std::vector<double> a(ps.size());
        for (std::size_t p = 0; p < ps.size(); ++p) a[p] = t - ps.birth_times()[p];
        return values_to(a);
      }, py::arg("t"), "t - birth time per particle (a new array)")
      .def_property_readonly("betas", [](const ParticleSet& ps) {
        std::vector<double> b(ps.size());
        for (std::size_t p = 0; p < ps.size(); ++p) b[p] = ps.beta(p);
        return values_to(b);
      }, "beta = 1 / s^2 per particle (a new array)")
      .def("add",
           [](ParticleSet& ps, const py::object& x, double width_s, double mass, double birth_time) {
             // One point: a 2-D array is refused rather than cut to its first row.
             if (const DoubleArray a = real_array(x, "x"); a.ndim() != 1)
               throw InvalidArgument("x: shape " + shape_of(a) +
                                     ": add() takes one point (1 to 3 coordinates); for many particles build "
                                     "ParticleSet(dim, positions, widths, masses)");
             const Vec3 point = points_from(x, "x", ps.dim()).at(0);
             require(std::isfinite(width_s) && width_s > 0.0, "width_s", width_s, "must be finite and > 0");
             require(std::isfinite(mass) && mass > 0.0, "mass", mass, "must be finite and > 0");
             if (!std::isfinite(birth_time)) throw InvalidArgument("birth_time = " + num(birth_time) + ": must be finite");
             require_no_views(ps, "ParticleSet.add");
             return ps.add(point, width_s, mass, birth_time);
           },
           py::arg("x"), py::arg("width_s"), py::arg("mass"), py::arg("birth_time") = 0.0,
           "Appends one particle (x: one point of 1 to 3 coordinates); returns its id.")
      .def("remove",
           [](ParticleSet& ps, std::size_t index) {
             require_no_views(ps, "ParticleSet.remove");
             require(index < ps.size(), "index", static_cast<double>(index), "must be below the number of particles");
             ps.remove(index);
           },
           py::arg("index"))
      .def("clear", [](ParticleSet& ps) {
        require_no_views(ps, "ParticleSet.clear");
        ps.clear();
      })
      .def("index_of", &ParticleSet::index_of, py::arg("id"))
      .def("total_mass", &ParticleSet::total_mass)
      .def_property_readonly("next_id", &ParticleSet::next_id)
      .def("copy", [](const ParticleSet& ps) { return ParticleSet(ps); })
      .def("__copy__", [](const ParticleSet& ps) { return ParticleSet(ps); })
      .def("__deepcopy__", [](const ParticleSet& ps, py::dict) { return ParticleSet(ps); })
      .def("__repr__", [](const ParticleSet& ps) {
        return "ParticleSet(dim=" + std::to_string(ps.dim()) + ", n=" + std::to_string(ps.size()) + ")";
      });
  m.def("read_particles", &read_particles, py::arg("path"), py::arg("dim"),
        "Particles from a CSV (particles_final.csv's columns) or an otfp .vtp.");
  m.def("particles_csv", [](const ParticleSet& ps) { return particles_csv(ps); }, py::arg("particles"),
        "The CSV text of particles_final.csv (round-trips bit for bit).");

  // ---- domains
  py::class_<Domain, PyDomain>(m, "Domain", "Signed distance plus boundary patches.")
      .def_property_readonly("dim", &Domain::dim)
      .def_property_readonly("volume", &Domain::volume)
      .def_property_readonly("num_patches", &Domain::num_patches)
      .def_property_readonly("is_periodic", &Domain::is_periodic)
      .def_property_readonly("inertia_center", &Domain::inertia_center, "default centre of the polar inertia")
      .def("mean_square_distance", &Domain::mean_square_distance, py::arg("center"),
           "mean of |x - c|^2 over Omega at uniform density (J_inf = M_inf x it)")
      .def("patch_area", &Domain::patch_area, py::arg("patch"))
      .def("patch_name", &Domain::patch_name, py::arg("patch"))
      .def("patch_by_name", &Domain::patch_by_name, py::arg("name"), "patch id, or -1")
      .def_property_readonly("patch_names", [](const Domain& d) {
        std::vector<std::string> names;
        for (int p = 0; p < d.num_patches(); ++p) names.push_back(d.patch_name(p));
        return names;
      })
      .def("bounding_box", [](const Domain& d) {
        const Aabb b = d.bounding_box();
        return py::make_tuple(Vec3(b.lo), Vec3(b.hi));
      })
      .def("signed_distance", [](const Domain& d, const py::object& x) {
        return per_point(x, [&](const Vec3& p) { return d.signed_distance(p); });
      }, py::arg("points"), "< 0 inside; a float for one point, else an array")
      .def("closest_point", [](const Domain& d, const py::object& x) {
        return per_point(x, [&](const Vec3& p) { return d.closest_point(p); });
      }, py::arg("points"))
      .def("patch_id", [](const Domain& d, const py::object& x) {
        return per_point(x, [&](const Vec3& p) { return d.patch_id(p); });
      }, py::arg("points"), "the patch of the closest boundary point")
      .def("contains", [](const Domain& d, const py::object& x) {
        return per_point(x, [&](const Vec3& p) { return d.contains(p); });
      }, py::arg("points"));
  m.def("make_ball", [](int dim, const Vec3& c, double r) { return mutable_domain(make_ball(dim, c, r)); },
        py::arg("dim"), py::arg("center"), py::arg("radius"), "Ball (d = 3) or disc (d = 2), one patch.");
  m.def("make_box", [](int dim, const Vec3& lo, const Vec3& hi) { return mutable_domain(make_box(dim, lo, hi)); },
        py::arg("dim"), py::arg("lo"), py::arg("hi"), "Box, one patch per face (x-, x+, y-, ...).");
  m.def("make_cylinder", [](const Vec3& a, const Vec3& b, double r) { return mutable_domain(make_cylinder(a, b, r)); },
        py::arg("end_a"), py::arg("end_b"), py::arg("radius"), "Capped cylinder (3-D): mantle and two caps.");
  m.def("make_periodic_box",
        [](int dim, const Vec3& lo, const Vec3& hi) { return mutable_domain(make_periodic_box(dim, lo, hi)); },
        py::arg("dim"), py::arg("lo"), py::arg("hi"));
  m.def("make_square_pipe_obstacle",
        [](int dim, const Vec3& lo, const Vec3& hi, int axis, const Vec3& c, double r) {
          return mutable_domain(make_square_pipe_obstacle(dim, lo, hi, axis, c, r));
        },
        py::arg("dim"), py::arg("lo"), py::arg("hi"), py::arg("axis"), py::arg("obstacle_center"), py::arg("radius"),
        "Box minus a cylinder across it (a disc in 2-D): faces x-, x+, ..., then \"obstacle\".");
  m.def("make_free_space",
        [](int dim, const Vec3& lo, const Vec3& hi) { return mutable_domain(make_free_space(dim, lo, hi)); },
        py::arg("dim"), py::arg("lo"), py::arg("hi"),
        "Unbounded space: no boundary or patches; [lo, hi] serves the fill and the spacing rule.");
  m.def("make_union", [](const PyDomain& a, const PyDomain& b) { return mutable_domain(make_union(a, b)); });
  m.def("make_difference", [](const PyDomain& a, const PyDomain& b) { return mutable_domain(make_difference(a, b)); },
        "a minus b (e.g. an obstacle)");

  // ---- boundary data
  Options<ConstantBoundaryData>(m, "BoundaryData",
                                "Constant data on one patch over [t_start, t_end): Dirichlet g or Neumann outward flux f.")
      .field("patch", &ConstantBoundaryData::patch, "patch id (Domain.patch_by_name)")
      .field("kind", &ConstantBoundaryData::kind, "PatchKind or 'dirichlet' | 'neumann' | 'no_flux'")
      .field("value", &ConstantBoundaryData::value, "g or f")
      .field("t_start", &ConstantBoundaryData::t_start, "switched on at")
      .field("t_end", &ConstantBoundaryData::t_end, "switched off at")
      .done();
}

}  // namespace otfp::python
