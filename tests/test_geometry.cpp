#include "otfp/geometry.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <numbers>
#include <string>
#include <vector>

using namespace otfp;

namespace {

constexpr double kPi = std::numbers::pi;

void expect_vec_near(const Vec3& got, const Vec3& want, double tol) {
  EXPECT_NEAR((got - want).norm(), 0.0, tol) << "got (" << got.transpose() << "), want (" << want.transpose()
                                             << ")";
}

// Checks sd, closest point and patch of one query.
void expect_query(const Domain& d, const Vec3& x, double sd, const Vec3& cp, int patch, double tol = 1e-12) {
  const BoundaryQuery q = d.query(x);
  EXPECT_NEAR(q.signed_distance, sd, tol) << "at (" << x.transpose() << ")";
  expect_vec_near(q.closest_point, cp, tol);
  EXPECT_EQ(q.patch, patch) << "at (" << x.transpose() << ")";
}

// Binomial fraction check: |hits/n - p| <= 3 sigma.
void expect_fraction(int hits, int n, double p) {
  const double sigma = std::sqrt(p * (1.0 - p) / n);
  EXPECT_NEAR(static_cast<double>(hits) / n, p, 3.0 * sigma) << "hits " << hits << " of " << n;
}

// Tolerance for a Monte Carlo volume v of a cell inside a box of measure vb
// estimated with n samples: 4 standard deviations.
double mc_tolerance(double v, double vb, int n) {
  const double p = v / vb;
  return 4.0 * vb * std::sqrt(p * (1.0 - p) / n);
}

double box_measure(const Aabb& b, int dim) {
  double v = 1.0;
  for (int k = 0; k < dim; ++k) v *= b.hi[k] - b.lo[k];
  return v;
}

// The square pipe of the example: [0,4]x[0,1]x[0,1] minus a cylinder along z
// through (2, 0.5), radius 0.2, sticking out of both z faces.
DomainPtr pipe_with_obstacle() {
  return make_difference(make_box(3, Vec3(0, 0, 0), Vec3(4, 1, 1)),
                         make_cylinder(Vec3(2, 0.5, -0.1), Vec3(2, 0.5, 1.1), 0.2));
}

}  // namespace

// --------------------------------------------------------------------------- Ball

TEST(Ball, SignedDistanceAndClosestPoint3D) {
  const auto ball = make_ball(3, Vec3(1, 2, 3), 2.0);
  expect_query(*ball, Vec3(1, 2, 3.5), -1.5, Vec3(1, 2, 5), 0);
  expect_query(*ball, Vec3(4, 6, 3), 3.0, Vec3(1 + 1.2, 2 + 1.6, 3), 0);
  expect_query(*ball, Vec3(1, 0, 3), 0.0, Vec3(1, 0, 3), 0);
  // At the centre the closest point is some boundary point.
  const BoundaryQuery q = ball->query(Vec3(1, 2, 3));
  EXPECT_DOUBLE_EQ(q.signed_distance, -2.0);
  EXPECT_NEAR((q.closest_point - Vec3(1, 2, 3)).norm(), 2.0, 1e-12);
  EXPECT_TRUE(ball->contains(Vec3(2, 3, 4)));
  EXPECT_FALSE(ball->contains(Vec3(2.2, 3.2, 4.2)));
  EXPECT_EQ(ball->patch_name(0), "surface");
  EXPECT_EQ(ball->patch_by_name("surface"), 0);
  EXPECT_EQ(ball->patch_by_name("nope"), -1);
}

TEST(Ball, LowerDimensionsIgnoreExtraCoordinates) {
  const auto disc = make_ball(2, Vec3(0, 0, 0), 1.0);
  expect_query(*disc, Vec3(3, 4, 7), 4.0, Vec3(0.6, 0.8, 0), 0);
  expect_query(*disc, Vec3(0, 0.25, -9), -0.75, Vec3(0, 1, 0), 0);
  const auto interval = make_ball(1, Vec3(2, 5, 5), 0.5);
  expect_query(*interval, Vec3(2.1, 3, 3), -0.4, Vec3(2.5, 0, 0), 0);
  expect_query(*interval, Vec3(1.0, 0, 0), 0.5, Vec3(1.5, 0, 0), 0);
  EXPECT_EQ(interval->dim(), 1);
}

TEST(Ball, VolumesAndAreas) {
  const double r = 1.5;
  EXPECT_DOUBLE_EQ(make_ball(1, Vec3::Zero(), r)->volume(), 3.0);
  EXPECT_DOUBLE_EQ(make_ball(2, Vec3::Zero(), r)->volume(), kPi * 2.25);
  EXPECT_DOUBLE_EQ(make_ball(3, Vec3::Zero(), r)->volume(), 4.0 / 3.0 * kPi * 3.375);
  EXPECT_DOUBLE_EQ(make_ball(1, Vec3::Zero(), r)->patch_area(0), 2.0);
  EXPECT_DOUBLE_EQ(make_ball(2, Vec3::Zero(), r)->patch_area(0), 3.0 * kPi);
  EXPECT_DOUBLE_EQ(make_ball(3, Vec3::Zero(), r)->patch_area(0), 9.0 * kPi);
  const Aabb box = make_ball(2, Vec3(1, 1, 0), r)->bounding_box();
  expect_vec_near(box.lo, Vec3(-0.5, -0.5, 0), 1e-15);
  expect_vec_near(box.hi, Vec3(2.5, 2.5, 0), 1e-15);
}

TEST(Ball, InvalidArgumentsThrow) {
  EXPECT_THROW(make_ball(3, Vec3::Zero(), 0.0), InvalidArgument);
  EXPECT_THROW(make_ball(3, Vec3::Zero(), -1.0), InvalidArgument);
  EXPECT_THROW(make_ball(0, Vec3::Zero(), 1.0), InvalidArgument);
  EXPECT_THROW(make_ball(4, Vec3::Zero(), 1.0), InvalidArgument);
  try {
    make_ball(3, Vec3::Zero(), -2.0);
    FAIL() << "no throw";
  } catch (const InvalidArgument& e) {
    EXPECT_NE(std::string(e.what()).find("radius"), std::string::npos) << e.what();
  }
  const auto ball = make_ball(3, Vec3::Zero(), 1.0);
  EXPECT_THROW((void)ball->patch_area(1), InvalidArgument);
  EXPECT_THROW((void)ball->layer_cell_volume(0, 0.0, LayerPart::Whole), InvalidArgument);
}

