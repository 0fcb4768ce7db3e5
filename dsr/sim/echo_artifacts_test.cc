// The simulator's real-echo artefacts (sim/echo_artifacts.h, docs/design.md 6.7): each
// effect on frames built to show it, against the value its formula gives; dropouts in whole
// sequences (only noise in the wedge, every other voxel and draw unchanged, the share of
// views with a wedge); off by default; the options' validation.
#include <cmath>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "dsr/sim/echo_artifacts.h"
#include "dsr/sim/phantom.h"
#include "dsr/sim/simulate.h"

namespace dsr {
namespace {

// A 33x33x40 frame of 1 mm voxels (the apex at index (16, 16, 0)).
ImageGeometry BoxGeometry() {
  ImageGeometry g;
  g.size = Eigen::Vector3i(33, 33, 40);
  return g;
}

// 4 frames of 40^3 from an 80^3 phantom, noise sigma 10.
SimulationOptions SmallOptions() {
  SimulationOptions o;
  o.num_frames = 4;
  o.frame_size = Eigen::Vector3i(40, 40, 40);
  o.max_rotation_deg = 6.0;
  o.max_translation_voxels = 3.0;
  o.sigma = 10.0;
  o.min_depth_voxels = 2.0;
  return o;
}

Image SmallPhantom() {
  PhantomOptions p;
  p.size = 80;
  return MakePhantom(p);
}

TEST(EchoArtifacts, OffByDefaultAndTheirOtherSettingsChangeNothing) {
  const SimulationOptions defaults;
  EXPECT_EQ(defaults.echogenicity_range, 0.0);
  EXPECT_EQ(defaults.shadow_strength, 0.0);
  EXPECT_EQ(defaults.psf_lateral_mm, 0.0);
  EXPECT_EQ(defaults.dropout_fraction, 0.0);
  EXPECT_FALSE(HasBeamArtifacts(defaults));
  const Image source = SmallPhantom();
  SimulationOptions o = SmallOptions();
  SimulatedSequence plain, other;
  std::string error;
  ASSERT_TRUE(Simulate(source, o, &plain, &error)) << error;
  o.shadow_threshold = 50.0;  // unused without a shadow strength
  o.dropout_view_fraction = 1.0;  // unused without a dropout fraction
  ASSERT_TRUE(Simulate(source, o, &other, &error)) << error;
  for (int f = 0; f < o.num_frames; ++f) EXPECT_EQ(plain.frames[f].voxels, other.frames[f].voxels);
}

// 100 everywhere, a bright slab (255) in slices 10 and 11 for i in [12, 20]: with strength
// 0.5 and threshold 200 each slab voxel passes half the beam. Up to slice 10 nothing
// changes; the central beam (i = j = 16, its points on the voxels) carries 0.5 into slice 11
// and 0.25 beyond; a beam that passes beside the slab is not shadowed.
TEST(EchoArtifacts, ShadowsDarkenOnlyWhatLiesBehindABrightReflector) {
  const ImageGeometry g = BoxGeometry();
  const Mask fov(g, 1);
  Image frame(g, 100.0f);
  for (int k = 10; k <= 11; ++k) {
    for (int j = 0; j < 33; ++j) {
      for (int i = 12; i <= 20; ++i) frame.at(i, j, k) = 255.0f;
    }
  }
  const Image before = frame;
  ApplyShadows(fov, 0.5, 200.0, &frame);
  for (int k = 0; k <= 10; ++k) {
    for (int i = 0; i < 33; ++i) {
      EXPECT_EQ(frame.at(i, 16, k), before.at(i, 16, k)) << i << "," << k;
    }
  }
  EXPECT_FLOAT_EQ(frame.at(16, 16, 11), 255.0f * 0.5f);
  for (int k = 12; k < 40; ++k) EXPECT_FLOAT_EQ(frame.at(16, 16, k), 25.0f) << k;
  // At depth 20 the beam through i = 0 was at i = 8 in slices 10 and 11: beside the slab.
  EXPECT_FLOAT_EQ(frame.at(0, 16, 20), 100.0f);
}

// An interface across the central beam (50 below slice 20, 150 from it) brightens by the
// range there; one along it (50 for i < 16, 150 from 16) darkens by as much; flat voxels
// keep their value.
TEST(EchoArtifacts, EchogenicityBrightensInterfacesAcrossTheBeamAndDarkensThoseAlongIt) {
  const ImageGeometry g = BoxGeometry();
  const Mask fov(g, 1);
  const double e = 0.25;
  Image across(g, 50.0f), along(g, 50.0f);
  for (int k = 0; k < 40; ++k) {
    for (int j = 0; j < 33; ++j) {
      for (int i = 0; i < 33; ++i) {
        if (k >= 20) across.at(i, j, k) = 150.0f;
        if (i >= 16) along.at(i, j, k) = 150.0f;
      }
    }
  }
  ApplyEchogenicity(fov, e, &across);
  ApplyEchogenicity(fov, e, &along);
  EXPECT_FLOAT_EQ(across.at(16, 16, 19), static_cast<float>(50.0 * (1.0 + e)));
  EXPECT_FLOAT_EQ(across.at(16, 16, 20), static_cast<float>(150.0 * (1.0 + e)));
  // At (15, 16, 30) the beam runs along (-1, 0, 30): cos(phi) = 1 / sqrt(901).
  EXPECT_FLOAT_EQ(along.at(15, 16, 30), static_cast<float>(50.0 * (1.0 + e * (2.0 / 901 - 1.0))));
  EXPECT_FLOAT_EQ(along.at(16, 16, 30), static_cast<float>(150.0 * (1.0 - e)));
  EXPECT_FLOAT_EQ(across.at(16, 16, 5), 50.0f);
  EXPECT_FLOAT_EQ(along.at(5, 16, 30), 50.0f);
  // Off the central beam the angle shrinks the change: between the two extremes.
  EXPECT_LT(across.at(30, 16, 20), across.at(16, 16, 20));
  EXPECT_GT(across.at(30, 16, 20), 150.0f);
}

// A line along j (255 at i = 16) spreads across i with the variance sigma(k)^2, sigma(k) =
// psf k / (n_k - 1): none at the apex, psf^2 at full depth, a quarter of it half way; the
// line's total is kept. A frame that varies with depth only is left as it is.
TEST(EchoArtifacts, LateralBlurWidensWithDepthAndLeavesDepthAlone) {
  const ImageGeometry g = BoxGeometry();
  const Mask fov(g, 1);
  Image line(g, 0.0f);
  for (int k = 0; k < 40; ++k) {
    for (int j = 0; j < 33; ++j) line.at(16, j, k) = 255.0f;
  }
  const double psf = 2.0;
  ApplyLateralBlur(fov, psf, &line);
  const auto moments = [&](int k, double* total, double* variance) {
    double sum = 0.0, second = 0.0;
    for (int i = 0; i < 33; ++i) {
      sum += line.at(i, 16, k);
      second += line.at(i, 16, k) * (i - 16.0) * (i - 16.0);
    }
    *total = sum;
    *variance = second / sum;
  };
  double total = 0.0, variance = 0.0;
  moments(0, &total, &variance);
  EXPECT_EQ(variance, 0.0);
  for (const int k : {13, 26, 39}) {
    moments(k, &total, &variance);
    const double sigma = psf * k / 39.0;
    EXPECT_NEAR(total, 255.0, 1e-3) << k;
    EXPECT_NEAR(variance, sigma * sigma, 0.02 * sigma * sigma + 1e-3) << k;
  }
  Image depth(g, 0.0f);
  for (size_t l = 0; l < depth.voxels.size(); ++l) {
    depth.voxels[l] = static_cast<float>(l / (33 * 33));  // its slice k
  }
  const Image before = depth;
  ApplyLateralBlur(fov, psf, &depth);
  for (size_t l = 0; l < depth.voxels.size(); ++l) {
    ASSERT_NEAR(depth.voxels[l], before.voxels[l], 1e-4) << l;
  }
}

// With every view given a wedge of 20-40 % of the azimuth: each wedge's voxels hold only
// noise (mean sigma / sqrt(2 pi) for noise clamped at 0), every voxel outside the wedges is
// the one the sequence without dropouts has (the noise draws are the same), and the wedge's
// width lies in its range. Later phases keep their view's wedge.
TEST(EchoArtifacts, DropoutWedgesHoldOnlyNoiseAndLeaveEveryOtherVoxelAlone) {
  const Image source = SmallPhantom();
  SimulationOptions o = SmallOptions();
  SimulatedSequence plain, dropped;
  std::string error;
  ASSERT_TRUE(Simulate(source, o, &plain, &error)) << error;
  o.dropout_fraction = 0.4;
  o.dropout_view_fraction = 1.0;
  ASSERT_TRUE(Simulate(source, o, &dropped, &error)) << error;
  const ImageGeometry& g = plain.frames[0].geometry;
  const Mask fov = PyramidFieldOfView(g, o);
  for (int f = 0; f < o.num_frames; ++f) {
    SCOPED_TRACE(f);
    const auto angle = [&](int i, int k) { return std::atan((i - 0.5 * (g.size[0] - 1)) / k); };
    double lo = 10.0, hi = -10.0;  // the changed voxels' azimuth angles
    for (int k = 1; k < g.size[2]; ++k) {
      for (int j = 0; j < g.size[1]; ++j) {
        for (int i = 0; i < g.size[0]; ++i) {
          if (plain.frames[f].at(i, j, k) == dropped.frames[f].at(i, j, k)) continue;
          lo = std::min(lo, angle(i, k));
          hi = std::max(hi, angle(i, k));
        }
      }
    }
    // Every field-of-view voxel inside that range is noise; every one outside is unchanged.
    double sum = 0.0;
    int64_t count = 0;
    for (int k = 1; k < g.size[2]; ++k) {
      for (int j = 0; j < g.size[1]; ++j) {
        for (int i = 0; i < g.size[0]; ++i) {
          if (!fov.at(i, j, k)) continue;
          if (angle(i, k) < lo || angle(i, k) > hi) {
            ASSERT_EQ(plain.frames[f].at(i, j, k), dropped.frames[f].at(i, j, k));
            continue;
          }
          sum += dropped.frames[f].at(i, j, k);
          ++count;
        }
      }
    }
    ASSERT_GT(count, 1000);
    EXPECT_NEAR(sum / count, o.sigma / std::sqrt(2.0 * M_PI), 0.3);
    const double opening = o.azimuth_deg * M_PI / 180.0;
    EXPECT_GT(hi - lo, 0.2 * opening * 0.9);
    EXPECT_LT(hi - lo, 0.4 * opening);
  }
}

// Each view has a wedge with the chance dropout_view_fraction (its own stream per view).
TEST(EchoArtifacts, AboutTheGivenShareOfViewsHasADropout) {
  const ImageGeometry g = BoxGeometry();
  SimulationOptions o;
  o.frame_size = g.size;
  o.dropout_fraction = 0.3;
  const Mask fov = PyramidFieldOfView(g, o);
  int with = 0;
  constexpr int kViews = 400;
  for (int v = 0; v < kViews; ++v) {
    with += DropoutWedge(g, fov, o, 1000003u * v + 17u).empty() ? 0 : 1;
  }
  // Binomial(400, 0.33): standard deviation 9.4.
  EXPECT_NEAR(with, 0.33 * kViews, 40);
  o.dropout_view_fraction = 0.0;
  EXPECT_TRUE(DropoutWedge(g, fov, o, 5u).empty());
}

TEST(EchoArtifacts, ValidationNamesTheField) {
  const auto refused = [](SimulationOptions o) {
    std::string error;
    EXPECT_FALSE(o.Validate(&error));
    return error;
  };
  SimulationOptions o;
  o.echogenicity_range = 0.95;
  EXPECT_EQ(refused(o), "echogenicity_range=0.95: must be in [0, 0.9]");
  o = SimulationOptions();
  o.shadow_strength = -0.1;
  EXPECT_EQ(refused(o), "shadow_strength=-0.1: must be in [0, 1]");
  o = SimulationOptions();
  o.psf_lateral_mm = 25.0;
  EXPECT_EQ(refused(o), "psf_lateral_mm=25: must be in [0, 20]");
  o = SimulationOptions();
  o.dropout_fraction = 1.0;
  EXPECT_EQ(refused(o), "dropout_fraction=1: must be in [0, 0.9]");
  o = SimulationOptions();
  o.dropout_view_fraction = 2.0;
  EXPECT_EQ(refused(o), "dropout_view_fraction=2: must be in [0, 1]");
}

}  // namespace
}  // namespace dsr
