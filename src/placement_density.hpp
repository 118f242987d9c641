#pragma once
// Internal: the blob density (29) at arbitrary points with the image blobs
// the functional has at mirrored walls. The quiet Dirichlet reservoir
// (src/reservoir.cpp) measures its sublayers' deficits with it and puts
// particles where it is lowest and takes them where it is highest. Not
// installed; tests/test_reservoir.cpp checks it against the O(n^2) sum.
#include <vector>

#include "cell_grid.hpp"
#include "otfp/images.hpp"
#include "otfp/particles.hpp"

namespace otfp::detail {

// The kernel value (relative to its peak) at the placement density's cut-off.
constexpr double kPlacementKernelTolerance = 1e-8;

class PlacementDensity {
 public:
  // The blobs are the particles and their images across `walls`, chosen as
  // the functional chooses them (WallImages with the cut-off as reach, up to
  // images of images at edges and corners), so that a settled state of the
  // functional reads as one here. Kernels are cut at kernel_tolerance.
  PlacementDensity(const ParticleSet& particles, const std::vector<MirrorWallPtr>& walls,
                   double kernel_tolerance = kPlacementKernelTolerance, double s_floor = 0.0);
  // The largest cut-off radius of the blobs (of a width s_floor at least:
  // other processes' blobs, which a distributed projection does not hold).
  double radius() const { return radius_; }
  // The blob density at y, images included.
  double at(const Vec3& y) const;
  // The blobs (particles, then images) and their widths and masses.
  const std::vector<Vec3>& blobs() const { return blobs_; }
  const std::vector<double>& widths() const { return width_; }
  const std::vector<double>& masses() const { return mass_; }
  // The kernel of a blob of width s and mass m, w(y) = m (beta/pi)^(d/2)
  // exp(-beta |y - x|^2) with beta = 1/s^2 (29), uncut: its two factors once,
  // then its value at a distance.
  struct Kernel {
    double beta = 0.0, factor = 0.0;
    Kernel(double s, double m, int dim);
    double operator()(const Vec3& y, const Vec3& x) const;
  };

 private:
  double radius_ = 0.0;
  std::vector<Vec3> blobs_;
  std::vector<double> width_, mass_;
  CellGrid grid_;
  std::vector<double> beta_, pre_;  // per blob, in grid_ order
};

}  // namespace otfp::detail
