// The mean gauge (solve/gauge.h): every pose free, a prior on their mean displacement.
//  * the prior's Jacobian against central differences of the prior itself, and its
//    displacement the same for every frame under one world motion;
//  * the fast chunk cost against the per-voxel reference, through Ceres (cost, gradient and
//    Gauss-Newton matrix, frame 0's pose block included, with and without photometric
//    parameters);
//  * the mean frame a registration's solves run in;
//  * full solves of both costs reach the same poses, which are the ground truth on exact
//    problems relative to frame 0 (they are returned in the start's world, frame 0 moved);
// Reusing passes in the mean gauge: streamed_cost_test.
#include <array>
#include <random>
#include <vector>

#include <ceres/ceres.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "dsr/dsr_reduced/dsr_solver.h"
#include "dsr/dsr_reduced/reduced_cost.h"
#include "dsr/geometry/se3.h"
#include "dsr/solve/gauge.h"
#include "dsr/stream/reduced_system.h"
#include "dsr/tests/support/fixed_point_options.h"
#include "dsr/tests/support/pose_matchers.h"
#include "dsr/tests/support/sanitizer.h"
#include "dsr/tests/support/test_problems.h"
#include "dsr/tests/support/tolerances.h"

namespace dsr {
namespace {

using testing_problems::Candidates;
using testing_problems::DenseJacobian;
using testing_problems::InteriorCandidates;
using testing_problems::MakeSequence;
using testing_problems::MovedTogether;
using testing_problems::Perturbed;
using testing_problems::SequenceOptions;
using testing_poses::FramesFromWorldNear;
using testing_solve::FixedPointOptions;
using testing_tolerances::kFixedPointRotationRad;
using testing_tolerances::kFixedPointTranslationMm;
using testing_tolerances::kSystemRelativeTolerance;

Vector6d RandomTangent(std::mt19937_64* rng, double translation, double rotation) {
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  Vector6d d;
  d << translation * u(*rng), translation * u(*rng), translation * u(*rng), rotation * u(*rng),
      rotation * u(*rng), rotation * u(*rng);
  return d;
}

TEST(Gauge, NamesRoundTrip) {
  for (Gauge g : {Gauge::kFrame0, Gauge::kMean}) {
    Gauge back = g == Gauge::kMean ? Gauge::kFrame0 : Gauge::kMean;
    ASSERT_TRUE(StringToGauge(GaugeToString(g), &back));
    EXPECT_EQ(back, g);
  }
  Gauge untouched = Gauge::kMean;
  EXPECT_FALSE(StringToGauge("frame_0", &untouched));
  EXPECT_EQ(untouched, Gauge::kMean);
}

// The prior through Ceres's ambient Jacobian and the pose manifold's PlusJacobian, against
// central differences of its residuals under T <- Exp(h e_k) T, away from the initial poses
// and across the quaternion sign flip (frame 3 turned by up to 3 rad).
TEST(MeanPosePrior, JacobianMatchesCentralDifferences) {
  std::mt19937_64 rng(7);
  const int m = 4;
  std::vector<Eigen::Isometry3d> initial(m), current(m);
  std::vector<Eigen::Vector3d> centres(m);
  for (int i = 0; i < m; ++i) {
    initial[i] = ExpSE3(RandomTangent(&rng, 20.0, 0.5));
    current[i] = ExpSE3(RandomTangent(&rng, 3.0, i == 3 ? 3.0 : 0.3)) * initial[i];
    centres[i] = RandomTangent(&rng, 40.0, 0.0).head<3>();
  }
  Vector6d stiffness;
  stiffness << 4.0, 9.0, 1.0, 100.0, 25.0, 16.0;
  MeanPosePrior prior(initial, centres, stiffness);
  std::vector<std::array<double, kPoseAmbientSize>> x(m);
  std::vector<const double*> parameters;
  for (int i = 0; i < m; ++i) {
    PoseToParameters(current[i], x[i].data());
    parameters.push_back(x[i].data());
  }
  Vector6d r;
  std::vector<Eigen::Matrix<double, 6, kPoseAmbientSize, Eigen::RowMajor>> ambient(m);
  std::vector<double*> jacobians;
  for (auto& j : ambient) jacobians.push_back(j.data());
  ASSERT_TRUE(prior.Evaluate(parameters.data(), r.data(), jacobians.data()));
  PoseManifold manifold;
  const double h = 1e-6;
  for (int i = 0; i < m; ++i) {
    Eigen::Matrix<double, kPoseAmbientSize, 6, Eigen::RowMajor> plus;
    ASSERT_TRUE(manifold.PlusJacobian(x[i].data(), plus.data()));
    const Matrix6d analytic = ambient[i] * plus;
    Matrix6d numeric;
    for (int k = 0; k < 6; ++k) {
      Vector6d residual[2];
      for (int side = 0; side < 2; ++side) {
        std::array<double, kPoseAmbientSize> moved;
        PoseToParameters(ExpSE3((side == 0 ? h : -h) * Vector6d::Unit(k)) * current[i],
                         moved.data());
        std::vector<const double*> at = parameters;
        at[i] = moved.data();
        ASSERT_TRUE(prior.Evaluate(at.data(), residual[side].data(), nullptr));
      }
      numeric.col(k) = (residual[0] - residual[1]) / (2.0 * h);
    }
    EXPECT_LT((analytic - numeric).norm(), 1e-7 * std::max(1.0, numeric.norm())) << "frame " << i
        << "\nanalytic\n" << analytic << "\nnumeric\n" << numeric;
  }
  // Zero at the initial poses.
  std::vector<std::array<double, kPoseAmbientSize>> x0(m);
  for (int i = 0; i < m; ++i) {
    PoseToParameters(initial[i], x0[i].data());
    parameters[i] = x0[i].data();
  }
  ASSERT_TRUE(prior.Evaluate(parameters.data(), r.data(), nullptr));
  EXPECT_LT(r.norm(), 1e-12);
}

// One world motion G of every frame (T_i -> T_i G) is one displacement: the same rotation
// part for every frame, and for a translation the same centre part. So the prior's reaction
// is a common force on the rigid set of frames, not a push of some frames against others.
TEST(PoseDisplacement, IsTheSameForEveryFrameUnderOneWorldMotion) {
  std::mt19937_64 rng(11);
  std::vector<Eigen::Isometry3d> initial;
  std::vector<Eigen::Vector3d> centres;
  for (int i = 0; i < 3; ++i) {
    initial.push_back(ExpSE3(RandomTangent(&rng, 15.0, 0.3)));
    centres.push_back(RandomTangent(&rng, 40.0, 0.0).head<3>());
  }
  const Eigen::Isometry3d turn = ExpSE3(RandomTangent(&rng, 2.0, 0.05));
  const Eigen::Isometry3d shift(Eigen::Translation3d(0.3, -0.4, 0.2));
  for (int i = 0; i < 3; ++i) {
    const Vector6d turned = PoseDisplacement(initial[i] * turn, initial[i], centres[i]);
    const Vector6d turned0 = PoseDisplacement(initial[0] * turn, initial[0], centres[0]);
    EXPECT_LT((turned.tail<3>() - turned0.tail<3>()).norm(), 1e-12) << i;
    const Vector6d shifted = PoseDisplacement(initial[i] * shift, initial[i], centres[i]);
    EXPECT_LT((shifted.head<3>() + shift.translation()).norm(), 1e-12) << i;
    EXPECT_LT(shifted.tail<3>().norm(), 1e-12) << i;
  }
}

// The mean frame: one world motion G of every frame moves it by G^-1 (so the world a solve
// runs in, built on it, is the same whatever world the poses came in); orientations spread
// symmetrically about R average to R; frames of one orientation give it exactly, and the
// origin is the mean of the centres' world positions.
TEST(MeanFrame, FollowsAWorldMotionAndAveragesOrientationsAndCentres) {
  std::mt19937_64 rng(17);
  std::vector<Eigen::Isometry3d> poses;
  std::vector<Eigen::Vector3d> centres;
  for (int i = 0; i < 4; ++i) {
    poses.push_back(ExpSE3(RandomTangent(&rng, 20.0, 0.4)));
    centres.push_back(RandomTangent(&rng, 40.0, 0.0).head<3>());
  }
  const Eigen::Isometry3d mean = MeanFrame(poses, centres);
  EXPECT_LT((mean.linear().transpose() * mean.linear() - Eigen::Matrix3d::Identity()).norm(),
            1e-12);
  EXPECT_NEAR(mean.linear().determinant(), 1.0, 1e-12);
  const Eigen::Isometry3d world_motion = ExpSE3(RandomTangent(&rng, 30.0, 1.0));
  std::vector<Eigen::Isometry3d> moved = poses;
  for (auto& pose : moved) pose = pose * world_motion;
  EXPECT_LT((MeanFrame(moved, centres).matrix() - (world_motion.inverse() * mean).matrix())
                .norm(),
            1e-9);

  const Eigen::Isometry3d orientation = ExpSE3(RandomTangent(&rng, 0.0, 1.5));
  const Vector6d spread = RandomTangent(&rng, 0.0, 0.3);
  std::vector<Eigen::Isometry3d> symmetric;
  Eigen::Vector3d world_centres = Eigen::Vector3d::Zero();
  for (int i = 0; i < 4; ++i) {
    // frame_from_world = (R Exp(+-phi) + shift)^-1, with the shifts' mean world centre.
    Eigen::Isometry3d world_from_frame = orientation * ExpSE3((i % 2 == 0 ? 1.0 : -1.0) * spread);
    world_from_frame.translation() = RandomTangent(&rng, 25.0, 0.0).head<3>();
    world_centres += world_from_frame * centres[i];
    symmetric.push_back(world_from_frame.inverse());
  }
  const Eigen::Isometry3d symmetric_mean = MeanFrame(symmetric, centres);
  EXPECT_LT((symmetric_mean.linear() - orientation.linear()).norm(), 1e-12);
  EXPECT_LT((symmetric_mean.translation() - world_centres / 4.0).norm(), 1e-12);

  const std::vector<Eigen::Isometry3d> one(3, poses[1]);
  EXPECT_LT((MeanFrame(one, {centres[0], centres[1], centres[2]}).linear() -
             poses[1].inverse().linear())
                .norm(),
            1e-12);
}

TEST(MeanGaugeStiffness, IsMTimesTheMeanDiagonalPerKind) {
  const int m = 3, p = 8;
  Eigen::MatrixXd h = Eigen::MatrixXd::Zero(p * m, p * m);
  for (int i = 0; i < m; ++i) {
    for (int k = 0; k < 3; ++k) h(p * i + k, p * i + k) = 2.0 * (i + 1);       // mean 4
    for (int k = 3; k < 6; ++k) h(p * i + k, p * i + k) = 100.0 * (i + 1);     // mean 200
    h(p * i + 6, p * i + 6) = h(p * i + 7, p * i + 7) = 1e9;                   // photometric
  }
  const Vector6d s = MeanGaugeStiffness(h, m, p);
  for (int k = 0; k < 3; ++k) EXPECT_DOUBLE_EQ(s[k], 3.0 * 4.0);
  for (int k = 3; k < 6; ++k) EXPECT_DOUBLE_EQ(s[k], 3.0 * 200.0);
  EXPECT_EQ(MeanGaugeStiffness(Eigen::MatrixXd::Zero(6 * m, 6 * m), m, 6), Vector6d::Ones());
}

// A small noisy sequence (14^3 frames, noise 5) and a start every frame is off from, frame 0
// included (all moved together too), with its candidates; *seed advances by 3.
struct NoisyStart {
  testing_problems::TestSequence sequence;
  std::vector<Eigen::Isometry3d> poses;
  CandidateSet candidates;
};
NoisyStart MakeNoisyStart(int num_frames, uint64_t* seed) {
  SequenceOptions o;
  o.num_frames = num_frames;
  o.size = 14;
  o.noise_sigma = 5.0;
  o.seed = (*seed)++;
  NoisyStart start;
  start.sequence = MakeSequence(o);
  start.poses = MovedTogether(Perturbed(start.sequence.ground_truth, 0.03, 1.0, *seed), *seed + 1);
  *seed += 2;
  start.candidates = Candidates(start.sequence, start.poses);
  return start;
}

// The fast path's prior stiffness comes from its chunks' passes at the initial poses, which
// they keep for the solve's first evaluation (one pass fewer per solve): MeanGaugeStiffnessAt's
// (one pass over every candidate at the given poses) to rounding (the chunks evaluate at
// the poses of their parameter blocks, quaternions); evaluating the problem there with
// Jacobians makes no second pass.
TEST(MeanGauge, PriorStiffnessIsTheChunksPassAtTheStart) {
  uint64_t seed = 401;
  for (bool photometric : {false, true}) {
    const NoisyStart p = MakeNoisyStart(4, &seed);
    const auto& s = p.sequence;
    const auto& poses = p.poses;
    const CandidateSet& cand = p.candidates;
    std::vector<Photometric> gains;
    if (photometric) {
      gains.assign(s.frames.size(), Photometric{});
      for (size_t i = 1; i < gains.size(); ++i) gains[i] = {0.05 * i, 3.0 * i};
    }
    const Vector6d expected =
        MeanGaugeStiffnessAt(s.frames, cand, poses, gains, nullptr, StreamContext{2});
    for (int chunks : {1, 3}) {
      DsrOptions options;
      options.gauge = Gauge::kMean;
      options.photometric = photometric;
      options.initial_photometric = gains;
      options.num_chunks = chunks;
      options.solve.num_threads = 2;
      DsrProblem problem(s.frames, cand, poses, options);
      for (int k = 0; k < 6; ++k) {
        EXPECT_NEAR(problem.gauge_stiffness()[k], expected[k], 1e-12 * expected[k]) << k;
      }
      for (const ReducedChunkCost* chunk : problem.chunks()) {
        EXPECT_EQ(chunk->pass_counts().jacobian_passes, 1) << chunks;  // the stiffness's
      }
      double cost = 0.0;
      std::vector<double> gradient;
      ceres::CRSMatrix jacobian;
      ASSERT_TRUE(problem.problem().Evaluate(ceres::Problem::EvaluateOptions(), &cost, nullptr,
                                             &gradient, &jacobian));
      for (const ReducedChunkCost* chunk : problem.chunks()) {
        EXPECT_EQ(chunk->pass_counts().jacobian_passes, 1) << chunks;  // no second pass
        EXPECT_EQ(chunk->pass_counts().cost_passes, 0) << chunks;
      }
    }
  }
}

// Fast path and reference in the mean gauge: the same cost, gradient and Gauss-Newton matrix
// over every pose (frame 0's included) and the photometric blocks of frames 1..m-1.
TEST(MeanGauge, FastPathMatchesPerVoxelReference) {
  uint64_t seed = 301;
  for (bool photometric : {false, true}) {
    for (int num_frames : {3, 4}) {
      const NoisyStart p = MakeNoisyStart(num_frames, &seed);
      const auto& s = p.sequence;
      const auto& poses = p.poses;
      const CandidateSet& cand = p.candidates;
      DsrOptions ref_options;
      ref_options.reference_cost = true;
      ref_options.gauge = Gauge::kMean;
      ref_options.photometric = photometric;
      if (photometric) {
        std::mt19937_64 rng(seed++);
        std::uniform_real_distribution<double> u(-0.1, 0.1);
        ref_options.initial_photometric.assign(num_frames, Photometric{});
        for (int i = 1; i < num_frames; ++i) {
          ref_options.initial_photometric[i] = {u(rng), 50.0 * u(rng)};
        }
      }
      const auto blocks_of = [&](DsrProblem* problem) {
        std::vector<double*> blocks;
        for (int i = 0; i < num_frames; ++i) blocks.push_back(problem->pose_parameters(i));
        for (int i = 1; photometric && i < num_frames; ++i) {
          blocks.push_back(problem->photometric_parameters(i));
        }
        return blocks;
      };
      DsrProblem reference(s.frames, cand, poses, ref_options);
      Eigen::VectorXd r;
      double ref_cost;
      const Eigen::MatrixXd j = DenseJacobian(&reference.problem(), blocks_of(&reference), &r,
                                              &ref_cost);
      ASSERT_EQ(j.cols(), 6 * num_frames + (photometric ? 2 * (num_frames - 1) : 0));
      const Eigen::MatrixXd ref_h = j.transpose() * j;
      const Eigen::VectorXd ref_g = j.transpose() * r;
      for (int chunks : {1, 3}) {
        DsrOptions fast_options = ref_options;
        fast_options.reference_cost = false;
        fast_options.num_chunks = chunks;
        fast_options.solve.num_threads = 2;
        DsrProblem fast(s.frames, cand, poses, fast_options);
        Eigen::VectorXd fr;
        double fast_cost;
        const Eigen::MatrixXd fj = DenseJacobian(&fast.problem(), blocks_of(&fast), &fr,
                                                 &fast_cost);
        EXPECT_NEAR(fast_cost, ref_cost, kSystemRelativeTolerance * ref_cost);
        EXPECT_LT((fj.transpose() * fr - ref_g).norm() / ref_g.norm(),
                  kSystemRelativeTolerance * 10)
            << "chunks=" << chunks << " photometric=" << photometric;
        EXPECT_LT((fj.transpose() * fj - ref_h).norm() / ref_h.norm(), kSystemRelativeTolerance)
            << "chunks=" << chunks << " photometric=" << photometric;
      }
    }
  }
}


// On lattice-aligned problems (every residual vanishes at the ground truth; see
// dsr_theorem_test) both costs in the mean gauge converge from a start where every frame,
// frame 0 included, is off, to the ground truth relative to frame 0.
TEST(MeanGauge, SolvesOfBothCostsReachTheGroundTruthRelativeToFrame0) {
  DSR_SKIP_HEAVY_UNDER_SANITIZER();
  uint64_t seed = 351;
  for (int num_frames : {3, 4}) {
    SequenceOptions o;
    o.num_frames = num_frames;
    o.size = 16;
    o.noise_sigma = 0.0;
    o.lattice = true;
    o.seed = seed++;
    const auto s = MakeSequence(o);
    const auto init = MovedTogether(Perturbed(s.ground_truth, 0.02, 0.5, seed), seed + 1);
    seed += 2;
    const CandidateSet cand = InteriorCandidates(s, init, 1.5);
    ASSERT_GT(cand.num_voxels(), 200);
    std::vector<std::vector<Eigen::Isometry3d>> results;
    for (bool reference : {false, true}) {
      DsrOptions options;
      options.solve = FixedPointOptions(1000);
      options.gauge = Gauge::kMean;
      options.reference_cost = reference;
      SolveReport report;
      std::string error;
      ASSERT_TRUE(SolveDsr(s.frames, cand, init, options, &report, &error)) << error;
      ASSERT_TRUE(report.usable) << report.termination;
      // The poses come back in the start's world, where frame 0 moved too.
      EXPECT_GT((report.frame_from_world[0].matrix() - init[0].matrix()).norm(), 1e-6);
      const std::vector<Eigen::Isometry3d> relative = RelativeToFrame0(report.frame_from_world);
      EXPECT_THAT(relative, FramesFromWorldNear(s.ground_truth, kFixedPointRotationRad,
                                                kFixedPointTranslationMm))
          << "m=" << num_frames << " reference=" << reference;
      results.push_back(relative);
    }
    EXPECT_THAT(results[0],
                FramesFromWorldNear(results[1], kFixedPointRotationRad, kFixedPointTranslationMm));
  }
}

}  // namespace
}  // namespace dsr
