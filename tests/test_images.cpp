// Image blobs at no-flux walls: reflections and their Jacobians, the image
// set at edges and corners, the exact gradient of the functional with images
// against finite differences, the list path against the O(n^2) sum and
// against an independent periodic-extension computation, and the O(s/R)
// error of the tangent-plane reflection at a curved wall.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <omp.h>

#include <cmath>
#include <memory>
#include <string>

#include "otfp/functional.hpp"
#include "otfp/geometry.hpp"
#include "otfp/images.hpp"
#include "otfp/implicit_stepper.hpp"
#include "test_support.hpp"

using namespace otfp;
using otfp::testing::central_difference;
using otfp::testing::random_cloud;

namespace {

// d(image)/dx by central differences.
Mat3 fd_jacobian(const MirrorWall& w, const Vec3& x, int dim) {
  Mat3 j = Mat3::Zero();
  for (int k = 0; k < dim; ++k) {
    for (int i = 0; i < dim; ++i) {
      auto f = [&](double e) {
        Vec3 y = x;
        y[k] += e;
        return w.reflect(y, nullptr)[i];
      };
      j(i, k) = central_difference(f, 1e-5);
    }
  }
  return j;
}

void expect_jacobian(const MirrorWall& w, const Vec3& x, int dim) {
  Mat3 jac;
  w.reflect(x, &jac);
  const Mat3 fd = fd_jacobian(w, x, dim);
  for (int i = 0; i < dim; ++i)
    for (int k = 0; k < dim; ++k) EXPECT_NEAR(jac(i, k), fd(i, k), 1e-8) << "entry " << i << "," << k;
}

}  // namespace

TEST(MirrorWall, PlaneIsAnInvolutionWithExactJacobian) {
  auto w = make_plane_wall(Vec3(0.3, -0.2, 0.1), Vec3(1.0, 2.0, -0.5));
  const Vec3 x(0.7, 0.1, -0.4);
  const Vec3 y = w->reflect(x, nullptr);
  EXPECT_NEAR((w->reflect(y, nullptr) - x).norm(), 0.0, 1e-14);
  EXPECT_NEAR(w->distance(y), -w->distance(x), 1e-14);
  expect_jacobian(*w, x, 3);
}

TEST(MirrorWall, SphereReflectsRadiallyAcrossTheTangentPlane) {
  for (int dim = 1; dim <= 3; ++dim) {
    auto w = make_sphere_wall(dim, Vec3(0.1, 0.2, 0.3), 1.5);
    Vec3 x(0.1 + 1.2, 0.2, 0.3);
    if (dim >= 2) x += Vec3(0.0, 0.3, 0.0);
    if (dim == 3) x += Vec3(0.0, 0.0, -0.25);
    for (int k = dim; k < 3; ++k) x[k] = 0.0;
    const Vec3 y = w->reflect(x, nullptr);
    // r* = 2R - r along the same ray: distances are opposite, the midpoint is on the sphere.
    EXPECT_NEAR(w->distance(y), -w->distance(x), 1e-13) << "d=" << dim;
    EXPECT_NEAR(w->distance(0.5 * (x + y)), 0.0, 1e-13) << "d=" << dim;
    for (int k = dim; k < 3; ++k) EXPECT_EQ(y[k], 0.0);
    expect_jacobian(*w, x, dim);
    expect_jacobian(*w, Vec3(x[0] + 0.5, x[1], x[2]), dim);  // a source outside the wall
  }
}

TEST(MirrorWall, CylinderSideReflectsRadiallyAndKeepsTheAxialCoordinate) {
  const Vec3 a(0.2, -0.1, 0.4), u = Vec3(1.0, 0.5, -0.3).normalized();
  auto w = make_cylinder_wall(a, u, 0.6);
  const Vec3 x = a + 1.3 * u + 0.45 * Vec3(0.5, -1.0, 0.0).cross(u).normalized();
  const Vec3 y = w->reflect(x, nullptr);
  EXPECT_NEAR((y - a).dot(u), (x - a).dot(u), 1e-13);
  EXPECT_NEAR(w->distance(y), -w->distance(x), 1e-13);
  expect_jacobian(*w, x, 3);
}

