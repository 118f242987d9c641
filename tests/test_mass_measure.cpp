// M_rho: the blob density integrated over Omega (otfp/mass_measure.hpp).
// Every closed form is checked against an independent computation (a
// different integral of the same probability by composite 5-point
// Gauss-Legendre, or Monte Carlo against Domain::contains with a fixed seed and
// a tolerance of 5 standard errors), then the limits, then the generic
// quadrature against the closed forms on the same geometries.
#include <gtest/gtest.h>

#include <Eigen/Geometry>

#include <cmath>
#include <functional>
#include <numbers>

#include "otfp/geometry.hpp"
#include "otfp/mass_measure.hpp"
#include "otfp/particles.hpp"

using namespace otfp;

namespace {

constexpr double kPi = std::numbers::pi;

// Composite 5-point Gauss-Legendre on [a, b] with `panels` panels (hard-coded
// nodes: independent of the library's Golub-Welsch rules).
double integrate(const std::function<double(double)>& f, double a, double b, int panels) {
  static const double x[5] = {-0.9061798459386640, -0.5384693101056831, 0.0, 0.5384693101056831,
                              0.9061798459386640};
  static const double w[5] = {0.2369268850561891, 0.4786286704993665, 0.5688888888888889, 0.4786286704993665,
                              0.2369268850561891};
  const double h = (b - a) / panels;
  double sum = 0.0;
  for (int j = 0; j < panels; ++j) {
    const double mid = a + (j + 0.5) * h;
    for (int i = 0; i < 5; ++i) sum += 0.5 * h * w[i] * f(mid + 0.5 * h * x[i]);
  }
  return sum;
}

// Monte Carlo: fraction of N(x, s^2/2 I) samples with contains(); returns the
// estimate and its standard error.
std::pair<double, double> monte_carlo(const Domain& dom, const Vec3& x, double s, int samples, std::uint64_t seed) {
  Rng rng(seed);
  const double sigma = s / std::sqrt(2.0);
  long hits = 0;
  for (int i = 0; i < samples; ++i) {
    Vec3 y = x;
    for (int k = 0; k < dom.dim(); ++k) y[k] += sigma * rng.normal();
    if (dom.contains(y)) ++hits;
  }
  const double p = static_cast<double>(hits) / samples;
  return {p, std::sqrt(std::max(p * (1.0 - p), 1.0 / samples) / samples)};
}

// 1-D Gaussian density of width s (variance s^2/2).
double phi(double u, double s) { return std::exp(-u * u / (s * s)) / (s * std::sqrt(kPi)); }

}  // namespace

TEST(MassMeasure, IntervalAndBoxAgainstQuadratureOfTheDensity) {
  const double s = 0.13;
  for (double x : {-0.5, -0.1, 0.0, 0.05, 0.37, 0.5, 0.93, 1.0, 1.2, 1.9}) {
    const double ref = integrate([&](double y) { return phi(y - x, s); }, 0.0, 1.0, 400);
    EXPECT_NEAR(gaussian_in_interval(x, s, 0.0, 1.0), ref, 1e-13) << x;
  }
  // Tails: relative accuracy (erfc forms) far outside.
  const double far = gaussian_in_interval(3.0, 0.2, 0.0, 1.0);  // 10 s outside
  EXPECT_GT(far, 0.0);
  EXPECT_NEAR(far, 0.5 * (std::erfc(10.0) - std::erfc(15.0)), 1e-14 * far);
  // 3-D box: a tensor quadrature of the density over the box.
  const Vec3 lo(0.0, -0.2, 0.1), hi(1.0, 0.3, 0.4);
  for (const Vec3& x : {Vec3(0.5, 0.0, 0.25), Vec3(0.02, 0.29, 0.12), Vec3(-0.1, 0.35, 0.45), Vec3(1.05, 0.0, 0.2)}) {
    double ref = 1.0;
    for (int k = 0; k < 3; ++k) ref *= integrate([&](double y) { return phi(y - x[k], s); }, lo[k], hi[k], 300);
    EXPECT_NEAR(gaussian_in_box(3, x, s, lo, hi), ref, 1e-13);
  }
}

TEST(MassMeasure, BoxAgainstMonteCarloOfTheDomain) {
  const DomainPtr box = make_box(3, Vec3(0, 0, 0), Vec3(1.0, 0.5, 0.7));
  const double s = 0.1;
  for (const Vec3& x : {Vec3(0.03, 0.02, 0.35), Vec3(0.98, 0.51, 0.69), Vec3(-0.05, 0.25, 0.3)}) {
    const auto [p, se] = monte_carlo(*box, x, s, 200000, 17);
    EXPECT_NEAR(blob_fraction_in_domain(*box, x, s), p, 5.0 * se) << x.transpose();
  }
}

