// Built-in phantom (sim/phantom.h): geometry, determinism by seed, value range, intensity
// classes and texture at several scales. Exact values depend on the standard library's
// std::normal_distribution, so nothing here compares against stored numbers.
#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "dsr/sim/phantom.h"

namespace dsr {
namespace {

constexpr int kSize = 64;

Image SmallPhantom(uint64_t seed) {
  PhantomOptions options;
  options.size = kSize;
  options.seed = seed;
  return MakePhantom(options);
}

// Fraction of interior voxels whose central-difference gradient magnitude (intensity per
// voxel) exceeds `threshold`.
double FractionWithGradientAbove(const Image& image, double threshold) {
  const Eigen::Vector3i n = image.geometry.size;
  int64_t above = 0, total = 0;
  for (int k = 1; k + 1 < n[2]; ++k) {
    for (int j = 1; j + 1 < n[1]; ++j) {
      for (int i = 1; i + 1 < n[0]; ++i) {
        const double gx = 0.5 * (image.at(i + 1, j, k) - image.at(i - 1, j, k));
        const double gy = 0.5 * (image.at(i, j + 1, k) - image.at(i, j - 1, k));
        const double gz = 0.5 * (image.at(i, j, k + 1) - image.at(i, j, k - 1));
        above += std::sqrt(gx * gx + gy * gy + gz * gz) > threshold;
        ++total;
      }
    }
  }
  return static_cast<double>(above) / total;
}

// Block means over b^3 voxels: removes the speckle-scale texture.
Image BlockMean(const Image& image, int b) {
  ImageGeometry g;
  g.size = image.geometry.size / b;
  Image out(g, 0.0f);
  for (int k = 0; k < g.size[2] * b; ++k) {
    for (int j = 0; j < g.size[1] * b; ++j) {
      for (int i = 0; i < g.size[0] * b; ++i) {
        out.at(i / b, j / b, k / b) += image.at(i, j, k) / static_cast<float>(b * b * b);
      }
    }
  }
  return out;
}

TEST(Phantom, GeometryIsCentredOnTheOrigin) {
  PhantomOptions options;
  options.size = 32;
  options.spacing_mm = 0.5;
  const Image image = MakePhantom(options);
  EXPECT_EQ(image.geometry.size, Eigen::Vector3i(32, 32, 32));
  EXPECT_EQ(image.voxels.size(), 32u * 32u * 32u);
  EXPECT_TRUE(image.geometry.spacing_mm.isApprox(Eigen::Vector3d::Constant(0.5)));
  EXPECT_TRUE(image.geometry.direction.isIdentity());
  EXPECT_LT(image.geometry.IndexToPhysical(Eigen::Vector3d::Constant(15.5)).norm(), 1e-12);
}

TEST(Phantom, DeterministicBySeedAndSeedsDiffer) {
  const Image a = SmallPhantom(1);
  const Image b = SmallPhantom(1);
  EXPECT_EQ(a.voxels, b.voxels);  // bit-identical, whatever the thread count
  const Image c = SmallPhantom(2);
  int64_t different = 0;
  for (size_t v = 0; v < a.voxels.size(); ++v)
    different += std::abs(a.voxels[v] - c.voxels[v]) > 1.0f;
  EXPECT_GT(different, static_cast<int64_t>(a.voxels.size() / 2));
}

TEST(Phantom, ValuesAreFiniteAndInRange) {
  const Image image = SmallPhantom(3);
  for (float v : image.voxels) {
    ASSERT_TRUE(std::isfinite(v));
    ASSERT_GE(v, 0.0f);
    ASSERT_LE(v, 255.0f);
  }
}

TEST(Phantom, HasBloodTissueAndWallIntensities) {
  PhantomOptions options;
  options.size = 96;
  const Image image = MakePhantom(options);
  std::vector<float> sorted = image.voxels;
  std::sort(sorted.begin(), sorted.end());
  auto fraction_below = [&](float t) {
    return static_cast<double>(std::lower_bound(sorted.begin(), sorted.end(), t) - sorted.begin()) /
           sorted.size();
  };
  // Most of the volume is background around the heart: measured ~6% blood below 45 and
  // ~3% bright walls above 150 for seeds 1-3 at sizes 64-192; bounds at half that.
  EXPECT_GT(fraction_below(45.0f), 0.03);          // blood pools
  EXPECT_GT(1.0 - fraction_below(150.0f), 0.015);  // myocardium, pericardium, valves
  const float median = sorted[sorted.size() / 2];
  EXPECT_GT(median, 65.0f);  // background tissue (~70-110) dominates
  EXPECT_LT(median, 115.0f);
  // Clamping touches only the tails.
  EXPECT_LT(fraction_below(0.5f), 0.01);
}

TEST(Phantom, IsTexturedAtSeveralScales) {
  const Image image = SmallPhantom(1);
  // Speckle scale: almost every voxel has a gradient well above zero (not piecewise flat).
  EXPECT_GT(FractionWithGradientAbove(image, 2.0), 0.8);
  // After 4^3 block means (speckle averaged out), structure and the medium/slow texture
  // remain: most blocks still differ from their neighbours by several intensity units.
  const Image coarse = BlockMean(image, 4);
  EXPECT_GT(FractionWithGradientAbove(coarse, 2.0), 0.5);
}

TEST(Phantom, ValidateRejectsNonsense) {
  std::string error;
  PhantomOptions options;
  EXPECT_TRUE(options.Validate(&error));
  options.size = 8;
  EXPECT_FALSE(options.Validate(&error));
  EXPECT_NE(error.find("size=8"), std::string::npos) << error;
  options = PhantomOptions();
  options.spacing_mm = 0.0;
  EXPECT_FALSE(options.Validate(&error));
  EXPECT_NE(error.find("spacing"), std::string::npos) << error;
  options.spacing_mm = std::nan("");
  EXPECT_FALSE(options.Validate(&error));
}

}  // namespace
}  // namespace dsr
