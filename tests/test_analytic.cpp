#include <gtest/gtest.h>

#include <cmath>

#include "otfp/analytic.hpp"
#include "otfp/diagnostics.hpp"
#include "otfp/types.hpp"

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

// Below tau = 1e-6 the uptakes switch from Crank's series to the short-time
// forms (the series would need ~1/sqrt(tau) terms): the sphere's
// 6 sqrt(tau/pi) - 3 tau (Crank 6.21) and the slab's 2 sqrt(tau/pi) (Crank
// 4.20, the semi-infinite solid). Each branch has its value, and the two join
// continuously across the switch (their difference there, ~exp(-1/tau), is
// far below double precision).
TEST(Analytic, ShortTimeBranchesHaveTheirValueAndJoinContinuously) {
  for (double tau : {1e-12, 3.7e-9, 2.5e-7, 9.9e-7}) {
    const double sphere = 6.0 * std::sqrt(tau / M_PI) - 3.0 * tau;
    const double slab = 2.0 * std::sqrt(tau / M_PI);
    EXPECT_NEAR(crank_sphere_uptake(tau), sphere, 1e-15 * sphere) << tau;
    EXPECT_NEAR(crank_slab_uptake(tau), slab, 1e-15 * slab) << tau;
  }
  // (The sphere's -3 tau is 0.04 % of the value at tau = 2.5e-7: the
  // tolerance above, 1e-15 relative, sees it many times over.)
  // Across the switch: tau just below and at 1e-6 (the series), where the
  // values' slope is 3/sqrt(pi tau) ~ 1.7e3 (sphere) and 1.1e3 (slab).
  const double below = std::nextafter(1e-6, 0.0), at = 1e-6;
  EXPECT_NEAR(crank_sphere_uptake(below), crank_sphere_uptake(at), 1e-13);
  EXPECT_NEAR(crank_slab_uptake(below), crank_slab_uptake(at), 1e-13);
  // And the series at the switch is the short-time form (Crank 6.21: the
  // remainder is of order exp(-1/tau)).
  EXPECT_NEAR(crank_sphere_uptake(at), 6.0 * std::sqrt(at / M_PI) - 3.0 * at, 1e-13);
  EXPECT_NEAR(crank_slab_uptake(at), 2.0 * std::sqrt(at / M_PI), 1e-13);
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

TEST(Analytic, SlabPolarInertiaTendsToTheUniformBox) {
  // Late times: rho = g everywhere, so J = M_inf times the second moment of
  // the uniform box about the centre, (w^2/12 + offset^2) summed over the axes.
  SlabBox slab;
  slab.dim = 3;
  slab.lo = otfp::Vec3(0.0, -1.0, 0.0);
  slab.hi = otfp::Vec3(2.0, 1.0, 0.5);
  slab.axis = 0;
  slab.length = 2.0;
  slab.center = otfp::Vec3(0.3, 0.0, 0.1);
  slab.M_inf = 4.0;
  double second = 0.0;
  for (int k = 0; k < 3; ++k) {
    const double w = slab.hi[k] - slab.lo[k], off = 0.5 * (slab.hi[k] + slab.lo[k]) - slab.center[k];
    second += w * w / 12.0 + off * off;
  }
  EXPECT_NEAR(crank_slab_polar_inertia(200.0, slab), slab.M_inf * second, 1e-12);
  EXPECT_EQ(crank_slab_polar_inertia(0.0, slab), 0.0);
  // Held at hi instead: the mirror image about the box centre along the axis.
  SlabBox mirrored = slab;
  mirrored.held_at_hi = true;
  mirrored.center[0] = 2.0 - slab.center[0];
  EXPECT_NEAR(crank_slab_polar_inertia(0.1, mirrored), crank_slab_polar_inertia(0.1, slab), 1e-12);
  // At an intermediate time, against a fine midpoint rule of the profile
  // (another quadrature than the function's Simpson rule).
  const double transverse = second - (slab.length * slab.length / 12.0 + (1.0 - slab.center[0]) * (1.0 - slab.center[0]));
  const int m = 20000;
  double integral = 0.0;
  for (int i = 0; i < m; ++i) {
    const double depth = (i + 0.5) / m, x = slab.lo[0] + depth * slab.length;
    const double dx = x - slab.center[0];
    integral += crank_slab_density(0.1, depth) * (dx * dx + transverse);
  }
  EXPECT_NEAR(crank_slab_polar_inertia(0.1, slab), slab.M_inf * integral / m, 1e-7);
}

TEST(Analytic, TimeDiscreteRates) {
  const double lambda = 3.0, dt = 0.2, z = lambda * dt;
  EXPECT_NEAR(time_discrete_rate(otfp::TimeScheme::Euler, lambda, dt), std::log(1.0 + z) / dt, 1e-14);
  // BDF2's factor is the root of (3/2 + z) g^2 - 2 g + 1/2 = 0 in (0, 1) (z = 0.3 here).
  const double g = std::exp(-time_discrete_rate(otfp::TimeScheme::Bdf2, lambda, 0.1) * 0.1);
  EXPECT_NEAR((1.5 + 0.3) * g * g - 2.0 * g + 0.5, 0.0, 1e-14);
  EXPECT_GT(g, 0.5);  // the principal root, not the parasitic one
  // Past z = 1/2 the roots are a complex pair of modulus sqrt(product) = (3 + 2 z)^-1/2.
  EXPECT_NEAR(time_discrete_rate(otfp::TimeScheme::Bdf2, lambda, 1.0), 0.5 * std::log(3.0 + 2.0 * lambda), 1e-14);
  EXPECT_NEAR(time_discrete_rate(otfp::ExplicitScheme::EulerForce27, lambda, 0.1), -std::log(1.0 - 0.3) / 0.1, 1e-13);
  EXPECT_EQ(time_discrete_rate(otfp::ExplicitScheme::EulerExactGradient, lambda, 1.0), HUGE_VAL);  // 1 - z < 0
  // Consistency: every scheme tends to lambda as dt -> 0, RK4 to fourth order.
  EXPECT_NEAR(time_discrete_rate(otfp::ExplicitScheme::Rk4Force27, lambda, 1e-3), lambda, 1e-9);
  EXPECT_NEAR(time_discrete_rate(otfp::TimeScheme::Bdf2, lambda, 1e-4), lambda, 1e-6);
  EXPECT_THROW(time_discrete_rate(otfp::TimeScheme::Euler, lambda, 0.0), otfp::InvalidArgument);
}

TEST(Diagnostics, CosineAmplitudeOfALatticeIsExact) {
  // N equispaced point blobs with masses 1 + a cos(k x): by discrete
  // orthogonality sum cos^2 = N/2 and sum cos = 0, so the amplitude is a.
  // Widths s damp it by exp(-k^2 s^2 / 4).
  const int N = 64;
  const double a = 0.3, k = 2.0 * M_PI / 2.0, x0 = -1.0, s = 0.05;
  otfp::ParticleSet ps(1);
  for (int j = 0; j < N; ++j) {
    const double x = x0 + 2.0 * j / N;
    ps.add(otfp::Vec3(x, 0.0, 0.0), s, 1.0 + a * std::cos(k * (x - x0)));
  }
  EXPECT_NEAR(otfp::cosine_mode_amplitude(ps, k, x0), a * std::exp(-0.25 * k * k * s * s), 1e-14);
  EXPECT_EQ(otfp::cosine_mode_amplitude(otfp::ParticleSet(1), k, x0), 0.0);
}

TEST(Diagnostics, BlobSecondMomentAddsEachBlobsVariance) {
  // One blob at the centre: its Gaussian's variance d s^2 / 2 times m; moving
  // it by r adds m r^2.
  otfp::ParticleSet ps(3);
  ps.add(otfp::Vec3(1.0, 2.0, 3.0), 0.4, 2.0);
  const otfp::Vec3 c(1.0, 2.0, 3.0);
  EXPECT_NEAR(otfp::blob_second_moment(ps, c), 2.0 * 1.5 * 0.16, 1e-15);
  EXPECT_NEAR(otfp::blob_second_moment(ps, c + otfp::Vec3(0.0, 3.0, 4.0)), 2.0 * (25.0 + 1.5 * 0.16), 1e-13);
}
