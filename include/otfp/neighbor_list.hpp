#pragma once
// Cell list (O(n) build) and Verlet neighbour list with a skin.
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

// Uniform grid of cells over the points' bounding box (or the periodic box)
// with a counting-sort build. Cells are at least cell_size wide and a query
// visits `reach` cells on each side, so any point within reach x cell_size of
// the query point is a candidate.
class CellGrid {
 public:
  void build(const std::vector<Vec3>& x, double cell_size, const Periodicity& periodicity, int reach = 1);
  // Calls f(begin, end, shift) for every cell around y, each once: the points
  // items()[begin..end) of that cell, seen at sorted_x/y/z + shift (the
  // periodic image nearest the query when images do not alias).
  template <class F>
  void for_each_cell(const Vec3& y, F&& f) const { for_each_cell(y, reach_, 0.0, std::forward<F>(f)); }
  // The same with `reach` cells on each side instead of the build's, and,
  // when radius > 0, only the cells that come within radius of y (then y
  // must be canonical(): the cell geometry is that of the stored points).
  template <class F>
  void for_each_cell(const Vec3& y, int reach, double radius, F&& f) const;
  // Calls f(j) for every point j in the cells around y, each once.
  template <class F>
  void for_each_candidate(const Vec3& y, F&& f) const {
    for_each_cell(y, [&](std::uint32_t b, std::uint32_t e, const Vec3&) {
      for (std::uint32_t k = b; k < e; ++k) f(items_[k]);
    });
  }
  // True when the shift passed to for_each_cell is exact (no aliasing of images).
  bool shifts_exact() const { return shifts_exact_; }
  bool shifts_exact(int reach) const;  // the same for a query with `reach` cells on each side
  // A point wrapped into the periodic box as the grid stores it; queries
  // whose shifts are used must be given in this form.
  Vec3 canonical(const Vec3& a) const;
  double min_cell_width() const;       // smallest cell width over the used axes
  std::size_t num_cells() const { return cell_start_.empty() ? 0 : cell_start_.size() - 1; }
  const std::vector<std::uint32_t>& items() const { return items_; }
  // Coordinates of items() in cell order (canonical(): wrapped along periodic axes).
  const std::vector<double>& sorted_x() const { return sx_; }
  const std::vector<double>& sorted_y() const { return sy_; }
  const std::vector<double>& sorted_z() const { return sz_; }

 private:
  int cell_coord(double v, int axis) const;
  Periodicity per_;
  Vec3 origin_ = Vec3::Zero();
  Vec3 cell_width_ = Vec3::Ones();
  int n_[3] = {1, 1, 1};
  int reach_ = 1;
  bool shifts_exact_ = true;
  std::vector<std::uint32_t> cell_start_;  // size num_cells + 1
  std::vector<std::uint32_t> items_;       // point indices sorted by cell
  std::vector<double> sx_, sy_, sz_;
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

  bool built() const { return built_; }
  std::size_t size() const { return offsets_.empty() ? 0 : offsets_.size() - 1; }
  double list_radius() const { return list_radius_; }  // largest particle radius R_p at build time
  double cutoff() const { return cutoff_; }  // cut-off of the widest blob at build time
  double skin() const { return skin_; }
  std::size_t num_entries() const { return indices_.size(); }  // = 2 * number of pairs
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
  CellGrid grid_;
};

// ---- template implementation ----
template <class F>
void CellGrid::for_each_cell(const Vec3& y, int reach, double radius, F&& f) const {
  const int dim = per_.dim;
  int c[3] = {0, 0, 0}, lo[3] = {0, 0, 0}, hi[3] = {0, 0, 0};
  bool all_cells[3] = {false, false, false};
  for (int k = 0; k < dim; ++k) {
    c[k] = cell_coord(y[k], k);
    if (per_.period[k] > 0.0 && n_[k] < 2 * reach + 1) {
      // Offsets would alias: visit every cell along this axis once.
      all_cells[k] = true;
      lo[k] = 0;
      hi[k] = n_[k] - 1;
    } else if (per_.period[k] > 0.0) {
      lo[k] = c[k] - reach;
      hi[k] = c[k] + reach;
    } else {  // cells beyond the grid hold nothing
      lo[k] = std::max(c[k] - reach, 0);
      hi[k] = std::min(c[k] + reach, n_[k] - 1);
    }
  }
  const bool prune = radius > 0.0;
  const double radius_sq = radius * radius;
  // Distance along axis k from y to the cell of (unwrapped) index i; 0 where
  // the axis is unused or every cell is visited.
  auto gap = [&](int k, int i) {
    if (k >= dim || all_cells[k]) return 0.0;
    const double a = origin_[k] + i * cell_width_[k];
    return std::max({0.0, a - y[k], y[k] - (a + cell_width_[k])});
  };
  for (int i2 = lo[2]; i2 <= hi[2]; ++i2) {
    const double g2 = prune ? gap(2, i2) : 0.0;
    if (g2 * g2 > radius_sq && prune) continue;
    int j2 = i2;
    double s2 = 0.0;
    if (!all_cells[2] && per_.period[2] > 0.0) {
      if (j2 < 0) { j2 += n_[2]; s2 = -per_.period[2]; }
      else if (j2 >= n_[2]) { j2 -= n_[2]; s2 = per_.period[2]; }
    } else if (j2 < 0 || j2 >= n_[2]) continue;
    for (int i1 = lo[1]; i1 <= hi[1]; ++i1) {
      const double g1 = prune ? gap(1, i1) : 0.0;
      const double left_sq = radius_sq - g2 * g2 - g1 * g1;
      if (prune && left_sq < 0.0) continue;
      int j1 = i1;
      double s1 = 0.0;
      if (!all_cells[1] && per_.period[1] > 0.0) {
        if (j1 < 0) { j1 += n_[1]; s1 = -per_.period[1]; }
        else if (j1 >= n_[1]) { j1 -= n_[1]; s1 = per_.period[1]; }
      } else if (j1 < 0 || j1 >= n_[1]) continue;
      // Cells along x are contiguous in items(): visit them as runs.
      const std::size_t row = (static_cast<std::size_t>(j2) * n_[1] + j1) * n_[0];
      auto run = [&](int c0, int c1, double s0) {
        if (c0 > c1) return;
        const std::uint32_t b = cell_start_[row + c0], e = cell_start_[row + c1 + 1];
        if (b < e) f(b, e, Vec3(s0, s1, s2));
      };
      if (all_cells[0]) {
        run(0, n_[0] - 1, 0.0);
        continue;
      }
      int lo0 = lo[0], hi0 = hi[0];
      if (prune) {  // only the cells along x that the remaining radius reaches
        const double reach_x = std::sqrt(left_sq);
        const double t0 = std::floor((y[0] - reach_x - origin_[0]) / cell_width_[0]);
        const double t1 = std::floor((y[0] + reach_x - origin_[0]) / cell_width_[0]);
        lo0 = static_cast<int>(std::max<double>(lo0, t0));
        hi0 = static_cast<int>(std::min<double>(hi0, t1));
      }
      if (per_.period[0] > 0.0) {
        if (lo0 < 0) run(lo0 + n_[0], n_[0] - 1, -per_.period[0]);
        run(std::max(lo0, 0), std::min(hi0, n_[0] - 1), 0.0);
        if (hi0 >= n_[0]) run(0, hi0 - n_[0], per_.period[0]);
      } else {
        run(std::max(lo0, 0), std::min(hi0, n_[0] - 1), 0.0);
      }
    }
  }
}

}  // namespace otfp
