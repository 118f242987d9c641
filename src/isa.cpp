// The instruction-set switch of the SIMD kernels (src/isa.hpp).
#include "isa.hpp"

#include <cstdlib>
#include <cstring>

namespace otfp::detail {

namespace {

struct Cpu {
  bool avx2 = false;
  bool fma = false;
};

// What the CPU offers, among the builds compiled in.
const Cpu& cpu() {
  static const Cpu c = [] {
    Cpu out;
#ifdef OTFP_HAVE_AVX2_KERNELS
    out.avx2 = __builtin_cpu_supports("avx2");
    out.fma = __builtin_cpu_supports("fma");
#endif
    return out;
  }();
  return c;
}

struct Choice {
  bool avx2 = false;      // neighbour search
  bool avx2_fma = false;  // pair sweeps
};

Choice decide(KernelIsa isa) {
  Choice ch;
  ch.avx2 = isa != KernelIsa::Generic && cpu().avx2;
  ch.avx2_fma = ch.avx2 && cpu().fma;
  return ch;
}

Choice& choice() {
  static Choice ch = decide(kernel_isa_from_env(std::getenv("OTFP_NEIGHBOR_KERNELS")));
  return ch;
}

}  // namespace

KernelIsa kernel_isa_from_env(const char* value) {
  return value && std::strcmp(value, "generic") == 0 ? KernelIsa::Generic : KernelIsa::Auto;
}

void set_kernel_isa(KernelIsa isa) { choice() = decide(isa); }

const char* kernel_isa() {
  const Choice& ch = choice();
  return ch.avx2_fma ? "avx2+fma" : ch.avx2 ? "avx2" : "generic";
}

bool use_avx2() { return choice().avx2; }
bool use_avx2_fma() { return choice().avx2_fma; }

}  // namespace otfp::detail
