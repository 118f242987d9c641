// The square pipe with a round obstacle across it ([2025] Sec. 5.3 and the
// examples' square_pipe_occlusion.toml) as one domain class.
#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>
#include <numbers>
#include <string>

#include "geometry_internal.hpp"
#include "otfp/images.hpp"

namespace otfp {

using namespace geometry_detail;

namespace {

// Box [lo, hi] minus a cylinder of radius r whose axis (along `axis`, through
// c) crosses the whole pipe; in 2D a rectangle minus a disc. Because the
// domain is (cross-section minus disc) x (interval), the signed distance is
// exact on both sides: the CSG difference of geometry.hpp is only a lower
// bound outside, with kinks where particles pushed through a wall over the
// obstacle's footprint sit, and the implicit solver then stalls there.
// Patches: the box faces 0 .. 2 dim - 1 (x-, x+, y-, y+, z-, z+), then "obstacle".
class SquarePipeObstacle final : public Domain {
 public:
  SquarePipeObstacle(int dim, const Vec3& lo, const Vec3& hi, int axis, const Vec3& c, double r)
      : dim_(dim), lo_(project(lo, dim)), hi_(project(hi, dim)), axis_(dim == 3 ? axis : -1), c_(project(c, dim)), r_(r) {
    require(dim == 2 || dim == 3, "square pipe dim", dim, "must be 2 or 3");
    check_box(lo, hi, dim, "square pipe");
    check_point(c, "square pipe obstacle centre");
    require(dim == 2 || (axis >= 0 && axis <= 2), "square pipe obstacle axis", axis, "must be 0, 1 or 2");
    double clearance = std::numeric_limits<double>::infinity();
    for (int k = 0; k < dim; ++k)
      if (dim == 2 || k != axis) clearance = std::min({clearance, c[k] - lo[k], hi[k] - c[k]});
    require(std::isfinite(r) && r > 0.0 && r < clearance, "square pipe obstacle radius", r,
            "must be > 0 and < the distance from its axis to the walls (" + std::to_string(clearance) + ")");
    if (dim == 2) {
      u_ = 0;
      v_ = 1;
    } else {
      u_ = axis == 0 ? 1 : 0;
      v_ = axis == 2 ? 1 : 2;
    }
  }
  int dim() const override { return dim_; }
  int num_patches() const override { return 2 * dim_ + 1; }
  int obstacle() const { return 2 * dim_; }
  // Image blobs: the faces are planes, the obstacle a round wall with the domain outside.
  std::shared_ptr<const MirrorWall> patch_wall(int p) const override {
    if (p < 0 || p > obstacle()) throw InvalidArgument("patch = " + std::to_string(p) + ": out of range");
    if (p == obstacle())
      return dim_ == 3 ? make_cylinder_wall(c_, Vec3::Unit(axis_), r_, WallSide::DomainOutside)
                       : make_sphere_wall(2, c_, r_, WallSide::DomainOutside);
    const Vec3 e = Vec3::Unit(p / 2);
    return p % 2 == 0 ? make_plane_wall(lo_, -e) : make_plane_wall(hi_, e);
  }
  std::string patch_name(int p) const override {
    static const char* kNames[6] = {"x-", "x+", "y-", "y+", "z-", "z+"};
    if (p == obstacle()) return "obstacle";
    if (p < 0 || p > obstacle()) throw InvalidArgument("patch = " + std::to_string(p) + ": out of range");
    return kNames[p];
  }
  Aabb bounding_box() const override { return Aabb{lo_, hi_}; }
  double height() const { return dim_ == 3 ? hi_[axis_] - lo_[axis_] : 1.0; }
  double volume() const override {
    double v = 1.0;
    for (int k = 0; k < dim_; ++k) v *= hi_[k] - lo_[k];
    return v - std::numbers::pi * r_ * r_ * height();
  }
  double patch_area(int p) const override {
    if (p == obstacle()) return 2.0 * std::numbers::pi * r_ * height();
    if (p < 0 || p > obstacle()) throw InvalidArgument("patch = " + std::to_string(p) + ": out of range");
    const int k = p / 2;
    double a = 1.0;
    for (int j = 0; j < dim_; ++j)
      if (j != k) a *= hi_[j] - lo_[j];
    return k == axis_ ? a - std::numbers::pi * r_ * r_ : a;
  }

