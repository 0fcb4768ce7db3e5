// Simulator (DESIGN.md section 6): consistency of frames with their ground-truth poses,
// determinism, noise statistics, field of view.
#include "sim/simulate.h"

#include <cmath>

#include <gtest/gtest.h>

#include "core/frame.h"
#include "sim/phantom.h"

namespace dsr {
namespace {

SimulationOptions Small() {
  SimulationOptions o;
  o.num_frames = 3;
  o.frame_size = Eigen::Vector3i(28, 28, 24);
  o.max_rotation_deg = 6.0;
  o.max_translation_voxels = 4.0;
  o.noise_sigma = 0.0;
  o.azimuth_deg = 80.0;
  o.elevation_deg = 80.0;
  return o;
}

TEST(Phantom, DeterministicTexturedAndInRange) {
  PhantomOptions p;
  p.size = 48;
  const Image a = MakePhantom(p), b = MakePhantom(p);
  EXPECT_EQ(a.voxels, b.voxels);
  p.seed = 2;
  EXPECT_NE(MakePhantom(p).voxels, a.voxels);
  int64_t textured = 0;
  for (int k = 1; k < 47; ++k)
    for (int j = 1; j < 47; ++j)
      for (int i = 1; i < 47; ++i) {
        EXPECT_GE(a.at(i, j, k), 0.0f);
        EXPECT_LE(a.at(i, j, k), 255.0f);
        textured += std::abs(a.at(i + 1, j, k) - a.at(i - 1, j, k)) > 4.0f;
      }
  EXPECT_GT(textured, 46 * 46 * 46 / 4);  // not piecewise flat
}

// Resampling frame j into frame i with the true poses reproduces frame i: the two are
// trilinear samples of one source, so they differ only by interpolation error of the
// speckle texture (measured ~2.6 intensity units on average; texture amplitude is ~20,
// so a pose off by a voxel would give several times more).
constexpr double kResampleMeanAbsTolerance = 4.0;

TEST(Simulate, FramesAgreeUnderGroundTruthPoses) {
  for (double spacing : {1.0, 0.8}) {
    PhantomOptions p;
    p.size = 80;
    p.spacing_mm = spacing;
    const Image source = MakePhantom(p);
    SimulatedSequence s;
    std::string error;
    ASSERT_TRUE(Simulate(source, Small(), &s, &error)) << error;
    ASSERT_EQ(s.frames.size(), 3u);
    const Frame frame_j(s.frames[1], s.masks[1]);
    const Eigen::Isometry3d j_from_i = s.frame_from_world[1] * s.frame_from_world[0].inverse();
    double sum = 0.0;
    int64_t count = 0;
    const ImageGeometry& g = s.frames[0].geometry;
    for (int k = 0; k < g.size[2]; ++k)
      for (int jj = 0; jj < g.size[1]; ++jj)
        for (int i = 0; i < g.size[0]; ++i) {
          if (!s.masks[0].at(i, jj, k)) continue;
          double value;
          if (!frame_j.Sample(j_from_i * g.IndexToPhysical(Eigen::Vector3d(i, jj, k)), &value, nullptr)) continue;
          sum += std::abs(value - s.frames[0].at(i, jj, k));
          ++count;
        }
    ASSERT_GT(count, 1000);
    EXPECT_LT(sum / count, kResampleMeanAbsTolerance) << "spacing " << spacing;
  }
}

TEST(Simulate, DeterministicForASeed) {
  PhantomOptions p;
  p.size = 80;
  const Image source = MakePhantom(p);
  SimulationOptions o = Small();
  o.noise_sigma = 25.0;
  SimulatedSequence a, b;
  std::string error;
  ASSERT_TRUE(Simulate(source, o, &a, &error));
  ASSERT_TRUE(Simulate(source, o, &b, &error));
  EXPECT_EQ(a.frames[2].voxels, b.frames[2].voxels);
  EXPECT_TRUE(a.frame_from_world[2].isApprox(b.frame_from_world[2]));
}

TEST(Simulate, NoiseHasTheRequestedStandardDeviation) {
  ImageGeometry g;
  g.size = Eigen::Vector3i(80, 80, 80);
  const Image flat(g, 128.0f);
  SimulationOptions o = Small();
  o.noise_sigma = 25.0;
  SimulatedSequence s;
  std::string error;
  ASSERT_TRUE(Simulate(flat, o, &s, &error)) << error;
  const Mask fov = PyramidFieldOfView(s.frames[0].geometry, o);
  double sum = 0.0, sum2 = 0.0;
  int64_t n = 0;
  for (size_t v = 0; v < fov.voxels.size(); ++v) {
    if (!fov.voxels[v]) {
      EXPECT_EQ(s.frames[0].voxels[v], 0.0f);
      continue;
    }
    sum += s.frames[0].voxels[v];
    sum2 += double{s.frames[0].voxels[v]} * s.frames[0].voxels[v];
    ++n;
  }
  const double mean = sum / n, sd = std::sqrt(sum2 / n - mean * mean);
  EXPECT_NEAR(mean, 128.0, 1.0);
  EXPECT_NEAR(sd, 25.0, 1.0);  // clamping at 0/255 is > 5 sigma away
}

TEST(Simulate, FieldOfViewIsAPyramidAndMaskIsInside) {
  SimulationOptions o = Small();
  ImageGeometry g;
  g.size = o.frame_size;
  const Mask fov = PyramidFieldOfView(g, o);
  for (int j = 0; j < g.size[1]; ++j)
    for (int i = 0; i < g.size[0]; ++i) EXPECT_EQ(fov.at(i, j, 0), 0);  // apex row empty
  EXPECT_EQ(fov.at(g.size[0] / 2, g.size[1] / 2, g.size[2] - 1), 1);
  EXPECT_EQ(fov.at(0, 0, 6), 0);
  PhantomOptions p;
  p.size = 80;
  SimulatedSequence s;
  std::string error;
  ASSERT_TRUE(Simulate(MakePhantom(p), o, &s, &error));
  for (size_t v = 0; v < fov.voxels.size(); ++v) {
    if (s.masks[0].voxels[v]) EXPECT_EQ(fov.voxels[v], 1);
  }
  EXPECT_LT(CountInside(s.masks[0]), CountInside(fov));
}

TEST(Simulate, RejectsNonsenseOptions) {
  std::string error;
  SimulationOptions o;
  o.num_frames = 1;
  EXPECT_FALSE(o.Validate(&error));
  EXPECT_NE(error.find("--num_frames"), std::string::npos);
  o = SimulationOptions();
  o.noise_sigma = -1.0;
  EXPECT_FALSE(o.Validate(&error));
  EXPECT_NE(error.find("--sigma"), std::string::npos);
  o = SimulationOptions();
  ImageGeometry g;
  g.size = Eigen::Vector3i(20, 20, 20);
  SimulatedSequence s;
  EXPECT_FALSE(Simulate(Image(g, 1.0f), o, &s, &error));  // source far too small
  EXPECT_NE(error.find("outside the source"), std::string::npos) << error;
}

}  // namespace
}  // namespace dsr
