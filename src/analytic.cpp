#include "otfp/analytic.hpp"

#include <cmath>
#include <limits>

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

double crank_slab_polar_inertia(double tau, const SlabBox& slab, int intervals) {
  require(std::isfinite(tau) && tau >= 0.0, "kappa t / L^2", tau, "must be finite and >= 0");
  require(slab.dim >= 1 && slab.dim <= 3, "slab.dim", slab.dim, "must be 1, 2 or 3");
  require(slab.axis >= 0 && slab.axis < slab.dim, "slab.axis", slab.axis, "must be an axis below dim");
  require(std::isfinite(slab.length) && slab.length > 0.0, "slab.length", slab.length, "must be finite and > 0");
  require(intervals >= 2 && intervals % 2 == 0, "intervals", intervals, "must be even and >= 2");
  if (tau == 0.0) return 0.0;
  const int a = slab.axis;
  double transverse = 0.0;
  for (int k = 0; k < slab.dim; ++k)
    if (k != a) {
      const double w = slab.hi[k] - slab.lo[k], mid = 0.5 * (slab.hi[k] + slab.lo[k]);
      transverse += w * w / 12.0 + (mid - slab.center[k]) * (mid - slab.center[k]);
    }
  const double L = slab.length;
  double integral = 0.0;
  for (int i = 0; i <= intervals; ++i) {
    const double depth = static_cast<double>(i) / intervals;
    const double x = slab.held_at_hi ? slab.hi[a] - depth * L : slab.lo[a] + depth * L;
    const double w = (i == 0 || i == intervals) ? 1.0 : (i % 2 ? 4.0 : 2.0);
    integral += w * crank_slab_density(tau, depth) * ((x - slab.center[a]) * (x - slab.center[a]) + transverse);
  }
  return slab.M_inf * integral / (3.0 * intervals);  // M_inf = g |Omega|, depth in units of L
}

namespace {
double rate_of_factor(double g, double dt) {
  return g > 0.0 ? -std::log(g) / dt : std::numeric_limits<double>::infinity();
}
void require_rate_inputs(double lambda, double dt) {
  require(std::isfinite(lambda) && lambda >= 0.0, "lambda", lambda, "must be finite and >= 0");
  require(std::isfinite(dt) && dt > 0.0, "dt", dt, "must be finite and > 0");
}
}  // namespace

double time_discrete_rate(TimeScheme scheme, double lambda, double dt) {
  require_rate_inputs(lambda, dt);
  const double z = lambda * dt;
  if (scheme == TimeScheme::Euler) return rate_of_factor(1.0 / (1.0 + z), dt);
  // BDF2: the roots of (3/2 + z) g^2 - 2 g + 1/2 = 0 are (2 +- sqrt(1 - 2 z)) / (3 + 2 z);
  // the principal one (-> 1 as z -> 0) while real, else the complex pair's
  // modulus sqrt(1 / (3 + 2 z)) (the product of the roots).
  const double g = z <= 0.5 ? (2.0 + std::sqrt(1.0 - 2.0 * z)) / (3.0 + 2.0 * z) : 1.0 / std::sqrt(3.0 + 2.0 * z);
  return rate_of_factor(g, dt);
}

double time_discrete_rate(ExplicitScheme scheme, double lambda, double dt) {
  require_rate_inputs(lambda, dt);
  const double z = lambda * dt;
  const double g = scheme == ExplicitScheme::Rk4Force27 ? 1.0 - z + z * z / 2.0 - z * z * z / 6.0 + z * z * z * z / 24.0
                                                         : 1.0 - z;
  return rate_of_factor(g, dt);
}

}  // namespace otfp::analytic
