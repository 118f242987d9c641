#pragma once
// The norm of the density error estimate (ErrorMeasure::Density,
// docs/stepper.md), computed independently of the stepper for the tests:
// the blob densities of a and b, each blob widened to s sqrt(1 + c^2) (the
// blob density convolved with a Gaussian of c widths), at a's particles;
// mass-weighted RMS of the difference relative to the mass-weighted mean of
// a's, with the cut-off at 1e-12.
#include <cmath>
#include <vector>

#include "otfp/density.hpp"
#include "otfp/particles.hpp"

namespace otfp::test {

inline double smoothed_density_difference(const ParticleSet& a, const ParticleSet& b, double smoothing,
                                          const Periodicity& per) {
  const double widen = std::sqrt(1.0 + smoothing * smoothing);
  auto widened = [&](const ParticleSet& p) {
    std::vector<double> w = p.widths();
    for (double& v : w) v *= widen;
    return w;
  };
  std::vector<double> ra, rb;
  blob_density(a.dim(), a.positions(), widened(a), a.masses(), a.positions(), per, 1e-12, ra, nullptr);
  blob_density(b.dim(), b.positions(), widened(b), b.masses(), a.positions(), per, 1e-12, rb, nullptr);
  double sum = 0.0, mean = 0.0, mass = 0.0;
  for (std::size_t i = 0; i < ra.size(); ++i) {
    const double m = a.masses()[i];
    sum += m * (ra[i] - rb[i]) * (ra[i] - rb[i]);
    mean += m * ra[i];
    mass += m;
  }
  return std::sqrt(sum / mass) / (mean / mass);
}

}  // namespace otfp::test
