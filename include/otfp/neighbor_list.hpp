#pragma once
// Verlet neighbour list with a skin, built over an O(n) cell list (the cell
// grid is internal: src/cell_grid.hpp).
//
// The cut-off comes from a kernel tolerance, not from 1/sqrt(beta)
// (docs/method_notes.md#neighbour-cutoff): exp(-beta r_c^2) = tol, i.e. r_c = s sqrt(ln(1/tol))
// with s = beta^-1/2. The pair (p, q) enters through w_q(x_p), which uses
// beta_q, and through w_p(x_q), which uses beta_p; so the pair's radius is
// the cut-off of the wider of the two plus the skin,
//   |x_p - x_q| <= max(R_p, R_q),  R_p = r_c(s_p) + skin,
// and the list is symmetric (full: both (p, q) and (q, p) are stored, so
// sweeps gather and never scatter). A per-pair radius rather than that of the
// widest blob matters for optimised widths, where a few blobs several times
// wider than the rest would otherwise lengthen every particle's list.
#include <algorithm>
#include <cstddef>
#include <cmath>
#include <cstdint>
#include <memory>
#include <utility>
#include <vector>

#include "otfp/types.hpp"

namespace otfp {

class Domain;

// Periodic images: axes k < dim with period[k] > 0 wrap (minimum image).
struct Periodicity {
  int dim = 3;
  Vec3 lo = Vec3::Zero();
  Vec3 period = Vec3::Zero();  // 0: not periodic along that axis
  bool any() const { return (period.array() > 0.0).any(); }
  static Periodicity none(int dim);
  static Periodicity from_domain(const Domain& domain);
  // Maps a point into [lo, lo + period) along the periodic axes.
  Vec3 wrap(const Vec3& a) const {
    Vec3 y = a;
    for (int k = 0; k < 3; ++k)
      if (period[k] > 0.0) y[k] = lo[k] + (y[k] - lo[k]) - period[k] * std::floor((y[k] - lo[k]) / period[k]);
    return y;
  }
  // Minimum-image displacement a - b.
  Vec3 displacement(const Vec3& a, const Vec3& b) const {
    Vec3 d = a - b;
    for (int k = 0; k < 3; ++k)
      if (period[k] > 0.0) d[k] -= period[k] * std::nearbyint(d[k] / period[k]);
    return d;
  }
};

// Cut-off radius r_c = s sqrt(ln(1/tol)) for a blob of width s = beta^-1/2.
double cutoff_radius(double width_s, double kernel_tolerance);

struct NeighborOptions {
  double kernel_tolerance = 1e-8;  // kernel value (relative to its peak) at the cut-off
  double skin = -1.0;              // absolute skin length; < 0: skin_factor * smallest width s
  double skin_factor = 0.5;        // skin in units of the smallest width s when skin < 0
  void validate() const;           // throws InvalidArgument naming the field
};

class NeighborList {
 public:
  explicit NeighborList(NeighborOptions options = {});

  // Builds the full list of pairs with |x_p - x_q| <= max(R_p, R_q),
  // R_p = particle_radius(s_p).
  void build(const std::vector<Vec3>& x, const std::vector<double>& width_s, const Periodicity& periodicity);
  // True when a pair inside its cut-off might be missing: twice the largest
  // displacement since the build plus the largest growth of a particle's
  // cut-off exceeds the skin.
  bool needs_rebuild(const std::vector<Vec3>& x, const std::vector<double>& width_s) const;
  // R = r_c(s) + skin of a particle of width s (skin of the last build).
  double particle_radius(double width_s) const { return cutoff_radius(width_s, options_.kernel_tolerance) + skin_; }
  // Largest displacement since the last build (minimum image).
  double max_displacement(const std::vector<Vec3>& x) const;
  // Keeps, in the rows p >= rows, only the entries q < rows: the pairs of
  // two blobs that carry no term of their own (a DistributedFunctional's
  // ghosts, whose rows only gather the derivatives of the own blobs' terms)
  // are dropped. Rows below `rows` are unchanged. Until the next build the
  // list is then no longer symmetric.
  void drop_pairs_beyond(std::size_t rows);

  bool built() const { return built_; }
  std::size_t size() const { return offsets_.empty() ? 0 : offsets_.size() - 1; }
  double list_radius() const { return list_radius_; }  // largest particle radius R_p at build time
  double cutoff() const { return cutoff_; }  // cut-off of the widest blob at build time
  double skin() const { return skin_; }
  std::size_t num_entries() const { return indices_.size(); }  // = 2 * number of pairs (after a build)
  int build_count() const { return build_count_; }
  double build_seconds() const { return build_seconds_; }  // wall time of all builds so far
  const Periodicity& periodicity() const { return per_; }
  const NeighborOptions& options() const { return options_; }

  // Row p: neighbours indices_[offsets_[p] .. offsets_[p+1]).
  const std::vector<std::uint32_t>& offsets() const { return offsets_; }
  const std::vector<std::uint32_t>& indices() const { return indices_; }
  std::size_t memory_bytes() const;

 private:
  NeighborOptions options_;
  Periodicity per_;
  std::vector<std::uint32_t> offsets_;
  std::vector<std::uint32_t> indices_;
  std::vector<Vec3> x_build_;
  std::vector<double> s_build_;
  double list_radius_ = 0.0, cutoff_ = 0.0, skin_ = 0.0;
  int build_count_ = 0;
  double build_seconds_ = 0.0;
  bool built_ = false;
  // The cell grid of the builds (internal, src/cell_grid.hpp), kept to reuse
  // its storage; made by the first build(). Copying a list copies the list,
  // not the grid: the copy makes its own at its next build().
  struct Workspace;
  struct WorkspaceHandle {
    std::unique_ptr<Workspace> ptr;
    WorkspaceHandle();
    ~WorkspaceHandle();
    WorkspaceHandle(const WorkspaceHandle&);
    WorkspaceHandle& operator=(const WorkspaceHandle&);
    WorkspaceHandle(WorkspaceHandle&&) noexcept;
    WorkspaceHandle& operator=(WorkspaceHandle&&) noexcept;
  };
  WorkspaceHandle work_;
};

}  // namespace otfp
