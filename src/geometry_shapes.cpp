// The primitive domains, with closed-form volumes, patch areas and layer
// cells: ball (disc, interval), axis-aligned box, capped cylinder, periodic box.
#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "geometry_internal.hpp"
#include "otfp/images.hpp"

namespace otfp {

using namespace geometry_detail;

namespace {

// A layer part's volume from its two halves' closed forms.
double layer_part_volume(LayerPart part, double interior, double exterior) {
  switch (part) {
    case LayerPart::Interior: return interior;
    case LayerPart::Exterior: return exterior;
    case LayerPart::Whole: return interior + exterior;
  }
  return 0.0;
}

void check_dim(int dim) { require(dim >= 1 && dim <= 3, "dim", dim, "must be 1, 2 or 3"); }

double unit_ball_volume(int dim) {
  switch (dim) {
    case 1: return 2.0;
    case 2: return kPi;
    default: return 4.0 / 3.0 * kPi;
  }
}

// ---------------------------------------------------------------------------
// Ball / disc / interval

class Ball final : public Domain {
 public:
  Ball(int dim, const Vec3& center, double radius) : dim_(dim), c_(project(center, dim)), r_(radius) {
    check_dim(dim);
    check_point(center, "ball center");
    require(std::isfinite(radius) && radius > 0.0, "ball radius", radius, "must be finite and > 0");
    wall_ = make_sphere_wall(dim_, c_, r_);
  }

  std::shared_ptr<const MirrorWall> patch_wall(int patch) const override {
    check_patch(*this, patch);
    return wall_;
  }

  DomainPtr extended(const std::vector<int>& patches, double w) const override {
    check_extension(*this, patches, w);
    return make_ball(dim_, c_, patches.empty() ? r_ : r_ + w);
  }

  double radius() const { return r_; }
  const Vec3& center() const { return c_; }

  int dim() const override { return dim_; }

  BoundaryQuery query(const Vec3& x) const override {
    const Vec3 v = project(x, dim_) - c_;
    const double n = v.norm();
    BoundaryQuery q;
    q.signed_distance = n - r_;
    // At the centre every boundary point is closest; take the +x one.
    q.closest_point = n > 0.0 ? Vec3(c_ + (r_ / n) * v) : Vec3(c_ + r_ * Vec3::UnitX());
    q.patch = 0;
    return q;
  }

  double volume() const override { return unit_ball_volume(dim_) * std::pow(r_, dim_); }
  int num_patches() const override { return 1; }

  double patch_area(int patch) const override {
    check_patch(*this, patch);
    switch (dim_) {
      case 1: return 2.0;  // two end points, counting measure
      case 2: return 2.0 * kPi * r_;
      default: return 4.0 * kPi * r_ * r_;
    }
  }

  std::string patch_name(int patch) const override {
    check_patch(*this, patch);
    return "surface";
  }

  Aabb bounding_box() const override { return inflate(Aabb{c_, c_}, dim_, r_); }
  Vec3 inertia_center() const override { return c_; }
  // d / (d + 2) R^2 about the centre (a ball's second moment), plus the offset.
  double mean_square_distance(const Vec3& c) const override {
    return dim_ / (dim_ + 2.0) * r_ * r_ + (c_ - project(c, dim_)).squaredNorm();
  }

  std::optional<DomainShape> shape() const override {
    DomainShape sh;
    sh.kind = DomainShape::Kind::Ball;
    sh.dim = dim_;
    sh.center = c_;
    sh.radius = r_;
    return sh;
  }

  // Spherical shell between the inner and outer radius of the part.
  double layer_cell_volume(int patch, double b, LayerPart part, int /*samples*/) const override {
    check_patch(*this, patch);
    check_thickness(b);
    const double inner = part == LayerPart::Exterior ? r_ : std::max(r_ - b, 0.0);
    const double outer = part == LayerPart::Interior ? r_ : r_ + b;
    return unit_ball_volume(dim_) * (std::pow(outer, dim_) - std::pow(inner, dim_));
  }

