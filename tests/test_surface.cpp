#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <cstring>
#include <numbers>
#include <string>

#include "otfp/surface.hpp"

using namespace otfp;

namespace {
constexpr double kPi = std::numbers::pi;

// Grid spacing of boundary_surface along an axis of extent L (grown by b).
double spacing(double extent, double b, int n) { return (extent + 2.0 * b) / (n - 2); }
}  // namespace

// Linear interpolation of the exact signed distance puts every vertex within
// O(h^2 / R) of the sphere and every facet normal within O(h / R) of the
// true one, so the area error is O((h / R)^2): halving h must cut it about
// fourfold. The constant 2 bounds the measured 0.26 (n = 24 and 48) with margin.
TEST(Surface, SphereAreaConvergesAtSecondOrder) {
  const double R = 1.0;
  const Vec3 c(0.1, -0.2, 0.05);  // off the grid's symmetry
  const auto ball = make_ball(3, c, R);
  double err[2];
  int i = 0;
  for (int n : {24, 48}) {
    const SurfaceMesh m = boundary_surface(*ball, 0.0, n);
    const double h = spacing(2.0 * R, 0.0, n);
    err[i] = std::abs(surface_measure(m) / (4.0 * kPi * R * R) - 1.0);
    EXPECT_LT(err[i], 2.0 * (h / R) * (h / R)) << "n = " << n;
    for (const Vec3& x : m.points) EXPECT_LT(std::abs((x - c).norm() - R), h * h / R) << "vertex off the sphere";
    ++i;
  }
  EXPECT_LT(err[1], err[0] / 3.0) << "second order: the error falls about fourfold when h halves";
}

TEST(Surface, OffsetSurfaceOfABallHasAreaOfTheGrownBall) {
  const double R = 0.8, b = 0.3;
  const SurfaceMesh m = boundary_surface(*make_ball(3, Vec3::Zero(), R), b, 48);
  const double h = spacing(2.0 * R, b, 48);
  EXPECT_NEAR(surface_measure(m) / (4.0 * kPi * (R + b) * (R + b)), 1.0, 2.0 * (h / (R + b)) * (h / (R + b)));
}

TEST(Surface, SphereNormalsPointOutward) {
  const SurfaceMesh m = boundary_surface(*make_ball(3, Vec3::Zero(), 1.0), 0.0, 16);
  ASSERT_GT(m.num_cells(), 100u);
  for (std::size_t t = 0; t < m.num_cells(); ++t) {
    const Vec3 a = m.points[m.cells[3 * t]], b = m.points[m.cells[3 * t + 1]], c = m.points[m.cells[3 * t + 2]];
    EXPECT_GT((b - a).cross(c - a).dot(a + b + c), 0.0) << t;
  }
}

TEST(Surface, BoxFacesAreExactWithTheirPatchIds) {
  const Vec3 lo(0.0, -1.0, 0.5), hi(1.0, 1.0, 2.0);
  const auto box = make_box(3, lo, hi);
  const SurfaceMesh m = boundary_surface(*box, 0.0, 20);
  const Vec3 e = hi - lo;
  EXPECT_NEAR(surface_measure(m), 2.0 * (e[0] * e[1] + e[1] * e[2] + e[2] * e[0]), 1e-10);
  for (int p = 0; p < 6; ++p) EXPECT_NEAR(surface_measure(m, p), box->patch_area(p), 1e-10) << box->patch_name(p);
  for (std::size_t t = 0; t < m.num_cells(); ++t) {
    const int p = m.patch[t], axis = p / 2;
    const Vec3 a = m.points[m.cells[3 * t]], b = m.points[m.cells[3 * t + 1]], c = m.points[m.cells[3 * t + 2]];
    const Vec3 n = (b - a).cross(c - a).normalized();
    EXPECT_NEAR(n[axis], p % 2 ? 1.0 : -1.0, 1e-9) << "cell " << t << " on face " << box->patch_name(p);
  }
  const SurfaceMesh only = boundary_surface(*box, 0.0, 20, {1, 4});
  EXPECT_NEAR(surface_measure(only), box->patch_area(1) + box->patch_area(4), 1e-10);
  for (int p : only.patch) EXPECT_TRUE(p == 1 || p == 4);
}

// The outer surface of a box's layer is the parallel surface: faces, quarter
// cylinders along the edges and eighth spheres at the corners, area
// 2 (ab + bc + ca) + 2 pi b (a + b + c) + 4 pi b^2 (Steiner).
TEST(Surface, OffsetBoxFollowsSteinersFormula) {
  const double a = 1.0, bb = 2.0, c = 1.5, w = 0.25;
  const auto box = make_box(3, Vec3::Zero(), Vec3(a, bb, c));
  const double exact = 2.0 * (a * bb + bb * c + c * a) + 2.0 * kPi * w * (a + bb + c) + 4.0 * kPi * w * w;
  const double e40 = std::abs(surface_measure(boundary_surface(*box, w, 40)) - exact);
  const double e80 = std::abs(surface_measure(boundary_surface(*box, w, 80)) - exact);
  EXPECT_LT(e40 / exact, 5e-3);
  EXPECT_LT(e80, e40 / 2.5) << "the rounded edges converge";
}

TEST(Surface, DiscPerimeterConvergesAtSecondOrder) {
  const double R = 0.7;
  const auto disc = make_ball(2, Vec3(0.3, 0.1, 0.0), R);
  double err[2];
  int i = 0;
  for (int n : {32, 64}) {
    const SurfaceMesh m = boundary_surface(*disc, 0.0, n);
    EXPECT_EQ(m.dim, 2);
    EXPECT_EQ(m.cells.size(), 2 * m.num_cells());
    const double h = spacing(2.0 * R, 0.0, n);
    err[i] = std::abs(surface_measure(m) / (2.0 * kPi * R) - 1.0);
    EXPECT_LT(err[i], 0.2 * (h / R) * (h / R)) << "n = " << n;  // measured 0.047 (h / R)^2
    for (const Vec3& x : m.points) EXPECT_EQ(x[2], 0.0);
    ++i;
  }
  EXPECT_LT(err[1], err[0] / 3.0);
}

