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
#include <cstddef>
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
  // d[i] = distance(x[i]) for i < n, bit for bit: one call for a block of
  // points (WallImages::select). The default calls distance(); the walls
  // made below override it with a loop the compiler can inline.
  virtual void distances(const Vec3* x, std::size_t n, double* d) const;
  // Mirror image of x and, if jacobian is not null, d(image)/dx.
  virtual Vec3 reflect(const Vec3& x, Mat3* jacobian) const = 0;
  // True when a reflection never brings a point of the domain's side nearer
  // another one: |p - reflect(q)| >= |p - q| for p, q on the domain's side
  // (planes; spheres and cylinders the domain lies inside). Not for an
  // obstacle: the image of a blob on one side lies inside it, nearer the
  // blobs on its far side. A distributed evaluation widens its ghosts where
  // this is false.
  virtual bool keeps_images_farther() const { return false; }
  // WallImages::select calls distance() and distances() from several
  // threads at once: they must not change the wall (nor throw, ideally; an
  // exception is passed on after the threads have finished).
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
  // Images are listed by source particle, then by subset (the nonempty
  // subsets of the first 16 nearby walls, in increasing wall order as binary
  // counting gives them). Parallel (OpenMP): each thread takes a run of
  // blocks of 256 particles, computes a block's distances to each wall in
  // one call (vectorised), skips the particles within no wall's reach and
  // lists the images of the others; the lists are joined in particle order,
  // so the result does not depend on the number of threads.
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
  // select()'s images of one thread, in particle order, and its scratch for
  // a block's distances to every wall (kept: no allocation per call).
  struct SelectBuffer {
    std::vector<std::uint32_t> source;
    std::vector<std::uint8_t> order;
    std::vector<std::array<std::uint8_t, 3>> chain;
    std::vector<double> distance;
  };
  // select() for the particles of block b: appends their images to out.
  void select_block(const std::vector<Vec3>& x, const std::vector<double>& reach, std::size_t b,
                    SelectBuffer& out) const;
  std::vector<MirrorWallPtr> walls_;
  int max_order_ = 3;
  std::vector<std::uint32_t> source_;
  std::vector<std::uint8_t> order_;                 // walls composed per image (1 ... max_order)
  std::vector<std::array<std::uint8_t, 3>> chain_;  // wall indices, applied first to last
  std::vector<SelectBuffer> buffers_;               // select(): one per thread
};

}  // namespace otfp