TEST(Ball, LayerCellMembership) {
  const auto ball = make_ball(3, Vec3::Zero(), 1.0);
  const double b = 0.1;
  EXPECT_TRUE(ball->in_layer_cell(Vec3(0, 0, 0.95), 0, b, LayerPart::Interior));
  EXPECT_FALSE(ball->in_layer_cell(Vec3(0, 0, 0.95), 0, b, LayerPart::Exterior));
  EXPECT_TRUE(ball->in_layer_cell(Vec3(0, 0, 0.95), 0, b, LayerPart::Whole));
  EXPECT_TRUE(ball->in_layer_cell(Vec3(0, 1.05, 0), 0, b, LayerPart::Exterior));
  EXPECT_FALSE(ball->in_layer_cell(Vec3(0, 1.05, 0), 0, b, LayerPart::Interior));
  EXPECT_FALSE(ball->in_layer_cell(Vec3(0, 0, 0.85), 0, b, LayerPart::Whole));
  EXPECT_FALSE(ball->in_layer_cell(Vec3(0, 0, 1.15), 0, b, LayerPart::Whole));
  // The boundary itself is Interior, not Exterior.
  EXPECT_TRUE(ball->in_layer_cell(Vec3(1, 0, 0), 0, b, LayerPart::Interior));
  EXPECT_FALSE(ball->in_layer_cell(Vec3(1, 0, 0), 0, b, LayerPart::Exterior));
  EXPECT_FALSE(ball->in_layer_cell(Vec3(0, 0, 0.95), 1, b, LayerPart::Whole));
}

TEST(Ball, AnalyticShellVolumeMatchesMonteCarlo) {
  const int n = 400000;
  for (int dim = 1; dim <= 3; ++dim) {
    const auto ball = make_ball(dim, Vec3(0.5, -0.5, 0.25), 1.0);
    const double ub = dim == 1 ? 2.0 : (dim == 2 ? kPi : 4.0 / 3.0 * kPi);
    for (double b : {0.2, 1.5}) {  // 1.5 > R: the inner radius clamps at 0
      const double rin = std::max(1.0 - b, 0.0);
      const double want_int = ub * (1.0 - std::pow(rin, dim));
      const double want_ext = ub * (std::pow(1.0 + b, dim) - 1.0);
      EXPECT_NEAR(ball->layer_cell_volume(0, b, LayerPart::Interior), want_int, 1e-12);
      EXPECT_NEAR(ball->layer_cell_volume(0, b, LayerPart::Exterior), want_ext, 1e-12);
      EXPECT_NEAR(ball->layer_cell_volume(0, b, LayerPart::Whole), want_int + want_ext, 1e-12);
      const double vb = box_measure(ball->layer_bounding_box(0, b), dim);
      for (LayerPart part : {LayerPart::Interior, LayerPart::Exterior}) {
        const double exact = ball->layer_cell_volume(0, b, part);
        const double mc = ball->Domain::layer_cell_volume(0, b, part, n);
        EXPECT_NEAR(mc, exact, mc_tolerance(exact, vb, n)) << "dim " << dim << " b " << b;
      }
    }
  }
}

TEST(Ball, SampleInteriorIsUniform) {
  // Fraction inside the concentric ball of radius R/2 is 2^-d.
  for (int dim = 1; dim <= 3; ++dim) {
    const auto ball = make_ball(dim, Vec3(1, 1, 1), 2.0);
    Rng rng(100 + dim);
    const int n = 20000;
    int inner = 0;
    for (int i = 0; i < n; ++i) {
      const Vec3 x = ball->sample_interior(rng);
      ASSERT_TRUE(ball->contains(x));
      for (int k = dim; k < 3; ++k) ASSERT_EQ(x[k], 0.0);
      if ((x - Vec3(1, 1, 1)).head(dim).norm() < 1.0) ++inner;
    }
    expect_fraction(inner, n, std::pow(0.5, dim));
  }
}

TEST(Ball, SampleLayerCellIsUniform) {
  const double r = 1.0, b = 0.3;
  const auto ball = make_ball(3, Vec3::Zero(), r);
  // Interior shell [r-b, r]: the median radius splits r^3 - rin^3 in half.
  const double rin = r - b;
  const double median_int = std::cbrt(0.5 * (r * r * r + rin * rin * rin));
  const double median_ext = std::cbrt(0.5 * (r * r * r + (r + b) * (r + b) * (r + b)));
  const int n = 20000;
  Rng rng(7);
  int above_int = 0, above_ext = 0, upper_half = 0;
  for (int i = 0; i < n; ++i) {
    const Vec3 xi = ball->sample_layer_cell(0, b, LayerPart::Interior, rng);
    ASSERT_TRUE(ball->in_layer_cell(xi, 0, b, LayerPart::Interior));
    if (xi.norm() > median_int) ++above_int;
    if (xi.z() > 0.0) ++upper_half;
    const Vec3 xe = ball->sample_layer_cell(0, b, LayerPart::Exterior, rng);
    ASSERT_TRUE(ball->in_layer_cell(xe, 0, b, LayerPart::Exterior));
    if (xe.norm() > median_ext) ++above_ext;
  }
  expect_fraction(above_int, n, 0.5);
  expect_fraction(above_ext, n, 0.5);
  expect_fraction(upper_half, n, 0.5);
}

// --------------------------------------------------------------------------- Box

