// Batched Gauss-Newton matrix of the voxel stream (stream/voxel_stream.h).
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
// padding lane: 3 rows x 12 columns per tile (stream/kernels/kernels_avx2.cc).
//
// Terms with photometric parameters (docs/design.md section 2.8) have 8 parameters per
// frame: their rows hold wide Jacobians J'_a = [a_a J_a, a_a I_a, 1] (8k doubles, the
// batch's wide_jac) and the same form holds with 8 x 8 blocks; every kernel has a width-8
// variant (two AVX2 registers, or one AVX-512 register, per block row).
//
// The slow twin is the per-voxel AddOuter path of the same term (tests compare them).
#ifndef DSR_STREAM_HESSIAN_BATCH_H_
#define DSR_STREAM_HESSIAN_BATCH_H_

#include <cstdint>

#include "dsr/model/observation.h"
#include "dsr/util/cpu.h"

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
// With `projection_factors` (one u_f > 0 per frame), `weights` is not read: every voxel
// has the form of a weighted mean's projection instead,
//   H_ab += (delta_ab - u_a u_b / sum_c u_c^2) J_a^T J_b   (c over the voxel's observers),
// which is DSR's with photometric parameters (u = 1 / gain; docs/design.md 2.8) and the
// plain form (1, -1/k) when every u is 1. Voxels with the same observers share it.
// `path`: the kernel to run (util/cpu.h; kAuto: the widest available).
void AddBatchHessian(KernelPath path,
                     const VoxelBatch& batch,
                     const HessianWeights* weights,
                     double* h,
                     int n,
                     double* gradient = nullptr,
                     int width = 6,
                     const double* projection_factors = nullptr);

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
  // Null, or per observer f_a: the shared weight of block (a, b) is then shared f_a f_b.
  const double* factor = nullptr;
};

// The scale of block (a, b) (positions in the group): shared (times f_a f_b with factors)
// plus diagonal when a == b. Every kernel scales its sums by this.
inline double BlockScale(const HessianGroup& group, const HessianWeights& weights, int a, int b) {
  const double shared =
      group.factor != nullptr ? weights.shared * group.factor[a] * group.factor[b] : weights.shared;
  return shared + (a == b ? weights.diagonal : 0.0);
}

// Adds scale_ab * sum_r J_a^T J_b to block (frame[a], frame[b]) (width x width, at rows
// and columns width * frame) of the row-major n x n `h` for a <= b, with scale_ab =
// BlockScale(group, weights, a, b). Every kernel path (stream/kernels/kernels_avx2.h,
// stream/kernels/kernels_avx512.h) has this contract.
void AddGroupHessianPortable(const HessianGroup& group,
                             const HessianWeights& weights,
                             double* h,
                             int n);

// Adds sum_r residuals[r][a] J_a (row r's a-th Jacobian) to the width entries of frame[a]
// in `g`, for every a. `residuals[r]` points at voxel r's k residuals.
void AddGroupGradientPortable(const HessianGroup& group, const double* const* residuals, double* g);

}  // namespace internal
}  // namespace dsr

#endif  // DSR_STREAM_HESSIAN_BATCH_H_