 private:
  int dim_;
  Vec3 c_;
  double r_;
  std::shared_ptr<const MirrorWall> wall_;
};

// ---------------------------------------------------------------------------
// Axis-aligned box

class Box final : public Domain {
 public:
  Box(int dim, const Vec3& lo, const Vec3& hi) : dim_(dim), lo_(project(lo, dim)), hi_(project(hi, dim)) {
    check_dim(dim);
    check_box(lo, hi, dim, "box");
    for (int f = 0; f < 2 * dim_; ++f) {
      const int k = f / 2;
      const Vec3 e = Vec3::Unit(k);
      walls_.push_back(f % 2 == 0 ? make_plane_wall(lo_, -e) : make_plane_wall(hi_, e));
    }
  }

  std::shared_ptr<const MirrorWall> patch_wall(int patch) const override {
    check_patch(*this, patch);
    return walls_[static_cast<std::size_t>(patch)];
  }

  DomainPtr extended(const std::vector<int>& patches, double w) const override {
    check_extension(*this, patches, w);
    Vec3 lo = lo_, hi = hi_;
    for (int p : patches) (p % 2 == 0 ? lo : hi)[p / 2] += (p % 2 == 0 ? -w : w);
    return make_box(dim_, lo, hi);
  }

  int dim() const override { return dim_; }

  BoundaryQuery query(const Vec3& x) const override {
    const Vec3 y = project(x, dim_);
    BoundaryQuery q;
    // Outside: the closest point is the clamp; the patch is the face along
    // the axis with the largest violation (lowest axis on ties).
    int worst_axis = -1;
    double worst = 0.0;
    for (int k = 0; k < dim_; ++k) {
      const double v = std::max(lo_[k] - y[k], y[k] - hi_[k]);
      if (v > worst) {
        worst = v;
        worst_axis = k;
      }
    }
    if (worst_axis >= 0) {
      q.closest_point = y.cwiseMax(lo_).cwiseMin(hi_);
      q.signed_distance = (y - q.closest_point).norm();
      q.patch = 2 * worst_axis + (y[worst_axis] < lo_[worst_axis] ? 0 : 1);
      return q;
    }
    // Inside (or on the boundary): the nearest face, lowest index on ties.
    double best = std::numeric_limits<double>::infinity();
    int face = 0;
    for (int f = 0; f < 2 * dim_; ++f) {
      const int k = f / 2;
      const double dist = (f % 2 == 0) ? y[k] - lo_[k] : hi_[k] - y[k];
      if (dist < best) {
        best = dist;
        face = f;
      }
    }
    q.signed_distance = -best;
    q.closest_point = y;
    q.closest_point[face / 2] = (face % 2 == 0) ? lo_[face / 2] : hi_[face / 2];
    q.patch = face;
    return q;
  }

  double volume() const override { return box_measure(bounding_box(), dim_); }
  double mean_square_distance(const Vec3& c) const override { return box_mean_square(bounding_box(), dim_, c); }
  int num_patches() const override { return 2 * dim_; }

  double patch_area(int patch) const override {
    check_patch(*this, patch);
    double a = 1.0;  // in d = 1 a face is one point
    for (int j = 0; j < dim_; ++j)
      if (j != patch / 2) a *= hi_[j] - lo_[j];
    return a;
  }

  std::string patch_name(int patch) const override {
    check_patch(*this, patch);
    static const char* kNames[6] = {"x-", "x+", "y-", "y+", "z-", "z+"};
    return kNames[patch];
  }

  Aabb bounding_box() const override { return Aabb{lo_, hi_}; }

  std::optional<DomainShape> shape() const override {
    DomainShape sh;
    sh.kind = DomainShape::Kind::Box;
    sh.dim = dim_;
    sh.lo = lo_;
    sh.hi = hi_;
    return sh;
  }

  // The face inflated by b: every layer point is within b of its face.
  Aabb layer_bounding_box(int patch, double b) const override {
    Aabb box = Domain::layer_bounding_box(patch, b);
    const int k = patch / 2;
    const double f = (patch % 2 == 0) ? lo_[k] : hi_[k];
    box.lo[k] = f - b;
    box.hi[k] = f + b;
    return box;
  }

