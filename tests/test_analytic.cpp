#include <gtest/gtest.h>

#include <cmath>

#include "otfp/analytic.hpp"

using namespace otfp::analytic;

TEST(Analytic, CrankSphereKnownValue) {
  EXPECT_NEAR(crank_sphere_uptake(0.25), 0.9484368978658284, 1e-15);
  EXPECT_EQ(crank_sphere_uptake(0.0), 0.0);
  EXPECT_NEAR(crank_sphere_uptake(50.0), 1.0, 1e-15);
}

TEST(Analytic, CrankSlabKnownValue) {
  EXPECT_NEAR(crank_slab_uptake(0.25), 0.5622335417621369, 1e-15);
  EXPECT_NEAR(crank_slab_uptake(200.0), 1.0, 1e-15);
}

TEST(Analytic, ShortTimeFormsJoinTheSeries) {
  // Both forms at the switch-over point, computed independently.
  const double tau = 1.0001e-6;  // just above the switch: the series is used
  EXPECT_NEAR(crank_sphere_uptake(tau), 6.0 * std::sqrt(tau / M_PI) - 3.0 * tau, 1e-12);
  EXPECT_NEAR(crank_slab_uptake(tau), 2.0 * std::sqrt(tau / M_PI), 1e-12);
  // Monotone increase.
  double prev = 0.0;
  for (double t = 1e-7; t < 2.0; t *= 1.3) {
    const double m = crank_sphere_uptake(t);
    EXPECT_GT(m, prev);
    prev = m;
  }
}

TEST(Analytic, FreeSpaceAndCosineMode) {
  EXPECT_DOUBLE_EQ(free_space_variance_growth(0.5, 3.0), 3.0);
  EXPECT_NEAR(cosine_mode_decay(1.0, 2.0 * M_PI, 0.01), std::exp(-0.04 * M_PI * M_PI), 1e-16);
}

namespace {
// Composite Simpson rule over [a, b] with an even number of intervals.
template <class F>
double simpson(F f, double a, double b, int intervals) {
  const double h = (b - a) / intervals;
  double s = f(a) + f(b);
  for (int i = 1; i < intervals; ++i) s += (i % 2 ? 4.0 : 2.0) * f(a + i * h);
  return s * h / 3.0;
}

// Crank 6.18: radial profile of the sphere held at g = 1 on r = R = 1.
double sphere_profile(double r, double tau) {
  double s = 0.0;
  for (int n = 1; n < 20000; ++n) {
    const double e = std::exp(-n * n * M_PI * M_PI * tau);
    s += ((n % 2) ? -1.0 : 1.0) / n * std::sin(n * M_PI * r) * e;
    if (e < 1e-18) break;
  }
  return 1.0 + 2.0 / (M_PI * r) * s;
}
}  // namespace

// The polar-inertia series against the radial profile integrated numerically,
// and the profile's mass against the uptake series (which checks the profile).
TEST(Analytic, CrankSpherePolarInertiaMatchesTheIntegratedProfile) {
  EXPECT_EQ(crank_sphere_polar_inertia(0.0), 0.0);
  EXPECT_NEAR(crank_sphere_polar_inertia(50.0), 1.0, 1e-15);
  for (double tau : {0.01, 0.05, 0.25, 1.0}) {
    const double mass = simpson([&](double r) { return 3.0 * r * r * sphere_profile(r, tau); }, 1e-9, 1.0, 4000);
    EXPECT_NEAR(mass, crank_sphere_uptake(tau), 1e-7) << "tau = " << tau;
    const double j = simpson([&](double r) { return 5.0 * std::pow(r, 4) * sphere_profile(r, tau); }, 1e-9, 1.0, 4000);
    EXPECT_NEAR(crank_sphere_polar_inertia(tau), j, 1e-7) << "tau = " << tau;
  }
}

// The slab profile integrates to the uptake series; held face at 1; filled
// at late times.
TEST(Analytic, CrankSlabDensityIntegratesToTheUptake) {
  for (double tau : {0.01, 0.05, 0.25, 1.0}) {
    const double mass = simpson([&](double x) { return crank_slab_density(tau, x); }, 0.0, 1.0, 2000);
    EXPECT_NEAR(mass, crank_slab_uptake(tau), 1e-8) << "tau = " << tau;
    EXPECT_EQ(crank_slab_density(tau, 0.0), 1.0);
  }
  EXPECT_NEAR(crank_slab_density(100.0, 1.0), 1.0, 1e-15);
  EXPECT_NEAR(crank_slab_density(1e-3, 1.0), 0.0, 1e-12);  // the far face is still empty
}
