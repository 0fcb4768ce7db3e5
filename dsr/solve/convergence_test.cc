// The pose stopping rule (solve/convergence.h): the distance still to go estimated from
// the last two accepted steps, and the callback that ends a solve by it.
#include "dsr/solve/convergence.h"

#include <cmath>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "dsr/geometry/se3.h"
#include "dsr/geometry/volume.h"
#include "dsr/image/frame.h"

namespace dsr {
namespace {

TEST(RemainingMotionVoxels, SumsTheStepsStillToComeOfALinearConvergence) {
  // Steps contracting by 0.9: 0.9 + 0.81 + ... = 9 times the last step.
  EXPECT_NEAR(RemainingMotionVoxels(0.9e-3, 1e-3), 9 * 0.9e-3, 1e-15);
  EXPECT_NEAR(RemainingMotionVoxels(0.6e-3, 1e-3), 1.5 * 0.6e-3, 1e-15);
  // Never below the step itself (what the rule read before): fast contraction, or no
  // step before this one.
  EXPECT_DOUBLE_EQ(RemainingMotionVoxels(1e-4, 1e-2), 1e-4);
  EXPECT_DOUBLE_EQ(RemainingMotionVoxels(2e-3, 0.0), 2e-3);
  // A step longer than the one before: at most 19 steps more.
  EXPECT_NEAR(RemainingMotionVoxels(2e-3, 1e-3), 19 * 2e-3, 1e-15);
  EXPECT_EQ(RemainingMotionVoxels(0.0, 1e-3), 0.0);
}

// A 12^3 frame of 1 mm voxels whose mask is the whole grid.
Frame UnitFrame() {
  ImageGeometry g;
  g.size = Eigen::Vector3i(12, 12, 12);
  Image image(g, 0.0f);
  for (int64_t v = 0; v < g.NumVoxels(); ++v) image.voxels[v] = static_cast<float>(v % 7);
  return Frame(image, Mask(g, 1));
}

// When frame 0 moves too (the mean gauge), the motion is measured against frame 0's: every
// frame moved by one world motion has not moved; frame 0 moved alone moves the others.
TEST(LargestMotionVoxels, MeasuresAgainstFrame0WhenFrame0Moves) {
  const std::vector<Frame> frames = {UnitFrame(), UnitFrame(), UnitFrame()};
  Vector6d d;
  d << 0.3, -0.2, 0.5, 0.01, -0.02, 0.015;
  std::vector<Eigen::Isometry3d> a = {Eigen::Isometry3d::Identity(), ExpSE3(0.5 * d),
                                      ExpSE3(-d)};
  std::vector<Eigen::Isometry3d> together = a;
  for (auto& pose : together) pose = pose * ExpSE3(d);
  EXPECT_LT(LargestMotionVoxels(frames, a, together), 1e-12);
  std::vector<Eigen::Isometry3d> frame0_alone = a;
  frame0_alone[0] = Eigen::Isometry3d(Eigen::Translation3d(0.25, 0.0, 0.0));
  // Frames 1 and 2 now sit 0.25 voxel further along -x against frame 0 (unit voxels).
  EXPECT_NEAR(LargestMotionVoxels(frames, a, frame0_alone), 0.25, 1e-9);
  // With frame 0 fixed, the former rule: frame 1's own motion.
  std::vector<Eigen::Isometry3d> frame1_moved = a;
  frame1_moved[1] = Eigen::Isometry3d(Eigen::Translation3d(0.0, 0.125, 0.0)) * a[1];
  EXPECT_NEAR(LargestMotionVoxels(frames, a, frame1_moved), 0.125, 1e-12);
}

// Runs a PoseStepCallback with `tolerance` over accepted steps that translate frame 1 of
// `frames` by first * ratio^k voxels at step k; returns the k whose step ended the solve
// (-1: none in `max_steps`) and the callback's reason.
int StepThatEndsTheSolve(const std::vector<Frame>& frames, double tolerance, double first,
                         double ratio, int max_steps, std::string* reason) {
  double x[kPoseAmbientSize];
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  PoseToParameters(pose, x);
  PoseStepCallback stop(&frames, {nullptr, x}, tolerance, /*max_rejected_steps=*/5);
  ceres::IterationSummary summary;
  summary.iteration = 0;
  EXPECT_EQ(stop(summary), ceres::SOLVER_CONTINUE);
  summary.step_is_successful = true;
  int ended = -1;
  for (int k = 0; k < max_steps && ended < 0; ++k) {
    pose.translation().x() += first * std::pow(ratio, k);
    PoseToParameters(pose, x);
    summary.iteration = k + 1;
    if (stop(summary) == ceres::SOLVER_TERMINATE_SUCCESSFULLY) ended = k;
  }
  *reason = stop.reason();
  return ended;
}

TEST(PoseStepCallback, StopsWhenTheEstimatedDistanceLeftIsBelowTheTolerance) {
  const std::vector<Frame> frames = {UnitFrame(), UnitFrame()};
  const double tolerance = 0.02;
  std::string reason;
  // Steps of 0.05 * 0.9^k: every step from k = 9 on is below the tolerance, but 9 steps'
  // worth is still to go until 9 * 0.05 * 0.9^k < 0.02, at k = 30.
  EXPECT_LT(0.05 * std::pow(0.9, 9), tolerance);
  EXPECT_EQ(StepThatEndsTheSolve(frames, tolerance, 0.05, 0.9, 60, &reason), 30);
  EXPECT_NE(reason.find("estimated still to go"), std::string::npos) << reason;
  // A solve's first step has no step before it to estimate rho from: the estimate is the
  // step itself, so a first step below the tolerance ends the solve, as under the former
  // rule.
  EXPECT_EQ(StepThatEndsTheSolve(frames, tolerance, 0.01, 0.9, 60, &reason), 0);
  // Steps that halve: the estimate is the step, and the solve ends at the first step below
  // the tolerance (0.05 / 2^2 = 0.0125), as under the former rule.
  EXPECT_EQ(StepThatEndsTheSolve(frames, tolerance, 0.05, 0.5, 60, &reason), 2);
}

TEST(PoseStepCallback, EndsAfterTheRejectedStepsLimit) {
  const std::vector<Frame> frames = {UnitFrame(), UnitFrame()};
  double x[kPoseAmbientSize];
  PoseToParameters(Eigen::Isometry3d::Identity(), x);
  PoseStepCallback stop(&frames, {nullptr, x}, 1e-3, /*max_rejected_steps=*/3);
  ceres::IterationSummary summary;
  summary.iteration = 0;
  ASSERT_EQ(stop(summary), ceres::SOLVER_CONTINUE);
  summary.step_is_successful = false;
  for (int k = 1; k <= 2; ++k) {
    summary.iteration = k;
    EXPECT_EQ(stop(summary), ceres::SOLVER_CONTINUE);
  }
  summary.iteration = 3;
  EXPECT_EQ(stop(summary), ceres::SOLVER_TERMINATE_SUCCESSFULLY);
  EXPECT_NE(stop.reason().find("3 steps in a row"), std::string::npos) << stop.reason();
}

// A rejected step that the streamed blocks found would have ended the solve by the rule
// (within the tolerance of its fixed point) ends it at once, without the run of rejected
// steps; one that would not, does not; and without a tolerance the rule is off.
TEST(PoseStepCallback, ARejectedStepWithinTheToleranceEndsTheSolve) {
  const std::vector<Frame> frames = {UnitFrame(), UnitFrame()};
  double x[kPoseAmbientSize];
  PoseToParameters(Eigen::Isometry3d::Identity(), x);
  for (double tolerance : {1e-3, 0.0}) {
    bool trial_ends_solve = false;
    PoseStepCallback stop(&frames, {nullptr, x}, tolerance, /*max_rejected_steps=*/5);
    stop.SetTrialEndsSolve([&] { return trial_ends_solve; });
    ceres::IterationSummary summary;
    summary.iteration = 0;
    ASSERT_EQ(stop(summary), ceres::SOLVER_CONTINUE);
    summary.step_is_successful = false;
    summary.iteration = 1;
    EXPECT_EQ(stop(summary), ceres::SOLVER_CONTINUE);  // a step beyond the tolerance
    trial_ends_solve = true;
    summary.iteration = 2;
    if (tolerance > 0.0) {
      EXPECT_EQ(stop(summary), ceres::SOLVER_TERMINATE_SUCCESSFULLY);
      EXPECT_NE(stop.reason().find("a rejected step would have left less than"),
                std::string::npos)
          << stop.reason();
    } else {
      EXPECT_EQ(stop(summary), ceres::SOLVER_CONTINUE);
    }
  }
}

}  // namespace
}  // namespace dsr
