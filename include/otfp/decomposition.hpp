#pragma once
// Which rank of the MPI world owns which particle (component otfp::mpi,
// docs/distributed.md): slabs of equal counts along one axis, and the
// migration of particles to the rank that owns their position after they
// have moved.
#include <cstddef>
#include <vector>

#include "otfp/particles.hpp"
#include "otfp/types.hpp"

namespace otfp {

// Owner rank of each particle: `ranks` slabs along `axis` with equal counts
// (ties broken by index), the simplest decomposition by position.
std::vector<int> partition_slabs(const std::vector<Vec3>& x, int axis, int ranks);

// Slabs along one axis: rank r owns the positions with cuts[r - 1] <= x[axis]
// < cuts[r] (the first and last slab are open).
struct SlabLayout {
  int axis = 0;
  std::vector<double> cuts;  // world_size() - 1 increasing values
  int owner(const Vec3& x) const;
};

// Collective: the cuts that split all ranks' positions into slabs of equal
// counts (to one particle, unless positions tie), found by bisection on the
// global counts below each cut.
SlabLayout balanced_slabs(const std::vector<Vec3>& owned_x, int axis);

// Collective: sends each particle (position, width, mass, birth time, id) to
// the rank whose slab holds it, and takes in the ones sent here (appended
// after the ones kept, in the order of their ranks). Returns how many this
// rank sent away. Ids must be unique over the ranks (add_with_id): a
// repeated id throws InvalidArgument on the rank that receives it.
std::size_t migrate(ParticleSet& owned, const SlabLayout& layout);

}  // namespace otfp
