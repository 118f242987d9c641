#pragma once
// The two pair sweeps of the exact gradient of (28) over a neighbour list, on
// packed per-particle records so that a neighbour costs one 32-byte load
// instead of one gather per field. On x86-64 a hand-vectorised AVX2/FMA build
// (pair_kernels_avx2.cpp) is picked at run time by the instruction-set switch
// (src/isa.hpp), so the library needs no -march flag
// (docs/method_notes.md#solver-facts: no -march=native against Debian's
// Ceres); elsewhere the portable build (pair_kernels_generic.cpp).
// Both evaluate the same exp polynomial (in another order) and agree to
// round-off; each sums a row in a fixed order, whatever the thread count.
#include <cstddef>
#include <cstdint>
#include <vector>

namespace otfp::detail {

struct BlobArrays {
  const double* xyzb;         // 4 per particle, 32-byte aligned: x, y, z, beta = 1/s^2
  const double* mc;           // m (beta/pi)^(d/2): the kernel's peak value
  double uniform_beta = 0.0;  // > 0: every blob has this beta, and xyzb holds x, y, z, mc instead
  std::size_t count = 0;      // records in xyzb, mc (and a sweep's xyza): the list's indices lie below it
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

// Sweep 2, rows [r0, r1): with a_p = m_p/rho_p (xyza: 4 per particle, 32-byte
// aligned: x, y, z, a) and w_pr = a_p mc_r exp(-beta_r |x_p - x_r|^2),
// s_r = sum_p w_pr (x_p - x_r), wsum_r = sum_p w_pr (self term included),
// wr2_r = sum_p w_pr |x_p - x_r|^2.
void gather_rows(std::size_t r0, std::size_t r1, const std::uint32_t* offsets, const std::uint32_t* indices,
                 const BlobArrays& b, const double* xyza, const MinimumImage& mi, double* sx, double* sy, double* sz,
                 double* wsum, double* wr2);

// Throws std::out_of_range unless rows [r0, r1) and every neighbour index of
// theirs lie below b.count and the offsets do not decrease: the check the
// sanitizer build makes before each sweep (OTFP_CHECK_KERNEL_BOUNDS), where
// the AVX2 sweeps are compiled without AddressSanitizer (src/CMakeLists.txt):
// ASan's check of each of their loads made them the sanitizer pass's largest
// cost, and an index within range is what keeps every record load in bounds.
void check_rows(std::size_t r0, std::size_t r1, const std::uint32_t* offsets, const std::uint32_t* indices,
                const BlobArrays& b);

// A 32-byte aligned view into a vector of doubles sized for n records of 4
// (the vector's own storage is only 16-byte aligned).
inline double* packed_records(std::vector<double>& storage, std::size_t n) {
  storage.resize(4 * n + 4);
  auto addr = reinterpret_cast<std::uintptr_t>(storage.data());
  return storage.data() + ((32 - addr % 32) % 32) / sizeof(double);
}

}  // namespace otfp::detail
