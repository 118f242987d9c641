#pragma once
// Internal: the inner loops of NeighborList::build (src/neighbor_list.cpp),
// compiled twice from src/neighbor_kernels_impl.inc: generic, and with AVX2
// (src/neighbor_kernels_avx2.cpp, chosen at run time by src/isa.hpp). No FMA:
// both builds round every squared distance the same way, so the list does not
// depend on the instruction set.
#include <cstddef>
#include <cstdint>

namespace otfp::neighbor_kernels {

// Output arrays of both functions need room for len + 8 entries. avx2: run
// the AVX2 build (the caller asks detail::use_avx2(), src/isa.hpp, once per
// list build).

// Appends to out the indices b + j, j < e - b, of the points (x, y, z)[b + j]
// + shift whose squared gap to the box [lo, hi] is <= r2max (g2: scratch of
// e - b); returns how many.
std::size_t box_candidates(bool avx2, const double* x, const double* y, const double* z, std::uint32_t b,
                           std::uint32_t e, const double shift[3], const double lo[3], const double hi[3],
                           double r2max, double* g2, std::uint32_t* out);

// d2[j] = |q - c_j|^2 for j < len, and appends to out the ids[j] with
// d2[j] <= r2 and ids[j] != self; returns how many.
std::size_t row_hits(bool avx2, const double* cx, const double* cy, const double* cz, const std::uint32_t* ids,
                     std::size_t len, double qx, double qy, double qz, double r2, std::uint32_t self, double* d2,
                     std::uint32_t* out);

}  // namespace otfp::neighbor_kernels
