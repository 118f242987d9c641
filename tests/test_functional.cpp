// Functional (28): finite-difference gradient checks, accelerated path against
// the O(n^2) sweep and against an independent naive evaluation, the
// single-blob width law and thread-count independence.
#include <gtest/gtest.h>
#include <omp.h>

#include <cmath>
#include <cstdint>
#include <set>
#include <stdexcept>
#include <string>
#include <vector>

#include "otfp/functional.hpp"
#include "otfp/geometry.hpp"
#include "test_support.hpp"
#include "../src/isa.hpp"  // internal: to run each kernel build
#include "../src/pair_kernels.hpp"  // internal: the sweeps' bounds check

using namespace otfp;
using otfp::testing::central_difference;
using otfp::testing::random_cloud;

namespace {

struct Case {
  int dim;
  bool widths;
  WidthMetric metric;
  bool periodic;
};

// Sets up a functional on a random cloud that spills out of a ball (barrier
// active) or lives in a periodic box, with a reference configuration that
// differs from the evaluation point in x and s.
struct Fixture {
  ParticleSet ps;
  std::vector<Vec3> x;
  std::vector<double> s;
  std::unique_ptr<Functional> f;
  DomainPtr domain;
};

Fixture make_fixture(const Case& c, std::size_t n = 60, std::uint64_t seed = 7) {
  Fixture fx;
  const double s0 = 0.25;
  if (c.periodic) {
    fx.domain = make_periodic_box(c.dim, Vec3::Zero(), Vec3::Constant(3.2));
    fx.ps = random_cloud(c.dim, n, 0.0, 3.2, s0, 0.3, 0.02, seed);
  } else {
    fx.domain = make_ball(c.dim, Vec3::Zero(), 1.0);
    fx.ps = random_cloud(c.dim, n, -1.15, 1.15, s0, 0.3, 0.02, seed);  // corners lie outside: barrier active
  }
  FunctionalOptions o;
  o.dt = 0.01;
  o.kappa = 0.7;
  o.rho_ref = 0.3;
  o.width_metric = c.metric;
  o.optimise_widths = c.widths;
  Barrier barrier = c.periodic ? Barrier() : Barrier(fx.domain, 50.0);
  fx.f = std::make_unique<Functional>(c.dim, o, barrier, Periodicity::from_domain(*fx.domain));
  fx.f->set_reference(fx.ps.positions(), fx.ps.widths(), fx.ps.masses());
  Rng rng(seed + 1);
  fx.x = fx.ps.positions();
  fx.s = fx.ps.widths();
  for (auto& p : fx.x)
    for (int k = 0; k < c.dim; ++k) p[k] += 0.05 * rng.normal();
  for (auto& v : fx.s) v *= 1.0 + 0.1 * rng.uniform(-1.0, 1.0);
  return fx;
}

void check_gradient(const Case& c) {
  Fixture fx = make_fixture(c);
  Gradient g;
  fx.f->evaluate(fx.x, fx.s, &g);
  double gmax = 0.0;
  for (const auto& v : g.x) gmax = std::max(gmax, v.cwiseAbs().maxCoeff());
  for (double v : g.s) gmax = std::max(gmax, std::abs(v));
  ASSERT_GT(gmax, 1e-2) << "gradient is trivially zero";
  if (!c.periodic) {
    // The barrier must contribute: some particle is outside the ball.
    double outside = 0.0;
    for (const auto& p : fx.x) outside = std::max(outside, fx.domain->signed_distance(p));
    ASSERT_GT(outside, 0.02);
  }
  const double h = 1e-5;
  const double tol = 1e-6 * gmax;  // scale-aware: relative to the largest gradient entry
  double worst = 0.0;
  for (std::size_t p = 0; p < fx.x.size(); ++p) {
    for (int k = 0; k < c.dim; ++k) {
      auto fk = [&](double e) {
        auto x = fx.x;
        x[p][k] += e;
        return fx.f->evaluate(x, fx.s, nullptr).total();
      };
      const double fd = central_difference(fk, h);
      worst = std::max(worst, std::abs(fd - g.x[p][k]));
      EXPECT_NEAR(g.x[p][k], fd, tol) << "d=" << c.dim << " particle " << p << " axis " << k;
    }
    for (int k = c.dim; k < 3; ++k) EXPECT_EQ(g.x[p][k], 0.0);
    if (c.widths) {
      auto fs = [&](double e) {
        auto s = fx.s;
        s[p] += e;
        return fx.f->evaluate(fx.x, s, nullptr).total();
      };
      const double fd = central_difference(fs, h);
      EXPECT_NEAR(g.s[p], fd, tol) << "width of particle " << p;
    }
  }
  EXPECT_EQ(fx.f->list().build_count(), 1) << "finite differences should not trigger list rebuilds";
}

}  // namespace