  // Exact. Interior: the points at depth t <= b from face l that are not
  // closer to another face form a rectangle shrunk by 2t in each tangential
  // side, for t <= min side/2. Exterior: the slab over the face plus the share
  // of the edge wedges and corner octants (split by the largest violation, so
  // each face gets 1/2 of a wedge and 1/3 of an octant).
  double layer_cell_volume(int patch, double b, LayerPart part, int /*samples*/) const override {
    check_patch(*this, patch);
    check_thickness(b);
    const int k = patch / 2;
    double side[2] = {0.0, 0.0};
    int n = 0;
    double t = b;
    for (int j = 0; j < dim_; ++j) {
      const double len = hi_[j] - lo_[j];
      t = std::min(t, 0.5 * len);
      if (j != k) side[n++] = len;
    }
    double interior = 0.0, exterior = 0.0;
    if (n == 0) {
      interior = t;
      exterior = b;
    } else if (n == 1) {
      interior = side[0] * t - t * t;
      exterior = side[0] * b + kPi * b * b / 4.0;
    } else {
      interior = side[0] * side[1] * t - (side[0] + side[1]) * t * t + 4.0 * t * t * t / 3.0;
      exterior = side[0] * side[1] * b + (side[0] + side[1]) * kPi * b * b / 4.0 + 2.0 * kPi * b * b * b / 9.0;
    }
    return layer_part_volume(part, interior, exterior);
  }

 private:
  int dim_;
  Vec3 lo_, hi_;
  std::vector<std::shared_ptr<const MirrorWall>> walls_;
};

// ---------------------------------------------------------------------------
// Finite capped cylinder (3D)

class Cylinder final : public Domain {
 public:
  Cylinder(const Vec3& a, const Vec3& b, double radius) : a_(a), b_(b), r_(radius) {
    check_point(a, "cylinder end a");
    check_point(b, "cylinder end b");
    require(std::isfinite(radius) && radius > 0.0, "cylinder radius", radius, "must be finite and > 0");
    len_ = (b - a).norm();
    require(len_ > 0.0, "cylinder length |b - a|", len_, "must be > 0 (a != b)");
    u_ = (b - a) / len_;
    // A fixed unit normal to the axis, for points on the axis itself.
    int e = 0;
    for (int k = 1; k < 3; ++k)
      if (std::abs(u_[k]) < std::abs(u_[e])) e = k;
    const Vec3 ek = Vec3::Unit(e);
    perp_ = (ek - ek.dot(u_) * u_).normalized();
    walls_ = {make_cylinder_wall(a_, u_, r_), make_plane_wall(a_, -u_), make_plane_wall(b_, u_)};
  }

  std::shared_ptr<const MirrorWall> patch_wall(int patch) const override {
    check_patch(*this, patch);
    return walls_[static_cast<std::size_t>(patch)];
  }

  DomainPtr extended(const std::vector<int>& patches, double w) const override {
    check_extension(*this, patches, w);
    Vec3 a = a_, b = b_;
    double r = r_;
    for (int p : patches) {
      if (p == 0) r += w;
      else if (p == 1) a -= w * u_;
      else b += w * u_;
    }
    return make_cylinder(a, b, r);
  }

  int dim() const override { return 3; }

  BoundaryQuery query(const Vec3& x) const override {
    const Vec3 d = x - a_;
    const double s = d.dot(u_);  // axial coordinate, 0 at a, len_ at b
    const Vec3 p = d - s * u_;
    const double rho = p.norm();
    const Vec3 dir = rho > 0.0 ? Vec3(p / rho) : perp_;
    BoundaryQuery q;
    if (s >= 0.0 && s <= len_ && rho <= r_) {
      // Inside: the nearest of lateral / cap_a / cap_b, lowest id on ties.
      const double dist[3] = {r_ - rho, s, len_ - s};
      int best = 0;
      for (int i = 1; i < 3; ++i)
        if (dist[i] < dist[best]) best = i;
      q.signed_distance = -dist[best];
      q.patch = best;
      if (best == 0) q.closest_point = a_ + s * u_ + r_ * dir;
      else if (best == 1) q.closest_point = x - s * u_;
      else q.closest_point = x + (len_ - s) * u_;
      return q;
    }
    // Outside: radial and axial excess; in the rim region the closest point
    // is on the rim and the patch goes to the larger excess (lateral on ties),
    // the same rule as the box edges.
    const double dr = std::max(rho - r_, 0.0);
    const double ds = s < 0.0 ? -s : (s > len_ ? s - len_ : 0.0);
    q.signed_distance = std::hypot(dr, ds);
    q.closest_point = a_ + std::clamp(s, 0.0, len_) * u_ + std::min(rho, r_) * dir;
    q.patch = dr >= ds ? 0 : (s < 0.0 ? 1 : 2);
    return q;
  }

