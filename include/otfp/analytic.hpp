#pragma once
// Analytic references (docs/method_notes.md#analytic-references). The
// blob-side quantities they are compared with (second moment, mode
// amplitude) are in diagnostics.hpp.
#include "otfp/enums.hpp"
#include "otfp/types.hpp"

namespace otfp::analytic {

// Sphere of radius R, initially empty, surface held at g (Crank eq. 6.20):
// M(t)/M_inf = 1 - (6/pi^2) sum_{n>=1} n^-2 exp(-n^2 pi^2 kappa t / R^2).
double crank_sphere_uptake(double kappa_t_over_R2);

// Slab 0 < x < L, x = 0 held at g, x = L no flux (Crank eq. 4.18):
// M(t)/M_inf = 1 - sum_{k>=0} 8/((2k+1)^2 pi^2) exp(-(2k+1)^2 pi^2 kappa t / (4 L^2)).
double crank_slab_uptake(double kappa_t_over_L2);

// Same sphere: polar inertia about the centre relative to its steady value
// J_inf = (3/5) M_inf R^2. From the radial profile (Crank 6.18) integrated
// against r^2: J/J_inf = 1 + 5 sum_n exp(-n^2 pi^2 tau) (12/(n pi)^4 - 2/(n pi)^2).
double crank_sphere_polar_inertia(double kappa_t_over_R2);

// Same slab: rho/g at depth xi from the held face (Crank 4.17 with the no-flux
// face as the symmetry plane):
// 1 - (4/pi) sum_k (-1)^k/(2k+1) exp(-(2k+1)^2 pi^2 tau / 4) cos((2k+1) pi (1 - xi/L) / 2).
double crank_slab_density(double kappa_t_over_L2, double depth_over_L);

// Same slab inside the box [lo, hi] (dim axes), held face normal to `axis`
// at hi (held_at_hi) or lo, depth `length` = L: the polar inertia about
// `center` of the density g rho/g (crank_slab_density) with M_inf = g |Omega|.
// The depth integral is Simpson's rule over `intervals` (even) intervals; the
// transverse axes add their uniform second moment.
struct SlabBox {
  int dim = 3;
  Vec3 lo = Vec3::Zero(), hi = Vec3::Ones();
  int axis = 0;
  bool held_at_hi = false;
  double length = 1.0;
  Vec3 center = Vec3::Zero();
  double M_inf = 1.0;
};
double crank_slab_polar_inertia(double kappa_t_over_L2, const SlabBox& slab, int intervals = 512);

// Free space: growth of the second moment per axis, 2 kappa t.
inline double free_space_variance_growth(double kappa, double t) { return 2.0 * kappa * t; }

// Periodic box, density 1 + a cos(k x): amplitude factor exp(-kappa k^2 t).
double cosine_mode_decay(double kappa, double wavenumber, double t);

// The decay rate the time scheme alone gives a mode exp(-lambda t) at
// constant steps dt (exact in space): -log(g) / dt with the amplification
// factor g per step; +infinity where g <= 0. Implicit Euler 1 / (1 + z),
// z = lambda dt; BDF2 the principal root of (3/2 + z) g^2 - 2 g + 1/2 = 0
// (the modulus of the complex pair for z > 1/2); the explicit Euler schemes
// 1 - z; RK4 its quartic.
double time_discrete_rate(TimeScheme scheme, double lambda, double dt);
double time_discrete_rate(ExplicitScheme scheme, double lambda, double dt);

}  // namespace otfp::analytic
