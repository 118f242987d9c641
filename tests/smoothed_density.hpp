#pragma once
// The norm of the density error estimate (ErrorMeasure::Density,
// docs/stepper.md), computed independently of the stepper for the tests:
// the blob densities of a and b, each blob widened to s sqrt(1 + c^2) (the
// blob density convolved with a Gaussian of c widths), at a's particles;
// mass-weighted RMS of the difference relative to the mass-weighted mean of
// a's, with the cut-off at 1e-12 (and the largest difference, the local
// form).
#include <algorithm>
#include <cmath>
#include <vector>

#include "otfp/density.hpp"
#include "otfp/particles.hpp"

namespace otfp::test {

// The smoothed blob densities of a and b at a's particles (ra, rb).
inline void smoothed_densities(const ParticleSet& a, const ParticleSet& b, double smoothing, const Periodicity& per,
                               std::vector<double>& ra, std::vector<double>& rb) {
  const double widen = std::sqrt(1.0 + smoothing * smoothing);
  auto widened = [&](const ParticleSet& p) {
    std::vector<double> w = p.widths();
    for (double& v : w) v *= widen;
    return w;
  };
  blob_density(a.dim(), a.positions(), widened(a), a.masses(), a.positions(), per, 1e-12, ra, nullptr);
  blob_density(b.dim(), b.positions(), widened(b), b.masses(), a.positions(), per, 1e-12, rb, nullptr);
}

inline double smoothed_density_difference(const ParticleSet& a, const ParticleSet& b, double smoothing,
                                          const Periodicity& per) {
  std::vector<double> ra, rb;
  smoothed_densities(a, b, smoothing, per, ra, rb);
  double sum = 0.0, mean = 0.0, mass = 0.0;
  for (std::size_t i = 0; i < ra.size(); ++i) {
    const double m = a.masses()[i];
    sum += m * (ra[i] - rb[i]) * (ra[i] - rb[i]);
    mean += m * ra[i];
    mass += m;
  }
  return std::sqrt(sum / mass) / (mean / mass);
}

// The local form: the largest difference at a's particles relative to the
// mean of a's density.
inline double largest_smoothed_density_difference(const ParticleSet& a, const ParticleSet& b, double smoothing,
                                                  const Periodicity& per) {
  std::vector<double> ra, rb;
  smoothed_densities(a, b, smoothing, per, ra, rb);
  double worst = 0.0, mean = 0.0;
  for (std::size_t i = 0; i < ra.size(); ++i) {
    worst = std::max(worst, std::abs(ra[i] - rb[i]));
    mean += ra[i];
  }
  return worst / (mean / static_cast<double>(ra.size()));
}

}  // namespace otfp::test
