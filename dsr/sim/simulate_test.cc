// Simulator (docs/design.md section 6, sim/simulate.h): frames agree with each other under the
// ground-truth poses, determinism, the protocol's pose ranges (random and walk), which
// motions fit the default phantom, noise statistics, the field of view and its mask,
// option validation; the cubic source interpolation (CubicInterpolateValue) and the
// default linear frames staying bit-identical; the ultrasound-like effects (gain, offset,
// speckle, attenuation) and their ground truth; the world-fixed part of the speckle
// (speckle_world_fraction): its statistics, its sharing between frames, its determinism;
// the echo-like intensity mapping's default leaving the sequences bit for bit (the mapping
// itself: echo_mapping_test.cc).
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <random>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "dsr/image/frame.h"
#include "dsr/sim/phantom.h"
#include "dsr/sim/simulate.h"
#include "dsr/tests/support/tolerances.h"
#include "dsr/tests/support/sanitizer.h"

namespace dsr {
namespace {

// 4 frames of 32^3 with smaller motions, cut from an 80^3 phantom.
SimulationOptions SmallOptions() {
  SimulationOptions o;
  o.num_frames = 4;
  o.frame_size = Eigen::Vector3i(32, 32, 32);
  o.max_rotation_deg = 8.0;
  o.max_translation_voxels = 4.0;
  o.sigma = 0.0;
  o.min_depth_voxels = 2.0;
  return o;
}

Image SmallSource(const Eigen::Vector3d& spacing_mm) {
  PhantomOptions p;
  p.size = 80;
  Image source = MakePhantom(p);
  // Relabel the grid (same voxels): anisotropic spacing, still centred on the origin.
  source.geometry.spacing_mm = spacing_mm;
  source.geometry.origin_mm =
      -0.5 *
      (source.geometry.size.cast<double>() - Eigen::Vector3d::Ones()).cwiseProduct(spacing_mm);
  return source;
}

struct Agreement {
  double mean_abs_difference = 0.0;
  int64_t count = 0;
};

// Resamples frame j at every mask voxel of frame i, x_in_j = T_j T_i^-1 x_in_i, optionally
// with an extra world-space error `world_error` in frame j's pose, and compares with frame i
// where frame j's sample is valid.
Agreement Compare(const SimulatedSequence& s,
                  int i,
                  int j,
                  const Eigen::Isometry3d& world_error = Eigen::Isometry3d::Identity()) {
  const Frame frame_j(s.frames[j], s.masks[j]);
  const Eigen::Isometry3d j_from_i =
      s.frame_from_world[j] * world_error * s.frame_from_world[i].inverse();
  const ImageGeometry& g = s.frames[i].geometry;
  double sum = 0.0;
  Agreement a;
  for (int k = 0; k < g.size[2]; ++k) {
    for (int y = 0; y < g.size[1]; ++y) {
      for (int x = 0; x < g.size[0]; ++x) {
        if (!s.masks[i].at(x, y, k)) continue;
        double value = 0.0;
        if (!frame_j.Sample(
                j_from_i * g.IndexToPhysical(Eigen::Vector3d(x, y, k)), &value, nullptr))
          continue;
        sum += std::abs(value - s.frames[i].at(x, y, k));
        ++a.count;
      }
    }
  }
  a.mean_abs_difference = a.count > 0 ? sum / a.count : 0.0;
  return a;
}

// Frame voxels are trilinear samples of the source, and frame j resampled into frame i is a
// trilinear sample of trilinear samples. For a source linear in x both are exact (tested
// below to float precision), which pins the pose and sampling conventions. On the phantom
// the second interpolation adds an error proportional to the second derivative: small on
// the texture, but the blood/wall edges (contrast ~170 over 2.5 voxels) give up to ~20 on
// edge voxels. Measured mean: 2.6-3.5 (80^3 phantom, 32^3 frames, both spacings). A pose
// error of 0.25 voxel gives ~5.6, 1 voxel ~18, so 4.5 still catches a quarter voxel.
constexpr double kResampleMeanAbsTolerance = 4.5;
// Float storage of the frames (values < 256, ulp < 3e-5) bounds the error on linear sources.
constexpr double kLinearSourceTolerance = 1e-3;

TEST(Simulate, LinearSourceIsReproducedExactly) {
  for (const Eigen::Vector3d& spacing :
       {Eigen::Vector3d(1.0, 1.0, 1.0), Eigen::Vector3d(1.0, 1.25, 0.8)}) {
    ImageGeometry g;
    g.size = Eigen::Vector3i(80, 80, 80);
    g.spacing_mm = spacing;
    g.origin_mm = Eigen::Vector3d(-40.0, -50.0, -30.0);
    Image source(g);
    for (int k = 0; k < 80; ++k) {
      for (int j = 0; j < 80; ++j) {
        for (int i = 0; i < 80; ++i)
          source.at(i, j, k) = static_cast<float>(30.0 + 1.1 * i + 0.6 * j + 0.9 * k);
      }
    }
    SimulatedSequence s;
    std::string error;
    ASSERT_TRUE(Simulate(source, SmallOptions(), &s, &error)) << error;
    // Frame 0 itself: the value at each voxel is the linear function at its world point.
    const Eigen::Isometry3d world_from_frame0 = s.frame_from_world[0].inverse();
    const ImageGeometry& fg = s.frames[0].geometry;
    for (int k = 0; k < fg.size[2]; k += 3) {
      for (int y = 0; y < fg.size[1]; y += 3) {
        for (int x = 0; x < fg.size[0]; x += 3) {
          if (!s.masks[0].at(x, y, k)) continue;
          const Eigen::Vector3d ijk =
              g.PhysicalToIndex(world_from_frame0 * fg.IndexToPhysical(Eigen::Vector3d(x, y, k)));
          ASSERT_NEAR(s.frames[0].at(x, y, k),
                      30.0 + 1.1 * ijk[0] + 0.6 * ijk[1] + 0.9 * ijk[2],
                      kLinearSourceTolerance);
        }
      }
    }
    for (int j = 1; j < 4; ++j) {
      const Agreement a = Compare(s, 0, j);
      ASSERT_GT(a.count, 2000);
      EXPECT_LT(a.mean_abs_difference, kLinearSourceTolerance)
          << "frame " << j << ", spacing " << spacing.transpose();
    }
  }
}

TEST(Simulate, FramesAgreeUnderGroundTruthPoses) {
  for (const Eigen::Vector3d& spacing :
       {Eigen::Vector3d(1.0, 1.0, 1.0), Eigen::Vector3d(1.0, 1.25, 0.8)}) {
    const Image source = SmallSource(spacing);
    for (PoseModel model : {PoseModel::kRandom, PoseModel::kWalk}) {
      SimulationOptions o = SmallOptions();
      o.pose_model = model;
      SimulatedSequence s;
      std::string error;
      ASSERT_TRUE(Simulate(source, o, &s, &error)) << error;
      ASSERT_EQ(s.frames.size(), 4u);
      for (int j = 1; j < 4; ++j) {
        const Agreement a = Compare(s, 0, j);
        const Agreement b = Compare(s, j, 0);
        ASSERT_GT(a.count, 2000) << "frames 0 and " << j << " barely overlap";
        EXPECT_LT(a.mean_abs_difference, kResampleMeanAbsTolerance)
            << "frame " << j << " into frame 0, spacing " << spacing.transpose() << ", "
            << PoseModelToString(model);
        EXPECT_LT(b.mean_abs_difference, kResampleMeanAbsTolerance)
            << "frame 0 into frame " << j << ", spacing " << spacing.transpose() << ", "
            << PoseModelToString(model);
      }
    }
  }
}

TEST(Simulate, WrongPosesDisagree) {
  // The control for the tolerance above: a quarter voxel of pose error is visible.
  const Image source = SmallSource(Eigen::Vector3d::Ones());
  SimulatedSequence s;
  std::string error;
  ASSERT_TRUE(Simulate(source, SmallOptions(), &s, &error)) << error;
  Eigen::Isometry3d shifted = Eigen::Isometry3d::Identity();
  shifted.translation() = Eigen::Vector3d(1.0, 0.0, 0.0);
  EXPECT_GT(Compare(s, 0, 1, shifted).mean_abs_difference, 3.0 * kResampleMeanAbsTolerance);
  shifted.translation() = Eigen::Vector3d(0.0, 0.0, 0.25);
  EXPECT_GT(Compare(s, 0, 1, shifted).mean_abs_difference, kResampleMeanAbsTolerance);
  Eigen::Isometry3d rotated = Eigen::Isometry3d::Identity();  // about the source centre
  rotated.linear() =
      Eigen::AngleAxisd(2.0 * M_PI / 180.0, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  EXPECT_GT(Compare(s, 0, 1, rotated).mean_abs_difference, kResampleMeanAbsTolerance);
}

TEST(Simulate, DeterministicForASeedAndSeedsDiffer) {
  const Image source = SmallSource(Eigen::Vector3d::Ones());
  SimulationOptions o = SmallOptions();
  o.sigma = 25.0;
  SimulatedSequence a, b, c;
  std::string error;
  ASSERT_TRUE(Simulate(source, o, &a, &error)) << error;
  ASSERT_TRUE(Simulate(source, o, &b, &error)) << error;
  for (int f = 0; f < o.num_frames; ++f) {
    EXPECT_EQ(a.frames[f].voxels, b.frames[f].voxels) << "frame " << f;
    EXPECT_EQ(a.masks[f].voxels, b.masks[f].voxels) << "frame " << f;
    EXPECT_TRUE(a.frame_from_world[f].matrix() == b.frame_from_world[f].matrix()) << "frame " << f;
  }
  o.seed = 2;
  ASSERT_TRUE(Simulate(source, o, &c, &error)) << error;
  EXPECT_FALSE(a.frame_from_world[0].isApprox(c.frame_from_world[0], 1e-6));
  EXPECT_NE(a.frames[0].voxels, c.frames[0].voxels);
}

// The first rows of frame_from_world for frames 0, 1 and 10 of the default options (seed 1)
// on the default phantom's grid, recorded from the simulator before the walk model was
// added: existing random sequences must not change. 1e-12 leaves room for a libm whose
// sin/cos differ in the last bit; on the development machine they are bit-identical.
constexpr double kRecordedPoseTolerance = 1e-12;

ImageGeometry DefaultPhantomGrid() {
  PhantomOptions p;
  ImageGeometry phantom;
  phantom.size = Eigen::Vector3i::Constant(p.size);
  phantom.spacing_mm = Eigen::Vector3d::Constant(p.spacing_mm);
  phantom.origin_mm = Eigen::Vector3d::Constant(-0.5 * (p.size - 1) * p.spacing_mm);
  return phantom;
}

TEST(Simulate, RandomPosesAreTheRecordedOnes) {
  struct Recorded {
    int frame;
    double row0[4];
    double row2[4];
  };
  const Recorded recorded[] = {
      {0,
       {0.9882181614469411, 0.04336483958258794, -0.14677995801336038, 31.29467641750668},
       {0.15171335619231227, -0.150992650787284, 0.9768235649087781, 50.050115060303355}},
      {1,
       {0.9837317423746683, -0.027079694648590724, -0.1775909603055242, 51.52515578578681},
       {0.17732176752488096, -0.012056868987724378, 0.9840790733838745, 42.02641480116703}},
      {10,
       {0.9667376088942824, 0.18586863212253713, -0.17570215463181568, 41.589966226499435},
       {0.20766258935382118, -0.16936099796769058, 0.963427787304401, 37.943921157809555}},
  };
  SimulationOptions o;
  ASSERT_EQ(o.pose_model, PoseModel::kRandom);  // the default
  const std::vector<Eigen::Isometry3d> poses = SimulatedPoses(DefaultPhantomGrid(), o);
  ASSERT_EQ(poses.size(), 11u);
  for (const Recorded& r : recorded) {
    const Eigen::Matrix4d t = poses[r.frame].matrix();
    for (int c = 0; c < 4; ++c) {
      EXPECT_NEAR(t(0, c), r.row0[c], kRecordedPoseTolerance) << "frame " << r.frame;
      EXPECT_NEAR(t(2, c), r.row2[c], kRecordedPoseTolerance) << "frame " << r.frame;
    }
  }
}

// (alpha, beta, gamma) with R = Rz(gamma) Ry(beta) Rx(alpha), beta in [-pi/2, pi/2].
Eigen::Vector3d EulerZyx(const Eigen::Matrix3d& r) {
  return Eigen::Vector3d(
      std::atan2(r(2, 1), r(2, 2)), -std::asin(r(2, 0)), std::atan2(r(1, 0), r(0, 0)));
}

// A walk's consecutive frames: the rotation angle of world_from_frame_i *
// frame_from_world_{i-1} (the step Q), and how far the frame centre moved in the world.
struct WalkStep {
  double angle = 0.0;
  double shift_mm = 0.0;
};
WalkStep StepBetween(const Eigen::Isometry3d& previous,
                     const Eigen::Isometry3d& next,
                     const Eigen::Vector3d& frame_center) {
  WalkStep step;
  step.angle = Eigen::AngleAxisd(next.linear().transpose() * previous.linear()).angle();
  step.shift_mm = (next.inverse() * frame_center - previous.inverse() * frame_center).norm();
  return step;
}

TEST(Simulate, WalkStepsStayWithinTheirBoundsAndTheBox) {
  ImageGeometry source;  // anisotropic and off-centre: steps are in frame voxels (0.7 mm)
  source.size = Eigen::Vector3i(100, 120, 90);
  source.spacing_mm = Eigen::Vector3d(0.7, 0.9, 1.1);
  source.origin_mm = Eigen::Vector3d(-3.0, 5.0, 2.0);
  const Eigen::Vector3d c_s =
      source.IndexToPhysical(0.5 * (source.size.cast<double>() - Eigen::Vector3d::Ones()));
  struct Case {
    double max_rotation_deg, max_translation_voxels, step_rotation_deg, step_translation_voxels;
    bool clamped;  // the box is small against the steps
  };
  const Case cases[] = {
      {30.0, 40.0, 6.0, 6.0, false},  // the walk protocol's steps in a roomy box
      {2.0, 1.0, 10.0, 10.0, true},   // steps far larger than the box
      {45.0, 10.0, 3.0, 2.0, false},
  };
  for (const Case& c : cases) {
    SimulationOptions o;
    o.pose_model = PoseModel::kWalk;
    o.num_frames = 300;
    o.max_rotation_deg = c.max_rotation_deg;
    o.max_translation_voxels = c.max_translation_voxels;
    o.step_rotation_deg = c.step_rotation_deg;
    o.step_translation_voxels = c.step_translation_voxels;
    const std::vector<Eigen::Isometry3d> poses = SimulatedPoses(source, o);
    ASSERT_EQ(poses.size(), 300u);
    const ImageGeometry frame = SimulatedFrameGeometry(source, o);
    const Eigen::Vector3d c_f =
        frame.IndexToPhysical(0.5 * (frame.size.cast<double>() - Eigen::Vector3d::Ones()));
    const double step_angle = c.step_rotation_deg * M_PI / 180.0;
    const double step_shift = c.step_translation_voxels * 0.7;
    const double max_angle = c.max_rotation_deg * M_PI / 180.0;
    const double max_shift = c.max_translation_voxels * 0.7;
    double largest_angle = 0.0, largest_shift = 0.0;
    for (size_t f = 0; f < poses.size(); ++f) {
      const Eigen::Matrix3d r = poses[f].linear();
      ASSERT_NEAR((r.transpose() * r - Eigen::Matrix3d::Identity()).norm(), 0.0, 1e-12);
      const Eigen::Vector3d euler = EulerZyx(r);
      const Eigen::Vector3d seen = poses[f].inverse() * c_f;  // = c_s - t
      EXPECT_LE(euler.cwiseAbs().maxCoeff(), max_angle + 1e-9) << "frame " << f;
      EXPECT_LE((seen - c_s).cwiseAbs().maxCoeff(), max_shift + 1e-9) << "frame " << f;
      if (f == 0) continue;
      const WalkStep step = StepBetween(poses[f - 1], poses[f], c_f);
      EXPECT_LE(step.angle, step_angle + 1e-9) << "frame " << f;
      EXPECT_LE(step.shift_mm, step_shift + 1e-9) << "frame " << f;
      largest_angle = std::max(largest_angle, step.angle);
      largest_shift = std::max(largest_shift, step.shift_mm);
    }
    if (!c.clamped) {
      // Uniform step sizes, 299 of each, rarely clamped in a roomy box: they span the range.
      EXPECT_GT(largest_angle, 0.95 * step_angle);
      EXPECT_GT(largest_shift, 0.95 * step_shift);
    } else {
      EXPECT_GT(largest_angle, 0.0);  // clamped, yet still moving
      EXPECT_GT(largest_shift, 0.0);
    }
  }
}

TEST(Simulate, WalkIsDeterministicAndStartsWhereRandomStarts) {
  const ImageGeometry grid = DefaultPhantomGrid();
  SimulationOptions o;
  o.pose_model = PoseModel::kWalk;
  const std::vector<Eigen::Isometry3d> a = SimulatedPoses(grid, o);
  const std::vector<Eigen::Isometry3d> b = SimulatedPoses(grid, o);
  for (size_t f = 0; f < a.size(); ++f) {
    EXPECT_TRUE(a[f].matrix() == b[f].matrix()) << "frame " << f;
  }
  SimulationOptions random = o;
  random.pose_model = PoseModel::kRandom;
  const std::vector<Eigen::Isometry3d> r = SimulatedPoses(grid, random);
  EXPECT_TRUE(a[0].matrix() == r[0].matrix()) << "frame 0 is drawn as in the random model";
  EXPECT_FALSE(a[1].isApprox(r[1], 1e-6));
  // Consecutive walk frames are within one step (the default 6 voxels of 1 mm).
  const Eigen::Vector3d c_f = 0.5 * (o.frame_size.cast<double>() - Eigen::Vector3d::Ones());
  EXPECT_LE(StepBetween(a[0], a[1], c_f).shift_mm, 6.0 + 1e-9);
  o.seed = 2;
  const std::vector<Eigen::Isometry3d> c = SimulatedPoses(grid, o);
  EXPECT_FALSE(a[0].isApprox(c[0], 1e-6));
  EXPECT_FALSE(a[5].isApprox(c[5], 1e-6));

  // Whole sequences, noise included.
  const Image source = SmallSource(Eigen::Vector3d::Ones());
  SimulationOptions small = SmallOptions();
  small.pose_model = PoseModel::kWalk;
  small.sigma = 25.0;
  SimulatedSequence s1, s2;
  std::string error;
  ASSERT_TRUE(Simulate(source, small, &s1, &error)) << error;
  ASSERT_TRUE(Simulate(source, small, &s2, &error)) << error;
  for (int f = 0; f < small.num_frames; ++f) {
    EXPECT_EQ(s1.frames[f].voxels, s2.frames[f].voxels) << "frame " << f;
    EXPECT_TRUE(s1.frame_from_world[f].matrix() == s2.frame_from_world[f].matrix());
  }
}

TEST(Simulate, PosesFollowTheProtocol) {
  // T = Translate(c_f) R Translate(t - c_s): R from Euler angles within the bound, and the
  // frame centre sees c_s - t with |t| within the bound per world axis.
  SimulationOptions o;  // the paper's ranges: 12 degrees, 15 voxels
  o.num_frames = 200;
  ImageGeometry source;
  source.size = Eigen::Vector3i(100, 120, 90);
  source.spacing_mm = Eigen::Vector3d(0.7, 0.9, 1.1);
  source.origin_mm = Eigen::Vector3d(-3.0, 5.0, 2.0);
  const std::vector<Eigen::Isometry3d> poses = SimulatedPoses(source, o);
  ASSERT_EQ(poses.size(), 200u);
  const ImageGeometry frame = SimulatedFrameGeometry(source, o);
  EXPECT_DOUBLE_EQ(frame.spacing_mm[2], 0.7);  // frame spacing 0: the source's x spacing
  const Eigen::Vector3d c_s =
      source.IndexToPhysical(0.5 * (source.size.cast<double>() - Eigen::Vector3d::Ones()));
  const Eigen::Vector3d c_f =
      frame.IndexToPhysical(0.5 * (frame.size.cast<double>() - Eigen::Vector3d::Ones()));
  const double max_angle = 12.0 * M_PI / 180.0;
  double largest_angle = 0.0, largest_shift = 0.0;
  for (const Eigen::Isometry3d& t : poses) {
    const Eigen::Matrix3d r = t.linear();
    ASSERT_NEAR((r.transpose() * r - Eigen::Matrix3d::Identity()).norm(), 0.0, 1e-12);
    // R = Rz(g) Ry(b) Rx(a): b = -asin(r20), a = atan2(r21, r22), g = atan2(r10, r00).
    const double beta = -std::asin(r(2, 0));
    const double alpha = std::atan2(r(2, 1), r(2, 2));
    const double gamma = std::atan2(r(1, 0), r(0, 0));
    for (double angle : {alpha, beta, gamma}) {
      EXPECT_LE(std::abs(angle), max_angle + 1e-12);
      largest_angle = std::max(largest_angle, std::abs(angle));
    }
    const Eigen::Vector3d seen = t.inverse() * c_f;  // = c_s - t
    for (int a = 0; a < 3; ++a) {
      EXPECT_LE(std::abs(seen[a] - c_s[a]), 15.0 * 0.7 + 1e-9);
      largest_shift = std::max(largest_shift, std::abs(seen[a] - c_s[a]));
    }
  }
  // The draws span their ranges (uniform, 600 samples each).
  EXPECT_GT(largest_angle, 0.95 * max_angle);
  EXPECT_GT(largest_shift, 0.95 * 15.0 * 0.7);
}

// The corners of each slice's field-of-view rectangle (frame indices): the field of view
// is convex, so a rigid map sends all of it inside a box iff it sends these inside.
std::vector<Eigen::Vector3d> FieldOfViewCorners(const Mask& fov) {
  const ImageGeometry& g = fov.geometry;
  std::vector<Eigen::Vector3d> corners;
  for (int k = 0; k < g.size[2]; ++k) {
    Eigen::Vector2i lo(g.size[0], g.size[1]), hi(-1, -1);
    for (int j = 0; j < g.size[1]; ++j) {
      for (int i = 0; i < g.size[0]; ++i) {
        if (!fov.at(i, j, k)) continue;
        lo = lo.cwiseMin(Eigen::Vector2i(i, j));
        hi = hi.cwiseMax(Eigen::Vector2i(i, j));
      }
    }
    if (hi[0] < 0) continue;  // empty slice
    for (int c = 0; c < 4; ++c) {
      corners.emplace_back(c & 1 ? hi[0] : lo[0], c & 2 ? hi[1] : lo[1], k);
    }
  }
  return corners;
}

// Whether every field-of-view voxel (given by FieldOfViewCorners on `frame`) of a frame at
// `frame_from_world` maps inside `source` (index in [0, size - 1]).
bool FieldOfViewFits(const ImageGeometry& source,
                     const ImageGeometry& frame,
                     const std::vector<Eigen::Vector3d>& fov_corners,
                     const Eigen::Isometry3d& frame_from_world) {
  const Eigen::Vector3d upper = source.size.cast<double>() - Eigen::Vector3d::Ones();
  const Eigen::Isometry3d world_from_frame = frame_from_world.inverse();
  for (const Eigen::Vector3d& corner : fov_corners) {
    const Eigen::Vector3d ijk =
        source.PhysicalToIndex(world_from_frame * frame.IndexToPhysical(corner));
    if ((ijk.array() < 0.0).any() || (ijk.array() > upper.array()).any()) return false;
  }
  return true;
}

TEST(Simulate, DefaultsFitTheDefaultPhantomForAnySeed) {
  // dsr_simulate's defaults must never fail: every frame-box corner (a superset of the
  // field of view, which is convex) maps inside the default 192^3 phantom, for many seeds,
  // with either pose model (the walk stays in the random model's pose box).
  const ImageGeometry phantom = DefaultPhantomGrid();
  for (PoseModel model : {PoseModel::kRandom, PoseModel::kWalk}) {
    SimulationOptions o;
    o.pose_model = model;
    const ImageGeometry frame = SimulatedFrameGeometry(phantom, o);
    const Eigen::Vector3d upper = phantom.size.cast<double>() - Eigen::Vector3d::Ones();
    for (uint64_t seed = 1; seed <= 300; ++seed) {
      o.seed = seed;
      for (const Eigen::Isometry3d& t : SimulatedPoses(phantom, o)) {
        for (int c = 0; c < 8; ++c) {
          const Eigen::Vector3d corner((c & 1) * (frame.size[0] - 1),
                                       ((c >> 1) & 1) * (frame.size[1] - 1),
                                       ((c >> 2) & 1) * (frame.size[2] - 1));
          const Eigen::Vector3d ijk =
              phantom.PhysicalToIndex(t.inverse() * frame.IndexToPhysical(corner));
          ASSERT_TRUE((ijk.array() >= 0.0).all() && (ijk.array() <= upper.array()).all())
              << PoseModelToString(model) << " seed " << seed << " corner " << c << " -> "
              << ijk.transpose();
        }
      }
    }
  }
}

TEST(Simulate, LargerMotionsFitWhereTheHelpSaysTheyFit) {
  // dsr_simulate's --max_rotation_deg and --phantom_size help, for 96x96x80 frames: the
  // default 192^3 phantom fits +/-45 degrees with +/-10 voxels, and a 208^3 phantom the
  // "wide" +/-25 degrees with +/-20 voxels (192^3 has only 0.4 voxel to spare there over
  // 1000 seeds, and walks leave it), for either pose model. Field-of-view voxels, not the
  // frame box: the pyramid is narrow near its apex.
  struct Case {
    int phantom_size;
    double max_rotation_deg, max_translation_voxels;
  };
  // Under the sanitizers 10 seeds: the same poses and checks, not the search for a rare one.
  const uint64_t seeds = testing_support::FullUnlessSanitized<uint64_t>(200, 10);
  for (const Case& c : {Case{192, 45.0, 10.0}, Case{208, 25.0, 20.0}}) {
    ImageGeometry phantom;
    phantom.size = Eigen::Vector3i::Constant(c.phantom_size);
    phantom.origin_mm = Eigen::Vector3d::Constant(-0.5 * (c.phantom_size - 1));
    for (PoseModel model : {PoseModel::kRandom, PoseModel::kWalk}) {
      SimulationOptions o;
      o.pose_model = model;
      o.max_rotation_deg = c.max_rotation_deg;
      o.max_translation_voxels = c.max_translation_voxels;
      const ImageGeometry frame = SimulatedFrameGeometry(phantom, o);
      const std::vector<Eigen::Vector3d> corners =
          FieldOfViewCorners(PyramidFieldOfView(frame, o));
      for (uint64_t seed = 1; seed <= seeds; ++seed) {
        o.seed = seed;
        const std::vector<Eigen::Isometry3d> poses = SimulatedPoses(phantom, o);
        for (size_t f = 0; f < poses.size(); ++f) {
          ASSERT_TRUE(FieldOfViewFits(phantom, frame, corners, poses[f]))
              << c.phantom_size << "^3, " << c.max_rotation_deg << " deg, "
              << c.max_translation_voxels << " voxels, " << PoseModelToString(model)
              << ", seed " << seed << ", frame " << f;
        }
      }
    }
  }
}

TEST(Simulate, NoiseHasTheRequestedStatistics) {
  ImageGeometry g;
  g.size = Eigen::Vector3i(60, 60, 60);
  g.origin_mm = Eigen::Vector3d(10.0, -20.0, 5.0);
  const Image flat(g, 128.0f);
  SimulationOptions o = SmallOptions();
  o.sigma = 25.0;
  SimulatedSequence s;
  std::string error;
  ASSERT_TRUE(Simulate(flat, o, &s, &error)) << error;
  const Mask fov = PyramidFieldOfView(s.frames[0].geometry, o);
  double sum = 0.0, sum2 = 0.0;
  int64_t n = 0;
  for (const Image& frame : s.frames) {
    for (size_t v = 0; v < fov.voxels.size(); ++v) {
      if (!fov.voxels[v]) {
        ASSERT_EQ(frame.voxels[v], 0.0f);  // zero outside the field of view
        continue;
      }
      sum += frame.voxels[v];
      sum2 += double{frame.voxels[v]} * frame.voxels[v];
      ++n;
    }
  }
  ASSERT_GT(n, 40000);
  const double mean = sum / n, sd = std::sqrt(sum2 / n - mean * mean);
  // Standard errors: 25 / sqrt(n) ~ 0.1 for the mean, 25 / sqrt(2n) ~ 0.08 for the standard
  // deviation; clamping at 0 and 255 is > 5 sigma away from 128.
  EXPECT_NEAR(mean, 128.0, 0.5);
  EXPECT_NEAR(sd, 25.0, 0.5);
}

TEST(Simulate, FieldOfViewIsAPyramidAndTheMaskIsItsErosion) {
  SimulationOptions o;
  o.frame_size = Eigen::Vector3i(41, 31, 40);
  o.azimuth_deg = 60.0;
  o.elevation_deg = 90.0;
  o.min_depth_voxels = 3.0;
  ImageGeometry g;
  g.size = o.frame_size;
  const Mask fov = PyramidFieldOfView(g, o);
  const double ta = std::tan(30.0 * M_PI / 180.0), te = 1.0;  // tan(half angles)
  for (int k = 0; k < g.size[2]; ++k) {
    for (int j = 0; j < g.size[1]; ++j) {
      for (int i = 0; i < g.size[0]; ++i) {
        const bool inside = k >= 3 && std::abs(i - 20.0) <= k * ta && std::abs(j - 15.0) <= k * te;
        ASSERT_EQ(fov.at(i, j, k), inside ? 1 : 0) << i << " " << j << " " << k;
      }
    }
  }
  for (int j = 0; j < g.size[1]; ++j) {
    for (int i = 0; i < g.size[0]; ++i) EXPECT_EQ(fov.at(i, j, 0), 0);  // apex row empty
  }
  EXPECT_EQ(fov.at(20, 15, 3), 1);  // the axis, from the near-field cut on
  EXPECT_EQ(fov.at(20, 15, 39), 1);
  EXPECT_EQ(fov.at(0, 15, 39), 1);  // wide enough at depth to reach the box sides
  EXPECT_EQ(fov.at(0, 15, 10), 0);

  const Mask mask = ErodeFieldOfView(fov, 1);
  ASSERT_GT(CountInside(mask), 0);
  EXPECT_LT(CountInside(mask), CountInside(fov));
  for (int k = 0; k < g.size[2]; ++k) {
    for (int j = 0; j < g.size[1]; ++j) {
      for (int i = 0; i < g.size[0]; ++i) {
        const bool border = i == 0 || j == 0 || k == 0 || i == g.size[0] - 1 ||
                            j == g.size[1] - 1 || k == g.size[2] - 1;
        const bool interior = !border && fov.at(i, j, k) && fov.at(i - 1, j, k) &&
                              fov.at(i + 1, j, k) && fov.at(i, j - 1, k) && fov.at(i, j + 1, k) &&
                              fov.at(i, j, k - 1) && fov.at(i, j, k + 1);
        ASSERT_EQ(mask.at(i, j, k), interior ? 1 : 0) << i << " " << j << " " << k;
      }
    }
  }

  // Simulate writes exactly this mask with every frame.
  ImageGeometry source_grid;
  source_grid.size = Eigen::Vector3i(90, 90, 90);
  source_grid.origin_mm = Eigen::Vector3d::Constant(-44.5);
  o.num_frames = 2;
  o.max_translation_voxels = 2.0;
  SimulatedSequence s;
  std::string error;
  ASSERT_TRUE(Simulate(Image(source_grid, 100.0f), o, &s, &error)) << error;
  for (const Mask& m : s.masks) EXPECT_EQ(m.voxels, mask.voxels);
}

TEST(Simulate, MaskErosionCountsVoxelsAndZeroIsTheFieldOfView) {
  SimulationOptions o;
  o.frame_size = Eigen::Vector3i(41, 31, 40);
  o.min_depth_voxels = 3.0;
  o.num_frames = 2;
  o.max_translation_voxels = 2.0;
  ImageGeometry g;
  g.size = o.frame_size;
  const Mask fov = PyramidFieldOfView(g, o);
  EXPECT_EQ(ErodeFieldOfView(fov, 0).voxels, fov.voxels);
  const Mask once = ErodeFieldOfView(fov, 1);
  const Mask twice = ErodeFieldOfView(fov, 2);
  EXPECT_EQ(twice.voxels, ErodeFieldOfView(once, 1).voxels);
  EXPECT_LT(CountInside(twice), CountInside(once));

  ImageGeometry source_grid;
  source_grid.size = Eigen::Vector3i(90, 90, 90);
  source_grid.origin_mm = Eigen::Vector3d::Constant(-44.5);
  const Image source(source_grid, 100.0f);
  for (int erosion : {0, 2}) {
    o.mask_erosion = erosion;
    SimulatedSequence s;
    std::string error;
    ASSERT_TRUE(Simulate(source, o, &s, &error)) << error;
    for (const Mask& m : s.masks) EXPECT_EQ(m.voxels, (erosion == 0 ? fov : twice).voxels);
  }
  // An erosion that eats the whole field of view is refused, naming the flag.
  o.mask_erosion = 30;
  SimulatedSequence s;
  std::string error;
  EXPECT_FALSE(Simulate(source, o, &s, &error));
  EXPECT_NE(error.find("(mask_erosion)"), std::string::npos) << error;
}

// FNV-1a (64 bit) over the frames' float bit patterns, in frame and voxel order.
uint64_t FramesChecksum(const SimulatedSequence& s) {
  uint64_t hash = 14695981039346656037ull;
  for (const Image& frame : s.frames) {
    for (float v : frame.voxels) {
      uint32_t bits = 0;
      std::memcpy(&bits, &v, sizeof(bits));
      for (int b = 0; b < 4; ++b) {
        hash ^= (bits >> (8 * b)) & 0xffu;
        hash *= 1099511628211ull;
      }
    }
  }
  return hash;
}

// Checksums of the frames of SmallOptions() on SmallSource(spacing), recorded before
// SimulationOptions::interpolation was added: the default (kLinear) frames must stay
// bit-identical. They depend on the phantom, std::normal_distribution and the trilinear
// arithmetic being bit-reproducible, which holds for one compiler and standard library
// (the development machine's); 4 combinations so a failure says which path changed.
TEST(Simulate, DefaultLinearFramesAreBitIdenticalToBeforeTheCubicOption) {
  struct Recorded {
    double sigma;
    Eigen::Vector3d spacing;
    uint64_t checksum;
  };
  const Recorded recorded[] = {
      {0.0, Eigen::Vector3d(1.0, 1.0, 1.0), 0xc8565d1bf8defe19ull},
      {0.0, Eigen::Vector3d(1.0, 1.25, 0.8), 0xff31152f0ff99833ull},
      {25.0, Eigen::Vector3d(1.0, 1.0, 1.0), 0x24d5d7dc47e47602ull},
      {25.0, Eigen::Vector3d(1.0, 1.25, 0.8), 0xc663be377d28d6daull},
  };
  for (const Recorded& r : recorded) {
    SimulationOptions o = SmallOptions();
    ASSERT_EQ(o.interpolation, SourceInterpolation::kLinear);  // the default
    o.sigma = r.sigma;
    SimulatedSequence s;
    std::string error;
    ASSERT_TRUE(Simulate(SmallSource(r.spacing), o, &s, &error)) << error;
    EXPECT_EQ(FramesChecksum(s), r.checksum)
        << "sigma " << r.sigma << ", spacing " << r.spacing.transpose();
  }
}

// A random 9x8x7 image with float-exact values, for the interpolator's tests.
Image RandomImage(uint64_t seed) {
  ImageGeometry g;
  g.size = Eigen::Vector3i(9, 8, 7);
  Image image(g);
  std::mt19937_64 rng(seed);
  std::uniform_int_distribution<int> value(0, 1020);
  for (float& v : image.voxels) v = 0.25f * static_cast<float>(value(rng));
  return image;
}

TEST(CubicInterpolateValue, ReproducesVoxelsAtIntegerIndices) {
  const Image image = RandomImage(3);
  const Eigen::Vector3i& n = image.geometry.size;
  for (int k = 0; k < n[2]; ++k) {
    for (int j = 0; j < n[1]; ++j) {
      for (int i = 0; i < n[0]; ++i) {
        // Exact: the weights at t = 0 are (0, 1, 0, 0); border voxels included.
        ASSERT_EQ(CubicInterpolateValue(image, Eigen::Vector3d(i, j, k)), image.at(i, j, k))
            << i << " " << j << " " << k;
      }
    }
  }
}

TEST(CubicInterpolateValue, ReproducesQuadraticsInTheInteriorAndConstantsEverywhere) {
  // q has every monomial of degree <= 2; its values at integer indices are multiples of
  // 1/4 below 2^11, exact in float, so the only error is double rounding in the sum.
  constexpr double kDoubleRoundingTolerance = 1e-9;
  const auto q = [](const Eigen::Vector3d& x) {
    return 7.0 + 1.5 * x[0] - 2.0 * x[1] + 0.75 * x[2] + 0.25 * x[0] * x[0] -
           0.5 * x[1] * x[1] + 1.25 * x[2] * x[2] + 0.5 * x[0] * x[1] - 0.75 * x[1] * x[2] +
           x[0] * x[2];
  };
  ImageGeometry g;
  g.size = Eigen::Vector3i(9, 8, 7);
  Image quadratic(g), constant(g, 42.5f);
  for (int k = 0; k < g.size[2]; ++k) {
    for (int j = 0; j < g.size[1]; ++j) {
      for (int i = 0; i < g.size[0]; ++i) {
        quadratic.at(i, j, k) = static_cast<float>(q(Eigen::Vector3d(i, j, k)));
        ASSERT_EQ(static_cast<double>(quadratic.at(i, j, k)), q(Eigen::Vector3d(i, j, k)));
      }
    }
  }
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  const Eigen::Vector3d upper = g.size.cast<double>() - Eigen::Vector3d::Ones();
  for (int trial = 0; trial < 2000; ++trial) {
    // Interior: the 4x4x4 stencil inside the grid, i.e. ijk in [1, size - 2) per axis.
    Eigen::Vector3d interior, anywhere;
    for (int a = 0; a < 3; ++a) {
      interior[a] = 1.0 + (upper[a] - 2.0) * u(rng);
      anywhere[a] = upper[a] * u(rng);
    }
    ASSERT_NEAR(CubicInterpolateValue(quadratic, interior), q(interior), kDoubleRoundingTolerance)
        << interior.transpose();
    ASSERT_NEAR(CubicInterpolateValue(constant, anywhere), 42.5, kDoubleRoundingTolerance)
        << anywhere.transpose();
  }
  // Not a trilinear interpolant in disguise: a cubic term is not reproduced.
  Image cubic(g);
  for (int k = 0; k < g.size[2]; ++k) {
    for (int j = 0; j < g.size[1]; ++j) {
      for (int i = 0; i < g.size[0]; ++i) cubic.at(i, j, k) = static_cast<float>(i * i * i);
    }
  }
  // Keys' error for x^3 is -t(2t - 1)(t - 1) (derived from the weights): at t = 1/4, -3/32.
  EXPECT_NEAR(CubicInterpolateValue(cubic, Eigen::Vector3d(3.25, 3.0, 3.0)),
              3.25 * 3.25 * 3.25 + 3.0 / 32.0,
              kDoubleRoundingTolerance);
}

// A smooth analytic source f(x) = 128 + A sin(k . x + phase), x in world mm, and the bound
// on Keys' error it implies. Keys reproduces quadratics, so along one axis (index units)
// the error at x is -sum_i w_i R_i with R_i the third-order Taylor remainder of f at the
// tap offset d_i: |R_i| <= M3 |d_i|^3 / 6, and max_t sum_i |w_i| |d_i|^3 = 9/16 (at
// t = 1/2), so e_a <= 3/32 M3_a, with M3_a = A |k_a h_a|^3 the third derivative's bound
// along index axis a. The 3-D interpolant is P = Pz Py Px (x innermost), and
// f - Pf = (f - Pz f) + Pz (f - Py f) + Pz Py (f - Px f), with each P's weights summing
// in absolute value to at most 5/4 (at t = 1/2), so |f - Pf| <= e_z + 5/4 e_y + 25/16 e_x.
// Float storage adds at most (5/4)^3 half-ulps of the source (values < 256: 2^-16 each)
// plus one half-ulp of the frame: below 1e-4.
struct SmoothSource {
  double amplitude = 100.0;
  Eigen::Vector3d wave_per_mm = Eigen::Vector3d(0.25, -0.2, 0.3);  // wavelengths 21-31 mm
  double phase = 0.7;

  double operator()(const Eigen::Vector3d& x_mm) const {
    return 128.0 + amplitude * std::sin(wave_per_mm.dot(x_mm) + phase);
  }
  double CubicErrorBound(const Eigen::Vector3d& spacing_mm) const {
    constexpr double kFloatSlack = 1e-4;
    Eigen::Vector3d e;
    for (int a = 0; a < 3; ++a) {
      e[a] = 3.0 / 32.0 * amplitude * std::pow(std::abs(wave_per_mm[a] * spacing_mm[a]), 3);
    }
    return e[2] + 1.25 * e[1] + 1.5625 * e[0] + kFloatSlack;
  }
};

TEST(Simulate, CubicFramesSampleASmoothSourceWithinTheDerivedBound) {
  const SmoothSource f;
  std::vector<Eigen::Vector3d> spacings = {Eigen::Vector3d(1.0, 1.0, 1.0),
                                           Eigen::Vector3d(1.0, 1.25, 0.8)};
  // Under the sanitizers the anisotropic spacing only: the same code on half the voxels.
  if (testing_support::kUnderAddressSanitizer) spacings.erase(spacings.begin());
  for (const Eigen::Vector3d& spacing : spacings) {
    ImageGeometry g;
    g.size = Eigen::Vector3i(80, 80, 80);
    g.spacing_mm = spacing;
    g.origin_mm = -0.5 * Eigen::Vector3d::Constant(79.0).cwiseProduct(spacing);
    Image source(g);
    for (int k = 0; k < 80; ++k) {
      for (int j = 0; j < 80; ++j) {
        for (int i = 0; i < 80; ++i) {
          source.at(i, j, k) = static_cast<float>(f(g.IndexToPhysical(Eigen::Vector3d(i, j, k))));
        }
      }
    }
    const double bound = f.CubicErrorBound(spacing);
    double max_error[2] = {0.0, 0.0};  // linear, cubic
    for (SourceInterpolation interpolation :
         {SourceInterpolation::kLinear, SourceInterpolation::kCubic}) {
      SimulationOptions o = SmallOptions();
      o.interpolation = interpolation;
      o.mask_erosion = 0;
      SimulatedSequence s;
      std::string error;
      ASSERT_TRUE(Simulate(source, o, &s, &error)) << error;
      const ImageGeometry& fg = s.frames[0].geometry;
      int64_t count = 0;
      for (int frame = 0; frame < o.num_frames; ++frame) {
        const Eigen::Isometry3d world_from_frame = s.frame_from_world[frame].inverse();
        for (int k = 0; k < fg.size[2]; ++k) {
          for (int y = 0; y < fg.size[1]; ++y) {
            for (int x = 0; x < fg.size[0]; ++x) {
              if (!s.masks[frame].at(x, y, k)) continue;
              const Eigen::Vector3d x_in_world =
                  world_from_frame * fg.IndexToPhysical(Eigen::Vector3d(x, y, k));
              // The bound holds where the stencil is inside the source (no clamping).
              const Eigen::Vector3d ijk = g.PhysicalToIndex(x_in_world);
              ASSERT_TRUE((ijk.array() >= 1.0).all() && (ijk.array() < 78.0).all())
                  << ijk.transpose();
              const double e = std::abs(s.frames[frame].at(x, y, k) - f(x_in_world));
              double& m = max_error[interpolation == SourceInterpolation::kCubic];
              m = std::max(m, e);
              ++count;
            }
          }
        }
      }
      ASSERT_GT(count, 10000);
    }
    EXPECT_LE(max_error[1], bound) << "spacing " << spacing.transpose();
    // The control: trilinear sampling (error up to (1/8) A sum_a (k_a h_a)^2) breaks the
    // cubic bound, so the test tells the two apart.
    EXPECT_GT(max_error[0], 2.0 * bound) << "spacing " << spacing.transpose();
    std::printf("spacing %s: bound %.4f, max |frame - f|: linear %.4f, cubic %.4f\n",
                spacing[1] == 1.0 ? "1,1,1" : "1,1.25,0.8",
                bound,
                max_error[0],
                max_error[1]);
  }
}

TEST(Simulate, CubicIsDeterministicAndDiffersFromLinearOnlyByInterpolation) {
  const Image source = SmallSource(Eigen::Vector3d::Ones());
  SimulationOptions o = SmallOptions();
  o.sigma = 25.0;
  SimulatedSequence linear, a, b;
  std::string error;
  ASSERT_TRUE(Simulate(source, o, &linear, &error)) << error;
  o.interpolation = SourceInterpolation::kCubic;
  ASSERT_TRUE(Simulate(source, o, &a, &error)) << error;
  ASSERT_TRUE(Simulate(source, o, &b, &error)) << error;
  for (int f = 0; f < o.num_frames; ++f) {
    EXPECT_EQ(a.frames[f].voxels, b.frames[f].voxels) << "frame " << f;
    EXPECT_NE(a.frames[f].voxels, linear.frames[f].voxels) << "frame " << f;
    EXPECT_EQ(a.masks[f].voxels, linear.masks[f].voxels) << "frame " << f;
    EXPECT_TRUE(a.frame_from_world[f].matrix() == linear.frame_from_world[f].matrix());
  }
  // Noise-free cubic frames agree under the ground-truth poses as linear ones do.
  o.sigma = 0.0;
  SimulatedSequence quiet;
  ASSERT_TRUE(Simulate(source, o, &quiet, &error)) << error;
  for (int j = 1; j < o.num_frames; ++j) {
    EXPECT_LT(Compare(quiet, 0, j).mean_abs_difference, kResampleMeanAbsTolerance) << j;
  }
}

TEST(Simulate, InterpolationNames) {
  SourceInterpolation interpolation = SourceInterpolation::kCubic;
  EXPECT_TRUE(StringToSourceInterpolation("linear", &interpolation));
  EXPECT_EQ(interpolation, SourceInterpolation::kLinear);
  EXPECT_TRUE(StringToSourceInterpolation("cubic", &interpolation));
  EXPECT_EQ(interpolation, SourceInterpolation::kCubic);
  for (const char* bad : {"", "Cubic", "linear ", "bspline", "nearest"}) {
    EXPECT_FALSE(StringToSourceInterpolation(bad, &interpolation)) << bad;
    EXPECT_EQ(interpolation, SourceInterpolation::kCubic) << "untouched on failure";
  }
  EXPECT_STREQ(SourceInterpolationToString(SourceInterpolation::kLinear), "linear");
  EXPECT_STREQ(SourceInterpolationToString(SourceInterpolation::kCubic), "cubic");
}

TEST(Simulate, PoseModelNames) {
  PoseModel model = PoseModel::kWalk;
  EXPECT_TRUE(StringToPoseModel("random", &model));
  EXPECT_EQ(model, PoseModel::kRandom);
  EXPECT_TRUE(StringToPoseModel("walk", &model));
  EXPECT_EQ(model, PoseModel::kWalk);
  for (const char* bad : {"", "Walk", "random ", "spiral"}) {
    EXPECT_FALSE(StringToPoseModel(bad, &model)) << bad;
    EXPECT_EQ(model, PoseModel::kWalk) << "untouched on failure";
  }
  EXPECT_STREQ(PoseModelToString(PoseModel::kRandom), "random");
  EXPECT_STREQ(PoseModelToString(PoseModel::kWalk), "walk");
}

TEST(Simulate, ValidateRejectsNonsense) {
  struct Case {
    void (*edit)(SimulationOptions*);
    const char* flag;
  };
  const Case cases[] = {
      {[](SimulationOptions* o) { o->num_frames = 1; }, "num_frames=1"},
      {[](SimulationOptions* o) { o->max_rotation_deg = -1.0; }, "max_rotation_deg"},
      {[](SimulationOptions* o) { o->max_translation_voxels = std::nan(""); },
       "max_translation_voxels"},
      {[](SimulationOptions* o) { o->sigma = -1.0; }, "sigma=-1"},
      {[](SimulationOptions* o) { o->sigma = INFINITY; }, "sigma"},
      {[](SimulationOptions* o) { o->frame_size = Eigen::Vector3i(96, 0, 80); },
       "frame_size=96,0,80"},
      {[](SimulationOptions* o) { o->frame_spacing = -0.5; }, "frame_spacing"},
      {[](SimulationOptions* o) { o->azimuth_deg = 0.0; }, "azimuth_deg"},
      {[](SimulationOptions* o) { o->elevation_deg = 180.0; }, "elevation_deg"},
      {[](SimulationOptions* o) { o->min_depth_voxels = 78.0; }, "min_depth_voxels"},
      {[](SimulationOptions* o) { o->pose_model = static_cast<PoseModel>(7); },
       "pose_model=7"},
      {[](SimulationOptions* o) { o->step_rotation_deg = 181.0; }, "step_rotation_deg=181"},
      {[](SimulationOptions* o) { o->step_translation_voxels = -1.0; },
       "step_translation_voxels=-1"},
      {[](SimulationOptions* o) { o->mask_erosion = -1; }, "mask_erosion=-1"},
      {[](SimulationOptions* o) { o->mask_erosion = 51; }, "mask_erosion=51"},
      {[](SimulationOptions* o) { o->interpolation = static_cast<SourceInterpolation>(7); },
       "interpolation=7: must be linear or cubic"},
      {[](SimulationOptions* o) { o->gain_range = -0.1; },
       "gain_range=-0.1: must be in [0, 0.9]"},
      {[](SimulationOptions* o) { o->gain_range = 0.95; }, "gain_range=0.95"},
      {[](SimulationOptions* o) { o->gain_range = std::nan(""); }, "gain_range=nan"},
      {[](SimulationOptions* o) { o->offset_range = 101.0; },
       "offset_range=101: must be in [0, 100]"},
      {[](SimulationOptions* o) { o->offset_range = -1.0; }, "offset_range=-1"},
      {[](SimulationOptions* o) { o->speckle_looks = -1; },
       "speckle_looks=-1: must be 0 (no speckle) or in [1, 64]"},
      {[](SimulationOptions* o) { o->speckle_looks = 65; }, "speckle_looks=65"},
      {[](SimulationOptions* o) { o->speckle_correlation_voxels = 4.5; },
       "speckle_correlation_voxels=4.5: must be in [0, 4]"},
      {[](SimulationOptions* o) { o->speckle_correlation_voxels = -1.0; },
       "speckle_correlation_voxels=-1"},
      {[](SimulationOptions* o) { o->speckle_world_fraction = 1.5; },
       "speckle_world_fraction=1.5: must be in [0, 1]"},
      {[](SimulationOptions* o) { o->speckle_world_fraction = -0.1; },
       "speckle_world_fraction=-0.1: must be in [0, 1]"},
      {[](SimulationOptions* o) { o->speckle_world_fraction = std::nan(""); },
       "speckle_world_fraction=nan"},
      {[](SimulationOptions* o) { o->speckle_world_fraction = 0.5; },  // no speckle
       "speckle_world_fraction=0.5: needs speckle, but speckle_looks=0"},
      {[](SimulationOptions* o) { o->attenuation_db_per_cm = 11.0; },
       "attenuation_db_per_cm=11: must be in [0, 10]"},
      {[](SimulationOptions* o) { o->attenuation_db_per_cm = INFINITY; },
       "attenuation_db_per_cm=inf"},
      {[](SimulationOptions* o) { o->intensity_mapping = static_cast<IntensityMapping>(7); },
       "intensity_mapping=7: must be none or echo"},
      {[](SimulationOptions* o) { o->echo_reject = 251.0; },
       "echo_reject=251: must be in [0, 250]"},
      {[](SimulationOptions* o) { o->echo_reject = -1.0; }, "echo_reject=-1"},
      {[](SimulationOptions* o) { o->echo_reject = std::nan(""); }, "echo_reject=nan"},
      {[](SimulationOptions* o) { o->echo_edge_sigma_mm = -0.5; },
       "echo_edge_sigma_mm=-0.5: must be in [0, 20]"},
      {[](SimulationOptions* o) { o->echo_edge_sigma_mm = INFINITY; }, "echo_edge_sigma_mm=inf"},
      {[](SimulationOptions* o) { o->echo_edge_weight = 1.5; },
       "echo_edge_weight=1.5: must be in [0, 1]"},
      {[](SimulationOptions* o) { o->echo_edge_weight = -0.1; }, "echo_edge_weight=-0.1"},
  };
  const Image source = SmallSource(Eigen::Vector3d::Ones());
  for (const Case& c : cases) {
    SimulationOptions o;
    std::string error;
    EXPECT_TRUE(o.Validate(&error));
    c.edit(&o);
    EXPECT_FALSE(o.Validate(&error)) << c.flag;
    EXPECT_NE(error.find(c.flag), std::string::npos) << error;
    SimulatedSequence s;
    EXPECT_FALSE(Simulate(source, o, &s, &error)) << c.flag;
  }
}

// --- Ultrasound-like effects (docs/design.md section 6.6) ---

// Float storage of frame values below ~400 (ulp <= 3e-5) and of the speckle field.
using testing_tolerances::kFloatValueTolerance;

SimulationOptions WithAllEffects(SimulationOptions o) {
  o.gain_range = 0.3;
  o.offset_range = 20.0;
  o.speckle_looks = 2;
  o.attenuation_db_per_cm = 3.0;
  return o;
}

TEST(SimulateEffects, OffByDefaultAndExplicitZerosChangeNothing) {
  const SimulationOptions defaults;
  EXPECT_EQ(defaults.gain_range, 0.0);
  EXPECT_EQ(defaults.offset_range, 0.0);
  EXPECT_EQ(defaults.speckle_looks, 0);
  EXPECT_EQ(defaults.attenuation_db_per_cm, 0.0);
  const Image source = SmallSource(Eigen::Vector3d::Ones());
  SimulationOptions o = SmallOptions();
  o.sigma = 25.0;
  SimulatedSequence plain, zeros;
  std::string error;
  ASSERT_TRUE(Simulate(source, o, &plain, &error)) << error;
  o.gain_range = 0.0;
  o.offset_range = 0.0;
  o.speckle_looks = 0;
  o.speckle_correlation_voxels = 2.5;  // unused without looks
  o.attenuation_db_per_cm = 0.0;
  ASSERT_TRUE(Simulate(source, o, &zeros, &error)) << error;
  for (int f = 0; f < o.num_frames; ++f) {
    EXPECT_EQ(plain.frames[f].voxels, zeros.frames[f].voxels) << "frame " << f;
    EXPECT_EQ(plain.gain[f], 1.0);
    EXPECT_EQ(plain.offset[f], 0.0);
  }
  // The bit-for-bit comparison with the simulator before the effects existed is
  // DefaultLinearFramesAreBitIdenticalToBeforeTheCubicOption's recorded checksums.
}

TEST(SimulateEffects, GainAndOffsetMapEveryFrameAndLeaveTheNoiseDrawsAlone) {
  const Image source = SmallSource(Eigen::Vector3d::Ones());
  SimulationOptions o = SmallOptions();  // sigma 0
  o.num_frames = 6;
  SimulatedSequence clean, mapped;
  std::string error;
  ASSERT_TRUE(Simulate(source, o, &clean, &error)) << error;
  SimulationOptions g = o;
  g.gain_range = 0.3;
  g.offset_range = 20.0;
  ASSERT_TRUE(Simulate(source, g, &mapped, &error)) << error;
  const Mask fov = PyramidFieldOfView(clean.frames[0].geometry, o);
  double lowest_gain = 2.0, highest_gain = 0.0;
  int64_t clamped = 0;
  for (int f = 0; f < o.num_frames; ++f) {
    const double gain = mapped.gain[f], offset = mapped.offset[f];
    EXPECT_GE(gain, 0.7) << f;
    EXPECT_LE(gain, 1.3) << f;
    EXPECT_GE(offset, -20.0) << f;
    EXPECT_LE(offset, 20.0) << f;
    lowest_gain = std::min(lowest_gain, gain);
    highest_gain = std::max(highest_gain, gain);
    EXPECT_TRUE(mapped.frame_from_world[f].matrix() == clean.frame_from_world[f].matrix());
    EXPECT_EQ(mapped.masks[f].voxels, clean.masks[f].voxels);
    for (size_t v = 0; v < fov.voxels.size(); ++v) {
      if (!fov.voxels[v]) {
        ASSERT_EQ(mapped.frames[f].voxels[v], 0.0f) << "outside the field of view";
        continue;
      }
      const double expected = gain * clean.frames[f].voxels[v] + offset;
      const double clamp = std::clamp(expected, 0.0, 255.0);
      clamped += clamp != expected;
      ASSERT_NEAR(mapped.frames[f].voxels[v], clamp, kFloatValueTolerance)
          << "frame " << f << " voxel " << v;
    }
  }
  EXPECT_LT(lowest_gain, highest_gain);  // drawn per frame
  EXPECT_GT(clamped, 0) << "offsets below 0 clamp the dark blood pools";

  // With noise: the noise of each voxel is the same draw with and without the gain and
  // offset (they come from their own generator).
  o.sigma = 25.0;
  g.sigma = 25.0;
  SimulatedSequence noisy, noisy_mapped;
  ASSERT_TRUE(Simulate(source, o, &noisy, &error)) << error;
  ASSERT_TRUE(Simulate(source, g, &noisy_mapped, &error)) << error;
  int64_t compared = 0;
  for (int f = 0; f < o.num_frames; ++f) {
    EXPECT_EQ(noisy_mapped.gain[f], mapped.gain[f]);
    EXPECT_EQ(noisy_mapped.offset[f], mapped.offset[f]);
    for (size_t v = 0; v < fov.voxels.size(); ++v) {
      const double a = noisy.frames[f].voxels[v], b = noisy_mapped.frames[f].voxels[v];
      if (!fov.voxels[v] || a <= 0.0 || a >= 255.0 || b <= 0.0 || b >= 255.0) continue;
      const double noise = a - clean.frames[f].voxels[v];
      const double noise_mapped =
          b - (mapped.gain[f] * clean.frames[f].voxels[v] + mapped.offset[f]);
      ASSERT_NEAR(noise_mapped, noise, kFloatValueTolerance) << "frame " << f << " voxel " << v;
      ++compared;
    }
  }
  EXPECT_GT(compared, 20000);

  // Each effect's draws are its own: the gains and offsets do not change when the speckle
  // and the attenuation are on, nor does the gain when the offset is off.
  SimulatedSequence all, gain_only;
  ASSERT_TRUE(Simulate(source, WithAllEffects(o), &all, &error)) << error;
  SimulationOptions only = o;
  only.gain_range = 0.3;
  ASSERT_TRUE(Simulate(source, only, &gain_only, &error)) << error;
  EXPECT_EQ(all.gain, noisy_mapped.gain);
  EXPECT_EQ(all.offset, noisy_mapped.offset);
  EXPECT_EQ(gain_only.gain, noisy_mapped.gain);
  EXPECT_EQ(gain_only.offset, std::vector<double>(o.num_frames, 0.0));
}

TEST(SimulateEffects, CorrectionsPutEveryFrameOnFrame0sScale) {
  // A source linear in the index, so frame 0's value at any world point is known: with
  // sigma 0, frame i = g_i L(x) + o_i, and the corrections must map it to g_0 L(x) + o_0.
  ImageGeometry grid;
  grid.size = Eigen::Vector3i(80, 80, 80);
  grid.origin_mm = Eigen::Vector3d::Constant(-39.5);
  Image source(grid);
  const auto linear = [](const Eigen::Vector3d& ijk) {
    return 20.0 + 0.9 * ijk[0] + 0.5 * ijk[1] + 0.7 * ijk[2];
  };
  for (int k = 0; k < 80; ++k) {
    for (int j = 0; j < 80; ++j) {
      for (int i = 0; i < 80; ++i) source.at(i, j, k) = linear(Eigen::Vector3d(i, j, k));
    }
  }
  SimulationOptions o = SmallOptions();
  o.gain_range = 0.4;
  o.offset_range = 30.0;
  SimulatedSequence s;
  std::string error;
  ASSERT_TRUE(Simulate(source, o, &s, &error)) << error;
  std::vector<double> gain, offset;
  Frame0IntensityCorrections(s.gain, s.offset, &gain, &offset);
  ASSERT_EQ(gain.size(), 4u);
  EXPECT_EQ(gain[0], 1.0);  // the gauge, exactly
  EXPECT_EQ(offset[0], 0.0);
  const ImageGeometry& fg = s.frames[0].geometry;
  for (int f = 1; f < o.num_frames; ++f) {
    EXPECT_DOUBLE_EQ(gain[f], s.gain[0] / s.gain[f]);
    EXPECT_DOUBLE_EQ(offset[f], s.offset[0] - s.gain[0] * s.offset[f] / s.gain[f]);
    const Eigen::Isometry3d world_from_frame = s.frame_from_world[f].inverse();
    int64_t count = 0;
    for (int k = 0; k < fg.size[2]; k += 2) {
      for (int y = 0; y < fg.size[1]; y += 2) {
        for (int x = 0; x < fg.size[0]; x += 2) {
          const double value = s.frames[f].at(x, y, k);
          if (!s.masks[f].at(x, y, k) || value <= 0.0 || value >= 255.0) continue;
          const double seen_by_frame0 =
              s.gain[0] *
                  linear(grid.PhysicalToIndex(world_from_frame *
                                              fg.IndexToPhysical(Eigen::Vector3d(x, y, k)))) +
              s.offset[0];
          ASSERT_NEAR(gain[f] * value + offset[f], seen_by_frame0, kFloatValueTolerance)
              << "frame " << f << " voxel " << x << " " << y << " " << k;
          ++count;
        }
      }
    }
    EXPECT_GT(count, 500) << "frame " << f;
  }
}

// Mean, variance and the correlation of voxels `lag` apart along `axis` of the field's
// voxels, over the whole grid.
struct FieldStatistics {
  double mean = 0.0, variance = 0.0;
};
FieldStatistics Statistics(const Image& field) {
  double sum = 0.0, sum2 = 0.0;
  for (float v : field.voxels) {
    sum += v;
    sum2 += double{v} * v;
  }
  FieldStatistics st;
  st.mean = sum / field.voxels.size();
  st.variance = sum2 / field.voxels.size() - st.mean * st.mean;
  return st;
}
double Correlation(const Image& field, int axis, int lag) {
  const Eigen::Vector3i& n = field.geometry.size;
  const FieldStatistics st = Statistics(field);
  double sum = 0.0;
  int64_t count = 0;
  for (int k = 0; k < n[2]; ++k) {
    for (int j = 0; j < n[1]; ++j) {
      for (int i = 0; i < n[0]; ++i) {
        Eigen::Vector3i other(i, j, k);
        other[axis] += lag;
        if (other[axis] >= n[axis]) continue;
        sum += (field.at(i, j, k) - st.mean) * (field.at(other[0], other[1], other[2]) - st.mean);
        ++count;
      }
    }
  }
  return sum / count / st.variance;
}

TEST(SimulateEffects, SpeckleHasMeanOneVarianceOneOverLooksAndItsCorrelation) {
  ImageGeometry g;
  g.size = Eigen::Vector3i(64, 64, 64);
  // 262144 voxels, about 16700 independent ones at a correlation of 1 voxel: standard
  // errors about 0.8% of the mean and 2% of the variance with one look (exponential), less
  // with more looks, and 0.01 on a correlation.
  constexpr double kMeanTolerance = 0.03;
  constexpr double kRelativeVarianceTolerance = 0.1;
  constexpr double kCorrelationTolerance = 0.05;
  for (int looks : {1, 4}) {
    SimulationOptions o;
    o.speckle_looks = looks;
    const Image speckle = SpeckleField(g, o, 0, 0);
    ASSERT_EQ(speckle.geometry.size, g.size);
    EXPECT_GE(*std::min_element(speckle.voxels.begin(), speckle.voxels.end()), 0.0f);
    const FieldStatistics st = Statistics(speckle);
    EXPECT_NEAR(st.mean, 1.0, kMeanTolerance) << looks << " looks";
    EXPECT_NEAR(st.variance * looks, 1.0, kRelativeVarianceTolerance) << looks << " looks";
    // Correlation about exp(-d^2 / 2) at a lag of d voxels (c = 1), along every axis.
    for (int axis = 0; axis < 3; ++axis) {
      EXPECT_NEAR(Correlation(speckle, axis, 1), std::exp(-0.5), kCorrelationTolerance)
          << looks << " looks, axis " << axis;
      EXPECT_NEAR(Correlation(speckle, axis, 2), std::exp(-2.0), kCorrelationTolerance)
          << looks << " looks, axis " << axis;
      EXPECT_NEAR(Correlation(speckle, axis, 4), 0.0, kCorrelationTolerance)
          << looks << " looks, axis " << axis;
    }
  }
  // The correlation length follows --speckle_correlation_voxels; 0: independent voxels.
  SimulationOptions o;
  o.speckle_looks = 1;
  o.speckle_correlation_voxels = 2.0;
  EXPECT_NEAR(Correlation(SpeckleField(g, o, 0, 0), 0, 1), std::exp(-0.125), kCorrelationTolerance);
  o.speckle_correlation_voxels = 0.0;
  const Image white = SpeckleField(g, o, 0, 0);
  EXPECT_NEAR(Statistics(white).mean, 1.0, kMeanTolerance);
  EXPECT_NEAR(Statistics(white).variance, 1.0, kRelativeVarianceTolerance);
  EXPECT_NEAR(Correlation(white, 0, 1), 0.0, kCorrelationTolerance);
}

TEST(SimulateEffects, SpeckleIsPerFrameSeededAndIndependentOfThreads) {
  ImageGeometry g;
  g.size = Eigen::Vector3i(23, 17, 19);  // odd sizes, so slices split unevenly
  SimulationOptions o;
  o.speckle_looks = 3;
  o.speckle_correlation_voxels = 1.5;
  const Image one = SpeckleField(g, o, 2, 1);
  for (int threads : {2, 3, 0}) {
    EXPECT_EQ(SpeckleField(g, o, 2, threads).voxels, one.voxels) << threads << " threads";
  }
  EXPECT_NE(SpeckleField(g, o, 3, 1).voxels, one.voxels) << "another frame, another draw";
  o.seed = 2;
  EXPECT_NE(SpeckleField(g, o, 2, 1).voxels, one.voxels) << "another seed, another draw";
}

TEST(SimulateEffects, SpeckleMultipliesTheFramesInsideTheFieldOfView) {
  // A constant source: each frame is the constant times its speckle field, clamped at 255.
  ImageGeometry grid;
  grid.size = Eigen::Vector3i(80, 80, 80);
  grid.origin_mm = Eigen::Vector3d::Constant(-39.5);
  const Image flat(grid, 60.0f);
  SimulationOptions o = SmallOptions();
  o.speckle_looks = 1;
  SimulatedSequence s, plain;
  std::string error;
  ASSERT_TRUE(Simulate(flat, o, &s, &error)) << error;
  const ImageGeometry& fg = s.frames[0].geometry;
  const Mask fov = PyramidFieldOfView(fg, o);
  int64_t clamped = 0;
  for (int f = 0; f < o.num_frames; ++f) {
    const Image speckle = SpeckleField(fg, o, f, 1);
    for (size_t v = 0; v < fov.voxels.size(); ++v) {
      const double expected = fov.voxels[v] ? std::min(60.0 * speckle.voxels[v], 255.0) : 0.0;
      clamped += fov.voxels[v] && expected == 255.0;
      ASSERT_NEAR(s.frames[f].voxels[v], expected, kFloatValueTolerance)
          << "frame " << f << " voxel " << v;
    }
  }
  EXPECT_GT(clamped, 0) << "one look exceeds 255 / 60 at about 1.4% of the voxels";
  // Poses and noise draws are untouched (the noise-free frames are the plain ones times the
  // speckle, above; the poses here).
  o.speckle_looks = 0;
  ASSERT_TRUE(Simulate(flat, o, &plain, &error)) << error;
  for (int f = 0; f < o.num_frames; ++f) {
    EXPECT_TRUE(s.frame_from_world[f].matrix() == plain.frame_from_world[f].matrix());
  }
}

TEST(SimulateEffects, AttenuationFollowsTheDistanceFromTheApex) {
  const Image source = SmallSource(Eigen::Vector3d::Ones());
  for (double spacing_mm : {0.0, 0.5}) {  // 0: the source's 1 mm
    SimulationOptions o = SmallOptions();
    o.frame_spacing = spacing_mm;
    SimulatedSequence plain, attenuated;
    std::string error;
    ASSERT_TRUE(Simulate(source, o, &plain, &error)) << error;
    o.attenuation_db_per_cm = 6.0;
    ASSERT_TRUE(Simulate(source, o, &attenuated, &error)) << error;
    const ImageGeometry& g = plain.frames[0].geometry;
    const double h_cm = 0.1 * g.spacing_mm[0];
    const double cx = 0.5 * (g.size[0] - 1), cy = 0.5 * (g.size[1] - 1);
    // A few voxels on the axis, off axis and at a corner of the far face.
    const Eigen::Vector3i voxels[] = {{16, 16, 4}, {15, 16, 10}, {10, 20, 20}, {0, 0, 31}};
    for (int f = 0; f < o.num_frames; ++f) {
      for (const Eigen::Vector3i& v : voxels) {
        const double before = plain.frames[f].at(v[0], v[1], v[2]);
        ASSERT_GT(before, 1.0) << v.transpose();  // inside the field of view, not black
        const double depth = v[2];
        const double r_cm = h_cm * std::sqrt((v[0] - cx) * (v[0] - cx) +
                                             (v[1] - cy) * (v[1] - cy) + depth * depth);
        const double expected = std::pow(10.0, -6.0 * r_cm / 20.0);
        EXPECT_NEAR(attenuated.frames[f].at(v[0], v[1], v[2]) / before, expected, 1e-5)
            << "frame " << f << " voxel " << v.transpose() << ", spacing " << g.spacing_mm[0];
      }
    }
  }
}

TEST(SimulateEffects, AllEffectsTogetherAreDeterministicAndInTheirOrder) {
  // Source x attenuation x speckle, x gain + offset, then noise and the clamp.
  const Image source = SmallSource(Eigen::Vector3d::Ones());
  SimulationOptions o = WithAllEffects(SmallOptions());
  SimulatedSequence a, b, clean;
  std::string error;
  ASSERT_TRUE(Simulate(source, o, &a, &error)) << error;
  ASSERT_TRUE(Simulate(source, o, &b, &error)) << error;
  SimulationOptions none = SmallOptions();
  ASSERT_TRUE(Simulate(source, none, &clean, &error)) << error;
  const ImageGeometry& g = a.frames[0].geometry;
  const Mask fov = PyramidFieldOfView(g, o);
  SimulationOptions attenuation_only = none;
  attenuation_only.attenuation_db_per_cm = o.attenuation_db_per_cm;
  SimulatedSequence attenuated;
  ASSERT_TRUE(Simulate(source, attenuation_only, &attenuated, &error)) << error;
  for (int f = 0; f < o.num_frames; ++f) {
    EXPECT_EQ(a.frames[f].voxels, b.frames[f].voxels) << "frame " << f;
    const Image speckle = SpeckleField(g, o, f, 1);
    for (size_t v = 0; v < fov.voxels.size(); ++v) {
      if (!fov.voxels[v]) continue;
      const double expected = std::clamp(
          a.gain[f] * attenuated.frames[f].voxels[v] * speckle.voxels[v] + a.offset[f], 0.0, 255.0);
      ASSERT_NEAR(a.frames[f].voxels[v], expected, kFloatValueTolerance)
          << "frame " << f << " voxel " << v;
    }
  }
}

// --- World-fixed speckle (SimulationOptions::speckle_world_fraction, SpeckleFields) ---

// The world-speckle tests' frames on a 64^3 grid with a wide pyramid (150 degrees, from
// depth 0), so that most voxels are in the field of view: frame 0 rotated by 3 degrees and
// shifted by a fraction of a voxel, frame 1 rotated by a further 5 degrees about another
// axis through the grid's centre and shifted by (3, -2, 4.4) voxels. Neither grid is
// aligned with the world lattice, so their voxels sample the world field at every
// sub-voxel offset (the variance normalisation matters everywhere).
ImageGeometry WorldSpeckleGrid() {
  ImageGeometry g;
  g.size = Eigen::Vector3i(64, 64, 64);
  return g;
}
SimulationOptions WorldSpeckleOptions(int looks, double world_fraction) {
  SimulationOptions o;
  o.azimuth_deg = 150.0;
  o.elevation_deg = 150.0;
  o.min_depth_voxels = 0.0;
  o.speckle_looks = looks;
  o.speckle_world_fraction = world_fraction;
  return o;
}
std::vector<Eigen::Isometry3d> WorldSpecklePoses(const ImageGeometry& g) {
  const Eigen::Vector3d center =
      g.IndexToPhysical(0.5 * (g.size.cast<double>() - Eigen::Vector3d::Ones()));
  const auto about_center = [&](double degrees,
                                const Eigen::Vector3d& axis,
                                const Eigen::Vector3d& shift_voxels) {
    return Eigen::Isometry3d(Eigen::Translation3d(center + shift_voxels) *
                             Eigen::AngleAxisd(degrees * M_PI / 180.0, axis.normalized()) *
                             Eigen::Translation3d(-center));
  };
  const Eigen::Isometry3d world_from_frame0 =
      about_center(3.0, Eigen::Vector3d(1.0, 2.0, 0.5), Eigen::Vector3d(0.3, -0.45, 0.2));
  const Eigen::Isometry3d world_from_frame1 =
      about_center(5.0, Eigen::Vector3d(-0.5, 1.0, 1.5), Eigen::Vector3d(3.0, -2.0, 4.4)) *
      world_from_frame0;
  return {world_from_frame0.inverse(), world_from_frame1.inverse()};
}

// Mean and variance of `field` over the voxels of `mask`.
FieldStatistics MaskedStatistics(const Image& field, const Mask& mask) {
  double sum = 0.0, sum2 = 0.0;
  int64_t count = 0;
  for (size_t v = 0; v < field.voxels.size(); ++v) {
    if (!mask.voxels[v]) continue;
    sum += field.voxels[v];
    sum2 += double{field.voxels[v]} * field.voxels[v];
    ++count;
  }
  FieldStatistics st;
  st.mean = sum / count;
  st.variance = sum2 / count - st.mean * st.mean;
  return st;
}

// The correlation of two frames' speckle at the world points both observe: each
// field-of-view voxel of frame 0 is paired with the field-of-view voxel of frame 1 nearest
// to its world point (up to half a voxel per axis away). `all` is over every pair, `close`
// over the pairs at most kClosePairVoxels apart, which see nearly one world point.
constexpr double kClosePairVoxels = 0.25;
struct CrossFrame {
  double all = 0.0, close = 0.0;
  int64_t all_pairs = 0, close_pairs = 0;
};
CrossFrame CrossFrameCorrelation(const std::vector<Image>& fields,
                                 const std::vector<Eigen::Isometry3d>& frame_from_world,
                                 const Mask& fov) {
  const ImageGeometry& g = fields[0].geometry;
  const Eigen::Isometry3d frame1_from_frame0 = frame_from_world[1] * frame_from_world[0].inverse();
  struct Sums {
    double a = 0.0, b = 0.0, aa = 0.0, bb = 0.0, ab = 0.0;
    int64_t count = 0;
    void Add(double x, double y) {
      a += x;
      b += y;
      aa += x * x;
      bb += y * y;
      ab += x * y;
      ++count;
    }
    double Correlation() const {
      const double ma = a / count, mb = b / count;
      return (ab / count - ma * mb) / std::sqrt((aa / count - ma * ma) * (bb / count - mb * mb));
    }
  } all, close;
  for (int k = 0; k < g.size[2]; ++k) {
    for (int j = 0; j < g.size[1]; ++j) {
      for (int i = 0; i < g.size[0]; ++i) {
        if (!fov.at(i, j, k)) continue;
        const Eigen::Vector3d y =
            g.PhysicalToIndex(frame1_from_frame0 * g.IndexToPhysical(Eigen::Vector3d(i, j, k)));
        const Eigen::Vector3d nearest = y.array().round();
        if ((nearest.array() < 0.0).any() ||
            (nearest.array() > g.size.cast<double>().array() - 1.0).any()) {
          continue;
        }
        const Eigen::Vector3i n = nearest.cast<int>();
        if (!fov.at(n[0], n[1], n[2])) continue;
        const double a = fields[0].at(i, j, k), b = fields[1].at(n[0], n[1], n[2]);
        all.Add(a, b);
        if ((y - nearest).norm() <= kClosePairVoxels) close.Add(a, b);
      }
    }
  }
  CrossFrame c;
  c.all = all.Correlation();
  c.close = close.Correlation();
  c.all_pairs = all.count;
  c.close_pairs = close.count;
  return c;
}

// Checksums (FramesChecksum) of SmallOptions() with sigma 25 and every effect on
// (WorldFractionChecksumOptions) on SmallSource(1 mm), recorded with the simulator before
// speckle_world_fraction existed: at 0 the speckle must stay bit-identical. Same caveat as
// DefaultLinearFramesAreBitIdenticalToBeforeTheCubicOption (one compiler and library).
SimulationOptions WorldFractionChecksumOptions(int looks, double correlation_voxels) {
  SimulationOptions o = SmallOptions();
  o.sigma = 25.0;
  o.gain_range = 0.3;
  o.offset_range = 20.0;
  o.attenuation_db_per_cm = 3.0;
  o.speckle_looks = looks;
  o.speckle_correlation_voxels = correlation_voxels;
  return o;
}

TEST(SimulateWorldSpeckle, ZeroWorldFractionIsBitIdenticalToBefore) {
  struct Recorded {
    int looks;
    double correlation_voxels;
    uint64_t checksum;
  };
  const Recorded recorded[] = {
      {1, 1.0, 0x301a69dc9d439906ull},
      {3, 0.0, 0x0f9a2c550127fe62ull},
      {3, 2.5, 0x55d99b415aee51d8ull},
  };
  const Image source = SmallSource(Eigen::Vector3d::Ones());
  for (const Recorded& r : recorded) {
    SimulationOptions o = WorldFractionChecksumOptions(r.looks, r.correlation_voxels);
    ASSERT_EQ(o.speckle_world_fraction, 0.0);  // the default
    SimulatedSequence s;
    std::string error;
    ASSERT_TRUE(Simulate(source, o, &s, &error)) << error;
    EXPECT_EQ(FramesChecksum(s), r.checksum)
        << r.looks << " looks, correlation " << r.correlation_voxels;
  }
  // SpeckleFields at 0 is SpeckleField frame by frame.
  const ImageGeometry g = WorldSpeckleGrid();
  const SimulationOptions o = WorldSpeckleOptions(2, 0.0);
  const std::vector<Image> fields = SpeckleFields(g, WorldSpecklePoses(g), o, 0);
  ASSERT_EQ(fields.size(), 2u);
  for (int f = 0; f < 2; ++f) EXPECT_EQ(fields[f].voxels, SpeckleField(g, o, f, 0).voxels) << f;
}

TEST(SimulateWorldSpeckle, WorldGridCoversEveryFieldOfViewOnTheWorldLattice) {
  // Under the sanitizers a 32^3 frame grid: the same rule checked on an eighth of the voxels.
  ImageGeometry g = WorldSpeckleGrid();
  g.size = Eigen::Vector3i::Constant(testing_support::FullUnlessSanitized(64, 32));
  const std::vector<Eigen::Isometry3d> poses = WorldSpecklePoses(g);
  for (const SimulationOptions& o : {WorldSpeckleOptions(1, 0.5), SmallOptions()}) {
    const ImageGeometry world = SpeckleWorldGrid(g, poses, o);
    EXPECT_TRUE(world.direction.isIdentity());
    EXPECT_EQ(world.spacing_mm, g.spacing_mm);
    const Mask fov = PyramidFieldOfView(g, o);
    // The continuous world-grid indices of the voxel centres: inside [0, size - 1], and the
    // box is the smallest on the lattice (each face less than one voxel past a centre).
    Eigen::Vector3d lo = Eigen::Vector3d::Constant(1e9), hi = -lo;
    for (const Eigen::Isometry3d& frame_from_world : poses) {
      for (int k = 0; k < g.size[2]; ++k) {
        for (int j = 0; j < g.size[1]; ++j) {
          for (int i = 0; i < g.size[0]; ++i) {
            if (!fov.at(i, j, k)) continue;
            const Eigen::Vector3d u = world.PhysicalToIndex(
                frame_from_world.inverse() * g.IndexToPhysical(Eigen::Vector3d(i, j, k)));
            lo = lo.cwiseMin(u);
            hi = hi.cwiseMax(u);
          }
        }
      }
    }
    for (int a = 0; a < 3; ++a) {
      EXPECT_NEAR(world.origin_mm[a] / world.spacing_mm[a],
                  std::round(world.origin_mm[a] / world.spacing_mm[a]),
                  1e-9)
          << "on the lattice, axis " << a;
      EXPECT_GE(lo[a], -1e-9) << a;
      EXPECT_LT(lo[a], 1.0) << a;
      EXPECT_LE(hi[a], world.size[a] - 1 + 1e-9) << a;
      EXPECT_GT(hi[a], world.size[a] - 2.0) << a;
    }
  }
}

TEST(SimulateWorldSpeckle, KeepsMeanOneAndVarianceOneOverLooks) {
  DSR_SKIP_UNDER_SANITIZER("statistics over 8 x 2 speckle fields of 237000 voxels: run by the "
                           "Release pass; SpeckleFields runs under the sanitizers in "
                           "IsIndependentOfThreadsAndKeepsThePerFrameDraws");
  // Over the ~237000 field-of-view voxels of frame 1 (rotated against the world lattice):
  // as SpeckleHasMeanOneVarianceOneOverLooksAndItsCorrelation, about 15000 independent
  // values at c = 1, so standard errors about 0.8% of the mean and 2% of the variance
  // with one look, less with four and at c = 0. Without the per-sample normalisation the
  // world part's mean would be E[V] = (2/3 + r1/3)^3: 0.80 at c = 1, 0.30 at c = 0.
  constexpr double kMeanTolerance = 0.03;
  constexpr double kRelativeVarianceTolerance = 0.1;
  const ImageGeometry g = WorldSpeckleGrid();
  const std::vector<Eigen::Isometry3d> poses = WorldSpecklePoses(g);
  for (double c : {1.0, 0.0}) {
    for (int looks : {1, 4}) {
      for (double rho : {0.5, 1.0}) {
        SimulationOptions o = WorldSpeckleOptions(looks, rho);
        o.speckle_correlation_voxels = c;
        const Mask fov = PyramidFieldOfView(g, o);
        ASSERT_GT(CountInside(fov), 200000);
        const std::vector<Image> fields = SpeckleFields(g, poses, o, 0);
        ASSERT_EQ(fields.size(), 2u);
        for (int f = 0; f < 2; ++f) {
          EXPECT_GE(*std::min_element(fields[f].voxels.begin(), fields[f].voxels.end()), 0.0f);
          const FieldStatistics st = MaskedStatistics(fields[f], fov);
          EXPECT_NEAR(st.mean, 1.0, kMeanTolerance)
              << "c " << c << ", " << looks << " looks, rho " << rho << ", frame " << f;
          EXPECT_NEAR(st.variance * looks, 1.0, kRelativeVarianceTolerance)
              << "c " << c << ", " << looks << " looks, rho " << rho << ", frame " << f;
        }
      }
    }
  }
}

TEST(SimulateWorldSpeckle, FramesShareTheSquareOfTheWorldFraction) {
  DSR_SKIP_UNDER_SANITIZER("correlations over 200000 voxel pairs of 3 speckle field pairs: "
                           "run by the Release pass; SpeckleFields runs under the sanitizers "
                           "in IsIndependentOfThreadsAndKeepsThePerFrameDraws");
  // Frames 0 and 1 of WorldSpecklePoses: 5 degrees and about 5.7 voxels apart. At one world
  // point the intensities of one look correlate by |rho k|^2, k the world part's complex
  // correlation between the two sample points (1 at one point), whatever the looks.
  // Close pairs (<= 0.25 voxel apart, ~12900 pairs): k^2 >= exp(-0.25^2 / 2) = 0.97 at
  // c = 1. Over seeds 1-10 with 4 looks the close correlation was 0.983-0.985 at rho = 1,
  // 0.228-0.279 at 0.5 and -0.009-0.033 at 0 (standard deviation 0.016: the pairs come in
  // clusters, about 2500 independent ones), so 0.06 is ~4 standard deviations. All pairs
  // (~203000, up to 0.87 voxel apart, standard error ~0.005): the correlation is rho^2
  // times the rho = 1 one (0.896-0.898), checked to 0.02.
  constexpr double kCloseTolerance = 0.06;
  constexpr double kAllTolerance = 0.02;
  const ImageGeometry g = WorldSpeckleGrid();
  const std::vector<Eigen::Isometry3d> poses = WorldSpecklePoses(g);
  const Mask fov = PyramidFieldOfView(g, WorldSpeckleOptions(4, 0.0));
  const CrossFrame shared = CrossFrameCorrelation(
      SpeckleFields(g, poses, WorldSpeckleOptions(4, 1.0), 0), poses, fov);
  EXPECT_GT(shared.close_pairs, 10000);
  EXPECT_GT(shared.all_pairs, 150000);
  EXPECT_GT(shared.close, 0.95);
  EXPECT_GT(shared.all, 0.85);
  for (double rho : {0.0, 0.5}) {
    const CrossFrame c = CrossFrameCorrelation(
        SpeckleFields(g, poses, WorldSpeckleOptions(4, rho), 0), poses, fov);
    EXPECT_NEAR(c.close, rho * rho, kCloseTolerance) << "rho " << rho;
    EXPECT_NEAR(c.all, rho * rho * shared.all, kAllTolerance) << "rho " << rho;
  }
}

TEST(SimulateWorldSpeckle, IsIndependentOfThreadsAndKeepsThePerFrameDraws) {
  ImageGeometry g;
  g.size = Eigen::Vector3i(23, 17, 19);  // odd sizes, so slices split unevenly
  std::vector<Eigen::Isometry3d> poses = WorldSpecklePoses(g);
  poses.push_back(poses[1] * Eigen::Translation3d(1.3, 0.0, -2.1));
  for (double rho : {0.6, 1.0}) {  // 1: no per-frame field at all
    SimulationOptions o = WorldSpeckleOptions(3, rho);
    o.speckle_correlation_voxels = 1.5;
    const std::vector<Image> one = SpeckleFields(g, poses, o, 1);
    ASSERT_EQ(one.size(), 3u);
    for (int threads : {2, 3, 0}) {
      const std::vector<Image> many = SpeckleFields(g, poses, o, threads);
      for (int f = 0; f < 3; ++f) {
        EXPECT_EQ(many[f].voxels, one[f].voxels) << "rho " << rho << ", " << threads
                                                 << " threads, frame " << f;
      }
    }
    o.seed = 2;
    EXPECT_NE(SpeckleFields(g, poses, o, 1)[0].voxels, one[0].voxels) << "another seed";
  }
  // A tiny world fraction barely moves the per-frame speckle in the field of view (the
  // per-frame draws are today's: z = 1e-5 zW + (1 - 5e-11) z_i changes s by ~1e-5 of its
  // size) and leaves 1 outside it.
  SimulationOptions o = WorldSpeckleOptions(3, 1e-10);
  o.azimuth_deg = o.elevation_deg = 75.0;
  const Mask fov = PyramidFieldOfView(g, o);
  ASSERT_GT(CountInside(fov), 0);
  ASSERT_LT(CountInside(fov), g.NumVoxels());
  const std::vector<Image> tiny = SpeckleFields(g, poses, o, 0);
  o.speckle_world_fraction = 0.0;
  for (int f = 0; f < 3; ++f) {
    const Image alone = SpeckleField(g, o, f, 0);
    for (size_t v = 0; v < alone.voxels.size(); ++v) {
      if (!fov.voxels[v]) {
        ASSERT_EQ(tiny[f].voxels[v], 1.0f) << "frame " << f << " voxel " << v;
        continue;
      }
      ASSERT_NEAR(tiny[f].voxels[v], alone.voxels[v], 1e-3 * (1.0 + alone.voxels[v]))
          << "frame " << f << " voxel " << v;
    }
  }
}

TEST(SimulateWorldSpeckle, SimulateAppliesItAndLeavesTheOtherDrawsAlone) {
  // A constant source: frame = clamp(g_i 60 s_i + o_i + n), s_i = SpeckleFields at the
  // drawn poses. The poses, gains, offsets and noise draws are those of the world fraction
  // 0 run (each voxel's noise: frame minus its noise-free value, where nothing clamps).
  ImageGeometry grid;
  grid.size = Eigen::Vector3i(80, 80, 80);
  grid.origin_mm = Eigen::Vector3d::Constant(-39.5);
  const Image flat(grid, 60.0f);
  SimulationOptions o = SmallOptions();
  o.sigma = 10.0;
  o.speckle_looks = 2;
  o.gain_range = 0.2;
  o.offset_range = 5.0;
  o.speckle_world_fraction = 0.7;
  SimulatedSequence world, plain;
  std::string error;
  ASSERT_TRUE(Simulate(flat, o, &world, &error)) << error;
  SimulationOptions p = o;
  p.speckle_world_fraction = 0.0;
  ASSERT_TRUE(Simulate(flat, p, &plain, &error)) << error;
  const ImageGeometry& fg = world.frames[0].geometry;
  const Mask fov = PyramidFieldOfView(fg, o);
  const std::vector<Image> world_fields = SpeckleFields(fg, world.frame_from_world, o, 1);
  const std::vector<Image> plain_fields = SpeckleFields(fg, plain.frame_from_world, p, 1);
  int64_t compared = 0;
  for (int f = 0; f < o.num_frames; ++f) {
    EXPECT_TRUE(world.frame_from_world[f].matrix() == plain.frame_from_world[f].matrix());
    EXPECT_EQ(world.gain[f], plain.gain[f]);
    EXPECT_EQ(world.offset[f], plain.offset[f]);
    EXPECT_NE(world_fields[f].voxels, plain_fields[f].voxels);
    for (size_t v = 0; v < fov.voxels.size(); ++v) {
      if (!fov.voxels[v]) {
        ASSERT_EQ(world.frames[f].voxels[v], 0.0f);
        continue;
      }
      const double a = world.frames[f].voxels[v], b = plain.frames[f].voxels[v];
      if (a <= 0.0 || a >= 255.0 || b <= 0.0 || b >= 255.0) continue;
      const double noise_world =
          a - (world.gain[f] * 60.0 * world_fields[f].voxels[v] + world.offset[f]);
      const double noise_plain =
          b - (plain.gain[f] * 60.0 * plain_fields[f].voxels[v] + plain.offset[f]);
      ASSERT_NEAR(noise_world, noise_plain, kFloatValueTolerance)
          << "frame " << f << " voxel " << v;
      ASSERT_LT(std::abs(noise_world), 6.0 * o.sigma);
      ++compared;
    }
  }
  EXPECT_GT(compared, 20000);
}

// --- The echo-like intensity mapping (intensity_mapping; its tests: echo_mapping_test.cc) ---

// bench/protocols.sh's us_flat at SmallOptions()' scale (smaller walk steps): walk poses,
// noise sigma 15, speckle of 4 looks with world fraction 0.8.
void UsFlatOptions(SimulationOptions* o) {
  o->pose_model = PoseModel::kWalk;
  o->step_rotation_deg = 4.0;
  o->step_translation_voxels = 3.0;
  o->sigma = 15.0;
  o->speckle_looks = 4;
  o->speckle_world_fraction = 0.8;
}

// bench/protocols.sh's us: us_flat plus attenuation, gain and offset.
void UsOptions(SimulationOptions* o) {
  UsFlatOptions(o);
  o->attenuation_db_per_cm = 0.5;
  o->gain_range = 0.15;
  o->offset_range = 10.0;
}

// Checksums (FramesChecksum) of SmallOptions() with the bench's walk poses and ultrasound
// effects (bench/protocols.sh: us, us_flat) and with cubic sampling of an anisotropic
// source, recorded with the simulator before intensity_mapping existed: its default (kNone)
// must leave every sequence bit for bit as it was. Same caveat as
// DefaultLinearFramesAreBitIdenticalToBeforeTheCubicOption (one compiler and library).
TEST(SimulateEchoMapping, NoneIsBitIdenticalToBefore) {
  struct Recorded {
    const char* name;
    void (*edit)(SimulationOptions*);
    Eigen::Vector3d spacing;
    uint64_t checksum;
  };
  const Recorded recorded[] = {
      {"us", UsOptions, Eigen::Vector3d(1.0, 1.0, 1.0), 0xf9e42ceabf35c609ull},
      {"us_flat", UsFlatOptions, Eigen::Vector3d(1.0, 1.0, 1.0), 0xf941e7639e628715ull},
      {"cubic, anisotropic",
       [](SimulationOptions* o) {
         o->sigma = 25.0;
         o->interpolation = SourceInterpolation::kCubic;
       },
       Eigen::Vector3d(1.0, 1.25, 0.8),
       0x60922efa3bdb622full},
  };
  for (const Recorded& r : recorded) {
    SimulationOptions o = SmallOptions();
    r.edit(&o);
    ASSERT_EQ(o.intensity_mapping, IntensityMapping::kNone);  // the default
    SimulatedSequence s;
    std::string error;
    ASSERT_TRUE(Simulate(SmallSource(r.spacing), o, &s, &error)) << error;
    EXPECT_EQ(FramesChecksum(s), r.checksum) << r.name << ": 0x" << std::hex << FramesChecksum(s);
  }
}

TEST(Simulate, FailsClearlyWhenTheSourceIsTooSmall) {
  ImageGeometry g;
  g.size = Eigen::Vector3i(40, 40, 40);
  SimulatedSequence s;
  std::string error;
  for (SourceInterpolation interpolation :
       {SourceInterpolation::kLinear, SourceInterpolation::kCubic}) {
    SimulationOptions o;
    o.interpolation = interpolation;
    EXPECT_FALSE(Simulate(Image(g, 1.0f), o, &s, &error));
    EXPECT_NE(error.find("outside the source grid"), std::string::npos) << error;
    EXPECT_NE(error.find("40x40x40"), std::string::npos) << error;
  }
  EXPECT_TRUE(s.frames.empty());
  EXPECT_FALSE(Simulate(Image(), SimulationOptions(), &s, &error));
  EXPECT_NE(error.find("empty"), std::string::npos) << error;
}

}  // namespace
}  // namespace dsr
