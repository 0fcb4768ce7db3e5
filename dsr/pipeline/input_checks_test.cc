// Checks of a registration's inputs (pipeline/input_checks.h): intensities at any scale
// give the same poses (the solver's tolerances see normalised intensities), and inputs that
// would fail later under another name are refused naming what is wrong.
#include <cmath>

#include <gtest/gtest.h>

#include "dsr/eval/eval.h"
#include "dsr/geometry/se3.h"
#include "dsr/pipeline/input_checks.h"
#include "dsr/pipeline/registration.h"
#include "dsr/sim/phantom.h"
#include "dsr/sim/simulate.h"

namespace dsr {
namespace {

SimulatedSequence SmallSequence() {
  PhantomOptions phantom;
  phantom.size = 96;
  SimulationOptions o;
  o.num_frames = 4;
  o.frame_size = Eigen::Vector3i(40, 40, 32);
  o.sigma = 10.0;
  o.max_translation_voxels = 4.0;
  o.max_rotation_deg = 6.0;
  o.min_depth_voxels = 2.0;
  o.mask_erosion = 0;
  o.seed = 5;
  SimulatedSequence s;
  std::string error;
  EXPECT_TRUE(Simulate(MakePhantom(phantom), o, &s, &error)) << error;
  return s;
}

RegistrationOptions SmallOptions() {
  RegistrationOptions o;
  o.solve.progress = false;
  o.solve.num_threads = 2;
  o.pyramid_levels = 2;
  o.pyramid_min_size = 8;
  return o;
}

TEST(IntensityScale, ExponentIsZeroInsideTheBandAndNormalisesOutside) {
  EXPECT_EQ(IntensityScaleExponent(0.0), 0);
  EXPECT_EQ(IntensityScaleExponent(std::nan("")), 0);
  EXPECT_EQ(IntensityScaleExponent(kMinIntensitySpread), 0);
  EXPECT_EQ(IntensityScaleExponent(30.0), 0);
  EXPECT_EQ(IntensityScaleExponent(kMaxIntensitySpread), 0);
  for (double spread : {1e-12, 3e-5, 1e5, 1e12, 1e30}) {
    const int e = IntensityScaleExponent(spread);
    const double normalised = std::ldexp(spread, e);
    EXPECT_GT(normalised, kTargetIntensitySpread / std::sqrt(2.0) - 1e-9) << spread;
    EXPECT_LT(normalised, kTargetIntensitySpread * std::sqrt(2.0) + 1e-9) << spread;
  }
}

TEST(IntensityScale, SpreadIsTheMedianAbsoluteDeviation) {
  ImageGeometry g;
  g.size = Eigen::Vector3i(10, 10, 10);
  Image image(g, 0.0f);
  Mask mask(g, 1);
  for (int64_t l = 0; l < g.NumVoxels(); ++l) image.voxels[l] = static_cast<float>(l % 10);
  // Values 0..9 equally often: median 5, absolute deviations 5,4,3,2,1,0,1,2,3,4 -> median 3.
  EXPECT_DOUBLE_EQ(IntensitySpread({image}, {mask}), 3.0);
  // Mostly one value (a dark field of view): the mean absolute deviation instead.
  Image dark(g, 0.0f);
  dark.voxels[0] = 1000.0f;
  EXPECT_NEAR(IntensitySpread({dark}, {mask}), 1.0, 1e-9);
  // Outside the mask does not count.
  Mask none(g, 0);
  EXPECT_EQ(IntensitySpread({image}, {none}), 0.0);
}

// The same sequence at 1, 1e-12 and 1e12 times its intensities: the same poses (up to the
// rounding of the scaled floats), and costs in the input's units.
TEST(IntensityScale, PosesDoNotDependOnTheIntensityUnit) {
  const SimulatedSequence s = SmallSequence();
  const std::vector<Eigen::Isometry3d> identity(s.frames.size(), Eigen::Isometry3d::Identity());
  const RegistrationOptions o = SmallOptions();
  RegistrationResult reference;
  std::string error;
  ASSERT_TRUE(Register(s.frames, s.masks, identity, o, &reference, &error)) << error;
  ASSERT_TRUE(reference.usable) << reference.failure;
  EXPECT_LT(ComparePoses(reference.frame_from_world, s.frame_from_world, s.masks).tre_mean_mm, 0.1);
  for (double scale : {1e-12, 1e12}) {
    std::vector<Image> frames = s.frames;
    for (Image& f : frames) {
      for (float& v : f.voxels) v = static_cast<float>(v * scale);
    }
    RegistrationResult scaled;
    ASSERT_TRUE(Register(frames, s.masks, identity, o, &scaled, &error)) << error;
    ASSERT_TRUE(scaled.usable) << scale << ": " << scaled.failure;
    EXPECT_GT(scaled.total_iterations, 0) << scale;
    for (size_t f = 1; f < s.frames.size(); ++f) {
      const Eigen::Isometry3d d =
          scaled.frame_from_world[f] * reference.frame_from_world[f].inverse();
      EXPECT_LT(LogSE3(d).norm(), 1e-4) << "scale " << scale << ", frame " << f;
    }
    const double ratio = scaled.solves.back().report.final_cost /
                         reference.solves.back().report.final_cost;
    EXPECT_NEAR(std::log10(ratio), 2.0 * std::log10(scale), 0.01) << scale;
    ASSERT_EQ(scaled.frame_misfits.size(), reference.frame_misfits.size());
    EXPECT_NEAR(scaled.frame_misfits[1] / reference.frame_misfits[1], scale, 1e-3 * scale);
  }
}

TEST(CheckRegistrationInputs, NamesWhatIsWrong) {
  const SimulatedSequence s = SmallSequence();
  const std::vector<Eigen::Isometry3d> identity(s.frames.size(), Eigen::Isometry3d::Identity());
  RegistrationOptions o = SmallOptions();
  std::string error;
  EXPECT_TRUE(CheckRegistrationInputs(s.frames, identity, o, &error)) << error;

  // A frame whose header says nanometres.
  std::vector<Image> frames = s.frames;
  frames[2].geometry.spacing_mm *= 1e-9;
  EXPECT_FALSE(CheckRegistrationInputs(frames, identity, o, &error));
  EXPECT_NE(error.find("frame 2 has a voxel spacing"), std::string::npos) << error;
  EXPECT_NE(error.find("finer than frame 0's"), std::string::npos) << error;
  frames[2].geometry.spacing_mm = s.frames[2].geometry.spacing_mm * 1e9;
  EXPECT_FALSE(CheckRegistrationInputs(frames, identity, o, &error));
  EXPECT_NE(error.find("coarser"), std::string::npos) << error;

  // A smoothing that erases the frames.
  o.smoothing = 1e6;
  EXPECT_FALSE(CheckRegistrationInputs(s.frames, identity, o, &error));
  EXPECT_NE(error.find("smoothing=1e+06"), std::string::npos) << error;
  o.smoothing = 1.0;
  EXPECT_TRUE(CheckRegistrationInputs(s.frames, identity, o, &error)) << error;

  // Panorama voxels larger than the frames.
  o.panorama_spacing = 1e300;
  EXPECT_FALSE(CheckRegistrationInputs(s.frames, identity, o, &error));
  EXPECT_NE(error.find("panorama_spacing=1e+300"), std::string::npos) << error;
  o.panorama_spacing = 1.0;

  // An initial translation of 1e300 mm names --init (and does not overflow to a pass).
  std::vector<Eigen::Isometry3d> far = identity;
  far[3].translation() = Eigen::Vector3d(1e300, 1e300, 0.0);
  EXPECT_FALSE(CheckRegistrationInputs(s.frames, far, o, &error));
  EXPECT_NE(error.find("(init) place frame 3"), std::string::npos) << error;
  far[3].translation() = Eigen::Vector3d(500.0, 0.0, 0.0);  // apart, but a sane number
  EXPECT_TRUE(CheckRegistrationInputs(s.frames, far, o, &error)) << error;

  // Without initial poses, one frame whose header puts it 1e9 mm away names that frame and
  // its origin, not the poses; every origin moved alike is no error (local coordinates).
  std::vector<Image> moved = s.frames;
  moved[2].geometry.origin_mm += Eigen::Vector3d(1e9, 0.0, 0.0);
  EXPECT_FALSE(CheckRegistrationInputs(moved, identity, o, &error));
  EXPECT_EQ(error.find("frame 2 lies 1e+09 mm from frame 0"), 0u) << error;
  EXPECT_NE(error.find("origin"), std::string::npos) << error;
  for (Image& image : moved) image.geometry.origin_mm[0] = 1e9;
  EXPECT_TRUE(CheckRegistrationInputs(moved, identity, o, &error)) << error;
}

// One voxel that outweighs the rest of its frame (more than half of its squared deviation
// from the median) is named with its position, value and share; the same frame with the
// voxel's share just under half passes, just over half does not (the shares from a loop of
// the test's own).
TEST(CheckRegistrationInputs, NamesAnOutlierVoxelWithItsShare) {
  const SimulatedSequence s = SmallSequence();
  const std::vector<Eigen::Isometry3d> identity(s.frames.size(), Eigen::Isometry3d::Identity());
  const RegistrationOptions o = SmallOptions();
  std::vector<Image> frames = s.frames;
  Image& frame = frames[1];
  const Eigen::Vector3i& n = frame.geometry.size;
  const size_t at = 3 + 5 * static_cast<size_t>(n[0]) + 2 * static_cast<size_t>(n[0]) * n[1];
  std::vector<float> sample;
  const size_t stride = std::max<size_t>(1, frame.voxels.size() / 100000);
  for (size_t l = 0; l < frame.voxels.size(); l += stride) sample.push_back(frame.voxels[l]);
  std::nth_element(sample.begin(), sample.begin() + sample.size() / 2, sample.end());
  const double median = sample[sample.size() / 2];
  const auto share_with = [&](float value) {
    double sum = 0.0, largest = 0.0;
    for (size_t l = 0; l < frame.voxels.size(); ++l) {
      const double x = l == at ? value : frame.voxels[l];
      sum += (x - median) * (x - median);
      largest = std::max(largest, (x - median) * (x - median));
    }
    return largest / sum;
  };
  frame.voxels[at] = 1e30f;
  ASSERT_GT(share_with(1e30f), 0.99);
  std::string error;
  EXPECT_FALSE(CheckRegistrationInputs(frames, identity, o, &error));
  EXPECT_EQ(error.find("frame 1 has an outlier intensity: its voxel (3,5,2) is 1e+30"), 0u)
      << error;
  // A value whose share is 0.45: no outlier.
  double rest = 0.0;
  for (size_t l = 0; l < frame.voxels.size(); ++l) {
    if (l != at) rest += (frame.voxels[l] - median) * (frame.voxels[l] - median);
  }
  const float moderate = static_cast<float>(median + std::sqrt(0.45 / 0.55 * rest));
  EXPECT_NEAR(share_with(moderate), 0.45, 1e-3);
  frame.voxels[at] = moderate;
  EXPECT_TRUE(CheckRegistrationInputs(frames, identity, o, &error)) << error;
  const float heavy = static_cast<float>(median + std::sqrt(0.55 / 0.45 * rest));
  frame.voxels[at] = heavy;
  EXPECT_FALSE(CheckRegistrationInputs(frames, identity, o, &error));
  EXPECT_NE(error.find("holds 55% of the frame's squared deviation"), std::string::npos)
      << error;
}

// The outlier is found wherever it lies and on either side of the median: below it at the
// frame's last voxel (past the pass's whole groups of 8) and in its first group.
TEST(CheckRegistrationInputs, NamesTheFirstOutlierVoxelWhereverItLies) {
  const SimulatedSequence s = SmallSequence();
  const std::vector<Eigen::Isometry3d> identity(s.frames.size(), Eigen::Isometry3d::Identity());
  const RegistrationOptions o = SmallOptions();
  std::vector<Image> frames = s.frames;
  // Frame 2 cropped to 39x39x31 voxels (47151: 7 past the last whole group of 8).
  ImageGeometry cropped = frames[2].geometry;
  cropped.size = Eigen::Vector3i(39, 39, 31);
  Image frame(cropped, 0.0f);
  for (int k = 0; k < 31; ++k) {
    for (int j = 0; j < 39; ++j) {
      for (int i = 0; i < 39; ++i) frame.at(i, j, k) = frames[2].at(i, j, k);
    }
  }
  const Eigen::Vector3i& n = frame.geometry.size;
  ASSERT_EQ(frame.voxels.size() % 8, 7u);
  frame.voxels.back() = -1e30f;
  frames[2] = frame;
  std::string error;
  EXPECT_FALSE(CheckRegistrationInputs(frames, identity, o, &error));
  const std::string last = "(" + std::to_string(n[0] - 1) + "," + std::to_string(n[1] - 1) +
                           "," + std::to_string(n[2] - 1) + ")";
  EXPECT_EQ(error.find("frame 2 has an outlier intensity: its voxel " + last + " is -1e+30"), 0u)
      << error;
  frames[2].voxels.back() = frames[2].voxels[0];
  frames[2].voxels[7] = -1e30f;
  EXPECT_FALSE(CheckRegistrationInputs(frames, identity, o, &error));
  EXPECT_EQ(error.find("frame 2 has an outlier intensity: its voxel (7,0,0) is -1e+30"), 0u)
      << error;
}

}  // namespace
}  // namespace dsr
