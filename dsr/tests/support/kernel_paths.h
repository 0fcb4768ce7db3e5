// Test helper for the kernel paths of util/cpu.h: every path this CPU runs (never kAuto).
#ifndef DSR_TESTS_SUPPORT_KERNEL_PATHS_H_
#define DSR_TESTS_SUPPORT_KERNEL_PATHS_H_

#include <vector>

#include "dsr/util/cpu.h"

namespace dsr {
namespace testing_kernels {

inline std::vector<KernelPath> AvailablePaths() {
  std::vector<KernelPath> paths = {KernelPath::kPortable};
  if (KernelPathAvailable(KernelPath::kAvx2)) paths.push_back(KernelPath::kAvx2);
  if (KernelPathAvailable(KernelPath::kAvx512)) paths.push_back(KernelPath::kAvx512);
  return paths;
}

}  // namespace testing_kernels
}  // namespace dsr

#endif  // DSR_TESTS_SUPPORT_KERNEL_PATHS_H_
