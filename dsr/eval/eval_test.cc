// ComparePoses's split of the frames' centre errors into the offset they share (frame 0 off
// against the rest) and their spread about it (eval/eval.h).
#include "dsr/eval/eval.h"

#include <vector>

#include <gtest/gtest.h>

namespace dsr {
namespace {

// A 10^3 mask of 1 mm voxels, full except its first slice (so its centroid, the mean of its
// TRE points, is not the grid's centre).
Mask TestMask() {
  ImageGeometry g;
  g.size = Eigen::Vector3i(10, 10, 10);
  Mask mask(g, 1);
  for (int j = 0; j < 10; ++j)
    for (int i = 0; i < 10; ++i) mask.voxels[g.LinearIndex(i, j, 0)] = 0;
  return mask;
}

// Frame 0 at the world origin and frames 1..3 at known poses, the truth the tests perturb.
std::vector<Eigen::Isometry3d> Truth() {
  std::vector<Eigen::Isometry3d> truth(4, Eigen::Isometry3d::Identity());
  for (int i = 1; i < 4; ++i) {
    truth[i].translate(Eigen::Vector3d(2.0 * i, -1.0, 0.5 * i));
    truth[i].rotate(Eigen::AngleAxisd(0.1 * i, Eigen::Vector3d::UnitZ()));
  }
  return truth;
}

TEST(ComparePoses, ACommonWorldShiftIsTheSharedOffset) {
  // Every frame i >= 1 sees the world moved by d: T_est^-1 x = T_gt^-1 x + d everywhere.
  const std::vector<Eigen::Isometry3d> truth = Truth();
  const Eigen::Vector3d d(0.03, -0.02, 0.01);
  std::vector<Eigen::Isometry3d> estimate = truth;
  for (int i = 1; i < 4; ++i) estimate[i] = truth[i] * Eigen::Translation3d(-d);
  const std::vector<Mask> masks(4, TestMask());
  const PoseErrorSummary e = ComparePoses(estimate, truth, masks, 1);
  EXPECT_LT((e.shared_offset_mm - d).norm(), 1e-12);
  EXPECT_LT(e.frame_spread_mm, 1e-12);
  for (int i = 1; i < 4; ++i) EXPECT_LT((e.frames[i].centre_error_mm - d).norm(), 1e-12);
  EXPECT_NEAR(e.tre_mean_mm, d.norm(), 1e-12);
}

TEST(ComparePoses, OppositeErrorsSpreadWithoutSharedOffset) {
  // Frames 1 and 2 off by +d and -d, frame 3 exact: mean 0, spread (|d| + |d| + 0) / 3.
  const std::vector<Eigen::Isometry3d> truth = Truth();
  const Eigen::Vector3d d(0.0, 0.04, -0.03);
  std::vector<Eigen::Isometry3d> estimate = truth;
  estimate[1] = truth[1] * Eigen::Translation3d(-d);
  estimate[2] = truth[2] * Eigen::Translation3d(d);
  const std::vector<Mask> masks(4, TestMask());
  const PoseErrorSummary e = ComparePoses(estimate, truth, masks, 1);
  EXPECT_LT(e.shared_offset_mm.norm(), 1e-12);
  EXPECT_NEAR(e.frame_spread_mm, 2.0 * d.norm() / 3.0, 1e-12);
}

TEST(ComparePoses, CentreErrorIsTheErrorAtTheFieldOfViewsCentroid) {
  // A rotation error about frame 1's own origin moves its field of view's centroid, which
  // the mask's missing first slice puts at (4.5, 4.5, 5) in frame 1: the centre error is
  // the displacement of that point's world position.
  const std::vector<Eigen::Isometry3d> truth = Truth();
  std::vector<Eigen::Isometry3d> estimate = truth;
  const Eigen::AngleAxisd error(0.002, Eigen::Vector3d(1, 2, 2).normalized());
  estimate[1] = Eigen::Isometry3d(error) * truth[1];
  const std::vector<Mask> masks(4, TestMask());
  const PoseErrorSummary e = ComparePoses(estimate, truth, masks, 1);
  const Eigen::Vector3d centroid(4.5, 4.5, 5.0);
  const Eigen::Vector3d expected = estimate[1].inverse() * centroid - truth[1].inverse() * centroid;
  EXPECT_LT((e.frames[1].centre_error_mm - expected).norm(), 1e-12);
  EXPECT_LT((e.shared_offset_mm - expected / 3.0).norm(), 1e-12);
}

}  // namespace
}  // namespace dsr