// An obstacle (domain outside the round wall): the same reflection, the
// distance negative outside the obstacle, so a point in the domain maps into it.
TEST(MirrorWall, ObstacleWallsHaveTheDomainOutside) {
  const Vec3 a(0.2, -0.1, 0.4), u = Vec3(1.0, 0.5, -0.3).normalized();
  auto cyl = make_cylinder_wall(a, u, 0.6, WallSide::DomainOutside);
  const Vec3 x = a + 1.3 * u + 0.75 * Vec3(0.5, -1.0, 0.0).cross(u).normalized();  // 0.15 outside the obstacle
  EXPECT_NEAR(cyl->distance(x), -0.15, 1e-13);
  const Vec3 y = cyl->reflect(x, nullptr);
  EXPECT_NEAR(cyl->distance(y), 0.15, 1e-13);
  EXPECT_NEAR((y - a).dot(u), (x - a).dot(u), 1e-13);
  expect_jacobian(*cyl, x, 3);
  auto disc = make_sphere_wall(2, Vec3(0.5, 0.5, 0.0), 0.25, WallSide::DomainOutside);
  const Vec3 p(0.5, 0.8, 0.0);
  EXPECT_NEAR(disc->distance(p), -0.05, 1e-14);
  EXPECT_NEAR((disc->reflect(p, nullptr) - Vec3(0.5, 0.7, 0.0)).norm(), 0.0, 1e-14);
  expect_jacobian(*disc, p, 2);
  // reflect_inside puts a point that entered the obstacle back into the domain.
  std::vector<Vec3> pts = {Vec3(0.5, 0.72, 0.0), Vec3(0.5, 0.9, 0.0)};
  EXPECT_EQ(reflect_inside({disc}, pts), 1u);
  EXPECT_NEAR((pts[0] - Vec3(0.5, 0.78, 0.0)).norm(), 0.0, 1e-14);
  EXPECT_EQ(pts[1], Vec3(0.5, 0.9, 0.0));
}

TEST(WallImages, CornersGetImagesOfImages) {
  auto box = make_box(3, Vec3::Zero(), Vec3(2.0, 1.0, 1.0));
  WallImages images(mirror_walls(*box));
  ASSERT_EQ(images.walls().size(), 6u);
  // One particle near one face, one near an edge, one near a corner, one deep inside.
  std::vector<Vec3> x = {Vec3(1.0, 0.05, 0.5), Vec3(1.0, 0.05, 0.06), Vec3(0.04, 0.05, 0.06), Vec3(1.0, 0.5, 0.5)};
  images.select(x, std::vector<double>(x.size(), 0.1));
  std::vector<int> count(x.size(), 0);
  for (auto s : images.sources()) ++count[s];
  EXPECT_EQ(count[0], 1);
  EXPECT_EQ(count[1], 3);
  EXPECT_EQ(count[2], 7);
  EXPECT_EQ(count[3], 0);
  std::vector<Vec3> y;
  images.positions(x, y);
  // The corner particle's images are its reflections through every subset of the three faces.
  int found = 0;
  for (std::size_t i = 0; i < y.size(); ++i) {
    if (images.sources()[i] != 2) continue;
    for (int mask = 1; mask < 8; ++mask) {
      const Vec3 e(mask & 1 ? -0.04 : 0.04, mask & 2 ? -0.05 : 0.05, mask & 4 ? -0.06 : 0.06);
      if ((y[i] - e).norm() < 1e-14) ++found;
    }
  }
  EXPECT_EQ(found, 7);
}

namespace {

// The images of select() written out the plain way: for each wall the
// distances of all particles (O(n) per wall), then per particle the nearby
// walls in wall order and the subsets of (the first 16 of) them in binary
// counting order, each image's position by composing the reflections.
struct ReferenceImages {
  std::vector<std::uint32_t> source;
  std::vector<Vec3> position;
};

ReferenceImages reference_images(const std::vector<MirrorWallPtr>& walls, int max_order, const std::vector<Vec3>& x,
                                 const std::vector<double>& reach) {
  std::vector<std::vector<double>> dist(walls.size(), std::vector<double>(x.size()));
  for (std::size_t w = 0; w < walls.size(); ++w)
    for (std::size_t p = 0; p < x.size(); ++p) dist[w][p] = walls[w]->distance(x[p]);
  ReferenceImages ref;
  for (std::size_t p = 0; p < x.size(); ++p) {
    std::vector<std::size_t> near;
    std::vector<double> depth;
    for (std::size_t w = 0; w < walls.size(); ++w)
      if (dist[w][p] >= -reach[p] && near.size() < 16) {
        near.push_back(w);
        depth.push_back(std::max(-dist[w][p], 0.0));
      }
    for (std::uint32_t mask = 1; mask < (1u << near.size()); ++mask) {
      std::vector<std::size_t> chain;
      double sq = 0.0;
      for (std::size_t j = 0; j < near.size(); ++j)
        if (mask & (1u << j)) {
          chain.push_back(near[j]);
          sq += depth[j] * depth[j];
        }
      if (static_cast<int>(chain.size()) > max_order || sq > reach[p] * reach[p]) continue;
      Vec3 y = x[p];
      for (std::size_t w : chain) y = walls[w]->reflect(y, nullptr);
      ref.source.push_back(static_cast<std::uint32_t>(p));
      ref.position.push_back(y);
    }
  }
  return ref;
}

// A plane wall that only has distance(): select() goes through MirrorWall's own distances().
class PlainPlane final : public MirrorWall {
 public:
  PlainPlane(const Vec3& p, const Vec3& n) : plane_(make_plane_wall(p, n)) {}
  double distance(const Vec3& x) const override { return plane_->distance(x); }
  Vec3 reflect(const Vec3& x, Mat3* j) const override { return plane_->reflect(x, j); }

