#include "dsr/solve/convergence.h"

#include <algorithm>
#include <cstdio>

#include <glog/logging.h>

#include "dsr/geometry/se3.h"

namespace dsr {

double MaxCornerMotionVoxels(const Frame& frame,
                             const Eigen::Isometry3d& a,
                             const Eigen::Isometry3d& b) {
  const Eigen::AlignedBox3d& box = frame.ValidIndexBox();
  if (box.isEmpty()) return 0.0;
  const Eigen::Isometry3d a_from_b = a * b.inverse();
  double motion = 0.0;
  for (int c = 0; c < 8; ++c) {
    const Eigen::Vector3d ijk = box.corner(static_cast<Eigen::AlignedBox3d::CornerType>(c));
    const Eigen::Vector3d x = frame.geometry().IndexToPhysical(ijk);
    // The world point seen at x under pose b is seen at a_from_b x under pose a.
    motion = std::max(motion, (frame.index_from_physical() * (a_from_b * x - x)).norm());
  }
  return motion;
}

double LargestMotionVoxels(const std::vector<Frame>& frames,
                           const std::vector<Eigen::Isometry3d>& a,
                           const std::vector<Eigen::Isometry3d>& b) {
  CHECK_EQ(a.size(), frames.size());
  CHECK_EQ(b.size(), frames.size());
  // Frame 0 moved (the mean gauge): compare the poses against frame 0's.
  const bool relative = a[0].matrix() != b[0].matrix();
  const Eigen::Isometry3d a0_inverse = a[0].inverse(), b0_inverse = b[0].inverse();
  double motion = 0.0;
  for (size_t i = 1; i < frames.size(); ++i) {
    motion = std::max(motion, relative ? MaxCornerMotionVoxels(frames[i], a[i] * a0_inverse,
                                                               b[i] * b0_inverse)
                                       : MaxCornerMotionVoxels(frames[i], a[i], b[i]));
  }
  return motion;
}

double RemainingMotionVoxels(double motion, double previous_motion) {
  constexpr double kMinContraction = 0.5;
  constexpr double kMaxContraction = 0.95;
  double rho = kMinContraction;
  if (previous_motion > 0.0) {
    rho = std::clamp(motion / previous_motion, kMinContraction, kMaxContraction);
  }
  return motion * rho / (1.0 - rho);
}

PoseStepCallback::PoseStepCallback(const std::vector<Frame>* frames,
                                   std::vector<const double*> pose_blocks,
                                   double tolerance_voxels,
                                   int max_rejected_steps)
    : frames_(frames),
      pose_blocks_(std::move(pose_blocks)),
      tolerance_voxels_(tolerance_voxels),
      max_rejected_steps_(max_rejected_steps) {
  CHECK_EQ(frames_->size(), pose_blocks_.size());
  for (size_t i = 1; i < pose_blocks_.size(); ++i) CHECK(pose_blocks_[i] != nullptr) << i;
  previous_ = Current();
}

void PoseStepCallback::AddTo(ceres::Solver::Options* options) {
  if (tolerance_voxels_ <= 0.0 && max_rejected_steps_ <= 0) return;
  options->update_state_every_iteration = true;
  options->callbacks.push_back(this);
}

std::vector<Eigen::Isometry3d> PoseStepCallback::Current() const {
  std::vector<Eigen::Isometry3d> poses;
  for (const double* block : pose_blocks_) {
    poses.push_back(block != nullptr ? ParametersToPose(block) : Eigen::Isometry3d::Identity());
  }
  return poses;
}

ceres::CallbackReturnType PoseStepCallback::operator()(const ceres::IterationSummary& summary) {
  if (summary.iteration == 0) return ceres::SOLVER_CONTINUE;
  if (!summary.step_is_successful) {
    ++rejected_in_a_row_;
    if (tolerance_voxels_ > 0.0 && trial_ends_solve_ && trial_ends_solve_()) {
      char text[160];
      std::snprintf(text, sizeof(text),
                    "pose step tolerance: a rejected step would have left less than %.2e "
                    "voxels to go",
                    tolerance_voxels_);
      reason_ = text;
      return ceres::SOLVER_TERMINATE_SUCCESSFULLY;
    }
    if (max_rejected_steps_ > 0 && rejected_in_a_row_ >= max_rejected_steps_) {
      reason_ = "no cost decrease in " + std::to_string(rejected_in_a_row_) +
                " steps in a row (at the noise floor)";
      return ceres::SOLVER_TERMINATE_SUCCESSFULLY;
    }
    return ceres::SOLVER_CONTINUE;
  }
  rejected_in_a_row_ = 0;
  const std::vector<Eigen::Isometry3d> now = Current();
  const double motion = LargestMotionVoxels(*frames_, previous_, now);
  previous_ = now;
  const double remaining = RemainingMotionVoxels(motion, previous_motion_);
  previous_motion_ = motion;
  if (tolerance_voxels_ > 0.0 && remaining < tolerance_voxels_) {
    char text[200];
    std::snprintf(text, sizeof(text),
                  "pose step tolerance: the last step moved no field of view by more than "
                  "%.2e voxels, %.2e voxels estimated still to go (< %.2e)",
                  motion, remaining, tolerance_voxels_);
    reason_ = text;
    return ceres::SOLVER_TERMINATE_SUCCESSFULLY;
  }
  return ceres::SOLVER_CONTINUE;
}

}  // namespace dsr
