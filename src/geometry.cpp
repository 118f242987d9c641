#include "otfp/geometry.hpp"

#include "otfp/images.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <memory>
#include <mutex>
#include <numbers>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace otfp {

namespace {

constexpr double kPi = std::numbers::pi;
// Fixed seed: Monte Carlo volumes must be reproducible run to run.
constexpr std::uint64_t kMonteCarloSeed = 0x6f74667067656f6dULL;
constexpr long kMaxRejectionTries = 10'000'000;
// CSG volumes and patch areas: 2e6 samples give ~1e-4 relative noise.
constexpr int kCsgSamples = 2'000'000;
// Shell half-thickness for CSG patch areas, relative to the box diagonal.
constexpr double kCsgShellFraction = 2e-3;

Vec3 project(const Vec3& x, int dim) {
  Vec3 y = x;
  for (int k = dim; k < 3; ++k) y[k] = 0.0;
  return y;
}

void check_dim(int dim) { require(dim >= 1 && dim <= 3, "dim", dim, "must be 1, 2 or 3"); }

void check_point(const Vec3& x, const std::string& field) {
  require(x.allFinite(), field, x.norm(), "must be finite");
}

void check_patch(const Domain& d, int patch) {
  require(patch >= 0 && patch < d.num_patches(), "patch", patch,
          "must be in [0, " + std::to_string(d.num_patches()) + ")");
}

void check_thickness(double b) {
  require(std::isfinite(b) && b > 0.0, "layer half-thickness b", b, "must be finite and > 0");
}

void check_extension(const Domain& d, const std::vector<int>& patches, double w) {
  require(std::isfinite(w) && w > 0.0, "extension thickness w", w, "must be finite and > 0");
  for (int p : patches) check_patch(d, p);
}

double unit_ball_volume(int dim) {
  switch (dim) {
    case 1: return 2.0;
    case 2: return kPi;
    default: return 4.0 / 3.0 * kPi;
  }
}

Aabb inflate(const Aabb& box, int dim, double b) {
  Aabb out = box;
  for (int k = 0; k < dim; ++k) {
    out.lo[k] -= b;
    out.hi[k] += b;
  }
  return out;
}

Aabb intersect(const Aabb& p, const Aabb& q) {
  return Aabb{p.lo.cwiseMax(q.lo), p.hi.cwiseMin(q.hi)};
}

bool is_empty(const Aabb& box, int dim) {
  for (int k = 0; k < dim; ++k)
    if (!(box.hi[k] > box.lo[k])) return true;
  return false;
}

bool disjoint(const Aabb& p, const Aabb& q, int dim) {
  for (int k = 0; k < dim; ++k)
    if (p.hi[k] < q.lo[k] || q.hi[k] < p.lo[k]) return true;
  return false;
}

double box_measure(const Aabb& box, int dim) {
  double v = 1.0;
  for (int k = 0; k < dim; ++k) v *= std::max(box.hi[k] - box.lo[k], 0.0);
  return v;
}

double box_diagonal(const Aabb& box, int dim) {
  double s = 0.0;
  for (int k = 0; k < dim; ++k) s += (box.hi[k] - box.lo[k]) * (box.hi[k] - box.lo[k]);
  return std::sqrt(s);
}

// All 2^dim corners (the unused axes stay at the box's value, i.e. 0).
std::vector<Vec3> corners(const Aabb& box, int dim) {
  std::vector<Vec3> out;
  for (int mask = 0; mask < (1 << dim); ++mask) {
    Vec3 c = box.lo;
    for (int k = 0; k < dim; ++k)
      if (mask & (1 << k)) c[k] = box.hi[k];
    out.push_back(c);
  }
  return out;
}

Vec3 uniform_in(const Aabb& box, int dim, Rng& rng) {
  Vec3 x = Vec3::Zero();
  for (int k = 0; k < dim; ++k) x[k] = rng.uniform(box.lo[k], box.hi[k]);
  return x;
}

}  // namespace

// ---------------------------------------------------------------------------
// Domain defaults

template <class Pred>
double Domain::monte_carlo_volume(const Aabb& box, int dim, int samples, Pred pred) {
  require(samples > 0, "samples", samples, "must be > 0");
  if (is_empty(box, dim)) return 0.0;
  Rng rng(kMonteCarloSeed);
  long hits = 0;
  for (int i = 0; i < samples; ++i)
    if (pred(uniform_in(box, dim, rng))) ++hits;
  return box_measure(box, dim) * static_cast<double>(hits) / static_cast<double>(samples);
}

