// Tests for otfp::minimize with every backend and every algorithm they offer
// (TAO where the build has otfp::mpi: this suite registers it).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <limits>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "otfp/minimizer.hpp"
#include "otfp/types.hpp"
#ifdef OTFP_WITH_TAO
#include "otfp/tao.hpp"
#endif

namespace {

using otfp::Algorithm;
using otfp::Backend;
using otfp::MinimizerOptions;
using otfp::MinimizerSummary;
using otfp::TerminationReason;

// f(z) and its gradient (gradient may be null). Returns f.
using Function = std::function<double(const double* z, double* g)>;

// Test objective: counts its calls, can be made non-finite outside a region,
// can scale its stopping measure and can throw on a given call.
class TestObjective final : public otfp::Objective {
 public:
  TestObjective(std::size_t n, Function f) : n_(n), f_(std::move(f)) {}
  std::size_t num_variables() const override { return n_; }
  bool evaluate(const double* z, double* value, double* gradient) override {
    ++calls;
    if (throw_at > 0 && calls == throw_at) throw std::runtime_error("objective exploded");
    if (finite && !finite(z)) {
      *value = std::numeric_limits<double>::quiet_NaN();
      if (gradient) std::fill(gradient, gradient + n_, std::numeric_limits<double>::quiet_NaN());
      return false;
    }
    *value = f_(z, gradient);
    return true;
  }
  double stopping_measure(const double* z, const double* gradient) const override {
    if (measure_scale == 1.0) return Objective::stopping_measure(z, gradient);
    return measure_scale * Objective::stopping_measure(z, gradient);
  }
  // Direct, uncounted evaluation for checking results.
  double value(const std::vector<double>& z, std::vector<double>* g = nullptr) const {
    if (g) g->assign(n_, 0.0);
    return f_(z.data(), g ? g->data() : nullptr);
  }
  double measure_at(const std::vector<double>& z) const {
    std::vector<double> g;
    value(z, &g);
    return stopping_measure(z.data(), g.data());
  }

  int calls = 0;
  int throw_at = 0;                              // throw on this call (0: never)
  double measure_scale = 1.0;                    // stopping measure = scale * max|g|
  std::function<bool(const double*)> finite;     // empty: finite everywhere

