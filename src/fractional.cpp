#include "otfp/fractional.hpp"

#include <algorithm>
#include <cmath>
#include <exception>
#include <stdexcept>
#include <string>

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

namespace {

// Line 3 at particle p: its growth factor g = exp(int_t^{t+dt} s) (Simpson's
// rule in time) and what `rng` makes of it: removed (g < 1, with
// probability 1 - g), or floor(g - 1) copies plus one with probability
// frac(g - 1), placed at draws from N(x_p, s_p^2/2) per axis and appended to
// `places` (refused before the copies are drawn when `held` particles plus
// them would pass max_particles). Returns whether p is removed.
bool particle_fate(const ParticleSet& particles, std::size_t p, const SourceField& s, double t, double dt, Rng& rng,
                   std::size_t held, std::int64_t max_particles, std::vector<Vec3>& places) {
  const Vec3 x = particles.positions()[p];
  const double integral = dt / 6.0 * (s(x, t) + 4.0 * s(x, t + 0.5 * dt) + s(x, t + dt));
  require(std::isfinite(integral), "source s(x, t)", integral, "must be finite");
  const double g = std::exp(integral);
  if (g < 1.0) return rng.uniform() >= g;
  const double extra = g - 1.0;
  require_particle_room(std::ceil(extra), held, max_particles, "the source at a particle");
  long copies = static_cast<long>(std::floor(extra));
  if (rng.uniform() < extra - std::floor(extra)) ++copies;
  const double spread = particles.widths()[p] / std::sqrt(2.0);
  for (long c = 0; c < copies; ++c) {
    Vec3 y = x;
    for (int k = 0; k < particles.dim(); ++k) y[k] += spread * rng.normal();
    places.push_back(y);
  }
  return false;
}

}  // namespace

SourceResult apply_source(ParticleSet& particles, const SourceField& s, double t, double dt, Rng& rng,
                          std::int64_t max_particles) {
  SourceResult result;
  const std::size_t n0 = particles.size();
  std::vector<std::size_t> doomed;
  std::vector<Vec3> places;
  for (std::size_t p = 0; p < n0; ++p) {
    const double m = particles.masses()[p];
    places.clear();
    if (particle_fate(particles, p, s, t, dt, rng, particles.size(), max_particles, places)) {
      doomed.push_back(p);
      ++result.removed;
      result.mass_removed += m;
    }
    for (const Vec3& y : places) {
      particles.add(y, particles.widths()[p], m, t + dt);
      ++result.inserted;
      result.mass_inserted += m;
    }
  }
  particles.remove_indices(std::move(doomed));
  return result;
}

namespace {
// One stream per particle and step: the id spread over 64 bits (a SplitMix64
// finaliser) and mixed with the step's key; Rng seeds itself through
// SplitMix64 again, so neighbouring ids give unrelated streams.
std::uint64_t stream_seed(std::uint64_t key, ParticleId id) {
  std::uint64_t z = static_cast<std::uint64_t>(id) + 0x9E3779B97F4A7C15ull;
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return key ^ (z ^ (z >> 31));
}
}  // namespace

SourceResult apply_source_by_id(ParticleSet& particles, const SourceField& s, double t, double dt,
                                const SourceDraws& draws, std::int64_t max_particles) {
  const std::size_t n0 = particles.size();
  const bool shared = draws.gather && draws.sum;
  const std::int64_t global = draws.global_size >= 0 ? draws.global_size : static_cast<std::int64_t>(n0);
  // 1. Every particle's fate from its own stream; nothing changes yet.
  std::vector<std::size_t> doomed, parent_of;
  std::vector<Vec3> places;
  std::vector<std::int64_t> pairs;  // (parent id, copies) of this process's parents with copies
  // removed, mass removed, mass inserted; refusals: bad data, a resource limit, other
  double sums[6] = {0.0, 0.0, 0.0, 0.0, 0.0, 0.0};
  std::exception_ptr refused;
  require(draws.first_id >= particles.next_id(), "source first_id", static_cast<double>(draws.first_id),
          "must be >= the set's next id " + std::to_string(particles.next_id()));
  try {
    for (std::size_t p = 0; p < n0; ++p) {
      const double m = particles.masses()[p];
      Rng rng(stream_seed(draws.key, particles.ids()[p]));
      // Against the copies this process has drawn so far too.
      const std::size_t before = places.size();
      if (particle_fate(particles, p, s, t, dt, rng, static_cast<std::size_t>(global) + before, max_particles,
                        places)) {
        doomed.push_back(p);
        sums[0] += 1.0;
        sums[1] += m;
      }
      const auto copies = static_cast<std::int64_t>(places.size() - before);
      for (std::int64_t c = 0; c < copies; ++c) {
        parent_of.push_back(p);
        sums[2] += m;
      }
      if (copies > 0) pairs.insert(pairs.end(), {particles.ids()[p], copies});
    }
  } catch (const InvalidArgument&) {
    refused = std::current_exception();
    sums[3] = 1.0;
  } catch (const ResourceLimitExceeded&) {
    refused = std::current_exception();
    sums[4] = 1.0;
  } catch (...) {
    refused = std::current_exception();
    sums[5] = 1.0;
  }
  // 2. A refusal anywhere is every process's, of the same kind.
  if (shared) draws.sum(sums, 6);
  if (refused) std::rethrow_exception(refused);
  const std::string elsewhere = "the source: refused on another process (its error names the cause)";
  if (sums[3] > 0.0) throw InvalidArgument(elsewhere);
  if (sums[4] > 0.0) throw ResourceLimitExceeded(elsewhere);
  if (sums[5] > 0.0) throw std::runtime_error(elsewhere);
  // 3. The copies numbered in the order of their parents' ids, over all processes.
  std::vector<std::int64_t> all = shared ? draws.gather(pairs) : pairs;
  std::vector<std::pair<std::int64_t, std::int64_t>> parents;
  for (std::size_t i = 0; i + 1 < all.size(); i += 2) parents.emplace_back(all[i], all[i + 1]);
  std::sort(parents.begin(), parents.end());
  std::int64_t total = 0;
  for (auto& [id, count] : parents) {
    const std::int64_t c = count;
    count = total;  // now the first copy's offset
    total += c;
  }
  require_particle_room(static_cast<double>(total), static_cast<std::size_t>(global - static_cast<std::int64_t>(sums[0])),
                        max_particles, "the source");
  // 4. Apply.
  for (std::size_t k = 0; k < places.size();) {
    const std::size_t p = parent_of[k];
    const ParticleId id = particles.ids()[p];
    const auto it = std::lower_bound(parents.begin(), parents.end(), std::make_pair(id, std::int64_t{0}),
                                     [](const auto& a, const auto& b) { return a.first < b.first; });
    std::int64_t next = draws.first_id + it->second;
    for (; k < places.size() && parent_of[k] == p; ++k)
      particles.add_with_id(next++, places[k], particles.widths()[p], particles.masses()[p], t + dt);
  }
  particles.set_next_id(std::max<ParticleId>(particles.next_id(), draws.first_id + total));
  particles.remove_indices(std::move(doomed));
  SourceResult result;
  result.inserted = static_cast<long>(total);
  result.removed = static_cast<long>(sums[0]);
  result.mass_removed = sums[1];
  result.mass_inserted = sums[2];
  return result;
}

}  // namespace otfp
