// Compiled with -mavx2 -mfma (src/CMakeLists.txt); used only when the CPU has both.
#define OTFP_KERNEL_NS avx2
#include "pair_kernels_impl.inc"