 private:
  MirrorWallPtr plane_;
};

class ThrowingWall final : public MirrorWall {
 public:
  double distance(const Vec3& x) const override {
    if (x[0] > 0.9) throw InvalidArgument("distance of a point beyond x = 0.9");
    return x[0] - 1.0;
  }
  Vec3 reflect(const Vec3& x, Mat3*) const override { return Vec3(2.0 - x[0], x[1], x[2]); }
};

// Points in the walls' bounding box widened by 0.2 (some beyond the walls,
// as band particles are) and reaches from 0 to 0.35.
std::vector<Vec3> cloud_around(int dim, const Vec3& lo, const Vec3& hi, std::size_t n, std::uint64_t seed,
                               std::vector<double>& reach) {
  Rng rng(seed);
  std::vector<Vec3> x(n, Vec3::Zero());
  reach.resize(n);
  for (std::size_t p = 0; p < n; ++p) {
    for (int k = 0; k < dim; ++k) x[p][k] = rng.uniform(lo[k] - 0.2, hi[k] + 0.2);
    reach[p] = rng.uniform(0.0, 0.35);
  }
  return x;
}

}  // namespace

// The block form distances() (spelt out per component so that it
// vectorises) gives distance()'s bits for every kind of wall.
TEST(MirrorWall, DistancesOfABlockAreDistanceBitForBit) {
  const std::vector<std::pair<int, MirrorWallPtr>> walls = {
      {3, make_plane_wall(Vec3(0.1, -0.2, 0.3), Vec3(0.3, -1.0, 0.7))},
      {2, make_plane_wall(Vec3(0.5, 0.5, 0.0), Vec3(1.0, 2.0, 0.0))},
      {3, make_sphere_wall(3, Vec3(0.1, 0.2, -0.3), 0.8)},
      {3, make_sphere_wall(3, Vec3(0.1, 0.2, -0.3), 0.8, WallSide::DomainOutside)},
      {2, make_sphere_wall(2, Vec3(0.1, 0.2, 0.0), 0.6)},
      {1, make_sphere_wall(1, Vec3(0.1, 0.0, 0.0), 0.6)},
      {3, make_cylinder_wall(Vec3(0.1, 0.2, 0.3), Vec3(1.0, 0.4, -0.2), 0.5)},
      {3, make_cylinder_wall(Vec3::Zero(), Vec3::UnitZ(), 0.5, WallSide::DomainOutside)}};
  Rng rng(17);
  for (const auto& [dim, wall] : walls) {
    std::vector<Vec3> x(1001, Vec3::Zero());
    for (Vec3& p : x)
      for (int k = 0; k < dim; ++k) p[k] = rng.uniform(-1.5, 1.5);
    x[3] = Vec3::Zero();  // the centre
    std::vector<double> d(x.size());
    wall->distances(x.data(), x.size(), d.data());
    for (std::size_t i = 0; i < x.size(); ++i) ASSERT_EQ(d[i], wall->distance(x[i])) << "point " << i;
  }
}

