#include "otfp/fractional.hpp"

#include <cmath>

namespace otfp {

void advect(ParticleSet& particles, const VelocityField& u, double t, double dt, int substeps) {
  require(substeps >= 1, "advection substeps", substeps, "must be >= 1");
  require(std::isfinite(dt) && dt >= 0.0, "dt", dt, "must be finite and >= 0");
  const double h = dt / substeps;
  const int dim = particles.dim();
  for (auto& x : particles.positions()) {
    double tt = t;
    for (int k = 0; k < substeps; ++k) {
      const Vec3 k1 = u(x, tt);
      const Vec3 k2 = u(x + 0.5 * h * k1, tt + 0.5 * h);
      const Vec3 k3 = u(x + 0.5 * h * k2, tt + 0.5 * h);
      const Vec3 k4 = u(x + h * k3, tt + h);
      x += h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4);
      tt += h;
    }
    for (int k = dim; k < 3; ++k) x[k] = 0.0;
    require(x.allFinite(), "advected position", x.norm(), "must be finite (check the velocity field)");
  }
}

SourceResult apply_source(ParticleSet& particles, const SourceField& s, double t, double dt, Rng& rng,
                          std::int64_t max_particles) {
  SourceResult result;
  const int dim = particles.dim();
  const std::size_t n0 = particles.size();
  std::vector<std::size_t> doomed;
  for (std::size_t p = 0; p < n0; ++p) {
    const Vec3 x = particles.positions()[p];
    const double integral = dt / 6.0 * (s(x, t) + 4.0 * s(x, t + 0.5 * dt) + s(x, t + dt));
    require(std::isfinite(integral), "source s(x, t)", integral, "must be finite");
    const double g = std::exp(integral);
    const double m = particles.masses()[p];
    if (g < 1.0) {
      if (rng.uniform() >= g) {
        doomed.push_back(p);
        ++result.removed;
        result.mass_removed += m;
      }
    } else {
      const double extra = g - 1.0;
      require_particle_room(std::ceil(extra), particles.size(), max_particles, "the source at a particle");
      long copies = static_cast<long>(std::floor(extra));
      if (rng.uniform() < extra - std::floor(extra)) ++copies;
      const double spread = particles.widths()[p] / std::sqrt(2.0);
      for (long c = 0; c < copies; ++c) {
        Vec3 y = x;
        for (int k = 0; k < dim; ++k) y[k] += spread * rng.normal();
        particles.add(y, particles.widths()[p], m, t + dt);
        ++result.inserted;
        result.mass_inserted += m;
      }
    }
  }
  particles.remove_indices(std::move(doomed));
  return result;
}

}  // namespace otfp
