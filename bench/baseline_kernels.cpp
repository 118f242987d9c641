// Today's pair kernel as of issue 15 (separate x, y, z, beta, mc arrays gathered
// per neighbour; the compiler's AVX2 vectorisation of the omp simd loops), kept
// as the baseline the library's kernel is measured against in one benchmark run
// (bench_functional.cpp, BM_PairSweeps). Compiled with -mavx2 -mfma as the
// library's AVX2 build was. Not used by the library.
#include <cmath>

#include "baseline_kernels.hpp"
#include "fast_exp.hpp"

namespace otfp::bench_baseline {

using otfp::detail::exp_nonpositive;
using otfp::detail::MinimumImage;


namespace {

template <bool Periodic>
__attribute__((always_inline)) inline void image(double& dx, double& dy, double& dz, const MinimumImage& mi) {
  if constexpr (Periodic) {
    dx -= mi.period[0] * std::nearbyint(dx * mi.inv_period[0]);
    dy -= mi.period[1] * std::nearbyint(dy * mi.inv_period[1]);
    dz -= mi.period[2] * std::nearbyint(dz * mi.inv_period[2]);
  }
}

template <bool Periodic>
__attribute__((always_inline)) inline void density_rows_impl(std::size_t r0, std::size_t r1, const std::uint32_t* off, const std::uint32_t* idx,
                              const BaselineArrays& b, const MinimumImage& mi, double* rho, double* gx, double* gy,
                              double* gz) {
  for (std::size_t p = r0; p < r1; ++p) {
    const double xp = b.px[p], yp = b.py[p], zp = b.pz[p];
    double r = b.mc[p], ax = 0.0, ay = 0.0, az = 0.0;
    const std::uint32_t e = off[p + 1];
#pragma omp simd reduction(+ : r, ax, ay, az)
    for (std::uint32_t k = off[p]; k < e; ++k) {
      const std::uint32_t q = idx[k];
      double dx = xp - b.px[q], dy = yp - b.py[q], dz = zp - b.pz[q];
      image<Periodic>(dx, dy, dz, mi);
      const double bq = b.beta[q];
      const double w = b.mc[q] * exp_nonpositive(-bq * (dx * dx + dy * dy + dz * dz));
      const double c = -2.0 * bq * w;
      r += w;
      ax += c * dx;
      ay += c * dy;
      az += c * dz;
    }
    rho[p] = r;
    gx[p] = ax;
    gy[p] = ay;
    gz[p] = az;
  }
}

template <bool Periodic>
__attribute__((always_inline)) inline void gather_rows_impl(std::size_t r0, std::size_t r1, const std::uint32_t* off, const std::uint32_t* idx,
                             const BaselineArrays& b, const MinimumImage& mi, const double* a, double* sx, double* sy,
                             double* sz, double* wsum, double* wr2) {
  for (std::size_t r = r0; r < r1; ++r) {
    const double xr = b.px[r], yr = b.py[r], zr = b.pz[r];
    const double br = b.beta[r], mr = b.mc[r];
    double ax = 0.0, ay = 0.0, az = 0.0, ws = 0.0, w2 = 0.0;
    const std::uint32_t e = off[r + 1];
#pragma omp simd reduction(+ : ax, ay, az, ws, w2)
    for (std::uint32_t k = off[r]; k < e; ++k) {
      const std::uint32_t p = idx[k];
      double dx = b.px[p] - xr, dy = b.py[p] - yr, dz = b.pz[p] - zr;
      image<Periodic>(dx, dy, dz, mi);
      const double d2 = dx * dx + dy * dy + dz * dz;
      const double w = a[p] * mr * exp_nonpositive(-br * d2);
      ax += w * dx;
      ay += w * dy;
      az += w * dz;
      ws += w;
      w2 += w * d2;
    }
    sx[r] = ax;
    sy[r] = ay;
    sz[r] = az;
    wsum[r] = ws + a[r] * mr;  // self term: w_rr = a_r mc_r, zero displacement
    wr2[r] = w2;
  }
}

}  // namespace

void density_rows(std::size_t r0, std::size_t r1, const std::uint32_t* offsets, const std::uint32_t* indices,
                  const BaselineArrays& b, const MinimumImage& mi, double* rho, double* gx, double* gy, double* gz) {
  if (mi.any) density_rows_impl<true>(r0, r1, offsets, indices, b, mi, rho, gx, gy, gz);
  else density_rows_impl<false>(r0, r1, offsets, indices, b, mi, rho, gx, gy, gz);
}

void gather_rows(std::size_t r0, std::size_t r1, const std::uint32_t* offsets, const std::uint32_t* indices,
                 const BaselineArrays& b, const MinimumImage& mi, const double* a, double* sx, double* sy, double* sz,
                 double* wsum, double* wr2) {
  if (mi.any) gather_rows_impl<true>(r0, r1, offsets, indices, b, mi, a, sx, sy, sz, wsum, wr2);
  else gather_rows_impl<false>(r0, r1, offsets, indices, b, mi, a, sx, sy, sz, wsum, wr2);
}

}  // namespace otfp::bench_baseline
