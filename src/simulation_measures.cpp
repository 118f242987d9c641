// What a Simulation measures of its state (otfp/simulation.hpp): the blob
// mass, the state's measures and the blob density at the particles; over
// several processes each is this process's share combined through the
// RunDistribution (sums, the largest value, the other processes' blobs
// within reach), and the process queries the CLI's writers use.
#include <algorithm>
#include <cmath>
#include <vector>

#include "otfp/density.hpp"
#include "otfp/images.hpp"
#include "otfp/neighbor_list.hpp"
#include "otfp/run_distribution.hpp"
#include "otfp/simulation.hpp"

namespace otfp {

double Simulation::blob_mass(const BlobMassOptions& options) const {
  const double mine = share_blob_mass(options);
  return distribution_ ? distribution_->sum(mine) : mine;
}

double Simulation::share_blob_mass(const BlobMassOptions& options) const {
  double mass = blob_mass_in_domain(*domain_, particles_, options);
  if (walls_.empty() || particles_.empty()) return mass;
  // Images within the measure's own cut-off of a wall (beyond it a blob has
  // no mass on the other side at the measure's tolerance).
  const double depth = std::sqrt(std::log(1.0 / options.cutoff_tolerance));
  std::vector<double> reach(particles_.size());
  for (std::size_t p = 0; p < particles_.size(); ++p) reach[p] = depth * particles_.widths()[p];
  WallImages images(walls_);
  images.select(particles_.positions(), reach);
  if (images.size() == 0) return mass;
  std::vector<Vec3> y;
  images.positions(particles_.positions(), y);
  ParticleSet blobs(domain_->dim());
  blobs.reserve(y.size());
  for (std::size_t i = 0; i < y.size(); ++i) {
    const std::uint32_t q = images.sources()[i];
    blobs.add(y[i], particles_.widths()[q], particles_.masses()[q], 0.0);
  }
  return mass + blob_mass_in_domain(*domain_, blobs, options);
}

StateMeasures Simulation::measure(const Vec3& center, std::vector<std::int32_t>* region) const {
  StateMeasures r = measure_state(*domain_, buffer_, particles_, center, time_, region);
  if (!distribution_) return r;
  // One reduction of the sums (counts as doubles: exact below 2^53) and
  // one of the largest age (an empty share reports 0, and ages are >= 0).
  double v[11] = {static_cast<double>(r.n_particles), static_cast<double>(r.n_inside),
                  static_cast<double>(r.n_buffer), static_cast<double>(r.n_outside), r.mass_total, r.mass_inside,
                  r.mass_with_layer, r.polar_inertia, r.polar_inertia_with_layer, r.polar_inertia_total,
                  r.mean_age * static_cast<double>(r.n_particles)};
  distribution_->sum(v, 11);
  r.n_particles = static_cast<std::int64_t>(v[0]);
  r.n_inside = static_cast<std::int64_t>(v[1]);
  r.n_buffer = static_cast<std::int64_t>(v[2]);
  r.n_outside = static_cast<std::int64_t>(v[3]);
  r.mass_total = v[4];
  r.mass_inside = v[5];
  r.mass_with_layer = v[6];
  r.polar_inertia = v[7];
  r.polar_inertia_with_layer = v[8];
  r.polar_inertia_total = v[9];
  r.mean_age = r.n_particles > 0 ? v[10] / static_cast<double>(r.n_particles) : 0.0;
  r.max_age = distribution_->max(r.max_age);
  return r;
}

std::vector<double> Simulation::particle_density(double kernel_tolerance) const {
  const Periodicity per = domain_->is_periodic() ? Periodicity::from_domain(*domain_) : Periodicity::none(domain_->dim());
  std::vector<double> rho;
  if (!distribution_) {
    if (!particles_.empty()) blob_density(particles_, particles_.positions(), per, kernel_tolerance, rho, nullptr);
    return rho;
  }
  // This share and the other processes' blobs within the largest cut-off.
  double s_max = 0.0;
  for (double s : particles_.widths()) s_max = std::max(s_max, s);
  s_max = distribution_->max(s_max);
  ParticleSet blobs = particles_;
  const ParticleSet others = distribution_->nearby(particles_, cutoff_radius(s_max, kernel_tolerance), per);
  for (std::size_t p = 0; p < others.size(); ++p)
    blobs.add(others.positions()[p], others.widths()[p], others.masses()[p]);
  if (!particles_.empty()) blob_density(blobs, particles_.positions(), per, kernel_tolerance, rho, nullptr);
  return rho;
}

ParticleSet Simulation::gathered_particles() const { return distribution_ ? distribution_->gather(particles_) : particles_; }

bool Simulation::root_process() const { return !distribution_ || distribution_->root(); }
int Simulation::process_rank() const { return distribution_ ? distribution_->rank() : 0; }
int Simulation::process_count() const { return distribution_ ? distribution_->size() : 1; }

bool Simulation::any_process(bool v) const {
  return distribution_ ? distribution_->sum(std::int64_t{v ? 1 : 0}) > 0 : v;
}

}  // namespace otfp
