// The divergence guard (pipeline/divergence_guard.h): frames that slide out of the overlap,
// alone or as a group, are reported by name; ordinary motion is not.
#include <gtest/gtest.h>

#include "core/panorama.h"
#include "pipeline/divergence_guard.h"
#include "test_problems.h"

namespace dsr {
namespace {

using testing_problems::MakeSequence;
using testing_problems::SequenceOptions;
using testing_problems::TestSequence;

CandidateSet CandidatesAt(const std::vector<Frame>& frames,
                          const std::vector<Eigen::Isometry3d>& poses) {
  ImageGeometry grid;
  std::string error;
  EXPECT_TRUE(BuildPanoramaGrid(frames, poses, 1.0, &grid, &error)) << error;
  return BuildCandidates(frames, poses, grid, 0);
}

// `poses` with frame i shifted by `x_mm` along the world x axis.
std::vector<Eigen::Isometry3d> Shifted(std::vector<Eigen::Isometry3d> poses, int i, double x_mm) {
  poses[i] = poses[i] * Eigen::Translation3d(-x_mm, 0.0, 0.0);
  return poses;
}

class DivergenceGuardTest : public ::testing::Test {
 protected:
  DivergenceGuardTest() {
    SequenceOptions o;
    o.num_frames = 4;
    o.size = 16;
    o.frame_offset = 3.0;
    sequence_ = MakeSequence(o);
  }
  TestSequence sequence_;
};

TEST_F(DivergenceGuardTest, TiedFractionsFollowTheOverlapChain) {
  const std::vector<Frame>& frames = sequence_.frames;
  const std::vector<double> at_truth = TiedFractions(frames, CandidatesAt(frames, sequence_.ground_truth));
  ASSERT_EQ(at_truth.size(), 4u);
  EXPECT_EQ(at_truth[0], 1.0);
  for (int i = 1; i < 4; ++i) {
    // Consecutive frames 3 mm apart on 14-voxel valid regions: most of each is shared.
    EXPECT_GT(at_truth[i], 0.5) << i;
    EXPECT_LE(at_truth[i], 1.0) << i;
  }
  // Frame 3 far away: not connected to frame 0 any more.
  const std::vector<double> away =
      TiedFractions(frames, CandidatesAt(frames, Shifted(sequence_.ground_truth, 3, 100.0)));
  EXPECT_EQ(away[3], 0.0);
  EXPECT_GT(away[2], 0.5);
}

TEST_F(DivergenceGuardTest, ReportsAFrameThatSlidOut) {
  const std::vector<Frame>& frames = sequence_.frames;
  DivergenceGuard guard(0.25);
  std::string why;
  ASSERT_FALSE(guard.Diverged(frames, CandidatesAt(frames, sequence_.ground_truth), &why));
  // Ordinary motion (2 mm) keeps the chain.
  EXPECT_FALSE(guard.Diverged(frames, CandidatesAt(frames, Shifted(sequence_.ground_truth, 2, 2.0)),
                              &why))
      << why;
  // The last frame slid 10 mm further out: 13 mm from its neighbour, with 14 mm wide
  // valid regions, a thin sliver is left.
  EXPECT_TRUE(guard.Diverged(frames, CandidatesAt(frames, Shifted(sequence_.ground_truth, 3, 10.0)),
                             &why));
  EXPECT_NE(why.find("diverged: frame 3 slid out of the overlap"), std::string::npos) << why;
}

TEST_F(DivergenceGuardTest, ReportsAGroupThatDriftedOffTogether) {
  // Frames 2 and 3 moved together: they still overlap each other, not frames 0 and 1.
  const std::vector<Frame>& frames = sequence_.frames;
  DivergenceGuard guard(0.25);
  std::string why;
  ASSERT_FALSE(guard.Diverged(frames, CandidatesAt(frames, sequence_.ground_truth), &why));
  const auto group = Shifted(Shifted(sequence_.ground_truth, 2, 40.0), 3, 40.0);
  const CandidateSet candidates = CandidatesAt(frames, group);
  EXPECT_GT(CandidateOverlap(candidates)(2, 3), 0);
  EXPECT_TRUE(guard.Diverged(frames, candidates, &why));
  EXPECT_NE(why.find("frame 2 slid out"), std::string::npos) << why;
}

TEST_F(DivergenceGuardTest, ZeroTurnsItOff) {
  const std::vector<Frame>& frames = sequence_.frames;
  DivergenceGuard guard(0.0);
  std::string why;
  ASSERT_FALSE(guard.Diverged(frames, CandidatesAt(frames, sequence_.ground_truth), &why));
  EXPECT_FALSE(guard.Diverged(frames, CandidatesAt(frames, Shifted(sequence_.ground_truth, 2, 100.0)),
                              &why));
}

}  // namespace
}  // namespace dsr
