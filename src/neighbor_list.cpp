#include "otfp/neighbor_list.hpp"

#include <omp.h>

#include <algorithm>
#include <atomic>
#include <limits>
#include <cstdlib>
#include <cstring>
#include <new>
#include <chrono>
#include <cmath>
#include <stdexcept>
#include <string>

#include "cell_grid.hpp"
#include "isa.hpp"
#include "neighbor_kernels.hpp"
#include "otfp/geometry.hpp"

namespace otfp {

namespace neighbor_kernels {
namespace generic {
#include "neighbor_kernels_impl.inc"
}  // namespace generic
#ifdef OTFP_HAVE_AVX2_KERNELS
namespace avx2 {
std::size_t box_candidates(const double* x, const double* y, const double* z, std::uint32_t b, std::uint32_t e,
                           const double shift[3], const double lo[3], const double hi[3], double r2max, double* g2,
                           std::uint32_t* out);
std::size_t row_hits(const double* cx, const double* cy, const double* cz, const std::uint32_t* ids, std::size_t len,
                     double qx, double qy, double qz, double r2, std::uint32_t self, double* d2, std::uint32_t* out);
}  // namespace avx2
#endif
std::size_t box_candidates(bool avx2, const double* x, const double* y, const double* z, std::uint32_t b,
                           std::uint32_t e, const double shift[3], const double lo[3], const double hi[3],
                           double r2max, double* g2, std::uint32_t* out) {
#ifdef OTFP_HAVE_AVX2_KERNELS
  if (avx2) return avx2::box_candidates(x, y, z, b, e, shift, lo, hi, r2max, g2, out);
#else
  (void)avx2;
#endif
  return generic::box_candidates(x, y, z, b, e, shift, lo, hi, r2max, g2, out);
}

std::size_t row_hits(bool avx2, const double* cx, const double* cy, const double* cz, const std::uint32_t* ids,
                     std::size_t len, double qx, double qy, double qz, double r2, std::uint32_t self, double* d2,
                     std::uint32_t* out) {
#ifdef OTFP_HAVE_AVX2_KERNELS
  if (avx2) return avx2::row_hits(cx, cy, cz, ids, len, qx, qy, qz, r2, self, d2, out);
#else
  (void)avx2;
#endif
  return generic::row_hits(cx, cy, cz, ids, len, qx, qy, qz, r2, self, d2, out);
}

}  // namespace neighbor_kernels

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
  const double r2_max_all = n ? *std::max_element(radius_sq.begin(), radius_sq.end()) : 0.0;
  const auto& items = grid.items();
  const double* sx = grid.sorted_x().data();
  const double* sy = grid.sorted_y().data();
  const double* sz = grid.sorted_z().data();
  std::vector<double> sorted_r2(n);
  for (std::size_t k = 0; k < n; ++k) sorted_r2[k] = radius_sq[items[k]];
  const std::vector<std::uint32_t>& cell_start = grid.cell_start();
  const std::size_t ncell = grid.num_cells();

