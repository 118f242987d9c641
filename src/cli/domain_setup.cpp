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
    if (d.type == DomainType::Ball) {
      const Vec3 ctr = project(d.center, dim);
      base = make_ball(dim, ctr, d.radius);
      out.length_L = d.radius;
      out.min_extent = 2.0 * d.radius;
      // The "north pole": the end of the last used axis.
      const double r = d.radius;
      patch_center = [ctr, r, dim](int) { return std::optional<Vec3>(ctr + r * Vec3::Unit(dim - 1)); };
    } else if (d.type == DomainType::Box || d.type == DomainType::PeriodicBox || d.type == DomainType::Free) {
      if (d.type == DomainType::Box) {
        base = make_box(dim, lo, hi);
      } else if (d.type == DomainType::PeriodicBox) {
        base = make_periodic_box(dim, lo, hi);
      } else {
        base = make_free_space(dim, lo, hi);
        out.free_space = true;
      }
      const Vec3 ext = hi - lo;
      out.length_L = ext.head(dim).maxCoeff();
      out.min_extent = ext.head(dim).minCoeff();
      patch_center = [lo, hi](int p) {
        Vec3 x = 0.5 * (lo + hi);
        x[p / 2] = p % 2 == 0 ? lo[p / 2] : hi[p / 2];
        return std::optional<Vec3>(x);
      };
    } else if (d.type == DomainType::Cylinder) {
      base = make_cylinder(d.end_a, d.end_b, d.radius);
      out.length_L = d.radius;
      out.min_extent = std::min((d.end_b - d.end_a).norm(), 2.0 * d.radius);
      const Vec3 a = d.end_a, b = d.end_b;
      patch_center = [a, b](int p) {
        if (p == 1) return std::optional<Vec3>(a);
        if (p == 2) return std::optional<Vec3>(b);
        return std::optional<Vec3>{};
      };
    } else if (d.type == DomainType::SquarePipeObstacle) {
      const int axis = dim == 2 ? 2 : static_cast<int>(d.obstacle_axis);
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
      base = make_square_pipe_obstacle(dim, lo, hi, axis, oc, r);
      const Vec3 ext = hi - lo;
      out.length_L = ext.head(dim).maxCoeff();
      out.min_extent = ext.head(dim).minCoeff();
      const int np = 2 * dim;
      patch_center = [lo, hi, np](int p) {
        if (p >= np) return std::optional<Vec3>{};
        Vec3 x = 0.5 * (lo + hi);
        x[p / 2] = p % 2 == 0 ? lo[p / 2] : hi[p / 2];
        return std::optional<Vec3>(x);
      };
    }
  } catch (const InvalidArgument& e) {
    throw ConfigError("domain", fmt::format("domain.type = \"{}\": {}", to_string(d.type), e.what()));
  }

  if (!d.subpatches.empty()) {
    if (base->num_patches() == 0)
      throw ConfigError("domain.subpatch[0].on", "\"" + d.subpatches[0].on + "\"",
                        "domain type \"" + to_string(d.type) + "\" has no boundary patches");
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
    throw ConfigError("domain", fmt::format("domain.type = \"{}\": volume = {}: must be > 0 (empty domain)", to_string(d.type), vol));
  return out;
}

}  // namespace otfp::app::detail
