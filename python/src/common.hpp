// Internal to the Python module otfp._otfp (not installed): the helpers that
// several binding files share (the functions not defined here are in
// common.cpp). Built on the library alone (no otfp_app).
//
// Every binding file includes this header first, so that all of them see the
// same pybind11 type casters (Eigen, std::function, numpy, STL containers,
// std::filesystem::path): a type converted with different casters in two
// translation units would break the one-definition rule.
#pragma once

#include <pybind11/eigen.h>
#include <pybind11/functional.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>
#include <pybind11/stl/filesystem.h>

#include <cstdint>
#include <memory>
#include <mutex>
#include <string>
#include <unordered_map>
#include <vector>

#include "otfp/geometry.hpp"
#include "otfp/particles.hpp"
#include "otfp/simulation.hpp"
#include "otfp/types.hpp"

namespace py = pybind11;

namespace otfp::python {

// ------------------------------------------------------------------ arrays

using DoubleArray = py::array_t<double, py::array::c_style | py::array::forcecast>;

// A number in messages: the shortest form that reads back (0, 0.45, nan, inf).
std::string num(double v);
std::string shape_of(const py::array& a);

// Any array-like of real numbers as a C-ordered double array. numpy would
// cast complex values to real with only a warning, and strings fail later
// with pybind11's overload listing: both are refused here, naming the field.
DoubleArray real_array(const py::handle& obj, const std::string& name);

// (n, k) with 1 <= k <= 3 (or a single point of k values) -> n points padded
// with zeros. Every coordinate finite; coordinates beyond `dim` must be 0
// (the (n, 3) positions of a 2-D set), not dropped silently.
std::vector<Vec3> points_from(const py::handle& obj, const char* name, int dim = 3);

// n values, each finite (and > 0 when `positive`: widths, masses).
std::vector<double> values_from(const py::handle& obj, std::size_t n, const char* name, bool positive);

// A set handed to a stepper or a Simulation: its arrays may have been
// written through the views, so a NaN there is bad input of this call (not
// a step that diverged later).
void check_particles(const ParticleSet& ps, const char* name);

// A seed: any Python int in the range of the library's 64-bit unsigned seed.
std::uint64_t seed_from(const py::int_& v);

py::array_t<double> points_to(const std::vector<Vec3>& x);
py::array_t<double> values_to(const std::vector<double>& v);

// Live numpy views per ParticleSet: a set with views must not move its storage
// (the views themselves: view_of in bind_particles_geometry.cpp).
std::unordered_map<const ParticleSet*, long>& exports();

// ------------------------------------------------------------------ threads

// Serialises the methods of one bound object across threads. A thread waits
// for it with the GIL released: the holder may need the GIL to finish (the
// observer of run_until), so waiting with it would deadlock. Re-entrant, so
// that an observer called under the lock may use its own simulation. Call
// hold() with the GIL held (as every bound method is called).
class ObjectLock {
 public:
  std::unique_lock<std::recursive_mutex> hold() {
    std::unique_lock<std::recursive_mutex> lock(mutex_, std::try_to_lock);
    if (!lock.owns_lock()) {
      py::gil_scoped_release release;
      lock.lock();
    }
    return lock;
  }

 private:
  std::recursive_mutex mutex_;
};

// A library object and its lock (the library's classes cannot be moved, so
// the object is held by pointer).
template <class T>
struct Locked {
  explicit Locked(std::unique_ptr<T> o) : object(std::move(o)) {}
  std::unique_ptr<T> object;
  ObjectLock lock;
};

// otfp.Simulation (bind_simulation.cpp; ConfiguredRun.make_simulation returns
// one too).
using PySimulation = Locked<Simulation>;

// The locks of the ParticleSets that a stepper is working on (guarded by the
// GIL): a second step of the same set waits for the first, so neither result
// is lost, and resizing the set meanwhile is refused.
struct SetStep {
  ObjectLock lock;
  long users = 0;
};
std::unordered_map<const ParticleSet*, std::unique_ptr<SetStep>>& set_steps();

// BufferError when `set` has live numpy views or a stepper is stepping it:
// `what` (e.g. "ParticleSet.add") would move its storage.
void require_no_views(const ParticleSet& set, const char* what);

// Runs f on a copy of `set` and takes the result back without moving the
// storage (the steppers reorder particles; views stay valid and see the
// result). Steps of one set from several threads take turns.
template <class F>
auto on_copy(ParticleSet& set, F&& f) {
  std::unique_ptr<SetStep>& entry = set_steps()[&set];
  if (!entry) entry = std::make_unique<SetStep>();
  SetStep* const step = entry.get();  // stays put while users > 0
  ++step->users;
  struct Release {
    const ParticleSet* set;
    SetStep* step;
    ~Release() {  // the GIL is held again here
      if (--step->users == 0) set_steps().erase(set);
    }
  } release_entry{&set, step};
  auto held = step->lock.hold();
  ParticleSet work = set;
  auto result = [&] {
    py::gil_scoped_release release;
    return f(work);
  }();
  set.assign_in_place(work);
  held.unlock();
  return result;
}

// ------------------------------------------------------------------ options

// An options class: fields bound read/write and listed in _fields, so that the
// package's __init__ can accept keyword arguments and print them.
template <class T>
class Options {
 public:
  Options(py::module_& m, const char* name, const char* doc) : cls_(m, name, doc) {
    cls_.def(py::init<>());
  }
  template <class M>
  Options& field(const char* name, M T::*member, const char* doc) {
    cls_.def_readwrite(name, member, doc);
    fields_.append(name);
    return *this;
  }
  Options& validated() {
    return validated([](const T& o) { o.validate(); });
  }
  template <class F>
  Options& validated(F check) {
    cls_.def("validate", check, "Raises ValueError naming the offending field.");
    return *this;
  }
  void done() { cls_.attr("_fields") = fields_; }

 private:
  py::class_<T> cls_;
  py::list fields_;
};

// ------------------------------------------------------------------ domains

using PyDomain = std::shared_ptr<Domain>;
inline PyDomain mutable_domain(const DomainPtr& d) { return std::const_pointer_cast<Domain>(d); }

}  // namespace otfp::python