TEST(Box, SignedDistanceAndClosestPoint) {
  const auto box = make_box(3, Vec3(0, 0, 0), Vec3(4, 2, 1));
  // Inside: nearest face.
  expect_query(*box, Vec3(1, 1, 0.2), -0.2, Vec3(1, 1, 0), 4);
  expect_query(*box, Vec3(3.9, 1, 0.5), -0.1, Vec3(4, 1, 0.5), 1);
  expect_query(*box, Vec3(1, 1.7, 0.5), -0.3, Vec3(1, 2, 0.5), 3);
  // Inside tie between z- and z+: the lowest face index wins.
  expect_query(*box, Vec3(2, 1, 0.5), -0.5, Vec3(2, 1, 0), 4);
  // Outside a face.
  expect_query(*box, Vec3(-0.5, 1, 0.5), 0.5, Vec3(0, 1, 0.5), 0);
  expect_query(*box, Vec3(2, 1, 1.25), 0.25, Vec3(2, 1, 1), 5);
  // Outside an edge: Euclidean distance, patch of the larger violation.
  expect_query(*box, Vec3(4.3, 2.4, 0.5), 0.5, Vec3(4, 2, 0.5), 3);
  expect_query(*box, Vec3(4.4, 2.3, 0.5), 0.5, Vec3(4, 2, 0.5), 1);
  // Outside a corner.
  expect_query(*box, Vec3(-1, -2, 3), std::sqrt(1.0 + 4.0 + 4.0), Vec3(0, 0, 1), 2);
  expect_query(*box, Vec3(-3, -2, 3), std::sqrt(9.0 + 4.0 + 4.0), Vec3(0, 0, 1), 0);
  EXPECT_TRUE(box->contains(Vec3(4, 2, 1)));
  EXPECT_FALSE(box->contains(Vec3(4, 2, 1.0001)));
}

TEST(Box, LowerDimensions) {
  const auto seg = make_box(1, Vec3(-1, 5, 5), Vec3(2, 6, 6));
  expect_query(*seg, Vec3(0, 9, 9), -1.0, Vec3(-1, 0, 0), 0);
  expect_query(*seg, Vec3(1.5, 0, 0), -0.5, Vec3(2, 0, 0), 1);
  expect_query(*seg, Vec3(3, 0, 0), 1.0, Vec3(2, 0, 0), 1);
  const auto rect = make_box(2, Vec3(0, 0, 0), Vec3(2, 1, 0));
  expect_query(*rect, Vec3(3, 2, 5), std::sqrt(2.0), Vec3(2, 1, 0), 1);
  expect_query(*rect, Vec3(0.5, 0.4, 5), -0.4, Vec3(0.5, 0, 0), 2);
  EXPECT_EQ(rect->num_patches(), 4);
}

TEST(Box, PatchNamesVolumesAreas) {
  const auto box = make_box(3, Vec3(0, 0, 0), Vec3(4, 2, 1));
  const std::vector<std::string> names = {"x-", "x+", "y-", "y+", "z-", "z+"};
  ASSERT_EQ(box->num_patches(), 6);
  for (int p = 0; p < 6; ++p) {
    EXPECT_EQ(box->patch_name(p), names[static_cast<std::size_t>(p)]);
    EXPECT_EQ(box->patch_by_name(names[static_cast<std::size_t>(p)]), p);
  }
  EXPECT_DOUBLE_EQ(box->volume(), 8.0);
  EXPECT_DOUBLE_EQ(box->patch_area(0), 2.0);
  EXPECT_DOUBLE_EQ(box->patch_area(3), 4.0);
  EXPECT_DOUBLE_EQ(box->patch_area(5), 8.0);
  const auto rect = make_box(2, Vec3(0, 0, 0), Vec3(3, 1, 0));
  EXPECT_DOUBLE_EQ(rect->volume(), 3.0);
  EXPECT_DOUBLE_EQ(rect->patch_area(0), 1.0);
  EXPECT_DOUBLE_EQ(rect->patch_area(2), 3.0);
  EXPECT_DOUBLE_EQ(make_box(1, Vec3(0, 0, 0), Vec3(3, 0, 0))->patch_area(1), 1.0);
  EXPECT_THROW(make_box(3, Vec3(0, 0, 0), Vec3(1, 0, 1)), InvalidArgument);
  EXPECT_THROW(make_box(2, Vec3(0, 0, 0), Vec3(1, -1, 0)), InvalidArgument);
  EXPECT_NO_THROW(make_box(2, Vec3(0, 0, 5), Vec3(1, 1, 0)));  // z unused in 2D
}

TEST(Box, AnalyticLayerVolumeMatchesMonteCarlo) {
  const int n = 200000;
  for (int dim = 1; dim <= 3; ++dim) {
    const auto box = make_box(dim, Vec3(0, 0, 0), Vec3(2, 1, 0.8));
    for (double b : {0.1, 0.6}) {  // 0.6 > half of the short sides
      for (int p = 0; p < box->num_patches(); ++p) {
        const double vb = box_measure(box->layer_bounding_box(p, b), dim);
        for (LayerPart part : {LayerPart::Interior, LayerPart::Exterior}) {
          const double exact = box->layer_cell_volume(p, b, part);
          const double mc = box->Domain::layer_cell_volume(p, b, part, n);
          EXPECT_NEAR(mc, exact, mc_tolerance(exact, vb, n))
              << "dim " << dim << " patch " << p << " b " << b << " part " << static_cast<int>(part);
        }
      }
    }
    // The Interior cells tile the box for b >= half the shortest side.
    double total = 0.0;
    for (int p = 0; p < box->num_patches(); ++p) total += box->layer_cell_volume(p, 5.0, LayerPart::Interior);
    EXPECT_NEAR(total, box->volume(), 1e-12);
  }
  // A closed form: 2D exterior of a face of length 3 is 3b + pi b^2 / 4.
  const auto rect = make_box(2, Vec3(0, 0, 0), Vec3(3, 1, 0));
  EXPECT_NEAR(rect->layer_cell_volume(2, 0.2, LayerPart::Exterior), 0.6 + kPi * 0.01, 1e-14);
}

TEST(Box, SamplingIsUniform) {
  const auto box = make_box(3, Vec3(0, 0, 0), Vec3(4, 2, 1));
  Rng rng(11);
  const int n = 20000;
  int left = 0;
  for (int i = 0; i < n; ++i) {
    const Vec3 x = box->sample_interior(rng);
    ASSERT_TRUE(box->contains(x));
    if (x.x() < 1.0) ++left;
  }
  expect_fraction(left, n, 0.25);
  // Interior cell of face z- (b = 0.2): depth t has cross-section
  // (4 - 2t)(2 - 2t); the fraction with depth below 0.1 follows.
  const double b = 0.2;
  const auto vol = [](double t) { return 8.0 * t - 6.0 * t * t + 4.0 * t * t * t / 3.0; };
  int shallow = 0;
  for (int i = 0; i < n; ++i) {
    const Vec3 x = box->sample_layer_cell(4, b, LayerPart::Interior, rng);
    ASSERT_TRUE(box->in_layer_cell(x, 4, b, LayerPart::Interior));
    if (x.z() < 0.1) ++shallow;
  }
  expect_fraction(shallow, n, vol(0.1) / vol(0.2));
  for (int i = 0; i < 2000; ++i) {
    const Vec3 x = box->sample_layer_cell(1, b, LayerPart::Exterior, rng);
    ASSERT_TRUE(box->in_layer_cell(x, 1, b, LayerPart::Exterior));
  }
}

