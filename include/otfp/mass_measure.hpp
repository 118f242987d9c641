#pragma once
// Mass of the blob density inside Omega, independent of where the particle
// centres sit:
//
//   M_rho = integral over Omega of rho(y),   rho(y) = sum_q m_q (beta_q/pi)^(d/2) exp(-beta_q |y - x_q|^2)
//         = sum_q m_q P_q(Omega),
//
// where P_q is the probability that a normal variable with mean x_q and
// variance 1/(2 beta_q) = s_q^2 / 2 per axis lies in Omega. (43) counts a
// particle fully or not at all by the sign of sd(x_q); M_rho counts the part
// of each blob that lies inside, so it does not jump when a centre crosses
// the boundary and it sees the mass that a soft barrier holds just outside.
//
// Estimators, by domain (blob_mass_method()):
//   ClosedForm  box (any d): product of erf differences; ball: d = 1 erf,
//               d = 2 radial Gauss-Legendre quadrature with the exp-scaled
//               Bessel I0 kernel (error below 1e-11), d = 3 the
//               closed form of gaussian_in_ball(); capped cylinder: axial erf
//               times the d = 2 disc. Sub-patch domains use their base.
//   Total       periodic boxes: every blob counts fully (M_rho = total mass).
//   Quadrature  anything else (CSG, user domains): see blob_fraction_quadrature().
#include <string>
#include <vector>

#include "otfp/geometry.hpp"
#include "otfp/particles.hpp"
#include "otfp/types.hpp"
#include "otfp/enums.hpp"

namespace otfp {

struct BlobMassOptions {
  // Quadrature path: blobs whose centre is farther than the cut-off
  // r_c = s sqrt(ln(1/cutoff_tolerance)) from the boundary count fully
  // (inside) or not at all (outside). At 1e-16, r_c = 6.07 s and the mass of a
  // blob beyond r_c is below 1e-15 of its mass in d <= 3.
  double cutoff_tolerance = 1e-16;
  // Quadrature path: Gauss-Hermite nodes per tangential axis (1 .. 64).
  int hermite_nodes = 10;
  // Use the quadrature path even where a closed form exists (for tests and
  // comparisons).
  bool force_quadrature = false;

  void validate() const;  // throws InvalidArgument naming the field
};

// Which estimator blob_mass_in_domain() uses for this domain.
BlobMassMethod blob_mass_method(const Domain& domain, const BlobMassOptions& options = {});

// P(Omega) for one blob: the fraction of the mass of the Gaussian of centre x
// and width s = beta^-1/2 (variance s^2/2 per axis) that lies in Omega.
double blob_fraction_in_domain(const Domain& domain, const Vec3& x, double width_s,
                               const BlobMassOptions& options = {});
// P_q(Omega) for every particle, in particle order (OpenMP over particles).
std::vector<double> blob_fractions_in_domain(const Domain& domain, const ParticleSet& particles,
                                             const BlobMassOptions& options = {});
// M_rho = sum_q m_q P_q(Omega) (the sum is serial: reproducible for any thread count).
double blob_mass_in_domain(const Domain& domain, const ParticleSet& particles, const BlobMassOptions& options = {});

// ---------------------------------------------------------------------------
// Closed forms. x, lo, hi, a, b use the first `dim` components; s > 0 is the
// blob width (variance s^2/2 per axis); every result is in [0, 1].

// 1-D: P(lo <= X <= hi) = (erf((hi - x)/s) - erf((lo - x)/s)) / 2 (erfc forms in the tails).
double gaussian_in_interval(double x, double s, double lo, double hi);
// Axis-aligned box: the product of the intervals.
double gaussian_in_box(int dim, const Vec3& x, double s, const Vec3& lo, const Vec3& hi);
// Ball of radius R in d = 1, 2, 3; r0 = |x - centre| >= 0. d = 3:
//   P = (erf(A) + erf(B))/2 - s/(2 sqrt(pi) r0) (exp(-A^2) - exp(-B^2)),
//   A = (R - r0)/s, B = (R + r0)/s  (limit r0 -> 0: erf(R/s) - 2R/(s sqrt(pi)) exp(-R^2/s^2)).
double gaussian_in_ball(int dim, double r0, double s, double radius);
// d = 2 disc, by radial quadrature of the Rice density
//   f(r) = (2r/s^2) exp(-(r - r0)^2/s^2) I0e(2 r r0/s^2),  I0e(z) = exp(-z) I0(z),
// over [0, R] clipped to r0 -/+ 7 s (composite 16-point Gauss-Legendre, panels of width <= 2 s).
double gaussian_in_disc(double r0, double s, double radius);
// Capped cylinder with axis from a to b: the axial interval [0, |b - a|] times the disc.
double gaussian_in_cylinder(const Vec3& x, double s, const Vec3& a, const Vec3& b, double radius);

// exp(-z) I0(z) for z >= 0 (power series up to z = 20, asymptotic series beyond;
// relative error about 1e-15).
double bessel_i0_scaled(double z);

// The generic estimator, for any domain given by its signed distance.
// Blobs farther than r_c from the boundary count 1 or 0. For the others, in the
// frame of the outward normal n at the closest boundary point and d-1
// tangents, a tensor Gauss-Hermite rule (hermite_nodes per tangential axis)
// integrates over the tangential directions, and along each normal line
// through a tangential node the weight exp(-xi^2)/sqrt(pi) is integrated
// exactly over the parts of the line inside Omega: the line is walked with
// steps of |sd| (sd is 1-Lipschitz, so no crossing is skipped; at least 0.1 s)
// and every crossing is located by regula falsi. Accuracy per blob (measured
// in tests/test_mass_measure.cpp, s = 0.05, 10 nodes, centres spread over
// |sd| < r_c): flat walls and smooth curved walls (ball, disc, R = 20 s) at
// round-off (< 3e-14); next to edges, corners and a cylinder's rim the normal
// lines run parallel to the other face, the tangential integrand jumps and the
// error reaches 6e-2 (cylinder rim 3e-2), 1e-3 on average over the blobs near
// the walls; more nodes do not remove it. Slivers of Omega (or of its
// complement) thinner than 0.1 s along a normal line can be missed.
double blob_fraction_quadrature(const Domain& domain, const Vec3& x, double width_s,
                                const BlobMassOptions& options = {});

}  // namespace otfp
