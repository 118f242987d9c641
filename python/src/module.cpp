// The Python module otfp._otfp (re-exported by the package otfp): particle
// sets, domains, the functional (28), the steppers, otfp::Simulation, the
// diagnostics and analytic references, and the command-line tool's TOML
// configurations. docs/python.md describes the API.
//
// Threads: every object whose methods release the GIL (Simulation, the
// steppers, Functional, ConfiguredRun.run, and a ParticleSet while a stepper
// works on it) serialises them with a lock of its own (ObjectLock below), so
// that threads sharing an object take turns instead of racing.
//
// Arrays: a ParticleSet's positions, widths, masses, birth times and ids are
// numpy views of its own storage (no copy); while a view is alive the set
// refuses to change size or order (BufferError, as bytearray does), because
// that would move the storage. Everything else (a Simulation's particles,
// gradients, point queries) is returned as a new array.
#include <pybind11/eigen.h>
#include <pybind11/functional.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>
#include <pybind11/stl/filesystem.h>

#include <fmt/format.h>

#include <cmath>
#include <limits>
#include <memory>
#include <mutex>
#include <string>
#include <unordered_map>
#include <vector>

#include "otfp/analytic.hpp"
#include "otfp/barrier.hpp"
#include "otfp/diagnostics.hpp"
#include "otfp/enums.hpp"
#include "otfp/explicit_stepper.hpp"
#include "otfp/functional.hpp"
#include "otfp/geometry.hpp"
#include "otfp/implicit_stepper.hpp"
#include "otfp/initial_fill.hpp"
#include "otfp/neighbor_list.hpp"
#include "otfp/particle_io.hpp"
#include "otfp/parameters.hpp"
#include "otfp/particles.hpp"
#include "otfp/simulation.hpp"
#include "otfp/time_step_control.hpp"
#include "otfp/types.hpp"
#include "otfp_app/config.hpp"
#include "otfp_app/out_dir.hpp"
#include "otfp_app/simulation.hpp"

namespace py = pybind11;
using namespace otfp;