TEST(FunctionalGradient, PositionsMatchFiniteDifferences1D) { check_gradient({1, false, WidthMetric::AsPrinted, false}); }
TEST(FunctionalGradient, PositionsMatchFiniteDifferences2D) { check_gradient({2, false, WidthMetric::AsPrinted, false}); }
TEST(FunctionalGradient, PositionsMatchFiniteDifferences3D) { check_gradient({3, false, WidthMetric::AsPrinted, false}); }
TEST(FunctionalGradient, WidthsMatchFiniteDifferences1DExactMetric) {
  check_gradient({1, true, WidthMetric::ExactGaussian, false});
}
TEST(FunctionalGradient, WidthsMatchFiniteDifferences2D) { check_gradient({2, true, WidthMetric::AsPrinted, false}); }
TEST(FunctionalGradient, WidthsMatchFiniteDifferences3DAsPrinted) {
  check_gradient({3, true, WidthMetric::AsPrinted, false});
}
TEST(FunctionalGradient, WidthsMatchFiniteDifferences3DExactMetric) {
  check_gradient({3, true, WidthMetric::ExactGaussian, false});
}
TEST(FunctionalGradient, PeriodicImages2D) { check_gradient({2, true, WidthMetric::AsPrinted, true}); }
TEST(FunctionalGradient, PeriodicImages3D) { check_gradient({3, true, WidthMetric::ExactGaussian, true}); }

TEST(FunctionalTerms, EachTermGradientMatchesFiniteDifferences) {
  const int dim = 3;
  ParticleSet ps = random_cloud(dim, 30, -1.1, 1.1, 0.3, 0.3, 0.05, 11);
  DomainPtr ball = make_ball(dim, Vec3::Zero(), 1.0);
  const auto& x = ps.positions();
  const auto& s = ps.widths();
  const auto& m = ps.masses();
  std::vector<Vec3> xr = x;
  std::vector<double> sr = s;
  for (auto& p : xr) p += Vec3(0.03, -0.02, 0.01);
  for (auto& v : sr) v *= 0.9;
  TransportTerm T(0.02, 1.5);
  EntropyTerm E(dim, 1.3, 0.5);
  BarrierTerm B(Barrier(ball, 20.0));
  NeighborList list;
  list.build(x, s, Periodicity::none(dim));

  Gradient gT, gE, gB;
  gT.resize(x.size(), true);
  gE.resize(x.size(), true);
  gB.resize(x.size(), false);
  T.evaluate(x, s, m, xr, sr, &gT);
  E.evaluate(x, s, m, list, &gE);
  B.evaluate(x, m, &gB);
  const double h = 1e-5;
  for (std::size_t p = 0; p < x.size(); p += 3) {
    for (int k = 0; k < dim; ++k) {
      auto shifted = [&](double e) {
        auto y = x;
        y[p][k] += e;
        return y;
      };
      EXPECT_NEAR(gT.x[p][k], central_difference([&](double e) { return T.evaluate(shifted(e), s, m, xr, sr, nullptr); }, h), 1e-6 * (1 + std::abs(gT.x[p][k])));
      EXPECT_NEAR(gE.x[p][k], central_difference([&](double e) { return E.evaluate(shifted(e), s, m, list, nullptr); }, h), 1e-6 * (1 + std::abs(gE.x[p][k])));
      EXPECT_NEAR(gB.x[p][k], central_difference([&](double e) { return B.evaluate(shifted(e), m, nullptr); }, h), 1e-6 * (1 + std::abs(gB.x[p][k])));
    }
    auto wider = [&](double e) {
      auto t = s;
      t[p] += e;
      return t;
    };
    EXPECT_NEAR(gT.s[p], central_difference([&](double e) { return T.evaluate(x, wider(e), m, xr, sr, nullptr); }, h), 1e-6 * (1 + std::abs(gT.s[p])));
    EXPECT_NEAR(gE.s[p], central_difference([&](double e) { return E.evaluate(x, wider(e), m, list, nullptr); }, h), 1e-6 * (1 + std::abs(gE.s[p])));
  }
}