std::shared_ptr<const MirrorWall> Domain::patch_wall(int patch) const {
  check_patch(*this, patch);
  return nullptr;
}

DomainPtr Domain::extended(const std::vector<int>& patches, double w) const {
  require(patches.empty(), "extended patch", patches.empty() ? "" : patch_name(patches.front()),
          "this domain cannot be extended over its patches");
  (void)w;
  return nullptr;
}

std::string Domain::patch_name(int patch) const {
  check_patch(*this, patch);
  return "patch" + std::to_string(patch);
}

int Domain::patch_by_name(const std::string& name) const {
  for (int p = 0; p < num_patches(); ++p)
    if (patch_name(p) == name) return p;
  return -1;
}

bool Domain::in_layer_cell(const Vec3& x, int patch, double b, LayerPart part) const {
  const BoundaryQuery q = query(x);
  if (q.patch != patch || patch < 0) return false;
  const double sd = q.signed_distance;
  switch (part) {
    case LayerPart::Interior: return sd >= -b && sd <= 0.0;
    case LayerPart::Exterior: return sd > 0.0 && sd <= b;
    case LayerPart::Whole: return std::abs(sd) <= b;
  }
  return false;
}

Vec3 Domain::sample_interior(Rng& rng) const {
  const Aabb box = bounding_box();
  const int d = dim();
  for (long i = 0; i < kMaxRejectionTries; ++i) {
    const Vec3 x = uniform_in(box, d, rng);
    if (contains(x)) return x;
  }
  throw std::runtime_error("sample_interior: no point of the domain found in " +
                           std::to_string(kMaxRejectionTries) + " tries (empty domain?)");
}

Vec3 Domain::sample_layer_cell(int patch, double b, LayerPart part, Rng& rng) const {
  check_patch(*this, patch);
  check_thickness(b);
  const Aabb box = layer_bounding_box(patch, b);
  const int d = dim();
  if (!is_empty(box, d)) {
    for (long i = 0; i < kMaxRejectionTries; ++i) {
      const Vec3 x = uniform_in(box, d, rng);
      if (in_layer_cell(x, patch, b, part)) return x;
    }
  }
  throw std::runtime_error("sample_layer_cell: no point of the layer cell of patch '" + patch_name(patch) +
                           "' (b = " + std::to_string(b) + ") found in " +
                           std::to_string(kMaxRejectionTries) + " tries (empty cell?)");
}

Aabb Domain::layer_bounding_box(int patch, double b) const {
  check_patch(*this, patch);
  require(std::isfinite(b) && b >= 0.0, "layer half-thickness b", b, "must be finite and >= 0");
  return inflate(bounding_box(), dim(), b);
}

double Domain::layer_cell_volume(int patch, double b, LayerPart part, int samples) const {
  check_patch(*this, patch);
  check_thickness(b);
  return monte_carlo_volume(layer_bounding_box(patch, b), dim(), samples,
                            [&](const Vec3& x) { return in_layer_cell(x, patch, b, part); });
}

namespace {

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
    check_point(lo, "box lo");
    check_point(hi, "box hi");
    static const char* kAxis[3] = {"x", "y", "z"};
    for (int k = 0; k < dim; ++k)
      require(lo[k] < hi[k], std::string("box hi.") + kAxis[k], hi[k],
              "must be > lo." + std::string(kAxis[k]) + " = " + std::to_string(lo[k]));
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
    switch (part) {
      case LayerPart::Interior: return interior;
      case LayerPart::Exterior: return exterior;
      case LayerPart::Whole: return interior + exterior;
    }
    return 0.0;
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
    switch (part) {
      case LayerPart::Interior: return interior;
      case LayerPart::Exterior: return exterior;
      case LayerPart::Whole: return interior + exterior;
    }
    return 0.0;
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
// Periodic box

class PeriodicBox final : public Domain {
 public:
  PeriodicBox(int dim, const Vec3& lo, const Vec3& hi) : dim_(dim), lo_(project(lo, dim)), hi_(project(hi, dim)) {
    check_dim(dim);
    check_point(lo, "periodic box lo");
    check_point(hi, "periodic box hi");
    static const char* kAxis[3] = {"x", "y", "z"};
    for (int k = 0; k < dim; ++k)
      require(lo[k] < hi[k], std::string("periodic box hi.") + kAxis[k], hi[k],
              "must be > lo." + std::string(kAxis[k]) + " = " + std::to_string(lo[k]));
  }