// select() is parallel over runs of particles and skips those within no
// wall's reach; its images, in order, are those of the plain serial rule, bit
// for bit, on one and two threads: planes, spheres, cylinders, obstacles,
// the reservoir band's shell, 1-D to 3-D, 20 walls at a point (only 16 are
// composed), max_order 1-3, a wall with only distance(), and sizes around
// the block of 256 particles and the threshold of parallel runs (4096).
TEST(WallImages, ParallelSelectionMatchesTheSerialRuleBitForBit) {
  struct Case {
    std::string name;
    int dim;
    std::vector<MirrorWallPtr> walls;
    Vec3 lo, hi;
  };
  std::vector<Case> cases;
  cases.push_back({"box", 3, mirror_walls(*make_box(3, Vec3::Zero(), Vec3(2.0, 1.0, 1.0))), Vec3::Zero(),
                   Vec3(2.0, 1.0, 1.0)});
  cases.push_back({"square", 2, mirror_walls(*make_box(2, Vec3::Zero(), Vec3(1.0, 1.0, 0.0))), Vec3::Zero(),
                   Vec3(1.0, 1.0, 0.0)});
  cases.push_back({"interval", 1, mirror_walls(*make_box(1, Vec3::Zero(), Vec3(1.0, 0.0, 0.0))), Vec3::Zero(),
                   Vec3(1.0, 0.0, 0.0)});
  cases.push_back({"ball", 3, mirror_walls(*make_ball(3, Vec3::Zero(), 1.0)), Vec3::Constant(-1.0), Vec3::Ones()});
  // The sphere example's setup: Dirichlet surface open, the band's back face mirrored.
  auto ball = make_ball(3, Vec3::Zero(), 1.0);
  cases.push_back({"reservoir shell", 3, mirror_walls(*ball->extended({0}, 0.3)), Vec3::Constant(-1.3),
                   Vec3::Constant(1.3)});
  cases.push_back({"cylinder", 3, mirror_walls(*make_cylinder(Vec3::Zero(), Vec3(2.0, 0.0, 0.0), 0.5)),
                   Vec3(0.0, -0.5, -0.5), Vec3(2.0, 0.5, 0.5)});
  cases.push_back({"square with an obstacle", 2,
                   {make_plane_wall(Vec3::Zero(), Vec3(-1.0, 0.0, 0.0)), make_plane_wall(Vec3::Ones(), Vec3::UnitX()),
                    make_sphere_wall(2, Vec3(0.5, 0.5, 0.0), 0.2, WallSide::DomainOutside),
                    std::make_shared<PlainPlane>(Vec3::Zero(), Vec3(0.0, -1.0, 0.0)),
                    std::make_shared<PlainPlane>(Vec3::Ones(), Vec3::UnitY())},
                   Vec3::Zero(), Vec3(1.0, 1.0, 0.0)});
  // 20 planes through points 0.05 from the origin: a point near it has all
  // 20 within reach; only the first 16 are composed.
  std::vector<MirrorWallPtr> fan;
  for (int k = 0; k < 20; ++k) {
    const double a = 2.0 * 3.14159265358979 * k / 20.0;
    const Vec3 nrm(std::cos(a), std::sin(a), 0.0);
    fan.push_back(make_plane_wall(0.05 * nrm, nrm));
  }
  cases.push_back({"20 planes", 2, fan, Vec3(-0.05, -0.05, 0.0), Vec3(0.05, 0.05, 0.0)});

  const int threads_before = omp_get_max_threads();
  std::uint64_t seed = 1;
  for (const Case& c : cases) {
    for (int max_order : {1, 2, 3}) {
      // Parallel from 16 blocks of 256 particles on (4096).
      for (std::size_t n : {std::size_t{0}, std::size_t{1}, std::size_t{20}, std::size_t{255}, std::size_t{257},
                            std::size_t{3000}, std::size_t{4095}, std::size_t{4097}, std::size_t{9001}}) {
        if (c.name == "20 planes" && n > 20) continue;  // 2^16 subsets per point
        SCOPED_TRACE(c.name + ", max_order " + std::to_string(max_order) + ", n " + std::to_string(n));
        std::vector<double> reach;
        const std::vector<Vec3> x = cloud_around(c.dim, c.lo, c.hi, n, seed++, reach);
        const ReferenceImages ref = reference_images(c.walls, max_order, x, reach);
        WallImages images(c.walls, max_order);
        for (int threads : {1, 2}) {
          omp_set_num_threads(threads);
          images.select(x, reach);
          std::vector<Vec3> y;
          images.positions(x, y);
          ASSERT_EQ(images.sources(), ref.source) << threads << " threads";
          ASSERT_EQ(y, ref.position) << threads << " threads";  // bitwise: Vec3's == compares exactly
        }
        if (n == 9001 && max_order == 3) {
          EXPECT_GT(ref.source.size(), 0u);
        }
      }
    }
  }
  omp_set_num_threads(threads_before);
}

// A wall whose distance() throws inside the parallel loop: select() throws
// it after the loop and leaves no images.
TEST(WallImages, AnExceptionInTheParallelSelectionReachesTheCaller) {
  WallImages images({std::make_shared<ThrowingWall>()});
  std::vector<Vec3> x(5000, Vec3(0.5, 0.0, 0.0));
  images.select(x, std::vector<double>(x.size(), 0.6));
  EXPECT_EQ(images.size(), x.size());
  x[4321] = Vec3(0.95, 0.0, 0.0);
  EXPECT_THROW(images.select(x, std::vector<double>(x.size(), 0.6)), InvalidArgument);
  EXPECT_EQ(images.size(), 0u);
}

