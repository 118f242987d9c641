#pragma once
// Internal: what the boundary projection (src/boundary.cpp) and its Dirichlet
// reservoir (src/reservoir.cpp) share. Not installed.
#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <utility>
#include <vector>

#include "otfp/boundary.hpp"
#include "otfp/geometry.hpp"
#include "otfp/types.hpp"

namespace otfp::detail {

// Fixed seed for the quadrature points: targets must not change run to run.
inline constexpr std::uint64_t kQuadratureSeed = 0x626e647271756164ULL;
// Counts are floors of mass ratios; a ratio that is an integer up to
// round-off (e.g. 0.37 added 100 times) must count as that integer.
inline constexpr double kCountTolerance = 1e-9;

// Fixed seeds of the reservoir volumes / quadrature and of the points on A_l.
inline constexpr std::uint64_t kReservoirSeed = 0x7265736572766f69ULL;
inline constexpr std::uint64_t kSurfaceSeed = 0x7375726661636570ULL;
// Quiet reservoir: at least this many fixed candidate points per sublayer
// (reservoir.cpp builds them, reservoir_quiet.cpp ranks them).
inline constexpr std::size_t kMinCandidates = 64;

inline Vec3 uniform_in(const Aabb& box, int dim, Rng& rng) {
  Vec3 x = Vec3::Zero();
  for (int k = 0; k < dim; ++k) x[k] = rng.uniform(box.lo[k], box.hi[k]);
  return x;
}

inline double box_measure(const Aabb& box, int dim) {
  double v = 1.0;
  for (int k = 0; k < dim; ++k) v *= std::max(box.hi[k] - box.lo[k], 0.0);
  return v;
}

inline double mean_of(const BoundaryData& g, const std::vector<Vec3>& points, double t) {
  double sum = 0.0;
  for (const Vec3& y : points) sum += g(y, t);
  return sum / static_cast<double>(points.size());
}

// How far a blob's mass is followed from its centre (in widths s) when the
// quiet reservoir sums it into depth intervals.
constexpr double kTailWidths = 7.0;

// Draws one not-yet-drawn entry of pool[k..] uniformly (partial Fisher-Yates),
// so repeated calls with k = 0, 1, ... sample without replacement.
inline std::size_t draw_without_replacement(std::vector<std::size_t>& pool, std::size_t k, Rng& rng) {
  const std::size_t j = k + static_cast<std::size_t>(rng.below(pool.size() - k));
  std::swap(pool[k], pool[j]);
  return pool[k];
}

}  // namespace otfp::detail
