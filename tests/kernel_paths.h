// Test helpers for the kernel paths of stream/voxel_stream.h: every path this CPU runs, and
// a scope that selects one and restores the previous choice.
#ifndef DSR_TESTS_KERNEL_PATHS_H_
#define DSR_TESTS_KERNEL_PATHS_H_

#include <vector>

#include "dsr/stream/voxel_stream.h"

namespace dsr {
namespace testing_kernels {

class KernelPathScope {
 public:
  explicit KernelPathScope(KernelPath path) : saved_(ActiveKernelPath()) { SetKernelPath(path); }
  ~KernelPathScope() { SetKernelPath(saved_); }
  KernelPathScope(const KernelPathScope&) = delete;
  KernelPathScope& operator=(const KernelPathScope&) = delete;

 private:
  KernelPath saved_;
};

inline std::vector<KernelPath> AvailablePaths() {
  std::vector<KernelPath> paths = {KernelPath::kPortable};
  if (KernelPathAvailable(KernelPath::kAvx2)) paths.push_back(KernelPath::kAvx2);
  if (KernelPathAvailable(KernelPath::kAvx512)) paths.push_back(KernelPath::kAvx512);
  return paths;
}

}  // namespace testing_kernels
}  // namespace dsr

#endif  // DSR_TESTS_KERNEL_PATHS_H_
