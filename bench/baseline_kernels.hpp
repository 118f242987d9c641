#pragma once
// The pair kernels as they were before issue 15 (see baseline_kernels.cpp).
#include <cstddef>
#include <cstdint>

#include "pair_kernels.hpp"

namespace otfp::bench_baseline {

struct BaselineArrays {
  const double* px;
  const double* py;
  const double* pz;
  const double* beta;  // 1/s^2
  const double* mc;    // m (beta/pi)^(d/2)
};

void density_rows(std::size_t r0, std::size_t r1, const std::uint32_t* offsets, const std::uint32_t* indices,
                  const BaselineArrays& b, const detail::MinimumImage& mi, double* rho, double* gx, double* gy,
                  double* gz);
void gather_rows(std::size_t r0, std::size_t r1, const std::uint32_t* offsets, const std::uint32_t* indices,
                 const BaselineArrays& b, const detail::MinimumImage& mi, const double* a, double* sx, double* sy,
                 double* sz, double* wsum, double* wr2);

}  // namespace otfp::bench_baseline
