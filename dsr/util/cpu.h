// Which implementation of the hot kernels runs (the voxel sampler and the batched
// Gauss-Newton kernel of stream/), and what this build and CPU can run.
//
// kAvx2: both in AVX2 + FMA; kAvx512: the AVX2 sampler with an AVX-512 Gauss-Newton kernel;
// kPortable: plain C++, the twin the tests compare the others with; kAuto: the widest the CPU
// runs. Only the kernels themselves are compiled for AVX2 or AVX-512 (function attributes),
// so the rest of the build stays baseline x86-64 and runs on any x86-64 CPU. All paths
// evaluate the same formulas; results agree to rounding (about 1e-15 relative).
//
// The choice is an option (SolveOptions::kernels, StreamContext::kernels), not process state.
#ifndef DSR_UTIL_CPU_H_
#define DSR_UTIL_CPU_H_

#include <string>

// The SIMD kernels exist in builds for x86-64 with GCC or Clang (they need the target
// attribute and __builtin_cpu_supports).
#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
#define DSR_HAVE_X86_KERNELS 1
#endif

namespace dsr {

enum class KernelPath { kAuto, kPortable, kAvx2, kAvx512 };

// True when this build has the kernels of `path` and the CPU runs them (kAuto and
// kPortable: always).
bool KernelPathAvailable(KernelPath path);
// kAuto: the widest available path; any other path is returned as it is.
KernelPath ResolveKernelPath(KernelPath path);

// "auto", "portable", "avx2", "avx512".
const char* KernelPathToString(KernelPath path);
// False for any other name.
bool StringToKernelPath(const std::string& name, KernelPath* path);
// The names StringToKernelPath accepts, "auto|portable|avx2|avx512".
std::string KernelPathNames();

}  // namespace dsr

#endif  // DSR_UTIL_CPU_H_
