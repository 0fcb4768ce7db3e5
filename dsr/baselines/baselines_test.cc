// The paper's baselines (baselines/, docs/design.md section 5):
//  1. APE's per-voxel identity with DSR: cost, gradient and Gauss-Newton matrix of a voxel
//     seen k_j times are k_j times DSR's;
//  2. APE's streamed normal equations equal its per-pair reference cost through Ceres;
//  3. Lie normalisation's templated SE(3) log equals geometry/'s LogSE3, and its pose graph
//     recovers consistent measurements exactly;
//  4. every baseline recovers ground truth on small noise-free sequences (pipeline).
#include <ceres/ceres.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cstdlib>
#include <random>

#include "dsr/baselines/baselines.h"
#include "dsr/baselines/lie_log.h"
#include "dsr/dsr_reduced/reduced_cost.h"
#include "dsr/eval/eval.h"
#include "dsr/pipeline/registration.h"
#include "dsr/sim/phantom.h"
#include "dsr/sim/simulate.h"
#include "dsr/tests/support/pose_matchers.h"
#include "dsr/tests/support/tolerances.h"
#include "dsr/tests/support/test_problems.h"

namespace dsr {
namespace {

using testing_problems::Candidates;
using testing_problems::DenseJacobian;
using testing_problems::MakeSequence;
using testing_problems::Perturbed;
using testing_problems::SequenceOptions;
using testing_poses::FramesFromWorldNear;
using testing_tolerances::kSystemRelativeTolerance;

double Relative(const Eigen::MatrixXd& a, const Eigen::MatrixXd& b) {
  return (a - b).norm() / std::max(1e-300, b.norm());
}

TEST(Ape, PerVoxelCostIsKTimesTheDsrCost) {
  SequenceOptions o;
  o.num_frames = 5;
  o.size = 16;
  o.noise_sigma = 5.0;
  o.frame_offset = 2.0;  // frames overlap heavily: voxels with k = 2..5
  const auto s = MakeSequence(o);
  const auto poses = Perturbed(s.ground_truth, 0.03, 1.0, 7);
  const CandidateSet cand = Candidates(s, poses);
  ASSERT_GT(cand.num_voxels(), 100);
  std::vector<int> voxels_with_k(6, 0);
  for (int64_t v = 0; v < cand.num_voxels(); ++v) {
    NormalEquations ape, dsr;
    AccumulateApeSystem(s.frames, cand, poses, v, v + 1, true, StreamContext{1}, &ape);
    AccumulateReducedSystem(s.frames, cand, poses, v, v + 1, true, StreamContext{1}, &dsr);
    const int64_t k = dsr.observations;  // k_j (0 when fewer than 2 observe the voxel)
    EXPECT_EQ(ape.observations, k * (k - 1) / 2);
    if (k < 2) continue;
    ++voxels_with_k[k];
    EXPECT_NEAR(ape.cost, k * dsr.cost, 1e-12 * std::max(1.0, ape.cost));
    if (dsr.gradient.norm() > 0.0) {
      // DSR's gradient sums J_a (a_a - mu), APE's J_a (a_a - a_b): different cancellations.
      EXPECT_LT(Relative(ape.gradient, k * dsr.gradient), 1e-9);
      EXPECT_LT(Relative(ape.hessian, k * dsr.hessian), 1e-12);
    }
  }
  // The identity was checked for every multiplicity, and APE is not DSR scaled overall.
  for (int k = 2; k <= 5; ++k) EXPECT_GT(voxels_with_k[k], 0) << "k=" << k;
  NormalEquations ape, dsr;
  AccumulateApeSystem(s.frames, cand, poses, 0, cand.num_voxels(), true, StreamContext{2}, &ape);
  AccumulateReducedSystem(s.frames, cand, poses, 0, cand.num_voxels(), true, StreamContext{2},
                          &dsr);
  EXPECT_GT(ape.observations, dsr.observations);
  EXPECT_GT(Relative(ape.gradient / ape.gradient.norm(), dsr.gradient / dsr.gradient.norm()), 1e-3);
}

TEST(Ape, BatchedFormOfItsGaussNewtonMatrixIsTheSameMatrix) {
  // The bench's measurement variant (batched_hessian) must change only how H is summed.
  SequenceOptions o;
  o.num_frames = 5;
  o.size = 16;
  o.noise_sigma = 5.0;
  o.frame_offset = 2.0;
  const auto s = MakeSequence(o);
  const auto poses = Perturbed(s.ground_truth, 0.03, 1.0, 8);
  const CandidateSet cand = Candidates(s, poses);
  NormalEquations pairs, batched;
  AccumulateApeSystem(s.frames, cand, poses, 0, cand.num_voxels(), true, StreamContext{2}, &pairs);
  AccumulateApeSystem(s.frames, cand, poses, 0, cand.num_voxels(), true, StreamContext{2},
                      &batched, true);
  EXPECT_EQ(pairs.cost, batched.cost);
  EXPECT_TRUE(pairs.gradient == batched.gradient);
  ASSERT_GT(pairs.hessian.norm(), 0.0);
  EXPECT_LT(Relative(batched.hessian, pairs.hessian), 1e-12);
}

TEST(Ape, StreamedSystemMatchesPerPairReference) {
  uint64_t seed = 11;
  for (int num_frames : {2, 3, 4}) {
    SequenceOptions o;
    o.num_frames = num_frames;
    o.size = 14;
    o.noise_sigma = 5.0;
    o.seed = seed++;
    const auto s = MakeSequence(o);
    const auto poses = Perturbed(s.ground_truth, 0.03, 1.0, seed++);
    const CandidateSet cand = Candidates(s, poses);
    // Reference: one VoxelApeCost per voxel, Jacobian from Ceres.
    std::vector<std::array<double, kPoseAmbientSize>> params(num_frames);
    ceres::Problem::Options problem_options;
    problem_options.manifold_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
    ceres::Problem problem(problem_options);
    PoseManifold manifold;
    for (int i = 0; i < num_frames; ++i) {
      PoseToParameters(poses[i], params[i].data());
      problem.AddParameterBlock(params[i].data(), kPoseAmbientSize, &manifold);
    }
    for (int64_t v = 0; v < cand.num_voxels(); ++v) {
      std::vector<const Frame*> observers;
      std::vector<double*> blocks;
      for (int i = 0; i < num_frames; ++i) {
        if (cand.observers[v] >> i & 1u) {
          observers.push_back(&s.frames[i]);
          blocks.push_back(params[i].data());
        }
      }
      problem.AddResidualBlock(new VoxelApeCost(observers, cand.VoxelCenter(v)), nullptr, blocks);
    }
    std::vector<double*> free_blocks;
    for (int i = 1; i < num_frames; ++i) free_blocks.push_back(params[i].data());
    Eigen::VectorXd r;
    double ref_cost = 0.0;
    const Eigen::MatrixXd j = DenseJacobian(&problem, free_blocks, &r, &ref_cost);
    NormalEquations ape;
    AccumulateApeSystem(s.frames, cand, poses, 0, cand.num_voxels(), true, StreamContext{2}, &ape);
    const int n = 6 * (num_frames - 1);
    EXPECT_NEAR(0.5 * ape.cost, ref_cost, kSystemRelativeTolerance * ref_cost);
    EXPECT_LT(Relative(ape.gradient.tail(n), j.transpose() * r), 10 * kSystemRelativeTolerance);
    EXPECT_LT(Relative(ape.hessian.bottomRightCorner(n, n), j.transpose() * j),
              kSystemRelativeTolerance);
    // The same through the streamed Ceres block (compressed residual and Jacobian).
    ceres::Problem streamed(problem_options);
    std::vector<std::array<double, kPoseAmbientSize>> p2(num_frames);
    std::vector<double*> p2_blocks;
    for (int i = 1; i < num_frames; ++i) {
      PoseToParameters(poses[i], p2[i].data());
      streamed.AddParameterBlock(p2[i].data(), kPoseAmbientSize, &manifold);
      p2_blocks.push_back(p2[i].data());
    }
    streamed.AddResidualBlock(
        new ApeChunkCost(&s.frames, &cand, poses[0], 0, cand.num_voxels(), StreamContext{2}),
        nullptr, p2_blocks);
    Eigen::VectorXd sr;
    double streamed_cost = 0.0;
    const Eigen::MatrixXd sj = DenseJacobian(&streamed, p2_blocks, &sr, &streamed_cost);
    EXPECT_NEAR(streamed_cost, ref_cost, kSystemRelativeTolerance * ref_cost);
    EXPECT_LT(Relative(sj.transpose() * sr, j.transpose() * r), 10 * kSystemRelativeTolerance);
    EXPECT_LT(Relative(sj.transpose() * sj, j.transpose() * j), kSystemRelativeTolerance);
  }
}

TEST(Ape, AccumulationIsIdenticalForAnyThreadCount) {
  SequenceOptions o;
  o.num_frames = 4;
  o.size = 16;
  o.noise_sigma = 5.0;
  const auto s = MakeSequence(o);
  const auto poses = Perturbed(s.ground_truth, 0.03, 1.0, 3);
  const CandidateSet cand = Candidates(s, poses);
  NormalEquations one, two, four;
  AccumulateApeSystem(s.frames, cand, poses, 0, cand.num_voxels(), true, StreamContext{1}, &one);
  AccumulateApeSystem(s.frames, cand, poses, 0, cand.num_voxels(), true, StreamContext{2}, &two);
  AccumulateApeSystem(s.frames, cand, poses, 0, cand.num_voxels(), true, StreamContext{4}, &four);
  EXPECT_EQ(one.cost, two.cost);
  EXPECT_EQ(one.cost, four.cost);
  EXPECT_TRUE(one.hessian == two.hessian && one.hessian == four.hessian);
  EXPECT_TRUE(one.gradient == two.gradient && one.gradient == four.gradient);
}

TEST(LieNormalization, TemplatedLogEqualsCoreLog) {
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  std::vector<Vector6d> deltas;
  for (int trial = 0; trial < 500; ++trial) {
    Vector6d d;
    for (int c = 0; c < 6; ++c) d[c] = u(rng) * (c < 3 ? 20.0 : 1.5);
    deltas.push_back(d);
  }
  Vector6d tiny;
  tiny << 1.0, -2.0, 0.5, 1e-7, -2e-7, 3e-8;
  deltas.push_back(tiny);
  Vector6d near_pi;
  near_pi << 3.0, 1.0, -1.0, 0.0, 0.0, M_PI - 1e-6;
  deltas.push_back(near_pi);
  for (const Vector6d& d : deltas) {
    const Eigen::Isometry3d t = ExpSE3(d);
    double x[kPoseAmbientSize];
    PoseToParameters(t, x);
    double out[6];
    LogSE3Quaternion(x, x + 4, out);
    const Vector6d expected = LogSE3(t);
    for (int c = 0; c < 6; ++c) EXPECT_NEAR(out[c], expected[c], 1e-9 * (1.0 + expected.norm()));
  }
}

TEST(LieNormalization, PoseGraphRecoversConsistentMeasurementsExactly) {
  std::mt19937_64 rng(9);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  const int m = 6;
  std::vector<Eigen::Isometry3d> truth(m, Eigen::Isometry3d::Identity()), start(m);
  for (int i = 1; i < m; ++i) {
    Vector6d d;
    for (int c = 0; c < 6; ++c) d[c] = u(rng) * (c < 3 ? 10.0 : 0.3);
    truth[i] = ExpSE3(d);
  }
  std::vector<RelativePose> measurements;
  for (int i = 0; i < m; ++i) {
    for (int k = i + 1; k < m; ++k) {
      if (k - i <= 2) measurements.push_back({i, k, truth[k] * truth[i].inverse()});
    }
  }
  start[0] = truth[0];
  for (int i = 1; i < m; ++i) {
    Vector6d d;
    for (int c = 0; c < 6; ++c) d[c] = u(rng) * (c < 3 ? 2.0 : 0.05);
    start[i] = ExpSE3(d) * truth[i];
  }
  SolveOptions solve;
  solve.progress = false;
  std::vector<Eigen::Isometry3d> poses;
  SolveReport report;
  std::string error;
  ASSERT_TRUE(SolvePoseGraph(measurements, start, solve, &poses, &report, &error)) << error;
  EXPECT_TRUE(report.usable);
  EXPECT_THAT(poses, FramesFromWorldNear(truth, 1e-9, 1e-8));
  // One inconsistent measurement: the graph spreads it instead of following it alone.
  measurements[0].k_from_i = ExpSE3((Vector6d() << 1.0, 0, 0, 0, 0, 0).finished()) *
                             measurements[0].k_from_i;
  ASSERT_TRUE(SolvePoseGraph(measurements, start, solve, &poses, &report, &error)) << error;
  // The bad edge keeps part of its disagreement and its neighbours take the rest.
  const double bad_edge =
      LogSE3(measurements[0].k_from_i.inverse() * poses[1] * poses[0].inverse()).norm();
  const double next_edge =
      LogSE3(measurements[1].k_from_i.inverse() * poses[2] * poses[0].inverse()).norm();
  EXPECT_GT(bad_edge, 1e-3);
  EXPECT_LT(bad_edge, 0.99);
  EXPECT_GT(next_edge, 1e-3);
}

// ---- Every baseline recovers ground truth (pipeline, simulated from the phantom) -------

SimulatedSequence SmallSequence() {
  PhantomOptions phantom;
  phantom.size = 96;
  static const Image source = MakePhantom(phantom);
  SimulationOptions options;
  options.num_frames = 4;
  options.frame_size = Eigen::Vector3i(40, 40, 32);
  options.sigma = 0.0;
  options.max_translation_voxels = 4.0;
  options.max_rotation_deg = 8.0;
  options.min_depth_voxels = 2.0;
  options.seed = 4;
  SimulatedSequence sequence;
  std::string error;
  EXPECT_TRUE(Simulate(source, options, &sequence, &error)) << error;
  return sequence;
}

PoseErrorSummary RegisterWith(const std::string& mode, RegistrationResult* result) {
  static const SimulatedSequence sequence = SmallSequence();
  RegistrationOptions o;
  EXPECT_TRUE(StringToMode(mode, &o.mode)) << mode;
  o.solve.progress = getenv("DSR_TEST_LOG") != nullptr;
  o.solve.num_threads = 2;
  o.pyramid_levels = 2;
  o.pyramid_min_size = 8;
  const std::vector<Eigen::Isometry3d> identity(sequence.frames.size(),
                                                Eigen::Isometry3d::Identity());
  std::string error;
  EXPECT_TRUE(Register(sequence.frames, sequence.masks, identity, o, result, &error)) << error;
  EXPECT_TRUE(result->usable) << result->failure;
  const PoseErrorSummary errors =
      ComparePoses(result->frame_from_world, sequence.frame_from_world, sequence.masks);
  if (getenv("DSR_TEST_LOG") != nullptr)
    std::printf("%s\n%s", mode.c_str(), errors.Table().c_str());
  return errors;
}

class BaselineRecovery : public ::testing::TestWithParam<const char*> {};

TEST_P(BaselineRecovery, RecoversGroundTruthWithoutNoise) {
  RegistrationResult result;
  const PoseErrorSummary errors = RegisterWith(GetParam(), &result);
  // Noise-free frames are trilinear resamplings of the phantom at different sub-voxel
  // offsets (not exactly consistent): a floor of hundredths of a voxel for the pair-based
  // methods, whose errors also chain.
  EXPECT_LT(errors.mae_translation_voxels, 0.05);
  EXPECT_LT(errors.mae_rotation_rad, 2e-3);
  EXPECT_LT(errors.tre_mean_mm, 0.1);
  EXPECT_GT(result.total_iterations, 0);
  EXPECT_TRUE(result.frame_from_world[0].isApprox(Eigen::Isometry3d::Identity(), 1e-15));
}

INSTANTIATE_TEST_SUITE_P(Modes,
                         BaselineRecovery,
                         ::testing::Values("pairwise", "lie_normalization", "sequential", "ape"));

TEST(Baselines, PairwiseInitialiserFeedsTheMode) {
  static const SimulatedSequence sequence = SmallSequence();
  RegistrationOptions o;
  o.mode = dsr::Mode::kDsr;
  o.init = InitialPoses::kPairwise;
  o.solve.progress = false;
  o.solve.num_threads = 2;
  o.pyramid_levels = 2;
  o.pyramid_min_size = 8;
  const std::vector<Eigen::Isometry3d> identity(sequence.frames.size(),
                                                Eigen::Isometry3d::Identity());
  RegistrationResult result;
  std::string error;
  ASSERT_TRUE(Register(sequence.frames, sequence.masks, identity, o, &result, &error)) << error;
  ASSERT_TRUE(result.usable) << result.failure;
  EXPECT_GT(result.init_iterations, 0);
  ASSERT_EQ(result.init_frame_from_world.size(), sequence.frames.size());
  // The initialiser already moved the frames near the truth; DSR refined from there.
  const PoseErrorSummary init =
      ComparePoses(result.init_frame_from_world, sequence.frame_from_world, sequence.masks);
  const PoseErrorSummary final_errors =
      ComparePoses(result.frame_from_world, sequence.frame_from_world, sequence.masks);
  EXPECT_LT(init.mae_translation_voxels, 0.1);
  EXPECT_LT(final_errors.mae_translation_voxels, 0.02);
}

TEST(Baselines, OptionsAreValidated) {
  BaselineOptions o;
  std::string error;
  EXPECT_TRUE(o.Validate(&error)) << error;
  o.solve.linear_solver = ceres::SPARSE_SCHUR;
  EXPECT_FALSE(o.Validate(&error));
  EXPECT_NE(error.find("solve.linear_solver=SPARSE_SCHUR"), std::string::npos) << error;
  o = BaselineOptions();
  o.panorama_spacing = -1.0;
  EXPECT_FALSE(o.Validate(&error));
  EXPECT_NE(error.find("panorama_spacing="), std::string::npos) << error;
}

}  // namespace
}  // namespace dsr
