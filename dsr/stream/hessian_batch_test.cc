// AddBatchHessian (stream/hessian_batch.h) against the voxel-by-voxel AddOuter and
// AddGradient twins, on random Jacobians, residuals and observer sets, for every kernel
// path this CPU has: a batch with one voxel, batches with one observer set, with many
// interleaved sets, and with the largest frame count; for 6 parameters per frame and for
// 8 (photometric parameters).
#include <gtest/gtest.h>

#include <cmath>
#include <memory>
#include <random>
#include <vector>

#include "dsr/stream/hessian_batch.h"
#include "dsr/stream/voxel_stream.h"
#include "dsr/tests/support/kernel_paths.h"

namespace dsr {
namespace {

// Same products summed in another order: agreement to rounding.
constexpr double kRelativeTolerance = 1e-12;

using testing_kernels::AvailablePaths;

// Fills a batch with `num_voxels` random voxels whose observer sets are drawn from
// `num_sets` random sets of at least two of `m` frames, in runs of random length; DSR's
// weights.
void FillRandomBatch(int m, int num_sets, int num_voxels, uint64_t seed, VoxelBatch* batch) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> n01;
  std::vector<uint32_t> sets;
  while (static_cast<int>(sets.size()) < num_sets) {
    const uint32_t bits = static_cast<uint32_t>(rng()) & ((m == 32 ? 0u : 1u << m) - 1u);
    if (__builtin_popcount(bits) >= 2) sets.push_back(bits);
  }
  batch->num_voxels = 0;
  batch->num_observations = 0;
  batch->begin[0] = 0;
  uint32_t bits = sets[0];
  for (int v = 0; v < num_voxels; ++v) {
    if (rng() % 7 == 0) bits = sets[rng() % sets.size()];  // runs of voxels share a set
    ASSERT_LE(batch->num_observations + __builtin_popcount(bits), VoxelBatch::kMaxObservations);
    for (uint32_t b = bits; b != 0; b &= b - 1) {
      const int o = batch->num_observations++;
      batch->frame[o] = __builtin_ctz(b);
      for (int t = 0; t < kJacobianSize; ++t) batch->jac[o][t] = n01(rng);
      for (int t = 0; t < kWideJacobianSize; ++t) batch->wide_jac[o][t] = n01(rng);
      batch->residual[o] = n01(rng);
    }
    batch->observers[batch->num_voxels] = bits;
    batch->begin[++batch->num_voxels] = batch->num_observations;
  }
}

// The twin of the width-8 kernels (photometric parameters): every block of every voxel,
// element by element; with `factors` (per frame u), the projection form
// delta_ab - u_a u_b / sum_c u_c^2 instead of `weights`.
void AddWideTwin(const VoxelBatch& batch,
                 const HessianWeights* weights,
                 const double* factors,
                 int n,
                 std::vector<double>* h,
                 std::vector<double>* g,
                 int W = kWideJacobianSize) {
  const auto jac = [&](int o) { return W == kJacobianSize ? batch.jac[o] : batch.wide_jac[o]; };
  for (int t = 0; t < batch.num_voxels; ++t) {
    const int first = batch.begin[t], k = batch.begin[t + 1] - first;
    double sum_u2 = 0.0;
    for (int a = 0; a < k && factors != nullptr; ++a) {
      sum_u2 += factors[batch.frame[first + a]] * factors[batch.frame[first + a]];
    }
    for (int a = 0; a < k; ++a) {
      const int fa = batch.frame[first + a];
      for (int i = 0; i < W; ++i) {
        (*g)[W * fa + i] += batch.residual[first + a] * jac(first + a)[i];
      }
      for (int b = a; b < k; ++b) {
        const int fb = batch.frame[first + b];
        const double scale =
            factors != nullptr ? (a == b ? 1.0 : 0.0) - factors[fa] * factors[fb] / sum_u2
                               : weights[k].shared + (a == b ? weights[k].diagonal : 0.0);
        for (int i = 0; i < W; ++i) {
          for (int j = 0; j < W; ++j) {
            (*h)[(W * fa + i) * n + W * fb + j] +=
                scale * jac(first + a)[i] * jac(first + b)[j];
          }
        }
      }
    }
  }
}

void CompareWithTwin(int m,
                     int num_sets,
                     int num_voxels,
                     uint64_t seed,
                     int width = kJacobianSize,
                     bool with_factors = false) {
  const std::unique_ptr<VoxelBatch> batch(new VoxelBatch);
  FillRandomBatch(m, num_sets, num_voxels, seed, batch.get());
  HessianWeights weights[kMaxFrames + 1];
  for (int k = 2; k <= kMaxFrames; ++k) weights[k] = {1.0, -1.0 / k};  // DSR's form
  const int n = width * m;
  std::vector<double> twin(n * n, 0.0), twin_gradient(n, 0.0);
  std::vector<double> factors;
  if (with_factors) {
    std::mt19937_64 rng(seed + 1000);
    std::uniform_real_distribution<double> u(0.7, 1.4);
    for (int f = 0; f < m; ++f) factors.push_back(u(rng));
  }
  const double* factor_data = with_factors ? factors.data() : nullptr;
  if (width == kWideJacobianSize || with_factors) {
    AddWideTwin(*batch, weights, factor_data, n, &twin, &twin_gradient, width);
  }
  for (int t = 0; t < batch->num_voxels && width == kJacobianSize && !with_factors; ++t) {
    const int first = batch->begin[t], k = batch->begin[t + 1] - first;
    const HessianWeights& w = weights[k];
    const double(*jac)[kJacobianSize] = batch->jac + first;
    for (int a = 0; a < k; ++a) {
      AddGradient(twin_gradient.data(), batch->frame[first + a], jac[a],
                  batch->residual[first + a]);
      AddOuter(twin.data(), n, batch->frame[first + a], batch->frame[first + a], jac[a], jac[a],
               w.diagonal + w.shared);
      for (int b = a + 1; b < k; ++b) {
        AddOuter(twin.data(), n, batch->frame[first + a], batch->frame[first + b], jac[a], jac[b],
                 w.shared);
      }
    }
  }
  for (KernelPath path : AvailablePaths()) {
    std::vector<double> batched(n * n, 0.0), batched_gradient(n, 0.0);
    AddBatchHessian(path, *batch, weights, batched.data(), n, batched_gradient.data(), width,
                    factor_data);
    double gradient_diff = 0.0, gradient_norm = 0.0;
    for (int r = 0; r < n; ++r) {
      gradient_diff +=
          (batched_gradient[r] - twin_gradient[r]) * (batched_gradient[r] - twin_gradient[r]);
      gradient_norm += twin_gradient[r] * twin_gradient[r];
    }
    ASSERT_GT(gradient_norm, 0.0);
    EXPECT_LT(std::sqrt(gradient_diff / gradient_norm), kRelativeTolerance)
        << KernelPathToString(path) << " m=" << m << " sets=" << num_sets
        << " voxels=" << num_voxels;
    // Compare the upper triangle (what the stream reads).
    double diff = 0.0, norm = 0.0;
    for (int r = 0; r < n; ++r) {
      for (int c = r; c < n; ++c) {
        diff += (batched[r * n + c] - twin[r * n + c]) * (batched[r * n + c] - twin[r * n + c]);
        norm += twin[r * n + c] * twin[r * n + c];
      }
    }
    ASSERT_GT(norm, 0.0);
    EXPECT_LT(std::sqrt(diff / norm), kRelativeTolerance)
        << KernelPathToString(path) << " m=" << m << " sets=" << num_sets
        << " voxels=" << num_voxels;
  }
}

TEST(AddBatchHessian, MatchesVoxelByVoxelAccumulation) {
  CompareWithTwin(3, 2, 1, 1);     // one voxel
  CompareWithTwin(4, 3, 200, 2);
  CompareWithTwin(11, 40, 250, 3);  // many interleaved sets
  CompareWithTwin(32, 12, 60, 4);   // the largest frame count
}

TEST(AddBatchHessian, OneObserverSetIsOneGroup) {
  CompareWithTwin(5, 1, VoxelBatch::kMaxVoxels, 5);  // a full batch of one set
}

// Width 8 (pose and photometric parameters per frame): the same cases.
TEST(AddBatchHessian, WideMatchesVoxelByVoxelAccumulation) {
  CompareWithTwin(3, 2, 1, 11, kWideJacobianSize);
  CompareWithTwin(4, 3, 200, 12, kWideJacobianSize);
  CompareWithTwin(11, 40, 250, 13, kWideJacobianSize);
  CompareWithTwin(32, 12, 60, 14, kWideJacobianSize);
  CompareWithTwin(5, 1, VoxelBatch::kMaxVoxels, 15, kWideJacobianSize);
}

// Width 8 with per-frame projection factors (DSR's form with photometric parameters).
TEST(AddBatchHessian, WideWithProjectionFactorsMatchesVoxelByVoxelAccumulation) {
  CompareWithTwin(3, 2, 1, 21, kWideJacobianSize, true);
  CompareWithTwin(4, 3, 200, 22, kWideJacobianSize, true);
  CompareWithTwin(11, 40, 250, 23, kWideJacobianSize, true);
  CompareWithTwin(32, 12, 60, 24, kWideJacobianSize, true);
  CompareWithTwin(11, 40, 250, 25, kJacobianSize, true);  // the width-6 kernels' factors
  CompareWithTwin(32, 12, 60, 26, kJacobianSize, true);
}

}  // namespace
}  // namespace dsr
