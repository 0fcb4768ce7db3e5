// Sampler (docs/design.md section 2): on a volume whose intensity is linear in physical space,
// trilinear interpolation and central differences are exact, so values and physical
// gradients must be reproduced up to float storage rounding, wherever the sample is valid,
// whatever the image holds outside the mask (the gradient rule of image/frame.h).
#include "dsr/image/frame.h"

#include <cmath>
#include <random>

#include <gtest/gtest.h>

#include "dsr/geometry/se3.h"
#include "dsr/geometry/volume.h"
#include "dsr/model/observation.h"
#include "dsr/tests/support/tolerances.h"

namespace dsr {
namespace {

// Voxels are stored as float: values up to ~300 carry ~2e-5 absolute rounding error.
using testing_tolerances::kFloatValueTolerance;
constexpr double kFloatGradientTolerance = 1e-4;

ImageGeometry ObliqueAnisotropicGeometry() {
  ImageGeometry g;
  g.size = Eigen::Vector3i(12, 10, 9);
  g.spacing_mm = Eigen::Vector3d(0.7, 1.3, 2.1);
  g.origin_mm = Eigen::Vector3d(-5.0, 3.0, 12.5);
  g.direction = Eigen::AngleAxisd(0.4, Eigen::Vector3d(1.0, 2.0, 3.0).normalized())
                    .toRotationMatrix();
  return g;
}

Image LinearImage(const ImageGeometry& g, const Eigen::Vector3d& slope, double offset) {
  Image image(g);
  for (int k = 0; k < g.size[2]; ++k)
    for (int j = 0; j < g.size[1]; ++j)
      for (int i = 0; i < g.size[0]; ++i)
        image.at(i, j, k) = static_cast<float>(
            slope.dot(g.IndexToPhysical(Eigen::Vector3d(i, j, k))) + offset);
  return image;
}

TEST(ImageGeometry, IndexPhysicalRoundTrip) {
  const ImageGeometry g = ObliqueAnisotropicGeometry();
  const Eigen::Vector3d ijk(1.25, 7.5, 3.0);
  EXPECT_LT((g.PhysicalToIndex(g.IndexToPhysical(ijk)) - ijk).norm(), 1e-12);
  // x = o + D S u
  const Eigen::Vector3d expected =
      g.origin_mm + g.direction * g.spacing_mm.cwiseProduct(ijk);
  EXPECT_LT((g.IndexToPhysical(ijk) - expected).norm(), 1e-12);
}

TEST(ImageGeometry, ValidateRejectsBadGrids) {
  std::string error;
  ImageGeometry g = ObliqueAnisotropicGeometry();
  EXPECT_TRUE(g.Validate("a.nii", &error)) << error;
  g.spacing_mm[1] = 0.0;
  EXPECT_FALSE(g.Validate("a.nii", &error));
  EXPECT_NE(error.find("spacing"), std::string::npos);
  g = ObliqueAnisotropicGeometry();
  g.direction.col(2) = g.direction.col(1);
  EXPECT_FALSE(g.Validate("a.nii", &error));
  EXPECT_NE(error.find("direction"), std::string::npos);
}

TEST(Frame, LinearFieldIsReproducedExactly) {
  for (const ImageGeometry& g : {ImageGeometry{Eigen::Vector3i(8, 9, 10)},
                                 ObliqueAnisotropicGeometry()}) {
    const Eigen::Vector3d slope(1.5, -2.0, 0.75);
    const Image image = LinearImage(g, slope, 100.0);
    const Frame frame(image, Mask(g, 1));
    std::mt19937_64 rng(7);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    for (int n = 0; n < 200; ++n) {
      // Anywhere in the valid cells: all but the outer voxel layer (the grid border counts
      // as outside the mask, so its voxels have no central difference).
      const Eigen::Vector3d ijk(1.0 + u(rng) * (g.size[0] - 3.001),
                                1.0 + u(rng) * (g.size[1] - 3.001),
                                1.0 + u(rng) * (g.size[2] - 3.001));
      const Eigen::Vector3d x = g.IndexToPhysical(ijk);
      double value;
      Eigen::Vector3d gradient;
      ASSERT_TRUE(frame.Sample(x, &value, &gradient));
      EXPECT_NEAR(value, slope.dot(x) + 100.0, kFloatValueTolerance);
      EXPECT_LT((gradient - slope).norm(), kFloatGradientTolerance) << gradient.transpose();
      EXPECT_NEAR(frame.InterpolateValue(ijk), value, 1e-9);
    }
  }
}

TEST(Frame, ValidityNeedsEveryCornersCentralDifferenceInsideTheMask) {
  ImageGeometry g;
  g.size = Eigen::Vector3i(6, 6, 6);
  Mask mask(g, 1);
  mask.at(3, 3, 3) = 0;
  const Frame frame(Image(g, 1.0f), mask);
  double value;
  // Corners must be inside the mask with their 6 neighbours: voxels 1..4 per axis (the
  // grid border counts as outside) except the hole and its 6 neighbours.
  EXPECT_TRUE(frame.Sample(Eigen::Vector3d(1.5, 1.5, 1.5), &value, nullptr));
  EXPECT_TRUE(frame.Sample(Eigen::Vector3d(3.0, 1.0, 1.0), &value, nullptr));
  EXPECT_TRUE(frame.Sample(Eigen::Vector3d(1.5, 1.5, 3.5), &value, nullptr));
  // Cells (2..3)^3 touch the hole.
  EXPECT_FALSE(frame.Sample(Eigen::Vector3d(2.5, 2.5, 2.5), &value, nullptr));
  EXPECT_FALSE(frame.Sample(Eigen::Vector3d(3.5, 3.5, 3.5), &value, nullptr));
  // Its 8 corners are inside the mask, but corner (2, 3, 3)'s difference along x would
  // read the hole.
  EXPECT_FALSE(frame.Sample(Eigen::Vector3d(1.5, 3.5, 3.5), &value, nullptr));
  // On the grid border, outside the grid, on the last index, or non-finite: invalid.
  EXPECT_FALSE(frame.Sample(Eigen::Vector3d(0.5, 0.5, 0.5), &value, nullptr));
  EXPECT_FALSE(frame.Sample(Eigen::Vector3d(-0.01, 1.0, 1.0), &value, nullptr));
  EXPECT_FALSE(frame.Sample(Eigen::Vector3d(5.0, 1.0, 1.0), &value, nullptr));
  EXPECT_FALSE(frame.Sample(Eigen::Vector3d(NAN, 1.0, 1.0), &value, nullptr));
  EXPECT_FALSE(frame.Sample(Eigen::Vector3d(1e30, 1.0, 1.0), &value, nullptr));
  // Of the 27 cells with corners in 1..4, only those with two lowest-corner coordinates
  // equal to 1 keep every corner off the hole's 7-voxel cross.
  EXPECT_EQ(frame.num_valid_cells(), 7);
}

// The valid-cell map against the rule written out cell by cell (the slow twin): a cell is
// valid when each of its 8 corners is inside the mask with its 6 neighbours, all inside the
// grid; the count and the bounding box of the valid cells follow. A random mask.
TEST(Frame, ValidCellsAreTheRuleCellByCell) {
  ImageGeometry g;
  g.size = Eigen::Vector3i(17, 11, 9);
  Mask mask(g, 0);
  std::mt19937_64 rng(5);
  std::bernoulli_distribution inside(0.99);
  for (int k = 1; k + 1 < g.size[2]; ++k)
    for (int j = 2; j + 1 < g.size[1]; ++j)
      for (int i = 1; i + 3 < g.size[0]; ++i) mask.at(i, j, k) = inside(rng) ? 1 : 0;
  const Frame frame(Image(g, 1.0f), mask);
  const auto in = [&](int i, int j, int k) {
    return i >= 0 && j >= 0 && k >= 0 && i < g.size[0] && j < g.size[1] && k < g.size[2] &&
           mask.at(i, j, k) != 0;
  };
  const auto stencil = [&](int i, int j, int k) {
    return in(i, j, k) && in(i - 1, j, k) && in(i + 1, j, k) && in(i, j - 1, k) &&
           in(i, j + 1, k) && in(i, j, k - 1) && in(i, j, k + 1);
  };
  int64_t count = 0;
  Eigen::AlignedBox3d box;
  for (int k = 0; k + 1 < g.size[2]; ++k) {
    for (int j = 0; j + 1 < g.size[1]; ++j) {
      for (int i = 0; i + 1 < g.size[0]; ++i) {
        bool valid = true;
        for (int c = 0; c < 8; ++c) valid = valid && stencil(i + (c & 1), j + (c >> 1 & 1),
                                                             k + (c >> 2));
        ASSERT_EQ(frame.IsValidCell(g.LinearIndex(i, j, k)), valid) << i << "," << j << "," << k;
        if (!valid) continue;
        ++count;
        box.extend(Eigen::Vector3d(i, j, k));
        box.extend(Eigen::Vector3d(i + 1, j + 1, k + 1));
      }
    }
  }
  ASSERT_GT(count, 50);
  EXPECT_EQ(frame.num_valid_cells(), count);
  EXPECT_EQ(frame.ValidIndexBox().min(), box.min());
  EXPECT_EQ(frame.ValidIndexBox().max(), box.max());
}

TEST(Frame, GradientsNeverReadOutsideTheMask) {
  // A linear field inside a ball-shaped field of view, 0 outside (and, second, a constant
  // that is no continuation of the field): every valid sample has the field's exact
  // gradient, the cells at the ball's edge included.
  const ImageGeometry g = ObliqueAnisotropicGeometry();
  const Eigen::Vector3d slope(0.8, -1.1, 2.0);
  const Eigen::Vector3d center(5.5, 4.5, 4.0);
  for (const float outside : {0.0f, 1000.0f}) {
    Image image = LinearImage(g, slope, 100.0);
    Mask mask(g, 0);
    for (int k = 0; k < g.size[2]; ++k)
      for (int j = 0; j < g.size[1]; ++j)
        for (int i = 0; i < g.size[0]; ++i) {
          const bool inside = (Eigen::Vector3d(i, j, k) - center).norm() <= 4.2;
          mask.at(i, j, k) = inside ? 1 : 0;
          if (!inside) image.at(i, j, k) = outside;
        }
    const Frame frame(image, mask);
    // Valid cells: those whose 8 corners lie in the mask eroded by the 6-neighbourhood.
    const auto stencil = [&](int i, int j, int k) {
      const auto in = [&](int x, int y, int z) {
        return x >= 0 && y >= 0 && z >= 0 && x < g.size[0] && y < g.size[1] && z < g.size[2] &&
               mask.at(x, y, z) != 0;
      };
      return in(i, j, k) && in(i - 1, j, k) && in(i + 1, j, k) && in(i, j - 1, k) &&
             in(i, j + 1, k) && in(i, j, k - 1) && in(i, j, k + 1);
    };
    int64_t expected_cells = 0, edge_cells = 0;
    for (int k = 0; k + 1 < g.size[2]; ++k)
      for (int j = 0; j + 1 < g.size[1]; ++j)
        for (int i = 0; i + 1 < g.size[0]; ++i) {
          bool corners_in_mask = true, corners_in_stencil = true;
          for (int c = 0; c < 8; ++c) {
            const int x = i + (c & 1), y = j + (c >> 1 & 1), z = k + (c >> 2 & 1);
            corners_in_mask = corners_in_mask && mask.at(x, y, z) != 0;
            corners_in_stencil = corners_in_stencil && stencil(x, y, z);
          }
          expected_cells += corners_in_stencil;
          edge_cells += corners_in_mask && !corners_in_stencil;
          EXPECT_EQ(frame.IsValidIndex(Eigen::Vector3d(i + 0.5, j + 0.5, k + 0.5)),
                    corners_in_stencil)
              << i << " " << j << " " << k;
        }
    EXPECT_EQ(frame.num_valid_cells(), expected_cells);
    ASSERT_GT(expected_cells, 20);
    ASSERT_GT(edge_cells, 20);  // the rule drops cells, not only the mask's corners
    std::mt19937_64 rng(3);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    int valid = 0;
    for (int n = 0; n < 2000; ++n) {
      const Eigen::Vector3d ijk(u(rng) * (g.size[0] - 1.001), u(rng) * (g.size[1] - 1.001),
                                u(rng) * (g.size[2] - 1.001));
      double value;
      Eigen::Vector3d gradient;
      if (!frame.Sample(g.IndexToPhysical(ijk), &value, &gradient)) continue;
      ++valid;
      EXPECT_NEAR(value, slope.dot(g.IndexToPhysical(ijk)) + 100.0, kFloatValueTolerance);
      EXPECT_LT((gradient - slope).norm(), kFloatGradientTolerance)
          << "outside " << outside << " at " << ijk.transpose() << ": " << gradient.transpose();
    }
    EXPECT_GT(valid, 100);
  }
}

// The sampler's twin: a stored float4 [I, gu, gv, gw] volume (the central differences in
// float at stencil voxels, 0 elsewhere), trilinearly interpolated in double corner by corner.
// The frame forms the differences where it samples; its samples must equal the stored
// volume's bit for bit, on a random image in a ball-shaped field of view (edge cells too),
// for a frame holding a copy of the image and for one that borrows the image's voxels.
TEST(Frame, SamplesEqualThoseOfAStoredGradientVolume) {
  const ImageGeometry g = ObliqueAnisotropicGeometry();
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  Image image(g);
  for (float& v : image.voxels) v = static_cast<float>(300.0 * u(rng) - 50.0);
  Mask mask(g, 0);
  const Eigen::Vector3d center(5.5, 4.5, 4.0);
  for (int k = 0; k < g.size[2]; ++k)
    for (int j = 0; j < g.size[1]; ++j)
      for (int i = 0; i < g.size[0]; ++i)
        mask.at(i, j, k) = (Eigen::Vector3d(i, j, k) - center).norm() <= 4.2 ? 1 : 0;
  const int64_t sx = 1, sy = g.size[0], sz = sy * g.size[1];
  std::vector<float> stored(4 * static_cast<size_t>(g.NumVoxels()), 0.0f);
  for (int k = 1; k + 1 < g.size[2]; ++k)
    for (int j = 1; j + 1 < g.size[1]; ++j)
      for (int i = 1; i + 1 < g.size[0]; ++i) {
        const int64_t l = g.LinearIndex(i, j, k);
        stored[4 * l] = image.voxels[l];
        const bool stencil = mask.voxels[l] && mask.voxels[l - sx] && mask.voxels[l + sx] &&
                             mask.voxels[l - sy] && mask.voxels[l + sy] &&
                             mask.voxels[l - sz] && mask.voxels[l + sz];
        if (!stencil) continue;
        const float* v = &image.voxels[l];
        stored[4 * l + 1] = 0.5f * (v[sx] - v[-sx]);
        stored[4 * l + 2] = 0.5f * (v[sy] - v[-sy]);
        stored[4 * l + 3] = 0.5f * (v[sz] - v[-sz]);
      }
  const Frame copied(image, mask);
  const Frame borrowed = Frame::Borrowing(image, {}, mask);
  EXPECT_EQ(borrowed.values(), image.voxels.data());  // read in place
  EXPECT_NE(copied.values(), image.voxels.data());
  int valid = 0;
  for (int n = 0; n < 3000; ++n) {
    const Eigen::Vector3d ijk(u(rng) * (g.size[0] - 1.001), u(rng) * (g.size[1] - 1.001),
                              u(rng) * (g.size[2] - 1.001));
    double value;
    Eigen::Vector3d gradient;
    const bool ok = copied.SampleAtIndex(ijk, &value, &gradient);
    double borrowed_value;
    Eigen::Vector3d borrowed_gradient;
    ASSERT_EQ(borrowed.SampleAtIndex(ijk, &borrowed_value, &borrowed_gradient), ok);
    if (!ok) continue;
    ++valid;
    const int i = static_cast<int>(std::floor(ijk[0])), j = static_cast<int>(std::floor(ijk[1])),
              k = static_cast<int>(std::floor(ijk[2]));
    const double fx = ijk[0] - i, fy = ijk[1] - j, fz = ijk[2] - k;
    double twin[4] = {0.0, 0.0, 0.0, 0.0};
    for (int c = 0; c < 8; ++c) {
      const int dx = c & 1, dy = (c >> 1) & 1, dz = (c >> 2) & 1;
      const double w = (dx ? fx : 1.0 - fx) * (dy ? fy : 1.0 - fy) * (dz ? fz : 1.0 - fz);
      const float* corner = &stored[4 * g.LinearIndex(i + dx, j + dy, k + dz)];
      for (int q = 0; q < 4; ++q) twin[q] += w * corner[q];
    }
    EXPECT_EQ(value, twin[0]);
    EXPECT_EQ(borrowed_value, twin[0]);
    for (int a = 0; a < 3; ++a) {
      EXPECT_EQ(gradient[a], twin[1 + a]) << "axis " << a << " at " << ijk.transpose();
      EXPECT_EQ(borrowed_gradient[a], twin[1 + a]);
    }
  }
  EXPECT_GT(valid, 100);
}

// The slopes of a sample's interpolants (the pose uncertainty's curvature): the value and
// gradient are SampleAtIndex's bit for bit, and inside a cell each slope is the derivative of
// its trilinear interpolant, which a central difference along the axis gives exactly (the
// interpolant is linear along each axis inside a cell) up to rounding.
TEST(Frame, SlopesAreTheInterpolantsDerivativesInsideTheCell) {
  ImageGeometry g;
  g.size = Eigen::Vector3i(9, 8, 7);
  Image image(g);
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> noise(0.0f, 200.0f);
  for (float& v : image.voxels) v = noise(rng);
  const Frame frame(image, Mask(g, 1));
  std::uniform_real_distribution<double> fraction(0.1, 0.9);
  constexpr double kStep = 0.05;  // stays inside the cell: fractions in [0.1, 0.9]
  for (int trial = 0; trial < 50; ++trial) {
    const Eigen::Vector3d u(2 + trial % 4 + fraction(rng), 2 + trial % 3 + fraction(rng),
                            2 + trial % 2 + fraction(rng));
    double value = 0.0, reference = 0.0;
    Eigen::Vector3d gradient, reference_gradient, value_slope;
    Eigen::Matrix3d gradient_slope;
    ASSERT_TRUE(frame.SampleSlopesAtIndex(u, &value, &gradient, &value_slope, &gradient_slope));
    ASSERT_TRUE(frame.SampleAtIndex(u, &reference, &reference_gradient));
    EXPECT_EQ(value, reference);
    EXPECT_TRUE(gradient == reference_gradient);
    for (int a = 0; a < 3; ++a) {
      const Eigen::Vector3d step = kStep * Eigen::Vector3d::Unit(a);
      double plus = 0.0, minus = 0.0;
      Eigen::Vector3d gradient_plus, gradient_minus;
      ASSERT_TRUE(frame.SampleAtIndex(u + step, &plus, &gradient_plus));
      ASSERT_TRUE(frame.SampleAtIndex(u - step, &minus, &gradient_minus));
      EXPECT_NEAR(value_slope[a], (plus - minus) / (2 * kStep), 1e-9) << "axis " << a;
      const Eigen::Vector3d difference = (gradient_plus - gradient_minus) / (2 * kStep);
      for (int q = 0; q < 3; ++q) {
        EXPECT_NEAR(gradient_slope(q, a), difference[q], 1e-9) << "gradient " << q << " axis " << a;
      }
    }
  }
  // Invalid cells: false, like SampleAtIndex.
  double value = 0.0;
  Eigen::Vector3d gradient, value_slope;
  Eigen::Matrix3d gradient_slope;
  EXPECT_FALSE(frame.SampleSlopesAtIndex(Eigen::Vector3d(0.5, 3.5, 3.5), &value, &gradient,
                                         &value_slope, &gradient_slope));
}

TEST(Frame, DilatedValidCellsGrowByTheMargin) {
  ImageGeometry g;
  g.size = Eigen::Vector3i(10, 10, 10);
  Mask mask(g, 0);
  // A 4^3 block: its inner 2^3 voxels have all 6 neighbours inside, one valid cell.
  for (int k = 3; k <= 6; ++k)
    for (int j = 3; j <= 6; ++j)
      for (int i = 3; i <= 6; ++i) mask.at(i, j, k) = 1;
  const Frame frame(Image(g, 1.0f), mask);
  EXPECT_EQ(frame.num_valid_cells(), 1);
  const std::vector<uint8_t> dilated = frame.DilatedValidCells(2);
  int count = 0;
  for (uint8_t d : dilated) count += d;
  EXPECT_EQ(count, 5 * 5 * 5);
  EXPECT_EQ(dilated[g.LinearIndex(2, 6, 4)], 1);
  EXPECT_EQ(dilated[g.LinearIndex(1, 4, 4)], 0);
}

TEST(MaskFromNonZero, ErodesByTheGivenNumberOfVoxels) {
  ImageGeometry g;
  g.size = Eigen::Vector3i(12, 12, 12);
  Image image(g, 0.0f);
  for (int k = 2; k < 10; ++k)
    for (int j = 2; j < 10; ++j)
      for (int i = 2; i < 10; ++i) image.at(i, j, k) = 5.0f;
  EXPECT_EQ(CountInside(MaskFromNonZero(image, 0)), 8 * 8 * 8);
  EXPECT_EQ(CountInside(MaskFromNonZero(image, 2)), 4 * 4 * 4);
  // The image border counts as outside.
  const Mask full = MaskFromNonZero(Image(g, 1.0f), 1);
  EXPECT_EQ(CountInside(full), 10 * 10 * 10);
}

// Zeros enclosed by data (noise clamped at 0, dark anatomy) are inside the field of view;
// zeros connected to the outside are not.
TEST(MaskFromNonZero, KeepsEnclosedZerosInside) {
  ImageGeometry g;
  g.size = Eigen::Vector3i(12, 12, 12);
  Image image(g, 0.0f);
  for (int k = 2; k < 10; ++k)
    for (int j = 2; j < 10; ++j)
      for (int i = 2; i < 10; ++i) image.at(i, j, k) = 5.0f;
  image.at(5, 5, 5) = 0.0f;  // enclosed: inside
  image.at(4, 6, 7) = 0.0f;
  for (int i = 2; i < 5; ++i) image.at(i, 3, 3) = 0.0f;  // a channel from the outside: outside
  const Mask mask = MaskFromNonZero(image, 0);
  EXPECT_EQ(mask.at(5, 5, 5), 1);
  EXPECT_EQ(mask.at(4, 6, 7), 1);
  EXPECT_EQ(mask.at(4, 3, 3), 0);
  EXPECT_EQ(CountInside(mask), 8 * 8 * 8 - 3);
  // Eroded, an enclosed zero removes nothing around it.
  EXPECT_EQ(MaskFromNonZero(image, 1).at(5, 5, 6), 1);
}

TEST(ObserveSample, JacobianMatchesNumericDerivativeOnLinearField) {
  const ImageGeometry g = ObliqueAnisotropicGeometry();
  const Eigen::Vector3d slope(0.8, -1.1, 2.0);
  const Frame frame(LinearImage(g, slope, 50.0), Mask(g, 1));
  Vector6d d;
  d << 0.3, -0.2, 0.1, 0.02, -0.01, 0.03;
  const Eigen::Isometry3d frame_from_world = ExpSE3(d);
  const Eigen::Vector3d p_world =
      frame_from_world.inverse() * g.IndexToPhysical(Eigen::Vector3d(5.2, 4.4, 3.7));
  double value;
  RowVector6d jacobian;
  ASSERT_TRUE(ObserveSample(frame, frame_from_world, p_world, &value, &jacobian));
  RowVector6d numeric;
  const double h = 1e-4;
  for (int a = 0; a < 6; ++a) {
    Vector6d e = Vector6d::Zero();
    e[a] = h;
    double plus, minus;
    ASSERT_TRUE(ObserveSample(frame, ExpSE3(e) * frame_from_world, p_world, &plus, nullptr));
    ASSERT_TRUE(ObserveSample(frame, ExpSE3(-e) * frame_from_world, p_world, &minus, nullptr));
    numeric[a] = (plus - minus) / (2 * h);
  }
  // Float voxels: numeric differences carry ~2e-5 / 1e-4 rounding.
  EXPECT_LT((numeric - jacobian).norm(), 2e-2 * std::max(1.0, jacobian.norm()))
      << numeric << "\n" << jacobian;
}

}  // namespace
}  // namespace dsr