 private:
  std::size_t n_;
  Function f_;
};

// 0.5 sum a_i (z_i - c_i)^2 with a_i spread over [1, 100].
struct Quadratic {
  std::vector<double> a, c;
  explicit Quadratic(std::size_t n) : a(n), c(n) {
    for (std::size_t i = 0; i < n; ++i) {
      a[i] = std::pow(100.0, static_cast<double>(i) / static_cast<double>(n - 1));
      c[i] = std::sin(1.0 + static_cast<double>(i)) + 0.5;
    }
  }
  Function function() const {
    return [a = a, c = c](const double* z, double* g) {
      double f = 0.0;
      for (std::size_t i = 0; i < a.size(); ++i) {
        const double d = z[i] - c[i];
        f += 0.5 * a[i] * d * d;
        if (g) g[i] = a[i] * d;
      }
      return f;
    };
  }
};

// Extended Rosenbrock: sum over pairs of 100 (z2 - z1^2)^2 + (1 - z1)^2; minimiser all ones.
Function extended_rosenbrock(std::size_t n) {
  return [n](const double* z, double* g) {
    double f = 0.0;
    for (std::size_t i = 0; i + 1 < n; i += 2) {
      const double t = z[i + 1] - z[i] * z[i];
      const double u = 1.0 - z[i];
      f += 100.0 * t * t + u * u;
      if (g) {
        g[i] = -400.0 * z[i] * t - 2.0 * u;
        g[i + 1] = 200.0 * t;
      }
    }
    return f;
  };
}
std::vector<double> rosenbrock_start(std::size_t n) {
  std::vector<double> z(n);
  for (std::size_t i = 0; i < n; ++i) z[i] = (i % 2 == 0) ? -1.2 : 1.0;
  return z;
}

double max_abs_diff(const std::vector<double>& a, const std::vector<double>& b) {
  double m = 0.0;
  for (std::size_t i = 0; i < a.size(); ++i) m = std::max(m, std::abs(a[i] - b[i]));
  return m;
}

struct Combo {
  Backend backend;
  Algorithm algorithm;
};
#ifdef OTFP_WITH_TAO
// Registered before the lists below are built (same translation unit, in order).
const bool kTaoRegistered = (otfp::register_tao_backend(), true);
#endif
const std::vector<Combo> kAllCombos = {
    {Backend::Ceres, Algorithm::Lbfgs},          {Backend::Ceres, Algorithm::Bfgs},
    {Backend::Ceres, Algorithm::NonlinearCg},    {Backend::Nlopt, Algorithm::Lbfgs},
    {Backend::Nlopt, Algorithm::TruncatedNewton}, {Backend::Nlopt, Algorithm::Var2},
    {Backend::Nlopt, Algorithm::Mma},
#ifdef OTFP_WITH_TAO
    {Backend::Tao, Algorithm::Lbfgs},
#endif
};
const std::vector<Backend> kBackends = {Backend::Ceres, Backend::Nlopt,
#ifdef OTFP_WITH_TAO
                                        Backend::Tao
#endif
};

std::string label(Backend b, Algorithm a) { return otfp::to_string(b) + "/" + otfp::to_string(a); }

MinimizerOptions make_options(Backend b, Algorithm a, double tol) {
  MinimizerOptions o;
  o.backend = b;
  o.algorithm = a;
  o.gradient_tolerance = tol;
  return o;
}

// Invariants every summary must satisfy whatever the reason.
void check_invariants(const TestObjective& obj, const std::vector<double>& z, const MinimizerSummary& s,
                      const MinimizerOptions& o) {
  EXPECT_EQ(s.evaluations, obj.calls) << "evaluations must count every objective call";
  EXPECT_EQ(s.success, s.reason == TerminationReason::Converged || s.reason == TerminationReason::FunctionTolerance);
  EXPECT_GE(s.solver_seconds, 0.0);
  EXPECT_LE(s.solver_seconds, s.total_seconds);
  if (s.reason == TerminationReason::Converged) {
    EXPECT_LE(s.final_stopping_measure, o.gradient_tolerance);
  }
  if (std::isnan(s.initial_value)) return;  // non-finite start: nothing else to check
  for (double v : z) ASSERT_TRUE(std::isfinite(v));
  if (obj.finite) {
    ASSERT_TRUE(obj.finite(z.data())) << "returned a point where the objective is not finite";
  }
  EXPECT_LE(s.final_value, s.initial_value);
  EXPECT_DOUBLE_EQ(s.final_value, obj.value(z)) << "final_value must be f at the returned z";
  EXPECT_DOUBLE_EQ(s.final_stopping_measure, obj.measure_at(z)) << "final measure must be at the returned z";
  EXPECT_LE(s.evaluations, o.max_evaluations + 1);  // +1: at most one uncapped look at the returned point
  EXPECT_LE(s.iterations, o.max_iterations);
}

// ---------------------------------------------------------------- convergence

TEST(Minimizer, CeresAndNloptReachSameMinimizerOnQuadratic) {
  const std::size_t n = 20;
  const Quadratic q(n);
  const double tol = 1e-8;
  for (const Combo& c : kAllCombos) {
    SCOPED_TRACE(label(c.backend, c.algorithm));
    TestObjective obj(n, q.function());
    std::vector<double> z(n, 0.0);
    const MinimizerOptions o = make_options(c.backend, c.algorithm, tol);
    const MinimizerSummary s = otfp::minimize(obj, z, o);
    check_invariants(obj, z, s, o);
    EXPECT_EQ(s.reason, TerminationReason::Converged) << s.message;
    EXPECT_TRUE(s.success);
    EXPECT_LE(obj.measure_at(z), tol);
    EXPECT_GT(s.iterations, 0);
    // |z_i - c_i| = |g_i| / a_i <= tol / min a = tol.
    EXPECT_LE(max_abs_diff(z, q.c), tol * (1 + 1e-12));
    EXPECT_GE(s.initial_value, s.final_value);
  }
}

// The relative rule: with a loose absolute tolerance, both backends still
// stop only once the measure is below rel x its start value, and report the
// threshold they used; the floor caps how tight the rule gets.
TEST(Minimizer, RelativeToleranceTightensTheAbsoluteOne) {
  const std::size_t n = 20;
  const Quadratic q(n);
  for (Backend b : kBackends) {
    TestObjective obj(n, q.function());
    std::vector<double> z(n, 0.0);
    const double m0 = obj.measure_at(z);
    MinimizerOptions o = make_options(b, Algorithm::Lbfgs, 10.0 * m0);  // absolute rule alone: stop at once
    o.relative_gradient_tolerance = 1e-4;
    MinimizerSummary s = otfp::minimize(obj, z, o);
    EXPECT_EQ(s.reason, TerminationReason::Converged) << s.message;
    EXPECT_DOUBLE_EQ(s.gradient_tolerance, 1e-4 * m0);
    EXPECT_LE(obj.measure_at(z), 1e-4 * m0);
    EXPECT_GT(s.iterations, 0);
    // Floor above rel x m0: the floor wins.
    z.assign(n, 0.0);
    o.gradient_tolerance_floor = 1e-2 * m0;
    s = otfp::minimize(obj, z, o);
    EXPECT_DOUBLE_EQ(s.gradient_tolerance, 1e-2 * m0);
    EXPECT_LE(obj.measure_at(z), 1e-2 * m0);
  }
}

TEST(Minimizer, LbfgsSolvesRosenbrock2d) {
  for (Backend b : kBackends) {
    SCOPED_TRACE(otfp::to_string(b));
    TestObjective obj(2, extended_rosenbrock(2));
    std::vector<double> z = rosenbrock_start(2);
    const MinimizerOptions o = make_options(b, Algorithm::Lbfgs, 1e-9);
    const MinimizerSummary s = otfp::minimize(obj, z, o);
    check_invariants(obj, z, s, o);
    EXPECT_EQ(s.reason, TerminationReason::Converged) << s.message;
    EXPECT_DOUBLE_EQ(s.initial_value, 24.2);  // f(-1.2, 1)
    EXPECT_LE(max_abs_diff(z, {1.0, 1.0}), 1e-6);
  }
}

TEST(Minimizer, LbfgsSolvesExtendedRosenbrock50) {
  const std::size_t n = 50;
  for (Backend b : kBackends) {
    SCOPED_TRACE(otfp::to_string(b));
    TestObjective obj(n, extended_rosenbrock(n));
    std::vector<double> z = rosenbrock_start(n);
    const MinimizerOptions o = make_options(b, Algorithm::Lbfgs, 1e-8);
    const MinimizerSummary s = otfp::minimize(obj, z, o);
    check_invariants(obj, z, s, o);
    EXPECT_EQ(s.reason, TerminationReason::Converged) << s.message;
    EXPECT_LE(max_abs_diff(z, std::vector<double>(n, 1.0)), 1e-6);
  }
}

TEST(Minimizer, StoppingMeasureComesFromObjective) {
  // measure = 1000 max|g|: converging on it needs max|g| <= tol/1000, which a
  // backend using its own gradient test would not deliver as "Converged".
  const std::size_t n = 20;
  const Quadratic q(n);
  for (const Combo& c : kAllCombos) {
    SCOPED_TRACE(label(c.backend, c.algorithm));
    TestObjective strict(n, q.function());
    strict.measure_scale = 1000.0;
    TestObjective loose(n, q.function());
    loose.measure_scale = 1e-3;
    std::vector<double> zs(n, 0.0), zl(n, 0.0);
    const MinimizerOptions o = make_options(c.backend, c.algorithm, 1e-5);
    const MinimizerSummary ss = otfp::minimize(strict, zs, o);
    const MinimizerSummary sl = otfp::minimize(loose, zl, o);
    check_invariants(strict, zs, ss, o);
    check_invariants(loose, zl, sl, o);
    EXPECT_EQ(ss.reason, TerminationReason::Converged) << ss.message;
    EXPECT_EQ(sl.reason, TerminationReason::Converged) << sl.message;
    std::vector<double> g;
    strict.value(zs, &g);
    EXPECT_LE(*std::max_element(g.begin(), g.end(), [](double x, double y) { return std::abs(x) < std::abs(y); }),
              1e-8 + 1e-20);
    // The loose run must stop early, not run on to the strict tolerance.
    EXPECT_LT(sl.evaluations, ss.evaluations);
  }
}

TEST(Minimizer, ConvergedAtStartMakesNoIterations) {
  for (Backend b : kBackends) {
    const Quadratic q(5);
    TestObjective obj(5, q.function());
    std::vector<double> z = q.c;
    const MinimizerOptions o = make_options(b, Algorithm::Lbfgs, 1e-6);
    const MinimizerSummary s = otfp::minimize(obj, z, o);
    check_invariants(obj, z, s, o);
    EXPECT_EQ(s.reason, TerminationReason::Converged);
    EXPECT_EQ(s.iterations, 0);
    EXPECT_EQ(s.evaluations, 1);
    EXPECT_EQ(z, q.c);
  }
}

TEST(Minimizer, FunctionToleranceStopsBothBackends) {
  for (Backend b : kBackends) {
    SCOPED_TRACE(otfp::to_string(b));
    TestObjective obj(2, extended_rosenbrock(2));
    std::vector<double> z = rosenbrock_start(2);
    MinimizerOptions o = make_options(b, Algorithm::Lbfgs, 1e-12);
    o.function_tolerance = 0.5;  // stops at the first step that gains less than half of f
    const MinimizerSummary s = otfp::minimize(obj, z, o);
    check_invariants(obj, z, s, o);
    EXPECT_EQ(s.reason, TerminationReason::FunctionTolerance) << s.message;
    EXPECT_TRUE(s.success);
    EXPECT_GT(s.final_stopping_measure, o.gradient_tolerance);
    EXPECT_LT(s.iterations, 100);
  }
}

// ---------------------------------------------------------------- caps

TEST(Minimizer, MaxIterationsCapIsReported) {
  for (Backend b : kBackends) {
    SCOPED_TRACE(otfp::to_string(b));
    TestObjective obj(2, extended_rosenbrock(2));
    std::vector<double> z = rosenbrock_start(2);
    MinimizerOptions o = make_options(b, Algorithm::Lbfgs, 1e-10);
    o.max_iterations = 5;
    const MinimizerSummary s = otfp::minimize(obj, z, o);
    check_invariants(obj, z, s, o);
    EXPECT_EQ(s.reason, TerminationReason::MaxIterations) << s.message;
    EXPECT_FALSE(s.success);
    EXPECT_EQ(s.iterations, 5);
    EXPECT_LT(s.final_value, s.initial_value);
  }
}

TEST(Minimizer, MaxEvaluationsCapIsReported) {
  // Several caps, so that the cap falls both between iterations and inside a line search.
  for (const Combo& c : kAllCombos) {
    for (int cap = 2; cap <= 12; ++cap) {
      SCOPED_TRACE(label(c.backend, c.algorithm) + " cap " + std::to_string(cap));
      TestObjective obj(2, extended_rosenbrock(2));
      std::vector<double> z = rosenbrock_start(2);
      MinimizerOptions o = make_options(c.backend, c.algorithm, 1e-10);
      o.max_evaluations = cap;
      const MinimizerSummary s = otfp::minimize(obj, z, o);
      check_invariants(obj, z, s, o);
      EXPECT_EQ(s.reason, TerminationReason::MaxEvaluations) << s.message;
      EXPECT_FALSE(s.success);
      EXPECT_LE(obj.calls, cap);
    }
  }
}

TEST(Minimizer, StartPointIsEvaluatedOnce) {
  // The backends re-request the start point; it must come from the cache.
  const Quadratic q(8);
  for (const Combo& c : kAllCombos) {
    SCOPED_TRACE(label(c.backend, c.algorithm));
    const std::vector<double> start(8, 0.1);
    int start_calls = 0;
    const Function f = q.function();
    TestObjective obj(8, [&](const double* z, double* g) {
      if (std::equal(start.begin(), start.end(), z)) ++start_calls;
      return f(z, g);
    });
    std::vector<double> z = start;
    const MinimizerOptions o = make_options(c.backend, c.algorithm, 1e-6);
    const MinimizerSummary s = otfp::minimize(obj, z, o);
    EXPECT_EQ(start_calls, 1);  // before check_invariants, which evaluates f itself
    check_invariants(obj, z, s, o);
    EXPECT_EQ(s.reason, TerminationReason::Converged) << s.message;
  }
}

// ---------------------------------------------------------------- non-finite

TEST(Minimizer, NonFiniteEverywhereButStartKeepsStart) {
  for (const Combo& c : kAllCombos) {
    SCOPED_TRACE(label(c.backend, c.algorithm));
    const Quadratic q(4);
    TestObjective obj(4, q.function());
    const std::vector<double> start(4, 0.25);
    obj.finite = [start](const double* z) { return std::equal(start.begin(), start.end(), z); };
    std::vector<double> z = start;
    const MinimizerOptions o = make_options(c.backend, c.algorithm, 1e-8);
    const MinimizerSummary s = otfp::minimize(obj, z, o);
    check_invariants(obj, z, s, o);
    EXPECT_FALSE(s.success);
    EXPECT_EQ(s.reason, TerminationReason::NonFinite) << otfp::to_string(s.reason) << ": " << s.message;
    EXPECT_EQ(z, start);
    EXPECT_EQ(s.final_value, s.initial_value);
    EXPECT_EQ(s.iterations, 0);
  }
}

TEST(Minimizer, NonFiniteRegionReturnsBestFinitePoint) {
  // The minimiser c lies outside the finite box |z_i| <= 0.5 for some i.
  for (const Combo& c : kAllCombos) {
    SCOPED_TRACE(label(c.backend, c.algorithm));
    const Quadratic q(6);
    TestObjective obj(6, q.function());
    obj.finite = [](const double* z) {
      for (int i = 0; i < 6; ++i)
        if (std::abs(z[i]) > 0.5) return false;
      return true;
    };
    std::vector<double> z(6, 0.0);
    const MinimizerOptions o = make_options(c.backend, c.algorithm, 1e-8);
    const MinimizerSummary s = otfp::minimize(obj, z, o);
    check_invariants(obj, z, s, o);
    EXPECT_FALSE(s.success) << otfp::to_string(s.reason);
    EXPECT_NE(s.reason, TerminationReason::Converged);
    EXPECT_LT(s.final_value, s.initial_value) << "some progress is possible inside the box";
  }
}

TEST(Minimizer, NonFiniteStartLeavesZUnchanged) {
  for (Backend b : kBackends) {
    TestObjective obj(3, extended_rosenbrock(3));
    obj.finite = [](const double*) { return false; };
    std::vector<double> z = {0.1, 0.2, 0.3};
    const MinimizerOptions o = make_options(b, Algorithm::Lbfgs, 1e-8);
    const MinimizerSummary s = otfp::minimize(obj, z, o);
    check_invariants(obj, z, s, o);
    EXPECT_EQ(s.reason, TerminationReason::NonFinite);
    EXPECT_FALSE(s.success);
    EXPECT_EQ(z, (std::vector<double>{0.1, 0.2, 0.3}));
    EXPECT_EQ(s.evaluations, 1);
    EXPECT_EQ(s.iterations, 0);
  }
}

TEST(Minimizer, ObjectiveExceptionPropagatesAndRestoresZ) {
  for (Backend b : kBackends) {
    SCOPED_TRACE(otfp::to_string(b));
    TestObjective obj(2, extended_rosenbrock(2));
    obj.throw_at = 6;
    std::vector<double> z = rosenbrock_start(2);
    const MinimizerOptions o = make_options(b, Algorithm::Lbfgs, 1e-8);
    EXPECT_THROW(otfp::minimize(obj, z, o), std::runtime_error);
    EXPECT_EQ(obj.calls, 6) << "no further calls after the exception";
    EXPECT_EQ(z, rosenbrock_start(2));
  }
}

// ---------------------------------------------------------------- validation

void expect_invalid(const MinimizerOptions& o, const std::string& field) {
  try {
    o.validate();
    ADD_FAILURE() << "validate() accepted a bad " << field;
  } catch (const otfp::InvalidArgument& e) {
    EXPECT_NE(std::string(e.what()).find(field), std::string::npos) << e.what();
  }
}

TEST(Minimizer, ValidateRejectsBadOptions) {
  EXPECT_NO_THROW(MinimizerOptions{}.validate());
  const double nan = std::numeric_limits<double>::quiet_NaN();
  for (double v : {0.0, -1e-6, nan, std::numeric_limits<double>::infinity()}) {
    MinimizerOptions o;
    o.gradient_tolerance = v;
    expect_invalid(o, "gradient_tolerance");
  }
  for (double v : {-0.1, nan}) {
    MinimizerOptions o;
    o.function_tolerance = v;
    expect_invalid(o, "function_tolerance");
  }
  {
    MinimizerOptions o;
    o.max_iterations = 0;
    expect_invalid(o, "max_iterations");
  }
  {
    MinimizerOptions o;
    o.max_evaluations = 0;
    expect_invalid(o, "max_evaluations");
  }
  {
    MinimizerOptions o;
    o.lbfgs_memory = 0;
    expect_invalid(o, "lbfgs_memory");
  }
  for (Algorithm a : {Algorithm::TruncatedNewton, Algorithm::Var2, Algorithm::Mma}) {
    MinimizerOptions o;
    o.backend = Backend::Ceres;
    o.algorithm = a;
    expect_invalid(o, "algorithm");
  }
  for (Algorithm a : {Algorithm::Bfgs, Algorithm::NonlinearCg}) {
    MinimizerOptions o;
    o.backend = Backend::Nlopt;
    o.algorithm = a;
    expect_invalid(o, "algorithm");
  }
  // TAO offers L-BFGS (LMVM) only; where the build has no TAO, the backend itself is refused.
  for (Algorithm a :
       {Algorithm::Bfgs, Algorithm::NonlinearCg, Algorithm::TruncatedNewton, Algorithm::Var2, Algorithm::Mma}) {
    MinimizerOptions o;
    o.backend = Backend::Tao;
    o.algorithm = a;
    expect_invalid(o, otfp::backend_available(Backend::Tao) ? "algorithm" : "backend");
  }
  for (const Combo& c : kAllCombos) EXPECT_NO_THROW(make_options(c.backend, c.algorithm, 1e-6).validate());
}

TEST(Minimizer, MinimizeValidatesOptionsAndSize) {
  const Quadratic q(3);
  TestObjective obj(3, q.function());
  std::vector<double> z(3, 0.0);
  MinimizerOptions o;
  o.max_iterations = 0;
  EXPECT_THROW(otfp::minimize(obj, z, o), otfp::InvalidArgument);
  std::vector<double> wrong(4, 0.0);
  EXPECT_THROW(otfp::minimize(obj, wrong, MinimizerOptions{}), otfp::InvalidArgument);
  EXPECT_EQ(obj.calls, 0);
}

TEST(Minimizer, EnumStringsRoundTrip) {
  for (Backend b : kBackends) EXPECT_EQ(otfp::backend_from_string(otfp::to_string(b)), b);
  for (const Combo& c : kAllCombos) EXPECT_EQ(otfp::algorithm_from_string(otfp::to_string(c.algorithm)), c.algorithm);
  EXPECT_EQ(otfp::to_string(Backend::Nlopt), "nlopt");
  EXPECT_EQ(otfp::to_string(Algorithm::TruncatedNewton), "tnewton");
  EXPECT_EQ(otfp::to_string(Algorithm::NonlinearCg), "nonlinear_cg");
  EXPECT_EQ(otfp::to_string(TerminationReason::MaxEvaluations), "max_evaluations");
  EXPECT_EQ(otfp::to_string(TerminationReason::NonFinite), "non_finite");
  try {
    otfp::backend_from_string("ipopt");
    ADD_FAILURE() << "accepted ipopt";
  } catch (const otfp::InvalidArgument& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find("solver.backend"), std::string::npos) << m;
    EXPECT_NE(m.find("ipopt"), std::string::npos) << m;
    EXPECT_NE(m.find("nlopt"), std::string::npos) << m;
  }
  try {
    otfp::algorithm_from_string("LBFGS");
    ADD_FAILURE() << "accepted LBFGS";
  } catch (const otfp::InvalidArgument& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find("solver.algorithm"), std::string::npos) << m;
    EXPECT_NE(m.find("LBFGS"), std::string::npos) << m;
    EXPECT_NE(m.find("var2"), std::string::npos) << m;
  }
}

