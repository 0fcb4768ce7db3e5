// SmoothInsideMask (image/pyramid.h): the per-axis overload is the single-sigma one when the
// three sigmas are equal, smooths each axis with its own Gaussian (the impulse response is
// the product of the three normalised 1-D kernels), and does not depend on the thread count.
#include "dsr/image/pyramid.h"

#include <cmath>
#include <random>
#include <vector>

#include <gtest/gtest.h>

#include "dsr/geometry/volume.h"

namespace dsr {
namespace {

// Float sums of at most 3 x 13 weights of magnitude <= 1: rounding below 1e-6.
constexpr double kFloatKernelTolerance = 1e-6;

Image RandomImage(const Eigen::Vector3i& size, uint64_t seed) {
  ImageGeometry g;
  g.size = size;
  g.spacing_mm = Eigen::Vector3d(0.6, 0.6, 4.0);
  Image image(g);
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<float> value(0.0f, 255.0f);
  for (float& v : image.voxels) v = value(rng);
  return image;
}

// Mask with a hole and a cut corner, so that the normalised convolution's weights matter.
Mask IrregularMask(const ImageGeometry& g) {
  Mask mask(g, 1);
  for (int k = 0; k < g.size[2]; ++k) {
    for (int j = 0; j < g.size[1]; ++j) {
      for (int i = 0; i < g.size[0]; ++i) {
        if ((i + j + 2 * k) % 11 == 0 || i + j < 5) mask.at(i, j, k) = 0;
      }
    }
  }
  return mask;
}

// The normalised 1-D Gaussian of image/pyramid.cc at offset d (radius max(1, ceil(3 s))).
double KernelWeight(double sigma, int d) {
  const int radius = std::max(1, static_cast<int>(std::ceil(3.0 * sigma)));
  if (std::abs(d) > radius) return 0.0;
  double sum = 0.0;
  for (int t = -radius; t <= radius; ++t) sum += std::exp(-0.5 * t * t / (sigma * sigma));
  return std::exp(-0.5 * d * d / (sigma * sigma)) / sum;
}

TEST(SmoothInsideMask, EqualSigmasPerAxisAreTheSingleSigmaBitForBit) {
  const Image image = RandomImage(Eigen::Vector3i(17, 14, 9), 3);
  const Mask mask = IrregularMask(image.geometry);
  for (double sigma : {0.0, 0.4, 1.0, 2.3}) {
    const Image single = SmoothInsideMask(image, mask, sigma, 2);
    const Image per_axis = SmoothInsideMask(image, mask, Eigen::Vector3d::Constant(sigma), 2);
    EXPECT_EQ(single.voxels, per_axis.voxels) << sigma;
  }
}

TEST(SmoothInsideMask, EachAxisGetsItsOwnGaussian) {
  ImageGeometry g;
  g.size = Eigen::Vector3i(21, 15, 11);
  Image impulse(g, 0.0f);
  const Eigen::Vector3i c(10, 7, 5);
  impulse.at(c[0], c[1], c[2]) = 1.0f;
  const Eigen::Vector3d sigma(1.5, 0.0, 0.7);  // y not smoothed
  const Image smoothed = SmoothInsideMask(impulse, Mask(g, 1), sigma, 1);
  for (int k = 0; k < g.size[2]; ++k) {
    for (int j = 0; j < g.size[1]; ++j) {
      for (int i = 0; i < g.size[0]; ++i) {
        // Inside the grid every kernel is whole, so the normalising weight is 1.
        const double expected = KernelWeight(sigma[0], i - c[0]) * (j == c[1] ? 1.0 : 0.0) *
                                KernelWeight(sigma[2], k - c[2]);
        ASSERT_NEAR(smoothed.at(i, j, k), expected, kFloatKernelTolerance)
            << i << "," << j << "," << k;
      }
    }
  }
}

TEST(SmoothInsideMask, PerAxisIsIndependentOfTheThreadCount) {
  const Image image = RandomImage(Eigen::Vector3i(23, 19, 13), 5);
  const Mask mask = IrregularMask(image.geometry);
  const Eigen::Vector3d sigma(1.7, 1.7, 0.25);  // 1 mm on a 0.6 x 0.6 x 4 mm grid
  const Image one = SmoothInsideMask(image, mask, sigma, 1);
  for (int threads : {2, 3, 0}) {
    EXPECT_EQ(SmoothInsideMask(image, mask, sigma, threads).voxels, one.voxels) << threads;
  }
  EXPECT_NE(one.voxels, image.voxels);
}

}  // namespace
}  // namespace dsr
