// Accuracy against ground truth (docs/design.md section 6): frame-0-relative pose errors.
//
// Both pose sets are re-expressed relative to frame 0 (T_i <- T_i T_0^-1) first, so any
// world convention of the ground truth works. Per frame i >= 1:
//   translation error   t_est - t_gt of the relative poses (mm, and voxels of frame i),
//   Euler angle error   angles(R_est) - angles(R_gt), R = Rz(gamma) Ry(beta) Rx(alpha)
//                       (the simulator's convention), wrapped to (-pi, pi],
//   target registration error (TRE): for the centres x of frame i's field-of-view voxels,
//                       |T_est^-1 x - T_gt^-1 x| in world mm (mean and max);
//   centre error        the mean of T_est^-1 x - T_gt^-1 x over the same points (the error
//                       at the field of view's centroid: a rigid error moves points affinely).
// Summaries average the absolute component errors over frames 1..m-1 (the paper's MAE),
// and split the centre errors into the part every frame shares (the mean over frames
// 1..m-1: frame 0 off against the rest) and the spread about it (docs/design.md 6.5).
#ifndef DSR_EVAL_EVAL_H_
#define DSR_EVAL_EVAL_H_

#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "dsr/geometry/volume.h"

namespace dsr {

// Euler angles (alpha, beta, gamma) with R = Rz(gamma) Ry(beta) Rx(alpha).
Eigen::Vector3d EulerZyxAngles(const Eigen::Matrix3d& rotation);

struct FramePoseError {
  Eigen::Vector3d translation_mm = Eigen::Vector3d::Zero();
  Eigen::Vector3d translation_voxels = Eigen::Vector3d::Zero();
  Eigen::Vector3d euler_rad = Eigen::Vector3d::Zero();
  double rotation_angle_rad = 0.0;  // angle of R_est R_gt^T
  double tre_mean_mm = 0.0;
  double tre_max_mm = 0.0;
  Eigen::Vector3d centre_error_mm = Eigen::Vector3d::Zero();  // world (frame 0's) axes
};

struct PoseErrorSummary {
  std::vector<FramePoseError> frames;  // frames[0] is zero by construction
  double mae_translation_voxels = 0.0;
  double mae_translation_mm = 0.0;
  double mae_rotation_rad = 0.0;
  double tre_mean_mm = 0.0;  // mean over frames of each frame's mean TRE
  double tre_max_mm = 0.0;   // max over frames and points
  // Mean of the centre errors over frames 1..m-1, in frame 0's physical axes (what every
  // frame shares: frame 0's own error against the rest), and the mean distance of the
  // centre errors from it (the frames' errors against each other).
  Eigen::Vector3d shared_offset_mm = Eigen::Vector3d::Zero();
  double frame_spread_mm = 0.0;
  // A per-frame table (one line per frame) for terminals and reports.
  std::string Table() const;
};

// `masks[i]` gives frame i's grid (for voxel units) and field of view (for TRE; every
// `tre_stride`-th voxel along each axis). Sizes must match (CHECKed).
PoseErrorSummary ComparePoses(const std::vector<Eigen::Isometry3d>& estimated_frame_from_world,
                              const std::vector<Eigen::Isometry3d>& true_frame_from_world,
                              const std::vector<Mask>& masks,
                              int tre_stride = 2);

}  // namespace dsr

#endif  // DSR_EVAL_EVAL_H_