  // One pass over the cells, in parallel, each cell on its own (so the rows
  // and their order do not depend on the thread count). The particles of a
  // cell that reach at most kReach cells (the "group", all of them with
  // equal widths) share their candidates: the points of the runs of cells
  // they visit that come within the largest group radius of the group's
  // bounding box, gathered once per cell with their periodic shift applied.
  // Each group particle then tests them all in one long loop (distances, then
  // a branch-free compress), which is what makes the search fast: the cell
  // visiting is paid once per cell, not once per particle. Wider particles and
  // aliasing periodic boxes search their own runs. The rows go to per-thread
  // buffers, then to indices_ by the offsets.
  // Row p: its hits in the order of the runs (cells along z, y, then x, and
  // the grid's order within a cell), then its extras (pairs that only the
  // wider particle's radius holds) by increasing index: the order of the
  // per-particle search.
  //
  // The bounding-box cut is exact in floating point: rounding is monotone, so
  // the gaps to the box as computed are at most |dx|, |dy|, |dz| as d2
  // computes them and their squared sum (in d2's order) is at most d2; a
  // point whose sum exceeds the largest R^2 has d2 > R^2 for every particle
  // of the group.
  struct Scratch {
    std::vector<double> cx, cy, cz, d2;  // candidates (shifted) and their squared distances
    std::vector<double> cr2;             // candidates' R^2 (variable widths only)
    std::vector<std::uint8_t> hit;       // extras test per candidate
    std::vector<std::uint32_t> cj, ci;   // their sorted indices and particle indices
    std::vector<double> dd;              // own search (apart: the cell's candidates stay): squared distances,
    std::vector<std::uint32_t> oj, oi;   // sorted indices and particle indices
    std::vector<std::uint32_t> row;      // the row being searched
    std::vector<std::uint32_t> own_rows; // rows of the particles searching alone, kept from pass 1 to pass 2
    std::vector<std::pair<std::uint32_t, std::uint32_t>> extras;  // (row, entry)
  };
  const int nthreads = std::max(1, omp_get_max_threads());
  std::vector<Scratch> scratch(static_cast<std::size_t>(nthreads));
  std::vector<std::uint32_t> counts(n, 0);
  const Periodicity& per = per_;
  const bool avx2 = detail::use_avx2();  // the instruction-set switch (src/isa.hpp)
  const std::uint32_t* items_p = items.data();
  const double* sr2 = sorted_r2.data();
  // ceil(R_p / h) cells reach every point within R_p; the slack absorbs round-off in R_p / h.
  std::vector<int> sorted_reach(n);
#pragma omp parallel for schedule(static)
  for (std::size_t k = 0; k < n; ++k)
    sorted_reach[k] = static_cast<int>(std::clamp(std::ceil(std::sqrt(sorted_r2[k]) / h - 1e-9), 1.0, 1e9));
  // Writes to sc.row from position at the hits of the particle at sorted
  // index k among candidates of sorted indices cj[0 .. len) at squared
  // distances d2; returns how many. Extras: see below.
  auto append = [&](Scratch& sc, std::size_t at, std::size_t k, const std::uint32_t* cj, const std::uint32_t* ci,
                    std::size_t len, const double* d2, bool extras) {
    const double r2 = sr2[k];
    if (sc.row.size() < at + len + 8) sc.row.resize(std::max(at + len + 8, 2 * sc.row.size()));
    std::uint32_t* out = sc.row.data() + at;
    const std::uint32_t pu = items_p[k];
    std::size_t cnt = 0;
    for (std::size_t j = 0; j < len; ++j) {
      out[cnt] = ci[j];
      cnt += (d2[j] <= r2) & (ci[j] != pu);  // branch-free append
    }
    if (extras && r2 > r2_min)
      for (std::size_t j = 0; j < len; ++j)
        if (d2[j] <= r2 && d2[j] > sr2[cj[j]] && ci[j] != pu) sc.extras.emplace_back(ci[j], pu);
    return static_cast<std::uint32_t>(cnt);
  };

