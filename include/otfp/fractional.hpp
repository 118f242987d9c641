#pragma once
// Advection and source fractional steps (Algorithm 1, lines 2-3).
#include <functional>

#include "otfp/particles.hpp"

namespace otfp {

using VelocityField = std::function<Vec3(const Vec3& x, double t)>;
using SourceField = std::function<double(const Vec3& x, double t)>;

// Moves every particle along the flow of u over [t, t + dt] with `substeps`
// classical RK4 steps: exact for a uniform u(t) that is polynomial of degree
// <= 3 in t, fourth-order accurate otherwise.
void advect(ParticleSet& particles, const VelocityField& u, double t, double dt, int substeps = 4);

struct SourceResult {
  long inserted = 0, removed = 0;
  double mass_inserted = 0.0, mass_removed = 0.0;
};

// rho <- rho exp(int_t^{t+dt} s dt') (Simpson's rule in time, at each particle):
// with growth factor g a particle is removed with probability 1 - g (g < 1),
// or gets floor(g - 1) copies plus one more with probability frac(g - 1)
// (g >= 1), so the expected mass change is exact. A copy is placed at a
// random point of its parent blob (a draw from N(x_p, s_p^2/2 per axis)).
// Throws ResourceLimitExceeded before a particle's copies would take the set
// past max_particles (<= 0: kMaxParticleCount).
SourceResult apply_source(ParticleSet& particles, const SourceField& s, double t, double dt, Rng& rng,
                          std::int64_t max_particles = 0);

}  // namespace otfp
