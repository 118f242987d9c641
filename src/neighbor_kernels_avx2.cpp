// AVX2 build of the neighbour-search kernels (src/neighbor_kernels_impl.inc),
// compiled with -mavx2 (no FMA) and chosen at run time by src/neighbor_list.cpp.
#include <algorithm>
#include <cstddef>
#include <cstdint>

#include <immintrin.h>

namespace otfp::neighbor_kernels::avx2 {
#include "neighbor_kernels_impl.inc"
}  // namespace otfp::neighbor_kernels::avx2