  // Two passes with the same search: the first counts the rows and collects
  // the extras, the second writes the rows in place (indices_ keeps its
  // storage from build to build: no per-build buffers of the list's size).
  std::vector<std::uint32_t> extra_count(n, 0), by_wide_start(n + 1, 0), by_wide;
  std::vector<std::uint16_t> own_thread(n, 0);  // where pass 1 left the rows of the particles searching alone
  // Pass 1 stops early once the rows add up to more than the 32-bit offsets hold.
  std::atomic<std::uint64_t> counted{0};
  std::atomic<bool> overflow{false};
  std::vector<std::size_t> own_pos(n, 0);
  std::uint32_t* dst = nullptr;
  bool mismatch = false;
  for (const int pass : {1, 2}) {
#pragma omp parallel reduction(|| : mismatch)
  {
    Scratch& sc = scratch[static_cast<std::size_t>(omp_get_thread_num())];
    // The row of sorted index k, count entries in sc.row: counted, or checked and copied.
    auto finish_row = [&](std::size_t k, std::uint32_t count) {
      const std::uint32_t p = items_p[k];
      if (pass == 1) {
        counts[p] = count;
        if (counted.fetch_add(count, std::memory_order_relaxed) + count > std::numeric_limits<std::uint32_t>::max())
          overflow.store(true, std::memory_order_relaxed);
      } else if (count != counts[p]) {
        mismatch = true;
      } else if (count > 0) {  // an empty list has no storage: memcpy must not see its null pointer
        std::memcpy(dst + offsets_[p], sc.row.data(), count * sizeof(std::uint32_t));
      }
    };
#pragma omp for schedule(dynamic, 16)
    for (std::size_t c = 0; c < ncell; ++c) {
      const std::size_t c0 = cell_start[c], c1 = cell_start[c + 1];
      if (c0 == c1 || (pass == 1 && overflow.load(std::memory_order_relaxed))) continue;
      // The group: reach <= kReach, sharing the runs of the largest such reach.
      int group_reach = 0;
      for (std::size_t k = c0; k < c1; ++k) {
        const int r = sorted_reach[k];
        if (r <= kReach) group_reach = std::max(group_reach, r);
      }
      const bool group_ok = group_reach > 0 && grid.shifts_exact(group_reach);
      auto in_group = [&](std::size_t k) { return group_ok && sorted_reach[k] <= group_reach; };
      std::size_t ncand = 0;
      if (group_ok) {
        double lo[3] = {0, 0, 0}, hi[3] = {0, 0, 0}, r2max = 0.0;
        bool first = true;
        std::size_t k_first = c0;
        for (std::size_t k = c0; k < c1; ++k) {
          if (!in_group(k)) continue;
          const double v[3] = {sx[k], sy[k], sz[k]};
          for (int a = 0; a < 3; ++a) {
            lo[a] = first ? v[a] : std::min(lo[a], v[a]);
            hi[a] = first ? v[a] : std::max(hi[a], v[a]);
          }
          if (first) k_first = k;
          first = false;
          r2max = std::max(r2max, sr2[k]);
        }
        grid.for_each_cell(Vec3(sx[k_first], sy[k_first], sz[k_first]), group_reach, 0.0,
                           [&](std::uint32_t cb, std::uint32_t ce, const Vec3& shift) {
                             const std::size_t need = ncand + (ce - cb) + 8;
                             if (sc.cx.size() < need) {
                               const std::size_t cap = std::max<std::size_t>(need, 2 * sc.cx.size());
                               sc.cx.resize(cap);
                               sc.cy.resize(cap);
                               sc.cz.resize(cap);
                               sc.cj.resize(cap);
                               sc.ci.resize(cap);
                               sc.d2.resize(cap);
                             }
                             // The images of the run's points nearest the group (shift 0 without
                             // periodic axes) that come within r2max of the group's box.
                             const double sh[3] = {shift[0], shift[1], shift[2]};
                             const std::size_t got = neighbor_kernels::box_candidates(
                                 avx2, sx, sy, sz, cb, ce, sh, lo, hi, r2max, sc.d2.data(), sc.cj.data() + ncand);
                             for (std::size_t i = ncand; i < ncand + got; ++i) {
                               const std::uint32_t j = sc.cj[i];
                               sc.cx[i] = sx[j] + sh[0];
                               sc.cy[i] = sy[j] + sh[1];
                               sc.cz[i] = sz[j] + sh[2];
                               sc.ci[i] = items_p[j];
                             }
                             ncand += got;
                           });
        if (sc.d2.size() < ncand) sc.d2.resize(ncand);
        if (r2_max_all > r2_min) {  // variable widths: the candidates' radii for the extras
          if (sc.cr2.size() < ncand) sc.cr2.resize(ncand);
          if (sc.hit.size() < ncand + 8) sc.hit.resize(ncand + 8);
          for (std::size_t i = 0; i < ncand; ++i) sc.cr2[i] = sr2[sc.cj[i]];
        }
      }
      for (std::size_t k = c0; k < c1; ++k) {
        const double r2 = sr2[k];
        const std::uint32_t pu = items_p[k];
        if (in_group(k)) {
          if (sc.row.size() < ncand + 8) sc.row.resize(std::max(ncand + 8, 2 * sc.row.size()));
          const std::size_t cnt = neighbor_kernels::row_hits(avx2, sc.cx.data(), sc.cy.data(), sc.cz.data(), sc.ci.data(),
                                                             ncand, sx[k], sy[k], sz[k], r2, pu, sc.d2.data(),
                                                             sc.row.data());
          finish_row(k, static_cast<std::uint32_t>(cnt));
          if (pass == 1 && r2 > r2_min) {
            // Pairs that only this particle's radius holds: a vectorisable test, then a scan 8 at a time.
            const double* d2 = sc.d2.data();
            const double* cr2 = sc.cr2.data();
            const std::uint32_t* ci = sc.ci.data();
            std::uint8_t* hit = sc.hit.data();
#pragma omp simd
            for (std::size_t j = 0; j < ncand; ++j)
              hit[j] = static_cast<std::uint8_t>((d2[j] <= r2) & (d2[j] > cr2[j]) & (ci[j] != pu));
            for (std::size_t j = 0; j < ncand; j += 8) {
              std::uint64_t word;
              std::memcpy(&word, hit + j, 8);  // hit has 8 spare bytes
              if (!word) continue;
              for (std::size_t i = j; i < std::min(j + 8, ncand); ++i)
                if (hit[i]) sc.extras.emplace_back(ci[i], pu);
            }
          }
          continue;
        }
        // The others search their own runs in full, in the first pass only
        // (their rows are the longest: kept for the second).
        if (pass == 2) {
          const Scratch& from = scratch[own_thread[pu]];
          if (counts[pu] > 0)
            std::memcpy(dst + offsets_[pu], from.own_rows.data() + own_pos[pu], counts[pu] * sizeof(std::uint32_t));
          continue;
        }
        const Vec3 xp(sx[k], sy[k], sz[k]);  // canonical: what the grid stores
        const int reach = sorted_reach[k];
        const bool exact_shifts = grid.shifts_exact(reach);
        // Wide particles skip the cells of their cube that lie beyond R_p (about half of them in 3D).
        const double prune_radius = reach > kReach ? std::sqrt(r2) : 0.0;
        std::uint32_t total = 0;
        grid.for_each_cell(xp, reach, prune_radius, [&](std::uint32_t cb, std::uint32_t ce, const Vec3& shift) {
          const std::uint32_t len = ce - cb;
          if (sc.dd.size() < len) {
            sc.dd.resize(std::max<std::size_t>(len, 2 * sc.dd.size()));
            sc.oj.resize(sc.dd.size());
            sc.oi.resize(sc.dd.size());
          }
          double* d2 = sc.dd.data();
          std::uint32_t* cj = sc.oj.data();
          std::uint32_t* ci = sc.oi.data();
          for (std::uint32_t j = 0; j < len; ++j) {
            cj[j] = cb + j;
            ci[j] = items_p[cb + j];
          }
          if (exact_shifts) {
            const double qx = xp[0] - shift[0], qy = xp[1] - shift[1], qz = xp[2] - shift[2];
#pragma omp simd
            for (std::uint32_t j = 0; j < len; ++j) {
              const double dx = qx - sx[cb + j], dy = qy - sy[cb + j], dz = qz - sz[cb + j];
              d2[j] = dx * dx + dy * dy + dz * dz;
            }
          } else {
            for (std::uint32_t j = 0; j < len; ++j)
              d2[j] = per.displacement(xp, Vec3(sx[cb + j], sy[cb + j], sz[cb + j])).squaredNorm();
          }
          total += append(sc, total, k, cj, ci, len, d2, pass == 1);
        });
        finish_row(k, total);
        own_thread[pu] = static_cast<std::uint16_t>(omp_get_thread_num());
        own_pos[pu] = sc.own_rows.size();
        sc.own_rows.insert(sc.own_rows.end(), sc.row.begin(), sc.row.begin() + total);
      }
    }
  }
  if (pass == 2) break;
  // Extras of each row by increasing index (the wider particles' order), by
  // two counting passes: the rows by wider particle, then (below) each row's
  // extras filled in that order.
  {
    for (const Scratch& sc : scratch)
      for (const auto& [row, entry] : sc.extras) {
        ++extra_count[row];
        ++by_wide_start[entry + 1];
      }
    for (std::size_t p = 0; p < n; ++p) by_wide_start[p + 1] += by_wide_start[p];
    by_wide.resize(by_wide_start[n]);
    std::vector<std::uint32_t> fill(by_wide_start.begin(), by_wide_start.end() - 1);
    for (Scratch& sc : scratch) {
      for (const auto& [row, entry] : sc.extras) by_wide[fill[entry]++] = row;
      std::vector<std::pair<std::uint32_t, std::uint32_t>>().swap(sc.extras);
    }
  }
  {
    // The offsets are 32-bit: a list of more entries (blobs that each
    // overlap tens of thousands of others: masses far below what their
    // widths need) is refused before anything is written.
    std::uint64_t entries = 0;
    for (std::size_t p = 0; p < n; ++p) entries += static_cast<std::uint64_t>(counts[p]) + extra_count[p];
    if (overflow.load() || entries > std::numeric_limits<std::uint32_t>::max())
      throw std::runtime_error("the neighbour list would hold more than " + std::to_string(entries) + " entries for " +
                               std::to_string(n) + " blobs (at most 2^32 - 1): each blob overlaps about " +
                               std::to_string(entries / std::max<std::size_t>(n, 1)) +
                               " others; the particles are far denser than their widths");
  }
  offsets_.assign(n + 1, 0);
  for (std::size_t p = 0; p < n; ++p) offsets_[p + 1] = offsets_[p] + counts[p] + extra_count[p];
  const std::size_t entries = offsets_[n];
  if (entries > indices_.capacity()) {
    // Growing: every entry is rewritten below, so the old storage goes first,
    // and 1/8 more is reserved, so that a list that grows a little from build
    // to build is not reallocated every time. resize() alone would allocate
    // up to twice the old size while still holding the old storage: three
    // times the list at the peak (400 of 629 MB of heap at n = 1e5 in
    // bench_scale, docs/performance.md).
    std::vector<std::uint32_t>().swap(indices_);
    indices_.reserve(entries + entries / 8);
  }
  indices_.resize(entries);
  dst = indices_.data();
  }
  if (mismatch) throw std::logic_error("NeighborList::build: the counting and writing passes disagree");
  {
    std::vector<std::uint32_t>& fill = extra_count;  // reused: extras written so far per row
    std::fill(fill.begin(), fill.end(), 0u);
    for (std::size_t p = 0; p < n; ++p)
      for (std::uint32_t i = by_wide_start[p]; i < by_wide_start[p + 1]; ++i) {
        const std::uint32_t row = by_wide[i];
        dst[offsets_[row] + counts[row] + fill[row]++] = static_cast<std::uint32_t>(p);
      }
  }

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

void NeighborList::drop_pairs_beyond(std::size_t rows) {
  const std::size_t n = size();
  if (rows >= n) return;
  std::size_t out = offsets_[rows];
  for (std::size_t p = rows; p < n; ++p) {
    const std::size_t begin = offsets_[p], end = offsets_[p + 1];
    offsets_[p] = static_cast<std::uint32_t>(out);
    for (std::size_t e = begin; e < end; ++e)
      if (indices_[e] < rows) indices_[out++] = indices_[e];
  }
  offsets_[n] = static_cast<std::uint32_t>(out);
  indices_.resize(out);
}

std::size_t NeighborList::memory_bytes() const {
  return offsets_.capacity() * sizeof(std::uint32_t) + indices_.capacity() * sizeof(std::uint32_t) +
         x_build_.capacity() * sizeof(Vec3) + s_build_.capacity() * sizeof(double);
}

}  // namespace otfp
