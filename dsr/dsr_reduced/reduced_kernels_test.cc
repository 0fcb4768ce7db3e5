// The kernel paths of the voxel stream (util/cpu.h, stream/voxel_stream.h) through whole DSR
// evaluations and solves: each SIMD path against the portable twin, the kernel path reaching
// the solver through its options, and the rule the solver's evaluation cache relies on (a
// cost-only pass gives bit-for-bit the cost of a pass with Jacobians).
#include <gtest/gtest.h>

#include <string>

#include "dsr/dsr_reduced/dsr_solver.h"
#include "dsr/dsr_reduced/reduced_cost.h"
#include "dsr/stream/voxel_stream.h"
#include "dsr/tests/support/kernel_paths.h"
#include "dsr/tests/support/test_problems.h"

namespace dsr {
namespace {

using testing_kernels::AvailablePaths;
using testing_problems::Candidates;
using testing_problems::KernelTestSequence;
using testing_problems::Perturbed;

// The paths sum the same terms in another order (and with FMA).
constexpr double kSystemRelativeTolerance = 1e-12;

TEST(ReducedKernels, KernelPathsGiveTheSameNormalEquations) {
  if (!KernelPathAvailable(KernelPath::kAvx2)) GTEST_SKIP() << "no AVX2+FMA on this CPU";
  const auto s = KernelTestSequence(9);
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
TEST(ReducedKernels, SolveOptionsChooseTheKernelPath) {
  if (!KernelPathAvailable(KernelPath::kAvx2)) GTEST_SKIP() << "no AVX2+FMA on this CPU";
  const auto s = KernelTestSequence(13);
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

TEST(ReducedKernels, CostOnlyPassGivesTheCostOfTheJacobianPassExactly) {
  const auto s = KernelTestSequence(11);
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
