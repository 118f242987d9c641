#pragma once
// Initial particles (Algorithm 1, "Require: fill Omega with n_0 particles"):
// uniform in Omega (random or on a lattice of cell centres), a Gaussian
// cloud, or a cosine mode 1 + a cos(k (x - lo_x)) along x in a box.
//
// The square and cubic lattices of cell centres are saddles of the entropy
// at beta dr^2 = 2 (docs/stepper.md, "The step's Hessian"): their steps
// rearrange them. The staggered lattice is a minimum: in 2-D every other row
// (along y) shifted by half a cell along x, in 3-D body-centred cubic (two
// points per cell, at 1/4 and 3/4 of its diagonal); in 1-D it is the
// lattice itself.
#include <array>
#include <cstdint>

#include "otfp/geometry.hpp"
#include "otfp/particles.hpp"
#include "otfp/enums.hpp"

namespace otfp {

struct FillOptions {
  FillShape shape = FillShape::Uniform;      // what density the particles sample
  std::int64_t count = 0;                    // particles (>= 0); with lattice: lattice_point_count(dim, lattice_counts, staggered)
  double width_s = 0.0;                      // s of every particle (> 0)
  double mass = 0.0;                         // m_p of every particle (> 0)
  bool lattice = false;                      // Uniform or Cosine: cell centres of a lattice in the box [lo, hi]
  std::array<std::int64_t, 3> lattice_counts{1, 1, 1};  // lattice cells per axis
  bool staggered = false;                    // lattice: staggered (2-D: an even count along y; 3-D: bcc)
  Vec3 lo = Vec3::Zero(), hi = Vec3::Ones();  // the box of the lattice and of the cosine fill
  Vec3 center = Vec3::Zero();                // Gaussian: centre
  double sigma = 0.1;                        // Gaussian: standard deviation per axis (> 0)
  double amplitude = 0.5;                    // Cosine: a in [0, 1)
  double wavenumber = 0.0;                   // Cosine: k (> 0)
  void validate() const;                     // throws InvalidArgument naming the field
};

// Draws in order from rng (the same stream gives the same particles); a
// Uniform random fill samples Omega itself, a Gaussian one is wrapped into a
// periodic cell. Particles are born at t = 0.
ParticleSet fill_particles(const Domain& domain, const FillOptions& options, Rng& rng);

// Points of a lattice of `counts` cells per axis in dimension dim: one per
// cell, or with `staggered` two per cell in 3-D (bcc).
std::int64_t lattice_point_count(int dim, const std::array<std::int64_t, 3>& counts, bool staggered);

// xi with xi + (a/k) sin(k xi) = u: the inverse of the cumulative density of
// 1 + a cos(k xi) (a < 1: strictly increasing, Newton converges).
double invert_cosine_cdf(double u, double a, double k);

}  // namespace otfp