// --------------------------------------------------------------------------- Cylinder

TEST(Cylinder, SignedDistanceAndClosestPoint) {
  const auto cyl = make_cylinder(Vec3(0, 0, 0), Vec3(0, 0, 4), 1.0);
  expect_query(*cyl, Vec3(0.9, 0, 2), -0.1, Vec3(1, 0, 2), 0);          // inside near lateral
  expect_query(*cyl, Vec3(0, 0.3, 0.2), -0.2, Vec3(0, 0.3, 0), 1);      // inside near cap_a
  expect_query(*cyl, Vec3(0.1, 0, 3.6), -0.4, Vec3(0.1, 0, 4), 2);      // inside near cap_b
  expect_query(*cyl, Vec3(0, -3, 1), 2.0, Vec3(0, -1, 1), 0);           // outside radially
  expect_query(*cyl, Vec3(0.5, 0, 5), 1.0, Vec3(0.5, 0, 4), 2);         // outside axially
  expect_query(*cyl, Vec3(0.5, 0, -0.5), 0.5, Vec3(0.5, 0, 0), 1);      // outside axially
  expect_query(*cyl, Vec3(0, 1.3, 4.4), 0.5, Vec3(0, 1, 4), 2);         // rim, axial excess larger
  expect_query(*cyl, Vec3(0, 1.4, -0.3), 0.5, Vec3(0, 1, 0), 0);        // rim, radial excess larger
  // On the axis: some point of the lateral surface at distance r.
  const BoundaryQuery q = cyl->query(Vec3(0, 0, 2));
  EXPECT_DOUBLE_EQ(q.signed_distance, -1.0);
  EXPECT_EQ(q.patch, 0);
  EXPECT_NEAR((q.closest_point - Vec3(0, 0, 2)).norm(), 1.0, 1e-12);
  EXPECT_NEAR(q.closest_point.z(), 2.0, 1e-12);
}

TEST(Cylinder, ObliqueAxis) {
  const Vec3 a(1, 2, 3);
  const Vec3 u = Vec3(1, 1, 1).normalized();
  const Vec3 m = Vec3(1, -1, 0).normalized();  // normal to the axis
  const auto cyl = make_cylinder(a, a + 2.0 * u, 0.5);
  expect_query(*cyl, a + u + 0.3 * m, -0.2, a + u + 0.5 * m, 0);
  expect_query(*cyl, a + 0.1 * u + 0.2 * m, -0.1, a + 0.2 * m, 1);
  expect_query(*cyl, a + 2.3 * u + 0.9 * m, 0.5, a + 2.0 * u + 0.5 * m, 0);
  expect_query(*cyl, a + 2.4 * u + 0.8 * m, 0.5, a + 2.0 * u + 0.5 * m, 2);
  expect_query(*cyl, a - 0.7 * u - 0.1 * m, 0.7, a - 0.1 * m, 1);
  // Bounding box: every sample inside it, and it is tight along each axis.
  const Aabb box = cyl->bounding_box();
  const double h = 0.5 * std::sqrt(1.0 - 1.0 / 3.0);
  expect_vec_near(box.lo, a - Vec3::Constant(h), 1e-12);
  expect_vec_near(box.hi, a + 2.0 * u + Vec3::Constant(h), 1e-12);
  Rng rng(3);
  for (int i = 0; i < 2000; ++i) {
    const Vec3 x = cyl->sample_interior(rng);
    ASSERT_TRUE(cyl->contains(x));
    ASSERT_TRUE((x.array() >= box.lo.array()).all() && (x.array() <= box.hi.array()).all());
  }
}

TEST(Cylinder, VolumesAreasNames) {
  const auto cyl = make_cylinder(Vec3(0, 0, 0), Vec3(3, 0, 0), 0.5);
  EXPECT_EQ(cyl->dim(), 3);
  EXPECT_DOUBLE_EQ(cyl->volume(), kPi * 0.25 * 3.0);
  EXPECT_DOUBLE_EQ(cyl->patch_area(0), 2.0 * kPi * 0.5 * 3.0);
  EXPECT_DOUBLE_EQ(cyl->patch_area(1), kPi * 0.25);
  EXPECT_DOUBLE_EQ(cyl->patch_area(2), kPi * 0.25);
  EXPECT_EQ(cyl->patch_by_name("lateral"), 0);
  EXPECT_EQ(cyl->patch_by_name("cap_a"), 1);
  EXPECT_EQ(cyl->patch_by_name("cap_b"), 2);
  EXPECT_THROW(make_cylinder(Vec3(1, 1, 1), Vec3(1, 1, 1), 0.5), InvalidArgument);
  EXPECT_THROW(make_cylinder(Vec3(0, 0, 0), Vec3(1, 1, 1), 0.0), InvalidArgument);
}

TEST(Cylinder, AnalyticLayerVolumeMatchesMonteCarlo) {
  const int n = 200000;
  // Oblique and long (L = 2 > 2r), then short and flat (L = 0.6 < 2r).
  const std::vector<DomainPtr> cylinders = {make_cylinder(Vec3(0, 0, 0), Vec3(0.6, 0.8, 0.0) * 2.0, 0.5),
                                            make_cylinder(Vec3(1, 0, 0), Vec3(1, 0, 0.6), 0.5)};
  for (const auto& cyl : cylinders) {
    for (double b : {0.1, 0.4, 0.7}) {  // 0.4 > L/2 of the short one, 0.7 > r
      for (int p = 0; p < 3; ++p) {
        const double vb = box_measure(cyl->layer_bounding_box(p, b), 3);
        for (LayerPart part : {LayerPart::Interior, LayerPart::Exterior}) {
          const double exact = cyl->layer_cell_volume(p, b, part);
          const double mc = cyl->Domain::layer_cell_volume(p, b, part, n);
          EXPECT_NEAR(mc, exact, mc_tolerance(exact, vb, n))
              << "patch " << p << " b " << b << " part " << static_cast<int>(part);
        }
        EXPECT_NEAR(cyl->layer_cell_volume(p, b, LayerPart::Whole),
                    cyl->layer_cell_volume(p, b, LayerPart::Interior) +
                        cyl->layer_cell_volume(p, b, LayerPart::Exterior),
                    1e-14);
      }
    }
    // The Interior cells tile the cylinder once b reaches the axis / mid-plane.
    double total = 0.0;
    for (int p = 0; p < 3; ++p) total += cyl->layer_cell_volume(p, 1.0, LayerPart::Interior);
    EXPECT_NEAR(total, cyl->volume(), 1e-12);
  }
}

