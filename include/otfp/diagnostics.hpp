#pragma once
// The diagnostics of [2025] Sec. 5.1: the mass M (43) and the polar inertia
// J_G (44) inside Omega and with the external layer, and their L1-in-time
// norms (46). docs/outputs.md defines every quantity.
#include <cstdint>
#include <vector>

#include "otfp/geometry.hpp"
#include "otfp/particles.hpp"

namespace otfp {

// Where a particle is: inside Omega (sd <= 0), in the buffer outside a
// Dirichlet patch (B^ext of width b, or the reservoir band of width w), or
// elsewhere (outside Omega at another patch, or beyond the buffer).
enum class Region : std::int32_t { Inside = 0, Buffer = 1, Elsewhere = 2 };

// Which particles count as "with the layer": those within buffer_width of
// Omega whose closest boundary point is on a patch flagged in buffer_patch.
struct BufferSpec {
  std::vector<char> buffer_patch;  // by patch id: 1 for a Dirichlet patch
  double buffer_width = 0.0;       // b, or w for the reservoir
};

Region region_of(const Domain& domain, const BufferSpec& buffer, const Vec3& x);

// Sums over the particles at time t about the centre c.
struct StateMeasures {
  std::int64_t n_particles = 0, n_inside = 0, n_buffer = 0, n_outside = 0;
  double mass_total = 0.0;                // all particles
  double mass_inside = 0.0;               // (43): particles in Omega
  double mass_with_layer = 0.0;           // (43) with the buffer
  double polar_inertia = 0.0;             // (44): sum m |x - c|^2 over particles in Omega
  double polar_inertia_with_layer = 0.0;  // (44) with the buffer
  double polar_inertia_total = 0.0;       // (44) over all particles, as (46) sums it
  double mean_age = 0.0, max_age = 0.0;   // t - birth time
};

// region (optional) receives the Region of each particle, as int32.
StateMeasures measure_state(const Domain& domain, const BufferSpec& buffer, const ParticleSet& particles,
                            const Vec3& center, double t, std::vector<std::int32_t>* region = nullptr);

// Second moment of the blob density about c: sum_p m_p (|x_p - c|^2 + d s_p^2 / 2)
// (each Gaussian adds its own variance d s^2 / 2; it grows by 2 d kappa M t
// in free space, analytic::free_space_variance_growth per axis).
double blob_second_moment(const ParticleSet& particles, const Vec3& center);

// Amplitude a of the mode 1 + a cos(k (x - x0)) of the blob density along
// the first axis: (2 / M) sum_p m_p exp(-k^2 s_p^2 / 4) cos(k (x_p - x0))
// (a Gaussian of width s damps the mode by exp(-k^2 s^2 / 4)). 0 for an
// empty set.
double cosine_mode_amplitude(const ParticleSet& particles, double wavenumber, double x0);

// Running L1-in-time norms (46). The rectangle sums are (46a)-(46b) as
// printed: sum over k = 0..K of the value at t_k times dt, over all particles
// (external shells included); the trapezoid sums integrate the inside and
// with-layer values over [0, t].
struct L1Norms {
  double mass_rectangle = 0.0, polar_inertia_rectangle = 0.0;
  double mass_inside_trapezoid = 0.0, mass_with_layer_trapezoid = 0.0;
  double polar_inertia_inside_trapezoid = 0.0, polar_inertia_with_layer_trapezoid = 0.0;
  // The first row (k = 0) adds only its rectangle; later rows add both rules
  // with the step dt from the previous row's measures.
  void add_first(const StateMeasures& now, double dt);
  void add(const StateMeasures& previous, const StateMeasures& now, double dt);
};

}  // namespace otfp
