#pragma once
// Domains as signed distance functions with boundary patches (Sec. 4.2).
//
// Sign convention: signed_distance < 0 inside Omega, > 0 outside, 0 on the
// boundary. Every point has a closest boundary point and the id of the patch
// A_l that point lies on. The boundary-layer cells of Sec. 4.2, (32)-(33), are
//   B_l      = { x : |sd(x)| <= b and patch(x) = l }      (LayerPart::Whole)
//   B_l^int  = { x : -b <= sd(x) <= 0 and patch(x) = l }   (LayerPart::Interior)
//   B_l^ext  = { x : 0 < sd(x) <= b and patch(x) = l }     (LayerPart::Exterior)
// Sampling, membership and the barrier all go through query(), so a new domain
// is one class that implements query(), volume(), patch areas and bounds.
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "otfp/types.hpp"

namespace otfp {

class MirrorWall;

struct BoundaryQuery {
  double signed_distance = 0.0;   // < 0 inside
  Vec3 closest_point = Vec3::Zero();
  int patch = -1;                 // -1: no boundary (periodic box)
};

enum class LayerPart { Interior, Exterior, Whole };

// Whether a signed distance sd lies in that part of a layer of depth b (the
// sets above, without the patch).
bool in_layer_part(double sd, double b, LayerPart part);

// Parameters of the primitive domains (make_box, make_ball, make_cylinder), for
// closed-form integrals over Omega (otfp/mass_measure.hpp). Sub-patch domains
// report their base's shape; periodic boxes, CSG and other domains none.
struct DomainShape {
  enum class Kind { Box, Ball, Cylinder };
  Kind kind = Kind::Box;
  int dim = 3;
  Vec3 lo = Vec3::Zero(), hi = Vec3::Zero();        // Box
  Vec3 center = Vec3::Zero();                       // Ball
  double radius = 0.0;                              // Ball, Cylinder
  Vec3 end_a = Vec3::Zero(), end_b = Vec3::Zero();  // Cylinder: axis from end_a to end_b
};

class Domain {
 public:
  virtual ~Domain() = default;

  virtual int dim() const = 0;
  virtual BoundaryQuery query(const Vec3& x) const = 0;
  virtual double volume() const = 0;
  virtual int num_patches() const = 0;
  virtual double patch_area(int patch) const = 0;  // (d-1)-measure of A_l
  virtual std::string patch_name(int patch) const;
  virtual Aabb bounding_box() const = 0;

  // Periodic domains have no boundary: query() returns sd = -inf, patch -1.
  virtual bool is_periodic() const { return false; }
  // Period along each axis (only meaningful when is_periodic()).
  virtual Vec3 period() const { return Vec3::Zero(); }
  // Maps a point back into the fundamental cell (identity if not periodic).
  virtual Vec3 wrap(const Vec3& x) const { return x; }
  // The primitive shape and its parameters, if the domain is one (see DomainShape).
  virtual std::optional<DomainShape> shape() const { return std::nullopt; }
  // The default centre of the polar inertia (43): the centre of symmetry of
  // the primitive (a ball's centre, a box's, a cylinder's mid-axis; a pipe's
  // box centre whatever its obstacle). Default: the bounding box's centre.
  virtual Vec3 inertia_center() const;
  // Mean of |x - c|^2 over Omega at uniform density (c's unused axes do not
  // count): M_inf times it is the
  // steady polar inertia J_inf about c. Closed forms for the primitives
  // (free space and periodic boxes: their box); default: fixed-seed Monte
  // Carlo over sample_interior() (2e5 points, the same value every call).
  virtual double mean_square_distance(const Vec3& c) const;

  double signed_distance(const Vec3& x) const { return query(x).signed_distance; }
  Vec3 closest_point(const Vec3& x) const { return query(x).closest_point; }
  int patch_id(const Vec3& x) const { return query(x).patch; }
  bool contains(const Vec3& x) const { return query(x).signed_distance <= 0.0; }
  int patch_by_name(const std::string& name) const;  // -1 if none

  // Membership of x in the layer cell of patch l with half-thickness b.
  bool in_layer_cell(const Vec3& x, int patch, double b, LayerPart part) const;

