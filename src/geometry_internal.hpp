#pragma once
// Internal to the domains (src/geometry*.cpp): the checks and box helpers
// every domain uses, and the Monte Carlo measure of Domain.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <numbers>
#include <optional>
#include <string>
#include <vector>

#include "otfp/geometry.hpp"

namespace otfp {

namespace geometry_detail {

constexpr double kPi = std::numbers::pi;
// Fixed seed: Monte Carlo volumes must be reproducible run to run.
constexpr std::uint64_t kMonteCarloSeed = 0x6f74667067656f6dULL;

inline Vec3 project(const Vec3& x, int dim) {
  Vec3 y = x;
  for (int k = dim; k < 3; ++k) y[k] = 0.0;
  return y;
}

inline void check_point(const Vec3& x, const std::string& field) {
  require(x.allFinite(), field, x.norm(), "must be finite");
}

// A box [lo, hi] of a domain called `what`: finite corners, lo < hi on each used axis.
inline void check_box(const Vec3& lo, const Vec3& hi, int dim, const std::string& what) {
  check_point(lo, what + " lo");
  check_point(hi, what + " hi");
  static const char* kAxis[3] = {"x", "y", "z"};
  for (int k = 0; k < dim; ++k)
    require(lo[k] < hi[k], what + " hi." + kAxis[k], hi[k],
            "must be > lo." + std::string(kAxis[k]) + " = " + std::to_string(lo[k]));
}

inline void check_patch(const Domain& d, int patch) {
  require(patch >= 0 && patch < d.num_patches(), "patch", patch,
          "must be in [0, " + std::to_string(d.num_patches()) + ")");
}

inline void check_thickness(double b) {
  require(std::isfinite(b) && b > 0.0, "layer half-thickness b", b, "must be finite and > 0");
}

inline void check_extension(const Domain& d, const std::vector<int>& patches, double w) {
  require(std::isfinite(w) && w > 0.0, "extension thickness w", w, "must be finite and > 0");
  for (int p : patches) check_patch(d, p);
}

inline Aabb inflate(const Aabb& box, int dim, double b) {
  Aabb out = box;
  for (int k = 0; k < dim; ++k) {
    out.lo[k] -= b;
    out.hi[k] += b;
  }
  return out;
}

inline bool is_empty(const Aabb& box, int dim) {
  for (int k = 0; k < dim; ++k)
    if (!(box.hi[k] > box.lo[k])) return true;
  return false;
}

inline double box_measure(const Aabb& box, int dim) {
  double v = 1.0;
  for (int k = 0; k < dim; ++k) v *= std::max(box.hi[k] - box.lo[k], 0.0);
  return v;
}

// Mean of |x - c|^2 over the box at uniform density: per axis, the
// variance len^2 / 12 plus the squared offset of the midpoint.
inline double box_mean_square(const Aabb& box, int dim, const Vec3& c) {
  double s = 0.0;
  for (int k = 0; k < dim; ++k) {
    const double len = box.hi[k] - box.lo[k], mid = 0.5 * (box.lo[k] + box.hi[k]);
    s += len * len / 12.0 + (mid - c[k]) * (mid - c[k]);
  }
  return s;
}

inline Vec3 uniform_in(const Aabb& box, int dim, Rng& rng) {
  Vec3 x = Vec3::Zero();
  for (int k = 0; k < dim; ++k) x[k] = rng.uniform(box.lo[k], box.hi[k]);
  return x;
}

// What the composite domains (geometry_composite.cpp) need to know of the
// primitive shapes (geometry_shapes.cpp): whether a domain is a ball, box or
// cylinder of make_ball, make_box, make_cylinder (all convex), and the
// centre and radius of a ball of make_ball (nullopt for any other domain).
bool is_convex_shape(const Domain& d);
struct BallGeometry {
  Vec3 center = Vec3::Zero();
  double radius = 0.0;
};
std::optional<BallGeometry> as_ball(const Domain& d);

}  // namespace geometry_detail

// Declared in otfp/geometry.hpp; the base class's layer cells and CSG's volume use it.
template <class Pred>
double Domain::monte_carlo_volume(const Aabb& box, int dim, int samples, Pred pred) {
  require(samples > 0, "samples", samples, "must be > 0");
  if (geometry_detail::is_empty(box, dim)) return 0.0;
  Rng rng(geometry_detail::kMonteCarloSeed);
  long hits = 0;
  for (int i = 0; i < samples; ++i)
    if (pred(geometry_detail::uniform_in(box, dim, rng))) ++hits;
  return geometry_detail::box_measure(box, dim) * static_cast<double>(hits) / static_cast<double>(samples);
}

}  // namespace otfp
