#include "placement_density.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <numbers>

#include "fast_exp.hpp"
#include "otfp/neighbor_list.hpp"

namespace otfp::detail {

PlacementDensity::PlacementDensity(const ParticleSet& particles, const std::vector<MirrorWallPtr>& walls,
                                   double kernel_tolerance, double s_floor) {
  const int dim = particles.dim();
  double s_max = s_floor;
  for (double s : particles.widths()) s_max = std::max(s_max, s);
  radius_ = cutoff_radius(s_max > 0.0 ? s_max : 1.0, kernel_tolerance);
  if (particles.empty()) return;
  blobs_ = particles.positions();
  width_ = particles.widths();
  mass_ = particles.masses();
  if (!walls.empty()) {
    WallImages images(walls);
    images.select(particles.positions(), std::vector<double>(particles.size(), radius_));
    std::vector<Vec3> y;
    images.positions(particles.positions(), y);
    for (std::size_t i = 0; i < y.size(); ++i) {
      const std::uint32_t q = images.sources()[i];
      blobs_.push_back(y[i]);
      width_.push_back(particles.widths()[q]);
      mass_.push_back(particles.masses()[q]);
    }
  }
  // Cells half the cut-off wide, visited only where they come within the
  // cut-off of the query: about a third of the volume of 3^d cells of r_c.
  grid_.build(blobs_, 0.5 * radius_, Periodicity::none(dim), 2);
  // Each blob's factors in the grid's cell order, next to its sorted coordinates.
  const auto& items = grid_.items();
  beta_.resize(items.size());
  pre_.resize(items.size());
  for (std::size_t k = 0; k < items.size(); ++k) {
    const double sq = width_[items[k]];
    beta_[k] = 1.0 / (sq * sq);
    pre_[k] = mass_[items[k]] * std::pow(beta_[k] / std::numbers::pi, 0.5 * dim);
  }
}

double PlacementDensity::at(const Vec3& y) const {
  if (pre_.empty()) return 0.0;
  double rho = 0.0;
  const double r2 = radius_ * radius_;
  const double* sx = grid_.sorted_x().data();
  const double* sy = grid_.sorted_y().data();
  const double* sz = grid_.sorted_z().data();
  const double* pre = pre_.data();
  const double* beta = beta_.data();
  grid_.for_each_cell(y, 2, radius_, [&](std::uint32_t b, std::uint32_t e, const Vec3&) {
    // Branch-free so that it vectorises: blobs beyond the cut-off add 0.
    double sum = 0.0;
    for (std::uint32_t k = b; k < e; ++k) {
      const double dx = y[0] - sx[k], dy = y[1] - sy[k], dz = y[2] - sz[k];
      const double d2 = dx * dx + dy * dy + dz * dz;
      const double inside = d2 < r2 ? 1.0 : 0.0;
      sum += inside * pre[k] * exp_nonpositive(-beta[k] * d2);
    }
    rho += sum;
  });
  return rho;
}

PlacementDensity::Kernel::Kernel(double s, double m, int dim)
    : beta(1.0 / (s * s)), factor(m * std::pow(beta / std::numbers::pi, 0.5 * dim)) {}

double PlacementDensity::Kernel::operator()(const Vec3& y, const Vec3& x) const {
  return factor * std::exp(-beta * (y - x).squaredNorm());
}

}  // namespace otfp::detail
