// The cost-evaluation backend extension point (dsr_reduced/reduced_cost_backend.h): a
// second backend plugs into a DSR solve through DsrOptions::backend. A counting wrapper
// around the CPU backend reaches bit-identical poses and shows every pass went through it;
// the per-voxel reference cost wrapped as a backend (another sampler, another
// accumulation) reaches the default's poses to the fixed-point tolerance the
// fast-against-reference solves use; a backend that fails makes the solve unusable.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <array>
#include <atomic>
#include <memory>
#include <string>
#include <vector>

#include "dsr/dsr_reduced/dsr_solver.h"
#include "dsr/dsr_reduced/reduced_cost.h"
#include "dsr/dsr_reduced/reduced_cost_backend.h"
#include "dsr/geometry/se3.h"
#include "dsr/tests/support/fixed_point_options.h"
#include "dsr/tests/support/pose_matchers.h"
#include "dsr/tests/support/sanitizer.h"
#include "dsr/tests/support/test_problems.h"
#include "dsr/tests/support/tolerances.h"

namespace dsr {
namespace {

using testing_poses::FramesFromWorldNear;
using testing_problems::Candidates;
using testing_problems::InteriorCandidates;
using testing_problems::MakeSequence;
using testing_problems::Perturbed;
using testing_problems::SequenceOptions;
using testing_problems::TestSequence;
using testing_solve::FixedPointOptions;
using testing_tolerances::kFixedPointRotationRad;
using testing_tolerances::kFixedPointTranslationMm;
using testing_tolerances::kSystemRelativeTolerance;

// The CPU backend, counting its calls.
class CountingBackend final : public ReducedCostBackend {
 public:
  std::string Name() const override { return "counting " + cpu_.Name(); }
  bool Evaluate(const ReducedCostInputs& inputs,
                const std::vector<Eigen::Isometry3d>& frame_from_world,
                const std::vector<Photometric>& photometric,
                int64_t begin,
                int64_t end,
                bool with_jacobian,
                NormalEquations* out) const override {
    ++(with_jacobian ? jacobian_calls : cost_calls);
    return cpu_.Evaluate(inputs, frame_from_world, photometric, begin, end, with_jacobian, out);
  }
  mutable std::atomic<int> jacobian_calls{0}, cost_calls{0};