// The BDF2 form: T = sum_p a_p m_p/(2 dt)(|x - x_ref|^2 + c_w (s - s_ref)^2),
// its value against the sum written out, its gradient against differences.
TEST(FunctionalTerms, WeightedTransportMatchesItsSumAndFiniteDifferences) {
  const int dim = 2;
  ParticleSet ps = random_cloud(dim, 12, -1.0, 1.0, 0.2, 0.3, 0.05, 4);
  const auto& x = ps.positions();
  const auto& s = ps.widths();
  const auto& m = ps.masses();
  std::vector<Vec3> xr = x;
  std::vector<double> sr = s, a(x.size());
  for (std::size_t p = 0; p < x.size(); ++p) {
    xr[p] += Vec3(0.01 * p, -0.02, 0.0);
    sr[p] *= 1.1;
    a[p] = 1.0 + 0.25 * (p % 3);
  }
  const double dt = 0.03, c_w = 1.0;
  TransportTerm T(dt, c_w);
  Gradient g;
  g.resize(x.size(), true);
  double expect = 0.0;
  for (std::size_t p = 0; p < x.size(); ++p)
    expect += a[p] * m[p] / (2 * dt) * ((x[p] - xr[p]).squaredNorm() + c_w * (s[p] - sr[p]) * (s[p] - sr[p]));
  EXPECT_NEAR(T.evaluate(x, s, m, xr, sr, &g, a), expect, 1e-13 * expect);
  const double h = 1e-5;
  for (std::size_t p = 0; p < x.size(); ++p) {
    for (int k = 0; k < dim; ++k) {
      const double fd = central_difference(
          [&](double e) {
            auto y = x;
            y[p][k] += e;
            return T.evaluate(y, s, m, xr, sr, nullptr, a);
          },
          h);
      EXPECT_NEAR(g.x[p][k], fd, 1e-7 * (1 + std::abs(fd)));
    }
    const double fd = central_difference(
        [&](double e) {
          auto t = s;
          t[p] += e;
          return T.evaluate(x, t, m, xr, sr, nullptr, a);
        },
        h);
    EXPECT_NEAR(g.s[p], fd, 1e-7 * (1 + std::abs(fd)));
  }
  // Through the functional: the weights reach the transport part only.
  FunctionalOptions fo;
  fo.dt = dt;
  Functional F(dim, fo);
  F.set_reference(xr, sr, m, a);
  EXPECT_NEAR(F.evaluate_all_pairs(x, s, nullptr).transport, expect, 1e-13 * expect);
  EXPECT_THROW(F.set_reference(xr, sr, m, std::vector<double>(3, 1.0)), InvalidArgument);
}

// Independent naive evaluation of (28) with std::exp and no neighbour list.
double naive_functional(int dim, const ParticleSet& ps, const std::vector<Vec3>& x, const std::vector<double>& s,
                        double dt, double c_w, double kappa, double rho_ref, const Barrier& barrier) {
  double F = 0.0;
  for (std::size_t p = 0; p < x.size(); ++p) {
    const double m = ps.masses()[p];
    F += m / (2 * dt) * ((x[p] - ps.positions()[p]).squaredNorm() + c_w * std::pow(s[p] - ps.widths()[p], 2));
    double rho = 0.0;
    for (std::size_t q = 0; q < x.size(); ++q) {
      const double beta = 1.0 / (s[q] * s[q]);
      rho += ps.masses()[q] * std::pow(beta / M_PI, dim / 2.0) * std::exp(-beta * (x[p] - x[q]).squaredNorm());
    }
    F += kappa * m * std::log(rho / rho_ref);
    F += m * barrier.value(x[p]);
  }
  return F;
}

