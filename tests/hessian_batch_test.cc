// HessianBatcher (core/hessian_batch.h) against the voxel-by-voxel AddOuter twin, on random
// Jacobians and observer sets: more distinct sets than open batches (evictions), batches
// that fill up, and partial batches at the final flush.
#include <gtest/gtest.h>

#include <random>
#include <vector>

#include "core/hessian_batch.h"
#include "core/voxel_stream.h"

namespace dsr {
namespace {

// Same products summed in another order: agreement to rounding.
constexpr double kRelativeTolerance = 1e-12;

// Runs `num_voxels` random voxels through both paths; observer sets are drawn from
// `num_sets` random sets of at least two of `m` frames, in runs of random length.
void CompareOnRandomVoxels(int m, int num_sets, int num_voxels, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> n01;
  std::vector<uint32_t> sets;
  while (static_cast<int>(sets.size()) < num_sets) {
    const uint32_t bits = static_cast<uint32_t>(rng()) & ((m == 32 ? 0u : 1u << m) - 1u);
    if (__builtin_popcount(bits) >= 2) sets.push_back(bits);
  }
  const int n = 6 * m;
  std::vector<double> batched_h(n * n, 0.0), twin_h(n * n, 0.0);
  HessianBatcher batcher(batched_h.data(), n);
  uint32_t bits = sets[0];
  for (int v = 0; v < num_voxels; ++v) {
    if (rng() % 7 == 0) bits = sets[rng() % sets.size()];  // runs of voxels share a set
    int frame[kMaxFrames];
    double jac[kMaxFrames][6];
    int k = 0;
    for (uint32_t b = bits; b != 0; b &= b - 1) frame[k++] = __builtin_ctz(b);
    for (int a = 0; a < k; ++a) {
      for (int i = 0; i < 6; ++i) jac[a][i] = n01(rng);
    }
    const HessianWeights w{1.0, -1.0 / k};  // DSR's form
    batcher.Add(k, frame, jac, w);
    for (int a = 0; a < k; ++a) {
      AddOuter(twin_h.data(), n, frame[a], frame[a], jac[a], jac[a], w.diagonal + w.shared);
      for (int b = a + 1; b < k; ++b) {
        AddOuter(twin_h.data(), n, frame[a], frame[b], jac[a], jac[b], w.shared);
      }
    }
  }
  batcher.Flush();
  // Compare the upper triangle (what the stream reads).
  double diff = 0.0, norm = 0.0;
  for (int r = 0; r < n; ++r) {
    for (int c = r; c < n; ++c) {
      diff += (batched_h[r * n + c] - twin_h[r * n + c]) * (batched_h[r * n + c] - twin_h[r * n + c]);
      norm += twin_h[r * n + c] * twin_h[r * n + c];
    }
  }
  ASSERT_GT(norm, 0.0);
  EXPECT_LT(std::sqrt(diff / norm), kRelativeTolerance)
      << "m=" << m << " sets=" << num_sets << " voxels=" << num_voxels;
}

TEST(HessianBatcher, MatchesVoxelByVoxelAccumulation) {
  CompareOnRandomVoxels(3, 2, 5, 1);  // fewer voxels than a batch: only the final flush
  CompareOnRandomVoxels(4, 3, 1000, 2);
  CompareOnRandomVoxels(11, 40, 20000, 3);  // far more sets than open batches
  CompareOnRandomVoxels(32, 12, 3000, 4);   // the largest frame count
}

TEST(HessianBatcher, OneObserverSetFillsWholeBatches) {
  // Exactly 3 full batches of one set: every flush is a full one.
  CompareOnRandomVoxels(5, 1, 3 * HessianBatcher::kRows, 5);
}

}  // namespace
}  // namespace dsr