TEST(WallImages, DirichletPatchesAreNotMirrored) {
  auto box = make_box(3, Vec3::Zero(), Vec3(2.0, 1.0, 1.0));
  EXPECT_EQ(mirror_walls(*box, {box->patch_by_name("x-")}).size(), 5u);
  auto pipe = make_with_subpatches(make_cylinder(Vec3::Zero(), Vec3(2.0, 0.0, 0.0), 0.5),
                                   {SubPatch{2, Vec3(2.0, 0.0, 0.0), 0.25, "outlet"}});
  EXPECT_EQ(mirror_walls(*pipe).size(), 3u);  // the outlet lies on cap_b's wall
  EXPECT_EQ(mirror_walls(*pipe, {3}).size(), 2u);
  auto csg = make_difference(make_box(3, Vec3::Zero(), Vec3::Ones()), make_ball(3, Vec3::Constant(0.5), 0.2));
  EXPECT_THROW(mirror_walls(*csg), InvalidArgument);
}

namespace {

struct ImageFixture {
  DomainPtr domain;
  ParticleSet ps;
  std::vector<Vec3> x;
  std::vector<double> s;
  std::unique_ptr<Functional> f;
};

ImageFixture make_image_fixture(DomainPtr domain, bool widths, std::size_t n, std::uint64_t seed, double s0 = 0.12) {
  ImageFixture fx;
  fx.domain = domain;
  const int dim = domain->dim();
  Rng rng(seed);
  fx.ps = ParticleSet(dim);
  const Aabb box = domain->bounding_box();
  while (fx.ps.size() < n) {
    Vec3 p = Vec3::Zero();
    for (int k = 0; k < dim; ++k) p[k] = rng.uniform(box.lo[k] - 0.05, box.hi[k] + 0.05);
    if (domain->signed_distance(p) > 0.04) continue;  // a few slightly outside: barrier and outside sources
    fx.ps.add(p, s0 * rng.uniform(0.8, 1.2), 0.02 * rng.uniform(0.5, 1.5));
  }
  FunctionalOptions o;
  o.dt = 0.01;
  o.kappa = 0.7;
  o.rho_ref = 0.3;
  o.optimise_widths = widths;
  fx.f = std::make_unique<Functional>(dim, o, Barrier(domain, 50.0));
  fx.f->set_images(WallImages(mirror_walls(*domain)));
  fx.f->set_reference(fx.ps.positions(), fx.ps.widths(), fx.ps.masses());
  fx.x = fx.ps.positions();
  fx.s = fx.ps.widths();
  for (auto& p : fx.x)
    for (int k = 0; k < dim; ++k) p[k] += 0.01 * rng.normal();
  for (auto& v : fx.s) v *= 1.0 + 0.05 * rng.uniform(-1.0, 1.0);
  return fx;
}

void check_image_gradient(DomainPtr domain, bool widths, double s0 = 0.12) {
  ImageFixture fx = make_image_fixture(domain, widths, 50, 11, s0);
  const int dim = domain->dim();
  Gradient g;
  fx.f->evaluate(fx.x, fx.s, &g);
  ASSERT_GT(fx.f->images().size(), 10u) << "the test must exercise images";
  double gmax = 0.0;
  for (const auto& v : g.x) gmax = std::max(gmax, v.cwiseAbs().maxCoeff());
  for (double v : g.s) gmax = std::max(gmax, std::abs(v));
  ASSERT_GT(gmax, 1e-2);
  const double tol = 1e-6 * gmax;
  for (std::size_t p = 0; p < fx.x.size(); ++p) {
    for (int k = 0; k < dim; ++k) {
      auto fk = [&](double e) {
        auto x = fx.x;
        x[p][k] += e;
        return fx.f->evaluate(x, fx.s, nullptr).total();
      };
      EXPECT_NEAR(g.x[p][k], central_difference(fk, 1e-5), tol) << "particle " << p << " axis " << k;
    }
    if (widths) {
      auto fs = [&](double e) {
        auto s = fx.s;
        s[p] += e;
        return fx.f->evaluate(fx.x, s, nullptr).total();
      };
      EXPECT_NEAR(g.s[p], central_difference(fs, 1e-5), tol) << "width of particle " << p;
    }
  }
  EXPECT_EQ(fx.f->list().build_count(), 1) << "finite differences should not change the image set";
}

}  // namespace

