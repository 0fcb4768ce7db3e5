// Fusion and interoperability: the mean and feathered panoramas against a
// brute-force reference, the field-of-view enlargement ratio, and per-frame ITK transform
// files that ITK's own reader and resampler turn into the project's resampling.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>

#include "dsr/image/frame.h"
#include "dsr/io/io_image.h"
#include "dsr/io/io_transform.h"
#include "dsr/model/panorama.h"
#include "dsr/io/io_image_test_itk.h"
#include "dsr/tests/support/scoped_temp_dir.h"
#include "dsr/tests/support/test_problems.h"

namespace dsr {
namespace {

using testing_problems::MakeSequence;
using testing_problems::Perturbed;
using testing_problems::SequenceOptions;

TEST(Fusion, MeanAndFeatherMatchBruteForce) {
  SequenceOptions o;
  o.num_frames = 3;
  o.size = 12;
  o.noise_sigma = 5.0;
  o.frame_offset = 3.0;
  const auto s = MakeSequence(o);
  const auto poses = Perturbed(s.ground_truth, 0.05, 0.7, 2);
  ImageGeometry grid;
  std::string error;
  ASSERT_TRUE(BuildPanoramaGrid(s.frames, poses, 1.0, &grid, &error)) << error;
  const PanoramaImages mean = FusePanoramaMean(s.frames, poses, grid, 2);
  const double feather = 3.0;
  const PanoramaImages feathered = FusePanoramaFeather(s.frames, poses, grid, feather, 2);
  std::vector<Volume<float>> distance;
  for (const Frame& f : s.frames) distance.push_back(ValidCellDistance(f));
  int64_t seen = 0, seen0 = 0, blended = 0;
  for (int k = 0; k < grid.size[2]; ++k) {
    for (int j = 0; j < grid.size[1]; ++j) {
      for (int i = 0; i < grid.size[0]; ++i) {
        const Eigen::Vector3d p = grid.IndexToPhysical(Eigen::Vector3d(i, j, k));
        double sum = 0.0, wsum = 0.0, wvalue = 0.0;
        int count = 0;
        for (size_t f = 0; f < s.frames.size(); ++f) {
          double value;
          RowVector6d unused;
          if (!ObserveSample(s.frames[f], poses[f], p, &value, nullptr)) continue;
          sum += value;
          ++count;
          if (f == 0) ++seen0;
          // Brute-force trilinear interpolation of the distance map.
          const Eigen::Vector3d u = s.frames[f].ToIndex(poses[f] * p);
          double d = 0.0;
          for (int c = 0; c < 8; ++c) {
            const int x = static_cast<int>(std::floor(u[0])) + (c & 1);
            const int y = static_cast<int>(std::floor(u[1])) + ((c >> 1) & 1);
            const int z = static_cast<int>(std::floor(u[2])) + ((c >> 2) & 1);
            const double w =
                (1 - std::abs(u[0] - x)) * (1 - std::abs(u[1] - y)) * (1 - std::abs(u[2] - z));
            d += w * distance[f].at(x, y, z);
          }
          const double weight = std::clamp(d / feather, 1e-6, 1.0);
          wsum += weight;
          wvalue += weight * value;
        }
        const int64_t l = grid.LinearIndex(i, j, k);
        ASSERT_EQ(mean.count.voxels[l], count);
        if (count > 0) ++seen;
        if (count > 1) ++blended;
        EXPECT_NEAR(mean.mean.voxels[l], count ? sum / count : 0.0, 1e-4);
        EXPECT_NEAR(feathered.mean.voxels[l], wsum > 0 ? wvalue / wsum : 0.0, 1e-3);
      }
    }
  }
  EXPECT_GT(blended, 100);
  EXPECT_EQ(mean.seen_voxels, seen);
  EXPECT_EQ(mean.frame0_voxels, seen0);
  EXPECT_DOUBLE_EQ(mean.EnlargementRatio(), static_cast<double>(seen) / seen0);
  EXPECT_GT(mean.EnlargementRatio(), 1.0);
}

// Two frames of the same content, frame 1 seen through a gain 1.2 and an offset 5 (its
// voxels are (content - 5) / 1.2): corrected by (1.2, 5) the fused panorama is the content
// wherever both observe it, without correction it has a seam; the gauge (1, 0) on every
// frame leaves the panorama bit for bit as it was.
TEST(Fusion, PhotometricCorrectionsRemoveAGainSeam) {
  ImageGeometry g;
  g.size = Eigen::Vector3i(16, 14, 12);
  const auto content = [](int i, int j, int k) {
    return 60.0 + 30.0 * std::sin(0.7 * i) + 15.0 * std::cos(0.5 * j) + 3.0 * k;
  };
  constexpr int kShift = 5;  // frame 1 sees world x = i + 5
  Image frame0(g), frame1(g);
  for (int k = 0; k < g.size[2]; ++k)
    for (int j = 0; j < g.size[1]; ++j)
      for (int i = 0; i < g.size[0]; ++i) {
        frame0.at(i, j, k) = static_cast<float>(content(i, j, k));
        frame1.at(i, j, k) = static_cast<float>((content(i + kShift, j, k) - 5.0) / 1.2);
      }
  const std::vector<Frame> frames = {Frame(frame0, Mask(g, 1)), Frame(frame1, Mask(g, 1))};
  Eigen::Isometry3d shifted = Eigen::Isometry3d::Identity();
  shifted.translation() = Eigen::Vector3d(-kShift, 0.0, 0.0);
  const std::vector<Eigen::Isometry3d> poses = {Eigen::Isometry3d::Identity(), shifted};
  const std::vector<Photometric> correction = {Photometric(), {std::log(1.2), 5.0}};
  ImageGeometry grid;
  std::string error;
  ASSERT_TRUE(BuildPanoramaGrid(frames, poses, 1.0, &grid, &error)) << error;
  const PanoramaImages raw = FusePanoramaMean(frames, poses, grid, 2);
  const PanoramaImages mean = FusePanoramaMean(frames, poses, grid, 2, correction);
  const PanoramaImages feathered = FusePanoramaFeather(frames, poses, grid, 3.0, 2, correction);
  int64_t overlap = 0;
  double largest_seam = 0.0;
  for (int k = 0; k < grid.size[2]; ++k) {
    for (int j = 0; j < grid.size[1]; ++j) {
      for (int i = 0; i < grid.size[0]; ++i) {
        const int64_t l = grid.LinearIndex(i, j, k);
        const Eigen::Vector3d p = grid.IndexToPhysical(Eigen::Vector3d(i, j, k));
        // Both frames interpolate the same lattice: the content there is frame 0's sample
        // where frame 0 sees p, else frame 1's corrected one.
        double value0, value1;
        const bool seen0 = frames[0].Sample(poses[0] * p, &value0, nullptr);
        const bool seen1 = frames[1].Sample(poses[1] * p, &value1, nullptr);
        ASSERT_EQ(mean.count.voxels[l], seen0 + seen1);
        if (!seen0 && !seen1) continue;
        const double expected = seen0 ? value0 : correction[1].Correct(value1);
        // Float voxels of about 100: a few 1e-6 relative at most.
        const double tolerance = 1e-6 * std::abs(expected);
        EXPECT_NEAR(mean.mean.voxels[l], expected, tolerance) << i << " " << j << " " << k;
        EXPECT_NEAR(feathered.mean.voxels[l], expected, tolerance) << i << " " << j << " " << k;
        if (seen0 && seen1) {
          ++overlap;
          largest_seam = std::max(largest_seam, std::abs(raw.mean.voxels[l] - expected));
        }
      }
    }
  }
  EXPECT_GT(overlap, 500);
  // Uncorrected, the overlap averages content and (content - 5) / 1.2: off by
  // (0.2 content + 5) / 2.4, several grey levels here.
  EXPECT_GT(largest_seam, 5.0);
  // No correction (the gauge everywhere): the uncorrected panorama, bit for bit.
  const std::vector<Photometric> gauge(2);
  EXPECT_EQ(FusePanoramaMean(frames, poses, grid, 2, gauge).mean.voxels, raw.mean.voxels);
  EXPECT_EQ(FusePanoramaFeather(frames, poses, grid, 3.0, 2, gauge).mean.voxels,
            FusePanoramaFeather(frames, poses, grid, 3.0, 2).mean.voxels);
}

TEST(Fusion, DistanceMapIsCityBlockDistanceToTheInvalidRegion) {
  ImageGeometry g;
  g.size = Eigen::Vector3i(11, 11, 11);
  Image image(g, 1.0f);
  Mask mask(g, 1);
  // Valid cells: 1..8 on each axis (the grid border has no central difference inside the
  // mask, so no valid cell has a corner there; image/frame.h).
  const Frame frame(image, mask);
  const Volume<float> d = ValidCellDistance(frame);
  EXPECT_EQ(d.at(9, 5, 5), 0.0f);  // last corner: not a valid cell
  EXPECT_EQ(d.at(0, 5, 5), 0.0f);  // the grid border
  EXPECT_EQ(d.at(1, 5, 5), 1.0f);  // next to it
  EXPECT_EQ(d.at(4, 4, 4), 4.0f);  // min over axes of distance to 0 or to 9
  EXPECT_EQ(d.at(5, 5, 5), 4.0f);
  EXPECT_EQ(d.at(2, 3, 4), 2.0f);
}

TEST(Fusion, EnlargementOfTwoDisjointFramesIsTwo) {
  ImageGeometry g;
  g.size = Eigen::Vector3i(10, 10, 10);
  Image image(g, 0.0f);
  for (size_t l = 0; l < image.voxels.size(); ++l) image.voxels[l] = static_cast<float>(l % 7);
  const std::vector<Frame> frames = {Frame(image, Mask(g, 1)), Frame(image, Mask(g, 1))};
  Eigen::Isometry3d shifted = Eigen::Isometry3d::Identity();
  shifted.translation() = Eigen::Vector3d(-20.0, 0.0, 0.0);  // frame 1 sees world x in [20, 29]
  const std::vector<Eigen::Isometry3d> poses = {Eigen::Isometry3d::Identity(), shifted};
  ImageGeometry grid;
  std::string error;
  ASSERT_TRUE(BuildPanoramaGrid(frames, poses, 1.0, &grid, &error)) << error;
  const PanoramaImages fused = FusePanoramaMean(frames, poses, grid, 1);
  EXPECT_DOUBLE_EQ(fused.EnlargementRatio(), 2.0);
}

// The panorama as a Frame: observed voxels are its field of view; an unobserved gap enclosed
// by observed voxels stays outside (no hole filling), so no valid cell touches it.
TEST(Fusion, PanoramaAsFrameLeavesUnobservedGapsOutside) {
  ImageGeometry g;
  g.size = Eigen::Vector3i(12, 12, 12);
  PanoramaImages fused;
  fused.mean = Image(g, 5.0f);
  fused.count = Volume<uint8_t>(g, 2);
  fused.count.at(6, 6, 6) = 0;  // the gap
  fused.mean.at(6, 6, 6) = 0.0f;
  const Frame panorama = PanoramaAsFrame(fused);
  // A cell is valid when its 8 corners carry gradients, i.e. they and their 6 neighbours
  // are observed: every cell within two voxels of the gap is invalid.
  EXPECT_FALSE(panorama.IsValidCell(g.LinearIndex(5, 5, 5)));
  EXPECT_FALSE(panorama.IsValidCell(g.LinearIndex(6, 6, 4)));
  EXPECT_TRUE(panorama.IsValidCell(g.LinearIndex(2, 2, 2)));
  EXPECT_TRUE(panorama.IsValidCell(g.LinearIndex(6, 6, 2)));
}

TEST(ItkTransform, FilesRoundTripAndResampleLikeTheProject) {
  const ScopedTempDir dir("dsr_fusion_test");
  SequenceOptions o;
  o.num_frames = 2;
  o.size = 14;
  o.spacing = 1.3;
  const auto s = MakeSequence(o);
  const auto poses = Perturbed(s.ground_truth, 0.08, 1.5, 4);
  const std::string image_path = dir.File("frame_01.nii.gz");
  std::string error;
  ASSERT_TRUE(WriteImage(s.images[1], image_path, &error)) << error;
  const std::string tfm = dir.File("frame_01.tfm");
  ASSERT_TRUE(WriteItkTransform(poses[1], tfm, &error)) << error;
  Eigen::Affine3d back;
  ASSERT_TRUE(ReadItkTransform(tfm, &back, &error)) << error;
  EXPECT_LT((back.matrix() - poses[1].matrix()).norm(), 1e-12);

  // ITK's reader and resampler put frame 1 on the panorama grid as the project does.
  ImageGeometry grid;
  ASSERT_TRUE(BuildPanoramaGrid(s.frames, poses, 0.8, &grid, &error)) << error;
  test_itk::Grid itk_grid;
  itk_grid.size = {grid.size[0], grid.size[1], grid.size[2]};
  for (int a = 0; a < 3; ++a) {
    itk_grid.origin[a] = grid.origin_mm[a];
    itk_grid.spacing[a] = grid.spacing_mm[a];
  }
  std::vector<float> itk;
  ASSERT_EQ(test_itk::ResampleWithTransformFile(image_path, tfm, itk_grid, &itk), "");
  const Frame& frame = s.frames[1];
  int64_t compared = 0;
  for (int k = 0; k < grid.size[2]; ++k) {
    for (int j = 0; j < grid.size[1]; ++j) {
      for (int i = 0; i < grid.size[0]; ++i) {
        const Eigen::Vector3d u =
            frame.ToIndex(poses[1] * grid.IndexToPhysical(Eigen::Vector3d(i, j, k)));
        // Inside the image (ITK and the project agree on the outside only as 0 vs 0).
        if ((u.array() < 0.0).any() ||
            (u.array() > (frame.geometry().size.cast<double>().array() - 1.0)).any()) {
          continue;
        }
        const double ours = frame.InterpolateValue(u);
        EXPECT_NEAR(itk[grid.LinearIndex(i, j, k)], ours, 1e-3 * (1.0 + std::abs(ours)));
        ++compared;
      }
    }
  }
  EXPECT_GT(compared, 500);
  EXPECT_FALSE(WriteItkTransform(poses[1], dir.File("frame.json"), &error));
  EXPECT_THAT(error, ::testing::HasSubstr(".tfm"));
  EXPECT_FALSE(ReadItkTransform(dir.File("missing.tfm"), &back, &error));
  EXPECT_THAT(error, ::testing::HasSubstr("missing.tfm"));
}

}  // namespace
}  // namespace dsr