TEST(FunctionalAccelerated, MatchesAllPairsAndNaiveEvaluation) {
  for (int dim = 1; dim <= 3; ++dim) {
    Fixture fx = make_fixture({dim, true, WidthMetric::ExactGaussian, false}, 400, 21);
    Gradient g_list, g_all;
    const FunctionalParts a = fx.f->evaluate(fx.x, fx.s, &g_list);
    const FunctionalParts b = fx.f->evaluate_all_pairs(fx.x, fx.s, &g_all);
    // The list drops pairs whose kernel is below 1e-8 of its peak.
    const double scale = std::abs(b.entropy) + std::abs(b.transport) + 1.0;
    EXPECT_NEAR(a.total(), b.total(), 1e-7 * scale) << "d=" << dim;
    EXPECT_NEAR(a.entropy, b.entropy, 1e-7 * scale);
    EXPECT_EQ(a.transport, b.transport);
    EXPECT_EQ(a.barrier, b.barrier);
    double gmax = 0.0, diff = 0.0;
    for (std::size_t p = 0; p < fx.x.size(); ++p) {
      gmax = std::max(gmax, g_all.x[p].cwiseAbs().maxCoeff());
      diff = std::max(diff, (g_list.x[p] - g_all.x[p]).cwiseAbs().maxCoeff());
      diff = std::max(diff, std::abs(g_list.s[p] - g_all.s[p]));
    }
    EXPECT_LE(diff, 1e-6 * gmax) << "d=" << dim;
    ASSERT_GT(fx.f->list().num_entries(), 0u);
    EXPECT_LT(fx.f->list().num_entries(), fx.x.size() * (fx.x.size() - 1)) << "list should be a real subset";

    const double c_w = width_metric_coefficient(WidthMetric::ExactGaussian, dim);
    const double naive = naive_functional(dim, fx.ps, fx.x, fx.s, 0.01, c_w, 0.7, 0.3, fx.f->barrier().barrier());
    EXPECT_NEAR(b.total(), naive, 1e-10 * (std::abs(naive) + 1.0)) << "d=" << dim;
  }
}

// The per-pair list radius (the wider blob's cut-off) with a few blobs 3-6x
// wider than the rest, as optimised widths produce: still the O(n^2) result.
TEST(FunctionalAccelerated, MatchesAllPairsWithAFewWideBlobs) {
  for (int dim = 1; dim <= 3; ++dim) {
    for (bool periodic : {false, true}) {
      Fixture fx = make_fixture({dim, true, WidthMetric::ExactGaussian, periodic}, 500, 40 + dim);
      Rng rng(3);
      for (std::size_t p = 0; p < fx.s.size(); p += 13) fx.s[p] *= rng.uniform(3.0, 6.0);
      if (periodic)  // the box must hold twice the widest radius
        for (auto& v : fx.s) v = std::min(v, 0.3);
      Gradient g_list, g_all;
      const FunctionalParts a = fx.f->evaluate(fx.x, fx.s, &g_list);
      const FunctionalParts b = fx.f->evaluate_all_pairs(fx.x, fx.s, &g_all);
      const double scale = std::abs(b.entropy) + std::abs(b.transport) + 1.0;
      EXPECT_NEAR(a.entropy, b.entropy, 1e-7 * scale) << "d=" << dim << " periodic=" << periodic;
      double gmax = 0.0, diff = 0.0;
      for (std::size_t p = 0; p < fx.x.size(); ++p) {
        gmax = std::max({gmax, g_all.x[p].cwiseAbs().maxCoeff(), std::abs(g_all.s[p])});
        diff = std::max(diff, (g_list.x[p] - g_all.x[p]).cwiseAbs().maxCoeff());
        diff = std::max(diff, std::abs(g_list.s[p] - g_all.s[p]));
      }
      EXPECT_LE(diff, 1e-6 * gmax) << "d=" << dim << " periodic=" << periodic;
      EXPECT_LT(fx.f->list().num_entries(), fx.x.size() * (fx.x.size() - 1));
    }
  }
}