  int dim() const override { return dim_; }

  BoundaryQuery query(const Vec3& x) const override {
    BoundaryQuery q;
    q.signed_distance = -std::numeric_limits<double>::infinity();
    q.closest_point = x;
    q.patch = -1;
    return q;
  }

  double volume() const override { return box_measure(bounding_box(), dim_); }
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

// ---------------------------------------------------------------------------
// Sub-patches

class SubPatchDomain final : public Domain {
 public:
  SubPatchDomain(DomainPtr base, std::vector<SubPatch> subs) : base_(std::move(base)), subs_(std::move(subs)) {
    require(base_ != nullptr, "base domain", "null", "must not be null");
    nb_ = base_->num_patches();
    const double scale = std::max(box_diagonal(base_->bounding_box(), base_->dim()), 1.0);
    for (std::size_t i = 0; i < subs_.size(); ++i) {
      SubPatch& s = subs_[i];
      const std::string tag = "sub-patch '" + s.name + "'";
      require(!s.name.empty(), "sub-patch " + std::to_string(i) + " name", s.name, "must not be empty");
      require(s.base_patch >= 0 && s.base_patch < nb_, tag + " base_patch", s.base_patch,
              "must be in [0, " + std::to_string(nb_) + ")");
      require(std::isfinite(s.radius) && s.radius > 0.0, tag + " radius", s.radius, "must be finite and > 0");
      check_point(s.center, tag + " center");
      s.center = project(s.center, base_->dim());
      const double sd = base_->signed_distance(s.center);
      require(std::abs(sd) <= 1e-8 * scale, tag + " center signed distance", sd,
              "the center must lie on the boundary of the base domain");
    }
  }

  const Domain& base() const { return *base_; }

  int dim() const override { return base_->dim(); }

  BoundaryQuery query(const Vec3& x) const override {
    BoundaryQuery q = base_->query(x);
    for (std::size_t i = 0; i < subs_.size(); ++i) {
      const SubPatch& s = subs_[i];
      if (q.patch == s.base_patch && (q.closest_point - s.center).norm() <= s.radius) {
        q.patch = nb_ + static_cast<int>(i);
        break;
      }
    }
    return q;
  }

  double volume() const override { return base_->volume(); }
  int num_patches() const override { return nb_ + static_cast<int>(subs_.size()); }

  // Base patches lose the area of their sub-patches (assumed disjoint and
  // entirely on the patch).
  double patch_area(int patch) const override {
    check_patch(*this, patch);
    if (patch >= nb_) return sub_area(subs_[static_cast<std::size_t>(patch - nb_)]);
    double a = base_->patch_area(patch);
    for (const SubPatch& s : subs_)
      if (s.base_patch == patch) a -= sub_area(s);
    return std::max(a, 0.0);
  }

  std::string patch_name(int patch) const override {
    check_patch(*this, patch);
    return patch < nb_ ? base_->patch_name(patch) : subs_[static_cast<std::size_t>(patch - nb_)].name;
  }

  Aabb bounding_box() const override { return base_->bounding_box(); }
  // Sub-patches do not change Omega.
  std::optional<DomainShape> shape() const override { return base_->shape(); }

  // A sub-patch lies on its base patch's wall.
  std::shared_ptr<const MirrorWall> patch_wall(int patch) const override {
    check_patch(*this, patch);
    return base_->patch_wall(patch < nb_ ? patch : subs_[static_cast<std::size_t>(patch - nb_)].base_patch);
  }

  // Only base patches that carry no sub-patch can move outward.
  DomainPtr extended(const std::vector<int>& patches, double w) const override {
    check_extension(*this, patches, w);
    for (int p : patches) {
      const bool carries = std::any_of(subs_.begin(), subs_.end(), [&](const SubPatch& s) { return s.base_patch == p; });
      require(p < nb_ && !carries, "extended patch", patch_name(p),
              "must be a whole patch of the base domain without sub-patches");
    }
    return make_with_subpatches(base_->extended(patches, w), subs_);
  }

  bool is_periodic() const override { return base_->is_periodic(); }
  Vec3 period() const override { return base_->period(); }
  Vec3 wrap(const Vec3& x) const override { return base_->wrap(x); }
  Vec3 sample_interior(Rng& rng) const override { return base_->sample_interior(rng); }

