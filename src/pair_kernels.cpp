// Run-time dispatch between the generic and the AVX2/FMA build of the pair
// kernels, as the instruction-set switch (src/isa.hpp) says.
#include "pair_kernels.hpp"

#include <cstdio>
#include <cstdlib>
#include <stdexcept>
#include <string>

#include "isa.hpp"

namespace otfp::detail {

namespace generic {
void density_rows(std::size_t, std::size_t, const std::uint32_t*, const std::uint32_t*, const BlobArrays&,
                  const MinimumImage&, double*, double*, double*, double*);
void gather_rows(std::size_t, std::size_t, const std::uint32_t*, const std::uint32_t*, const BlobArrays&,
                 const double*, const MinimumImage&, double*, double*, double*, double*, double*);
}  // namespace generic
#ifdef OTFP_HAVE_AVX2_KERNELS
namespace avx2 {
void density_rows(std::size_t, std::size_t, const std::uint32_t*, const std::uint32_t*, const BlobArrays&,
                  const MinimumImage&, double*, double*, double*, double*);
void gather_rows(std::size_t, std::size_t, const std::uint32_t*, const std::uint32_t*, const BlobArrays&,
                 const double*, const MinimumImage&, double*, double*, double*, double*, double*);
}  // namespace avx2
#endif

void check_rows(std::size_t r0, std::size_t r1, const std::uint32_t* offsets, const std::uint32_t* indices,
                const BlobArrays& b) {
  auto fail = [&](const std::string& what) {
    throw std::out_of_range("pair sweep over rows [" + std::to_string(r0) + ", " + std::to_string(r1) + ") of " +
                            std::to_string(b.count) + " records: " + what);
  };
  if (r1 < r0 || r1 > b.count) fail("rows beyond the records");
  for (std::size_t r = r0; r < r1; ++r) {
    if (offsets[r + 1] < offsets[r]) fail("offsets decrease at row " + std::to_string(r));
    for (std::uint32_t k = offsets[r]; k < offsets[r + 1]; ++k)
      if (indices[k] >= b.count)
        fail("row " + std::to_string(r) + " lists neighbour " + std::to_string(indices[k]));
  }
}

#ifdef OTFP_CHECK_KERNEL_BOUNDS
namespace {
// The sweeps run inside OpenMP regions, which an exception may not leave: a
// list beyond its records ends the process with the reason on stderr, as an
// ASan report would.
void check_rows_or_abort(std::size_t r0, std::size_t r1, const std::uint32_t* offsets, const std::uint32_t* indices,
                         const BlobArrays& b) {
  try {
    check_rows(r0, r1, offsets, indices, b);
  } catch (const std::out_of_range& e) {
    std::fprintf(stderr, "otfp: internal error: %s\n", e.what());
    std::abort();
  }
}
}  // namespace
#endif

void density_rows(std::size_t r0, std::size_t r1, const std::uint32_t* offsets, const std::uint32_t* indices,
                  const BlobArrays& b, const MinimumImage& mi, double* rho, double* gx, double* gy, double* gz) {
#ifdef OTFP_CHECK_KERNEL_BOUNDS
  check_rows_or_abort(r0, r1, offsets, indices, b);
#endif
#ifdef OTFP_HAVE_AVX2_KERNELS
  if (use_avx2_fma()) return avx2::density_rows(r0, r1, offsets, indices, b, mi, rho, gx, gy, gz);
#endif
  generic::density_rows(r0, r1, offsets, indices, b, mi, rho, gx, gy, gz);
}

void gather_rows(std::size_t r0, std::size_t r1, const std::uint32_t* offsets, const std::uint32_t* indices,
                 const BlobArrays& b, const double* xyza, const MinimumImage& mi, double* sx, double* sy, double* sz,
                 double* wsum, double* wr2) {
#ifdef OTFP_CHECK_KERNEL_BOUNDS
  check_rows_or_abort(r0, r1, offsets, indices, b);
#endif
#ifdef OTFP_HAVE_AVX2_KERNELS
  if (use_avx2_fma()) return avx2::gather_rows(r0, r1, offsets, indices, b, xyza, mi, sx, sy, sz, wsum, wr2);
#endif
  generic::gather_rows(r0, r1, offsets, indices, b, xyza, mi, sx, sy, sz, wsum, wr2);
}

}  // namespace otfp::detail