namespace {

// ------------------------------------------------------------------ arrays

using DoubleArray = py::array_t<double, py::array::c_style | py::array::forcecast>;

// A number in messages: the shortest form that reads back (0, 0.45, nan, inf).
std::string num(double v) { return fmt::format("{}", v); }
std::string shape_of(const py::array& a) {
  std::string out = "(";
  for (py::ssize_t k = 0; k < a.ndim(); ++k) out += (k ? ", " : "") + std::to_string(a.shape(k));
  return out + (a.ndim() == 1 ? ",)" : ")");
}

// Any array-like of real numbers as a C-ordered double array. numpy would
// cast complex values to real with only a warning, and strings fail later
// with pybind11's overload listing: both are refused here, naming the field.
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

// (n, k) with 1 <= k <= 3 (or a single point of k values) -> n points padded
// with zeros. Every coordinate finite; coordinates beyond `dim` must be 0
// (the (n, 3) positions of a 2-D set), not dropped silently.
std::vector<Vec3> points_from(const py::handle& obj, const char* name, int dim = 3) {
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

// n values, each finite (and > 0 when `positive`: widths, masses).
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

// A set handed to a stepper or a Simulation: its arrays may have been
// written through the views, so a NaN there is bad input of this call (not
// a step that diverged later).
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

// A seed: any Python int in the range of the library's 64-bit unsigned seed.
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

// Live numpy views per ParticleSet: a set with views must not move its storage.
std::unordered_map<const ParticleSet*, long>& exports() {
  static std::unordered_map<const ParticleSet*, long> map;
  return map;
}

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

// The locks of the ParticleSets that a stepper is working on (guarded by the
// GIL): a second step of the same set waits for the first, so neither result
// is lost, and resizing the set meanwhile is refused.
struct SetStep {
  ObjectLock lock;
  long users = 0;
};
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

// An enum with its names as strings: Backend("nlopt") and a plain "nlopt"
// wherever a Backend is expected.
template <class E, class FromString>
void bind_enum(py::module_& m, const char* name, std::initializer_list<std::pair<const char*, E>> values,
               FromString from_string) {
  py::enum_<E> e(m, name);
  for (const auto& [n, v] : values) e.value(n, v);
  e.def(py::init([from_string](const std::string& s) { return from_string(s); }));
  // Replaces enum_'s __str__ ("PatchKind.Dirichlet"): def() would add an
  // overload behind it that is never reached.
  e.attr("__str__") = py::cpp_function([](E v) { return to_string(v); }, py::name("__str__"), py::is_method(e));
  py::implicitly_convertible<py::str, E>();
}

template <class E>
E no_from_string(const std::string& s) {
  throw InvalidArgument("\"" + s + "\" cannot be converted to this enum");
}

// ------------------------------------------------------------------ domains

using PyDomain = std::shared_ptr<Domain>;
PyDomain mutable_domain(const DomainPtr& d) { return std::const_pointer_cast<Domain>(d); }

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

// ------------------------------------------------------------------ functional

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

// ------------------------------------------------------------------ observer stop

// Thrown by the observer wrapper when the Python observer returns False.
struct StopRequested {};

// ConfiguredRun.run's out_dir refused (an earlier run there, a held lock, not
// a directory): the command-line tool's rules, raised as a ValueError.
class OutputDirError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// Control characters as escapes: a path with a newline stays a one-line message.
std::string escaped(const std::string& s) {
  std::string out;
  for (const char ch : s) {
    const auto u = static_cast<unsigned char>(ch);
    if (u < 0x20 || u == 0x7f) {
      static const char hex[] = "0123456789abcdef";
      out += "\\x";
      out += hex[u >> 4];
      out += hex[u & 15];
    } else {
      out += ch;
    }
  }
  return out;
}

py::dict json_to_dict(const nlohmann::json& j) {
  py::module_ json = py::module_::import("json");
  return json.attr("loads")(j.dump()).cast<py::dict>();
}

}  // namespace

PYBIND11_MODULE(_otfp, m) {
  m.doc() = "otfp: the optimal-transport finite-particle method of driven mass diffusion (C++ core)";
  // One-line messages that name the field: subclasses of ValueError (bad
  // input) and RuntimeError (a step that could not be taken).
  py::register_exception<InvalidArgument>(m, "InvalidArgument", PyExc_ValueError);
  py::register_exception<app::ConfigError>(m, "ConfigError", PyExc_ValueError);
  py::register_exception<StepFailure>(m, "StepFailure", PyExc_RuntimeError);
  py::register_exception<OutputDirError>(m, "OutputDirError", PyExc_ValueError);
  m.attr("__version__") = app::version();

  // ---- enums
  bind_enum<Backend>(m, "Backend", {{"Ceres", Backend::Ceres}, {"Nlopt", Backend::Nlopt}}, backend_from_string);
  bind_enum<Algorithm>(m, "Algorithm",
                       {{"Lbfgs", Algorithm::Lbfgs}, {"Bfgs", Algorithm::Bfgs}, {"NonlinearCg", Algorithm::NonlinearCg},
                        {"TruncatedNewton", Algorithm::TruncatedNewton}, {"Var2", Algorithm::Var2}, {"Mma", Algorithm::Mma}},
                       algorithm_from_string);
  bind_enum<TerminationReason>(
      m, "TerminationReason",
      {{"Converged", TerminationReason::Converged}, {"FunctionTolerance", TerminationReason::FunctionTolerance},
       {"MaxIterations", TerminationReason::MaxIterations}, {"MaxEvaluations", TerminationReason::MaxEvaluations},
       {"LineSearchFailure", TerminationReason::LineSearchFailure}, {"NonFinite", TerminationReason::NonFinite},
       {"Failure", TerminationReason::Failure}},
      no_from_string<TerminationReason>);
  bind_enum<WidthMetric>(m, "WidthMetric",
                         {{"AsPrinted", WidthMetric::AsPrinted}, {"ExactGaussian", WidthMetric::ExactGaussian}},
                         width_metric_from_string);
  bind_enum<WidthMode>(m, "WidthMode", {{"Fixed", WidthMode::Fixed}, {"PerParticle", WidthMode::PerParticle}},
                       width_mode_from_string);
  bind_enum<TimeScheme>(m, "TimeScheme", {{"Euler", TimeScheme::Euler}, {"Bdf2", TimeScheme::Bdf2}},
                        time_scheme_from_string);
  bind_enum<Predictor>(m, "Predictor",
                       {{"None_", Predictor::None}, {"Extrapolate", Predictor::Extrapolate}, {"Damped", Predictor::Damped}},
                       predictor_from_string);
  bind_enum<ErrorMeasure>(m, "ErrorMeasure",
                          {{"Displacement", ErrorMeasure::Displacement}, {"Density", ErrorMeasure::Density}},
                          error_measure_from_string);
  bind_enum<StoppingNorm>(m, "StoppingNorm", {{"Max", StoppingNorm::Max}, {"Energy", StoppingNorm::Energy}},
                          stopping_norm_from_string);
  bind_enum<ExplicitScheme>(m, "ExplicitScheme",
                            {{"EulerForce27", ExplicitScheme::EulerForce27}, {"Rk4Force27", ExplicitScheme::Rk4Force27},
                             {"EulerExactGradient", ExplicitScheme::EulerExactGradient}},
                            explicit_scheme_from_string);
  bind_enum<PatchKind>(m, "PatchKind",
                       {{"NoFlux", PatchKind::NoFlux}, {"Dirichlet", PatchKind::Dirichlet}, {"Neumann", PatchKind::Neumann}},
                       patch_kind_from_string);
  bind_enum<NeumannOutflow>(m, "NeumannOutflow",
                            {{"Layer", NeumannOutflow::Layer}, {"NearestParticles", NeumannOutflow::NearestParticles}},
                            neumann_outflow_from_string);
  bind_enum<DirichletMode>(m, "DirichletMode",
                           {{"Layer", DirichletMode::Layer}, {"Reservoir", DirichletMode::Reservoir}},
                           dirichlet_mode_from_string);
  bind_enum<ReservoirProfile>(m, "ReservoirProfile",
                              {{"Uniform", ReservoirProfile::Uniform}, {"Odd", ReservoirProfile::Odd}},
                              reservoir_profile_from_string);
  bind_enum<ReservoirControl>(m, "ReservoirControl",
                              {{"Quiet", ReservoirControl::Quiet}, {"Exact", ReservoirControl::Exact}},
                              reservoir_control_from_string);
  bind_enum<DirichletTarget>(m, "DirichletTarget",
                             {{"CellIntegral", DirichletTarget::CellIntegral}, {"PaperEq34", DirichletTarget::PaperEq34}},
                             dirichlet_target_from_string);
  bind_enum<StepperKind>(m, "StepperKind", {{"Implicit", StepperKind::Implicit}, {"Explicit", StepperKind::Explicit}},
                         stepper_kind_from_string);
  bind_enum<NoFluxTreatment>(m, "NoFluxTreatment",
                             {{"Barrier", NoFluxTreatment::Barrier}, {"Images", NoFluxTreatment::Images}},
                             no_flux_treatment_from_string);
  bind_enum<FillShape>(m, "FillShape",
                       {{"Uniform", FillShape::Uniform}, {"Gaussian", FillShape::Gaussian}, {"Cosine", FillShape::Cosine}},
                       fill_shape_from_string);

  // ---- random numbers
  py::class_<Rng>(m, "Rng", "xoshiro256** seeded by SplitMix64: the same seed gives the same stream everywhere.")
      .def(py::init([](const py::int_& seed) { return Rng(seed_from(seed)); }), py::arg("seed") = 0x5eed)
      .def("uniform", py::overload_cast<>(&Rng::uniform))
      .def("normal", &Rng::normal);

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

  // ---- options
  Options<NeighborOptions>(m, "NeighborOptions", "Cut-off tolerance and skin of the neighbour list.")
      .field("kernel_tolerance", &NeighborOptions::kernel_tolerance, "kernel value at the cut-off, relative to its peak")
      .field("skin", &NeighborOptions::skin, "absolute skin; < 0: skin_factor x smallest width")
      .field("skin_factor", &NeighborOptions::skin_factor, "skin in smallest widths when skin < 0")
      .validated()
      .done();
  Options<MinimizerOptions>(m, "MinimizerOptions", "Backend and caps of the minimiser.")
      .field("backend", &MinimizerOptions::backend, "ceres | nlopt")
      .field("algorithm", &MinimizerOptions::algorithm, "lbfgs, bfgs, nonlinear_cg (Ceres); tnewton, var2, mma (NLopt)")
      .field("gradient_tolerance", &MinimizerOptions::gradient_tolerance, "set per step by the stepper")
      .field("relative_gradient_tolerance", &MinimizerOptions::relative_gradient_tolerance, "0: off")
      .field("gradient_tolerance_floor", &MinimizerOptions::gradient_tolerance_floor, "floor of the relative rule")
      .field("start_tolerance", &MinimizerOptions::start_tolerance, "a start below this is converged (0: off)")
      .field("function_tolerance", &MinimizerOptions::function_tolerance, "0: off")
      .field("max_iterations", &MinimizerOptions::max_iterations, "iteration cap")
      .field("max_evaluations", &MinimizerOptions::max_evaluations, "evaluation cap")
      .field("lbfgs_memory", &MinimizerOptions::lbfgs_memory, "L-BFGS history")
      .field("approximate_eigenvalue_scaling", &MinimizerOptions::approximate_eigenvalue_scaling, "Ceres only")
      .validated()
      .done();
  Options<FunctionalOptions>(m, "FunctionalOptions", "dt, kappa, rho_ref, width metric of the functional (28).")
      .field("dt", &FunctionalOptions::dt, "time step (> 0)")
      .field("kappa", &FunctionalOptions::kappa, "diffusivity (> 0)")
      .field("rho_ref", &FunctionalOptions::rho_ref, "reference density (> 0)")
      .field("width_metric", &FunctionalOptions::width_metric, "as_printed (c_w = 1) | exact (d/2)")
      .field("optimise_widths", &FunctionalOptions::optimise_widths, "gradient in the widths as well")
      .field("neighbor", &FunctionalOptions::neighbor, "NeighborOptions")
      .field("width_skin", &FunctionalOptions::width_skin, "optimise_widths: list built for widths s (1 + this)")
      .validated()
      .done();
  Options<ImplicitOptions>(m, "ImplicitOptions", "The implicit variational step (28).")
      .field("minimizer", &ImplicitOptions::minimizer, "MinimizerOptions")
      .field("displacement_tolerance", &ImplicitOptions::displacement_tolerance, "stop at max |dt/m dF/dx| <= this x s")
      .field("relative_tolerance", &ImplicitOptions::relative_tolerance, "... or this x the first gradient step")
      .field("width_mode", &ImplicitOptions::width_mode, "fixed | per_particle")
      .field("width_metric", &ImplicitOptions::width_metric, "as_printed | exact")
      .field("kappa", &ImplicitOptions::kappa, "diffusivity")
      .field("rho_ref", &ImplicitOptions::rho_ref, "reference density")
      .field("neighbor", &ImplicitOptions::neighbor, "NeighborOptions")
      .field("max_halvings", &ImplicitOptions::max_halvings, "dt/2 retries after a failed solve")
      .field("energy_tolerance", &ImplicitOptions::energy_tolerance, "allowed rise of F")
      .field("sort_particles", &ImplicitOptions::sort_particles, "reorder spatially each step (ids kept)")
      .field("time_scheme", &ImplicitOptions::time_scheme, "euler | bdf2")
      .field("predictor", &ImplicitOptions::predictor, "none | extrapolate | damped")
      .field("error_smoothing", &ImplicitOptions::error_smoothing, "error estimate smoothing (widths)")
      .field("error_measure", &ImplicitOptions::error_measure, "displacement | density: what error_estimate measures")
      .field("stopping_norm", &ImplicitOptions::stopping_norm, "max | energy: norm of the solve's stopping rule")
      .field("max_norm_factor", &ImplicitOptions::max_norm_factor, "energy norm: largest residual / RMS tolerance (>= 1)")
      .field("width_skin", &ImplicitOptions::width_skin, "per_particle: list built for widths s (1 + this)")
      .field("max_width_factor", &ImplicitOptions::max_width_factor, "per_particle: s <= this x nominal_width (0: off)")
      .field("nominal_width", &ImplicitOptions::nominal_width, "the width s0 the bound refers to")
      .validated()
      .done();
  Options<ExplicitOptions>(m, "ExplicitOptions", "The explicit baselines.")
      .field("scheme", &ExplicitOptions::scheme, "euler27 | rk4 | euler_exact")
      .field("kappa", &ExplicitOptions::kappa, "diffusivity")
      .field("rho_ref", &ExplicitOptions::rho_ref, "reference density")
      .field("neighbor", &ExplicitOptions::neighbor, "NeighborOptions")
      .field("sort_particles", &ExplicitOptions::sort_particles, "reorder spatially each step")
      .validated()
      .done();
  Options<TimeStepControlOptions>(m, "TimeStepControlOptions", "Adaptive steps.")
      .field("tolerance", &TimeStepControlOptions::tolerance, "largest error estimate per step (widths)")
      .field("safety", &TimeStepControlOptions::safety, "safety factor")
      .field("max_growth", &TimeStepControlOptions::max_growth, "largest dt_new / dt")
      .field("max_shrink", &TimeStepControlOptions::max_shrink, "smallest dt_new / dt")
      .field("dt_min", &TimeStepControlOptions::dt_min, "smallest step")
      .field("dt_max", &TimeStepControlOptions::dt_max, "largest step")
      .validated()
      .done();
  Options<ProjectionOptions>(m, "ProjectionOptions", "The boundary-layer projection of Sec. 4.2.")
      .field("layer_b", &ProjectionOptions::layer_b, "half-thickness b")
      .field("dirichlet_target", &ProjectionOptions::dirichlet_target, "cell_integral | paper_eq34")
      .field("quadrature_samples", &ProjectionOptions::quadrature_samples, "Monte Carlo points")
      .field("neumann_outflow", &ProjectionOptions::neumann_outflow, "layer | nearest_particles")
      .field("nearest_surface_points", &ProjectionOptions::nearest_surface_points, "points on A_l")
      .field("dirichlet_mode", &ProjectionOptions::dirichlet_mode, "layer | reservoir")
      .field("reservoir_thickness", &ProjectionOptions::reservoir_thickness, "band width w")
      .field("reservoir_sublayers", &ProjectionOptions::reservoir_sublayers, "0: about one spacing each")
      .field("reservoir_volume_samples", &ProjectionOptions::reservoir_volume_samples, "Monte Carlo points")
      .field("reservoir_profile", &ProjectionOptions::reservoir_profile, "uniform | odd")
      .field("reservoir_control", &ProjectionOptions::reservoir_control, "quiet | exact")
      .field("reservoir_tolerance", &ProjectionOptions::reservoir_tolerance, "quiet: deficit (particles) to act on")
      .field("reservoir_candidates", &ProjectionOptions::reservoir_candidates, "quiet: candidate points per particle")
      .field("absorb_exterior", &ProjectionOptions::absorb_exterior, "layer: remove stranded exterior particles")
      // The reservoir band's domain is built by the Simulation, not given here.
      .validated([](const ProjectionOptions& o) { o.validate(/*require_reservoir_domain=*/false); })
      .done();
  Options<SimulationOptions>(m, "SimulationOptions", "Algorithm 1 (otfp.Simulation).")
      .field("particle_mass", &SimulationOptions::particle_mass, "m_p of inserted particles (> 0)")
      .field("width_s", &SimulationOptions::width_s, "s of inserted particles (> 0)")
      .field("bounded", &SimulationOptions::bounded, "False: free space")
      .field("barrier_stiffness", &SimulationOptions::barrier_stiffness, "C of (40)")
      .field("no_flux", &SimulationOptions::no_flux, "images | barrier")
      .field("projection", &SimulationOptions::projection, "ProjectionOptions")
      .field("fill_reservoir_at_start", &SimulationOptions::fill_reservoir_at_start, "reservoir: fill at step 0")
      .field("stepper", &SimulationOptions::stepper, "implicit | explicit")
      .field("implicit", &SimulationOptions::implicit, "ImplicitOptions")
      .field("explicit_options", &SimulationOptions::explicit_options, "ExplicitOptions")
      .field("velocity", &SimulationOptions::velocity, "uniform advection velocity")
      .field("source_rate", &SimulationOptions::source_rate, "volumetric source rate")
      .field("time_control", &SimulationOptions::time_control, "TimeStepControlOptions")
      .field("max_error_rejections", &SimulationOptions::max_error_rejections, "adaptive tries per step")
      .field("seed", &SimulationOptions::seed, "random numbers")
      .field("max_particles", &SimulationOptions::max_particles, "a step past it fails; 0: default_max_particles()")
      .validated()
      .done();
  Options<FillOptions>(m, "FillOptions", "Initial particles: uniform, lattice, Gaussian or cosine.")
      .field("shape", &FillOptions::shape, "uniform | gaussian | cosine")
      .field("count", &FillOptions::count, "particles")
      .field("width_s", &FillOptions::width_s, "s of every particle")
      .field("mass", &FillOptions::mass, "m_p of every particle")
      .field("lattice", &FillOptions::lattice, "cell centres of a lattice in [lo, hi]")
      .field("lattice_counts", &FillOptions::lattice_counts, "points per axis")
      .field("lo", &FillOptions::lo, "box of the lattice / cosine")
      .field("hi", &FillOptions::hi, "box of the lattice / cosine")
      .field("center", &FillOptions::center, "Gaussian centre")
      .field("sigma", &FillOptions::sigma, "Gaussian standard deviation")
      .field("amplitude", &FillOptions::amplitude, "cosine amplitude a")
      .field("wavenumber", &FillOptions::wavenumber, "cosine k")
      .validated()
      .done();
  m.def("default_max_particles", &default_max_particles,
        "Half the machine's memory over 2.5 KB per particle: what SimulationOptions.max_particles = 0 means.");
  m.def("fill_particles",
        [](const PyDomain& domain, const FillOptions& o, const py::int_& seed) {
          Rng rng(seed_from(seed));
          return fill_particles(*domain, o, rng);
        },
        py::arg("domain"), py::arg("options"), py::arg("seed") = 1);

  // ---- summaries
  py::class_<FunctionalParts>(m, "FunctionalParts")
      .def_readonly("transport", &FunctionalParts::transport)
      .def_readonly("entropy", &FunctionalParts::entropy)
      .def_readonly("barrier", &FunctionalParts::barrier)
      .def_property_readonly("total", &FunctionalParts::total);
  py::class_<StepSummary>(m, "StepSummary", "What every diffusive step reports.")
      .def_readonly("accepted", &StepSummary::accepted)
      .def_readonly("reason", &StepSummary::reason)
      .def_readonly("message", &StepSummary::message)
      .def_readonly("dt", &StepSummary::dt)
      .def_readonly("substeps", &StepSummary::substeps)
      .def_readonly("halvings", &StepSummary::halvings)
      .def_readonly("rejected_solves", &StepSummary::rejected_solves)
      .def_readonly("f_before", &StepSummary::f_before)
      .def_readonly("f_after", &StepSummary::f_after)
      .def_readonly("parts_before", &StepSummary::parts_before)
      .def_readonly("parts_after", &StepSummary::parts_after)
      .def_readonly("iterations", &StepSummary::iterations)
      .def_readonly("evaluations", &StepSummary::evaluations)
      .def_readonly("residual_displacement", &StepSummary::residual_displacement)
      .def_readonly("list_builds", &StepSummary::list_builds)
      .def_readonly("wall_seconds", &StepSummary::wall_seconds)
      .def_readonly("solver_seconds", &StepSummary::solver_seconds)
      .def_readonly("list_seconds", &StepSummary::list_seconds)
      .def_readonly("gradient_tolerance", &StepSummary::gradient_tolerance)
      .def_readonly("pair_evaluations", &StepSummary::pair_evaluations)
      .def_readonly("inserted", &StepSummary::inserted)
      .def_readonly("removed", &StepSummary::removed)
      .def_readonly("error_estimate", &StepSummary::error_estimate)
      .def_readonly("density_error_estimate", &StepSummary::density_error_estimate)
      .def_readonly("displacement_error_estimate", &StepSummary::displacement_error_estimate)
      .def_readonly("error_order", &StepSummary::error_order)
      .def_readonly("error_rejected", &StepSummary::error_rejected)
      .def("__repr__", [](const StepSummary& s) {
        return "StepSummary(accepted=" + std::string(s.accepted ? "True" : "False") + ", reason=" +
               to_string(s.reason) + ", dt=" + std::to_string(s.dt) + ", F " + std::to_string(s.f_before) + " -> " +
               std::to_string(s.f_after) + ", evaluations=" + std::to_string(s.evaluations) + ")";
      });
  py::class_<SimulationStep>(m, "SimulationStep", "One step of Algorithm 1.")
      .def_readonly("step", &SimulationStep::step)
      .def_readonly("t_start", &SimulationStep::t_start)
      .def_readonly("t_end", &SimulationStep::t_end)
      .def_property_readonly("dt", &SimulationStep::dt)
      .def_readonly("diffusion", &SimulationStep::diffusion)
      .def_readonly("inserted", &SimulationStep::inserted)
      .def_readonly("removed", &SimulationStep::removed)
      .def_readonly("reflected", &SimulationStep::reflected)
      .def_readonly("error_rejections", &SimulationStep::error_rejections)
      .def_readonly("forced_at_dt_min", &SimulationStep::forced_at_dt_min)
      .def_readonly("dt_next", &SimulationStep::dt_next)
      .def_readonly("wall_seconds", &SimulationStep::wall_seconds)
      .def("brief_report", &SimulationStep::brief_report)
      .def("full_report", &SimulationStep::full_report)
      .def("__repr__", &SimulationStep::brief_report);
  py::class_<SimulationLedger>(m, "SimulationLedger", "n(t) = n(0) + inserted - removed, and the same for the mass.")
      .def_readonly("initial_particles", &SimulationLedger::initial_particles)
      .def_readonly("initial_mass", &SimulationLedger::initial_mass)
      .def_readonly("inserted", &SimulationLedger::inserted)
      .def_readonly("removed", &SimulationLedger::removed)
      .def_readonly("mass_inserted", &SimulationLedger::mass_inserted)
      .def_readonly("mass_removed", &SimulationLedger::mass_removed)
      .def_readonly("source_inserted", &SimulationLedger::source_inserted)
      .def_readonly("source_removed", &SimulationLedger::source_removed)
      .def_readonly("reflected", &SimulationLedger::reflected)
      .def("expected_particles", &SimulationLedger::expected_particles)
      .def("expected_mass", &SimulationLedger::expected_mass);
  py::class_<SimulationTotals>(m, "SimulationTotals")
      .def_readonly("iterations", &SimulationTotals::iterations)
      .def_readonly("evaluations", &SimulationTotals::evaluations)
      .def_readonly("rejected_solves", &SimulationTotals::rejected_solves)
      .def_readonly("halvings", &SimulationTotals::halvings)
      .def_readonly("error_rejected_steps", &SimulationTotals::error_rejected_steps)
      .def_readonly("steps_forced_at_dt_min", &SimulationTotals::steps_forced_at_dt_min)
      .def_readonly("step_seconds", &SimulationTotals::step_seconds)
      .def_readonly("solver_seconds", &SimulationTotals::solver_seconds);
  py::class_<StateMeasures>(m, "StateMeasures", "(43)-(44) at one time.")
      .def_readonly("n_particles", &StateMeasures::n_particles)
      .def_readonly("n_inside", &StateMeasures::n_inside)
      .def_readonly("n_buffer", &StateMeasures::n_buffer)
      .def_readonly("n_outside", &StateMeasures::n_outside)
      .def_readonly("mass_total", &StateMeasures::mass_total)
      .def_readonly("mass_inside", &StateMeasures::mass_inside)
      .def_readonly("mass_with_layer", &StateMeasures::mass_with_layer)
      .def_readonly("polar_inertia", &StateMeasures::polar_inertia)
      .def_readonly("polar_inertia_with_layer", &StateMeasures::polar_inertia_with_layer)
      .def_readonly("polar_inertia_total", &StateMeasures::polar_inertia_total)
      .def_readonly("mean_age", &StateMeasures::mean_age)
      .def_readonly("max_age", &StateMeasures::max_age);

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

  // ---- Simulation (with its lock: every method waits for a step running in
  // another thread; the observer of run_until may use its own simulation)
  using PySimulation = Locked<Simulation>;
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
                 if (r.is_none()) return;
                 // True/False (numpy's bool too); anything else is a mistake, not a truth value.
                 const bool is_bool = py::isinstance<py::bool_>(r) ||
                                      py::isinstance(r, py::module_::import("numpy").attr("bool_"));
                 if (!is_bool)
                   throw py::type_error("observer returned " +
                                        py::str(py::type::of(r).attr("__name__")).cast<std::string>() +
                                        ": an observer must return None or True (go on) or False (stop after this "
                                        "step)");
                 if (!r.cast<bool>()) throw StopRequested{};
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

  // ---- the command-line tool's configurations
  // run() steps the configuration's own Simulation: runs from several
  // threads take turns (the rest reads what the constructor fixed).
  using PyConfiguredRun = Locked<app::ConfiguredRun>;
  py::class_<PyConfiguredRun>(m, "ConfiguredRun", "A TOML configuration of `otfp run`, with its derived numbers.")
      .def_property_readonly("description",
                             [](const PyConfiguredRun& r) { return json_to_dict(r.object->describe()); },
                             "{'config': the resolved keys, 'derived': dt, n_steps, M_inf, ...}")
      .def_property_readonly("dt", [](const PyConfiguredRun& r) { return r.object->derived().dt; })
      .def_property_readonly("n_steps", [](const PyConfiguredRun& r) { return r.object->derived().n_steps; })
      .def_property_readonly("t_end", [](const PyConfiguredRun& r) { return r.object->config().run.t_end; })
      .def_property_readonly("M_inf", [](const PyConfiguredRun& r) { return r.object->derived().M_inf; })
      .def_property_readonly("center", [](const PyConfiguredRun& r) { return r.object->derived().center; })
      .def_property_readonly("domain", [](const PyConfiguredRun& r) { return mutable_domain(r.object->domain_ptr()); })
      .def("make_simulation",
           [](const PyConfiguredRun& r) { return std::make_unique<PySimulation>(r.object->make_simulation()); },
           "A started Simulation as `otfp run` builds it: advance_to(k * dt) reproduces the CLI's steps bit for bit.")
      .def("run",
           [](PyConfiguredRun& r, const std::filesystem::path& out_dir, bool progress, bool overwrite) {
             auto held = r.lock.hold();
             app::RunOptions o;
             o.out_dir = out_dir;
             o.progress = progress;
             o.keep_series = false;
             app::RunResult res;
             {
               py::gil_scoped_release release;
               // The command-line tool's rules: the directory locked for the
               // whole run, an earlier run's refused unless overwrite=True.
               app::OutputLock lock;
               if (!out_dir.empty())
                 if (const std::string why =
                         app::prepare_out_dir(out_dir, /*resume=*/false, overwrite, lock, "overwrite=True");
                     !why.empty())
                   throw OutputDirError("out_dir = \"" + escaped(out_dir.string()) + "\": " + escaped(why));
               res = r.object->run(o);
             }
             py::dict d;
             d["status"] = res.status;
             d["exit_code"] = res.exit_code;
             d["error"] = res.error;
             d["summary"] = json_to_dict(res.summary);
             return d;
           },
           py::arg("out_dir") = std::filesystem::path(), py::arg("progress") = false, py::kw_only(),
           py::arg("overwrite") = false,
           "The whole run as `otfp run CONFIG --out out_dir [--overwrite]` (nothing written when out_dir is empty). "
           "OutputDirError (a ValueError) when out_dir holds an earlier run (unless overwrite=True) or another "
           "run holds its lock.");
  m.def("load_config",
        [](const std::filesystem::path& path, const std::vector<std::string>& overrides) {
          return std::make_unique<PyConfiguredRun>(
              std::make_unique<app::ConfiguredRun>(app::parse_config_file(path, overrides)));
        },
        py::arg("path"), py::arg("overrides") = std::vector<std::string>{},
        "Reads a TOML configuration (overrides: 'key=value' as --set) and derives (36)-(40); ConfigError names the key.");
}
