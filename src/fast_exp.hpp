#pragma once
// exp(a) for a <= 0, branch-free so that pair loops vectorise. Cody-Waite
// reduction a = k ln2 + r, |r| <= ln2/2, degree-12 Taylor polynomial (relative
// error below 2e-16 on the reduced range), scale by 2^k through the exponent
// bits. Arguments below -700 are clamped (the kernel is then ~1e-304).
#include <bit>
#include <cstdint>

namespace otfp::detail {

__attribute__((always_inline)) inline double exp_nonpositive(double a) {
  // Arithmetic blend rather than a select: GCC 12 does not vectorise this loop
  // body when the clamp is written as a conditional expression.
  const double below = a < -700.0 ? 1.0 : 0.0;
  a += below * (-700.0 - a);
  constexpr double kLog2e = 1.4426950408889634;
  constexpr double kLn2Hi = 6.93147180369123816490e-01;
  constexpr double kLn2Lo = 1.90821492927058770002e-10;
  constexpr double kShift = 0x1.8p52;  // adding it rounds to an integer held in the low mantissa bits
  const double t = a * kLog2e + kShift;
  const double k = t - kShift;
  const double r = (a - k * kLn2Hi) - k * kLn2Lo;
  double p = 1.0 / 479001600.0;
  p = p * r + 1.0 / 39916800.0;
  p = p * r + 1.0 / 3628800.0;
  p = p * r + 1.0 / 362880.0;
  p = p * r + 1.0 / 40320.0;
  p = p * r + 1.0 / 5040.0;
  p = p * r + 1.0 / 720.0;
  p = p * r + 1.0 / 120.0;
  p = p * r + 1.0 / 24.0;
  p = p * r + 1.0 / 6.0;
  p = p * r + 0.5;
  p = p * r + 1.0;
  p = p * r + 1.0;
  // The low bits of t hold k (two's complement); build the double 2^k.
  const std::uint64_t kbits = std::bit_cast<std::uint64_t>(t);
  const std::uint64_t scale = (kbits + 1023u) << 52;
  return p * std::bit_cast<double>(scale);
}

}  // namespace otfp::detail