TEST(FunctionalAccelerated, ResultsDoNotDependOnThreadCount) {
  // Two identical set-ups, each building its list and evaluating with its own thread count.
  Fixture fx = make_fixture({3, true, WidthMetric::AsPrinted, false}, 3000, 5);
  Fixture fy = make_fixture({3, true, WidthMetric::AsPrinted, false}, 3000, 5);
  const int saved = omp_get_max_threads();
  omp_set_num_threads(1);
  Gradient g1, g2;
  const double f1 = fx.f->evaluate(fx.x, fx.s, &g1).total();
  omp_set_num_threads(2);
  const double f2 = fy.f->evaluate(fy.x, fy.s, &g2).total();
  omp_set_num_threads(saved);
  EXPECT_EQ(fx.f->list().indices(), fy.f->list().indices());
  EXPECT_EQ(f1, f2);
  for (std::size_t p = 0; p < fx.x.size(); ++p) {
    EXPECT_EQ(g1.x[p], g2.x[p]);
    EXPECT_EQ(g1.s[p], g2.s[p]);
  }
}

// A single free blob: dF/ds = 0 gives c_w (s - s^k) s = kappa d dt (docs/method_notes.md#width-metric).
TEST(SingleBlob, BruteForceWidthMinimiserSatisfiesClosedForm) {
  for (int dim = 1; dim <= 3; ++dim) {
    for (WidthMetric metric : {WidthMetric::AsPrinted, WidthMetric::ExactGaussian}) {
      const double sk = 0.2, dt = 0.01, kappa = 0.8;
      ParticleSet ps(dim);
      ps.add(Vec3::Zero(), sk, 1.3);
      FunctionalOptions o;
      o.dt = dt;
      o.kappa = kappa;
      o.width_metric = metric;
      o.optimise_widths = true;
      Functional f(dim, o);
      f.set_reference(ps.positions(), ps.widths(), ps.masses());
      auto F = [&](double s) { return f.evaluate(ps.positions(), {s}, nullptr).total(); };
      // Brute force: scan, then golden-section refinement.
      double best = sk, fbest = F(sk);
      for (int i = 1; i <= 4000; ++i) {
        const double s = sk * (0.5 + 2.5 * i / 4000.0);
        const double v = F(s);
        if (v < fbest) { fbest = v; best = s; }
      }
      double a = best - 2.5 * sk / 4000.0, b = best + 2.5 * sk / 4000.0;
      const double gr = (std::sqrt(5.0) - 1.0) / 2.0;
      for (int it = 0; it < 200; ++it) {
        const double c = b - gr * (b - a), d = a + gr * (b - a);
        if (F(c) < F(d)) b = d; else a = c;
      }
      const double s_star = 0.5 * (a + b);
      const double c_w = width_metric_coefficient(metric, dim);
      EXPECT_NEAR(c_w * (s_star - sk) * s_star, kappa * dim * dt, 1e-6 * kappa * dim * dt)
          << "d=" << dim << " c_w=" << c_w;
      const double root = 0.5 * (sk + std::sqrt(sk * sk + 4.0 * kappa * dim * dt / c_w));
      EXPECT_NEAR(s_star, root, 1e-6 * root);
    }
  }
}

TEST(FunctionalOptions, ValidateNamesTheField) {
  FunctionalOptions o;
  o.dt = 0.0;
  try {
    o.validate();
    FAIL() << "dt = 0 accepted";
  } catch (const InvalidArgument& e) {
    EXPECT_NE(std::string(e.what()).find("dt"), std::string::npos);
  }
  o.dt = 0.1;
  o.kappa = std::nan("");
  EXPECT_THROW(o.validate(), InvalidArgument);
  o.kappa = 1.0;
  o.neighbor.kernel_tolerance = 2.0;
  EXPECT_THROW(o.validate(), InvalidArgument);
}