  // A sub-patch cell lies within radius + b of its center.
  Aabb layer_bounding_box(int patch, double b) const override {
    check_patch(*this, patch);
    if (patch < nb_) return base_->layer_bounding_box(patch, b);
    const SubPatch& s = subs_[static_cast<std::size_t>(patch - nb_)];
    const Aabb around = inflate(Aabb{s.center, s.center}, dim(), s.radius + b);
    return intersect(base_->layer_bounding_box(s.base_patch, b), around);
  }

  // Untouched base patches keep the base's (possibly exact) value.
  double layer_cell_volume(int patch, double b, LayerPart part, int samples) const override {
    check_patch(*this, patch);
    if (patch < nb_ && std::none_of(subs_.begin(), subs_.end(),
                                    [&](const SubPatch& s) { return s.base_patch == patch; }))
      return base_->layer_cell_volume(patch, b, part, samples);
    return Domain::layer_cell_volume(patch, b, part, samples);
  }

 private:
  // Exact on a flat face (disc / segment) and on a ball (Archimedes: a cap
  // whose rim is at chord c from the pole has area pi c^2). Other curved
  // patches (e.g. a cylinder's lateral surface) get the flat value.
  double sub_area(const SubPatch& s) const {
    const Ball* ball = dynamic_cast<const Ball*>(base_.get());
    const int d = dim();
    if (d == 1) {
      if (!ball) return 1.0;
      int n = 0;  // end points of the interval within reach
      for (double sign : {-1.0, 1.0})
        if ((ball->center() + sign * ball->radius() * Vec3::UnitX() - s.center).norm() <= s.radius) ++n;
      return n;
    }
    if (d == 2) {
      if (!ball) return 2.0 * s.radius;
      const double r = ball->radius();
      return 4.0 * r * std::asin(std::min(s.radius / (2.0 * r), 1.0));
    }
    const double c = ball ? std::min(s.radius, 2.0 * ball->radius()) : s.radius;
    return kPi * c * c;
  }

  DomainPtr base_;
  std::vector<SubPatch> subs_;
  int nb_ = 0;
};

// ---------------------------------------------------------------------------
// CSG

bool is_convex(const Domain& d) {
  if (dynamic_cast<const Ball*>(&d) || dynamic_cast<const Box*>(&d) || dynamic_cast<const Cylinder*>(&d))
    return true;
  if (const auto* s = dynamic_cast<const SubPatchDomain*>(&d)) return is_convex(s->base());
  return false;
}

// Every corner of `box` in the closed domain; for a convex domain that puts
// the whole box inside it.
bool corners_inside(const Domain& d, const Aabb& box) {
  for (const Vec3& c : corners(box, d.dim()))
    if (d.signed_distance(c) > 0.0) return false;
  return true;
}

class Csg final : public Domain {
 public:
  enum class Op { Union, Difference };

  Csg(Op op, DomainPtr a, DomainPtr b) : op_(op), a_(std::move(a)), b_(std::move(b)) {
    const std::string what = op == Op::Union ? "union" : "difference";
    require(a_ != nullptr, what + " operand a", "null", "must not be null");
    require(b_ != nullptr, what + " operand b", "null", "must not be null");
    require(a_->dim() == b_->dim(), what + " operand b dim", b_->dim(),
            "must equal operand a dim = " + std::to_string(a_->dim()));
    require(!a_->is_periodic(), what + " operand a", "periodic", "must have a boundary");
    require(!b_->is_periodic(), what + " operand b", "periodic", "must have a boundary");
    na_ = a_->num_patches();
    const int n = na_ + b_->num_patches();
    area_once_ = std::make_unique<std::once_flag[]>(static_cast<std::size_t>(n));
    areas_.assign(static_cast<std::size_t>(n), 0.0);
    shell_ = kCsgShellFraction * box_diagonal(bounding_box(), dim());
  }

  int dim() const override { return a_->dim(); }

  // Union: min(sdA, sdB) is exact outside (distance to a union is the min of
  // the distances); inside an overlap it underestimates the depth.
  // Difference A \ B = A and not B: for x inside, the nearest point of the
  // complement (A^c union B) is at min(-sdA, sdB), so max(sdA, -sdB) is exact
  // inside; outside it is only a lower bound. The closest point and patch come
  // from the operand that attains the min / max.
  BoundaryQuery query(const Vec3& x) const override {
    const BoundaryQuery qa = a_->query(x);
    BoundaryQuery qb = b_->query(x);
    qb.patch += na_;
    if (op_ == Op::Union) return qa.signed_distance <= qb.signed_distance ? qa : qb;
    qb.signed_distance = -qb.signed_distance;
    return qa.signed_distance >= qb.signed_distance ? qa : qb;
  }

