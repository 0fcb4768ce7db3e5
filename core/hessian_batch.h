// Batched Gauss-Newton matrix of the voxel stream (core/voxel_stream.h).
//
// For DSR (and APE), one voxel observed by frames a = 0..k-1 with Jacobians J_a adds
//   H_ab += (delta_ab * diagonal + shared) J_a^T J_b        (DSR: 1 and -1/k)
// to every pair of its observers: k(k+1)/2 6x6 blocks. Added voxel by voxel, every one of
// those multiply-adds loads and stores an element of H. Neighbouring voxels mostly have
// the same observers, so a batch of voxels is grouped by observer set, and for each group
// and pair (a, b) the kernel sums J_a^T J_b over the group's voxels in registers before
// adding it, scaled, to H once:
//   H_ab += (delta_ab * diagonal + shared) sum_{voxels v of the group} J_av^T J_bv.
// Same sums as voxel by voxel, added in another order. The batch stores a voxel's k
// Jacobians contiguously (6k doubles, its row S_v = [J_0v ... J_{k-1,v}]), so the AVX2
// kernel reads the columns of two blocks (12 doubles, 3 registers) at once with no
// padding lane: 3 rows x 12 columns per tile (core/kernels_avx2.cc).
//
// Terms with photometric parameters (docs/design.md section 2.8) have 8 parameters per
// frame: their rows hold wide Jacobians J'_a = [a_a J_a, a_a I_a, 1] (8k doubles, the
// batch's wide_jac) and the same form holds with 8 x 8 blocks; every kernel has a width-8
// variant (two AVX2 registers, or one AVX-512 register, per block row).
//
// The slow twin is the per-voxel AddOuter path of the same term (tests compare them).
#ifndef DSR_CORE_HESSIAN_BATCH_H_
#define DSR_CORE_HESSIAN_BATCH_H_

#include <cstdint>

#include "core/observation.h"

namespace dsr {

struct VoxelBatch;

// The per-voxel form of a term's Gauss-Newton matrix, given the voxel's k observers.
struct HessianWeights {
  double diagonal = 0.0;  // added to the a == b blocks only
  double shared = 0.0;    // added to every block
};

// Adds the Gauss-Newton terms of every voxel of `batch` (which must hold Jacobians) to
// the row-major n x n matrix `h` (n = width m): the blocks (fa, fb) with fa <= fb, diagonal
// blocks whole. `weights[k]` is the form for voxels with k observers (k = 2..kMaxFrames).
// With `gradient` (n entries), also g_f += r J for every observation, from the
// batch's residuals, summed per group first like H. `width` 6 reads the batch's pose
// Jacobians (jac), 8 its wide ones (wide_jac).
// Uses the kernel path of ActiveKernelPath() (core/voxel_stream.h).
void AddBatchHessian(const VoxelBatch& batch,
                     const HessianWeights* weights,
                     double* h,
                     int n,
                     double* gradient = nullptr,
                     int width = 6);

namespace internal {

// One group of a batch: `num_rows` voxels with the same k observers `frame[0..k)`;
// rows[r] points at voxel r's k Jacobians, its row S_r = [J_0 ... J_{k-1}] (width k
// doubles; width 6 or 8).
struct HessianGroup {
  const double* const* rows;
  int num_rows;
  int k;
  const int* frame;
  int width;
};

// Adds scale_ab * sum_r J_a^T J_b to block (frame[a], frame[b]) (width x width, at rows
// and columns width * frame) of the row-major n x n `h` for a <= b, with scale_ab = shared
// + (a == b ? diagonal : 0). Every kernel path (core/kernels_avx2.h, core/kernels_avx512.h)
// has this contract.
void AddGroupHessianPortable(const HessianGroup& group,
                             const HessianWeights& weights,
                             double* h,
                             int n);

// Adds sum_r residuals[r][a] J_a (row r's a-th Jacobian) to the width entries of frame[a]
// in `g`, for every a. `residuals[r]` points at voxel r's k residuals.
void AddGroupGradientPortable(const HessianGroup& group, const double* const* residuals, double* g);

}  // namespace internal
}  // namespace dsr

#endif  // DSR_CORE_HESSIAN_BATCH_H_
