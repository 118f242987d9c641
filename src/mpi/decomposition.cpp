// Slabs, their balancing and the migration of particles between ranks
// (otfp/decomposition.hpp). Collectives go through MPI on PETSC_COMM_WORLD.
#include "otfp/decomposition.hpp"

#include <mpi.h>
#include <petscsys.h>

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <mutex>
#include <numeric>
#include <string>

#include "particle_exchange.hpp"
#include "petsc_session.hpp"

namespace otfp {

std::vector<int> partition_slabs(const std::vector<Vec3>& x, int axis, int ranks) {
  require(axis >= 0 && axis < 3, "axis", axis, "must be 0, 1 or 2");
  require(ranks >= 1, "ranks", ranks, "must be >= 1");
  std::vector<std::size_t> order(x.size());
  std::iota(order.begin(), order.end(), std::size_t{0});
  std::stable_sort(order.begin(), order.end(),
                   [&](std::size_t a, std::size_t b) { return x[a][axis] < x[b][axis]; });
  std::vector<int> owner(x.size(), 0);
  const std::size_t n = x.size();
  for (std::size_t k = 0; k < n; ++k)
    owner[order[k]] = static_cast<int>((k * static_cast<std::size_t>(ranks)) / std::max<std::size_t>(n, 1));
  return owner;
}

int SlabLayout::owner(const Vec3& x) const {
  // The number of cuts at or below x[axis] is the slab's index.
  return static_cast<int>(std::upper_bound(cuts.begin(), cuts.end(), x[axis]) - cuts.begin());
}

SlabLayout balanced_slabs(const std::vector<Vec3>& owned_x, int axis) {
  require(axis >= 0 && axis < 3, "axis", axis, "must be 0, 1 or 2");
  const std::lock_guard<std::recursive_mutex> lock(detail::petsc_mutex());
  const MPI_Comm comm = detail::world_comm();
  int size = 1;
  MPI_Comm_size(comm, &size);
  SlabLayout layout;
  layout.axis = axis;
  if (size == 1) return layout;
  // The global range and count.
  double range[2] = {std::numeric_limits<double>::infinity(), std::numeric_limits<double>::infinity()};
  for (const Vec3& y : owned_x) {
    range[0] = std::min(range[0], y[axis]);
    range[1] = std::min(range[1], -y[axis]);
  }
  MPI_Allreduce(MPI_IN_PLACE, range, 2, MPI_DOUBLE, MPI_MIN, comm);
  long long total = static_cast<long long>(owned_x.size());
  MPI_Allreduce(MPI_IN_PLACE, &total, 1, MPI_LONG_LONG, MPI_SUM, comm);
  const auto cuts = static_cast<std::size_t>(size - 1);
  if (total == 0) {
    layout.cuts.assign(cuts, 0.0);
    return layout;
  }
  // Bisection of every cut at once: cut r (1-based) is the smallest value
  // with at least r total / size positions below it. 64 halvings take the
  // bracket to the spacing of doubles around the cut.
  std::vector<double> lo(cuts, range[0]), hi(cuts, -range[1]), mid(cuts);
  std::vector<long long> below(cuts);
  for (int it = 0; it < 64; ++it) {
    for (std::size_t r = 0; r < cuts; ++r) mid[r] = 0.5 * (lo[r] + hi[r]);
    std::fill(below.begin(), below.end(), 0LL);
    for (const Vec3& y : owned_x)
      for (std::size_t r = 0; r < cuts; ++r)
        if (y[axis] < mid[r]) ++below[r];
    MPI_Allreduce(MPI_IN_PLACE, below.data(), static_cast<int>(cuts), MPI_LONG_LONG, MPI_SUM, comm);
    for (std::size_t r = 0; r < cuts; ++r) {
      const long long target = (static_cast<long long>(r + 1) * total) / size;
      (below[r] >= target ? hi[r] : lo[r]) = mid[r];
    }
  }
  layout.cuts = hi;
  return layout;
}

int BisectionLayout::owner(const Vec3& x) const {
  if (nodes.empty()) return 0;
  std::size_t i = 0;
  while (nodes[i].rank < 0) i = static_cast<std::size_t>(x[nodes[i].axis] < nodes[i].cut ? nodes[i].below : nodes[i].above);
  return nodes[i].rank;
}

int BisectionLayout::ranks() const {
  if (nodes.empty()) return 1;
  return static_cast<int>(std::count_if(nodes.begin(), nodes.end(), [](const Node& n) { return n.rank >= 0; }));
}

BisectionLayout balanced_bisection(const std::vector<Vec3>& owned_x, int dim) {
  require(dim >= 1 && dim <= 3, "dim", dim, "must be 1, 2 or 3");
  const std::lock_guard<std::recursive_mutex> lock(detail::petsc_mutex());
  const MPI_Comm comm = detail::world_comm();
  int size = 1;
  MPI_Comm_size(comm, &size);
  BisectionLayout layout;
  layout.nodes.emplace_back();
  struct Pending {
    int node, r0, r1;
  };
  std::vector<Pending> level = {{0, 0, size}};
  std::vector<int> where(owned_x.size(), 0);  // each particle's node at the current level
  constexpr double kInf = std::numeric_limits<double>::infinity();
  while (!level.empty()) {
    std::vector<Pending> split;
    for (const Pending& p : level) {
      if (p.r1 - p.r0 == 1)
        layout.nodes[static_cast<std::size_t>(p.node)].rank = p.r0;
      else
        split.push_back(p);
    }
    if (split.empty()) break;
    // Every node of this level at once: its particles' box and count, then
    // the cut across its longest side, by bisection on the counts below.
    const std::size_t m = split.size();
    std::vector<int> slot(layout.nodes.size(), -1);
    for (std::size_t k = 0; k < m; ++k) slot[static_cast<std::size_t>(split[k].node)] = static_cast<int>(k);
    std::vector<double> ext(6 * m, kInf);  // per node: min[3], -max[3]
    std::vector<long long> count(m, 0);
    for (std::size_t p = 0; p < owned_x.size(); ++p) {
      const int k = slot[static_cast<std::size_t>(where[p])];
      if (k < 0) continue;
      for (int a = 0; a < dim; ++a) {
        ext[6 * static_cast<std::size_t>(k) + static_cast<std::size_t>(a)] =
            std::min(ext[6 * static_cast<std::size_t>(k) + static_cast<std::size_t>(a)], owned_x[p][a]);
        ext[6 * static_cast<std::size_t>(k) + 3 + static_cast<std::size_t>(a)] =
            std::min(ext[6 * static_cast<std::size_t>(k) + 3 + static_cast<std::size_t>(a)], -owned_x[p][a]);
      }
      ++count[static_cast<std::size_t>(k)];
    }
    MPI_Allreduce(MPI_IN_PLACE, ext.data(), static_cast<int>(ext.size()), MPI_DOUBLE, MPI_MIN, comm);
    MPI_Allreduce(MPI_IN_PLACE, count.data(), static_cast<int>(m), MPI_LONG_LONG, MPI_SUM, comm);
    std::vector<int> axis(m, 0);
    std::vector<double> lo(m, 0.0), hi(m, 0.0), mid(m);
    std::vector<long long> target(m), below(m);
    for (std::size_t k = 0; k < m; ++k) {
      double widest = -1.0;
      for (int a = 0; a < dim; ++a) {
        const double extent = -ext[6 * k + 3 + static_cast<std::size_t>(a)] - ext[6 * k + static_cast<std::size_t>(a)];
        if (extent > widest) {
          widest = extent;
          axis[k] = a;
        }
      }
      if (count[k] > 0) {
        lo[k] = ext[6 * k + static_cast<std::size_t>(axis[k])];
        hi[k] = -ext[6 * k + 3 + static_cast<std::size_t>(axis[k])];
      }
      const int ranks = split[k].r1 - split[k].r0;
      target[k] = count[k] * (ranks / 2) / ranks;
    }
    for (int it = 0; it < 64; ++it) {
      for (std::size_t k = 0; k < m; ++k) mid[k] = 0.5 * (lo[k] + hi[k]);
      std::fill(below.begin(), below.end(), 0LL);
      for (std::size_t p = 0; p < owned_x.size(); ++p) {
        const int k = slot[static_cast<std::size_t>(where[p])];
        if (k >= 0 && owned_x[p][axis[static_cast<std::size_t>(k)]] < mid[static_cast<std::size_t>(k)])
          ++below[static_cast<std::size_t>(k)];
      }
      MPI_Allreduce(MPI_IN_PLACE, below.data(), static_cast<int>(m), MPI_LONG_LONG, MPI_SUM, comm);
      for (std::size_t k = 0; k < m; ++k) (below[k] >= target[k] ? hi[k] : lo[k]) = mid[k];
    }
    std::vector<Pending> next;
    for (std::size_t k = 0; k < m; ++k) {
      const Pending& p = split[k];
      const int half = (p.r1 - p.r0) / 2;
      const int below_node = static_cast<int>(layout.nodes.size());
      layout.nodes.emplace_back();
      layout.nodes.emplace_back();
      BisectionLayout::Node& n = layout.nodes[static_cast<std::size_t>(p.node)];
      n.axis = axis[k];
      n.cut = hi[k];
      n.below = below_node;
      n.above = below_node + 1;
      next.push_back({below_node, p.r0, p.r0 + half});
      next.push_back({below_node + 1, p.r0 + half, p.r1});
    }
    for (std::size_t p = 0; p < owned_x.size(); ++p) {
      const BisectionLayout::Node& n = layout.nodes[static_cast<std::size_t>(where[p])];
      if (n.rank < 0 && n.below >= 0) where[p] = owned_x[p][n.axis] < n.cut ? n.below : n.above;
    }
    level = std::move(next);
  }
  return layout;
}

std::size_t migrate(ParticleSet& owned, const Layout& layout) {
  const std::lock_guard<std::recursive_mutex> lock(detail::petsc_mutex());
  const MPI_Comm comm = detail::world_comm();
  int size = 1, rank = 0;
  MPI_Comm_size(comm, &size);
  MPI_Comm_rank(comm, &rank);
  require(layout.ranks() == size, "layout.ranks()", layout.ranks(), "must equal world_size()");
  std::vector<std::vector<std::size_t>> to(static_cast<std::size_t>(size));
  std::vector<std::size_t> leaving;
  for (std::size_t p = 0; p < owned.size(); ++p) {
    const int r = layout.owner(owned.positions()[p]);
    if (r == rank) continue;
    to[static_cast<std::size_t>(r)].push_back(p);
    leaving.push_back(p);
  }
  const detail::ParticleRecords arrived = detail::exchange_particles(owned, to, comm);
  const std::vector<std::int64_t>& in_ids = arrived.ids;

  // A repeated id (ids not unique over the ranks) is refused on every rank
  // before anything changes, so that no rank goes on alone.
  std::vector<std::int64_t> arriving(in_ids);
  std::sort(arriving.begin(), arriving.end());
  const auto twice = std::adjacent_find(arriving.begin(), arriving.end());
  int repeated = twice != arriving.end() ? 1 : 0;
  std::vector<bool> leaves(owned.size(), false);
  for (std::size_t p : leaving) leaves[p] = true;
  std::int64_t example = repeated ? *twice : -1;
  for (std::int64_t id : in_ids) {
    const std::ptrdiff_t here = owned.index_of(id);
    if (here >= 0 && !leaves[static_cast<std::size_t>(here)]) {
      repeated = 1;
      example = id;
    }
  }
  int any_repeated = repeated;
  MPI_Allreduce(MPI_IN_PLACE, &any_repeated, 1, MPI_INT, MPI_MAX, comm);
  require(any_repeated == 0, "particle id", repeated ? static_cast<double>(example) : -1.0,
          "is held by two ranks: ids must be unique over the ranks (add_with_id); nothing was moved");

  const std::size_t left = leaving.size();
  owned.remove_indices(std::move(leaving));
  for (std::size_t i = 0; i < arrived.size(); ++i) arrived.add_to(owned, i);
  return left;
}

}  // namespace otfp
