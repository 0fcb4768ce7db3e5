// SmoothInsideMask (image/pyramid.h): the per-axis overload is the single-sigma one when the
// three sigmas are equal, smooths each axis with its own Gaussian (the impulse response is
// the product of the three normalised 1-D kernels), and does not depend on the thread count.
#include "dsr/image/pyramid.h"

#include <algorithm>
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

// The normalised convolution written out voxel by voxel (the slow twin of the separable
// passes): the float kernel (GaussianKernel), then for each output voxel the
// x sums (masked) of the rows it needs, their y sums, their z sum, each tap added in
// increasing index order as float, and the value divided by the weight where the weight
// exceeds 1e-3. The fast passes take the same operations in the same order, so the two
// agree bit for bit.
std::vector<float> TwinSmooth(const Image& image, const Mask& mask, const Eigen::Vector3d& sigma,
                              int stride, Eigen::Vector3i* out_size) {
  const Eigen::Vector3i n = image.geometry.size;
  Eigen::Vector3i o;
  std::vector<float> kernel[3];
  int radius[3], step[3];
  for (int a = 0; a < 3; ++a) {
    step[a] = n[a] == 1 ? 1 : stride;
    o[a] = step[a] == 1 ? n[a] : (n[a] - 1) / step[a] + 1;
    // No smoothing: the x pass weighs by 1, the y and z passes copy (a one-tap kernel of 1).
    kernel[a] = sigma[a] > 0.0 && n[a] > 1 ? GaussianKernel(sigma[a]) : std::vector<float>{1.0f};
    radius[a] = static_cast<int>(kernel[a].size()) / 2;
  }
  *out_size = o;
  std::vector<float> out(static_cast<size_t>(o.cast<int64_t>().prod()));
  for (int k = 0; k < o[2]; ++k) {
    for (int j = 0; j < o[1]; ++j) {
      for (int i = 0; i < o[0]; ++i) {
        const int cx = step[0] * i, cy = step[1] * j, cz = step[2] * k;
        float value = 0.0f, weight = 0.0f;
        for (int z = std::max(0, cz - radius[2]); z <= std::min(n[2] - 1, cz + radius[2]); ++z) {
          float vy = 0.0f, wy = 0.0f;
          for (int y = std::max(0, cy - radius[1]); y <= std::min(n[1] - 1, cy + radius[1]);
               ++y) {
            float vx = 0.0f, wx = 0.0f;
            for (int x = std::max(0, cx - radius[0]); x <= std::min(n[0] - 1, cx + radius[0]);
                 ++x) {
              if (mask.at(x, y, z) == 0) continue;
              const float c = kernel[0][x - cx + radius[0]];
              vx += c * image.at(x, y, z);
              wx += c;
            }
            const float c = kernel[1][y - cy + radius[1]];
            vy += c * vx;
            wy += c * wx;
          }
          const float c = kernel[2][z - cz + radius[2]];
          value += c * vy;
          weight += c * wy;
        }
        out[i + int64_t{o[0]} * (j + int64_t{o[1]} * k)] =
            weight > 1e-3f ? value / weight : 0.0f;
      }
    }
  }
  return out;
}

TEST(SmoothInsideMask, IsTheNormalisedConvolutionVoxelByVoxelBitForBit) {
  const Image image = RandomImage(Eigen::Vector3i(19, 13, 11), 7);
  const Mask mask = IrregularMask(image.geometry);
  for (const Eigen::Vector3d& sigma :
       {Eigen::Vector3d(1.0, 1.0, 1.0), Eigen::Vector3d(1.7, 0.0, 0.6),
        Eigen::Vector3d(0.0, 2.3, 0.4)}) {
    Eigen::Vector3i size;
    const std::vector<float> twin = TwinSmooth(image, mask, sigma, 1, &size);
    ASSERT_EQ(size, image.geometry.size);
    for (int threads : {1, 2}) {
      EXPECT_EQ(SmoothInsideMask(image, mask, sigma, threads).voxels, twin)
          << sigma.transpose() << " threads " << threads;
    }
  }
}

TEST(Downsample, IsTheNormalisedConvolutionAtEveryOtherVoxelBitForBit) {
  for (const Eigen::Vector3i& n :
       {Eigen::Vector3i(19, 13, 11), Eigen::Vector3i(16, 9, 1), Eigen::Vector3i(1, 12, 7),
        Eigen::Vector3i(53, 6, 5), Eigen::Vector3i(4, 5, 3)}) {
    const Image image = RandomImage(n, 11 + n[0]);
    const Mask mask = IrregularMask(image.geometry);
    for (double sigma : {1.0, 0.5, 1.7}) {
      Eigen::Vector3i size;
      const std::vector<float> twin = TwinSmooth(image, mask, Eigen::Vector3d::Constant(sigma),
                                                 2, &size);
      for (int threads : {1, 2}) {
        const ImageLevel level = Downsample(image, mask, sigma, threads);
        EXPECT_EQ(level.image.geometry.size, size);
        EXPECT_EQ(level.image.voxels, twin) << n.transpose() << " sigma " << sigma;
      }
    }
  }
}

}  // namespace
}  // namespace dsr
