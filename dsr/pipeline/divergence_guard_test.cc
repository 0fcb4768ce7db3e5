// The divergence guard (pipeline/divergence_guard.h): frames that slide out of the overlap,
// alone or as a group, are reported by name; ordinary motion is not.
#include <gtest/gtest.h>

#include <cmath>

#include "dsr/model/panorama.h"
#include "dsr/pipeline/divergence_guard.h"
#include "dsr/tests/support/test_problems.h"

namespace dsr {
namespace {

using testing_problems::CandidatesAt;
using testing_problems::MakeSequence;
using testing_problems::SequenceOptions;
using testing_problems::TestSequence;

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
  // A guard that has recorded the ground truth as its initial poses.
  DivergenceGuard GuardFromTruth(double min_kept) {
    DivergenceGuard guard(min_kept);
    std::string why;
    EXPECT_FALSE(guard.Diverged(sequence_.frames,
                                CandidatesAt(sequence_.frames, sequence_.ground_truth), &why));
    return guard;
  }
  TestSequence sequence_;
};

TEST_F(DivergenceGuardTest, TiedFractionsFollowTheOverlapChain) {
  const std::vector<Frame>& frames = sequence_.frames;
  const std::vector<double> at_truth =
      TiedFractions(frames, CandidatesAt(frames, sequence_.ground_truth));
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
  DivergenceGuard guard = GuardFromTruth(0.25);
  std::string why;
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
  DivergenceGuard guard = GuardFromTruth(0.25);
  std::string why;
  const auto group = Shifted(Shifted(sequence_.ground_truth, 2, 40.0), 3, 40.0);
  const CandidateSet candidates = CandidatesAt(frames, group);
  EXPECT_GT(CandidateOverlap(candidates)(2, 3), 0);
  EXPECT_TRUE(guard.Diverged(frames, candidates, &why));
  EXPECT_NE(why.find("frame 2 slid out"), std::string::npos) << why;
}

TEST_F(DivergenceGuardTest, ZeroTurnsItOff) {
  const std::vector<Frame>& frames = sequence_.frames;
  DivergenceGuard guard = GuardFromTruth(0.0);
  std::string why;
  EXPECT_FALSE(guard.Diverged(
      frames, CandidatesAt(frames, Shifted(sequence_.ground_truth, 2, 100.0)), &why));
}

TEST_F(DivergenceGuardTest, MisfitsAreZeroAtAConsistentTruthAndPointAtAMisplacedFrame) {
  // Lattice-aligned frames are crops of one discrete volume: at the ground truth every
  // observer of a voxel samples the same value.
  SequenceOptions o;
  o.num_frames = 4;
  o.size = 16;
  o.frame_offset = 3.0;
  o.lattice = true;
  o.noise_sigma = 5.0;
  const TestSequence lattice = MakeSequence(o);
  const std::vector<Frame>& frames = lattice.frames;
  const CandidateSet at_truth = CandidatesAt(frames, lattice.ground_truth);
  for (double misfit : FrameMisfits(frames, at_truth, lattice.ground_truth, StreamContext{2})) {
    EXPECT_LT(misfit, 1e-3);
  }
  const std::vector<Eigen::Isometry3d> moved = Shifted(lattice.ground_truth, 2, 1.5);
  const CandidateSet candidates = CandidatesAt(frames, moved);
  const std::vector<double> misfits = FrameMisfits(frames, candidates, moved, StreamContext{2});
  for (int i : {0, 1, 3}) EXPECT_GT(misfits[2], misfits[i]) << i;
  EXPECT_GT(misfits[2], 1.0);
  // Fixed accumulation blocks: any thread count gives the same sums.
  EXPECT_EQ(FrameMisfits(frames, candidates, moved, StreamContext{1}), misfits);
  EXPECT_EQ(FrameMisfits(frames, candidates, moved, StreamContext{3}), misfits);
  std::string why;
  EXPECT_TRUE(MisfitOutlier(misfits, 1.2, &why));
  EXPECT_NE(why.find("frame 2 does not match the others"), std::string::npos) << why;
}

TEST(MisfitOutlier, ComparesTheWorstFrameWithTheMedian) {
  std::string why;
  EXPECT_TRUE(MisfitOutlier({10.0, 11.0, 40.0, 12.0}, 2.0, &why));  // lower quartile 10
  EXPECT_NE(why.find("frame 2 does not match"), std::string::npos) << why;
  EXPECT_NE(why.find("max_misfit_ratio=2"), std::string::npos) << why;
  EXPECT_FALSE(MisfitOutlier({10.0, 11.0, 20.0, 12.0}, 2.0, &why));  // 20 = 2 x 10
  // Three of five frames off: the reference stays with the good ones.
  EXPECT_TRUE(MisfitOutlier({10.0, 30.0, 31.0, 11.0, 32.0}, 2.0, &why));
  EXPECT_NE(why.find("frame 4 does not match"), std::string::npos) << why;
  EXPECT_FALSE(MisfitOutlier({10.0, 11.0, 400.0, 12.0}, 0.0, &why));  // off
  EXPECT_FALSE(MisfitOutlier({5.0, 5.0}, 2.0, &why));
}

// Exempt frames are never the outlier, but still count towards the lower quartile.
TEST(MisfitOutlier, SkipsExemptFrames) {
  std::string why;
  const std::vector<double> misfits = {10.0, 11.0, 40.0, 12.0, 30.0};
  const std::vector<bool> exempt_2 = {false, false, true, false, false};
  EXPECT_TRUE(MisfitOutlier(misfits, 2.0, &why, &exempt_2));
  EXPECT_NE(why.find("frame 4 does not match"), std::string::npos) << why;
  EXPECT_EQ(MisfitOutliers(misfits, 2.0, &exempt_2), std::vector<int>({4}));
  EXPECT_EQ(MisfitOutliers(misfits, 2.0), std::vector<int>({2, 4}));
  const std::vector<bool> exempt_2_4 = {false, false, true, false, true};
  EXPECT_FALSE(MisfitOutlier(misfits, 2.0, &why, &exempt_2_4));
  EXPECT_TRUE(MisfitOutliers(misfits, 2.0, &exempt_2_4).empty());
  // Exempting the low frames leaves the reference where it was: frame 3 (12) passes.
  const std::vector<bool> exempt_low = {true, true, false, false, false};
  EXPECT_EQ(MisfitOutliers(misfits, 2.0, &exempt_low), std::vector<int>({2, 4}));
}

// With photometric corrections the misfits compare corrected intensities: frames
// seen through a gain and an offset, on lattice-aligned noise-free data, match exactly once
// corrected back to frame 0's scale (up to float storage), while the raw intensities do not.
TEST(FrameMisfits, CompareCorrectedIntensities) {
  SequenceOptions o;
  o.num_frames = 4;
  o.size = 16;
  o.lattice = true;
  o.seed = 9;
  const TestSequence s = MakeSequence(o);
  const double g[] = {1.0, 1.3, 0.8, 1.1}, b[] = {0.0, 12.0, -7.0, 4.0};
  std::vector<Frame> frames;
  std::vector<Photometric> correction;  // back to frame 0's scale: (I - b) / g
  for (int i = 0; i < o.num_frames; ++i) {
    Image image = s.images[i];
    for (float& v : image.voxels) v = static_cast<float>(g[i] * v + b[i]);
    frames.emplace_back(image, s.masks[i]);
    correction.push_back({-std::log(g[i]), -b[i] / g[i]});
  }
  const CandidateSet candidates = CandidatesAt(frames, s.ground_truth);
  const std::vector<double> raw = FrameMisfits(frames, candidates, s.ground_truth,
                                               StreamContext{2});
  const std::vector<double> corrected =
      FrameMisfits(frames, candidates, s.ground_truth, StreamContext{2}, correction);
  ASSERT_EQ(corrected.size(), 4u);
  for (int i = 0; i < 4; ++i) {
    // Intensities of about 100 stored as float: differences of a few 1e-5 at most.
    EXPECT_LT(corrected[i], 1e-4) << i;
    EXPECT_GT(raw[i], 1.0) << i;
  }
  // Deterministic for any thread count.
  EXPECT_EQ(FrameMisfits(frames, candidates, s.ground_truth, StreamContext{1}, correction),
            FrameMisfits(frames, candidates, s.ground_truth, StreamContext{3}, correction));
  // The gauge on every frame (gain exactly 1, offset 0) is no correction.
  const std::vector<Photometric> gauge(4);
  const std::vector<double> with_gauge = FrameMisfits(frames, candidates, s.ground_truth,
                                                      StreamContext{2}, gauge);
  for (int i = 0; i < 4; ++i) EXPECT_NEAR(with_gauge[i], raw[i], 1e-12 * raw[i]) << i;
}

}  // namespace
}  // namespace dsr
