// The variance-stabilising intensity transform (model/intensity_transform.h).
#include "dsr/model/intensity_transform.h"

#include <gtest/gtest.h>

#include "dsr/tests/support/enum_names.h"

namespace dsr {
namespace {

// Two 3x2x1 frames; frame 1's mask leaves out its last voxel.
void TwoFrames(std::vector<Image>* images, std::vector<Mask>* masks) {
  ImageGeometry g;
  g.size = Eigen::Vector3i(3, 2, 1);
  images->assign(2, Image(g));
  masks->assign(2, Mask(g, 1));
  (*images)[0].voxels = {0.0f, 4.0f, 16.0f, 64.0f, 100.0f, 25.0f};
  (*images)[1].voxels = {1.0f, 9.0f, 36.0f, 49.0f, 81.0f, 400.0f};
  (*masks)[1].voxels[5] = 0;
}

TEST(IntensityTransform, NamesRoundTrip) {
  testing_enums::ExpectNamesRoundTrip({IntensityTransform::kNone, IntensityTransform::kSqrt},
                                      IntensityTransformToString, StringToIntensityTransform,
                                      {"log", "SQRT"});
}

// c is the largest intensity inside any mask (frame 1's 400 is outside its mask), and
// T maps [0, c] onto itself.
TEST(IntensityTransform, SqrtOfTheScaledIntensities) {
  std::vector<Image> images;
  std::vector<Mask> masks;
  TwoFrames(&images, &masks);
  const double c = IntensityTransformScale(images, masks);
  EXPECT_EQ(c, 100.0);
  std::vector<Image> out;
  std::string error;
  ASSERT_TRUE(ApplyIntensityTransform(images, masks, IntensityTransform::kSqrt, c, &out, &error))
      << error;
  ASSERT_EQ(out.size(), 2u);
  const std::vector<float> expected0 = {0.0f, 20.0f, 40.0f, 80.0f, 100.0f, 50.0f};
  const std::vector<float> expected1 = {10.0f, 30.0f, 60.0f, 70.0f, 90.0f, 200.0f};
  for (size_t l = 0; l < 6; ++l) {
    EXPECT_FLOAT_EQ(out[0].voxels[l], expected0[l]) << l;
    EXPECT_FLOAT_EQ(out[1].voxels[l], expected1[l]) << l;
    EXPECT_NEAR(InverseIntensity(out[0].voxels[l], c), images[0].voxels[l], 1e-4) << l;
  }
  EXPECT_EQ(out[1].geometry.size, images[1].geometry.size);
  // A gain stays a gain: T(a I) = sqrt(a) T(I).
  EXPECT_NEAR(ForwardIntensity(2.0 * 30.0, c), std::sqrt(2.0) * ForwardIntensity(30.0, c), 1e-12);
  // kNone copies.
  ASSERT_TRUE(ApplyIntensityTransform(images, masks, IntensityTransform::kNone, c, &out, &error));
  EXPECT_EQ(out[1].voxels, images[1].voxels);
}

// The start of the gains on the input's scale: exact for a pure gain, and for a gain and
// an offset the tangent of T^-1(g T(I) + b) at the frame's mean intensity.
TEST(IntensityTransform, GainAndOffsetOnTheInputsScaleMatchAtTheMean) {
  const double c = 255.0, mean = 90.0;
  double gain = 0.0, offset = 0.0;
  GainAndOffsetOnInputScale(1.1, 0.0, mean, c, &gain, &offset);
  EXPECT_DOUBLE_EQ(gain, 1.21);
  EXPECT_EQ(offset, 0.0);
  const double g = 0.93, b = 4.0;
  GainAndOffsetOnInputScale(g, b, mean, c, &gain, &offset);
  const auto mapped = [&](double v) { return InverseIntensity(g * ForwardIntensity(v, c) + b, c); };
  EXPECT_NEAR(gain * mean + offset, mapped(mean), 1e-9);
  const double h = 1e-3;
  EXPECT_NEAR(gain, (mapped(mean + h) - mapped(mean - h)) / (2.0 * h), 1e-6);
  // Away from the mean only to first order.
  EXPECT_GT(std::abs(gain * 200.0 + offset - mapped(200.0)), 1e-3);
}

// A negative intensity inside a mask is refused, naming the frame, the voxel and the field;
// one outside every mask is never observed and becomes 0.
TEST(IntensityTransform, RefusesNegativeIntensitiesInsideTheMask) {
  std::vector<Image> images;
  std::vector<Mask> masks;
  TwoFrames(&images, &masks);
  images[1].voxels[5] = -3.0f;  // outside frame 1's mask
  std::vector<Image> out;
  std::string error;
  ASSERT_TRUE(
      ApplyIntensityTransform(images, masks, IntensityTransform::kSqrt, 100.0, &out, &error));
  EXPECT_EQ(out[1].voxels[5], 0.0f);
  images[1].voxels[4] = -0.5f;  // voxel (1,1,0), inside
  EXPECT_FALSE(
      ApplyIntensityTransform(images, masks, IntensityTransform::kSqrt, 100.0, &out, &error));
  EXPECT_EQ(error,
            "frame 1 has a negative intensity (-0.5) at voxel (1,1,0) inside its mask: "
            "intensity_transform=sqrt needs intensities >= 0");
}

}  // namespace
}  // namespace dsr
