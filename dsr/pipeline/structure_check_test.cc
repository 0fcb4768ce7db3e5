// The structure check (pipeline/structure_check.h): at correct poses a frame's differences to
// the panorama hold noise only, whatever its level, and a brightness field between frames is
// not taken for anatomy out of line; a displaced frame leaves its anatomy in them and is
// flagged by name; a flat frame is not judged; the figures do not depend on the thread count.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>

#include "dsr/model/panorama.h"
#include "dsr/pipeline/structure_check.h"
#include "dsr/tests/support/test_problems.h"

namespace dsr {
namespace {

using testing_problems::CandidatesAt;
using testing_problems::MakeSequence;
using testing_problems::SequenceOptions;
using testing_problems::TestSequence;

StreamContext Threads(int n) {
  StreamContext context;
  context.num_threads = n;
  return context;
}

TestSequence Sequence(double noise_sigma, uint64_t seed = 3) {
  SequenceOptions o;
  o.num_frames = 4;
  o.size = 32;
  o.frame_offset = 4.0;
  o.noise_sigma = noise_sigma;
  o.seed = seed;
  return MakeSequence(o);
}

// The default limit (RegistrationOptions::max_structure_fraction).
constexpr double kLimit = 0.05;

TEST(FrameStructures, NoiseAloneLeavesNoStructureAtAnyLevel) {
  for (double sigma : {0.0, 2.0, 20.0}) {
    const TestSequence s = Sequence(sigma);
    const std::vector<FrameStructure> structure = FrameStructures(
        s.frames, CandidatesAt(s.frames, s.ground_truth), s.ground_truth, Threads(2));
    ASSERT_EQ(structure.size(), 4u);
    for (int i = 0; i < 4; ++i) {
      EXPECT_TRUE(structure[i].judged) << "sigma " << sigma << " frame " << i;
      EXPECT_GT(structure[i].pairs, 1000) << i;
      if (sigma == 0.0) {
        // Noise-free frames are exact samples of one world: only the resampling's error is
        // left, significant against no noise but a millionth of the structure.
        EXPECT_LT(std::abs(structure[i].fraction), 1e-4) << "frame " << i;
      } else {
        // With noise, the estimate spreads by its standard error: within it, whatever the
        // fraction (at sigma 20 the frames' own structure is a tenth of their variance).
        EXPECT_LT(std::abs(structure[i].significance), kStructureSignificance)
            << "sigma " << sigma << " frame " << i;
      }
    }
    EXPECT_TRUE(StructureOutliers(structure, kLimit).empty()) << "sigma " << sigma;
  }
}

TEST(FrameStructures, ADisplacedFrameIsNamed) {
  const TestSequence s = Sequence(2.0);
  std::vector<Eigen::Isometry3d> poses = s.ground_truth;
  poses[2] = poses[2] * Eigen::Translation3d(5.0, -3.0, 2.0);  // 6.2 mm off
  const std::vector<FrameStructure> structure =
      FrameStructures(s.frames, CandidatesAt(s.frames, poses), poses, Threads(2));
  const std::vector<int> outliers = StructureOutliers(structure, kLimit);
  ASSERT_FALSE(outliers.empty());
  EXPECT_EQ(outliers.front(), 2);
  EXPECT_GT(structure[2].fraction, 2.0 * kLimit);
  EXPECT_GT(structure[2].significance, kStructureSignificance);
  std::string why;
  EXPECT_TRUE(StructureOutlier(structure, kLimit, &why));
  EXPECT_EQ(why.find("frame 2 does not line up with the others"), 0u) << why;
  // An exempt frame is never named; off (0) names nobody.
  const std::vector<bool> exempt = {false, false, true, false};
  const std::vector<int> others = StructureOutliers(structure, kLimit, &exempt);
  EXPECT_EQ(std::count(others.begin(), others.end(), 2), 0);
  EXPECT_TRUE(StructureOutliers(structure, 0.0).empty());
}

TEST(FrameStructures, BrightnessIsNotAnatomyOutOfLine) {
  // Frame 1 seen through a gain of 1.2, an offset of 5 (the frames' structure spans about
  // 8 grey levels) and a gain that falls by 15 % along its depth (attenuation the others see
  // at other depths): a brightness field, no motion.
  TestSequence s = Sequence(2.0);
  Image& image = s.images[1];
  const ImageGeometry& g = image.geometry;
  for (int k = 0; k < g.size[2]; ++k) {
    for (int j = 0; j < g.size[1]; ++j) {
      for (int i = 0; i < g.size[0]; ++i) {
        const double depth = static_cast<double>(k) / (g.size[2] - 1);
        image.at(i, j, k) =
            static_cast<float>(1.2 * (1.0 - 0.15 * depth) * image.at(i, j, k) + 5.0);
      }
    }
  }
  s.frames[1] = Frame(image, s.masks[1]);
  const CandidateSet candidates = CandidatesAt(s.frames, s.ground_truth);
  const std::vector<FrameStructure> structure =
      FrameStructures(s.frames, candidates, s.ground_truth, Threads(2));
  EXPECT_TRUE(StructureOutliers(structure, kLimit).empty())
      << "frame 1's fraction " << structure[1].fraction;
  EXPECT_LT(structure[1].fraction, 0.5 * kLimit);
  // The same brightness field with frame 1 displaced is still named.
  std::vector<Eigen::Isometry3d> poses = s.ground_truth;
  poses[1] = poses[1] * Eigen::Translation3d(5.0, -3.0, 2.0);
  const std::vector<FrameStructure> off =
      FrameStructures(s.frames, CandidatesAt(s.frames, poses), poses, Threads(2));
  const std::vector<int> outliers = StructureOutliers(off, kLimit);
  EXPECT_NE(std::find(outliers.begin(), outliers.end(), 1), outliers.end());
}

TEST(FrameStructures, AFlatFrameIsNotJudged) {
  TestSequence s = Sequence(2.0);
  // Frame 3 holds noise about a constant: no structure of its own to compare with.
  std::mt19937_64 rng(7);
  std::normal_distribution<double> noise(0.0, 2.0);
  for (float& v : s.images[3].voxels) v = static_cast<float>(100.0 + noise(rng));
  s.frames[3] = Frame(s.images[3], s.masks[3]);
  const std::vector<FrameStructure> structure = FrameStructures(
      s.frames, CandidatesAt(s.frames, s.ground_truth), s.ground_truth, Threads(2));
  EXPECT_FALSE(structure[3].judged);
  EXPECT_EQ(structure[3].fraction, 0.0);
  EXPECT_EQ(std::count(StructureOutliers(structure, kLimit).begin(),
                       StructureOutliers(structure, kLimit).end(), 3),
            0);
  EXPECT_NE(StructureSummary(structure).find("1 frame too flat to judge"), std::string::npos)
      << StructureSummary(structure);
}

TEST(FrameStructures, DoNotDependOnTheThreadCount) {
  const TestSequence s = Sequence(5.0);
  const CandidateSet candidates = CandidatesAt(s.frames, s.ground_truth);
  const std::vector<FrameStructure> one =
      FrameStructures(s.frames, candidates, s.ground_truth, Threads(1));
  const std::vector<FrameStructure> three =
      FrameStructures(s.frames, candidates, s.ground_truth, Threads(3));
  for (size_t i = 0; i < one.size(); ++i) {
    EXPECT_EQ(one[i].pairs, three[i].pairs);
    EXPECT_EQ(one[i].residual_lag, three[i].residual_lag);
    EXPECT_EQ(one[i].signal_lag, three[i].signal_lag);
  }
}

TEST(FrameStructures, OnEvenlySpreadRowsAgreeWithEveryRow) {
  // Where the candidates hold more than twice pairs_per_frame observations per frame, the
  // check reads 1 row in keep: about 1/keep of the pairs, the same verdicts, and each
  // figure within the sampling spread the significance counts.
  const TestSequence s = Sequence(2.0);
  std::vector<Eigen::Isometry3d> poses = s.ground_truth;
  poses[2] = poses[2] * Eigen::Translation3d(5.0, -3.0, 2.0);
  for (const std::vector<Eigen::Isometry3d>& at : {s.ground_truth, poses}) {
    const CandidateSet candidates = CandidatesAt(s.frames, at);
    const double per_frame = static_cast<double>(candidates.NumObservations()) / 4.0;
    const std::vector<FrameStructure> all =
        FrameStructures(s.frames, candidates, at, Threads(2), {}, /*pairs_per_frame=*/0.0);
    EXPECT_EQ(all[0].pairs, FrameStructures(s.frames, candidates, at, Threads(2))[0].pairs)
        << "a small sequence reads every row by default";
    const std::vector<FrameStructure> rows =
        FrameStructures(s.frames, candidates, at, Threads(2), {}, per_frame / 4.0);
    for (int i = 0; i < 4; ++i) {
      EXPECT_GT(rows[i].pairs, all[i].pairs / 6) << i;
      EXPECT_LT(rows[i].pairs, all[i].pairs / 3) << i;
      ASSERT_TRUE(rows[i].judged) << i;
      // The fraction's standard error on the rows: v / sqrt(n) of the residual over b.
      const double error = rows[i].residual_variance / std::sqrt(rows[i].pairs) /
                           rows[i].signal_lag;
      EXPECT_LT(std::abs(rows[i].fraction - all[i].fraction), 5.0 * error)
          << "frame " << i << ": " << rows[i].fraction << " against " << all[i].fraction;
    }
    EXPECT_EQ(StructureOutliers(rows, kLimit), StructureOutliers(all, kLimit));
  }
  const std::vector<FrameStructure> off = FrameStructures(
      s.frames, CandidatesAt(s.frames, poses), poses, Threads(2), {},
      static_cast<double>(CandidatesAt(s.frames, poses).NumObservations()) / 16.0);
  ASSERT_FALSE(StructureOutliers(off, kLimit).empty());
  EXPECT_EQ(StructureOutliers(off, kLimit).front(), 2);
}

TEST(StructureLagVoxels, ReadsDisjointCellsOfEveryFrame) {
  const TestSequence s = Sequence(0.0);
  ImageGeometry grid;
  grid.spacing_mm = Eigen::Vector3d::Ones();
  EXPECT_EQ(StructureLagVoxels(s.frames, grid), 4);  // 2 sqrt 3 = 3.46 frame voxels
  grid.spacing_mm = Eigen::Vector3d::Constant(0.5);
  EXPECT_EQ(StructureLagVoxels(s.frames, grid), 7);
  grid.spacing_mm = Eigen::Vector3d::Constant(4.0);
  EXPECT_EQ(StructureLagVoxels(s.frames, grid), 2);  // never below 2
}

}  // namespace
}  // namespace dsr
