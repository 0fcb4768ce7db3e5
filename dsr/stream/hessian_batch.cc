#include "dsr/stream/hessian_batch.h"

#include <cstring>

#include <glog/logging.h>

#include "dsr/stream/kernels/kernels_avx2.h"
#include "dsr/stream/kernels/kernels_avx512.h"
#include "dsr/stream/voxel_stream.h"

namespace dsr {
namespace internal {

namespace {

template <int W>
void AddGroupHessianPortableOf(const HessianGroup& group,
                               const HessianWeights& weights,
                               double* h,
                               int n) {
  const int k = group.k;
  const int* frame = group.frame;
  for (int a = 0; a < k; ++a) {
    for (int b = a; b < k; ++b) {
      double sum[W][W] = {};
      for (int r = 0; r < group.num_rows; ++r) {
        const double* ja = group.rows[r] + W * a;
        const double* jb = group.rows[r] + W * b;
        for (int i = 0; i < W; ++i) {
          for (int j = 0; j < W; ++j) sum[i][j] += ja[i] * jb[j];
        }
      }
      const double scale = BlockScale(group, weights, a, b);
      for (int i = 0; i < W; ++i) {
        double* row = h + static_cast<int64_t>(W * frame[a] + i) * n + W * frame[b];
        for (int j = 0; j < W; ++j) row[j] += scale * sum[i][j];
      }
    }
  }
}

template <int W>
void AddGroupGradientPortableOf(const HessianGroup& group,
                                const double* const* residuals,
                                double* g) {
  for (int a = 0; a < group.k; ++a) {
    double sum[W] = {};
    for (int r = 0; r < group.num_rows; ++r) {
      const double w = residuals[r][a];
      const double* ja = group.rows[r] + W * a;
      for (int i = 0; i < W; ++i) sum[i] += w * ja[i];
    }
    double* ga = g + W * group.frame[a];
    for (int i = 0; i < W; ++i) ga[i] += sum[i];
  }
}

}  // namespace

void AddGroupHessianPortable(const HessianGroup& group,
                             const HessianWeights& weights,
                             double* h,
                             int n) {
  if (group.width == kWideJacobianSize) {
    AddGroupHessianPortableOf<kWideJacobianSize>(group, weights, h, n);
  } else {
    AddGroupHessianPortableOf<kJacobianSize>(group, weights, h, n);
  }
}

void AddGroupGradientPortable(const HessianGroup& group,
                              const double* const* residuals,
                              double* g) {
  if (group.width == kWideJacobianSize) {
    AddGroupGradientPortableOf<kWideJacobianSize>(group, residuals, g);
  } else {
    AddGroupGradientPortableOf<kJacobianSize>(group, residuals, g);
  }
}

}  // namespace internal

namespace {

// The group's gradient on `path`'s kernels (both SIMD paths use the AVX2 one).
void AddGroupGradient(KernelPath path,
                      const internal::HessianGroup& group,
                      const double* const* residuals,
                      double* gradient) {
#ifdef DSR_HAVE_AVX2_KERNELS
  if (path != KernelPath::kPortable) {
    internal::AddGroupGradientAvx2(group, residuals, gradient);
    return;
  }
#endif
  internal::AddGroupGradientPortable(group, residuals, gradient);
}

// The group's gradient (with `gradient`) and Gauss-Newton terms on `path`'s kernels.
void AddGroup(KernelPath path,
              const internal::HessianGroup& group,
              const double* const* residuals,
              const HessianWeights& weights,
              double* h,
              int n,
              double* gradient) {
  if (gradient != nullptr) AddGroupGradient(path, group, residuals, gradient);
#ifdef DSR_HAVE_AVX512_KERNELS
  if (path == KernelPath::kAvx512) {
    internal::AddGroupHessianAvx512(group, weights, h, n);
    return;
  }
#endif
#ifdef DSR_HAVE_AVX2_KERNELS
  if (path == KernelPath::kAvx2) {
    internal::AddGroupHessianAvx2(group, weights, h, n);
    return;
  }
#endif
  internal::AddGroupHessianPortable(group, weights, h, n);
}

}  // namespace

void AddBatchHessian(KernelPath requested,
                     const VoxelBatch& batch,
                     const HessianWeights* weights,
                     double* h,
                     int n,
                     double* gradient,
                     int width,
                     const double* projection_factors) {
  CHECK(width == kJacobianSize || width == kWideJacobianSize) << width;
  // Group the voxels by observer set: an open-addressing table (more slots than voxels),
  // groups numbered in order of first appearance, then a counting sort of the voxels.
  constexpr int kTableBits = 1 + __builtin_ctz(VoxelBatch::kMaxVoxels);
  constexpr int kTableSize = 1 << kTableBits;
  static_assert(kTableSize == 2 * VoxelBatch::kMaxVoxels, "kMaxVoxels: a power of two");
  int16_t slot_group[kTableSize];
  uint32_t slot_key[kTableSize];
  std::memset(slot_group, 0xff, sizeof(slot_group));  // -1: empty
  uint32_t group_key[VoxelBatch::kMaxVoxels];
  int group_size[VoxelBatch::kMaxVoxels];
  int16_t voxel_group[VoxelBatch::kMaxVoxels];
  int num_groups = 0;
  for (int t = 0; t < batch.num_voxels; ++t) {
    const uint32_t key = batch.observers[t];
    uint32_t s = (key * 2654435761u) >> (32 - kTableBits);  // top bits of the product
    while (slot_group[s] >= 0 && slot_key[s] != key) s = (s + 1) & (kTableSize - 1);
    if (slot_group[s] < 0) {
      slot_group[s] = static_cast<int16_t>(num_groups);
      slot_key[s] = key;
      group_key[num_groups] = key;
      group_size[num_groups] = 0;
      ++num_groups;
    }
    voxel_group[t] = slot_group[s];
    ++group_size[slot_group[s]];
  }
  int group_start[VoxelBatch::kMaxVoxels + 1];
  group_start[0] = 0;
  for (int g = 0; g < num_groups; ++g) group_start[g + 1] = group_start[g] + group_size[g];
  int fill[VoxelBatch::kMaxVoxels];
  for (int g = 0; g < num_groups; ++g) fill[g] = group_start[g];
  const double* rows[VoxelBatch::kMaxVoxels];       // each voxel's Jacobians, grouped
  const double* residuals[VoxelBatch::kMaxVoxels];  // and its residuals (with g)
  for (int t = 0; t < batch.num_voxels; ++t) {
    const int r = fill[voxel_group[t]]++;
    rows[r] =
        width == kWideJacobianSize ? batch.wide_jac[batch.begin[t]] : batch.jac[batch.begin[t]];
    residuals[r] = batch.residual + batch.begin[t];
  }

  const KernelPath path = ResolveKernelPath(requested);
  for (int g = 0; g < num_groups; ++g) {
    int frame[kMaxFrames];
    int k = 0;
    for (uint32_t bits = group_key[g]; bits != 0; bits &= bits - 1)
      frame[k++] = __builtin_ctz(bits);
    DCHECK_GE(k, 2);
    internal::HessianGroup group{rows + group_start[g], group_size[g], k, frame, width};
    HessianWeights form = weights != nullptr ? weights[k] : HessianWeights();
    double factor[kMaxFrames];
    if (projection_factors != nullptr) {
      double sum = 0.0;
      for (int a = 0; a < k; ++a) {
        factor[a] = projection_factors[frame[a]];
        sum += factor[a] * factor[a];
      }
      form = {1.0, -1.0 / sum};
      group.factor = factor;
    }
    AddGroup(path, group, residuals + group_start[g], form, h, n, gradient);
  }
}

}  // namespace dsr
