// The AVX-512 group kernel of the batched Gauss-Newton matrix (stream/kernels/kernels_avx512.cc).
// Internal: callers go through AddBatchHessian, which picks the kernel path
// (util/cpu.h: KernelPath::kAvx512 = the AVX2 sampler with this kernel).
//
// Only this function is compiled for AVX-512 (a function attribute), so the library still
// runs on any x86-64 CPU: the caller's KernelPath picks it (util/cpu.h checks the CPU).
#ifndef DSR_STREAM_KERNELS_KERNELS_AVX512_H_
#define DSR_STREAM_KERNELS_KERNELS_AVX512_H_

#include "dsr/stream/kernels/kernels_avx2.h"

#ifdef DSR_HAVE_AVX2_KERNELS
#define DSR_HAVE_AVX512_KERNELS 1
#endif

namespace dsr {

struct HessianWeights;

namespace internal {

struct HessianGroup;  // stream/hessian_batch.h

#ifdef DSR_HAVE_AVX512_KERNELS
// Same contract as AddGroupHessianPortable (stream/hessian_batch.h).
void AddGroupHessianAvx512(const HessianGroup& group,
                           const HessianWeights& weights,
                           double* h,
                           int n);
#endif

}  // namespace internal
}  // namespace dsr

#endif  // DSR_STREAM_KERNELS_KERNELS_AVX512_H_
