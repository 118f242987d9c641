#include "otfp/diagnostics.hpp"

#include <algorithm>
#include <cmath>

namespace otfp {

Region region_of(const Domain& domain, const BufferSpec& buffer, const Vec3& x) {
  const BoundaryQuery q = domain.query(x);
  if (q.signed_distance <= 0.0) return Region::Inside;
  if (q.patch >= 0 && static_cast<std::size_t>(q.patch) < buffer.buffer_patch.size() &&
      buffer.buffer_patch[static_cast<std::size_t>(q.patch)] && q.signed_distance <= buffer.buffer_width)
    return Region::Buffer;
  return Region::Elsewhere;
}

StateMeasures measure_state(const Domain& domain, const BufferSpec& buffer, const ParticleSet& particles,
                            const Vec3& center, double t, std::vector<std::int32_t>* region) {
  StateMeasures r;
  const std::size_t n = particles.size();
  if (region) region->assign(n, static_cast<std::int32_t>(Region::Elsewhere));
  double age_sum = 0.0;
  for (std::size_t p = 0; p < n; ++p) {
    const Vec3& x = particles.positions()[p];
    const double m = particles.masses()[p];
    const Region where = region_of(domain, buffer, x);
    const double r2 = (x - center).squaredNorm();
    r.mass_total += m;
    r.polar_inertia_total += m * r2;
    if (where == Region::Inside) {
      ++r.n_inside;
      r.mass_inside += m;
      r.polar_inertia += m * r2;
    } else if (where == Region::Buffer) {
      ++r.n_buffer;
    } else {
      ++r.n_outside;
    }
    if (where != Region::Elsewhere) {
      r.mass_with_layer += m;
      r.polar_inertia_with_layer += m * r2;
    }
    if (region) (*region)[p] = static_cast<std::int32_t>(where);
    const double age = t - particles.birth_times()[p];
    age_sum += age;
    r.max_age = std::max(r.max_age, age);
  }
  r.n_particles = static_cast<std::int64_t>(n);
  r.mean_age = n ? age_sum / static_cast<double>(n) : 0.0;
  return r;
}

void L1Norms::add_first(const StateMeasures& now, double dt) {
  mass_rectangle = now.mass_total * dt;
  polar_inertia_rectangle = now.polar_inertia_total * dt;
}

void L1Norms::add(const StateMeasures& previous, const StateMeasures& now, double dt) {
  mass_rectangle += now.mass_total * dt;
  polar_inertia_rectangle += now.polar_inertia_total * dt;
  mass_inside_trapezoid += 0.5 * (previous.mass_inside + now.mass_inside) * dt;
  mass_with_layer_trapezoid += 0.5 * (previous.mass_with_layer + now.mass_with_layer) * dt;
  polar_inertia_inside_trapezoid += 0.5 * (previous.polar_inertia + now.polar_inertia) * dt;
  polar_inertia_with_layer_trapezoid += 0.5 * (previous.polar_inertia_with_layer + now.polar_inertia_with_layer) * dt;
}

double blob_second_moment(const ParticleSet& particles, const Vec3& center) {
  const double dim = static_cast<double>(particles.dim());
  double S = 0.0;
  for (std::size_t p = 0; p < particles.size(); ++p) {
    const double sp = particles.widths()[p];
    S += particles.masses()[p] * ((particles.positions()[p] - center).squaredNorm() + 0.5 * dim * sp * sp);
  }
  return S;
}

double cosine_mode_amplitude(const ParticleSet& particles, double wavenumber, double x0) {
  const double k = wavenumber;
  double A = 0.0, mass = 0.0;
  for (std::size_t p = 0; p < particles.size(); ++p) {
    const double sp = particles.widths()[p];
    A += particles.masses()[p] * std::exp(-0.25 * k * k * sp * sp) * std::cos(k * (particles.positions()[p][0] - x0));
    mass += particles.masses()[p];
  }
  return mass > 0.0 ? A * (2.0 / mass) : 0.0;
}

}  // namespace otfp
