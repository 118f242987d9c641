#pragma once
// Advection and source fractional steps (Algorithm 1, lines 2-3).
#include <cstdint>
#include <functional>
#include <vector>

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

// The same step with each particle's random numbers drawn from a stream of
// its own, keyed by `key` (one draw of the run's generator per step) and the
// particle's id, and the copies numbered from first_id in the order of their
// parents' ids: the result depends neither on the particles' storage order
// nor, over several processes, on which process holds which particle.
// Collective over the processes when `gather` and `sum` are set (each
// process passes its share; null: one process): gather returns every
// process's values concatenated, sum adds in place. The result's counts and
// masses are then the totals over all processes, every process's alike, and
// so is a refusal (ResourceLimitExceeded against max_particles, counted over
// all processes; InvalidArgument for a non-finite source).
struct SourceDraws {
  std::uint64_t key = 0;
  ParticleId first_id = 0;            // the first free id (over all processes)
  std::int64_t global_size = -1;      // the particles of all processes (-1: this set's size)
  std::function<std::vector<std::int64_t>(const std::vector<std::int64_t>&)> gather;
  std::function<void(double*, int)> sum;
};
SourceResult apply_source_by_id(ParticleSet& particles, const SourceField& s, double t, double dt,
                                const SourceDraws& draws, std::int64_t max_particles = 0);

}  // namespace otfp
