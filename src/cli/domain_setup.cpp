#include "domain_setup.hpp"

#include "otfp/images.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>

namespace otfp::app::detail {

namespace {

Vec3 project(const Vec3& x, int dim) {
  Vec3 y = x;
  for (int k = dim; k < 3; ++k) y[k] = 0.0;
  return y;
}

std::string shown(const Vec3& v) { return fmt::format("[{}, {}, {}]", v[0], v[1], v[2]); }

double box_mean_square(const Vec3& lo, const Vec3& hi, int dim, const Vec3& c) {
  double s = 0.0;
  for (int k = 0; k < dim; ++k) {
    const double len = hi[k] - lo[k], mid = 0.5 * (lo[k] + hi[k]);
    s += len * len / 12.0 + (mid - c[k]) * (mid - c[k]);
  }
  return s;
}

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
      : dim_(dim), lo_(lo), hi_(hi), axis_(dim == 3 ? axis : -1), c_(c), r_(r) {
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

int axis_index(const std::string& a) { return a == "x" ? 0 : a == "y" ? 1 : 2; }

}  // namespace

int resolve_patch(const BuiltDomain& built, const std::string& name) {
  return built.domain->patch_by_name(name);
}

std::string patch_names(const BuiltDomain& built) {
  std::string out;
  for (int p = 0; p < built.domain->num_patches(); ++p) out += (p ? ", " : "") + built.domain->patch_name(p);
  return out.empty() ? std::string("none") : out;
}

BuiltDomain build_domain(const Config& c) {
  const int dim = c.run.dim;
  const DomainSection& d = c.domain;
  BuiltDomain out;
  DomainPtr base;
  // Default centre of each base patch for sub-patches (nullopt: must be given).
  std::function<std::optional<Vec3>(int)> patch_center = [](int) { return std::optional<Vec3>{}; };
  const Vec3 lo = project(d.lo, dim), hi = project(d.hi, dim);

  try {
    if (d.type == "ball") {
      const Vec3 ctr = project(d.center, dim);
      base = make_ball(dim, ctr, d.radius);
      out.centroid = ctr;
      out.length_L = d.radius;
      out.min_extent = 2.0 * d.radius;
      out.ball_radius = d.radius;
      const double r = d.radius;
      out.mean_square_distance = [ctr, r, dim](const Vec3& cc) {
        return dim / (dim + 2.0) * r * r + (ctr - cc).squaredNorm();
      };
      // The "north pole": the end of the last used axis.
      patch_center = [ctr, r, dim](int) { return std::optional<Vec3>(ctr + r * Vec3::Unit(dim - 1)); };
    } else if (d.type == "box" || d.type == "periodic_box" || d.type == "free") {
      if (d.type == "box") {
        base = make_box(dim, lo, hi);
      } else if (d.type == "periodic_box") {
        base = make_periodic_box(dim, lo, hi);
      } else {
        base = make_free_space(dim, lo, hi);
        out.free_space = true;
      }
      out.centroid = 0.5 * (lo + hi);
      const Vec3 ext = hi - lo;
      out.length_L = ext.head(dim).maxCoeff();
      out.min_extent = ext.head(dim).minCoeff();
      out.mean_square_distance = [lo, hi, dim](const Vec3& cc) { return box_mean_square(lo, hi, dim, cc); };
      patch_center = [lo, hi](int p) {
        Vec3 x = 0.5 * (lo + hi);
        x[p / 2] = p % 2 == 0 ? lo[p / 2] : hi[p / 2];
        return std::optional<Vec3>(x);
      };
    } else if (d.type == "cylinder") {
      base = make_cylinder(d.end_a, d.end_b, d.radius);
      const Vec3 mid = 0.5 * (d.end_a + d.end_b);
      const double len = (d.end_b - d.end_a).norm(), r = d.radius;
      out.centroid = mid;
      out.length_L = r;
      out.min_extent = std::min(len, 2.0 * r);
      out.mean_square_distance = [mid, len, r](const Vec3& cc) {
        return r * r / 2.0 + len * len / 12.0 + (mid - cc).squaredNorm();
      };
      const Vec3 a = d.end_a, b = d.end_b;
      patch_center = [a, b](int p) {
        if (p == 1) return std::optional<Vec3>(a);
        if (p == 2) return std::optional<Vec3>(b);
        return std::optional<Vec3>{};
      };
    } else if (d.type == "square_pipe_obstacle") {
      const int axis = dim == 2 ? 2 : axis_index(d.obstacle_axis);
      const Vec3 oc = project(d.obstacle_center.value_or(0.5 * (lo + hi)), dim);
      double clearance = std::numeric_limits<double>::infinity(), cross = clearance;
      for (int k = 0; k < dim; ++k)
        if (k != axis) {
          clearance = std::min({clearance, oc[k] - lo[k], hi[k] - oc[k]});
          cross = std::min(cross, hi[k] - lo[k]);
        }
      const double r = d.obstacle_radius.value_or(0.2 * cross);
      if (!(r < clearance))
        throw ConfigError(d.obstacle_radius ? "domain.obstacle_radius" : "domain.obstacle_center",
                          d.obstacle_radius ? fmt::format("{}", r) : shown(oc),
                          fmt::format("the obstacle (radius {}) must lie strictly inside the pipe cross-section "
                                      "(distance from its axis to the walls: {})",
                                      r, clearance));
      base = std::make_shared<SquarePipeObstacle>(dim, lo, hi, axis, oc, r);
      out.centroid = 0.5 * (lo + hi);
      const Vec3 ext = hi - lo;
      out.length_L = ext.head(dim).maxCoeff();
      out.min_extent = ext.head(dim).minCoeff();
      const DomainPtr dom = base;
      out.mean_square_distance = [dom, dim](const Vec3& cc) {
        // Fixed-seed Monte Carlo: the same value every run.
        Rng rng(0x6a696e66ULL);
        constexpr int kSamples = 200000;
        double s2 = 0.0;
        for (int i = 0; i < kSamples; ++i) s2 += (project(dom->sample_interior(rng), dim) - cc).squaredNorm();
        return s2 / kSamples;
      };
      const int np = 2 * dim;
      patch_center = [lo, hi, np](int p) {
        if (p >= np) return std::optional<Vec3>{};
        Vec3 x = 0.5 * (lo + hi);
        x[p / 2] = p % 2 == 0 ? lo[p / 2] : hi[p / 2];
        return std::optional<Vec3>(x);
      };
    }
  } catch (const InvalidArgument& e) {
    throw ConfigError("domain", fmt::format("domain.type = \"{}\": {}", d.type, e.what()));
  }

  if (!d.subpatches.empty()) {
    if (base->num_patches() == 0)
      throw ConfigError("domain.subpatch[0].on", "\"" + d.subpatches[0].on + "\"",
                        "domain type \"" + d.type + "\" has no boundary patches");
    BuiltDomain probe;
    probe.domain = base;
    std::vector<SubPatch> subs;
    const double scale = std::max(1.0, (base->bounding_box().hi - base->bounding_box().lo).norm());
    for (std::size_t i = 0; i < d.subpatches.size(); ++i) {
      const SubPatchSpec& s = d.subpatches[i];
      const std::string p = fmt::format("domain.subpatch[{}].", i);
      const int on = resolve_patch(probe, s.on);
      if (on < 0)
        throw ConfigError(p + "on", "\"" + s.on + "\"", "unknown patch (patches: " + patch_names(probe) + ")");
      if (resolve_patch(probe, s.name) >= 0)
        throw ConfigError(p + "name", "\"" + s.name + "\"", "already the name of a patch of the domain");
      std::optional<Vec3> ctr = s.center ? std::optional<Vec3>(project(*s.center, dim)) : patch_center(on);
      if (!ctr) throw ConfigError(p + "center", "(missing)", "required for a sub-patch of \"" + s.on + "\"");
      const BoundaryQuery q = base->query(*ctr);
      if (std::abs(q.signed_distance) > 1e-8 * scale || q.patch != on)
        throw ConfigError(p + "center", shown(*ctr), "must lie on patch \"" + s.on + "\"");
      subs.push_back(SubPatch{on, *ctr, s.radius, s.name});
    }
    try {
      base = make_with_subpatches(base, subs);
    } catch (const InvalidArgument& e) {
      throw ConfigError("domain.subpatch", std::string("domain.subpatch: ") + e.what());
    }
  }
  out.domain = base;

  const double vol = out.domain->volume();
  if (!(vol > 0.0) || !std::isfinite(vol))
    throw ConfigError("domain", fmt::format("domain.type = \"{}\": volume = {}: must be > 0 (empty domain)", d.type, vol));
  return out;
}

}  // namespace otfp::app::detail