// The 3-D ball: the closed form against the same probability written as an
// integral along the axis through the blob centre (the disc of radius
// sqrt(R^2 - z^2) is centred on the blob's axis, where a 2-D Gaussian gives
// 1 - exp(-rho^2/s^2)).
TEST(MassMeasure, BallThreeDClosedFormAgainstAxialIntegral) {
  const double R = 1.0;
  for (double s : {0.05, 0.2, 0.7}) {
    for (double r0 : {0.0, 1e-9, 1e-4, 0.3, 0.9, 0.97, 1.0, 1.02, 1.1, 1.5}) {
      const double ref = integrate(
          [&](double z) { return phi(z - r0, s) * (1.0 - std::exp(-(R * R - z * z) / (s * s))); }, -R, R, 2000);
      EXPECT_NEAR(gaussian_in_ball(3, r0, s, R), ref, 1e-12) << "s " << s << " r0 " << r0;
    }
  }
  // r0 -> 0 is continuous (the limit branch agrees with tiny r0).
  EXPECT_NEAR(gaussian_in_ball(3, 0.0, 0.4, 1.0), gaussian_in_ball(3, 1e-12, 0.4, 1.0), 1e-14);
  // Monte Carlo against the domain itself, off-centre ball.
  const DomainPtr ball = make_ball(3, Vec3(0.2, -0.1, 0.3), 0.8);
  const Vec3 x(0.2 + 0.75, -0.1, 0.3 + 0.1);
  const auto [p, se] = monte_carlo(*ball, x, 0.15, 200000, 5);
  EXPECT_NEAR(blob_fraction_in_domain(*ball, x, 0.15), p, 5.0 * se);
}

// The 2-D disc: radial quadrature with the Bessel kernel against the
// probability sliced along the other axis (y = R sin(theta) removes the
// square-root end points).
TEST(MassMeasure, DiscQuadratureAgainstSlicedIntegral) {
  const double R = 1.0;
  double worst = 0.0;
  for (double s : {0.01, 0.05, 0.2, 0.7}) {
    for (double r0 : {0.0, 0.01, 0.3, 0.9, 0.97, 0.999, 1.0, 1.03, 1.1, 1.5}) {
      const double ref = integrate(
          [&](double th) {
            const double y = R * std::sin(th), c = R * std::cos(th);
            return phi(y, s) * 0.5 * (std::erf((c - r0) / s) - std::erf((-c - r0) / s)) * c;
          },
          -0.5 * kPi, 0.5 * kPi, 4000);
      const double got = gaussian_in_disc(r0, s, R);
      worst = std::max(worst, std::abs(got - ref));
      EXPECT_NEAR(got, ref, 1e-11) << "s " << s << " r0 " << r0;
    }
  }
  RecordProperty("disc_max_abs_error", std::to_string(worst));
  // Through the domain: a disc not at the origin, d = 2 ball.
  const DomainPtr disc = make_ball(2, Vec3(0.5, 0.5, 0.0), 0.4);
  const Vec3 x(0.5 + 0.3, 0.5 + 0.25, 0.0);
  const auto [p, se] = monte_carlo(*disc, x, 0.1, 200000, 9);
  EXPECT_NEAR(blob_fraction_in_domain(*disc, x, 0.1), p, 5.0 * se);
  // d = 1 ball is the interval.
  const DomainPtr seg = make_ball(1, Vec3(0.3, 0, 0), 0.5);
  EXPECT_DOUBLE_EQ(blob_fraction_in_domain(*seg, Vec3(0.7, 0, 0), 0.1), gaussian_in_interval(0.7, 0.1, -0.2, 0.8));
}

TEST(MassMeasure, BesselI0ScaledAgainstStandardLibrary) {
  for (double z : {0.0, 1e-3, 0.5, 3.0, 10.0, 19.9, 20.0, 20.1, 35.0, 100.0, 400.0, 700.0}) {
    const double ref = std::cyl_bessel_i(0.0, z) * std::exp(-z);
    EXPECT_NEAR(bessel_i0_scaled(z), ref, 1e-14 * ref) << z;
  }
}

TEST(MassMeasure, CylinderAgainstMonteCarloOfTheDomain) {
  const Vec3 a(0.1, -0.2, 0.3), b(1.1, 0.5, -0.1);  // oblique axis
  const double R = 0.35;
  const DomainPtr cyl = make_cylinder(a, b, R);
  const Vec3 u = (b - a).normalized();
  Vec3 perp = u.cross(Vec3::UnitZ()).normalized();
  for (const Vec3& x : {Vec3(a + 0.5 * (b - a) + 0.3 * perp), Vec3(a + 0.02 * u + 0.33 * perp),
                        Vec3(b + 0.05 * u + 0.1 * perp), Vec3(a + 0.4 * (b - a))}) {
    const auto [p, se] = monte_carlo(*cyl, x, 0.12, 200000, 23);
    EXPECT_NEAR(blob_fraction_in_domain(*cyl, x, 0.12), p, 5.0 * se) << x.transpose();
  }
}

