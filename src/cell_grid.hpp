#pragma once
// Internal: the uniform cell grid behind the neighbour list
// (src/neighbor_list.cpp) and the blob density at arbitrary points
// (src/density.cpp). Not installed; the public API is otfp/neighbor_list.hpp.
// The small per-query members are inline here so that both users keep them
// inlined in their loops; the build is in src/cell_grid.cpp.
#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <utility>
#include <vector>

#include "otfp/neighbor_list.hpp"
#include "otfp/types.hpp"

namespace otfp {

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
  // Cell c holds items()[cell_start()[c] .. cell_start()[c + 1]).
  const std::vector<std::uint32_t>& cell_start() const { return cell_start_; }
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

// ---- inline members ----
inline int CellGrid::cell_coord(double v, int axis) const {
  // Clamped in double first: the cast of a far-away coordinate would overflow.
  double t = std::clamp((v - origin_[axis]) / cell_width_[axis], -1e9, 1e9);
  if (std::isnan(t)) t = 0.0;  // build() rejects NaN positions; a NaN query must not reach the cast
  int c = static_cast<int>(std::floor(t));
  if (per_.period[axis] > 0.0) {
    if (c == n_[axis] && v < per_.lo[axis] + per_.period[axis]) return c - 1;  // round-off at the top edge
    c %= n_[axis];
    if (c < 0) c += n_[axis];
    return c;
  }
  return std::clamp(c, 0, n_[axis] - 1);
}

inline Vec3 CellGrid::canonical(const Vec3& a) const {
  Vec3 y = per_.wrap(a);
  for (int k = 0; k < 3; ++k)  // wrap() can round up to lo + period
    if (per_.period[k] > 0.0 && y[k] >= per_.lo[k] + per_.period[k]) y[k] = per_.lo[k];
  return y;
}

inline bool CellGrid::shifts_exact(int reach) const {
  for (int k = 0; k < per_.dim; ++k)
    if (per_.period[k] > 0.0 && n_[k] < 2 * reach + 1) return false;
  return true;
}

inline double CellGrid::min_cell_width() const {
  double h = cell_width_[0];
  for (int k = 1; k < per_.dim; ++k) h = std::min(h, cell_width_[k]);
  return h;
}

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