TEST(FunctionalWithImages, GradientMatchesFiniteDifferencesInABoxCorner3D) {
  check_image_gradient(make_box(3, Vec3::Zero(), Vec3(0.6, 0.5, 0.5)), true, 0.06);
}
TEST(FunctionalWithImages, GradientMatchesFiniteDifferencesInASquare2D) {
  check_image_gradient(make_box(2, Vec3::Zero(), Vec3(0.7, 0.5, 0.0)), false, 0.08);
}
TEST(FunctionalWithImages, GradientMatchesFiniteDifferencesInABall3D) {
  check_image_gradient(make_ball(3, Vec3(0.1, 0.0, -0.1), 0.45), true);
}
TEST(FunctionalWithImages, GradientMatchesFiniteDifferencesInADisc2D) {
  check_image_gradient(make_ball(2, Vec3::Zero(), 0.5), true);
}
TEST(FunctionalWithImages, GradientMatchesFiniteDifferencesOnAnInterval1D) {
  check_image_gradient(make_ball(1, Vec3::Zero(), 0.6), false);
}
TEST(FunctionalWithImages, GradientMatchesFiniteDifferencesInACylinderWithRims) {
  check_image_gradient(make_cylinder(Vec3::Zero(), Vec3(0.3, 0.4, 0.2), 0.3), true);
}

TEST(FunctionalWithImages, ListPathMatchesAllPairs) {
  ImageFixture fx = make_image_fixture(make_box(3, Vec3::Zero(), Vec3(0.8, 0.6, 0.5)), true, 120, 5);
  Gradient g1, g2;
  const FunctionalParts a = fx.f->evaluate(fx.x, fx.s, &g1);
  const FunctionalParts b = fx.f->evaluate_all_pairs(fx.x, fx.s, &g2);
  EXPECT_NEAR(a.entropy, b.entropy, 1e-7 * std::abs(b.entropy));
  double gmax = 0.0;
  for (const auto& v : g2.x) gmax = std::max(gmax, v.norm());
  for (std::size_t p = 0; p < fx.x.size(); ++p) {
    EXPECT_NEAR((g1.x[p] - g2.x[p]).norm(), 0.0, 1e-6 * gmax);
    EXPECT_NEAR(g1.s[p], g2.s[p], 1e-6 * gmax);
  }
}

// A lattice at half-spacing offsets in a box with mirrored walls has the
// density of the evenly reflected lattice in the doubled periodic box
// (method of images = even periodic extension), computed here without images.
TEST(FunctionalWithImages, DensityEqualsTheEvenPeriodicExtension) {
  const double h = 0.1, s0 = 0.08;
  const Vec3 len(1.2, 0.9, 0.0);
  auto box = make_box(2, Vec3::Zero(), len);
  ParticleSet inside(2), doubled(2);
  Rng rng(3);
  for (int i = 0; i < 12; ++i)
    for (int j = 0; j < 9; ++j) {
      // Jittered so that the test is not a symmetric special case.
      const Vec3 p((i + 0.5) * h + 0.02 * rng.uniform(-1, 1), (j + 0.5) * h + 0.02 * rng.uniform(-1, 1), 0.0);
      const double m = rng.uniform(0.5, 1.5);
      inside.add(p, s0, m);
      for (int sx = 0; sx < 2; ++sx)
        for (int sy = 0; sy < 2; ++sy)
          doubled.add(Vec3(sx ? -p[0] : p[0], sy ? -p[1] : p[1], 0.0), s0, m);
    }
  FunctionalOptions o;
  Functional with_images(2, o);
  with_images.set_images(WallImages(mirror_walls(*box)));
  with_images.set_reference(inside.positions(), inside.widths(), inside.masses());
  with_images.evaluate(inside.positions(), inside.widths(), nullptr);
  const std::vector<double> rho_images(with_images.entropy().density().begin(),
                                       with_images.entropy().density().begin() + static_cast<long>(inside.size()));
  auto periodic = make_periodic_box(2, -len, len);
  Functional reference(2, o, Barrier(), Periodicity::from_domain(*periodic));
  reference.set_reference(doubled.positions(), doubled.widths(), doubled.masses());
  reference.evaluate_all_pairs(doubled.positions(), doubled.widths(), nullptr);
  for (std::size_t p = 0; p < inside.size(); ++p)
    EXPECT_NEAR(rho_images[p], reference.entropy().density()[4 * p], 1e-7 * reference.entropy().density()[4 * p]);
}