TEST(MassMeasure, Limits) {
  const DomainPtr box = make_box(3, Vec3(0, 0, 0), Vec3(1, 1, 1));
  const double s = 0.01;
  EXPECT_DOUBLE_EQ(blob_fraction_in_domain(*box, Vec3(0.5, 0.5, 0.5), s), 1.0);
  EXPECT_EQ(blob_fraction_in_domain(*box, Vec3(1.5, 0.5, 0.5), s), 0.0);
  EXPECT_NEAR(blob_fraction_in_domain(*box, Vec3(1.0, 0.5, 0.5), s), 0.5, 1e-15);  // centre on a face
  EXPECT_NEAR(blob_fraction_in_domain(*box, Vec3(1.0, 0.0, 1.0), s), 0.125, 1e-15);  // corner
  EXPECT_NEAR(blob_fraction_in_domain(*box, Vec3(0.0, 0.0, 0.5), s), 0.25, 1e-15);   // edge
  const DomainPtr ball = make_ball(3, Vec3::Zero(), 1.0);
  EXPECT_NEAR(blob_fraction_in_domain(*ball, Vec3::Zero(), s), 1.0, 1e-15);
  EXPECT_EQ(blob_fraction_in_domain(*ball, Vec3(3, 0, 0), s), 0.0);
  // On a curved face: 1/2 minus a curvature correction of order s/R.
  const double on = blob_fraction_in_domain(*ball, Vec3(0, 1, 0), s);
  EXPECT_LT(on, 0.5);
  EXPECT_NEAR(on, 0.5, 0.01);
  const DomainPtr disc = make_ball(2, Vec3::Zero(), 1.0);
  EXPECT_NEAR(blob_fraction_in_domain(*disc, Vec3(0, 1, 0), 1e-3), 0.5, 1e-3);
  EXPECT_NEAR(blob_fraction_in_domain(*disc, Vec3::Zero(), s), 1.0, 1e-15);
  EXPECT_EQ(blob_fraction_in_domain(*disc, Vec3(2, 0, 0), s), 0.0);
  const DomainPtr cyl = make_cylinder(Vec3::Zero(), Vec3(2, 0, 0), 0.5);
  EXPECT_NEAR(blob_fraction_in_domain(*cyl, Vec3(2, 0, 0), s), 0.5, 1e-15);          // centre of a cap
  EXPECT_NEAR(blob_fraction_in_domain(*cyl, Vec3(2, 0.5, 0), 1e-4), 0.25, 1e-4);     // on the rim
  EXPECT_NEAR(blob_fraction_in_domain(*cyl, Vec3(1, 0, 0), s), 1.0, 1e-15);
}

TEST(MassMeasure, DomainsAndParticleSets) {
  ParticleSet ps(3);
  ps.add(Vec3(0.5, 0.5, 0.5), 0.05, 2.0);
  ps.add(Vec3(1.0, 0.5, 0.5), 0.05, 1.0);   // on a face: half
  ps.add(Vec3(3.0, 0.5, 0.5), 0.05, 4.0);   // far outside
  const DomainPtr box = make_box(3, Vec3(0, 0, 0), Vec3(1, 1, 1));
  EXPECT_EQ(blob_mass_method(*box), BlobMassMethod::ClosedForm);
  EXPECT_NEAR(blob_mass_in_domain(*box, ps), 2.5, 1e-14);
  const std::vector<double> f = blob_fractions_in_domain(*box, ps);
  ASSERT_EQ(f.size(), 3u);
  EXPECT_NEAR(f[1], 0.5, 1e-15);
  // Sub-patches do not change Omega: the base's closed form.
  const DomainPtr sub = make_with_subpatches(box, {SubPatch{1, Vec3(1.0, 0.5, 0.5), 0.2, "outlet"}});
  EXPECT_EQ(blob_mass_method(*sub), BlobMassMethod::ClosedForm);
  EXPECT_EQ(blob_mass_in_domain(*sub, ps), blob_mass_in_domain(*box, ps));
  // Periodic: every blob counts fully.
  const DomainPtr per = make_periodic_box(3, Vec3(0, 0, 0), Vec3(1, 1, 1));
  EXPECT_EQ(blob_mass_method(*per), BlobMassMethod::Total);
  EXPECT_DOUBLE_EQ(blob_mass_in_domain(*per, ps), 7.0);
  // CSG: the quadrature.
  const DomainPtr csg = make_difference(box, make_ball(3, Vec3(0.5, 0.5, 0.5), 0.2));
  EXPECT_EQ(blob_mass_method(*csg), BlobMassMethod::Quadrature);
  // The first blob sits at the centre of the hole: only its tail beyond r = 0.2
  // (1e-6 of it) is inside. Lines through the hole cross the wall twice; both
  // crossings count. The tangential rule resolves the rim of the hole (where
  // the chord vanishes like a square root) to about 15% of this tiny tail.
  const double tail = 1.0 - gaussian_in_ball(3, 0.0, 0.05, 0.2);
  EXPECT_NEAR(blob_mass_in_domain(*csg, ps), 0.5 + 2.0 * tail, 0.2 * 2.0 * tail);
  // Next to the hole's wall (concave for Omega): 1 - P(ball), about 1e-3 on O(1) fractions.
  BlobMassOptions quad;
  quad.force_quadrature = true;
  for (double r : {0.17, 0.2, 0.23, 0.3}) {
    const double exact = 1.0 - gaussian_in_ball(3, r, 0.05, 0.2);
    EXPECT_NEAR(blob_fraction_in_domain(*csg, Vec3(0.5 + r, 0.5, 0.5), 0.05), exact, 2e-3) << r;
  }
  EXPECT_EQ(to_string(BlobMassMethod::ClosedForm), "closed_form");
  BlobMassOptions bad;
  bad.hermite_nodes = 0;
  EXPECT_THROW(blob_mass_in_domain(*box, ps, bad), InvalidArgument);
  EXPECT_THROW(blob_fraction_in_domain(*box, Vec3(0.5, 0.5, 0.5), 0.0), InvalidArgument);
}