TEST(Cylinder, SampleLayerCellSatisfiesMembership) {
  const auto cyl = make_cylinder(Vec3(0, 0, 0), Vec3(0, 0, 2), 0.5);
  Rng rng(5);
  const double b = 0.1;
  const int n = 20000;
  int near_axis = 0;
  for (int i = 0; i < n; ++i) {
    const Vec3 x = cyl->sample_layer_cell(1, b, LayerPart::Interior, rng);
    ASSERT_TRUE(cyl->in_layer_cell(x, 1, b, LayerPart::Interior));
    // Cross-section at depth s is a disc of radius r - s: the fraction with
    // radius below 0.2 is int_0^b 0.04 pi ds / int_0^b pi (r-s)^2 ds.
    if (x.head<2>().norm() < 0.2) ++near_axis;
  }
  const double p = 0.04 * b / ((0.125 - 0.4 * 0.4 * 0.4) / 3.0);
  expect_fraction(near_axis, n, p);
  for (LayerPart part : {LayerPart::Exterior, LayerPart::Whole})
    for (int patch = 0; patch < 3; ++patch)
      for (int i = 0; i < 500; ++i)
        ASSERT_TRUE(cyl->in_layer_cell(cyl->sample_layer_cell(patch, b, part, rng), patch, b, part));
}

// --------------------------------------------------------------------------- Periodic box

TEST(PeriodicBox, WrapAndQuery) {
  const auto per = make_periodic_box(2, Vec3(0, -1, 0), Vec3(2, 0, 0));
  EXPECT_TRUE(per->is_periodic());
  expect_vec_near(per->period(), Vec3(2, 1, 0), 0.0);
  expect_vec_near(per->wrap(Vec3(2.5, 0.25, 3)), Vec3(0.5, -0.75, 0), 1e-15);
  expect_vec_near(per->wrap(Vec3(-4.5, -1.25, 0)), Vec3(1.5, -0.25, 0), 1e-15);
  expect_vec_near(per->wrap(Vec3(2.0, -1.0, 0)), Vec3(0.0, -1.0, 0), 0.0);
  const Vec3 w = per->wrap(Vec3(-1e-18, 0, 0));
  EXPECT_GE(w.x(), 0.0);
  EXPECT_LT(w.x(), 2.0);
  const BoundaryQuery q = per->query(Vec3(0.3, -0.2, 0));
  EXPECT_EQ(q.signed_distance, -std::numeric_limits<double>::infinity());
  EXPECT_EQ(q.patch, -1);
  expect_vec_near(q.closest_point, Vec3(0.3, -0.2, 0), 0.0);
  EXPECT_EQ(per->num_patches(), 0);
  EXPECT_DOUBLE_EQ(per->volume(), 2.0);
  EXPECT_TRUE(per->contains(Vec3(100, 100, 0)));
  EXPECT_THROW((void)per->patch_area(0), InvalidArgument);
  EXPECT_FALSE(make_box(2, Vec3(0, 0, 0), Vec3(1, 1, 0))->is_periodic());
  EXPECT_THROW(make_periodic_box(2, Vec3(0, 0, 0), Vec3(0, 1, 0)), InvalidArgument);
}

TEST(PeriodicBox, SampleInteriorIsUniform) {
  const auto per = make_periodic_box(3, Vec3(0, 0, 0), Vec3(1, 2, 3));
  Rng rng(9);
  const int n = 20000;
  int low = 0;
  for (int i = 0; i < n; ++i) {
    const Vec3 x = per->sample_interior(rng);
    ASSERT_TRUE((x.array() >= 0.0).all() && x.x() < 1.0 && x.y() < 2.0 && x.z() < 3.0);
    if (x.z() < 1.0) ++low;
  }
  expect_fraction(low, n, 1.0 / 3.0);
}

// --------------------------------------------------------------------------- Sub-patches

TEST(SubPatches, OutletDiscOnCylinderCap) {
  const auto cyl = make_cylinder(Vec3(0, 0, 0), Vec3(0, 0, 2), 1.0);
  const auto dom = make_with_subpatches(cyl, {SubPatch{2, Vec3(0, 0, 2), 0.3, "outlet"}});
  ASSERT_EQ(dom->num_patches(), 4);
  EXPECT_EQ(dom->patch_name(3), "outlet");
  EXPECT_EQ(dom->patch_by_name("outlet"), 3);
  EXPECT_EQ(dom->patch_name(2), "cap_b");
  EXPECT_EQ(dom->patch_id(Vec3(0.1, 0.1, 2.05)), 3);
  EXPECT_EQ(dom->patch_id(Vec3(0.1, 0.1, 1.95)), 3);
  EXPECT_EQ(dom->patch_id(Vec3(0.5, 0, 2.05)), 2);
  EXPECT_EQ(dom->patch_id(Vec3(0.1, 0, 0.05)), 1);  // the other cap is untouched
  EXPECT_EQ(dom->patch_id(Vec3(0, 0.9, 1.0)), 0);
  EXPECT_NEAR(dom->signed_distance(Vec3(0.1, 0, 2.05)), 0.05, 1e-12);
  EXPECT_NEAR(dom->patch_area(3), kPi * 0.09, 1e-14);
  EXPECT_NEAR(dom->patch_area(2), kPi * (1.0 - 0.09), 1e-14);
  EXPECT_DOUBLE_EQ(dom->patch_area(1), kPi);
  EXPECT_DOUBLE_EQ(dom->volume(), cyl->volume());
  // Layer cell of the outlet: within 0.3 + b of its centre.
  Rng rng(21);
  for (int i = 0; i < 2000; ++i) {
    const Vec3 x = dom->sample_layer_cell(3, 0.05, LayerPart::Whole, rng);
    ASSERT_TRUE(dom->in_layer_cell(x, 3, 0.05, LayerPart::Whole));
    ASSERT_LE((x - Vec3(0, 0, 2)).norm(), 0.35 + 1e-12);
  }
  // Interior layer volume of the outlet for b small: a disc times b.
  EXPECT_NEAR(dom->layer_cell_volume(3, 0.01, LayerPart::Interior, 400000), kPi * 0.09 * 0.01, 3e-5);
  EXPECT_THROW(make_with_subpatches(cyl, {SubPatch{3, Vec3(0, 0, 2), 0.3, "x"}}), InvalidArgument);
  EXPECT_THROW(make_with_subpatches(cyl, {SubPatch{2, Vec3(0, 0, 2), 0.0, "x"}}), InvalidArgument);
  EXPECT_THROW(make_with_subpatches(cyl, {SubPatch{2, Vec3(0, 0, 2.5), 0.3, "x"}}), InvalidArgument);
}