// A uniform state stays put: on a symmetric lattice in a box with images the
// entropy gradient vanishes at every particle; with the barrier alone the
// particles next to the walls are pushed out.
TEST(FunctionalWithImages, UniformLatticeIsStationaryOnlyWithImages) {
  const double h = 0.1;
  auto box = make_box(3, Vec3::Zero(), Vec3(0.8, 0.6, 0.5));
  ParticleSet ps(3);
  for (int i = 0; i < 8; ++i)
    for (int j = 0; j < 6; ++j)
      for (int k = 0; k < 5; ++k) ps.add(Vec3((i + 0.5) * h, (j + 0.5) * h, (k + 0.5) * h), h / std::sqrt(2.0), 1.0);
  auto max_entropy_gradient = [&](bool images) {
    FunctionalOptions o;
    o.dt = 1.0;
    Functional f(3, o, Barrier(box, 1.0));
    if (images) f.set_images(WallImages(mirror_walls(*box)));
    f.set_reference(ps.positions(), ps.widths(), ps.masses());
    Gradient g;
    f.evaluate(ps.positions(), ps.widths(), &g);  // transport and barrier gradients vanish here
    double worst = 0.0;
    for (const auto& v : g.x) worst = std::max(worst, v.norm());
    return worst;
  };
  const double without = max_entropy_gradient(false);
  const double with = max_entropy_gradient(true);
  EXPECT_GT(without, 1.0);
  EXPECT_LT(with, 1e-8 * without);
}

// Tangent-plane images at a circle: the density next to the wall of a smooth
// uniform state is off by O(s / R). Without images it is about half.
TEST(FunctionalWithImages, CurvedWallErrorIsOfOrderWidthOverRadius) {
  const double h = 0.025, s0 = 2.0 * h;  // heavily overlapping blobs: a smooth uniform density
  auto wall_error = [&](double radius, bool images) {
    auto disc = make_ball(2, Vec3::Zero(), radius);
    ParticleSet ps(2);
    const int n = static_cast<int>(std::ceil(radius / h));
    for (int i = -n; i <= n; ++i)
      for (int j = -n; j <= n; ++j) {
        const Vec3 p(i * h, j * h, 0.0);
        if (disc->signed_distance(p) <= 0.0) ps.add(p, s0, h * h);  // density 1 in the bulk
      }
    FunctionalOptions o;
    Functional f(2, o);
    if (images) f.set_images(WallImages(mirror_walls(*disc)));
    f.set_reference(ps.positions(), ps.widths(), ps.masses());
    f.evaluate(ps.positions(), ps.widths(), nullptr);
    // Mean density over the particles within one width s of the wall.
    double sum = 0.0;
    int count = 0;
    for (std::size_t p = 0; p < ps.size(); ++p)
      if (disc->signed_distance(ps.positions()[p]) > -s0) {
        sum += f.entropy().density()[p];
        ++count;
      }
    return std::abs(sum / count - 1.0);
  };
  const double e1 = wall_error(0.5, true), e2 = wall_error(1.0, true);
  // Without images a flat wall keeps a fraction P(inside) = (1 + erf(depth/s))/2
  // of a blob: the deficit averaged over depths [0, s] is
  // (1/2) int_0^1 erfc(t) dt = (1 - erf(1) + (1 - 1/e)/sqrt(pi)) / 2 = 0.2570.
  const double flat_deficit = 0.5 * (1.0 - std::erf(1.0) + (1.0 - std::exp(-1.0)) / std::sqrt(M_PI));
  EXPECT_NEAR(wall_error(0.5, false), flat_deficit, 0.02);
  EXPECT_LT(e1, 0.5 * s0 / 0.5);  // O(s/R)
  EXPECT_LT(e2, 0.7 * e1);        // and first order: halving s/R about halves it
  std::printf("wall density error with tangent-plane images: s/R = %.2f: %.4f, s/R = %.2f: %.4f\n", s0 / 0.5, e1,
              s0 / 1.0, e2);
}

TEST(DomainExtension, MovesOnlyTheListedPatchesOutward) {
  const double w = 0.2;
  auto box = make_box(3, Vec3::Zero(), Vec3(2.0, 1.0, 1.0));
  auto ebox = box->extended({box->patch_by_name("x-")}, w);
  EXPECT_NEAR(ebox->volume(), 2.2, 1e-12);
  EXPECT_NEAR(ebox->signed_distance(Vec3(-0.1, 0.5, 0.5)), -0.1, 1e-12);
  EXPECT_NEAR(ebox->signed_distance(Vec3(1.9, 0.5, 0.5)), -0.1, 1e-12);
  EXPECT_EQ(ebox->patch_name(0), "x-");
  auto ball = make_ball(3, Vec3::Zero(), 1.0);
  EXPECT_NEAR(ball->extended({0}, w)->signed_distance(Vec3::Zero()), -1.2, 1e-12);
  auto cyl = make_cylinder(Vec3::Zero(), Vec3(2.0, 0.0, 0.0), 0.5);
  auto ecyl = cyl->extended({2}, w);
  EXPECT_NEAR(ecyl->volume(), M_PI * 0.25 * 2.2, 1e-12);
  EXPECT_NEAR(cyl->extended({0}, w)->volume(), M_PI * 0.49 * 2.0, 1e-12);
  auto pipe = make_with_subpatches(cyl, {SubPatch{2, Vec3(2.0, 0.0, 0.0), 0.25, "outlet"}});
  EXPECT_NO_THROW(pipe->extended({1}, w));
  EXPECT_THROW(pipe->extended({2}, w), InvalidArgument);  // carries the outlet
  EXPECT_THROW(pipe->extended({3}, w), InvalidArgument);  // a sub-patch
  EXPECT_THROW(box->extended({0}, -1.0), InvalidArgument);
  auto csg = make_difference(box, make_ball(3, Vec3(1.0, 0.5, 0.5), 0.2));
  EXPECT_THROW(csg->extended({0}, w), InvalidArgument);
}

