// The shared helpers of the Python module declared in common.hpp: array
// conversion and checks, and the registries of numpy views and of the sets a
// stepper is working on (one instance for the whole module).
#include "common.hpp"

#include <fmt/format.h>

#include <cmath>

namespace otfp::python {

// ------------------------------------------------------------------ arrays

std::string num(double v) { return fmt::format("{}", v); }
std::string shape_of(const py::array& a) {
  std::string out = "(";
  for (py::ssize_t k = 0; k < a.ndim(); ++k) out += (k ? ", " : "") + std::to_string(a.shape(k));
  return out + (a.ndim() == 1 ? ",)" : ")");
}

DoubleArray real_array(const py::handle& obj, const std::string& name) {
  py::array a = py::array::ensure(obj);
  if (!a) throw InvalidArgument(name + ": must be an array of real numbers");
  const char kind = a.dtype().kind();
  const std::string dtype = py::str(a.dtype()).cast<std::string>();
  if (kind == 'c') throw InvalidArgument(name + ": complex values (dtype " + dtype + "): must be real");
  if (kind != 'b' && kind != 'i' && kind != 'u' && kind != 'f')
    throw InvalidArgument(name + ": dtype " + dtype + ": must be real numbers");
  return DoubleArray::ensure(a);
}

std::vector<Vec3> points_from(const py::handle& obj, const char* name, int dim) {
  const DoubleArray a = real_array(obj, name);
  std::vector<Vec3> out;
  auto point = [&](py::ssize_t i, const Vec3& v, py::ssize_t k_used) {
    if (!v.allFinite())
      throw InvalidArgument(std::string(name) + (a.ndim() == 1 ? "" : ": row " + std::to_string(i)) + " = (" +
                            num(v[0]) + ", " + num(v[1]) + ", " + num(v[2]) + "): must be finite");
    for (py::ssize_t k = dim; k < k_used; ++k)
      if (v[k] != 0.0)
        throw InvalidArgument(
            a.ndim() == 1
                ? std::string(name) + ": " + std::to_string(k_used) + " coordinates for a dim = " +
                      std::to_string(dim) + " set: coordinate " + std::to_string(k) + " must be 0 (is " + num(v[k]) +
                      ")"
                : std::string(name) + ": shape " + shape_of(a) + " for a dim = " + std::to_string(dim) +
                      " set: column " + std::to_string(k) + " must be 0 (row " + std::to_string(i) + " has " +
                      num(v[k]) + "); give (n, " + std::to_string(dim) + ") positions");
  };
  if (a.ndim() == 1) {
    if (a.shape(0) < 1 || a.shape(0) > 3)
      throw InvalidArgument(std::string(name) + ": a point has 1 to 3 coordinates, got " + std::to_string(a.shape(0)));
    Vec3 v = Vec3::Zero();
    for (py::ssize_t k = 0; k < a.shape(0); ++k) v[k] = a.at(k);
    point(0, v, a.shape(0));
    out.push_back(v);
    return out;
  }
  if (a.ndim() != 2 || a.shape(1) < 1 || a.shape(1) > 3)
    throw InvalidArgument(std::string(name) + ": shape " + shape_of(a) +
                          ": must be an array of shape (n, d) with d = 1, 2 or 3");
  const auto r = a.unchecked<2>();
  out.assign(static_cast<std::size_t>(a.shape(0)), Vec3::Zero());
  for (py::ssize_t i = 0; i < a.shape(0); ++i) {
    Vec3& v = out[static_cast<std::size_t>(i)];
    for (py::ssize_t k = 0; k < a.shape(1); ++k) v[k] = r(i, k);
    point(i, v, a.shape(1));
  }
  return out;
}

std::vector<double> values_from(const py::handle& obj, std::size_t n, const char* name, bool positive) {
  const DoubleArray a = real_array(obj, name);
  if (a.ndim() != 1 || static_cast<std::size_t>(a.shape(0)) != n)
    throw InvalidArgument(std::string(name) + ": shape " + shape_of(a) + ": must be a 1-D array of " +
                          std::to_string(n) + " values");
  std::vector<double> out(a.data(), a.data() + n);
  for (std::size_t i = 0; i < n; ++i)
    if (!std::isfinite(out[i]) || (positive && !(out[i] > 0.0)))
      throw InvalidArgument(std::string(name) + ": row " + std::to_string(i) + " = " + num(out[i]) +
                            (positive ? ": must be finite and > 0" : ": must be finite"));
  return out;
}

void check_particles(const ParticleSet& ps, const char* name) {
  const std::string set(name);
  auto where = [&](std::size_t p) {
    return ": row " + std::to_string(p) + " (id " + std::to_string(ps.ids()[p]) + ")";
  };
  for (std::size_t p = 0; p < ps.size(); ++p) {
    const Vec3& x = ps.positions()[p];
    if (!x.allFinite())
      throw InvalidArgument(set + ".positions" + where(p) + " = (" + num(x[0]) + ", " + num(x[1]) + ", " + num(x[2]) +
                            "): must be finite");
    if (!(std::isfinite(ps.widths()[p]) && ps.widths()[p] > 0.0))
      throw InvalidArgument(set + ".widths" + where(p) + " = " + num(ps.widths()[p]) + ": must be finite and > 0");
    if (!(std::isfinite(ps.masses()[p]) && ps.masses()[p] > 0.0))
      throw InvalidArgument(set + ".masses" + where(p) + " = " + num(ps.masses()[p]) + ": must be finite and > 0");
    if (!std::isfinite(ps.birth_times()[p]))
      throw InvalidArgument(set + ".birth_times" + where(p) + " = " + num(ps.birth_times()[p]) + ": must be finite");
  }
}

std::uint64_t seed_from(const py::int_& v) {
  try {
    return v.cast<std::uint64_t>();
  } catch (const py::cast_error&) {
    throw InvalidArgument("seed = " + std::string(py::str(py::handle(v))) + ": must be an integer in 0 .. 2**64 - 1");
  }
}

py::array_t<double> points_to(const std::vector<Vec3>& x) {
  py::array_t<double> out({static_cast<py::ssize_t>(x.size()), py::ssize_t{3}});
  auto w = out.mutable_unchecked<2>();
  for (std::size_t i = 0; i < x.size(); ++i)
    for (int k = 0; k < 3; ++k) w(static_cast<py::ssize_t>(i), k) = x[i][k];
  return out;
}

py::array_t<double> values_to(const std::vector<double>& v) {
  return py::array_t<double>(static_cast<py::ssize_t>(v.size()), v.data());
}

std::unordered_map<const ParticleSet*, long>& exports() {
  static std::unordered_map<const ParticleSet*, long> map;
  return map;
}

// ------------------------------------------------------------------ threads

std::unordered_map<const ParticleSet*, std::unique_ptr<SetStep>>& set_steps() {
  static std::unordered_map<const ParticleSet*, std::unique_ptr<SetStep>> map;
  return map;
}

void require_no_views(const ParticleSet& set, const char* what) {
  auto it = exports().find(&set);
  if (it != exports().end() && it->second > 0)
    throw py::buffer_error(std::string(what) + ": " + std::to_string(it->second) +
                           " numpy view(s) of this ParticleSet are alive and would be left pointing at freed "
                           "memory; delete them (or take copies with numpy.array(view)) first");
  if (set_steps().count(&set))
    throw py::buffer_error(std::string(what) +
                           ": a stepper is stepping this ParticleSet in another thread; wait for its step first");
}

}  // namespace otfp::python
