#pragma once
// Which rank of the MPI world owns which particle (component otfp::mpi,
// docs/distributed.md): slabs of equal counts along one axis, recursive
// coordinate bisection, and the migration of particles to the rank that owns
// their position after they have moved.
#include <cstddef>
#include <vector>

#include "otfp/particles.hpp"
#include "otfp/types.hpp"

namespace otfp {

// Owner rank of each particle: `ranks` slabs along `axis` with equal counts
// (ties broken by index), the simplest decomposition by position.
std::vector<int> partition_slabs(const std::vector<Vec3>& x, int axis, int ranks);

// A rule, known to every rank, that gives each position its owner rank.
class Layout {
 public:
  virtual ~Layout() = default;
  virtual int owner(const Vec3& x) const = 0;
  virtual int ranks() const = 0;  // the number of ranks it assigns to
};

// Slabs along one axis: rank r owns the positions with cuts[r - 1] <= x[axis]
// < cuts[r] (the first and last slab are open).
class SlabLayout final : public Layout {
 public:
  int axis = 0;
  std::vector<double> cuts;  // ranks() - 1 increasing values
  int owner(const Vec3& x) const override;
  int ranks() const override { return static_cast<int>(cuts.size()) + 1; }
};

// Recursive coordinate bisection: the ranks [r0, r1) of a node split into
// [r0, r0 + k) and [r0 + k, r1), k = (r1 - r0) / 2, by a cut across the
// longest side of the node's particles' bounding box, placed so that each
// side holds its ranks' share of the node's particles. Leaves are ranks;
// their regions are boxes close to cubes, whose ghost shells are the
// thinnest a layout by position gives (docs/distributed.md).
class BisectionLayout final : public Layout {
 public:
  struct Node {
    int axis = 0;
    double cut = 0.0;
    int below = -1, above = -1;  // children (node indices), or -1
    int rank = -1;               // a leaf's rank (>= 0), -1 for an inner node
  };
  std::vector<Node> nodes;  // nodes[0] is the root
  int owner(const Vec3& x) const override;
  int ranks() const override;
};

// Collective: the cuts that split all ranks' positions into slabs of equal
// counts (to one particle, unless positions tie), found by bisection on the
// global counts below each cut.
SlabLayout balanced_slabs(const std::vector<Vec3>& owned_x, int axis);

// Collective: the recursive bisection of all ranks' positions over the ranks
// of the world, each leaf with an equal share (to one particle per cut,
// unless positions tie). Only the first `dim` axes are cut.
BisectionLayout balanced_bisection(const std::vector<Vec3>& owned_x, int dim);

// Collective: sends each particle (position, width, mass, birth time, id) to
// the rank the layout gives it, and takes in the ones sent here (appended
// after the ones kept, in the order of their ranks). Returns how many this
// rank sent away. Ids must be unique over the ranks (add_with_id): a
// repeated id throws InvalidArgument on the rank that receives it.
std::size_t migrate(ParticleSet& owned, const Layout& layout);

}  // namespace otfp
