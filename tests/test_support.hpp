#pragma once
// Helpers shared by the test executables: random clouds and finite differences.
#include <cmath>
#include <functional>
#include <vector>

#include "otfp/particles.hpp"
#include "otfp/types.hpp"

namespace otfp::testing {

// n particles uniform in [lo, hi]^dim, widths s0 * U(1 - spread, 1 + spread), masses m * U(0.5, 1.5).
inline ParticleSet random_cloud(int dim, std::size_t n, double lo, double hi, double s0, double spread, double m,
                                std::uint64_t seed) {
  Rng rng(seed);
  ParticleSet ps(dim);
  for (std::size_t i = 0; i < n; ++i) {
    Vec3 x = Vec3::Zero();
    for (int k = 0; k < dim; ++k) x[k] = rng.uniform(lo, hi);
    ps.add(x, s0 * rng.uniform(1.0 - spread, 1.0 + spread), m * rng.uniform(0.5, 1.5));
  }
  return ps;
}

// Fourth-order central difference of f along one coordinate.
inline double central_difference(const std::function<double(double)>& f, double h) {
  return (-f(2 * h) + 8 * f(h) - 8 * f(-h) + f(-2 * h)) / (12 * h);
}

}  // namespace otfp::testing
