#pragma once
// Blob density (29) and its gradient at arbitrary points:
//   rho(y) = sum_q m_q (beta_q/pi)^(d/2) exp(-beta_q |y - x_q|^2).
// At the particles themselves use EntropyTerm::density() after an evaluation.
#include <vector>

#include "otfp/neighbor_list.hpp"
#include "otfp/particles.hpp"

namespace otfp {

// Cell-list accelerated: blobs further than their cut-off radius (kernel
// tolerance, NeighborOptions) from y are skipped. grad may be null.
void blob_density(const ParticleSet& particles, const std::vector<Vec3>& points, const Periodicity& periodicity,
                  double kernel_tolerance, std::vector<double>& rho, std::vector<Vec3>* grad);

// The same for blobs given as arrays (positions, widths s, masses of one
// length; dim the dimension of the Gaussians).
void blob_density(int dim, const std::vector<Vec3>& x, const std::vector<double>& s, const std::vector<double>& m,
                  const std::vector<Vec3>& points, const Periodicity& periodicity, double kernel_tolerance,
                  std::vector<double>& rho, std::vector<Vec3>* grad);

// Plain O(n m) sum over all blobs (reference for tests).
void blob_density_all_pairs(const ParticleSet& particles, const std::vector<Vec3>& points,
                            const Periodicity& periodicity, std::vector<double>& rho, std::vector<Vec3>* grad);

}  // namespace otfp
