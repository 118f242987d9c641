// Domains built on other domains: sub-patches (a disc or cap of a base
// patch as a patch of its own) and CSG (union, difference).
#include <algorithm>
#include <cmath>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "geometry_internal.hpp"

namespace otfp {

using namespace geometry_detail;

namespace {

// CSG volumes and patch areas: 2e6 samples give ~1e-4 relative noise.
constexpr int kCsgSamples = 2'000'000;
// Shell half-thickness for CSG patch areas, relative to the box diagonal.
constexpr double kCsgShellFraction = 2e-3;

Aabb intersect(const Aabb& p, const Aabb& q) {
  return Aabb{p.lo.cwiseMax(q.lo), p.hi.cwiseMin(q.hi)};
}

bool disjoint(const Aabb& p, const Aabb& q, int dim) {
  for (int k = 0; k < dim; ++k)
    if (p.hi[k] < q.lo[k] || q.hi[k] < p.lo[k]) return true;
  return false;
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
  Vec3 inertia_center() const override { return base_->inertia_center(); }
  double mean_square_distance(const Vec3& c) const override { return base_->mean_square_distance(c); }

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
    const std::optional<BallGeometry> ball = as_ball(*base_);
    const int d = dim();
    if (d == 1) {
      if (!ball) return 1.0;
      int n = 0;  // end points of the interval within reach
      for (double sign : {-1.0, 1.0})
        if ((ball->center + sign * ball->radius * Vec3::UnitX() - s.center).norm() <= s.radius) ++n;
      return n;
    }
    if (d == 2) {
      if (!ball) return 2.0 * s.radius;
      const double r = ball->radius;
      return 4.0 * r * std::asin(std::min(s.radius / (2.0 * r), 1.0));
    }
    const double c = ball ? std::min(s.radius, 2.0 * ball->radius) : s.radius;
    return kPi * c * c;
  }

  DomainPtr base_;
  std::vector<SubPatch> subs_;
  int nb_ = 0;
};

// ---------------------------------------------------------------------------
// CSG

bool is_convex(const Domain& d) {
  if (is_convex_shape(d)) return true;
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
