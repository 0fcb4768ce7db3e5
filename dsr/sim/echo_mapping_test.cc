// The echo-like intensity mapping (sim/echo_mapping.h, SimulationOptions::intensity_mapping):
// exact levels on synthetic sources (flat regions below the reject black, flat tissue
// rescaled, a step's bright interface), the Gaussian's width and the gradient in mm on
// anisotropic grids, agreement with a direct slow reference on an oblique anisotropic
// grid, independence of the thread count, and Simulate sampling the mapped source with
// everything else unchanged. (Its default, kNone, keeping the sequences bit for bit:
// simulate_test's SimulateEchoMapping.NoneIsBitIdenticalToBefore.)
#include "dsr/sim/echo_mapping.h"

#include <algorithm>
#include <cmath>
#include <random>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "dsr/sim/phantom.h"
#include "dsr/sim/simulate.h"
#include "dsr/tests/support/tolerances.h"

namespace dsr {
namespace {

// E is stored as float (values <= 255: ulp <= 1.5e-5).
using testing_tolerances::kFloatValueTolerance;
// A flat region smoothed by normalised convolution is flat only up to float rounding where
// the kernel meets the grid border (partial sums): gradients of ~1e-5 grey levels per mm,
// which move E by far less than this.
constexpr double kFlatRegionTolerance = 1e-3;
// The slow reference sums in double, the mapping's smoothing in float: G differs by
// ~1e-5 of 255, the gradients by about as much; E by well under this.
constexpr double kReferenceTolerance = 1e-2;

constexpr float kDark = 50.0f;     // below the default reject (76.5)
constexpr float kBright = 200.0f;  // tissue

// Options with the echo mapping's defaults and the given edge smoothing.
SimulationOptions EchoOptions(double edge_sigma_mm) {
  SimulationOptions o;
  o.intensity_mapping = IntensityMapping::kEcho;
  o.echo_edge_sigma_mm = edge_sigma_mm;
  return o;
}

// 255 (1 - w) (S - r) / (255 - r): a flat region's level (echo_mapping.h).
double FlatLevel(const SimulationOptions& o, double s) {
  return 255.0 * (1.0 - o.echo_edge_weight) * std::max(0.0, s - o.echo_reject) /
         (255.0 - o.echo_reject);
}

// A source of `size` voxels at `spacing_mm`, kDark where index[axis] < step, else kBright.
Image StepSource(const Eigen::Vector3i& size,
                 const Eigen::Vector3d& spacing_mm,
                 int axis,
                 int step) {
  ImageGeometry g;
  g.size = size;
  g.spacing_mm = spacing_mm;
  Image source(g);
  for (int k = 0; k < size[2]; ++k) {
    for (int j = 0; j < size[1]; ++j) {
      for (int i = 0; i < size[0]; ++i) {
        const int index[3] = {i, j, k};
        source.at(i, j, k) = index[axis] < step ? kDark : kBright;
      }
    }
  }
  return source;
}

TEST(EchoMapping, Names) {
  IntensityMapping mapping = IntensityMapping::kEcho;
  EXPECT_TRUE(StringToIntensityMapping("none", &mapping));
  EXPECT_EQ(mapping, IntensityMapping::kNone);
  EXPECT_TRUE(StringToIntensityMapping("echo", &mapping));
  EXPECT_EQ(mapping, IntensityMapping::kEcho);
  for (const char* bad : {"", "Echo", "echo ", "ultrasound", "None"}) {
    EXPECT_FALSE(StringToIntensityMapping(bad, &mapping)) << bad;
    EXPECT_EQ(mapping, IntensityMapping::kEcho) << "untouched on failure";
  }
  EXPECT_STREQ(IntensityMappingToString(IntensityMapping::kNone), "none");
  EXPECT_STREQ(IntensityMappingToString(IntensityMapping::kEcho), "echo");
  const SimulationOptions defaults;
  EXPECT_EQ(defaults.intensity_mapping, IntensityMapping::kNone);
  EXPECT_EQ(defaults.echo_reject, 0.3 * 255.0);
  EXPECT_EQ(defaults.echo_edge_sigma_mm, 1.0);
  EXPECT_EQ(defaults.echo_edge_weight, 0.35);
}

TEST(EchoMapping, FlatRegionsAndAStepGiveTheModelsLevels) {
  // Unsmoothed (sigma 0): the central differences are non-zero only on the two voxels
  // beside the step, (200 - 50) / 2 per voxel each, which are 2 of 16 columns of the
  // anatomy, so they are g99 and get the whole edge term.
  const SimulationOptions o = EchoOptions(0.0);
  for (double spacing_x : {1.0, 2.5}) {
    const Image source =
        StepSource(Eigen::Vector3i(16, 6, 5), Eigen::Vector3d(spacing_x, 1.0, 1.0), 0, 8);
    double p99 = 0.0;
    const Image e = EchoIntensityMap(source, o, 1, &p99);
    EXPECT_DOUBLE_EQ(p99, (kBright - kDark) / (2.0 * spacing_x)) << "per mm";
    const double w = o.echo_edge_weight;
    for (int k = 0; k < 5; ++k) {
      for (int j = 0; j < 6; ++j) {
        for (int i = 0; i < 16; ++i) {
          const float v = e.at(i, j, k);
          if (i < 7) {
            ASSERT_EQ(v, 0.0f) << "below the reject, flat: black, " << i;
          } else if (i == 7) {
            ASSERT_NEAR(v, 255.0 * w, kFloatValueTolerance) << "dark side of the interface";
          } else if (i == 8) {
            ASSERT_NEAR(v, FlatLevel(o, kBright) + 255.0 * w, kFloatValueTolerance)
                << "bright side of the interface";
          } else {
            ASSERT_NEAR(v, FlatLevel(o, kBright), kFloatValueTolerance) << "flat tissue " << i;
          }
        }
      }
    }
  }
  // The levels themselves: 200 -> 0.65 x (200 - 76.5) / 178.5 x 255 = 114.7.
  EXPECT_NEAR(FlatLevel(o, kBright), 114.68, 0.01);
}

TEST(EchoMapping, SmoothedStepIsABrightInterfaceBetweenFlatLevels) {
  // Default sigma (1 mm = 1 voxel): the edge term spreads over a few voxels, peaks at the
  // step and fades to the flat levels 4 voxels away (the kernel's radius 3 plus the
  // central difference's 1).
  const SimulationOptions o = EchoOptions(1.0);
  const Image source = StepSource(Eigen::Vector3i(24, 8, 8), Eigen::Vector3d::Ones(), 0, 12);
  const Image e = EchoIntensityMap(source, o, 0);
  const int j = 4, k = 4;
  for (int i = 0; i <= 7; ++i) EXPECT_NEAR(e.at(i, j, k), 0.0, kFlatRegionTolerance) << i;
  for (int i = 16; i < 24; ++i) {
    EXPECT_NEAR(e.at(i, j, k), FlatLevel(o, kBright), kFlatRegionTolerance) << i;
  }
  // The interface: on the bright side brighter than the tissue by most of 255 w, on the
  // dark side lit by the edge term alone.
  const double peak = std::max(e.at(11, j, k), e.at(12, j, k));
  EXPECT_GT(peak, FlatLevel(o, kBright) + 0.5 * 255.0 * o.echo_edge_weight);
  EXPECT_GT(e.at(11, j, k), 0.5 * 255.0 * o.echo_edge_weight);
}

TEST(EchoMapping, GaussianWidthAndGradientAreInMillimetres) {
  // A 0.6 x 0.6 x 4 mm grid (like the CT's 0.63 x 0.63 x 5 mm). With sigma 1 mm a step
  // across the 4 mm slices stays one slice wide: two slices away the edge term is the
  // kernel's tail, exp(-(4 mm)^2 / 2) = 3e-4 of the peak; across the 0.6 mm columns the
  // same step is spread over 1.7 voxels per sigma, well past two columns. In voxels the two
  // would be alike.
  const Eigen::Vector3d spacing(0.6, 0.6, 4.0);
  const SimulationOptions o = EchoOptions(1.0);
  const Image along_z = StepSource(Eigen::Vector3i(12, 12, 12), spacing, 2, 6);
  const Image along_x = StepSource(Eigen::Vector3i(24, 12, 12), spacing, 0, 12);
  const Image ez = EchoIntensityMap(along_z, o, 0);
  const Image ex = EchoIntensityMap(along_x, o, 0);
  const double edge = 255.0 * o.echo_edge_weight;
  // Two voxels into the dark side, away from the other axes' borders.
  EXPECT_LT(ez.at(6, 6, 3), 1e-3 * edge);
  EXPECT_GT(ex.at(9, 6, 6), 0.2 * edge);
  // The gradient is per mm: unsmoothed, the slices' step is (200 - 50) / (2 x 4 mm).
  double p99 = 0.0;
  EchoIntensityMap(along_z, EchoOptions(0.0), 0, &p99);
  EXPECT_DOUBLE_EQ(p99, (kBright - kDark) / 8.0);
  EchoIntensityMap(along_x, EchoOptions(0.0), 0, &p99);
  EXPECT_DOUBLE_EQ(p99, (kBright - kDark) / 1.2);
}

// The map by its definition, in double: a direct (non-separable) normalised Gaussian sum
// over the grid with weights exp(-|d_mm|^2 / (2 sigma^2)), cut where image/pyramid.h's
// kernels are cut (max(1, ceil(3 sigma / spacing)) voxels per axis); the physical gradient
// through the physical-to-index matrix; g99 from a full sort.
std::vector<double> ReferenceEchoMap(const Image& source, const SimulationOptions& o) {
  const ImageGeometry& g = source.geometry;
  const Eigen::Vector3i& n = g.size;
  const double sigma = o.echo_edge_sigma_mm;
  int radius[3];
  for (int a = 0; a < 3; ++a) {
    radius[a] = std::max(1, static_cast<int>(std::ceil(3.0 * sigma / g.spacing_mm[a])));
  }
  std::vector<double> smoothed(g.NumVoxels());
  for (int k = 0; k < n[2]; ++k) {
    for (int j = 0; j < n[1]; ++j) {
      for (int i = 0; i < n[0]; ++i) {
        double sum = 0.0, weight = 0.0;
        for (int dk = -radius[2]; dk <= radius[2]; ++dk) {
          for (int dj = -radius[1]; dj <= radius[1]; ++dj) {
            for (int di = -radius[0]; di <= radius[0]; ++di) {
              const int x = i + di, y = j + dj, z = k + dk;
              if (x < 0 || y < 0 || z < 0 || x >= n[0] || y >= n[1] || z >= n[2]) continue;
              const Eigen::Vector3d d_mm =
                  Eigen::Vector3d(di, dj, dk).cwiseProduct(g.spacing_mm);
              const double w = std::exp(-d_mm.squaredNorm() / (2.0 * sigma * sigma));
              sum += w * source.at(x, y, z);
              weight += w;
            }
          }
        }
        smoothed[g.LinearIndex(i, j, k)] = sum / weight;
      }
    }
  }
  const Eigen::Matrix3d m_transpose = g.PhysicalToIndexMatrix().transpose();
  std::vector<double> magnitude(g.NumVoxels()), anatomy;
  for (int k = 0; k < n[2]; ++k) {
    for (int j = 0; j < n[1]; ++j) {
      for (int i = 0; i < n[0]; ++i) {
        const int ijk[3] = {i, j, k};
        Eigen::Vector3d d_index;
        for (int a = 0; a < 3; ++a) {
          int lo[3] = {i, j, k}, hi[3] = {i, j, k};
          lo[a] = std::max(ijk[a] - 1, 0);
          hi[a] = std::min(ijk[a] + 1, n[a] - 1);
          d_index[a] = (smoothed[g.LinearIndex(hi[0], hi[1], hi[2])] -
                        smoothed[g.LinearIndex(lo[0], lo[1], lo[2])]) /
                       (hi[a] - lo[a]);
        }
        const int64_t l = g.LinearIndex(i, j, k);
        magnitude[l] = (m_transpose * d_index).norm();
        if (source.voxels[l] > 0.0f) anatomy.push_back(magnitude[l]);
      }
    }
  }
  std::sort(anatomy.begin(), anatomy.end());
  const double p99 = anatomy[static_cast<size_t>(std::floor(0.99 * (anatomy.size() - 1)))];
  std::vector<double> e(g.NumVoxels());
  const double r = o.echo_reject, w = o.echo_edge_weight;
  for (size_t l = 0; l < e.size(); ++l) {
    const double tissue = std::max(0.0, source.voxels[l] - r) / (255.0 - r);
    e[l] = 255.0 * std::clamp((1.0 - w) * tissue + w * std::min(1.0, magnitude[l] / p99), 0.0,
                              1.0);
  }
  return e;
}

TEST(EchoMapping, MatchesADirectReferenceOnAnObliqueAnisotropicGrid) {
  ImageGeometry g;
  g.size = Eigen::Vector3i(14, 11, 7);
  g.spacing_mm = Eigen::Vector3d(0.7, 0.95, 2.5);  // 3 sigma / spacing: no integer
  g.origin_mm = Eigen::Vector3d(-3.0, 8.0, 1.5);
  g.direction =
      Eigen::AngleAxisd(0.6, Eigen::Vector3d(1.0, -2.0, 0.5).normalized()).toRotationMatrix();
  // Smooth blobs plus white noise, a quarter of the voxels 0 (background, left out of g99).
  Image source(g);
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  for (int k = 0; k < g.size[2]; ++k) {
    for (int j = 0; j < g.size[1]; ++j) {
      for (int i = 0; i < g.size[0]; ++i) {
        const double blob = 120.0 + 90.0 * std::sin(0.5 * i) * std::cos(0.4 * j + 0.7 * k);
        source.at(i, j, k) =
            u(rng) < 0.25 ? 0.0f : static_cast<float>(std::clamp(blob + 30.0 * u(rng), 0.0, 255.0));
      }
    }
  }
  for (double sigma_mm : {0.0, 1.0, 1.8}) {
    SimulationOptions o = EchoOptions(sigma_mm);
    o.echo_reject = 60.0;
    o.echo_edge_weight = 0.5;
    const Image e = EchoIntensityMap(source, o, 0);
    const std::vector<double> reference =
        sigma_mm > 0.0 ? ReferenceEchoMap(source, o) : std::vector<double>();
    if (sigma_mm == 0.0) {
      // The reference's smoothing needs sigma > 0; sigma 0 is sigma -> 0: no smoothing.
      SimulationOptions tiny = o;
      tiny.echo_edge_sigma_mm = 1e-3;
      const std::vector<double> limit = ReferenceEchoMap(source, tiny);
      for (size_t l = 0; l < limit.size(); ++l) {
        ASSERT_NEAR(e.voxels[l], limit[l], kReferenceTolerance) << "sigma 0, voxel " << l;
      }
      continue;
    }
    for (size_t l = 0; l < reference.size(); ++l) {
      ASSERT_NEAR(e.voxels[l], reference[l], kReferenceTolerance)
          << "sigma " << sigma_mm << ", voxel " << l;
    }
  }
}

// The 80^3 phantom relabelled to a CT-like 0.7 x 0.7 x 3 mm grid.
Image AnisotropicPhantom() {
  PhantomOptions p;
  p.size = 80;
  Image source = MakePhantom(p);
  source.geometry.spacing_mm = Eigen::Vector3d(0.7, 0.7, 3.0);
  source.geometry.origin_mm =
      -0.5 * (source.geometry.size.cast<double>() - Eigen::Vector3d::Ones())
                 .cwiseProduct(source.geometry.spacing_mm);
  return source;
}

TEST(EchoMapping, IsIndependentOfTheThreadCount) {
  const Image source = AnisotropicPhantom();
  const SimulationOptions o = EchoOptions(1.0);
  double p99_one = 0.0;
  const Image one = EchoIntensityMap(source, o, 1, &p99_one);
  for (int threads : {2, 3, 0}) {
    double p99 = 0.0;
    EXPECT_EQ(EchoIntensityMap(source, o, threads, &p99).voxels, one.voxels) << threads;
    EXPECT_EQ(p99, p99_one) << threads;
  }
  EXPECT_GT(p99_one, 0.0);
}

// 4 frames of 32^3 with small motions (as simulate_test's SmallOptions), noise-free.
SimulationOptions SmallEchoOptions() {
  SimulationOptions o;
  o.num_frames = 4;
  o.frame_size = Eigen::Vector3i(32, 32, 32);
  o.max_rotation_deg = 8.0;
  o.max_translation_voxels = 4.0;
  o.sigma = 0.0;
  o.min_depth_voxels = 2.0;
  o.intensity_mapping = IntensityMapping::kEcho;
  return o;
}

TEST(SimulateEchoMapping, FramesSampleTheMappedSourceAndEverythingElseIsUnchanged) {
  // With every effect and noise on: the kEcho sequence is, bit for bit, the kNone sequence
  // of the mapped source (the same poses, gains, offsets, speckle and noise draws).
  const Image source = AnisotropicPhantom();
  SimulationOptions o = SmallEchoOptions();
  o.pose_model = PoseModel::kWalk;
  o.sigma = 15.0;
  o.speckle_looks = 2;
  o.speckle_world_fraction = 0.8;
  o.attenuation_db_per_cm = 0.5;
  o.gain_range = 0.15;
  o.offset_range = 10.0;
  for (SourceInterpolation interpolation :
       {SourceInterpolation::kLinear, SourceInterpolation::kCubic}) {
    o.interpolation = interpolation;
    SimulatedSequence echo, of_mapped, plain;
    std::string error;
    ASSERT_TRUE(Simulate(source, o, &echo, &error)) << error;
    SimulationOptions none = o;
    none.intensity_mapping = IntensityMapping::kNone;
    ASSERT_TRUE(Simulate(EchoIntensityMap(source, o, 0), none, &of_mapped, &error)) << error;
    ASSERT_TRUE(Simulate(source, none, &plain, &error)) << error;
    for (int f = 0; f < o.num_frames; ++f) {
      EXPECT_EQ(echo.frames[f].voxels, of_mapped.frames[f].voxels) << f;
      EXPECT_NE(echo.frames[f].voxels, plain.frames[f].voxels) << f;
      EXPECT_TRUE(echo.frame_from_world[f].matrix() == plain.frame_from_world[f].matrix());
      EXPECT_EQ(echo.gain[f], plain.gain[f]);
      EXPECT_EQ(echo.offset[f], plain.offset[f]);
      EXPECT_EQ(echo.masks[f].voxels, plain.masks[f].voxels);
    }
  }
}

TEST(SimulateEchoMapping, ADarkPoolIsBlackInTheFramesBeforeNoise) {
  // 50-grey blood where world x < 0, 200-grey tissue elsewhere, cut through the middle of
  // every frame: noise-free frames are exactly 0 wherever everything their sample reads
  // lies in the blood, and the tissue level (to rounding) where it all lies in the tissue.
  // A sample reads the map's voxels up to 1 voxel away per axis (trilinear), each map voxel
  // the smoothed source 1 further along one axis (central differences), each of those the
  // source 3 further per axis (the kernel's radius, 3 sigma): up to 5 mm along x.
  ImageGeometry g;
  g.size = Eigen::Vector3i(72, 72, 72);
  g.origin_mm = Eigen::Vector3d::Constant(-35.5);
  Image source(g);
  for (int k = 0; k < g.size[2]; ++k) {
    for (int j = 0; j < g.size[1]; ++j) {
      for (int i = 0; i < g.size[0]; ++i) {
        source.at(i, j, k) = g.IndexToPhysical(Eigen::Vector3d(i, j, k))[0] < 0.0 ? kDark : kBright;
      }
    }
  }
  constexpr double kReachMm = 5.0;
  const SimulationOptions o = SmallEchoOptions();
  SimulatedSequence s;
  std::string error;
  ASSERT_TRUE(Simulate(source, o, &s, &error)) << error;
  const ImageGeometry& fg = s.frames[0].geometry;
  const Mask fov = PyramidFieldOfView(fg, o);
  int64_t black = 0, tissue = 0;
  for (int f = 0; f < o.num_frames; ++f) {
    const Eigen::Isometry3d world_from_frame = s.frame_from_world[f].inverse();
    for (int k = 0; k < fg.size[2]; ++k) {
      for (int j = 0; j < fg.size[1]; ++j) {
        for (int i = 0; i < fg.size[0]; ++i) {
          if (!fov.at(i, j, k)) continue;
          const Eigen::Vector3d x = world_from_frame * fg.IndexToPhysical(Eigen::Vector3d(i, j, k));
          const float v = s.frames[f].at(i, j, k);
          if (x[0] < -kReachMm) {
            ASSERT_EQ(v, 0.0f) << "frame " << f << " voxel " << i << "," << j << "," << k;
            ++black;
          } else if (x[0] > kReachMm) {
            ASSERT_NEAR(v, FlatLevel(o, kBright), kFlatRegionTolerance) << "frame " << f;
            ++tissue;
          }
        }
      }
    }
  }
  EXPECT_GT(black, 10000);
  EXPECT_GT(tissue, 10000);
}

}  // namespace
}  // namespace dsr
