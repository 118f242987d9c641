// The pair sweeps by hand in AVX2/FMA intrinsics (compiled with -mavx2 -mfma,
// src/CMakeLists.txt; run only when the CPU has both). Four neighbours per
// iteration: their packed (x, y, z, beta) or (x, y, z, a) records come in as
// eight 16-byte loads and four unpacks in registers, where the compiler's
// vectorisation of the portable loops gathers every field separately (five
// gathers per four pairs, the bottleneck of the previous kernel: ~2x slower,
// bench_functional.cpp BM_PairSweeps). A row's tail of 1-3 neighbours repeats
// its last index and masks the extra lanes to zero. Each row is summed in four
// lanes, then the lanes in a fixed order: the result depends on the list, not
// on the thread count.
#include <immintrin.h>

#include <cstdint>

#include "pair_kernels.hpp"

namespace otfp::detail::avx2 {

namespace {

// exp(a) = poly x scale for a <= 0, four lanes at once: fast_exp.hpp's
// reduction a = k ln2 + r and degree-12 Taylor polynomial, with two changes
// that shorten the chain of dependent operations (the sweeps are bound by its
// latency, not by arithmetic throughput): the polynomial by Estrin's scheme (4
// levels of FMAs instead of Horner's 13), and r = a - k ln2 in one FMA instead
// of Cody-Waite's two (the error k x 2.3e-17 in r is below 1e-15 relative for
// k <= 40, i.e. down to exp(-27), further than any list entry's kernel reaches
// at the default cut-off). The scale 2^k comes early and is returned apart,
// so that callers multiply it into their own factors off the critical path.
// The values agree with exp_nonpositive to about 1e-15.
struct Exp4 {
  __m256d poly, scale;
};
__attribute__((always_inline)) inline Exp4 exp_nonpositive4(__m256d a) {
  a = _mm256_max_pd(a, _mm256_set1_pd(-700.0));
  const __m256d shift = _mm256_set1_pd(0x1.8p52);
  const __m256d t = _mm256_fmadd_pd(a, _mm256_set1_pd(1.4426950408889634), shift);
  const __m256d k = _mm256_sub_pd(t, shift);
  const __m256d r = _mm256_fnmadd_pd(k, _mm256_set1_pd(0.6931471805599453), a);
  auto c = [](double v) { return _mm256_set1_pd(v); };
  const __m256d r2 = _mm256_mul_pd(r, r);
  const __m256d r4 = _mm256_mul_pd(r2, r2);
  const __m256d r8 = _mm256_mul_pd(r4, r4);
  const __m256d a0 = _mm256_fmadd_pd(c(1.0), r, c(1.0));
  const __m256d a1 = _mm256_fmadd_pd(c(1.0 / 6.0), r, c(0.5));
  const __m256d a2 = _mm256_fmadd_pd(c(1.0 / 120.0), r, c(1.0 / 24.0));
  const __m256d a3 = _mm256_fmadd_pd(c(1.0 / 5040.0), r, c(1.0 / 720.0));
  const __m256d a4 = _mm256_fmadd_pd(c(1.0 / 362880.0), r, c(1.0 / 40320.0));
  const __m256d a5 = _mm256_fmadd_pd(c(1.0 / 39916800.0), r, c(1.0 / 3628800.0));
  const __m256d b0 = _mm256_fmadd_pd(a1, r2, a0);
  const __m256d b1 = _mm256_fmadd_pd(a3, r2, a2);
  const __m256d b2 = _mm256_fmadd_pd(a5, r2, a4);
  const __m256d e0 = _mm256_fmadd_pd(b1, r4, b0);
  const __m256d e1 = _mm256_fmadd_pd(c(1.0 / 479001600.0), r4, b2);
  // The low bits of t hold k; 2^k through the exponent field.
  const __m256i kbits = _mm256_castpd_si256(t);
  const __m256i scale = _mm256_slli_epi64(_mm256_add_epi64(kbits, _mm256_set1_epi64x(1023)), 52);
  return {_mm256_fmadd_pd(e1, r8, e0), _mm256_castsi256_pd(scale)};
}

// Records q0..q3 (4 doubles each) -> columns c0..c3 (field j of the four
// records): 128-bit halves loaded straight into the lanes where they belong
// (the inserts take their operand from memory), then one unpack per column:
// fewer shuffles and a shorter chain than four full loads and a 4x4 transpose.
__attribute__((always_inline)) inline void load_transposed(const double* base, std::uint32_t q0, std::uint32_t q1,
                                                           std::uint32_t q2, std::uint32_t q3, __m256d& c0,
                                                           __m256d& c1, __m256d& c2, __m256d& c3) {
  const double* r0 = base + 4 * static_cast<std::size_t>(q0);
  const double* r1 = base + 4 * static_cast<std::size_t>(q1);
  const double* r2 = base + 4 * static_cast<std::size_t>(q2);
  const double* r3 = base + 4 * static_cast<std::size_t>(q3);
  const __m256d t0 = _mm256_insertf128_pd(_mm256_castpd128_pd256(_mm_load_pd(r0)), _mm_load_pd(r2), 1);  // x0 y0 x2 y2
  const __m256d t1 = _mm256_insertf128_pd(_mm256_castpd128_pd256(_mm_load_pd(r1)), _mm_load_pd(r3), 1);  // x1 y1 x3 y3
  const __m256d t2 =
      _mm256_insertf128_pd(_mm256_castpd128_pd256(_mm_load_pd(r0 + 2)), _mm_load_pd(r2 + 2), 1);  // z0 b0 z2 b2
  const __m256d t3 =
      _mm256_insertf128_pd(_mm256_castpd128_pd256(_mm_load_pd(r1 + 2)), _mm_load_pd(r3 + 2), 1);  // z1 b1 z3 b3
  c0 = _mm256_unpacklo_pd(t0, t1);
  c1 = _mm256_unpackhi_pd(t0, t1);
  c2 = _mm256_unpacklo_pd(t2, t3);
  c3 = _mm256_unpackhi_pd(t2, t3);
}

struct Image4 {
  __m256d period[3], inv_period[3];
  explicit Image4(const MinimumImage& mi) {
    for (int k = 0; k < 3; ++k) {
      period[k] = _mm256_set1_pd(mi.period[k]);
      inv_period[k] = _mm256_set1_pd(mi.inv_period[k]);
    }
  }
  __attribute__((always_inline)) inline __m256d apply(__m256d d, int k) const {
    const __m256d n = _mm256_round_pd(_mm256_mul_pd(d, inv_period[k]), _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC);
    return _mm256_fnmadd_pd(period[k], n, d);
  }
};

// Sum of the four lanes, always in the same order.
__attribute__((always_inline)) inline double hsum(__m256d v) {
  const __m128d lo = _mm256_castpd256_pd128(v), hi = _mm256_extractf128_pd(v, 1);
  const __m128d s = _mm_add_pd(lo, hi);  // (l0 + l2, l1 + l3)
  return _mm_cvtsd_f64(_mm_add_sd(s, _mm_unpackhi_pd(s, s)));
}

// Calls group(q, keep, masked) for a row's neighbours idx[k0..k1) four at a
// time; in the tail (1-3 left) the last index is repeated and `keep` zeroes
// the extra lanes (masked = true).
template <class Group>
__attribute__((always_inline)) inline void for_each_group(const std::uint32_t* idx, std::uint32_t k,
                                                          std::uint32_t k1, Group& group) {
  const __m256d all = _mm256_castsi256_pd(_mm256_set1_epi64x(-1));
  for (; k + 8 <= k1; k += 8) {
    group(idx + k, all, false);
    group(idx + k + 4, all, false);
  }
  for (; k + 4 <= k1; k += 4) group(idx + k, all, false);
  if (k < k1) {
    const std::uint32_t left = k1 - k;
    std::uint32_t q[4];
    for (std::uint32_t j = 0; j < 4; ++j) q[j] = idx[k + (j < left ? j : left - 1)];
    const __m256d lane = _mm256_set_pd(3.0, 2.0, 1.0, 0.0);
    group(q, _mm256_cmp_pd(lane, _mm256_set1_pd(static_cast<double>(left)), _CMP_LT_OQ), true);
  }
}

// Uniform: every blob has the width of b.uniform_beta and the records' fourth
// field is mc (x, y, z, mc), so a neighbour is one load; else (x, y, z, beta)
// plus mc from its own array.
template <bool Periodic, bool Uniform>
void density_rows_impl(std::size_t r0, std::size_t r1, const std::uint32_t* off, const std::uint32_t* idx,
                       const BlobArrays& b, const MinimumImage& mi, double* rho, double* gx, double* gy, double* gz) {
  const double* rec = b.xyzb;
  const Image4 img(mi);
  const __m256d minus_two = _mm256_set1_pd(-2.0);
  const __m256d uniform_beta = _mm256_set1_pd(b.uniform_beta);
  for (std::size_t p = r0; p < r1; ++p) {
    const __m256d xp = _mm256_set1_pd(rec[4 * p]), yp = _mm256_set1_pd(rec[4 * p + 1]),
                  zp = _mm256_set1_pd(rec[4 * p + 2]);
    __m256d ar = _mm256_setzero_pd(), ax = ar, ay = ar, az = ar;
    // One group of four neighbours q[0..3]; `keep` masks unused lanes (tail only).
    auto group = [&](const std::uint32_t q[4], __m256d keep, bool masked) __attribute__((always_inline)) {
      __m256d qx, qy, qz, bq, mq;
      if constexpr (Uniform) {
        load_transposed(rec, q[0], q[1], q[2], q[3], qx, qy, qz, mq);
        bq = uniform_beta;
      } else {
        load_transposed(rec, q[0], q[1], q[2], q[3], qx, qy, qz, bq);
        mq = _mm256_set_pd(b.mc[q[3]], b.mc[q[2]], b.mc[q[1]], b.mc[q[0]]);
      }
      __m256d dx = _mm256_sub_pd(xp, qx), dy = _mm256_sub_pd(yp, qy), dz = _mm256_sub_pd(zp, qz);
      if constexpr (Periodic) {
        dx = img.apply(dx, 0);
        dy = img.apply(dy, 1);
        dz = img.apply(dz, 2);
      }
      const __m256d d2 = _mm256_fmadd_pd(dz, dz, _mm256_fmadd_pd(dy, dy, _mm256_mul_pd(dx, dx)));
      // exp(-bq d2); the sign flip by xor is exact and runs beside the multiply's latency.
      const __m256d nbq = _mm256_xor_pd(bq, _mm256_set1_pd(-0.0));
      const Exp4 ex = exp_nonpositive4(_mm256_mul_pd(nbq, d2));
      __m256d ms = _mm256_mul_pd(mq, ex.scale);  // w = poly x (mq 2^k), c = -2 bq w
      if (masked) ms = _mm256_and_pd(ms, keep);
      const __m256d w = _mm256_mul_pd(ex.poly, ms);
      const __m256d c = _mm256_mul_pd(ex.poly, _mm256_mul_pd(_mm256_mul_pd(minus_two, bq), ms));
      ar = _mm256_add_pd(ar, w);
      ax = _mm256_fmadd_pd(c, dx, ax);
      ay = _mm256_fmadd_pd(c, dy, ay);
      az = _mm256_fmadd_pd(c, dz, az);
    };
    for_each_group(idx, off[p], off[p + 1], group);
    rho[p] = b.mc[p] + hsum(ar);  // self term: w_pp = mc_p
    gx[p] = hsum(ax);
    gy[p] = hsum(ay);
    gz[p] = hsum(az);
  }
}

template <bool Periodic>
void gather_rows_impl(std::size_t r0, std::size_t r1, const std::uint32_t* off, const std::uint32_t* idx,
                      const BlobArrays& b, const double* xyza, const MinimumImage& mi, double* sx, double* sy,
                      double* sz, double* wsum, double* wr2) {
  const Image4 img(mi);
  for (std::size_t r = r0; r < r1; ++r) {
    const __m256d xr = _mm256_set1_pd(xyza[4 * r]), yr = _mm256_set1_pd(xyza[4 * r + 1]),
                  zr = _mm256_set1_pd(xyza[4 * r + 2]);
    const __m256d minus_br = _mm256_set1_pd(-(b.uniform_beta > 0.0 ? b.uniform_beta : b.xyzb[4 * r + 3]));
    __m256d ax = _mm256_setzero_pd(), ay = ax, az = ax, ws = ax, w2 = ax;
    auto group = [&](const std::uint32_t q[4], __m256d keep, bool masked) __attribute__((always_inline)) {
      __m256d px, py, pz, ap;
      load_transposed(xyza, q[0], q[1], q[2], q[3], px, py, pz, ap);
      __m256d dx = _mm256_sub_pd(px, xr), dy = _mm256_sub_pd(py, yr), dz = _mm256_sub_pd(pz, zr);
      if constexpr (Periodic) {
        dx = img.apply(dx, 0);
        dy = img.apply(dy, 1);
        dz = img.apply(dz, 2);
      }
      const __m256d d2 = _mm256_fmadd_pd(dz, dz, _mm256_fmadd_pd(dy, dy, _mm256_mul_pd(dx, dx)));
      const Exp4 ex = exp_nonpositive4(_mm256_mul_pd(minus_br, d2));
      __m256d as = _mm256_mul_pd(ap, ex.scale);  // w = poly x (a_p 2^k)
      if (masked) as = _mm256_and_pd(as, keep);
      const __m256d w = _mm256_mul_pd(ex.poly, as);
      ax = _mm256_fmadd_pd(w, dx, ax);
      ay = _mm256_fmadd_pd(w, dy, ay);
      az = _mm256_fmadd_pd(w, dz, az);
      ws = _mm256_add_pd(ws, w);
      w2 = _mm256_fmadd_pd(w, d2, w2);
    };
    for_each_group(idx, off[r], off[r + 1], group);
    // mc_r is common to the row; self term: w_rr = a_r mc_r, zero displacement.
    const double mr = b.mc[r];
    sx[r] = mr * hsum(ax);
    sy[r] = mr * hsum(ay);
    sz[r] = mr * hsum(az);
    wsum[r] = mr * (hsum(ws) + xyza[4 * r + 3]);
    wr2[r] = mr * hsum(w2);
  }
}

}  // namespace

void density_rows(std::size_t r0, std::size_t r1, const std::uint32_t* offsets, const std::uint32_t* indices,
                  const BlobArrays& b, const MinimumImage& mi, double* rho, double* gx, double* gy, double* gz) {
  const bool uniform = b.uniform_beta > 0.0;
  if (mi.any && uniform) density_rows_impl<true, true>(r0, r1, offsets, indices, b, mi, rho, gx, gy, gz);
  else if (mi.any) density_rows_impl<true, false>(r0, r1, offsets, indices, b, mi, rho, gx, gy, gz);
  else if (uniform) density_rows_impl<false, true>(r0, r1, offsets, indices, b, mi, rho, gx, gy, gz);
  else density_rows_impl<false, false>(r0, r1, offsets, indices, b, mi, rho, gx, gy, gz);
}

void gather_rows(std::size_t r0, std::size_t r1, const std::uint32_t* offsets, const std::uint32_t* indices,
                 const BlobArrays& b, const double* xyza, const MinimumImage& mi, double* sx, double* sy, double* sz,
                 double* wsum, double* wr2) {
  if (mi.any) gather_rows_impl<true>(r0, r1, offsets, indices, b, xyza, mi, sx, sy, sz, wsum, wr2);
  else gather_rows_impl<false>(r0, r1, offsets, indices, b, xyza, mi, sx, sy, sz, wsum, wr2);
}

}  // namespace otfp::detail::avx2