// The generic quadrature against the closed forms on the same geometry, for
// blob centres spread over the band |sd| < r_c.
TEST(MassMeasure, QuadratureAgainstClosedForms) {
  BlobMassOptions quad;
  quad.force_quadrature = true;
  struct Case {
    const char* name;
    DomainPtr dom;
    double s;
    double max_tol, mean_tol;
  };
  const std::vector<Case> cases = {
      // Smooth walls: round-off (measured max 2.6e-14 interval, 3.5e-15 disc and ball).
      {"interval", make_box(1, Vec3(0, 0, 0), Vec3(1, 0, 0)), 0.05, 1e-12, 1e-13},
      {"disc", make_ball(2, Vec3(0.1, 0.2, 0), 1.0), 0.05, 1e-12, 1e-13},
      {"ball", make_ball(3, Vec3::Zero(), 1.0), 0.05, 1e-12, 1e-13},
      // Rims, edges and corners: normal lines parallel to the other face make
      // the tangential integrand jump (measured max 2.6e-2 / 6.3e-2 / 6.3e-2,
      // mean over the band 2.8e-4 / 8.1e-4 / 9.5e-4).
      {"cylinder", make_cylinder(Vec3::Zero(), Vec3(0, 0, 2), 0.5), 0.05, 4e-2, 5e-4},
      {"square", make_box(2, Vec3(0, 0, 0), Vec3(1, 1, 0)), 0.05, 8e-2, 1.5e-3},
      {"box", make_box(3, Vec3(0, 0, 0), Vec3(1, 1, 1)), 0.05, 8e-2, 1.5e-3},
  };
  for (const Case& c : cases) {
    Rng rng(99);
    const Aabb bb = c.dom->bounding_box();
    double worst = 0.0, sum = 0.0;
    int n = 0;
    while (n < 400) {
      Vec3 x = Vec3::Zero();
      for (int k = 0; k < c.dom->dim(); ++k) x[k] = rng.uniform(bb.lo[k] - 0.3, bb.hi[k] + 0.3);
      if (std::abs(c.dom->signed_distance(x)) > 6.1 * c.s) continue;
      const double e = std::abs(blob_fraction_in_domain(*c.dom, x, c.s, quad) - blob_fraction_in_domain(*c.dom, x, c.s));
      worst = std::max(worst, e);
      sum += e;
      ++n;
    }
    EXPECT_LT(worst, c.max_tol) << c.name;
    EXPECT_LT(sum / n, c.mean_tol) << c.name;
    RecordProperty(std::string(c.name) + "_max", std::to_string(worst));
    std::printf("quadrature vs closed form, %-8s: max %.2e mean %.2e\n", c.name, worst, sum / n);
  }
  // A half-space is exact: the face of a large box, away from its edges.
  const DomainPtr big = make_box(3, Vec3(0, 0, 0), Vec3(10, 10, 10));
  for (double dx : {-0.2, -0.05, 0.0, 0.03, 0.2})
    EXPECT_NEAR(blob_fraction_in_domain(*big, Vec3(10.0 + dx, 5, 5), 0.05, quad),
                gaussian_in_interval(10.0 + dx, 0.05, 0.0, 10.0), 1e-12);
}