TEST(SubPatches, CapOnSphereHasArchimedesArea) {
  const auto ball = make_ball(3, Vec3::Zero(), 1.0);
  const double c = 0.5;
  const auto dom = make_with_subpatches(ball, {SubPatch{0, Vec3(0, 0, 1), c, "orifice"}});
  EXPECT_EQ(dom->patch_id(Vec3(0, 0.2, 1.1)), 1);
  EXPECT_EQ(dom->patch_id(Vec3(0, 0.2, 0.7)), 1);
  EXPECT_EQ(dom->patch_id(Vec3(0, 0.6, 0.9)), 0);
  EXPECT_EQ(dom->patch_id(Vec3(0, 0, -1)), 0);
  EXPECT_NEAR(dom->patch_area(1), kPi * c * c, 1e-14);
  EXPECT_NEAR(dom->patch_area(0), 4.0 * kPi - kPi * c * c, 1e-13);
  // Independent check: a thin-shell Monte Carlo volume over 2h.
  const double h = 0.01;
  const double shell = dom->layer_cell_volume(1, h, LayerPart::Whole, 2000000);
  EXPECT_NEAR(shell / (2.0 * h), kPi * c * c, 0.02 * kPi * c * c);
  // The base patch keeps its exact layer volume only when untouched.
  const double whole = dom->layer_cell_volume(0, h, LayerPart::Whole, 2000000);
  EXPECT_NEAR((whole + shell) / (2.0 * h), 4.0 * kPi, 0.015 * 4.0 * kPi);
}

TEST(SubPatches, TwoDimensionalFaceAndCircle) {
  const auto rect = make_box(2, Vec3(0, 0, 0), Vec3(3, 1, 0));
  const auto dom = make_with_subpatches(rect, {SubPatch{3, Vec3(1, 1, 0), 0.25, "slot"},
                                               SubPatch{3, Vec3(2, 1, 0), 0.25, "slot2"}});
  EXPECT_EQ(dom->patch_id(Vec3(1.2, 1.1, 0)), 4);
  EXPECT_EQ(dom->patch_id(Vec3(2.1, 0.9, 0)), 5);
  EXPECT_EQ(dom->patch_id(Vec3(1.5, 0.9, 0)), 3);
  EXPECT_DOUBLE_EQ(dom->patch_area(4), 0.5);
  EXPECT_DOUBLE_EQ(dom->patch_area(3), 2.0);
  const auto disc = make_with_subpatches(make_ball(2, Vec3::Zero(), 1.0), {SubPatch{0, Vec3(1, 0, 0), 1.0, "arc"}});
  // Chord 1 on the unit circle spans 60 degrees either side: arc 2 pi / 3.
  EXPECT_NEAR(disc->patch_area(1), 2.0 * kPi / 3.0, 1e-14);
  EXPECT_NEAR(disc->patch_area(0), 2.0 * kPi - 2.0 * kPi / 3.0, 1e-14);
}

// --------------------------------------------------------------------------- CSG

TEST(Csg, PipeWithCylindricalObstacle) {
  const auto dom = pipe_with_obstacle();
  ASSERT_EQ(dom->num_patches(), 9);
  EXPECT_EQ(dom->patch_name(2), "y-");
  EXPECT_EQ(dom->patch_name(6), "b:lateral");
  EXPECT_EQ(dom->patch_by_name("b:cap_a"), 7);
  // In the fluid, nearest to a wall.
  expect_query(*dom, Vec3(1, 0.3, 0.6), -0.3, Vec3(1, 0, 0.6), 2);
  // In the fluid, nearest to the obstacle.
  expect_query(*dom, Vec3(2.3, 0.5, 0.5), -0.1, Vec3(2.2, 0.5, 0.5), 6);
  expect_query(*dom, Vec3(2, 0.8, 0.5), -0.1, Vec3(2, 0.7, 0.5), 6);
  // Inside the obstacle: outside the domain.
  expect_query(*dom, Vec3(2.1, 0.5, 0.5), 0.1, Vec3(2.2, 0.5, 0.5), 6);
  EXPECT_FALSE(dom->contains(Vec3(2, 0.5, 0.5)));
  EXPECT_TRUE(dom->contains(Vec3(2, 0.25, 0.5)));
  // Outside the pipe.
  expect_query(*dom, Vec3(0.5, 0.5, 1.5), 0.5, Vec3(0.5, 0.5, 1), 5);
  const Aabb box = dom->bounding_box();
  expect_vec_near(box.lo, Vec3(0, 0, 0), 0.0);
  expect_vec_near(box.hi, Vec3(4, 1, 1), 0.0);
}

TEST(Csg, PipeVolumeAndAreas) {
  const auto dom = pipe_with_obstacle();
  const double hole = kPi * 0.04;
  // Monte Carlo with 2e6 samples over a box of volume 4: sigma ~ 5e-4.
  EXPECT_NEAR(dom->volume(), 4.0 - hole, 3e-3);
  EXPECT_DOUBLE_EQ(dom->patch_area(0), 1.0);  // far from the obstacle: exact
  EXPECT_DOUBLE_EQ(dom->patch_area(2), 4.0);
  EXPECT_DOUBLE_EQ(dom->patch_area(7), 0.0);  // caps stick out of the pipe
  EXPECT_DOUBLE_EQ(dom->patch_area(8), 0.0);
  // Shell estimates: approximate, within 1.5 %.
  EXPECT_NEAR(dom->patch_area(4), 4.0 - hole, 0.015 * (4.0 - hole));
  EXPECT_NEAR(dom->patch_area(5), 4.0 - hole, 0.015 * (4.0 - hole));
  EXPECT_NEAR(dom->patch_area(6), 2.0 * kPi * 0.2, 0.015 * 2.0 * kPi * 0.2);
  // Cached: the same value twice.
  EXPECT_EQ(dom->volume(), dom->volume());
}

