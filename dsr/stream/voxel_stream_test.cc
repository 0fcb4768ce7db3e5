// The batch sampler of the voxel stream (stream/voxel_stream.h), each kernel path against
// the obviously-correct per-observation twin ObserveSample (model/observation.h): the same
// observers kept (sigma_ij), values and Jacobians to rounding. The kernel paths through
// whole DSR evaluations: dsr_reduced/reduced_kernels_test.cc.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <memory>

#include "dsr/stream/voxel_stream.h"
#include "dsr/tests/support/kernel_paths.h"
#include "dsr/tests/support/test_problems.h"

namespace dsr {
namespace {

using testing_problems::Candidates;
using testing_problems::KernelTestSequence;
using testing_problems::Perturbed;

// Same trilinear formula, other order of additions (and FMA on the AVX2 path).
constexpr double kValueTolerance = 1e-10;      // intensities are O(100)
constexpr double kJacobianTolerance = 1e-10;   // relative to the Jacobian's norm

using testing_kernels::AvailablePaths;

TEST(VoxelStream, BatchSamplerMatchesObserveSample) {
  const auto s = KernelTestSequence(5);
  // Candidates with a margin: many candidate observers fall outside the valid region, so
  // both outcomes of sigma_ij are exercised.
  const auto poses = Perturbed(s.ground_truth, 0.05, 1.5, 6);
  const CandidateSet cand = Candidates(s, poses, /*margin=*/2);
  ASSERT_GT(cand.num_voxels(), 100);
  const std::vector<PosedFrame> posed = PoseFrames(s.frames, poses);
  for (KernelPath path : AvailablePaths()) {
    const std::unique_ptr<VoxelBatch> batch(new VoxelBatch);
    int64_t sampled_voxels = 0, rejected = 0;
    for (int64_t v = 0; v < cand.num_voxels();) {
      const int64_t next = SampleVoxelBatch(path, posed, cand, v, cand.num_voxels(), true,
                                            batch.get());
      ASSERT_GT(next, v);
      int t = 0;
      for (; v < next; ++v) {
        // The twin: every candidate observer through ObserveSample.
        const Eigen::Vector3d p = cand.VoxelCenter(v);
        std::vector<int> frames;
        std::vector<double> values;
        std::vector<RowVector6d> jacobians;
        for (int f = 0; f < cand.num_frames; ++f) {
          if (!(cand.observers[v] >> f & 1u)) continue;
          double value;
          RowVector6d jac;
          if (ObserveSample(s.frames[f], poses[f], p, &value, &jac)) {
            frames.push_back(f);
            values.push_back(value);
            jacobians.push_back(jac);
          } else {
            ++rejected;
          }
        }
        if (frames.size() < 2) continue;  // the sampler drops such voxels
        ASSERT_LT(t, batch->num_voxels) << KernelPathToString(path);
        const int first = batch->begin[t], k = batch->begin[t + 1] - first;
        ASSERT_EQ(k, static_cast<int>(frames.size())) << KernelPathToString(path) << " voxel " << v;
        // The weighted terms find a voxel's weights by its candidate index.
        EXPECT_EQ(batch->voxel[t], v) << KernelPathToString(path);
        for (int a = 0; a < k; ++a) {
          EXPECT_EQ(batch->frame[first + a], frames[a]);
          EXPECT_NEAR(batch->value[first + a], values[a], kValueTolerance);
          EXPECT_LT((Eigen::Map<const RowVector6d>(batch->jac[first + a]) - jacobians[a]).norm(),
                    kJacobianTolerance * std::max(1.0, jacobians[a].norm()))
              << KernelPathToString(path) << " voxel " << v << " frame " << frames[a];
        }
        ++t;
        ++sampled_voxels;
      }
      EXPECT_EQ(t, batch->num_voxels);
    }
    EXPECT_GT(sampled_voxels, 50);
    EXPECT_GT(rejected, 0);  // the margin made some candidates invalid
  }
}

// A batch without Jacobians reads the cells' 8 values only (no differences): the same
// observations and the same values, bit for bit, as the batch with them, on every path.
TEST(VoxelStream, ValuesWithoutJacobiansAreThoseWithThem) {
  const auto s = KernelTestSequence(5);
  const auto poses = Perturbed(s.ground_truth, 0.05, 1.5, 7);
  const CandidateSet cand = Candidates(s, poses, /*margin=*/2);
  ASSERT_GT(cand.num_voxels(), 100);
  const std::vector<PosedFrame> posed = PoseFrames(s.frames, poses);
  for (KernelPath path : AvailablePaths()) {
    const std::unique_ptr<VoxelBatch> with(new VoxelBatch), without(new VoxelBatch);
    int64_t observations = 0;
    for (int64_t v = 0; v < cand.num_voxels();) {
      const int64_t next = SampleVoxelBatch(path, posed, cand, v, cand.num_voxels(), true,
                                            with.get());
      ASSERT_EQ(SampleVoxelBatch(path, posed, cand, v, cand.num_voxels(), false, without.get()),
                next);
      ASSERT_EQ(without->num_voxels, with->num_voxels);
      ASSERT_EQ(without->num_observations, with->num_observations);
      for (int t = 0; t <= with->num_voxels; ++t) ASSERT_EQ(without->begin[t], with->begin[t]);
      for (int o = 0; o < with->num_observations; ++o) {
        ASSERT_EQ(without->frame[o], with->frame[o]);
        ASSERT_EQ(without->value[o], with->value[o]) << KernelPathToString(path);
      }
      observations += with->num_observations;
      v = next;
    }
    EXPECT_GT(observations, 1000);
  }
}

TEST(VoxelStream, NonFinitePosesObserveNothing) {
  const auto s = KernelTestSequence(7);
  std::vector<Eigen::Isometry3d> poses = s.ground_truth;
  const CandidateSet cand = Candidates(s, poses);
  poses[1].translation().x() = std::numeric_limits<double>::quiet_NaN();
  poses[2].translation().y() = std::numeric_limits<double>::infinity();
  const std::vector<PosedFrame> posed = PoseFrames(s.frames, poses);
  for (KernelPath path : AvailablePaths()) {
    const std::unique_ptr<VoxelBatch> batch(new VoxelBatch);
    for (int64_t v = 0; v < cand.num_voxels();) {
      v = SampleVoxelBatch(path, posed, cand, v, cand.num_voxels(), false, batch.get());
      for (int o = 0; o < batch->num_observations; ++o) {
        EXPECT_NE(batch->frame[o], 1) << KernelPathToString(path);
        EXPECT_NE(batch->frame[o], 2) << KernelPathToString(path);
      }
    }
  }
}


}  // namespace
}  // namespace dsr
