// The pair check (pipeline/pair_check.h): frames that split into groups which do not agree
// with each other are caught and the smaller group named; a correct registration passes.
#include <algorithm>
#include <cmath>

#include <gtest/gtest.h>

#include "dsr/geometry/se3.h"
#include "dsr/image/frame.h"
#include "dsr/image/pyramid.h"
#include "dsr/pipeline/pair_check.h"
#include "dsr/pipeline/registration.h"
#include "dsr/sim/phantom.h"
#include "dsr/sim/simulate.h"

namespace dsr {
namespace {

bool Contains(const std::vector<int>& v, int x) {
  return std::find(v.begin(), v.end(), x) != v.end();
}

// All pairs of `m` frames with mismatch `good`, except those between `group` and the rest.
std::vector<PairMismatch> TwoGroups(int m, const std::vector<int>& group, double good, double bad) {
  std::vector<PairMismatch> pairs;
  for (int i = 0; i < m; ++i) {
    for (int j = i + 1; j < m; ++j) {
      const bool across = Contains(group, i) != Contains(group, j);
      pairs.push_back(PairMismatch{i, j, 0.5, across ? bad : good});
    }
  }
  return pairs;
}

TEST(PairDisagreement, NamesTheSmallerGroup) {
  // 5 of 11 frames agree among themselves but not with the 6 others (the lower quartile
  // is a within-group pair: at most three quarters of the pairs may be off).
  const std::vector<int> group = {1, 2, 4, 5, 8};
  std::vector<int> flagged;
  std::string why;
  ASSERT_TRUE(PairDisagreement(TwoGroups(11, group, 0.01, 0.1), 11, 5.0, &flagged, &why));
  std::vector<int> sorted = flagged;
  std::sort(sorted.begin(), sorted.end());
  EXPECT_EQ(sorted, group);
  EXPECT_NE(why.find("max_pair_mismatch_ratio=5"), std::string::npos) << why;
  EXPECT_NE(why.find("30 of 55 overlapping pairs disagree"), std::string::npos) << why;
}

TEST(PairDisagreement, NamesOneWrongFrameEvenWhenOnePairAgreesByChance) {
  // Frame 3 disagrees with all but frame 0 (a pair that matches by chance joins it to the
  // others' group): it disagrees with more frames than it agrees with.
  std::vector<PairMismatch> pairs = TwoGroups(6, {3}, 0.01, 0.2);
  for (PairMismatch& p : pairs) {
    if (p.first == 0 && p.second == 3) p.mismatch = 0.01;
  }
  std::vector<int> flagged;
  std::string why;
  ASSERT_TRUE(PairDisagreement(pairs, 6, 5.0, &flagged, &why));
  EXPECT_EQ(flagged, std::vector<int>({3}));
}

TEST(PairDisagreement, PassesAgreeingPairsAndIsOffAtZero) {
  std::vector<PairMismatch> pairs = TwoGroups(6, {}, 0.01, 0.0);
  pairs[4].mismatch = 0.04;  // 4 times the lower quartile: within the ratio
  std::vector<int> flagged;
  std::string why;
  EXPECT_FALSE(PairDisagreement(pairs, 6, 5.0, &flagged, &why));
  EXPECT_TRUE(flagged.empty());
  pairs[4].mismatch = 0.06;
  EXPECT_TRUE(PairDisagreement(pairs, 6, 5.0, &flagged, &why));
  EXPECT_FALSE(PairDisagreement(pairs, 6, 0.0, &flagged, &why));
  // Noise-free data: a reference near 0 is floored, so tiny mismatches never count.
  std::vector<PairMismatch> exact = TwoGroups(6, {}, 1e-7, 0.0);
  exact[2].mismatch = 1e-3;
  EXPECT_FALSE(PairDisagreement(exact, 6, 5.0, &flagged, &why));
  // Two pairs are too few to have a reference.
  EXPECT_FALSE(PairDisagreement({{0, 1, 0.5, 0.01}, {1, 2, 0.5, 0.9}}, 3, 5.0, &flagged, &why));
}

// On simulated frames: at the true poses every pair agrees; with frames 3 and 4 moved
// together by 6 mm and 6 degrees (each still agreeing with the other), the check names
// them.
TEST(PairMismatches, CatchesTwoGroupsOnSimulatedFrames) {
  PhantomOptions p;
  p.size = 128;
  const Image source = MakePhantom(p);
  SimulationOptions o;
  o.num_frames = 6;
  o.frame_size = Eigen::Vector3i(48, 48, 40);
  o.max_rotation_deg = 8.0;
  o.max_translation_voxels = 5.0;
  o.sigma = 10.0;
  o.min_depth_voxels = 2.0;
  o.seed = 4;
  SimulatedSequence s;
  std::string error;
  ASSERT_TRUE(Simulate(source, o, &s, &error)) << error;
  std::vector<Frame> frames;
  for (size_t f = 0; f < s.frames.size(); ++f) {
    const ImageLevel coarse = Downsample(s.frames[f], s.masks[f], 1.0, 1);
    frames.emplace_back(coarse.image, coarse.mask);
  }
  const std::vector<Eigen::Isometry3d> truth = RelativeToFrame0(s.frame_from_world);
  std::vector<int> flagged;
  std::string why;
  const std::vector<PairMismatch> at_truth = PairMismatches(frames, truth, 2);
  EXPECT_GE(at_truth.size(), 10u);
  EXPECT_FALSE(PairDisagreement(at_truth, 6, 5.0, &flagged, &why)) << why;

  Eigen::Isometry3d shift = Eigen::Isometry3d::Identity();
  shift.linear() = ExpSO3(Eigen::Vector3d(0.0, 0.0, 6.0 * M_PI / 180.0));
  shift.translation() = Eigen::Vector3d(6.0, 0.0, 0.0);
  std::vector<Eigen::Isometry3d> split = truth;
  split[3] = split[3] * shift;
  split[4] = split[4] * shift;
  ASSERT_TRUE(PairDisagreement(PairMismatches(frames, split, 2), 6, 5.0, &flagged, &why));
  std::sort(flagged.begin(), flagged.end());
  EXPECT_EQ(flagged, std::vector<int>({3, 4})) << why;
  // Deterministic for any thread count.
  const std::vector<PairMismatch> one = PairMismatches(frames, split, 1);
  const std::vector<PairMismatch> two = PairMismatches(frames, split, 2);
  ASSERT_EQ(one.size(), two.size());
  for (size_t k = 0; k < one.size(); ++k) EXPECT_EQ(one[k].mismatch, two[k].mismatch);
}

// The checks guard the baselines too: the pairwise baseline on a 4-frame
// sequence of the paper's protocol chains into a wrong minimum (39 voxels off before the
// checks guarded every mode); the registration is refused, not returned.
TEST(Checks, RefuseTheWrongMinimumOfThePairwiseBaseline) {
  SimulationOptions o;  // the paper's protocol, as dsr_simulate's defaults
  o.num_frames = 4;
  o.frame_size = Eigen::Vector3i(48, 48, 40);
  o.seed = 2;
  SimulatedSequence s;
  std::string error;
  ASSERT_TRUE(Simulate(MakePhantom(PhantomOptions()), o, &s, &error)) << error;
  RegistrationOptions r;
  r.mode = dsr::Mode::kPairwise;
  r.solve.progress = false;
  r.solve.num_threads = 2;
  const std::vector<Eigen::Isometry3d> identity(s.frames.size(), Eigen::Isometry3d::Identity());
  RegistrationResult result;
  ASSERT_TRUE(Register(s.frames, s.masks, identity, r, &result, &error)) << error;
  EXPECT_FALSE(result.usable);
  EXPECT_FALSE(result.flagged_frames.empty());  // here the overlap guard: frame 2 slid
  EXPECT_NE(result.failure.find("not usable"), std::string::npos) << result.failure;
}

}  // namespace
}  // namespace dsr