TEST(Csg, DifferenceWithEnclosedHoleIsExact) {
  const auto dom = make_difference(make_box(3, Vec3(0, 0, 0), Vec3(2, 2, 2)), make_ball(3, Vec3(1, 1, 1), 0.5));
  EXPECT_DOUBLE_EQ(dom->volume(), 8.0 - 4.0 / 3.0 * kPi * 0.125);
  EXPECT_DOUBLE_EQ(dom->patch_area(6), kPi);
  EXPECT_DOUBLE_EQ(dom->patch_area(0), 4.0);
  EXPECT_EQ(dom->patch_name(6), "b:surface");
  expect_query(*dom, Vec3(1, 1, 1.7), -0.2, Vec3(1, 1, 1.5), 6);
  expect_query(*dom, Vec3(1, 1, 1.9), -0.1, Vec3(1, 1, 2), 5);
  // Samples avoid the hole and fill the rest uniformly.
  Rng rng(17);
  const int n = 20000;
  int low = 0;
  for (int i = 0; i < n; ++i) {
    const Vec3 x = dom->sample_interior(rng);
    ASSERT_GE((x - Vec3(1, 1, 1)).norm(), 0.5);
    if (x.z() < 1.0) ++low;
  }
  expect_fraction(low, n, 0.5);
  for (int i = 0; i < 1000; ++i) {
    const Vec3 x = dom->sample_layer_cell(6, 0.1, LayerPart::Interior, rng);
    ASSERT_TRUE(dom->in_layer_cell(x, 6, 0.1, LayerPart::Interior));
    ASSERT_GE((x - Vec3(1, 1, 1)).norm(), 0.5 - 1e-12);
  }
}

TEST(Csg, UnionOfOverlappingDiscs) {
  const auto a = make_ball(2, Vec3(0, 0, 0), 1.0);
  const auto b = make_ball(2, Vec3(1, 0, 0), 1.0);
  const auto dom = make_union(a, b);
  ASSERT_EQ(dom->num_patches(), 2);
  EXPECT_EQ(dom->patch_name(1), "b:surface");
  expect_query(*dom, Vec3(-1.5, 0, 0), 0.5, Vec3(-1, 0, 0), 0);
  expect_query(*dom, Vec3(2.5, 0, 0), 0.5, Vec3(2, 0, 0), 1);
  EXPECT_TRUE(dom->contains(Vec3(0.5, 0.8, 0)));
  EXPECT_FALSE(dom->contains(Vec3(0.5, 0.9, 0)));
  // Lens overlap of two unit discs at distance 1: 2 pi / 3 - sqrt(3) / 2.
  const double lens = 2.0 * kPi / 3.0 - std::sqrt(3.0) / 2.0;
  EXPECT_NEAR(dom->volume(), 2.0 * kPi - lens, 6e-3);  // 4 sigma
  // Each circle keeps 240 degrees of its perimeter (shell estimate, ~0.6 %
  // Monte Carlo noise).
  EXPECT_NEAR(dom->patch_area(0), 4.0 * kPi / 3.0, 0.03 * 4.0 * kPi / 3.0);
  EXPECT_NEAR(dom->patch_area(1), 4.0 * kPi / 3.0, 0.03 * 4.0 * kPi / 3.0);
  // Disjoint operands: exact sums.
  const auto two = make_union(a, make_ball(2, Vec3(5, 0, 0), 0.5));
  EXPECT_DOUBLE_EQ(two->volume(), kPi * 1.25);
  EXPECT_DOUBLE_EQ(two->patch_area(1), kPi);
  EXPECT_THROW(make_union(a, make_ball(3, Vec3::Zero(), 1.0)), InvalidArgument);
  EXPECT_THROW(make_union(a, make_periodic_box(2, Vec3(0, 0, 0), Vec3(1, 1, 0))), InvalidArgument);
}

// Free space: every point inside and far from any boundary, no patches; the
// box only gives the volume of the spacing rule.
TEST(FreeSpace, HasNoBoundaryAndTheBoxVolume) {
  const otfp::DomainPtr d = otfp::make_free_space(2, otfp::Vec3(-1.0, 0.0, 5.0), otfp::Vec3(3.0, 0.5, 9.0));
  EXPECT_EQ(d->dim(), 2);
  EXPECT_EQ(d->num_patches(), 0);
  EXPECT_DOUBLE_EQ(d->volume(), 4.0 * 0.5);  // z is not an axis in 2-D
  for (const otfp::Vec3& x : {otfp::Vec3(0.0, 0.0, 0.0), otfp::Vec3(1e6, -1e6, 0.0)}) {
    const otfp::BoundaryQuery q = d->query(x);
    EXPECT_EQ(q.signed_distance, -std::numeric_limits<double>::infinity());
    EXPECT_EQ(q.patch, -1);
    EXPECT_TRUE(d->contains(x));
  }
  EXPECT_EQ(d->bounding_box().hi[2], 0.0);
  EXPECT_THROW(d->patch_area(0), otfp::InvalidArgument);
  EXPECT_THROW(otfp::make_free_space(4, otfp::Vec3::Zero(), otfp::Vec3::Ones()), otfp::InvalidArgument);
}

