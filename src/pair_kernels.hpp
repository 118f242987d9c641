#pragma once
// The two pair sweeps of the exact gradient of (28) over a neighbour list, on
// plain arrays so that the inner loops vectorise. On x86-64 an AVX2/FMA build
// of the kernels is picked at run time, so the library needs no -march flag
// (docs/method_notes.md#solver-facts: no -march=native against Debian's Ceres).
#include <cstddef>
#include <cstdint>

namespace otfp::detail {

struct BlobArrays {
  const double* px;
  const double* py;
  const double* pz;
  const double* beta;  // 1/s^2
  const double* mc;    // m (beta/pi)^(d/2): the kernel's peak value
};

// Minimum image along axes with period L > 0 (L = 0: not periodic).
struct MinimumImage {
  double period[3] = {0.0, 0.0, 0.0};
  double inv_period[3] = {0.0, 0.0, 0.0};
  bool any = false;
};

// Sweep 1, rows [r0, r1): rho_p = mc_p + sum_q mc_q exp(-beta_q r^2) and
// grad rho(x_p) = sum_q -2 beta_q w_pq (x_p - x_q).
void density_rows(std::size_t r0, std::size_t r1, const std::uint32_t* offsets, const std::uint32_t* indices,
                  const BlobArrays& b, const MinimumImage& mi, double* rho, double* gx, double* gy, double* gz);

// Sweep 2, rows [r0, r1): with a_p = m_p/rho_p and w_pr = a_p mc_r exp(-beta_r |x_p - x_r|^2),
// s_r = sum_p w_pr (x_p - x_r), wsum_r = sum_p w_pr (self term included),
// wr2_r = sum_p w_pr |x_p - x_r|^2.
void gather_rows(std::size_t r0, std::size_t r1, const std::uint32_t* offsets, const std::uint32_t* indices,
                 const BlobArrays& b, const MinimumImage& mi, const double* a, double* sx, double* sy, double* sz,
                 double* wsum, double* wr2);

// "avx2+fma" or "generic": which kernel build runs on this CPU.
const char* kernel_isa();

}  // namespace otfp::detail