  double volume() const override {
    std::call_once(volume_once_, [this] { volume_ = compute_volume(); });
    return volume_;
  }

  int num_patches() const override { return na_ + b_->num_patches(); }

  double patch_area(int patch) const override {
    check_patch(*this, patch);
    const auto i = static_cast<std::size_t>(patch);
    std::call_once(area_once_[i], [this, patch, i] { areas_[i] = compute_patch_area(patch); });
    return areas_[i];
  }

  std::string patch_name(int patch) const override {
    check_patch(*this, patch);
    return patch < na_ ? a_->patch_name(patch) : "b:" + b_->patch_name(patch - na_);
  }

  Aabb bounding_box() const override {
    const Aabb ba = a_->bounding_box();
    if (op_ == Op::Difference) return ba;
    const Aabb bb = b_->bounding_box();
    return Aabb{ba.lo.cwiseMin(bb.lo), ba.hi.cwiseMax(bb.hi)};
  }

  // A cell of an operand's patch lies in that operand's cell (same |sd| and
  // patch) and within b of this domain.
  Aabb layer_bounding_box(int patch, double b) const override {
    const Aabb own = Domain::layer_bounding_box(patch, b);
    const Aabb operand = patch < na_ ? a_->layer_bounding_box(patch, b) : b_->layer_bounding_box(patch - na_, b);
    return intersect(own, operand);
  }

 private:
  double compute_volume() const {
    const int d = dim();
    const Aabb ba = a_->bounding_box(), bb = b_->bounding_box();
    const double va = a_->volume(), vb = b_->volume();
    if (disjoint(ba, bb, d)) return op_ == Op::Union ? va + vb : va;
    if (is_convex(*a_) && corners_inside(*a_, bb)) return op_ == Op::Union ? va : va - vb;
    if (op_ == Op::Union && is_convex(*b_) && corners_inside(*b_, ba)) return vb;
    return monte_carlo_volume(bounding_box(), d, kCsgSamples, [this](const Vec3& x) { return contains(x); });
  }

  // Exact when the operand patch is clearly outside or inside the other
  // operand; otherwise (approximate) the Monte Carlo volume of the shell
  // |sd| <= h over 2h, with h = 2e-3 of the box diagonal: O(h^2) error on
  // curved parts, O(h) relative error where the patch has edges.
  double compute_patch_area(int patch) const {
    const bool from_a = patch < na_;
    const Domain& own = from_a ? *a_ : *b_;
    const Domain& other = from_a ? *b_ : *a_;
    const int local = from_a ? patch : patch - na_;
    // Union keeps each boundary outside the other operand; the difference
    // keeps A's boundary outside B and B's boundary inside A.
    const bool kept_outside = op_ == Op::Union || from_a;
    const Aabb pbox = own.layer_bounding_box(local, shell_);
    if (disjoint(pbox, other.bounding_box(), dim())) return kept_outside ? own.patch_area(local) : 0.0;
    if (is_convex(other) && corners_inside(other, pbox)) return kept_outside ? 0.0 : own.patch_area(local);
    return Domain::layer_cell_volume(patch, shell_, LayerPart::Whole, kCsgSamples) / (2.0 * shell_);
  }

  Op op_;
  DomainPtr a_, b_;
  int na_ = 0;
  double shell_ = 0.0;
  mutable std::once_flag volume_once_;
  mutable double volume_ = 0.0;
  std::unique_ptr<std::once_flag[]> area_once_;
  mutable std::vector<double> areas_;
};

}  // namespace

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

DomainPtr make_with_subpatches(DomainPtr base, std::vector<SubPatch> subpatches) {
  return std::make_shared<SubPatchDomain>(std::move(base), std::move(subpatches));
}

DomainPtr make_union(DomainPtr a, DomainPtr b) {
  return std::make_shared<Csg>(Csg::Op::Union, std::move(a), std::move(b));
}

DomainPtr make_difference(DomainPtr a, DomainPtr b) {
  return std::make_shared<Csg>(Csg::Op::Difference, std::move(a), std::move(b));
}

}  // namespace otfp