  double volume() const override { return kPi * r_ * r_ * len_; }
  Vec3 inertia_center() const override { return 0.5 * (a_ + b_); }
  // R^2 / 2 across the axis and len^2 / 12 along it, plus the offset.
  double mean_square_distance(const Vec3& c) const override {
    return r_ * r_ / 2.0 + len_ * len_ / 12.0 + (0.5 * (a_ + b_) - c).squaredNorm();
  }
  int num_patches() const override { return 3; }

  double patch_area(int patch) const override {
    check_patch(*this, patch);
    return patch == 0 ? 2.0 * kPi * r_ * len_ : kPi * r_ * r_;
  }

  std::string patch_name(int patch) const override {
    check_patch(*this, patch);
    static const char* kNames[3] = {"lateral", "cap_a", "cap_b"};
    return kNames[patch];
  }

  std::optional<DomainShape> shape() const override {
    DomainShape sh;
    sh.kind = DomainShape::Kind::Cylinder;
    sh.dim = 3;
    sh.radius = r_;
    sh.end_a = a_;
    sh.end_b = b_;
    return sh;
  }

  Aabb bounding_box() const override {
    Aabb box{a_.cwiseMin(b_), a_.cwiseMax(b_)};
    for (int k = 0; k < 3; ++k) {
      // Half-extent of a disc of radius r with normal u along axis k.
      const double h = r_ * std::sqrt(std::max(0.0, 1.0 - u_[k] * u_[k]));
      box.lo[k] -= h;
      box.hi[k] += h;
    }
    return box;
  }

  // Cap cells lie within b of their disc; the lateral one uses the default.
  Aabb layer_bounding_box(int patch, double b) const override {
    Aabb box = Domain::layer_bounding_box(patch, b);
    if (patch == 0) return box;
    const Vec3& c = patch == 1 ? a_ : b_;
    for (int k = 0; k < 3; ++k) {
      const double h = r_ * std::sqrt(std::max(0.0, 1.0 - u_[k] * u_[k])) + b;
      box.lo[k] = c[k] - h;
      box.hi[k] = c[k] + h;
    }
    return box;
  }

  // Exact. Interior at depth t: lateral ring of radius r-t and length L-2t,
  // cap disc of radius r-t, for t <= min(b, r, L/2). Exterior: the shell or
  // slab plus the share of the rim torus (a quarter disc of radius b swept
  // around the axis at r, split at 45 degrees), by Pappus' theorem.
  double layer_cell_volume(int patch, double b, LayerPart part, int /*samples*/) const override {
    check_patch(*this, patch);
    check_thickness(b);
    const double r = r_, len = len_;
    const double t = std::min({b, r, 0.5 * len});
    const double s2 = std::sqrt(0.5);
    double interior = 0.0, exterior = 0.0;
    if (patch == 0) {
      interior = 2.0 * kPi * (r * len * t - (2.0 * r + len) * t * t / 2.0 + 2.0 * t * t * t / 3.0);
      const double rim = 2.0 * kPi * (r * kPi * b * b / 8.0 + b * b * b * s2 / 3.0);
      exterior = kPi * ((r + b) * (r + b) - r * r) * len + 2.0 * rim;
    } else {
      interior = kPi * (r * r * r - (r - t) * (r - t) * (r - t)) / 3.0;
      const double rim = 2.0 * kPi * (r * kPi * b * b / 8.0 + b * b * b * (1.0 - s2) / 3.0);
      exterior = kPi * r * r * b + rim;
    }
    return layer_part_volume(part, interior, exterior);
  }

