#define OTFP_KERNEL_NS generic
#include "pair_kernels_impl.inc"
