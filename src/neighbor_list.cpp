#include "otfp/neighbor_list.hpp"

#include <omp.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <stdexcept>
#include <string>

#include "otfp/geometry.hpp"

namespace otfp {

Periodicity Periodicity::none(int dim) {
  Periodicity p;
  p.dim = dim;
  return p;
}

Periodicity Periodicity::from_domain(const Domain& domain) {
  Periodicity p;
  p.dim = domain.dim();
  if (domain.is_periodic()) {
    p.lo = domain.bounding_box().lo;
    p.period = domain.period();
  }
  return p;
}

double cutoff_radius(double width_s, double kernel_tolerance) {
  return width_s * std::sqrt(std::log(1.0 / kernel_tolerance));
}

void NeighborOptions::validate() const {
  require(std::isfinite(kernel_tolerance) && kernel_tolerance > 0.0 && kernel_tolerance < 1.0,
          "kernel_tolerance", kernel_tolerance, "must be in (0, 1)");
  require(std::isfinite(skin), "skin", skin, "must be finite (< 0 selects skin_factor)");
  require(std::isfinite(skin_factor) && skin_factor >= 0.0, "skin_factor", skin_factor, "must be finite and >= 0");
}

// ---------------------------------------------------------------- CellGrid

int CellGrid::cell_coord(double v, int axis) const {
  // Clamped in double first: the cast of a far-away coordinate would overflow.
  double t = std::clamp((v - origin_[axis]) / cell_width_[axis], -1e9, 1e9);
  if (std::isnan(t)) t = 0.0;  // build() rejects NaN positions; a NaN query must not reach the cast
  int c = static_cast<int>(std::floor(t));
  if (per_.period[axis] > 0.0) {
    c %= n_[axis];
    if (c < 0) c += n_[axis];
    return c;
  }
  return std::clamp(c, 0, n_[axis] - 1);
}

void CellGrid::build(const std::vector<Vec3>& x, double cell_size, const Periodicity& periodicity, int reach) {
  per_ = periodicity;
  reach_ = std::max(1, reach);
  const int dim = per_.dim;
  const std::size_t n = x.size();
  Vec3 lo = Vec3::Zero(), hi = Vec3::Zero();
  if (n > 0) {
    lo = x[0];
    hi = x[0];
    for (std::size_t i = 0; i < n; ++i) {
      // A diverged explicit step (dt far above its limit) ends here first.
      if (!x[i].allFinite())
        throw std::runtime_error("non-finite position of particle " + std::to_string(i) +
                                 ": the step diverged (an explicit dt above its stability limit?)");
      lo = lo.cwiseMin(x[i]);
      hi = hi.cwiseMax(x[i]);
    }
  }
  // Cap the cell count near n so that sparse, spread-out clouds stay O(n) in
  // memory: counts are computed in double (a cloud blown apart by an unstable
  // step can span far more cells than an int holds), cells grown until they fit.
  const double max_cells = std::max<double>(8.0, 2.0 * static_cast<double>(n));
  double size = cell_size;
  double counts[3] = {1.0, 1.0, 1.0};
  for (int attempt = 0; attempt < 200; ++attempt) {
    double total = 1.0;
    for (int k = 0; k < dim; ++k) {
      counts[k] = per_.period[k] > 0.0 ? std::max(1.0, std::floor(per_.period[k] / size))
                                       : std::max(1.0, std::floor((hi[k] - lo[k]) / size) + 1.0);
      total *= counts[k];
    }
    if (total <= max_cells) break;
    size *= std::max(1.26, 0.5 * std::pow(total / max_cells, 1.0 / dim));
  }
  for (int k = 0; k < 3; ++k) {
    if (k >= dim) {
      n_[k] = 1;
      origin_[k] = 0.0;
      cell_width_[k] = 1.0;
    } else if (per_.period[k] > 0.0) {
      origin_[k] = per_.lo[k];
      n_[k] = static_cast<int>(counts[k]);
      cell_width_[k] = per_.period[k] / n_[k];
    } else {
      origin_[k] = lo[k];
      n_[k] = static_cast<int>(counts[k]);
      cell_width_[k] = size;
    }
  }
  const std::size_t ncell = static_cast<std::size_t>(n_[0]) * n_[1] * n_[2];
  cell_start_.assign(ncell + 1, 0);
  std::vector<std::uint32_t> cell_of(n);
  for (std::size_t i = 0; i < n; ++i) {
    std::size_t c = 0;
    for (int k = dim - 1; k >= 0; --k) c = c * n_[k] + cell_coord(x[i][k], k);
    cell_of[i] = static_cast<std::uint32_t>(c);
    ++cell_start_[c + 1];
  }
  for (std::size_t c = 0; c < ncell; ++c) cell_start_[c + 1] += cell_start_[c];
  items_.resize(n);
  std::vector<std::uint32_t> fill(cell_start_.begin(), cell_start_.end() - 1);
  for (std::size_t i = 0; i < n; ++i) items_[fill[cell_of[i]]++] = static_cast<std::uint32_t>(i);
  sx_.resize(n);
  sy_.resize(n);
  sz_.resize(n);
  for (std::size_t k = 0; k < n; ++k) {
    sx_[k] = x[items_[k]][0];
    sy_[k] = x[items_[k]][1];
    sz_[k] = x[items_[k]][2];
  }
  shifts_exact_ = true;
  for (int k = 0; k < dim; ++k)
    if (per_.period[k] > 0.0 && n_[k] < 2 * reach_ + 1) shifts_exact_ = false;
}

// ------------------------------------------------------------ NeighborList

NeighborList::NeighborList(NeighborOptions options) : options_(options) { options_.validate(); }

void NeighborList::build(const std::vector<Vec3>& x, const std::vector<double>& width_s,
                         const Periodicity& periodicity) {
  const auto t0 = std::chrono::steady_clock::now();
  per_ = periodicity;
  const std::size_t n = x.size();
  double s_max = 0.0, s_min = n ? width_s[0] : 1.0;
  for (double s : width_s) {
    s_max = std::max(s_max, s);
    s_min = std::min(s_min, s);
  }
  cutoff_ = cutoff_radius(s_max, options_.kernel_tolerance);
  skin_ = options_.skin >= 0.0 ? options_.skin : options_.skin_factor * s_min;
  list_radius_ = cutoff_ + skin_;
  for (int k = 0; k < per_.dim; ++k)
    require(!(per_.period[k] > 0.0) || per_.period[k] >= 2.0 * list_radius_, "periodic box side",
            per_.period[k], "must be >= 2 x neighbour list radius (" + std::to_string(2.0 * list_radius_) + ")");

  // Half-width cells visited two deep: about 40% fewer candidates than one-deep cells.
  constexpr int kReach = 2;
  grid_.build(x, list_radius_ / kReach, per_, kReach);
  const double r2 = list_radius_ * list_radius_;
  const bool exact_shifts = grid_.shifts_exact();
  const auto& items = grid_.items();
  const double* sx = grid_.sorted_x().data();
  const double* sy = grid_.sorted_y().data();
  const double* sz = grid_.sorted_z().data();

  // Blocks of rows are searched in parallel into private buffers and joined in
  // block order, so the list is identical for any thread count.
  constexpr std::size_t kBlock = 512;
  const std::size_t nblocks = (n + kBlock - 1) / kBlock;
  std::vector<std::vector<std::uint32_t>> block_items(nblocks);
  std::vector<std::uint32_t> counts(n, 0);
#pragma omp parallel for schedule(dynamic, 4)
  for (std::size_t b = 0; b < nblocks; ++b) {
    auto& buf = block_items[b];
    const std::size_t end = std::min(n, (b + 1) * kBlock);
    buf.reserve(kBlock * 256);
    std::vector<double> keep;
    for (std::size_t p = b * kBlock; p < end; ++p) {
      const std::size_t before = buf.size();
      const Vec3 xp = x[p];
      grid_.for_each_cell(xp, [&](std::uint32_t cb, std::uint32_t ce, const Vec3& shift) {
        const std::size_t at = buf.size();
        buf.resize(at + (ce - cb));
        std::uint32_t* out = buf.data() + at;
        std::size_t cnt = 0;
        if (exact_shifts) {
          // Distances first (a loop that vectorises), then a scalar compress.
          const double qx = xp[0] - shift[0], qy = xp[1] - shift[1], qz = xp[2] - shift[2];
          const std::uint32_t len = ce - cb;
          keep.resize(len);
          double* kp = keep.data();
#pragma omp simd
          for (std::uint32_t k = 0; k < len; ++k) {
            const double dx = qx - sx[cb + k], dy = qy - sy[cb + k], dz = qz - sz[cb + k];
            kp[k] = r2 - (dx * dx + dy * dy + dz * dz);
          }
          for (std::uint32_t k = 0; k < len; ++k) {
            out[cnt] = items[cb + k];
            cnt += (kp[k] >= 0.0) & (items[cb + k] != p);  // branch-free append
          }
        } else {
          for (std::uint32_t k = cb; k < ce; ++k) {
            out[cnt] = items[k];
            cnt += (per_.displacement(xp, Vec3(sx[k], sy[k], sz[k])).squaredNorm() <= r2) & (items[k] != p);
          }
        }
        buf.resize(at + cnt);
      });
      counts[p] = static_cast<std::uint32_t>(buf.size() - before);
    }
  }
  offsets_.assign(n + 1, 0);
  for (std::size_t p = 0; p < n; ++p) offsets_[p + 1] = offsets_[p] + counts[p];
  indices_.resize(offsets_[n]);
#pragma omp parallel for schedule(static)
  for (std::size_t b = 0; b < nblocks; ++b)
    std::copy(block_items[b].begin(), block_items[b].end(), indices_.begin() + offsets_[b * kBlock]);

  x_build_ = x;
  built_ = true;
  ++build_count_;
  build_seconds_ += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

double NeighborList::max_displacement(const std::vector<Vec3>& x) const {
  if (!built_ || x.size() != x_build_.size()) return std::numeric_limits<double>::infinity();
  double m2 = 0.0;
  const std::size_t n = x.size();
#pragma omp parallel for reduction(max : m2) schedule(static)
  for (std::size_t p = 0; p < n; ++p) m2 = std::max(m2, per_.displacement(x[p], x_build_[p]).squaredNorm());
  return std::sqrt(m2);
}

bool NeighborList::needs_rebuild(const std::vector<Vec3>& x, const std::vector<double>& width_s) const {
  if (!built_ || x.size() != x_build_.size()) return true;
  double s_max = 0.0;
  for (double s : width_s) s_max = std::max(s_max, s);
  const double growth = std::max(0.0, cutoff_radius(s_max, options_.kernel_tolerance) - cutoff_);
  return 2.0 * max_displacement(x) + growth > skin_;
}

std::size_t NeighborList::memory_bytes() const {
  return offsets_.capacity() * sizeof(std::uint32_t) + indices_.capacity() * sizeof(std::uint32_t) +
         x_build_.capacity() * sizeof(Vec3);
}

}  // namespace otfp