 private:
  Vec3 a_, b_;
  double r_;
  double len_ = 0.0;
  Vec3 u_ = Vec3::UnitZ();
  Vec3 perp_ = Vec3::UnitX();
  std::vector<std::shared_ptr<const MirrorWall>> walls_;
};

// ---------------------------------------------------------------------------
// Domains without a boundary: every point is interior, none is near a patch.

BoundaryQuery no_boundary(const Vec3& x) {
  BoundaryQuery q;
  q.signed_distance = -std::numeric_limits<double>::infinity();
  q.closest_point = x;
  q.patch = -1;
  return q;
}

// Unbounded space for free diffusion: no boundary, no patches. The box
// [lo, hi] only serves an initial uniform fill, the spacing rule and the
// reference volume.
class FreeSpace final : public Domain {
 public:
  FreeSpace(int dim, const Vec3& lo, const Vec3& hi) : dim_(dim), box_{project(lo, dim), project(hi, dim)} {
    check_dim(dim);
    check_box(lo, hi, dim, "free space");
  }
  int dim() const override { return dim_; }
  BoundaryQuery query(const Vec3& x) const override { return no_boundary(x); }
  double volume() const override { return box_measure(box_, dim_); }
  double mean_square_distance(const Vec3& c) const override { return box_mean_square(box_, dim_, c); }
  int num_patches() const override { return 0; }
  double patch_area(int patch) const override {
    throw InvalidArgument("patch = " + std::to_string(patch) + ": free space has no patches");
  }
  Aabb bounding_box() const override { return box_; }

 private:
  int dim_;
  Aabb box_;
};

// ---------------------------------------------------------------------------
// Periodic box

class PeriodicBox final : public Domain {
 public:
  PeriodicBox(int dim, const Vec3& lo, const Vec3& hi) : dim_(dim), lo_(project(lo, dim)), hi_(project(hi, dim)) {
    check_dim(dim);
    check_box(lo, hi, dim, "periodic box");
  }

  int dim() const override { return dim_; }

  BoundaryQuery query(const Vec3& x) const override { return no_boundary(x); }

  double volume() const override { return box_measure(bounding_box(), dim_); }
  double mean_square_distance(const Vec3& c) const override { return box_mean_square(bounding_box(), dim_, c); }
  int num_patches() const override { return 0; }
  double patch_area(int patch) const override {
    check_patch(*this, patch);  // always throws: there are no patches
    return 0.0;
  }
  Aabb bounding_box() const override { return Aabb{lo_, hi_}; }

  bool is_periodic() const override { return true; }
  Vec3 period() const override { return hi_ - lo_; }

  Vec3 wrap(const Vec3& x) const override {
    Vec3 y = project(x, dim_);
    for (int k = 0; k < dim_; ++k) {
      const double len = hi_[k] - lo_[k];
      double v = lo_[k] + std::fmod(y[k] - lo_[k], len);
      if (v < lo_[k]) v += len;
      // fmod of a tiny negative number plus len can round up to hi.
      if (v >= hi_[k]) v = lo_[k];
      y[k] = v;
    }
    return y;
  }

  Vec3 sample_interior(Rng& rng) const override { return uniform_in(bounding_box(), dim_, rng); }

 private:
  int dim_;
  Vec3 lo_, hi_;
};

}  // namespace

namespace geometry_detail {

bool is_convex_shape(const Domain& d) {
  return dynamic_cast<const Ball*>(&d) || dynamic_cast<const Box*>(&d) || dynamic_cast<const Cylinder*>(&d);
}

std::optional<BallGeometry> as_ball(const Domain& d) {
  const Ball* ball = dynamic_cast<const Ball*>(&d);
  if (!ball) return std::nullopt;
  return BallGeometry{ball->center(), ball->radius()};
}

}  // namespace geometry_detail

DomainPtr make_ball(int dim, const Vec3& center, double radius) {
  return std::make_shared<Ball>(dim, center, radius);
}

DomainPtr make_box(int dim, const Vec3& lo, const Vec3& hi) { return std::make_shared<Box>(dim, lo, hi); }

DomainPtr make_cylinder(const Vec3& a, const Vec3& b, double radius) {
  return std::make_shared<Cylinder>(a, b, radius);
}

DomainPtr make_periodic_box(int dim, const Vec3& lo, const Vec3& hi) {
  return std::make_shared<PeriodicBox>(dim, lo, hi);
}

DomainPtr make_free_space(int dim, const Vec3& lo, const Vec3& hi) { return std::make_shared<FreeSpace>(dim, lo, hi); }

}  // namespace otfp
