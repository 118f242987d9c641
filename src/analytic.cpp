#include "otfp/analytic.hpp"

#include <cmath>

#include "otfp/types.hpp"

namespace otfp::analytic {

namespace {
// Sums a(n) exp(-c n^2 tau) over n = first, first + step, ... until the terms
// are negligible; the series converge for tau > 0 (about 1/sqrt(tau) terms).
template <class Weight>
double exp_series(double tau, double c, int first, int step, Weight weight) {
  double sum = 0.0;
  for (long n = first; n < 100000000; n += step) {
    const double e = std::exp(-c * static_cast<double>(n) * static_cast<double>(n) * tau);
    const double term = weight(n) * e;
    sum += term;
    if (e < 1e-18) break;
  }
  return sum;
}
}  // namespace

double crank_sphere_uptake(double tau) {
  require(std::isfinite(tau) && tau >= 0.0, "kappa t / R^2", tau, "must be finite and >= 0");
  if (tau == 0.0) return 0.0;
  if (tau < 1e-6) return 6.0 * std::sqrt(tau / M_PI) - 3.0 * tau;  // short-time form, error ~ exp(-1/tau)
  const double s = exp_series(tau, M_PI * M_PI, 1, 1, [](long n) { return 1.0 / (static_cast<double>(n) * n); });
  return 1.0 - 6.0 / (M_PI * M_PI) * s;
}

double crank_slab_uptake(double tau) {
  require(std::isfinite(tau) && tau >= 0.0, "kappa t / L^2", tau, "must be finite and >= 0");
  if (tau == 0.0) return 0.0;
  if (tau < 1e-6) return 2.0 * std::sqrt(tau / M_PI);  // semi-infinite solid, error ~ exp(-1/tau)
  const double s = exp_series(tau, M_PI * M_PI / 4.0, 1, 2, [](long n) { return 8.0 / (static_cast<double>(n) * n * M_PI * M_PI); });
  return 1.0 - s;
}

double crank_sphere_polar_inertia(double tau) {
  require(std::isfinite(tau) && tau >= 0.0, "kappa t / R^2", tau, "must be finite and >= 0");
  if (tau == 0.0) return 0.0;
  const double s = exp_series(tau, M_PI * M_PI, 1, 1, [](long n) {
    const double a2 = static_cast<double>(n) * static_cast<double>(n) * M_PI * M_PI;
    return 12.0 / (a2 * a2) - 2.0 / a2;
  });
  return 1.0 + 5.0 * s;
}

double crank_slab_density(double tau, double depth) {
  require(std::isfinite(tau) && tau >= 0.0, "kappa t / L^2", tau, "must be finite and >= 0");
  require(std::isfinite(depth) && depth >= 0.0 && depth <= 1.0, "depth / L", depth, "must be in [0, 1]");
  if (depth == 0.0) return 1.0;
  if (tau == 0.0) return 0.0;
  const double theta = 0.5 * M_PI * (1.0 - depth);
  const double s = exp_series(tau, M_PI * M_PI / 4.0, 1, 2, [theta](long n) {
    const double sign = (n / 2) % 2 == 0 ? 1.0 : -1.0;  // n = 2k + 1: (-1)^k
    return sign / static_cast<double>(n) * std::cos(static_cast<double>(n) * theta);
  });
  return 1.0 - 4.0 / M_PI * s;
}

double cosine_mode_decay(double kappa, double wavenumber, double t) {
  return std::exp(-kappa * wavenumber * wavenumber * t);
}

}  // namespace otfp::analytic
