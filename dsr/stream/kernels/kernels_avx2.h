// The AVX2 + FMA implementations of the hot kernels (stream/kernels/kernels_avx2.cc): the batch
// sampler of stream/voxel_stream.h and the group kernels of stream/hessian_batch.h. Internal:
// callers go through SampleVoxelBatch and AddBatchHessian, which pick the kernel path.
//
// Only these functions are compiled for AVX2 (a function attribute), so the library
// still runs on any x86-64 CPU: the caller's KernelPath picks them (util/cpu.h checks the
// CPU). Eigen is not compiled for AVX anywhere, so its alignment matches Debian's Ceres.
#ifndef DSR_STREAM_KERNELS_KERNELS_AVX2_H_
#define DSR_STREAM_KERNELS_KERNELS_AVX2_H_

#include <cstdint>
#include <vector>

#include "dsr/util/cpu.h"

#ifdef DSR_HAVE_X86_KERNELS
#define DSR_HAVE_AVX2_KERNELS 1
#endif

namespace dsr {

struct CandidateSet;
struct HessianWeights;
struct PosedFrame;
struct VoxelBatch;

namespace internal {

struct HessianGroup;  // stream/hessian_batch.h

#ifdef DSR_HAVE_AVX2_KERNELS
int64_t SampleVoxelBatchAvx2(const std::vector<PosedFrame>& posed,
                             const CandidateSet& candidates,
                             int64_t v,
                             int64_t end,
                             bool with_jacobian,
                             VoxelBatch* batch);

void AddGroupHessianAvx2(const HessianGroup& group,
                         const HessianWeights& weights,
                         double* h,
                         int n);
// AddGroupGradientPortable's contract (stream/hessian_batch.h); the AVX-512 path uses it too.
void AddGroupGradientAvx2(const HessianGroup& group, const double* const* residuals, double* g);
#endif

}  // namespace internal
}  // namespace dsr

#endif  // DSR_STREAM_KERNELS_KERNELS_AVX2_H_