// Each build of the pair kernels (portable, AVX2/FMA where the CPU has it),
// with equal widths (records carry mc) and unequal ones (records carry beta),
// free and periodic, in 1-3D: the O(n^2) result to within the cut-off's
// tolerance, and the two builds agree to round-off. Rows have all lengths mod
// 8, so the 4- and 8-neighbour groups and the masked tails all run.
TEST(PairKernels, EachBuildMatchesAllPairs) {
  for (int dim = 1; dim <= 3; ++dim) {
    for (bool periodic : {false, true}) {
      for (bool equal_widths : {true, false}) {
        Fixture fx = make_fixture({dim, true, WidthMetric::ExactGaussian, periodic}, 300, 60 + dim);
        if (equal_widths) {
          for (auto& v : fx.s) v = 0.2;
        } else if (periodic) {
          for (auto& v : fx.s) v = std::min(v, 0.3);
        }
        Gradient g_all;
        const FunctionalParts b = fx.f->evaluate_all_pairs(fx.x, fx.s, &g_all);
        std::vector<Gradient> g(2);
        std::vector<FunctionalParts> parts;
        const detail::KernelIsa builds[2] = {detail::KernelIsa::Generic, detail::KernelIsa::Avx2};
        for (int i = 0; i < 2; ++i) {
          detail::set_kernel_isa(builds[i]);
          parts.push_back(fx.f->evaluate(fx.x, fx.s, &g[i]));
          detail::set_kernel_isa(detail::KernelIsa::Auto);
        }
        const std::string where = "d=" + std::to_string(dim) + " periodic=" + std::to_string(periodic) +
                                  " equal widths=" + std::to_string(equal_widths);
        const double scale = std::abs(b.entropy) + 1.0;
        double gmax = 0.0;
        for (std::size_t p = 0; p < fx.x.size(); ++p)
          gmax = std::max({gmax, g_all.x[p].cwiseAbs().maxCoeff(), std::abs(g_all.s[p])});
        for (int i = 0; i < 2; ++i) {
          EXPECT_NEAR(parts[i].entropy, b.entropy, 1e-7 * scale) << where << " build " << i;
          double diff = 0.0, diff_builds = 0.0;
          for (std::size_t p = 0; p < fx.x.size(); ++p) {
            diff = std::max(diff, (g[i].x[p] - g_all.x[p]).cwiseAbs().maxCoeff());
            diff = std::max(diff, std::abs(g[i].s[p] - g_all.s[p]));
            diff_builds = std::max(diff_builds, (g[i].x[p] - g[0].x[p]).cwiseAbs().maxCoeff());
            diff_builds = std::max(diff_builds, std::abs(g[i].s[p] - g[0].s[p]));
          }
          EXPECT_LE(diff, 1e-6 * gmax) << where << " build " << i;
          EXPECT_LE(diff_builds, 1e-12 * gmax) << where << " build " << i;
          EXPECT_NEAR(parts[i].entropy, parts[0].entropy, 1e-13 * scale) << where;
        }
        std::set<std::uint32_t> row_lengths_mod_8;
        const auto& off = fx.f->list().offsets();
        for (std::size_t p = 0; p + 1 < off.size(); ++p) row_lengths_mod_8.insert((off[p + 1] - off[p]) % 8);
        EXPECT_EQ(row_lengths_mod_8.size(), 8u) << where;
      }
    }
  }
}

