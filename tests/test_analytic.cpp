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
