// gMock matchers for estimated poses (frame_from_world, world -> frame, geometry/se3.h):
//
//   EXPECT_THAT(report.frame_from_world[1], FrameFromWorldNear(truth[1], 1e-8, 1e-6));
//   EXPECT_THAT(report.frame_from_world, FramesFromWorldNear(truth, 1e-8, 1e-6));
//
// The error of `actual` against `expected` is expected^-1 * actual: its rotation angle (rad)
// and its translation (mm; the distance between the two poses' translations). A pose
// matches when neither exceeds its bound; a failure names both errors (and, for sequences,
// the frames over the bounds).
#ifndef DSR_TESTS_SUPPORT_POSE_MATCHERS_H_
#define DSR_TESTS_SUPPORT_POSE_MATCHERS_H_

#include <algorithm>
#include <cstddef>
#include <ostream>
#include <sstream>
#include <string>
#include <vector>

#include <Eigen/Geometry>
#include <gmock/gmock.h>

#include "dsr/geometry/se3.h"

// gtest prints a value it has no printer for as raw bytes; poses print as their 4x4 matrix.
// (gtest finds PrintTo by argument-dependent lookup, so it lives in the type's namespace.)
namespace Eigen {
inline void PrintTo(const Isometry3d& pose, std::ostream* os) {
  const IOFormat format(FullPrecision, DontAlignCols, ", ", "; ", "", "", "[", "]");
  *os << pose.matrix().format(format);
}
}  // namespace Eigen

namespace dsr {
namespace testing_poses {

struct PoseError {
  double angle_rad = 0.0;
  double translation_mm = 0.0;
};

// The rotation angle and the translation of expected^-1 * actual.
inline PoseError FrameFromWorldError(const Eigen::Isometry3d& actual,
                                     const Eigen::Isometry3d& expected) {
  const Eigen::Isometry3d error = expected.inverse() * actual;
  return {LogSO3(error.linear()).norm(), error.translation().norm()};
}

inline std::string Describe(const PoseError& e) {
  std::ostringstream s;
  s.precision(3);
  s << "rotation " << e.angle_rad << " rad, translation " << e.translation_mm << " mm";
  return s.str();
}

class FrameFromWorldNearMatcher {
 public:
  using is_gtest_matcher = void;

  FrameFromWorldNearMatcher(const Eigen::Isometry3d& expected,
                            double max_angle_rad,
                            double max_translation_mm)
      : expected_(expected),
        max_angle_rad_(max_angle_rad),
        max_translation_mm_(max_translation_mm) {}

  bool MatchAndExplain(const Eigen::Isometry3d& actual, std::ostream* os) const {
    const PoseError e = FrameFromWorldError(actual, expected_);
    if (os != nullptr) *os << "whose error against the expected pose is " << Describe(e);
    return e.angle_rad <= max_angle_rad_ && e.translation_mm <= max_translation_mm_;
  }
  void DescribeTo(std::ostream* os) const {
    *os << "is a pose within " << Bounds() << " of ";
    Eigen::PrintTo(expected_, os);
  }
  void DescribeNegationTo(std::ostream* os) const {
    *os << "is a pose farther than " << Bounds() << " from ";
    Eigen::PrintTo(expected_, os);
  }

 private:
  std::string Bounds() const {
    return Describe({max_angle_rad_, max_translation_mm_});
  }

  Eigen::Isometry3d expected_;
  double max_angle_rad_, max_translation_mm_;
};

class FramesFromWorldNearMatcher {
 public:
  using is_gtest_matcher = void;

  FramesFromWorldNearMatcher(const std::vector<Eigen::Isometry3d>& expected,
                             double max_angle_rad,
                             double max_translation_mm)
      : expected_(expected),
        max_angle_rad_(max_angle_rad),
        max_translation_mm_(max_translation_mm) {}

  bool MatchAndExplain(const std::vector<Eigen::Isometry3d>& actual, std::ostream* os) const {
    if (actual.size() != expected_.size()) {
      if (os != nullptr) *os << "which has " << actual.size() << " poses, not " << expected_.size();
      return false;
    }
    PoseError largest;
    std::string over;
    for (size_t i = 0; i < actual.size(); ++i) {
      const PoseError e = FrameFromWorldError(actual[i], expected_[i]);
      largest.angle_rad = std::max(largest.angle_rad, e.angle_rad);
      largest.translation_mm = std::max(largest.translation_mm, e.translation_mm);
      if (e.angle_rad > max_angle_rad_ || e.translation_mm > max_translation_mm_) {
        over += "\n  frame " + std::to_string(i) + ": " + Describe(e);
      }
    }
    if (os != nullptr) {
      *os << "whose largest errors against the expected poses are " << Describe(largest);
      if (!over.empty()) *os << "; over the bounds:" << over;
    }
    return over.empty();
  }
  void DescribeTo(std::ostream* os) const {
    *os << "are " << expected_.size() << " poses, each within "
        << Describe({max_angle_rad_, max_translation_mm_}) << " of the expected one";
  }
  void DescribeNegationTo(std::ostream* os) const {
    *os << "are not " << expected_.size() << " poses each within "
        << Describe({max_angle_rad_, max_translation_mm_}) << " of the expected one";
  }

 private:
  std::vector<Eigen::Isometry3d> expected_;
  double max_angle_rad_, max_translation_mm_;
};

// One pose: the rotation angle of expected^-1 * actual at most `max_angle_rad` and its
// translation at most `max_translation_mm`.
inline FrameFromWorldNearMatcher FrameFromWorldNear(const Eigen::Isometry3d& expected,
                                                    double max_angle_rad,
                                                    double max_translation_mm) {
  return FrameFromWorldNearMatcher(expected, max_angle_rad, max_translation_mm);
}

// A sequence of poses, frame by frame, as FrameFromWorldNear (and the same number of them).
inline FramesFromWorldNearMatcher FramesFromWorldNear(
    const std::vector<Eigen::Isometry3d>& expected,
    double max_angle_rad,
    double max_translation_mm) {
  return FramesFromWorldNearMatcher(expected, max_angle_rad, max_translation_mm);
}

}  // namespace testing_poses
}  // namespace dsr

#endif  // DSR_TESTS_SUPPORT_POSE_MATCHERS_H_
