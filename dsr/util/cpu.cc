// CPU feature checks and kernel-path names (util/cpu.h).
#include "dsr/util/cpu.h"

#include "dsr/util/option_fields.h"

namespace dsr {
namespace {

constexpr KernelPath kAllPaths[] = {KernelPath::kAuto, KernelPath::kPortable, KernelPath::kAvx2,
                                    KernelPath::kAvx512};

bool CpuHasAvx2Fma() {
#ifdef DSR_HAVE_X86_KERNELS
  __builtin_cpu_init();
  return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
#else
  return false;
#endif
}

bool CpuHasAvx512() {
#ifdef DSR_HAVE_X86_KERNELS
  __builtin_cpu_init();
  return __builtin_cpu_supports("avx512f") && CpuHasAvx2Fma();
#else
  return false;
#endif
}

}  // namespace

bool KernelPathAvailable(KernelPath path) {
  switch (path) {
    case KernelPath::kAuto:
    case KernelPath::kPortable:
      return true;
    case KernelPath::kAvx2:
      return CpuHasAvx2Fma();
    case KernelPath::kAvx512:
      return CpuHasAvx512();
  }
  return false;
}

KernelPath ResolveKernelPath(KernelPath path) {
  if (path != KernelPath::kAuto) return path;
  static const KernelPath widest = CpuHasAvx512()   ? KernelPath::kAvx512
                                   : CpuHasAvx2Fma() ? KernelPath::kAvx2
                                                     : KernelPath::kPortable;
  return widest;
}

const char* KernelPathToString(KernelPath path) {
  switch (path) {
    case KernelPath::kAuto:
      return "auto";
    case KernelPath::kPortable:
      return "portable";
    case KernelPath::kAvx2:
      return "avx2";
    case KernelPath::kAvx512:
      return "avx512";
  }
  return "?";
}

bool StringToKernelPath(const std::string& name, KernelPath* path) {
  return FindNamed(name, kAllPaths, KernelPathToString, path);
}

std::string KernelPathNames() {
  std::string names;
  for (KernelPath path : kAllPaths) {
    if (!names.empty()) names += '|';
    names += KernelPathToString(path);
  }
  return names;
}

}  // namespace dsr