  BoundaryQuery query(const Vec3& xin) const override {
    const Vec3 x = project(xin, dim_);
    const double du = x[u_] - c_[u_], dv = x[v_] - c_[v_];
    const double rho = std::hypot(du, dv);
    bool in_box = true;
    for (int k = 0; k < dim_; ++k) in_box = in_box && x[k] >= lo_[k] && x[k] <= hi_[k];
    BoundaryQuery q;
    const Vec3 on_circle = rim_point(x, du, dv, rho);
    if (in_box && rho >= r_) {
      // Inside (or on the boundary): the nearest wall or the obstacle.
      double best = rho - r_;
      q.patch = obstacle();
      q.closest_point = on_circle;
      for (int k = 0; k < dim_; ++k) {
        if (x[k] - lo_[k] < best) {
          best = x[k] - lo_[k];
          q.patch = 2 * k;
          q.closest_point = x;
          q.closest_point[k] = lo_[k];
        }
        if (hi_[k] - x[k] < best) {
          best = hi_[k] - x[k];
          q.patch = 2 * k + 1;
          q.closest_point = x;
          q.closest_point[k] = hi_[k];
        }
      }
      q.signed_distance = -best;
      return q;
    }
    // Outside: cross-section part and axial part combine in quadrature.
    Vec3 cp = x;
    double d2 = 0.0;
    int patch2 = -1;
    if (rho < r_) {
      cp[u_] = on_circle[u_];
      cp[v_] = on_circle[v_];
      d2 = r_ - rho;
      patch2 = obstacle();
    } else {
      double best_excess = 0.0;
      double e2 = 0.0;
      for (int k : {u_, v_}) {
        const double below = lo_[k] - x[k], above = x[k] - hi_[k];
        const double e = std::max({below, above, 0.0});
        if (e > 0.0) {
          cp[k] = below > 0.0 ? lo_[k] : hi_[k];
          e2 += e * e;
          if (e > best_excess) {
            best_excess = e;
            patch2 = 2 * k + (below > 0.0 ? 0 : 1);
          }
        }
      }
      d2 = std::sqrt(e2);
    }
    double dz = 0.0;
    int patchz = -1;
    if (axis_ >= 0) {
      const int a = axis_;
      const double below = lo_[a] - x[a], above = x[a] - hi_[a];
      if (below > 0.0) {
        dz = below;
        cp[a] = lo_[a];
        patchz = 2 * a;
      } else if (above > 0.0) {
        dz = above;
        cp[a] = hi_[a];
        patchz = 2 * a + 1;
      }
    }
    q.signed_distance = std::hypot(d2, dz);
    q.closest_point = cp;
    q.patch = d2 >= dz ? patch2 : patchz;
    return q;
  }

 private:
  Vec3 rim_point(const Vec3& x, double du, double dv, double rho) const {
    Vec3 p = x;
    if (rho > 0.0) {
      p[u_] = c_[u_] + r_ * du / rho;
      p[v_] = c_[v_] + r_ * dv / rho;
    } else {
      p[u_] = c_[u_] + r_;
      p[v_] = c_[v_];
    }
    return p;
  }
  int dim_;
  Vec3 lo_, hi_;
  int axis_;  // -1 in 2D
  Vec3 c_;
  double r_;
  int u_ = 0, v_ = 1;  // cross-section axes
};

}  // namespace

DomainPtr make_square_pipe_obstacle(int dim, const Vec3& lo, const Vec3& hi, int axis, const Vec3& obstacle_center,
                                    double radius) {
  return std::make_shared<SquarePipeObstacle>(dim, lo, hi, axis, obstacle_center, radius);
}

}  // namespace otfp
