#pragma once
// Cell list (O(n) build) and Verlet neighbour list with a skin.
//
// The cut-off comes from a kernel tolerance, not from 1/sqrt(beta)
// (METHOD-NOTES 2.5): exp(-beta r_c^2) = tol, i.e. r_c = s sqrt(ln(1/tol))
// with s = beta^-1/2. The pair (p, q) enters through w_q(x_p), which uses
// beta_q, and through w_p(x_q), which uses beta_p; so the list radius is the
// cut-off of the widest blob plus the skin, and the list is symmetric (full:
// both (p, q) and (q, p) are stored, so sweeps gather and never scatter).
#include <cstddef>
#include <cmath>
#include <cstdint>
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

// Uniform grid of cubic cells over the points' bounding box (or the periodic
// box) with a counting-sort build; cells are at least `cell_size` wide.
class CellGrid {
 public:
  void build(const std::vector<Vec3>& x, double cell_size, const Periodicity& periodicity);
  // Calls f(j) for every point j in the cells around y (3^d cells), each once.
  template <class F>
  void for_each_candidate(const Vec3& y, F&& f) const;
  std::size_t num_cells() const { return cell_start_.empty() ? 0 : cell_start_.size() - 1; }

 private:
  int cell_coord(double v, int axis) const;
  Periodicity per_;
  Vec3 origin_ = Vec3::Zero();
  Vec3 cell_width_ = Vec3::Ones();
  int n_[3] = {1, 1, 1};
  std::vector<std::uint32_t> cell_start_;  // size num_cells + 1
  std::vector<std::uint32_t> items_;       // point indices sorted by cell
};

class NeighborList {
 public:
  explicit NeighborList(NeighborOptions options = {});

  // Builds the full list of pairs with |x_p - x_q| <= list_radius().
  void build(const std::vector<Vec3>& x, const std::vector<double>& width_s, const Periodicity& periodicity);
  // True when a pair inside the cut-off might be missing: twice the largest
  // displacement since the build plus the growth of the largest cut-off exceeds the skin.
  bool needs_rebuild(const std::vector<Vec3>& x, const std::vector<double>& width_s) const;
  // Largest displacement since the last build (minimum image).
  double max_displacement(const std::vector<Vec3>& x) const;

  bool built() const { return built_; }
  std::size_t size() const { return offsets_.empty() ? 0 : offsets_.size() - 1; }
  double list_radius() const { return list_radius_; }
  double cutoff() const { return cutoff_; }  // cut-off of the widest blob at build time
  double skin() const { return skin_; }
  std::size_t num_entries() const { return indices_.size(); }  // = 2 * number of pairs
  int build_count() const { return build_count_; }
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
  double list_radius_ = 0.0, cutoff_ = 0.0, skin_ = 0.0;
  int build_count_ = 0;
  bool built_ = false;
  CellGrid grid_;
};

// ---- template implementation ----
template <class F>
void CellGrid::for_each_candidate(const Vec3& y, F&& f) const {
  const int dim = per_.dim;
  int c[3] = {0, 0, 0};
  for (int k = 0; k < dim; ++k) c[k] = cell_coord(y[k], k);
  int lo[3] = {0, 0, 0}, hi[3] = {0, 0, 0};
  for (int k = 0; k < dim; ++k) {
    if (per_.period[k] > 0.0) {
      // With fewer than 3 cells along a periodic axis, -1 and +1 alias: visit each cell once.
      if (n_[k] < 3) { lo[k] = 0; hi[k] = n_[k] - 1; c[k] = 0; }
      else { lo[k] = -1; hi[k] = 1; }
    } else {
      lo[k] = -1; hi[k] = 1;
    }
  }
  for (int a = lo[0]; a <= hi[0]; ++a) {
    int i0 = c[0] + a;
    if (per_.period[0] > 0.0) i0 = (i0 % n_[0] + n_[0]) % n_[0];
    else if (i0 < 0 || i0 >= n_[0]) continue;
    for (int b = lo[1]; b <= hi[1]; ++b) {
      int i1 = c[1] + b;
      if (per_.period[1] > 0.0) i1 = (i1 % n_[1] + n_[1]) % n_[1];
      else if (i1 < 0 || i1 >= n_[1]) continue;
      for (int e = lo[2]; e <= hi[2]; ++e) {
        int i2 = c[2] + e;
        if (per_.period[2] > 0.0) i2 = (i2 % n_[2] + n_[2]) % n_[2];
        else if (i2 < 0 || i2 >= n_[2]) continue;
        const std::size_t cell = (static_cast<std::size_t>(i2) * n_[1] + i1) * n_[0] + i0;
        for (std::uint32_t k = cell_start_[cell]; k < cell_start_[cell + 1]; ++k) f(items_[k]);
      }
    }
  }
}

}  // namespace otfp
