// Tests of the sector and dropout finder (dsr/geometry/lost_signal.h) on frames built by
// hand: a pyramidal sector of tissue with structure along every beam, and a wedge of it
// where only noise remains.
#include "dsr/geometry/lost_signal.h"

#include <cmath>
#include <random>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

namespace dsr {
namespace {

constexpr double kHalfOpening = 0.6;  // tan of the sector's half-angle, both ways

// A 48 x 44 x 40 frame whose field of view is a pyramid with its apex at (23.5, 21.5, -2):
// |i - 23.5| and |j - 21.5| at most kHalfOpening (k + 2), k >= 2. Inside, tissue with
// structure (about 60 + 30 s(i, j, k), times `tissue_scale`) and Gaussian noise of sigma 10
// clamped at 0; in the wedge 0.15 <= (i - 23.5) / (k + 2) < 0.45 (when `wedge`), the noise
// alone.
struct Sectored {
  Image image;
  Mask fov, wedge;
};

Sectored MakeSectored(bool wedge, uint64_t seed, double tissue_scale = 1.0) {
  ImageGeometry g;
  g.size = Eigen::Vector3i(48, 44, 40);
  Sectored s{Image(g, 0.0f), Mask(g, 0), Mask(g, 0)};
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> noise(0.0, 10.0);
  for (int k = 2; k < g.size[2]; ++k) {
    for (int j = 0; j < g.size[1]; ++j) {
      for (int i = 0; i < g.size[0]; ++i) {
        const double depth = k + 2.0, u = (i - 23.5) / depth, v = (j - 21.5) / depth;
        if (std::abs(u) > kHalfOpening || std::abs(v) > kHalfOpening) continue;
        const int64_t l = g.LinearIndex(i, j, k);
        s.fov.voxels[l] = 1;
        const bool lost = wedge && u >= 0.15 && u < 0.45;
        s.wedge.voxels[l] = lost;
        const double tissue =
            lost ? 0.0
                 : tissue_scale * (60.0 + 30.0 * std::sin(0.5 * i) * std::cos(0.4 * j) +
                                   20.0 * std::sin(0.3 * k));
        s.image.voxels[l] = static_cast<float>(std::max(0.0, tissue + noise(rng)));
      }
    }
  }
  return s;
}

TEST(LostSignal, FindsThePyramidsApexAndDepthAxis) {
  const Sectored s = MakeSectored(false, 1);
  const Sector sector = FindSector(s.fov);
  ASSERT_TRUE(sector.found);
  EXPECT_EQ(sector.depth_axis, 2);
  EXPECT_EQ(sector.direction, 1);
  EXPECT_NEAR(sector.apex[0], 23.5, 0.5);
  EXPECT_NEAR(sector.apex[1], 21.5, 0.5);
  EXPECT_NEAR(sector.apex[2], -2.0, 1.5);
  EXPECT_GT(sector.widening, 5.0);
}

// The same pyramid flipped along k and with its axes exchanged: the axis and direction follow.
TEST(LostSignal, FindsTheSectorAlongAnyAxisAndDirection) {
  const Sectored s = MakeSectored(false, 1);
  const ImageGeometry& g = s.fov.geometry;
  ImageGeometry turned;
  turned.size = Eigen::Vector3i(g.size[2], g.size[1], g.size[0]);  // k becomes i
  Mask flipped(turned, 0);
  for (int k = 0; k < g.size[2]; ++k) {
    for (int j = 0; j < g.size[1]; ++j) {
      for (int i = 0; i < g.size[0]; ++i) {
        flipped.at(g.size[2] - 1 - k, j, i) = s.fov.at(i, j, k);
      }
    }
  }
  const Sector sector = FindSector(flipped);
  ASSERT_TRUE(sector.found);
  EXPECT_EQ(sector.depth_axis, 0);
  EXPECT_EQ(sector.direction, -1);
  EXPECT_NEAR(sector.apex[0], g.size[2] - 1 + 2.0, 1.5);
  EXPECT_NEAR(sector.apex[1], 21.5, 0.5);
  EXPECT_NEAR(sector.apex[2], 23.5, 0.5);
}

TEST(LostSignal, ABoxHasNoSectorAndLosesNothing) {
  ImageGeometry g;
  g.size = Eigen::Vector3i(32, 32, 32);
  Mask box(g, 0);
  Image image(g, 0.0f);
  for (int k = 4; k < 28; ++k) {
    for (int j = 4; j < 28; ++j) {
      for (int i = 4; i < 28; ++i) box.at(i, j, k) = 1;
    }
  }
  EXPECT_FALSE(FindSector(box).found);
  const LostSignal lost = FindLostSignal(image, box);
  EXPECT_FALSE(lost.sector.found);
  EXPECT_EQ(lost.lost_voxels, 0);
  EXPECT_TRUE(lost.lost.empty());
}

TEST(LostSignal, LeavesOutTheWedgeWhereOnlyNoiseRemains) {
  for (uint64_t seed : {1, 2, 3}) {
    const Sectored s = MakeSectored(true, seed);
    const LostSignal lost = FindLostSignal(s.image, s.fov);
    ASSERT_FALSE(lost.lost.empty()) << "seed " << seed;
    int64_t both = 0, wedge = 0;
    for (size_t l = 0; l < s.fov.voxels.size(); ++l) {
      wedge += s.wedge.voxels[l];
      both += s.wedge.voxels[l] && lost.lost.voxels[l];
      EXPECT_TRUE(!lost.lost.voxels[l] || s.fov.voxels[l]);  // only inside the field of view
    }
    EXPECT_GT(both, 0.9 * wedge) << "seed " << seed;              // most of the wedge found
    EXPECT_GT(both, 0.9 * lost.lost_voxels) << "seed " << seed;   // little else
    EXPECT_EQ(lost.fov_voxels, CountInside(s.fov));
  }
}

// The share of `s`'s wedge that `lost` holds, and the share of `lost` inside the wedge.
std::pair<double, double> Overlap(const Sectored& s, const LostSignal& lost) {
  int64_t both = 0, wedge = 0;
  for (size_t l = 0; l < s.fov.voxels.size(); ++l) {
    wedge += s.wedge.voxels[l];
    both += s.wedge.voxels[l] && !lost.lost.empty() && lost.lost.voxels[l];
  }
  return {wedge > 0 ? static_cast<double>(both) / wedge : 0.0,
          lost.lost_voxels > 0 ? static_cast<double>(both) / lost.lost_voxels : 1.0};
}

// Views of dark tissue (0.15 of the others' level: about 11 grey levels over noise of sigma
// 10), whose wedges hold noise more than a quarter as bright as most of their bins: with a
// bright view of the same acquisition, whose wedge shows the level of noise alone, the
// wedges are found at least as well as alone, and a dark view without a wedge still loses
// nothing.
TEST(LostSignal, ADarkViewsWedgeIsFoundWithTheNoiseLevelTheViewsShare) {
  for (uint64_t seed : {5, 8, 11}) {
    const Sectored dark = MakeSectored(true, seed, 0.15), bright = MakeSectored(true, seed + 1);
    const Sectored dark_whole = MakeSectored(false, seed + 2, 0.15);
    const double alone = Overlap(dark, FindLostSignal(dark.image, dark.fov)).first;
    const std::vector<LostSignal> views = FindLostSignalInViews(
        {bright.image, dark.image, dark_whole.image}, {bright.fov, dark.fov, dark_whole.fov}, 2);
    ASSERT_EQ(views.size(), 3u);
    const auto [found, precise] = Overlap(dark, views[1]);
    EXPECT_GT(found, 0.85) << "seed " << seed;
    EXPECT_GE(found, alone) << "seed " << seed;
    EXPECT_GT(precise, 0.9) << "seed " << seed;
    EXPECT_GT(Overlap(bright, views[0]).first, 0.9) << "seed " << seed;
    EXPECT_EQ(views[2].lost_voxels, 0) << "seed " << seed;
    // One view gives what FindLostSignal gives.
    EXPECT_EQ(FindLostSignalInViews({dark.image}, {dark.fov}, 1)[0].lost_voxels,
              FindLostSignal(dark.image, dark.fov).lost_voxels);
  }
}

TEST(LostSignal, TissueWithoutAWedgeLosesNothing) {
  for (uint64_t seed : {1, 2, 3}) {
    const Sectored s = MakeSectored(false, seed);
    const LostSignal lost = FindLostSignal(s.image, s.fov);
    EXPECT_TRUE(lost.sector.found);
    EXPECT_EQ(lost.lost_voxels, 0) << "seed " << seed;
  }
}

// A uniform bright frame has no structure along its beams, but no bin lies far below its
// median: flat tissue is not lost contact.
TEST(LostSignal, FlatTissueIsNotADropout) {
  Sectored s = MakeSectored(false, 4);
  for (size_t l = 0; l < s.image.voxels.size(); ++l) {
    if (s.fov.voxels[l]) s.image.voxels[l] = 100.0f;
  }
  EXPECT_EQ(FindLostSignal(s.image, s.fov).lost_voxels, 0);
}

}  // namespace
}  // namespace dsr