// The forced build is the one that runs; Auto picks AVX2 exactly when the CPU has it.
TEST(PairKernels, ReportsTheBuildThatRuns) {
  detail::set_kernel_isa(detail::KernelIsa::Generic);
  EXPECT_STREQ(detail::kernel_isa(), "generic");
  EXPECT_FALSE(detail::use_avx2());
  EXPECT_FALSE(detail::use_avx2_fma());
  detail::set_kernel_isa(detail::KernelIsa::Auto);
#if defined(__x86_64__)
  const bool avx2 = __builtin_cpu_supports("avx2"), fma = avx2 && __builtin_cpu_supports("fma");
  EXPECT_STREQ(detail::kernel_isa(), fma ? "avx2+fma" : avx2 ? "avx2" : "generic");
  EXPECT_EQ(detail::use_avx2(), avx2);
  EXPECT_EQ(detail::use_avx2_fma(), fma);
#endif
}

// OTFP_NEIGHBOR_KERNELS=generic, read once at the first kernel call, forces
// the portable build of every kernel; other values leave the CPU's choice.
TEST(PairKernels, EnvironmentOverride) {
  EXPECT_EQ(detail::kernel_isa_from_env("generic"), detail::KernelIsa::Generic);
  EXPECT_EQ(detail::kernel_isa_from_env(nullptr), detail::KernelIsa::Auto);
  EXPECT_EQ(detail::kernel_isa_from_env(""), detail::KernelIsa::Auto);
  EXPECT_EQ(detail::kernel_isa_from_env("avx2"), detail::KernelIsa::Auto);
}

// The sanitizer build's check before each sweep (the AVX2 sweeps run without
// ASan there): a list within the records passes; a neighbour index, a row or
// offsets beyond them are refused, naming the row.
TEST(PairKernels, BoundsCheckRefusesIndicesBeyondTheRecords) {
  const std::vector<std::uint32_t> off{0, 2, 3, 5};
  const std::vector<std::uint32_t> idx{1, 2, 0, 0, 1};
  const std::vector<double> mc(3, 1.0);
  std::vector<double> storage;
  const double* rec = detail::packed_records(storage, 3);
  detail::BlobArrays b{rec, mc.data(), 0.0, 3};
  EXPECT_NO_THROW(detail::check_rows(0, 3, off.data(), idx.data(), b));
  EXPECT_NO_THROW(detail::check_rows(1, 1, off.data(), idx.data(), b));
  std::vector<std::uint32_t> bad = idx;
  bad[3] = 3;  // row 2 lists record 3 of 3
  try {
    detail::check_rows(0, 3, off.data(), bad.data(), b);
    ADD_FAILURE() << "index 3 of 3 records accepted";
  } catch (const std::out_of_range& e) {
    EXPECT_NE(std::string(e.what()).find("row 2 lists neighbour 3"), std::string::npos) << e.what();
  }
  EXPECT_NO_THROW(detail::check_rows(0, 2, off.data(), bad.data(), b));  // row 2 not swept
  b.count = 2;                                                          // rows [0, 3) of 2 records
  EXPECT_THROW(detail::check_rows(0, 3, off.data(), idx.data(), b), std::out_of_range);
  b.count = 3;
  const std::vector<std::uint32_t> down{0, 2, 1, 5};
  EXPECT_THROW(detail::check_rows(0, 3, down.data(), idx.data(), b), std::out_of_range);
}

#if defined(OTFP_SANITIZE_ADDRESS)
// The sanitizer build runs that check before each sweep and ends the process
// with the reason, as an ASan report would (the sweeps run inside OpenMP
// regions, which an exception may not leave).
TEST(PairKernelsDeathTest, SanitizerBuildStopsASweepBeyondTheRecords) {
  const std::vector<std::uint32_t> off{0, 1, 2};
  const std::vector<std::uint32_t> idx{1, 2};  // row 1 lists record 2 of 2
  const std::vector<double> mc(2, 1.0);
  std::vector<double> storage;
  double* rec = detail::packed_records(storage, 2);
  for (int k = 0; k < 8; ++k) rec[k] = 0.0;
  const detail::BlobArrays b{rec, mc.data(), 1.0, 2};
  std::vector<double> out(2);
  EXPECT_DEATH(detail::density_rows(0, 2, off.data(), idx.data(), b, detail::MinimumImage{}, out.data(), out.data(),
                                    out.data(), out.data()),
               "row 1 lists neighbour 2");
}
#endif