TEST(ReflectInside, PutsParticlesBackAcrossEveryWallTheyCrossed) {
  auto box = make_box(3, Vec3::Zero(), Vec3(2.0, 1.0, 1.0));
  const auto walls = mirror_walls(*box);
  std::vector<Vec3> x = {Vec3(0.5, 0.5, 0.5), Vec3(-0.1, 0.5, 0.5), Vec3(2.05, -0.02, 1.03)};
  EXPECT_EQ(reflect_inside(walls, x), 2u);
  EXPECT_NEAR((x[0] - Vec3(0.5, 0.5, 0.5)).norm(), 0.0, 0.0);
  EXPECT_NEAR((x[1] - Vec3(0.1, 0.5, 0.5)).norm(), 0.0, 1e-15);
  EXPECT_NEAR((x[2] - Vec3(1.95, 0.02, 0.97)).norm(), 0.0, 1e-14);  // a corner: three reflections
  auto ball = make_ball(3, Vec3::Zero(), 1.0);
  std::vector<Vec3> y = {Vec3(0.0, 1.2, 0.0)};
  EXPECT_EQ(reflect_inside(mirror_walls(*ball), y), 1u);
  EXPECT_NEAR((y[0] - Vec3(0.0, 0.8, 0.0)).norm(), 0.0, 1e-15);  // r* = 2R - r
}

// A uniform state stays uniform in a closed square with images: after implicit
// steps from a jittered lattice, the number density within two spacings of the
// walls is within 5% of the interior's, and no particle is outside. With the
// barrier alone the blob-density deficit pushes particles out of the walls.
TEST(FunctionalWithImages, ClosedSquareStaysUniform) {
  const int n_side = 30;
  const double h = 1.0 / n_side;
  auto square = make_box(2, Vec3::Zero(), Vec3(1.0, 1.0, 0.0));
  auto run = [&](bool images, double* outside_fraction) {
    ParticleSet ps(2);
    Rng rng(9);
    for (int i = 0; i < n_side; ++i)
      for (int j = 0; j < n_side; ++j)
        ps.add(Vec3((i + 0.5 + 0.2 * rng.uniform(-1, 1)) * h, (j + 0.5 + 0.2 * rng.uniform(-1, 1)) * h, 0.0),
               h / std::sqrt(2.0), h * h);
    ImplicitOptions o;
    ImplicitStepper stepper(2, o, Barrier(square, 1.0 / (h * h)));
    const auto walls = mirror_walls(*square);
    if (images) stepper.functional().set_images(WallImages(walls));
    int outside_max = 0;
    for (int k = 0; k < 10; ++k) {
      const StepSummary sum = stepper.step(ps, h * h);
      EXPECT_TRUE(sum.accepted) << sum.message;
      int outside = 0;
      for (const Vec3& x : ps.positions()) outside += square->signed_distance(x) > 0.0;
      outside_max = std::max(outside_max, outside);
      if (images) reflect_inside(walls, ps.positions());
    }
    *outside_fraction = static_cast<double>(outside_max) / static_cast<double>(ps.size());
    // Density within 2h of a wall against the interior.
    int near = 0, far = 0;
    for (const Vec3& x : ps.positions()) (square->signed_distance(x) > -2.0 * h ? near : far)++;
    const double near_area = 1.0 - (1.0 - 4.0 * h) * (1.0 - 4.0 * h), far_area = 1.0 - near_area;
    return (near / near_area) / (far / far_area);
  };
  double outside_images = 0.0, outside_barrier = 0.0;
  const double ratio_images = run(true, &outside_images);
  const double ratio_barrier = run(false, &outside_barrier);
  std::printf("wall/interior density: images %.4f (outside %.4f), barrier %.4f (outside %.4f)\n", ratio_images,
              outside_images, ratio_barrier, outside_barrier);
  EXPECT_NEAR(ratio_images, 1.0, 0.05);
  EXPECT_LT(outside_images, 0.01);
  EXPECT_GT(outside_barrier, 0.02);
}