  // The smooth wall surface that patch l lies on, for image blobs
  // (images.hpp); patches on one surface share one wall object. Null where
  // the domain cannot say (CSG): such walls keep only the barrier.
  virtual std::shared_ptr<const MirrorWall> patch_wall(int patch) const;
  // Omega extended outward by w over the given patches (the reservoir band
  // of a Dirichlet patch), with the same patch ids. Throws InvalidArgument
  // naming the patch where the domain cannot extend it.
  virtual std::shared_ptr<const Domain> extended(const std::vector<int>& patches, double w) const;

  // Uniform sample of Omega (rejection from bounding_box()).
  virtual Vec3 sample_interior(Rng& rng) const;
  // Uniform sample of a layer cell (rejection from layer_bounding_box()).
  Vec3 sample_layer_cell(int patch, double b, LayerPart part, Rng& rng) const;
  // Box that contains the layer cell of patch l with half-thickness b.
  virtual Aabb layer_bounding_box(int patch, double b) const;
  // Volume of a layer cell: analytic where the domain knows it, otherwise
  // Monte Carlo quadrature with a fixed seed and `samples` points.
  virtual double layer_cell_volume(int patch, double b, LayerPart part, int samples = 400000) const;

 protected:
  // Monte Carlo estimate of the measure of {x in box : pred(x)}, fixed seed.
  template <class Pred>
  static double monte_carlo_volume(const Aabb& box, int dim, int samples, Pred pred);
};

using DomainPtr = std::shared_ptr<const Domain>;

// Ball (d = 3), disc (d = 2) or interval (d = 1). One patch, "surface".
DomainPtr make_ball(int dim, const Vec3& center, double radius);
// Axis-aligned box [lo, hi]. Patches 2k and 2k+1 are the faces x_k = lo_k
// ("x-", "y-", "z-") and x_k = hi_k ("x+", "y+", "z+"), k < dim.
DomainPtr make_box(int dim, const Vec3& lo, const Vec3& hi);
// Finite capped cylinder (d = 3) with axis from a to b, any direction.
// Patches: 0 "lateral", 1 "cap_a" (the disc at a), 2 "cap_b" (the disc at b).
DomainPtr make_cylinder(const Vec3& a, const Vec3& b, double radius);
// Periodic box [lo, hi) in d dimensions; no boundary and no patches.
DomainPtr make_periodic_box(int dim, const Vec3& lo, const Vec3& hi);
// Box [lo, hi] minus a cylinder of radius r across it, its axis along
// `axis` (0, 1, 2; ignored in 2-D, where the obstacle is a disc) through
// obstacle_center: a pipe with an obstacle. Patches: the box faces 0 .. 2d-1
// ("x-", "x+", ...), then "obstacle". The signed distance is exact on both
// sides (make_difference's is a lower bound outside).
DomainPtr make_square_pipe_obstacle(int dim, const Vec3& lo, const Vec3& hi, int axis, const Vec3& obstacle_center,
                                    double radius);
// Unbounded space (free diffusion): no boundary and no patches; the box
// [lo, hi] serves an initial uniform fill and the spacing rule (its volume).
DomainPtr make_free_space(int dim, const Vec3& lo, const Vec3& hi);

// A sub-region of one patch of a base domain: the boundary points of patch
// `base_patch` within Euclidean distance `radius` of `center` (a point on that
// patch) form a new patch named `name`. On a flat face that is a disc, on a
// sphere a cap (the orifice of [2023] Sec. 5, the outlet of Sec. 5.3). The
// new patch gets id base->num_patches() + (number of earlier sub-patches).
struct SubPatch {
  int base_patch = 0;
  Vec3 center = Vec3::Zero();
  double radius = 0.0;
  std::string name;
};
DomainPtr make_with_subpatches(DomainPtr base, std::vector<SubPatch> subpatches);

// CSG. Patches of `a` keep their ids; patches of `b` are offset by
// a->num_patches() and their names prefixed with "b:" unless renamed later.
DomainPtr make_union(DomainPtr a, DomainPtr b);
DomainPtr make_difference(DomainPtr a, DomainPtr b);  // a \ b, e.g. an obstacle

}  // namespace otfp
