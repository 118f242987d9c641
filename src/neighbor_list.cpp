#include "otfp/neighbor_list.hpp"

#include <omp.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <stdexcept>
#include <string>

#include "cell_grid.hpp"
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

// ------------------------------------------------------------ NeighborList

struct NeighborList::Workspace {
  CellGrid grid;
};

NeighborList::WorkspaceHandle::WorkspaceHandle() = default;
NeighborList::WorkspaceHandle::~WorkspaceHandle() = default;
NeighborList::WorkspaceHandle::WorkspaceHandle(const WorkspaceHandle&) {}  // no grid: see the header
NeighborList::WorkspaceHandle& NeighborList::WorkspaceHandle::operator=(const WorkspaceHandle&) {
  return *this;  // keeps its own grid storage
}
NeighborList::WorkspaceHandle::WorkspaceHandle(WorkspaceHandle&&) noexcept = default;
NeighborList::WorkspaceHandle& NeighborList::WorkspaceHandle::operator=(WorkspaceHandle&&) noexcept = default;

NeighborList::NeighborList(NeighborOptions options) : options_(options) { options_.validate(); }

void NeighborList::build(const std::vector<Vec3>& x, const std::vector<double>& width_s,
                         const Periodicity& periodicity) {
  const auto t0 = std::chrono::steady_clock::now();
  require(width_s.size() == x.size(), "widths", static_cast<double>(width_s.size()),
          "must have one entry per particle (" + std::to_string(x.size()) + ")");
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

  // Per-particle radii R_p; the pair (p, q) belongs to the list when
  // |x_p - x_q| <= max(R_p, R_q). Each p searches its own R_p; a pair that
  // only the wider particle finds is added to the narrower one's row
  // afterwards ("extras"), so the list stays symmetric.
  std::vector<double> radius_sq(n);
  for (std::size_t p = 0; p < n; ++p) {
    const double r = particle_radius(width_s[p]);
    radius_sq[p] = r * r;
  }
  // Cells of half the median radius, visited two deep by a median particle
  // (about 40% fewer candidates than one-deep cells); wider particles visit
  // more cells. With equal widths this is the plain two-deep search.
  double r_cell = list_radius_;
  if (n > 0) {
    std::vector<double> tmp(radius_sq);
    std::nth_element(tmp.begin(), tmp.begin() + static_cast<std::ptrdiff_t>(n / 2), tmp.end());
    r_cell = std::sqrt(tmp[n / 2]);
  }
  constexpr int kReach = 2;
  if (!work_.ptr) work_.ptr = std::make_unique<Workspace>();
  CellGrid& grid = work_.ptr->grid;
  grid.build(x, r_cell / kReach, per_, kReach);
  const double h = grid.min_cell_width();
  const double r2_min = n ? *std::min_element(radius_sq.begin(), radius_sq.end()) : 0.0;
  const auto& items = grid.items();
  const double* sx = grid.sorted_x().data();
  const double* sy = grid.sorted_y().data();
  const double* sz = grid.sorted_z().data();
  std::vector<double> sorted_r2(n);
  for (std::size_t k = 0; k < n; ++k) sorted_r2[k] = radius_sq[items[k]];

  // Blocks of rows are searched in parallel into private buffers and joined in
  // block order, so the list is identical for any thread count.
  constexpr std::size_t kBlock = 512;
  const std::size_t nblocks = (n + kBlock - 1) / kBlock;
  std::vector<std::vector<std::uint32_t>> block_items(nblocks);
  std::vector<std::vector<std::pair<std::uint32_t, std::uint32_t>>> block_extras(nblocks);  // (row, entry)
  std::vector<std::uint32_t> counts(n, 0);
#pragma omp parallel for schedule(dynamic, 4)
  for (std::size_t b = 0; b < nblocks; ++b) {
    auto& buf = block_items[b];
    auto& extras = block_extras[b];
    const std::size_t end = std::min(n, (b + 1) * kBlock);
    buf.reserve(kBlock * 256);
    std::vector<double> dist_sq;
    for (std::size_t p = b * kBlock; p < end; ++p) {
      const std::size_t before = buf.size();
      const Vec3 xp = grid.canonical(x[p]);
      const double r2 = radius_sq[p];
      const bool may_have_extras = r2 > r2_min;
      // ceil(R_p / h) cells reach every point within R_p; the slack absorbs round-off in R_p / h.
      const int reach = std::max(1, static_cast<int>(std::ceil(std::sqrt(r2) / h - 1e-9)));
      const bool exact_shifts = grid.shifts_exact(reach);
      const auto pu = static_cast<std::uint32_t>(p);
      // Wide particles skip the cells of their cube that lie beyond R_p (about
      // half of them in 3D); at the median reach that bookkeeping costs more than it saves.
      const double prune_radius = reach > kReach ? std::sqrt(r2) : 0.0;
      grid.for_each_cell(xp, reach, prune_radius, [&](std::uint32_t cb, std::uint32_t ce, const Vec3& shift) {
        const std::uint32_t len = ce - cb;
        dist_sq.resize(len);
        double* d2 = dist_sq.data();
        if (exact_shifts) {
          // Distances first (a loop that vectorises), then a scalar compress.
          const double qx = xp[0] - shift[0], qy = xp[1] - shift[1], qz = xp[2] - shift[2];
#pragma omp simd
          for (std::uint32_t k = 0; k < len; ++k) {
            const double dx = qx - sx[cb + k], dy = qy - sy[cb + k], dz = qz - sz[cb + k];
            d2[k] = dx * dx + dy * dy + dz * dz;
          }
        } else {
          for (std::uint32_t k = 0; k < len; ++k)
            d2[k] = per_.displacement(xp, Vec3(sx[cb + k], sy[cb + k], sz[cb + k])).squaredNorm();
        }
        const std::size_t at = buf.size();
        buf.resize(at + len);
        std::uint32_t* out = buf.data() + at;
        std::size_t cnt = 0;
        for (std::uint32_t k = 0; k < len; ++k) {
          out[cnt] = items[cb + k];
          cnt += (d2[k] <= r2) & (items[cb + k] != pu);  // branch-free append
        }
        buf.resize(at + cnt);
        if (may_have_extras)
          for (std::uint32_t k = 0; k < len; ++k)
            if (d2[k] <= r2 && d2[k] > sorted_r2[cb + k] && items[cb + k] != pu) extras.emplace_back(items[cb + k], pu);
      });
      counts[p] = static_cast<std::uint32_t>(buf.size() - before);
    }
  }
  // Row p: its own hits, then the extras from wider particles in block order.
  std::vector<std::uint32_t> extra_count(n, 0);
  for (const auto& ex : block_extras)
    for (const auto& [row, entry] : ex) ++extra_count[row];
  offsets_.assign(n + 1, 0);
  for (std::size_t p = 0; p < n; ++p) offsets_[p + 1] = offsets_[p] + counts[p] + extra_count[p];
  indices_.resize(offsets_[n]);
#pragma omp parallel for schedule(static)
  for (std::size_t b = 0; b < nblocks; ++b) {
    const std::uint32_t* src = block_items[b].data();
    const std::size_t end = std::min(n, (b + 1) * kBlock);
    for (std::size_t p = b * kBlock; p < end; ++p) {
      std::copy(src, src + counts[p], indices_.begin() + offsets_[p]);
      src += counts[p];
    }
  }
  std::vector<std::uint32_t> fill(n, 0);
  for (const auto& ex : block_extras)
    for (const auto& [row, entry] : ex) indices_[offsets_[row] + counts[row] + fill[row]++] = entry;

  x_build_ = x;
  s_build_ = width_s;
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
  if (width_s.size() != s_build_.size()) return true;
  // A missing pair needs some particle's cut-off to have grown past its build-time value.
  double growth = 0.0;
  for (std::size_t p = 0; p < width_s.size(); ++p) growth = std::max(growth, width_s[p] - s_build_[p]);
  growth = cutoff_radius(growth, options_.kernel_tolerance);  // r_c is linear in s
  return 2.0 * max_displacement(x) + growth > skin_;
}

std::size_t NeighborList::memory_bytes() const {
  return offsets_.capacity() * sizeof(std::uint32_t) + indices_.capacity() * sizeof(std::uint32_t) +
         x_build_.capacity() * sizeof(Vec3) + s_build_.capacity() * sizeof(double);
}

}  // namespace otfp
