// The pose matchers of the test support (tests/support/pose_matchers.h): a pose matches
// within both bounds and fails beyond either, and the failure message gives the rotation
// angle of expected^-1 * actual and the translation error (and, for sequences, the frames).
#include "dsr/tests/support/pose_matchers.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <string>
#include <vector>

namespace dsr {
namespace {

using testing_poses::FrameFromWorldNear;
using testing_poses::FramesFromWorldNear;
using ::testing::HasSubstr;
using ::testing::Not;

Eigen::Isometry3d SomePose() {
  return Eigen::Isometry3d(Eigen::Translation3d(12.0, -4.0, 7.5) *
                           Eigen::AngleAxisd(0.4, Eigen::Vector3d(1.0, -2.0, 0.5).normalized()));
}

// `expected` followed by an error of `angle_rad` about an oblique axis and `shift_mm` along
// another: expected^-1 * actual is exactly that error.
Eigen::Isometry3d Off(const Eigen::Isometry3d& expected, double angle_rad, double shift_mm) {
  return expected *
         Eigen::Isometry3d(Eigen::Translation3d(shift_mm * Eigen::Vector3d(0.6, 0.0, 0.8)) *
                           Eigen::AngleAxisd(angle_rad, Eigen::Vector3d(0.0, 0.8, 0.6)));
}

template <typename Matcher, typename Value>
std::string Explanation(const Matcher& matcher, const Value& value) {
  ::testing::StringMatchResultListener listener;
  ::testing::ExplainMatchResult(matcher, value, &listener);
  return listener.str();
}

TEST(FrameFromWorldNear, MatchesWithinBothBoundsAndFailsBeyondEither) {
  const Eigen::Isometry3d expected = SomePose();
  const Eigen::Isometry3d actual = Off(expected, 1e-3, 0.02);
  EXPECT_THAT(expected, FrameFromWorldNear(expected, 1e-12, 1e-12));  // rounding only
  EXPECT_THAT(actual, FrameFromWorldNear(expected, 2e-3, 0.05));
  EXPECT_THAT(actual, Not(FrameFromWorldNear(expected, 5e-4, 0.05)));
  EXPECT_THAT(actual, Not(FrameFromWorldNear(expected, 2e-3, 0.01)));
  // The error is the pose's own, not a difference of matrix entries: a 1 mm shift of a
  // pose 0.4 rad from the identity is 1 mm.
  EXPECT_THAT(Off(expected, 0.0, 1.0), FrameFromWorldNear(expected, 1e-12, 1.0 + 1e-9));
  EXPECT_THAT(Off(expected, 0.0, 1.0), Not(FrameFromWorldNear(expected, 1e-12, 1.0 - 1e-9)));
}

TEST(FrameFromWorldNear, MessageGivesTheRotationAngleAndTheTranslationError) {
  const Eigen::Isometry3d expected = SomePose();
  const std::string why =
      Explanation(FrameFromWorldNear(expected, 5e-4, 0.01), Off(expected, 1e-3, 0.02));
  EXPECT_THAT(why, HasSubstr("rotation 0.001 rad"));
  EXPECT_THAT(why, HasSubstr("translation 0.02 mm"));
  const std::string description =
      ::testing::DescribeMatcher<Eigen::Isometry3d>(FrameFromWorldNear(expected, 5e-4, 0.01));
  EXPECT_THAT(description, HasSubstr("within rotation 0.0005 rad, translation 0.01 mm"));
  // The expected pose, printed row by row (translation last).
  EXPECT_THAT(description, HasSubstr(", 12; "));
  EXPECT_THAT(description, HasSubstr(", -4; "));
  EXPECT_THAT(description, HasSubstr(", 7.5; 0, 0, 0, 1]"));
}

TEST(FramesFromWorldNear, ChecksEveryFrameAndNamesTheOnesOverTheBounds) {
  const std::vector<Eigen::Isometry3d> expected = {Eigen::Isometry3d::Identity(), SomePose(),
                                                   Off(SomePose(), 0.1, 2.0)};
  std::vector<Eigen::Isometry3d> actual = expected;
  EXPECT_THAT(actual, FramesFromWorldNear(expected, 1e-12, 1e-12));  // rounding only
  actual[1] = Off(expected[1], 0.0, 0.3);
  EXPECT_THAT(actual, FramesFromWorldNear(expected, 1e-9, 0.3 + 1e-9));
  EXPECT_THAT(actual, Not(FramesFromWorldNear(expected, 1e-9, 0.1)));
  const std::string why = Explanation(FramesFromWorldNear(expected, 1e-9, 0.1), actual);
  EXPECT_THAT(why, HasSubstr("frame 1: rotation"));
  EXPECT_THAT(why, HasSubstr("translation 0.3 mm"));
  EXPECT_THAT(why, Not(HasSubstr("frame 0")));
  EXPECT_THAT(why, Not(HasSubstr("frame 2")));
  // Another number of poses never matches.
  actual.pop_back();
  EXPECT_THAT(actual, Not(FramesFromWorldNear(expected, 1.0, 100.0)));
  EXPECT_THAT(Explanation(FramesFromWorldNear(expected, 1.0, 100.0), actual),
              HasSubstr("which has 2 poses, not 3"));
}

}  // namespace
}  // namespace dsr