 private:
  CpuReducedCostBackend cpu_;
};

// The per-voxel reference cost (VoxelReducedCost: ObserveSample per observation, Jacobians
// per residual) as a backend: each voxel's residuals r and ambient Jacobians, turned into
// tangent ones with the pose manifold's PlusJacobian as Ceres does, summed into
// H = J^T J, g = J^T r and cost = |r|^2. The plain cost only (no weights, no photometric
// parameters: false), and without observation counts (the solve does not read them).
class PerVoxelReferenceBackend final : public ReducedCostBackend {
 public:
  std::string Name() const override { return "per-voxel reference"; }
  bool Evaluate(const ReducedCostInputs& inputs,
                const std::vector<Eigen::Isometry3d>& frame_from_world,
                const std::vector<Photometric>& photometric,
                int64_t begin,
                int64_t end,
                bool with_jacobian,
                NormalEquations* out) const override {
    if (inputs.weights != nullptr || !photometric.empty()) return false;
    const std::vector<Frame>& frames = *inputs.frames;
    const CandidateSet& candidates = *inputs.candidates;
    const int m = static_cast<int>(frames.size());
    std::vector<std::array<double, kPoseAmbientSize>> x(m);
    std::vector<Eigen::Matrix<double, kPoseAmbientSize, kPoseTangentSize, Eigen::RowMajor>> plus(m);
    PoseManifold manifold;
    for (int i = 0; i < m; ++i) {
      PoseToParameters(frame_from_world[i], x[i].data());
      manifold.PlusJacobian(x[i].data(), plus[i].data());
    }
    *out = NormalEquations();
    out->frame_cost.assign(m, 0.0);
    out->frame_observations.assign(m, 0);
    if (with_jacobian) {
      out->hessian.setZero(6 * m, 6 * m);
      out->gradient.setZero(6 * m);
    }
    for (int64_t v = begin; v < end; ++v) {
      std::vector<const Frame*> observers;
      std::vector<int> frame;
      std::vector<const double*> blocks;
      for (int i = 0; i < m; ++i) {
        if (!(candidates.observers[v] >> i & 1u)) continue;
        observers.push_back(&frames[i]);
        frame.push_back(i);
        blocks.push_back(x[i].data());
      }
      const int k = static_cast<int>(frame.size());
      const VoxelReducedCost cost(observers, candidates.VoxelCenter(v));
      Eigen::VectorXd r(k);
      std::vector<Eigen::Matrix<double, Eigen::Dynamic, kPoseAmbientSize, Eigen::RowMajor>>
          ambient(k, Eigen::MatrixXd::Zero(k, kPoseAmbientSize));
      std::vector<double*> jacobians;
      for (auto& a : ambient) jacobians.push_back(a.data());
      if (!cost.Evaluate(blocks.data(), r.data(), with_jacobian ? jacobians.data() : nullptr)) {
        return false;
      }
      out->cost += r.squaredNorm();
      for (int a = 0; a < k; ++a) out->frame_cost[frame[a]] += r[a] * r[a];
      if (!with_jacobian) continue;
      Eigen::MatrixXd j = Eigen::MatrixXd::Zero(k, 6 * m);
      for (int a = 0; a < k; ++a) j.middleCols(6 * frame[a], 6) = ambient[a] * plus[frame[a]];
      out->hessian += j.transpose() * j;
      out->gradient += j.transpose() * r;
    }
    return true;
  }
};

// A backend that cannot evaluate.
class FailingBackend final : public ReducedCostBackend {
 public:
  std::string Name() const override { return "failing"; }
  bool Evaluate(const ReducedCostInputs&, const std::vector<Eigen::Isometry3d>&,
                const std::vector<Photometric>&, int64_t, int64_t, bool,
                NormalEquations*) const override {
    return false;
  }
};

TestSequence SmallSequence(uint64_t seed, bool lattice) {
  SequenceOptions o;
  o.num_frames = 4;
  o.size = 16;
  o.noise_sigma = lattice ? 0.0 : 5.0;
  o.lattice = lattice;
  o.seed = seed;
  return MakeSequence(o);
}

DsrOptions QuietOptions() {
  DsrOptions options;
  options.solve.progress = false;
  options.solve.num_threads = 2;
  return options;
}

// What the counting backend must reproduce bit for bit: the default's solve.
struct Variant {
  std::string name;
  DsrOptions options;
};

std::vector<Variant> Variants() {
  std::vector<Variant> out;
  out.push_back({"plain", QuietOptions()});
  out.push_back({"3 chunks", QuietOptions()});
  out.back().options.num_chunks = 3;
  out.push_back({"photometric", QuietOptions()});
  out.back().options.photometric = true;
  out.push_back({"huber", QuietOptions()});
  out.back().options.loss = RobustLoss{RobustLoss::Kind::kHuber, 10.0};
  out.push_back({"mean gauge", QuietOptions()});
  out.back().options.gauge = Gauge::kMean;
  return out;
}

TEST(ReducedCostBackend, CountingWrapperReachesTheSamePosesBitForBit) {
  const TestSequence s = SmallSequence(21, false);
  const auto init = Perturbed(s.ground_truth, 0.02, 0.6, 22);
  const CandidateSet cand = Candidates(s, init);
  ASSERT_GT(cand.num_voxels(), 500);
  for (const Variant& variant : Variants()) {
    SolveReport expected, report;
    std::string error;
    ASSERT_TRUE(SolveDsr(s.frames, cand, init, variant.options, &expected, &error)) << error;
    auto counting = std::make_shared<CountingBackend>();
    DsrOptions options = variant.options;
    options.backend = counting;
    ASSERT_TRUE(options.Validate(&error)) << error;
    ASSERT_TRUE(SolveDsr(s.frames, cand, init, options, &report, &error)) << error;
    ASSERT_TRUE(report.usable) << variant.name << ": " << report.termination;
    ASSERT_EQ(report.frame_from_world.size(), expected.frame_from_world.size());
    for (size_t i = 0; i < report.frame_from_world.size(); ++i) {
      EXPECT_EQ(report.frame_from_world[i].matrix(), expected.frame_from_world[i].matrix())
          << variant.name << " frame " << i;
    }
    ASSERT_EQ(report.photometric.size(), expected.photometric.size()) << variant.name;
    for (size_t i = 0; i < report.photometric.size(); ++i) {
      EXPECT_EQ(report.photometric[i].log_gain, expected.photometric[i].log_gain) << variant.name;
      EXPECT_EQ(report.photometric[i].offset, expected.photometric[i].offset) << variant.name;
    }
    EXPECT_EQ(report.final_cost, expected.final_cost) << variant.name;
    EXPECT_EQ(report.num_iterations, expected.num_iterations) << variant.name;
    // Every pass of the chunks went through the backend, the mean gauge's prior stiffness
    // among them (the chunks' pass at the initial poses, which the first evaluation reuses).
    EXPECT_GT(counting->jacobian_calls.load(), 0) << variant.name;
    EXPECT_EQ(counting->jacobian_calls.load(), report.jacobian_passes) << variant.name;
    EXPECT_EQ(counting->cost_calls.load(), report.cost_passes) << variant.name;
  }
}

// The reference backend evaluates the cost the CPU backend does (to rounding), and a solve
// through it, run to the fixed point on a lattice-aligned problem, reaches the default's
// poses (and the ground truth) to the tolerance of the fast-against-reference solves
// (dsr_theorem_test.cc).
TEST(ReducedCostBackend, PerVoxelReferenceBackendReachesTheDefaultsPoses) {
  DSR_SKIP_HEAVY_UNDER_SANITIZER();
  const TestSequence s = SmallSequence(31, true);
  const auto init = Perturbed(s.ground_truth, 0.02, 0.5, 32);
  const CandidateSet cand = InteriorCandidates(s, init, 1.5);
  ASSERT_GT(cand.num_voxels(), 200);
  ReducedCostInputs inputs;
  inputs.frames = &s.frames;
  inputs.candidates = &cand;
  inputs.context = StreamContext{2};
  NormalEquations cpu, reference;
  ASSERT_TRUE(CpuReducedCostBackend().Evaluate(inputs, init, {}, 0, cand.num_voxels(), true, &cpu));
  ASSERT_TRUE(PerVoxelReferenceBackend().Evaluate(inputs, init, {}, 0, cand.num_voxels(), true,
                                                  &reference));
  EXPECT_NEAR(reference.cost, cpu.cost, kSystemRelativeTolerance * cpu.cost);
  EXPECT_LT((reference.gradient - cpu.gradient).norm(),
            10 * kSystemRelativeTolerance * cpu.gradient.norm());
  EXPECT_LT((reference.hessian - cpu.hessian).norm(),
            kSystemRelativeTolerance * cpu.hessian.norm());

  DsrOptions options;
  options.solve = FixedPointOptions(1000);
  SolveReport expected, report;
  std::string error;
  ASSERT_TRUE(SolveDsr(s.frames, cand, init, options, &expected, &error)) << error;
  ASSERT_TRUE(expected.usable) << expected.termination;
  options.backend = std::make_shared<PerVoxelReferenceBackend>();
  ASSERT_TRUE(SolveDsr(s.frames, cand, init, options, &report, &error)) << error;
  ASSERT_TRUE(report.usable) << report.termination;
  EXPECT_THAT(report.frame_from_world,
              FramesFromWorldNear(expected.frame_from_world, kFixedPointRotationRad,
                                  kFixedPointTranslationMm));
  EXPECT_THAT(report.frame_from_world,
              FramesFromWorldNear(s.ground_truth, kFixedPointRotationRad,
                                  kFixedPointTranslationMm));
  // The solve moved the poses far more than that.
  EXPECT_GT(testing_problems::MaxPoseDifference(report.frame_from_world, init).second, 0.1);
}

TEST(ReducedCostBackend, FailingBackendMakesTheSolveUnusable) {
  const TestSequence s = SmallSequence(41, false);
  const auto init = Perturbed(s.ground_truth, 0.02, 0.6, 42);
  const CandidateSet cand = Candidates(s, init);
  DsrOptions options = QuietOptions();
  options.backend = std::make_shared<FailingBackend>();
  SolveReport report;
  std::string error;
  ASSERT_TRUE(SolveDsr(s.frames, cand, init, options, &report, &error)) << error;
  EXPECT_FALSE(report.usable);
}

TEST(ReducedCostBackend, OptionsRefuseABackendWithTheReferenceCost) {
  DsrOptions options;
  std::string error;
  EXPECT_TRUE(options.Validate(&error)) << error;
  options.backend = DefaultReducedCostBackend();
  EXPECT_TRUE(options.Validate(&error)) << error;
  options.reference_cost = true;
  EXPECT_FALSE(options.Validate(&error));
  EXPECT_THAT(error, ::testing::HasSubstr("backend"));
}

}  // namespace
}  // namespace dsr
