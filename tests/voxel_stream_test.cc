// The batch sampler of the voxel stream (stream/voxel_stream.h), each kernel path against
// the obviously-correct per-observation twin ObserveSample (model/observation.h): the same
// observers kept (sigma_ij), values and Jacobians to rounding; and the kernel
// paths against each other through whole DSR evaluations. Also the rule the solver's
// evaluation cache relies on: a cost-only pass gives bit-for-bit the cost of a pass with
// Jacobians.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <memory>
#include <string>

#include "dsr/dsr_reduced/dsr_solver.h"
#include "dsr/dsr_reduced/reduced_cost.h"
#include "dsr/stream/voxel_stream.h"
#include "kernel_paths.h"
#include "test_problems.h"

namespace dsr {
namespace {

using testing_problems::Candidates;
using testing_problems::MakeSequence;
using testing_problems::Perturbed;
using testing_problems::SequenceOptions;

// Same trilinear formula, other order of additions (and FMA on the AVX2 path).
constexpr double kValueTolerance = 1e-10;      // intensities are O(100)
constexpr double kJacobianTolerance = 1e-10;   // relative to the Jacobian's norm
constexpr double kSystemRelativeTolerance = 1e-12;

using testing_kernels::AvailablePaths;

testing_problems::TestSequence Sequence(uint64_t seed) {
  SequenceOptions o;
  o.num_frames = 4;
  o.size = 16;
  o.noise_sigma = 10.0;
  o.max_rotation = 0.2;
  o.erosion = 2;
  o.seed = seed;
  return MakeSequence(o);
}

TEST(VoxelStream, BatchSamplerMatchesObserveSample) {
  const auto s = Sequence(5);
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

TEST(VoxelStream, NonFinitePosesObserveNothing) {
  const auto s = Sequence(7);
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

TEST(VoxelStream, KernelPathsGiveTheSameNormalEquations) {
  if (!KernelPathAvailable(KernelPath::kAvx2)) GTEST_SKIP() << "no AVX2+FMA on this CPU";
  const auto s = Sequence(9);
  const auto poses = Perturbed(s.ground_truth, 0.03, 1.0, 10);
  const CandidateSet cand = Candidates(s, poses);
  ReducedSystem portable;
  AccumulateReducedSystem(s.frames, cand, poses, 0, cand.num_voxels(), true,
                          StreamContext{2, KernelPath::kPortable}, &portable);
  for (KernelPath path : AvailablePaths()) {
    if (path == KernelPath::kPortable) continue;
    ReducedSystem simd;
    AccumulateReducedSystem(s.frames, cand, poses, 0, cand.num_voxels(), true,
                            StreamContext{2, path}, &simd);
    EXPECT_EQ(portable.observations, simd.observations) << KernelPathToString(path);
    EXPECT_NEAR(simd.cost, portable.cost, kSystemRelativeTolerance * portable.cost)
        << KernelPathToString(path);
    EXPECT_LT((simd.gradient - portable.gradient).norm() / portable.gradient.norm(),
              kSystemRelativeTolerance)
        << KernelPathToString(path);
    EXPECT_LT((simd.hessian - portable.hessian).norm() / portable.hessian.norm(),
              kSystemRelativeTolerance)
        << KernelPathToString(path);
  }
}

// The solvers run the kernels their SolveOptions name: the portable twin and each SIMD path
// give costs that agree to rounding but not bit for bit (FMA and another order of sums),
// so a path the options did not reach would show as identical costs.
TEST(VoxelStream, SolveOptionsChooseTheKernelPath) {
  if (!KernelPathAvailable(KernelPath::kAvx2)) GTEST_SKIP() << "no AVX2+FMA on this CPU";
  const auto s = Sequence(13);
  const auto poses = Perturbed(s.ground_truth, 0.03, 1.0, 14);
  const CandidateSet cand = Candidates(s, poses);
  const auto solve = [&](KernelPath path) {
    DsrOptions options;
    options.solve.max_iterations = 2;
    options.solve.progress = false;
    options.solve.kernels = path;
    SolveReport report;
    std::string error;
    EXPECT_TRUE(SolveDsr(s.frames, cand, poses, options, &report, &error)) << error;
    return report;
  };
  const SolveReport portable = solve(KernelPath::kPortable);
  for (KernelPath path : AvailablePaths()) {
    if (path == KernelPath::kPortable) continue;
    const SolveReport simd = solve(path);
    EXPECT_NE(simd.initial_cost, portable.initial_cost) << KernelPathToString(path);
    EXPECT_NEAR(simd.initial_cost, portable.initial_cost,
                kSystemRelativeTolerance * portable.initial_cost)
        << KernelPathToString(path);
  }
}

TEST(VoxelStream, CostOnlyPassGivesTheCostOfTheJacobianPassExactly) {
  const auto s = Sequence(11);
  const auto poses = Perturbed(s.ground_truth, 0.03, 1.0, 12);
  const CandidateSet cand = Candidates(s, poses);
  for (KernelPath path : AvailablePaths()) {
    ReducedSystem cost_only, full;
    const StreamContext context{2, path};
    AccumulateReducedSystem(s.frames, cand, poses, 0, cand.num_voxels(), false, context,
                            &cost_only);
    AccumulateReducedSystem(s.frames, cand, poses, 0, cand.num_voxels(), true, context, &full);
    EXPECT_EQ(cost_only.cost, full.cost) << KernelPathToString(path);
    EXPECT_EQ(cost_only.frame_cost, full.frame_cost) << KernelPathToString(path);
  }
}

}  // namespace
}  // namespace dsr
