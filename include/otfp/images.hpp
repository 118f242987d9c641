#pragma once
// No-flux walls by image blobs (issue 10; docs/boundaries.md).
//
// For a planar wall the Neumann heat kernel of the half-space is
// G(x - y) + G(x - y*), y* the mirror image of y, so adding to rho the images
// of the blobs near a wall removes the outward push of the density deficit
// there. The images move with their sources: y* = R(x), and the gradient of
// the entropy picks up the Jacobian of R (dE/dx += J^T dE/dy*). Edges and
// corners get images of images (every nonempty subset of the nearby walls,
// composed), which is the exact method of images for a quarter or eighth space.
//
// Curved walls reflect across the tangent plane at the closest wall point,
// y* = x + 2 (R - r) n for a sphere or a cylinder side of radius R (r the
// distance from the centre or axis, n the outward normal). That is exact in
// the normal direction and distorts tangential lengths by a factor
// (2R - r)/r = 1 + O(depth / R): the image density of a uniform layer is off
// by O(s / R) within a blob width s of the wall (tested in test_images.cpp).
#include <array>
#include <cstdint>
#include <memory>
#include <vector>

#include <Eigen/Core>

#include "otfp/types.hpp"

namespace otfp {

using Mat3 = Eigen::Matrix3d;

// One smooth wall surface and its reflection.
class MirrorWall {
 public:
  virtual ~MirrorWall() = default;
  // Signed distance to the wall surface, < 0 on the domain side.
  virtual double distance(const Vec3& x) const = 0;
  // Mirror image of x and, if jacobian is not null, d(image)/dx.
  virtual Vec3 reflect(const Vec3& x, Mat3* jacobian) const = 0;
};
using MirrorWallPtr = std::shared_ptr<const MirrorWall>;

// Plane through `point` with the domain on the side opposite to `outward_normal`.
MirrorWallPtr make_plane_wall(const Vec3& point, const Vec3& outward_normal);
// Which side of a round wall the domain lies on: inside a ball or pipe, or
// outside an obstacle.
enum class WallSide { DomainInside, DomainOutside };

// Sphere (d = 3), circle (d = 2) or the two end points of an interval (d = 1)
// of the given radius.
MirrorWallPtr make_sphere_wall(int dim, const Vec3& center, double radius, WallSide side = WallSide::DomainInside);
// Side of an infinite circular cylinder through `axis_point` along `axis`.
MirrorWallPtr make_cylinder_wall(const Vec3& axis_point, const Vec3& axis, double radius,
                                 WallSide side = WallSide::DomainInside);

class Domain;

// The walls to mirror in a domain: the walls of all its patches except those
// that carry one of `open_patches` (Dirichlet patches, which exchange mass
// with a reservoir instead); one wall per surface, in patch order. Throws
// InvalidArgument naming the patch when the domain has no wall for one (CSG).
std::vector<MirrorWallPtr> mirror_walls(const Domain& domain, const std::vector<int>& open_patches = {});

// Moves every point that lies beyond one of the walls back across it
// (specular reflection, the no-flux condition of a reflected random walk):
// with images, a blob outside a wall is pushed further out by its own image
// inside, so a particle that crossed must be put back, not left to the
// barrier. Returns how many points moved; their mass stays where it was counted.
std::size_t reflect_inside(const std::vector<MirrorWallPtr>& walls, std::vector<Vec3>& x);

// The image blobs of a set of walls.
class WallImages {
 public:
  WallImages() = default;  // no walls: inactive
  // max_order: largest number of walls composed in one image (3 covers the corners of a box).
  explicit WallImages(std::vector<MirrorWallPtr> walls, int max_order = 3);

  bool active() const { return !walls_.empty(); }
  const std::vector<MirrorWallPtr>& walls() const { return walls_; }

  // Chooses the images: particle p is mirrored across every wall w with
  // distance_w(x_p) >= -reach[p], and across every subset S of those walls
  // (up to max_order, composed) with sum over S of depth_w^2 <= reach[p]^2.
  // reach[p] should be the particle's list radius r_c(s_p) + skin: farther in,
  // its image is beyond the cut-off of every point on the domain side.
  void select(const std::vector<Vec3>& x, const std::vector<double>& reach);
  // Number of images chosen by the last select().
  std::size_t size() const { return source_.size(); }
  // Source particle of each image.
  const std::vector<std::uint32_t>& sources() const { return source_; }
  // Positions of the images for the current source positions (same particles as at select()).
  void positions(const std::vector<Vec3>& x, std::vector<Vec3>& y) const;
  // Adds J_i^T g_image[i] to g_source[source(i)] for every image i (chain rule through the reflections).
  void pull_back(const std::vector<Vec3>& x, const std::vector<Vec3>& g_image, std::vector<Vec3>& g_source) const;

 private:
  Vec3 image(std::size_t i, const Vec3& x, Mat3* jacobian) const;
  std::vector<MirrorWallPtr> walls_;
  int max_order_ = 3;
  std::vector<std::uint32_t> source_;
  std::vector<std::uint8_t> order_;                 // walls composed per image (1 ... max_order)
  std::vector<std::array<std::uint8_t, 3>> chain_;  // wall indices, applied first to last
};

}  // namespace otfp