// The square pipe with an obstacle against the CSG difference of a box and a
// cylinder (disc in 2-D), an independent construction: the same inside and
// outside, the same signed distance inside Omega (where the CSG one is exact),
// and patches, volume and areas by their formulas.
TEST(SquarePipeObstacle, AgreesWithTheBoxMinusCylinder) {
  using otfp::Vec3;
  for (int dim : {2, 3}) {
    const Vec3 lo(0.0, 0.0, 0.0), hi(4.0, 1.0, dim == 3 ? 1.0 : 0.0), c(1.5, 0.5, 0.5);
    const double r = 0.3;
    const otfp::DomainPtr pipe = otfp::make_square_pipe_obstacle(dim, lo, hi, 2, c, r);
    const otfp::DomainPtr box = otfp::make_box(dim, lo, hi);
    const otfp::DomainPtr obstacle =
        dim == 3 ? otfp::make_cylinder(Vec3(1.5, 0.5, -1.0), Vec3(1.5, 0.5, 2.0), r) : otfp::make_ball(2, c, r);
    const otfp::DomainPtr csg = otfp::make_difference(box, obstacle);
    ASSERT_EQ(pipe->num_patches(), 2 * dim + 1);
    EXPECT_EQ(pipe->patch_name(2 * dim), "obstacle");
    const double height = 1.0;  // the z extent in 3-D; a unit height in 2-D
    EXPECT_NEAR(pipe->volume(), 4.0 * 1.0 * height - std::numbers::pi * r * r * height, 1e-12);
    EXPECT_NEAR(pipe->patch_area(2 * dim), 2.0 * std::numbers::pi * r * height, 1e-12);
    otfp::Rng rng(7);
    int inside = 0;
    for (int i = 0; i < 4000; ++i) {
      Vec3 x = Vec3::Zero();
      for (int k = 0; k < dim; ++k) x[k] = rng.uniform(lo[k] - 0.3, hi[k] + 0.3);
      const otfp::BoundaryQuery q = pipe->query(x), e = csg->query(x);
      ASSERT_EQ(q.signed_distance <= 0.0, e.signed_distance <= 0.0) << x.transpose();
      if (q.signed_distance <= 0.0) {
        ++inside;
        EXPECT_NEAR(q.signed_distance, e.signed_distance, 1e-12) << x.transpose();
        EXPECT_NEAR((q.closest_point - x).norm(), -q.signed_distance, 1e-12);
      } else {
        // Outside: exact, so never below the CSG lower bound, and its closest point is on the boundary.
        EXPECT_GE(q.signed_distance, e.signed_distance - 1e-12) << x.transpose();
        EXPECT_NEAR((q.closest_point - x).norm(), q.signed_distance, 1e-12);
        EXPECT_NEAR(pipe->query(q.closest_point).signed_distance, 0.0, 1e-12);
      }
    }
    EXPECT_GT(inside, 1000);
  }
  EXPECT_THROW(otfp::make_square_pipe_obstacle(3, Vec3::Zero(), Vec3::Ones(), 2, Vec3(0.5, 0.5, 0.5), 0.6),
               otfp::InvalidArgument);  // the obstacle reaches the walls
}

namespace {

// Mean of |x - c|^2 over Omega by sampling it: the plain average over
// sample_interior() with its own seed, against each domain's closed form.
double sampled_mean_square(const Domain& d, const Vec3& c, int samples) {
  Rng rng(20261202);
  Vec3 cc = c;  // in d < 3 the unused axes do not count
  for (int k = d.dim(); k < 3; ++k) cc[k] = 0.0;
  double s2 = 0.0;
  for (int i = 0; i < samples; ++i) s2 += (d.sample_interior(rng) - cc).squaredNorm();
  return s2 / samples;
}

}  // namespace

TEST(Domain, MeanSquareDistanceClosedFormsMatchSampling) {
  const Vec3 c(0.3, -0.2, 0.1);
  const std::vector<DomainPtr> domains = {
      make_ball(3, Vec3(0.1, 0.2, 0.3), 1.5),     make_ball(2, Vec3(0.1, 0.2, 0.0), 0.7),
      make_box(3, Vec3(-1, 0, 0), Vec3(2, 1, 3)), make_box(2, Vec3(-1, 0, 0), Vec3(2, 1, 0)),
      make_cylinder(Vec3(0, 0, 0), Vec3(1, 2, 2), 0.5),
      make_periodic_box(2, Vec3(0, 0, 0), Vec3(1, 3, 0)),
      make_free_space(3, Vec3(-1, -1, -1), Vec3(1, 2, 1))};
  constexpr int kSamples = 400000;
  for (const DomainPtr& d : domains) {
    const double exact = d->mean_square_distance(c);
    // The sampled mean's standard error is below 1% of these values at this count.
    EXPECT_NEAR(exact, sampled_mean_square(*d, c, kSamples), 0.01 * exact) << "dim " << d->dim();
  }
  // The default (sampling with a fixed seed) on a domain without a closed form.
  const DomainPtr pipe = make_square_pipe_obstacle(2, Vec3(0, 0, 0), Vec3(4, 1, 0), 2, Vec3(1, 0.5, 0), 0.2);
  EXPECT_NEAR(pipe->mean_square_distance(c), sampled_mean_square(*pipe, c, kSamples), 0.01 * pipe->mean_square_distance(c));
  EXPECT_EQ(pipe->mean_square_distance(c), pipe->mean_square_distance(c));  // the same value every call
}

TEST(Domain, InertiaCenterIsTheCentreOfSymmetry) {
  EXPECT_EQ(make_ball(2, Vec3(0.1, 0.2, 0.3), 1.5)->inertia_center(), Vec3(0.1, 0.2, 0.0));
  EXPECT_EQ(make_box(3, Vec3(-1, 0, 0), Vec3(2, 1, 3))->inertia_center(), Vec3(0.5, 0.5, 1.5));
  EXPECT_EQ(make_cylinder(Vec3(0, 0, 0), Vec3(1, 2, 2), 0.5)->inertia_center(), Vec3(0.5, 1.0, 1.0));
  const DomainPtr box = make_box(3, Vec3(-1, 0, 0), Vec3(2, 1, 3));
  const DomainPtr with_outlet = make_with_subpatches(box, {SubPatch{0, Vec3(-1, 0.5, 1.5), 0.2, "outlet"}});
  EXPECT_EQ(with_outlet->inertia_center(), box->inertia_center());
  EXPECT_EQ(with_outlet->mean_square_distance(Vec3::Zero()), box->mean_square_distance(Vec3::Zero()));
  // Its box's centre, whatever the obstacle.
  EXPECT_EQ(make_square_pipe_obstacle(2, Vec3(0, 0, 0), Vec3(4, 1, 0), 2, Vec3(1, 0.5, 0), 0.2)->inertia_center(),
            Vec3(2.0, 0.5, 0.0));
}