TEST(Minimizer, DefaultStoppingMeasureIsMaxNorm) {
  TestObjective obj(3, [](const double*, double*) { return 0.0; });
  const double z[3] = {0, 0, 0};
  const double g[3] = {0.5, -2.0, 1.0};
  EXPECT_DOUBLE_EQ(obj.stopping_measure(z, g), 2.0);
  const double gn[3] = {0.5, std::numeric_limits<double>::quiet_NaN(), 1.0};
  EXPECT_TRUE(std::isnan(obj.stopping_measure(z, gn)));
}

}  // namespace

namespace {

// Ceres logs through glog, which writes warnings (e.g. nonlinear CG restarts)
// to stderr unless told otherwise: a library solve must print nothing.
TEST(Minimizer, CeresSolvesPrintNothingOnStderr) {
  const std::size_t n = 50;
  for (Algorithm a : {Algorithm::NonlinearCg, Algorithm::Lbfgs, Algorithm::Bfgs}) {
    SCOPED_TRACE(label(Backend::Ceres, a));
    for (int variant = 0; variant < 2; ++variant) {
      TestObjective obj(n, extended_rosenbrock(n));
      if (variant == 1) obj.finite = [](const double* z) { return z[0] < 0.0; };  // refuses points beyond
      std::vector<double> z = rosenbrock_start(n);
      MinimizerOptions o = make_options(Backend::Ceres, a, 1e-10);
      o.max_iterations = 300;
      ::testing::internal::CaptureStderr();
      const MinimizerSummary s = otfp::minimize(obj, z, o);
      const std::string printed = ::testing::internal::GetCapturedStderr();
      EXPECT_EQ(printed, "") << "variant " << variant;
      EXPECT_GT(s.iterations, 0);
    }
  }
}

}  // namespace
