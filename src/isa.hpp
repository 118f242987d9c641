#pragma once
// Internal: the one switch that picks the instruction-set build of every SIMD
// kernel, the pair sweeps of the functional (src/pair_kernels.cpp) and the
// neighbour search (src/neighbor_list.cpp). The library needs no -march flag
// (docs/method_notes.md#solver-facts): on x86-64 the AVX2 builds are compiled
// with their own flags (src/CMakeLists.txt, OTFP_HAVE_AVX2_KERNELS) and run
// where the CPU has the instructions; the portable builds run elsewhere.
//
// Decided once, at the first kernel call: what the CPU offers, unless the
// environment variable OTFP_NEIGHBOR_KERNELS=generic (its name from the days
// it chose only the neighbour search) forces the portable builds of every
// kernel. Tests and benchmarks switch builds with set_kernel_isa.
namespace otfp::detail {

// Kernel builds: Auto picks the AVX2 builds where the CPU has them, else Generic.
enum class KernelIsa { Auto, Generic, Avx2 };

// Tests and benchmarks: force the build of every kernel family (Avx2 falls
// back to Generic where the CPU or the compiler lacks it; Auto: what the CPU
// offers). Replaces the environment's choice. Not thread-safe; call between
// evaluations.
void set_kernel_isa(KernelIsa isa);
// Which builds run now: "avx2+fma" (every kernel), "avx2" (a CPU with AVX2 but
// no FMA: the neighbour search only) or "generic".
const char* kernel_isa();

// For the dispatchers: whether to run the AVX2 build of
bool use_avx2();      // the neighbour search (AVX2, no FMA: the list does not depend on the build)
bool use_avx2_fma();  // the pair sweeps (AVX2 and FMA)

// The choice an environment value asks for: "generic" -> Generic, anything
// else (null: unset) -> Auto.
KernelIsa kernel_isa_from_env(const char* value);

}  // namespace otfp::detail
