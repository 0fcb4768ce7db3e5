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

TEST(PoseStepCallback, StopsWhenTheEstimatedDistanceLeftIsBelowTheTolerance) {
  const std::vector<Frame> frames = {UnitFrame(), UnitFrame()};
  double x[kPoseAmbientSize];
  PoseToParameters(Eigen::Isometry3d::Identity(), x);
  const double tolerance = 0.02;
  PoseStepCallback stop(&frames, {nullptr, x}, tolerance, /*max_rejected_steps=*/5);
  ceres::IterationSummary summary;
  summary.iteration = 0;
  ASSERT_EQ(stop(summary), ceres::SOLVER_CONTINUE);
  // Frame 1 translates by 0.01 * 0.9^k voxels at step k: every step is below the
  // tolerance, but 9 steps' worth is still to go until 9 * 0.01 * 0.9^k < 0.02.
  double position = 0.0;
  int stopped_at = -1;
  for (int k = 0; k < 40 && stopped_at < 0; ++k) {
    position += 0.01 * std::pow(0.9, k);
    Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
    pose.translation().x() = position;
    PoseToParameters(pose, x);
    summary.iteration = k + 1;
    summary.step_is_successful = true;
    if (stop(summary) == ceres::SOLVER_TERMINATE_SUCCESSFULLY) stopped_at = k;
  }
  // Step 0 has no step before it (estimate: the step, 0.01 < 0.02) and ends the solve as
  // the former rule did; so start again from a second callback that has seen a step.
  EXPECT_EQ(stopped_at, 0);
  EXPECT_NE(stop.reason().find("estimated still to go"), std::string::npos) << stop.reason();

  PoseToParameters(Eigen::Isometry3d::Identity(), x);
  PoseStepCallback slow(&frames, {nullptr, x}, tolerance, 5);
  summary.iteration = 0;
  ASSERT_EQ(slow(summary), ceres::SOLVER_CONTINUE);
  position = 0.0;
  stopped_at = -1;
  int first_step_below = -1;
  for (int k = 0; k < 60 && stopped_at < 0; ++k) {
    const double step = 0.05 * std::pow(0.9, k);
    if (first_step_below < 0 && step < tolerance) first_step_below = k;
    position += step;
    Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
    pose.translation().x() = position;
    PoseToParameters(pose, x);
    summary.iteration = k + 1;
    if (slow(summary) == ceres::SOLVER_TERMINATE_SUCCESSFULLY) stopped_at = k;
  }
  // It goes on past the first step under the tolerance (k = 9), to the first k with
  // 9 * 0.05 * 0.9^k < 0.02 (k = 30).
  EXPECT_EQ(first_step_below, 9);
  EXPECT_EQ(stopped_at, 30);
}

TEST(PoseStepCallback, RejectedStepsDoNotCountAsSteps) {
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

}  // namespace
}  // namespace dsr
