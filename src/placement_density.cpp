#include "placement_density.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <numbers>

#include "otfp/neighbor_list.hpp"

namespace otfp::detail {

PlacementDensity::PlacementDensity(const ParticleSet& particles, const std::vector<MirrorWallPtr>& walls,
                                   double kernel_tolerance) {
  const int dim = particles.dim();
  double s_max = 0.0;
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
  grid_.build(blobs_, radius_, Periodicity::none(dim), 1);
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
  grid_.for_each_cell(y, [&](std::uint32_t b, std::uint32_t e, const Vec3&) {
    for (std::uint32_t k = b; k < e; ++k) {
      const double dx = y[0] - sx[k], dy = y[1] - sy[k], dz = y[2] - sz[k];
      const double d2 = dx * dx + dy * dy + dz * dz;
      if (d2 < r2) rho += pre_[k] * std::exp(-beta_[k] * d2);
    }
  });
  return rho;
}

double PlacementDensity::kernel(const Vec3& y, const Vec3& x, double s, double m, int dim) {
  const double beta = 1.0 / (s * s);
  return m * std::pow(beta / std::numbers::pi, 0.5 * dim) * std::exp(-beta * (y - x).squaredNorm());
}

}  // namespace otfp::detail
