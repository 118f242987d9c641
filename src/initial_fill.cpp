#include "otfp/initial_fill.hpp"

#include <cmath>

namespace otfp {

void FillOptions::validate() const {
  require(count >= 0, "fill count", static_cast<double>(count), "must be >= 0");
  require(std::isfinite(width_s) && width_s > 0.0, "fill width_s", width_s, "must be finite and > 0");
  require(std::isfinite(mass) && mass > 0.0, "fill mass", mass, "must be finite and > 0");
  require(lo.allFinite() && hi.allFinite() && (hi.array() >= lo.array()).all(), "fill box", (hi - lo).minCoeff(),
          "must be finite with hi >= lo");
  if (lattice)
    for (std::int64_t n : lattice_counts) require(n >= 1, "fill lattice count", static_cast<double>(n), "must be >= 1");
  if (shape == FillShape::Gaussian)
    require(std::isfinite(sigma) && sigma > 0.0, "fill sigma", sigma, "must be finite and > 0");
  if (shape == FillShape::Cosine) {
    require(std::isfinite(amplitude) && amplitude >= 0.0 && amplitude < 1.0, "fill amplitude", amplitude,
            "must be in [0, 1)");
    require(std::isfinite(wavenumber) && wavenumber > 0.0, "fill wavenumber", wavenumber, "must be finite and > 0");
  }
}

double invert_cosine_cdf(double u, double a, double k) {
  double xi = u;
  for (int it = 0; it < 100; ++it) {
    const double f = xi + a / k * std::sin(k * xi) - u;
    const double df = 1.0 + a * std::cos(k * xi);
    const double step = f / df;
    xi -= step;
    if (std::abs(step) <= 1e-15 * (1.0 + std::abs(xi))) break;
  }
  return xi;
}

ParticleSet fill_particles(const Domain& domain, const FillOptions& o, Rng& rng) {
  o.validate();
  const int dim = domain.dim();
  ParticleSet ps(dim);
  ps.reserve(static_cast<std::size_t>(o.count));
  for (std::int64_t i = 0; i < o.count; ++i) {
    Vec3 x;
    if (o.lattice || o.shape == FillShape::Cosine) {
      // Lattice: cell centres; random: uniform in the box. The cosine fill
      // then maps x through the inverse cumulative density of 1 + a cos(k x).
      x = Vec3::Zero();
      std::int64_t rest = i;
      for (int k = 0; k < dim; ++k) {
        const double lo = o.lo[k], len = o.hi[k] - o.lo[k];
        if (o.lattice) {
          const std::int64_t nk = o.lattice_counts[static_cast<std::size_t>(k)];
          x[k] = lo + (static_cast<double>(rest % nk) + 0.5) * len / static_cast<double>(nk);
          rest /= nk;
        } else {
          x[k] = lo + len * rng.uniform();
        }
      }
      if (o.shape == FillShape::Cosine) x[0] = o.lo[0] + invert_cosine_cdf(x[0] - o.lo[0], o.amplitude, o.wavenumber);
    } else if (o.shape == FillShape::Gaussian) {
      x = Vec3::Zero();
      for (int k = 0; k < dim; ++k) x[k] = o.center[k] + o.sigma * rng.normal();
      x = domain.wrap(x);
    } else {
      x = domain.sample_interior(rng);
    }
    ps.add(x, o.width_s, o.mass, 0.0);
  }
  return ps;
}

}  // namespace otfp