TEST(Surface, IntervalEndsArePoints) {
  const SurfaceMesh m = boundary_surface(*make_ball(1, Vec3(0.25, 0.0, 0.0), 1.0), 0.1, 10);
  ASSERT_EQ(m.num_cells(), 2u);
  EXPECT_EQ(surface_measure(m), 2.0);
  double lo = m.points[m.cells[0]][0], hi = m.points[m.cells[1]][0];
  if (lo > hi) std::swap(lo, hi);
  // The signed distance is linear on each side: the crossings are exact.
  EXPECT_NEAR(lo, 0.25 - 1.1, 1e-14);
  EXPECT_NEAR(hi, 0.25 + 1.1, 1e-14);
}

TEST(Surface, DomainsWithoutWallsGiveAnEmptyMesh) {
  const SurfaceMesh m = boundary_surface(*make_periodic_box(3, Vec3::Zero(), Vec3::Ones()), 0.0, 8);
  EXPECT_EQ(m.num_cells(), 0u);
  EXPECT_TRUE(m.points.empty());
  const std::string doc = surface_vtp(m);
  EXPECT_NE(doc.find("NumberOfPoints=\"0\""), std::string::npos);
  EXPECT_NE(doc.find("Name=\"patch\" format=\"appended\" offset=\"0\""), std::string::npos);
}

TEST(Surface, RejectsBadArguments) {
  const auto ball = make_ball(3, Vec3::Zero(), 1.0);
  try {
    boundary_surface(*ball, 0.0, 3);
    ADD_FAILURE() << "3 cells accepted";
  } catch (const InvalidArgument& e) {
    EXPECT_STREQ(e.what(), "boundary_surface: cells_per_axis = 3: must be in [4, 4096]");
  }
  EXPECT_THROW(boundary_surface(*ball, std::nan(""), 8), InvalidArgument);
}

TEST(Surface, VtpDeclaresCellsOfTheRightKind) {
  const SurfaceMesh m3 = boundary_surface(*make_ball(3, Vec3::Zero(), 1.0), 0.0, 8);
  const std::string d3 = surface_vtp(m3);
  EXPECT_NE(d3.find("NumberOfPolys=\"" + std::to_string(m3.num_cells()) + "\""), std::string::npos);
  EXPECT_NE(d3.find("<Polys>"), std::string::npos);
  EXPECT_NE(d3.find("<CellData Scalars=\"patch\">"), std::string::npos);
  const SurfaceMesh m2 = boundary_surface(*make_ball(2, Vec3::Zero(), 1.0), 0.0, 8);
  const std::string d2 = surface_vtp(m2);
  EXPECT_NE(d2.find("NumberOfLines=\"" + std::to_string(m2.num_cells()) + "\""), std::string::npos);
  EXPECT_NE(d2.find("<Lines>"), std::string::npos);
  // The offsets block (Int32: a display mesh's indices fit) ends at dim * cells.
  EXPECT_NE(d2.find("<DataArray type=\"Int32\" Name=\"offsets\""), std::string::npos);
  const std::size_t start = d2.find("_", d2.find("<AppendedData")) + 1;
  const std::size_t tag = d2.find("Name=\"offsets\"");
  const std::size_t off = std::stoull(d2.substr(d2.find("offset=\"", tag) + 8));
  std::uint64_t bytes = 0;
  std::memcpy(&bytes, d2.data() + start + off, 8);
  ASSERT_EQ(bytes, 4 * m2.num_cells());
  std::int32_t last = 0;
  std::memcpy(&last, d2.data() + start + off + 8 + bytes - 4, 4);
  EXPECT_EQ(last, static_cast<std::int32_t>(2 * m2.num_cells()));
}

TEST(Surface, VtpStoresADisplayMeshCompactly) {
  // Float32 points and Int32 connectivity: 12 bytes per point, 3 x 4 + 4 + 4
  // per triangle (connectivity, offset, patch) plus the XML (issue 23: the
  // sphere's domain.vtp was 2.3 MB, more than a particle snapshot).
  const SurfaceMesh m = boundary_surface(*make_ball(3, Vec3::Zero(), 1.0), 0.0, 16);
  const std::string doc = surface_vtp(m);
  EXPECT_NE(doc.find("<DataArray type=\"Float32\" Name=\"position\" NumberOfComponents=\"3\""), std::string::npos);
  EXPECT_NE(doc.find("<DataArray type=\"Int32\" Name=\"connectivity\""), std::string::npos);
  const std::size_t data = 12 * m.points.size() + 20 * m.num_cells() + 4 * 8;
  EXPECT_LE(doc.size(), data + 1024);
  EXPECT_GE(doc.size(), data);
  // The points are the mesh's, to Float32 precision.
  const std::size_t start = doc.find("_", doc.find("<AppendedData")) + 1;
  const std::size_t tag = doc.find("Name=\"position\"");
  const std::size_t off = std::stoull(doc.substr(doc.find("offset=\"", tag) + 8));
  std::vector<float> xyz(3 * m.points.size());
  std::memcpy(xyz.data(), doc.data() + start + off + 8, 4 * xyz.size());
  for (std::size_t p = 0; p < m.points.size(); ++p)
    for (int k = 0; k < 3; ++k) EXPECT_NEAR(xyz[3 * p + k], m.points[p][k], 1e-6);
}
