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
  require(lattice || !staggered, "fill staggered", 1.0, "needs a lattice fill");
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

std::int64_t lattice_point_count(int dim, const std::array<std::int64_t, 3>& counts, bool staggered) {
  std::int64_t n = staggered && dim == 3 ? 2 : 1;
  for (int k = 0; k < dim; ++k) n *= counts[static_cast<std::size_t>(k)];
  return n;
}

ParticleSet fill_particles(const Domain& domain, const FillOptions& o, Rng& rng) {
  o.validate();
  const int dim = domain.dim();
  // A staggered 2-D lattice repeats every two rows: an odd row count would
  // put two unshifted rows side by side across a periodic boundary.
  if (o.lattice && o.staggered && dim == 2)
    require(o.lattice_counts[1] % 2 == 0, "fill lattice count along y", static_cast<double>(o.lattice_counts[1]),
            "must be even for a staggered lattice");
  const bool bcc = o.lattice && o.staggered && dim == 3;
  ParticleSet ps(dim);
  ps.reserve(static_cast<std::size_t>(o.count));
  for (std::int64_t i = 0; i < o.count; ++i) {
    Vec3 x;
    if (o.lattice || o.shape == FillShape::Cosine) {
      // Lattice: cell centres; random: uniform in the box. The cosine fill
      // then maps x through the inverse cumulative density of 1 + a cos(k x).
      x = Vec3::Zero();
      // bcc: two points per cell, at 1/4 and 3/4 of its diagonal.
      std::int64_t rest = bcc ? i / 2 : i;
      const double offset = bcc ? (i % 2 == 0 ? 0.25 : 0.75) : 0.5;
      std::int64_t row = 0;  // the cell's index along y
      for (int k = 0; k < dim; ++k) {
        const double lo = o.lo[k], len = o.hi[k] - o.lo[k];
        if (o.lattice) {
          const std::int64_t nk = o.lattice_counts[static_cast<std::size_t>(k)];
          if (k == 1) row = rest % nk;
          x[k] = lo + (static_cast<double>(rest % nk) + offset) * len / static_cast<double>(nk);
          rest /= nk;
        } else {
          x[k] = lo + len * rng.uniform();
        }
      }
      // Staggered 2-D: rows alternately a quarter cell left and right along
      // x (half a cell apart, every point inside the box).
      if (o.lattice && o.staggered && dim == 2)
        x[0] += (row % 2 == 0 ? -0.25 : 0.25) * (o.hi[0] - o.lo[0]) / static_cast<double>(o.lattice_counts[0]);
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
