// Panorama grid, candidate rule and closed-form panorama (docs/design.md section 2).
#include "dsr/model/observation.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>

#include "dsr/model/panorama.h"
#include "dsr/tests/support/enum_names.h"

namespace dsr {
namespace {

ImageGeometry Cube(int n) {
  ImageGeometry g;
  g.size = Eigen::Vector3i(n, n, n);
  return g;
}

// A frame of constant `value` whose valid cells span physical [0, 9]^3 mm: its mask is
// [-1, 10]^3 (a valid cell's corners need their 6 neighbours inside; image/frame.h), in a
// grid with one more voxel of room on each side, so that cells within a margin of 1 of
// the valid region are inside the grid.
Frame UniformFrame(float value) {
  ImageGeometry g = Cube(14);
  g.origin_mm = Eigen::Vector3d::Constant(-2.0);
  Mask mask(g, 0);
  for (int k = 1; k <= 12; ++k)
    for (int j = 1; j <= 12; ++j)
      for (int i = 1; i <= 12; ++i) mask.at(i, j, k) = 1;
  return Frame(Image(g, value), mask);
}

Eigen::Isometry3d Translation(double x, double y, double z) {
  Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
  t.translation() = Eigen::Vector3d(x, y, z);
  return t;
}

struct TwoFrames {
  std::vector<Frame> frames;
  std::vector<Eigen::Isometry3d> poses;
};

// Frame 0 at the world origin, frame 1 seeing world x in [5, 14] (x_frame = x_world - 5).
TwoFrames MakeTwoFrames(float value0, float value1) {
  TwoFrames t;
  t.frames.push_back(UniformFrame(value0));
  t.frames.push_back(UniformFrame(value1));
  t.poses = {Eigen::Isometry3d::Identity(), Translation(-5, 0, 0)};
  return t;
}

TEST(BuildPanoramaGrid, CoversEveryFieldOfView) {
  const TwoFrames t = MakeTwoFrames(1, 2);
  ImageGeometry grid;
  std::string error;
  ASSERT_TRUE(BuildPanoramaGrid(t.frames, t.poses, 1.0, &grid, &error)) << error;
  // The valid fields of view span world [0, 14] x [0, 9] x [0, 9]; the origin is half a
  // frame-0 voxel below that box's minimum (frame 0's voxels sit at whole mm).
  EXPECT_EQ(grid.size, Eigen::Vector3i(16, 11, 11));
  EXPECT_LT((grid.origin_mm - Eigen::Vector3d::Constant(-0.5)).norm(), 1e-12);
  EXPECT_TRUE(grid.direction.isIdentity());
  ASSERT_TRUE(BuildPanoramaGrid(t.frames, t.poses, 2.0, &grid, &error)) << error;
  EXPECT_LT((grid.origin_mm - Eigen::Vector3d::Constant(-0.5)).norm(), 1e-12);
  EXPECT_EQ(grid.size, Eigen::Vector3i(9, 6, 6));  // 14.5/2 and 9.5/2 rounded up, + 1
}

// Frame 0 (the world) is sampled half a voxel off its own lattice on every axis, wherever
// the box starts: a constant offset other than 0 or 1/2 makes trilinear interpolation
// shift frame 0's content, which every frame-0-relative pose would inherit.
TEST(BuildPanoramaGrid, SamplesFrame0HalfwayBetweenItsVoxels) {
  for (const Eigen::Vector3d& shift :
       {Eigen::Vector3d(-5.3, 0.2, 7.9), Eigen::Vector3d(3.0, -2.75, 0.4)}) {
    TwoFrames t = MakeTwoFrames(1, 2);
    t.poses[1] = Translation(shift.x(), shift.y(), shift.z());
    for (double factor : {1.0, 2.0, 0.7}) {
      ImageGeometry grid;
      std::string error;
      ASSERT_TRUE(BuildPanoramaGrid(t.frames, t.poses, factor, &grid, &error)) << error;
      const Eigen::Vector3d u = t.frames[0].geometry().PhysicalToIndex(grid.origin_mm);
      for (int a = 0; a < 3; ++a) {
        EXPECT_NEAR(u[a] - std::floor(u[a]), 0.5, 1e-9) << "axis " << a << " factor " << factor;
        // Still the smallest such origin that covers every field of view.
        const double box_min = std::min(0.0, -shift[a]);
        EXPECT_LE(grid.origin_mm[a], box_min + 1e-12);
        EXPECT_GT(grid.origin_mm[a], box_min - 1.0);
        const double box_max = std::max(9.0, 9.0 - shift[a]);
        EXPECT_GE(grid.origin_mm[a] + (grid.size[a] - 1) * grid.spacing_mm[a], box_max - 1e-9);
      }
    }
  }
}

// PanoramaSampling::kAllPhases: the grid's step is 1 + 1/n frame-0 voxels (n = 9, frame
// 0's valid extent), so that across frame 0 its samples fall at every sub-voxel phase, in
// steps of 1/n, from the same origin; the grid still covers every field of view.
TEST(BuildPanoramaGrid, AllPhasesSamplesFrame0AtEveryPhase) {
  TwoFrames t = MakeTwoFrames(1, 2);
  t.poses[1] = Translation(-5.3, 0.2, 7.9);
  ImageGeometry half, all;
  std::string error;
  ASSERT_TRUE(BuildPanoramaGrid(t.frames, t.poses, 1.0, &half, &error)) << error;
  ASSERT_TRUE(BuildPanoramaGrid(t.frames, t.poses, 1.0, &all, &error,
                                PanoramaSampling::kAllPhases))
      << error;
  EXPECT_LT((all.origin_mm - half.origin_mm).norm(), 1e-12);
  const double n = 9.0;
  for (int a = 0; a < 3; ++a) {
    EXPECT_NEAR(all.spacing_mm[a], 1.0 + 1.0 / n, 1e-12) << a;
    std::vector<double> phases;
    for (int k = 0; k < all.size[a]; ++k) {
      const double u = t.frames[0].geometry().PhysicalToIndex(
          all.origin_mm + k * all.spacing_mm[a] * Eigen::Vector3d::Unit(a))[a];
      if (u < 0.0 || u > n) continue;  // outside frame 0
      phases.push_back(u - std::floor(u));
    }
    // About n^2 / (n + 1) samples across frame 0, whose phase advances 1/n each: one sweep
    // of [0, 1) in steps of 1/n, short of the steps the few missing samples would take
    // (the half-voxel grid's phases leave a gap of 1).
    std::sort(phases.begin(), phases.end());
    ASSERT_GE(phases.size(), 7u) << a;
    double largest_gap = phases.front() + 1.0 - phases.back();
    for (size_t q = 1; q < phases.size(); ++q) {
      largest_gap = std::max(largest_gap, phases[q] - phases[q - 1]);
    }
    EXPECT_LT(largest_gap, (n + 1.0 - phases.size()) / n + 1e-9) << a;
    const double box_min = std::min(0.0, -Eigen::Vector3d(-5.3, 0.2, 7.9)[a]);
    const double box_max = std::max(9.0, 9.0 - Eigen::Vector3d(-5.3, 0.2, 7.9)[a]);
    EXPECT_LE(all.origin_mm[a], box_min + 1e-12);
    EXPECT_GE(all.origin_mm[a] + (all.size[a] - 1) * all.spacing_mm[a], box_max - 1e-9);
  }
  // The half-voxel grid's phases are all 1/2.
  const double u =
      t.frames[0].geometry().PhysicalToIndex(half.origin_mm + 3.0 * half.spacing_mm)[0];
  EXPECT_NEAR(u - std::floor(u), 0.5, 1e-9);
  // The names round-trip.
  testing_enums::ExpectNamesRoundTrip({PanoramaSampling::kHalfVoxel, PanoramaSampling::kAllPhases},
                                      PanoramaSamplingToString, StringToPanoramaSampling,
                                      {"dither"});
}

// A frame 0 whose axes are not world axes (a rotated direction matrix, or the registration's
// mean-gauge grids on the frames' mean frame) has no lattice to align to: the origin is the
// box's minimum, and kAllPhases still makes the grid's step 1 + 1/n frame-0 voxels, so
// that no frame nearly parallel to the grid is sampled at one near-constant phase
// (docs/design.md 2.5).
TEST(BuildPanoramaGrid, RotatedFrame0KeepsTheBoxMinimumAndAllPhasesSweeps) {
  TwoFrames t = MakeTwoFrames(1, 2);
  const Eigen::Isometry3d rotation(Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitZ()));
  t.poses = {rotation, rotation * t.poses[1]};
  ImageGeometry grid;
  std::string error;
  ASSERT_TRUE(BuildPanoramaGrid(t.frames, t.poses, 1.0, &grid, &error)) << error;
  Eigen::AlignedBox3d box;
  for (int i = 0; i < 2; ++i) {
    for (int c = 0; c < 8; ++c) {
      const Eigen::Vector3d corner =
          Eigen::AlignedBox3d(Eigen::Vector3d::Zero(), Eigen::Vector3d::Constant(9.0))
              .corner(static_cast<Eigen::AlignedBox3d::CornerType>(c));
      box.extend(t.poses[i].inverse() * corner);
    }
  }
  EXPECT_LT((grid.origin_mm - box.min()).norm(), 1e-9);
  EXPECT_EQ(grid.spacing_mm, Eigen::Vector3d::Ones());
  ImageGeometry all;
  ASSERT_TRUE(BuildPanoramaGrid(t.frames, t.poses, 1.0, &all, &error,
                                PanoramaSampling::kAllPhases));
  EXPECT_EQ(all.origin_mm, grid.origin_mm);
  EXPECT_EQ(all.spacing_mm, Eigen::Vector3d::Constant(1.0 + 1.0 / 9.0));
}

TEST(BuildPanoramaGrid, RefusesAbsurdSizes) {
  TwoFrames t = MakeTwoFrames(1, 2);
  t.poses[1] = Translation(-1e6, 1e6, 1e6);
  ImageGeometry grid;
  std::string error;
  EXPECT_FALSE(BuildPanoramaGrid(t.frames, t.poses, 1.0, &grid, &error));
  EXPECT_NE(error.find("too large"), std::string::npos) << error;
}

TEST(BuildCandidates, KeepsVoxelsWithTwoCandidateObservers) {
  const TwoFrames t = MakeTwoFrames(1, 2);
  ImageGeometry grid;
  std::string error;
  ASSERT_TRUE(BuildPanoramaGrid(t.frames, t.poses, 1.0, &grid, &error));
  const CandidateSet c0 = BuildCandidates(t.frames, t.poses, grid, 0);
  // Both valid: world x in [5, 8] (cell floor <= 8), y and z in [0, 8].
  EXPECT_EQ(c0.num_voxels(), 4 * 9 * 9);
  EXPECT_EQ(c0.NumObservations(), 2 * 4 * 9 * 9);
  for (uint32_t bits : c0.observers) EXPECT_EQ(bits, 3u);
  const Eigen::Vector3d first = c0.VoxelCenter(0);  // voxels at half-integer mm
  EXPECT_LT((first - Eigen::Vector3d(5.5, 0.5, 0.5)).norm(), 1e-12);
  // A margin of 1 cell adds one layer on each side of each frame's valid region: world
  // x in [4, 10] (6 voxel centres), y and z in [-1, 10] (11).
  const CandidateSet c1 = BuildCandidates(t.frames, t.poses, grid, 1);
  EXPECT_EQ(c1.num_voxels(), 6 * 11 * 11);
}

// BuildCandidates against the rule written out for every voxel of every row (the slow
// twin): the frame's continuous index u(i) = u(0) + i step along the row, as the fast path
// forms it, its cell by std::floor, valid when inside the grid and a valid cell; a voxel is
// kept with two or more such frames. And CandidateOverlap against a count over every voxel
// and pair. Frames with holes in their masks, turned and shifted, on a panorama grid
// coarser along z.
TEST(BuildCandidates, EqualsTheRuleVoxelByVoxelAndOverlapCountsEveryPair) {
  std::mt19937_64 rng(17);
  std::uniform_real_distribution<double> angle(-0.4, 0.4), shift(-3.0, 3.0);
  std::vector<Frame> frames;
  std::vector<Eigen::Isometry3d> poses;
  for (int f = 0; f < 4; ++f) {
    ImageGeometry g;
    g.size = Eigen::Vector3i(13 + f, 12, 11 - f);
    g.spacing_mm = Eigen::Vector3d(1.0, 0.9, 1.2);
    Mask mask(g, 1);
    for (int k = 0; k < g.size[2]; ++k)
      for (int j = 0; j < g.size[1]; ++j)
        for (int i = 0; i < g.size[0]; ++i)
          if ((i * 7 + j * 3 + k * (f + 2)) % 61 == 0) mask.at(i, j, k) = 0;
    frames.emplace_back(Image(g, 1.0f), mask);
    Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
    if (f > 0) {
      pose.linear() = (Eigen::AngleAxisd(angle(rng), Eigen::Vector3d::UnitZ()) *
                       Eigen::AngleAxisd(angle(rng), Eigen::Vector3d::UnitX()))
                          .toRotationMatrix();
      pose.translation() = Eigen::Vector3d(shift(rng), shift(rng), shift(rng));
    }
    poses.push_back(pose);
  }
  ImageGeometry grid;
  std::string error;
  ASSERT_TRUE(BuildPanoramaGrid(frames, poses, 1.0, &grid, &error)) << error;
  grid.spacing_mm[2] *= 1.5;
  const CandidateSet fast = BuildCandidates(frames, poses, grid, 0);
  ASSERT_GT(fast.num_voxels(), 100);

  std::vector<int64_t> voxel;
  std::vector<uint32_t> observers;
  const Eigen::Matrix3d to_world = grid.IndexToPhysicalMatrix();
  for (int k = 0; k < grid.size[2]; ++k) {
    for (int j = 0; j < grid.size[1]; ++j) {
      const Eigen::Vector3d p0 = grid.origin_mm + to_world * Eigen::Vector3d(0, j, k);
      for (int i = 0; i < grid.size[0]; ++i) {
        uint32_t bits = 0;
        for (int f = 0; f < 4; ++f) {
          const Eigen::Matrix3d a = frames[f].index_from_physical() * poses[f].linear();
          const Eigen::Vector3d b = frames[f].index_from_physical() *
                                    (poses[f].translation() - frames[f].geometry().origin_mm);
          const Eigen::Vector3d u0 = a * p0 + b, step = a * to_world.col(0);
          const Eigen::Vector3i& n = frames[f].geometry().size;
          int64_t cell = 0, stride = 1;
          bool inside = true;
          for (int ax = 0; ax < 3; ++ax) {
            const double c = std::floor(u0[ax] + i * step[ax]);
            inside = inside && c >= 0.0 && c <= n[ax] - 2.0;
            if (inside) cell += static_cast<int64_t>(c) * stride;
            stride *= n[ax];
          }
          if (inside && frames[f].IsValidCell(cell)) bits |= 1u << f;
        }
        if (__builtin_popcount(bits) >= 2) {
          voxel.push_back(grid.LinearIndex(i, j, k));
          observers.push_back(bits);
        }
      }
    }
  }
  EXPECT_EQ(fast.voxel, voxel);
  EXPECT_EQ(fast.observers, observers);

  Eigen::MatrixXi pairs = Eigen::MatrixXi::Zero(4, 4);
  for (uint32_t bits : observers)
    for (int a = 0; a < 4; ++a)
      for (int b = 0; b < 4; ++b)
        if ((bits >> a & 1u) && (bits >> b & 1u)) ++pairs(a, b);
  EXPECT_EQ(CandidateOverlap(fast), pairs);
}

TEST(CandidatesInCubes, KeepsWholeCubesSpreadEvenly) {
  // Every voxel of a 16 x 8 x 8 grid, as cubes of 4: 4 x 2 x 2 cubes, those whose indices
  // sum to a multiple of 4 (0+0+0, 3+1+0, 3+0+1, 2+1+1) kept whole.
  CandidateSet all;
  all.grid.size = Eigen::Vector3i(16, 8, 8);
  all.num_frames = 2;
  for (int64_t l = 0; l < 16 * 8 * 8; ++l) {
    all.voxel.push_back(l);
    all.observers.push_back(static_cast<uint32_t>(1 + l % 3));
  }
  const CandidateSet kept = CandidatesInCubes(all, 4, 4);
  EXPECT_EQ(kept.num_voxels(), 4 * 64);
  EXPECT_EQ(kept.num_frames, 2);
  for (int64_t v = 0; v < kept.num_voxels(); ++v) {
    const int64_t l = kept.voxel[v];
    const int64_t x = l % 16, y = l / 16 % 8, z = l / 128;
    EXPECT_EQ((x / 4 + y / 4 + z / 4) % 4, 0) << l;
    EXPECT_EQ(kept.observers[v], static_cast<uint32_t>(1 + l % 3));  // carried along
    if (v > 0) {
      EXPECT_GT(l, kept.voxel[v - 1]);  // still increasing
    }
  }
  EXPECT_EQ(CandidatesInCubes(all, 4, 1).num_voxels(), all.num_voxels());
}

TEST(CandidatesInRows, KeepsWholeRowsAsBuildCandidatesDoes) {
  // Every voxel of a 16 x 8 x 8 grid but a few; rows (j, k) with j + 7 k a multiple of 3
  // kept whole, with their observers, in order.
  CandidateSet all;
  all.grid.size = Eigen::Vector3i(16, 8, 8);
  all.num_frames = 2;
  for (int64_t l = 0; l < 16 * 8 * 8; ++l) {
    if (l % 13 == 5) continue;  // rows need not be full
    all.voxel.push_back(l);
    all.observers.push_back(static_cast<uint32_t>(1 + l % 3));
  }
  const CandidateSet kept = CandidatesInRows(all, 3);
  int64_t expected = 0;
  for (int64_t v = 0; v < all.num_voxels(); ++v) {
    const int64_t l = all.voxel[v];
    if ((l / 16 % 8 + 7 * (l / 128)) % 3 == 0) ++expected;
  }
  EXPECT_EQ(kept.num_voxels(), expected);
  EXPECT_EQ(kept.num_frames, 2);
  EXPECT_EQ(kept.grid.size, all.grid.size);
  for (int64_t v = 0; v < kept.num_voxels(); ++v) {
    const int64_t l = kept.voxel[v];
    EXPECT_EQ((l / 16 % 8 + 7 * (l / 128)) % 3, 0) << l;
    EXPECT_EQ(kept.observers[v], static_cast<uint32_t>(1 + l % 3));
    if (v > 0) {
      EXPECT_GT(l, kept.voxel[v - 1]);
    }
  }
  EXPECT_EQ(CandidatesInRows(all, 1).voxel, all.voxel);
  // The rows BuildCandidates keeps with the same argument.
  const TwoFrames t = MakeTwoFrames(1, 2);
  ImageGeometry grid;
  std::string error;
  ASSERT_TRUE(BuildPanoramaGrid(t.frames, t.poses, 1.0, &grid, &error)) << error;
  const CandidateSet every = BuildCandidates(t.frames, t.poses, grid, 0);
  for (int keep : {2, 3, 5}) {
    const CandidateSet built = BuildCandidates(t.frames, t.poses, grid, 0, keep);
    const CandidateSet rows = CandidatesInRows(every, keep);
    EXPECT_GT(rows.num_voxels(), 0) << keep;
    EXPECT_EQ(rows.voxel, built.voxel) << keep;
    EXPECT_EQ(rows.observers, built.observers) << keep;
  }
}

TEST(CheckConnected, NamesFramesWithoutOverlap) {
  TwoFrames t = MakeTwoFrames(1, 2);
  t.frames.push_back(UniformFrame(3.0f));
  t.poses.push_back(Translation(-40, 0, 0));
  ImageGeometry grid;
  std::string error;
  ASSERT_TRUE(BuildPanoramaGrid(t.frames, t.poses, 1.0, &grid, &error));
  const CandidateSet c = BuildCandidates(t.frames, t.poses, grid, 0);
  EXPECT_FALSE(CheckConnected(c, 1, &error));
  EXPECT_NE(error.find("frame 2 does not overlap"), std::string::npos) << error;
  EXPECT_EQ(CandidateOverlap(c)(0, 1), 4 * 9 * 9);
  EXPECT_EQ(CandidateOverlap(c)(0, 2), 0);
  const CandidateSet c2 = BuildCandidates({t.frames[0], t.frames[1]},
                                          {t.poses[0], t.poses[1]}, grid, 0);
  EXPECT_TRUE(CheckConnected(c2, 1, &error));
  EXPECT_FALSE(CheckConnected(c2, 1000, &error));
  EXPECT_EQ(FramesNotConnected(CandidateOverlap(c), 1), std::vector<int>({2}));
  EXPECT_EQ(FramesNotConnected(CandidateOverlap(c2), 1), std::vector<int>());
  // Connected through frame 1 only: 0-1 and 1-3 overlap, 2 and 4 share only each other.
  Eigen::MatrixXi overlap = Eigen::MatrixXi::Zero(5, 5);
  overlap(0, 1) = overlap(1, 0) = 50;
  overlap(1, 3) = overlap(3, 1) = 50;
  overlap(2, 4) = overlap(4, 2) = 500;
  EXPECT_EQ(FramesNotConnected(overlap, 10), std::vector<int>({2, 4}));
  EXPECT_EQ(FramesNotConnected(overlap, 60), std::vector<int>({1, 2, 3, 4}));
}

TEST(FusePanoramaMean, AveragesTheObservingFrames) {
  const TwoFrames t = MakeTwoFrames(10, 20);
  ImageGeometry grid;
  std::string error;
  ASSERT_TRUE(BuildPanoramaGrid(t.frames, t.poses, 1.0, &grid, &error));
  for (int threads : {1, 2}) {
    const PanoramaImages p = FusePanoramaMean(t.frames, t.poses, grid, threads);
    EXPECT_FLOAT_EQ(p.mean.at(1, 1, 1), 10.0f);
    EXPECT_EQ(p.count.at(1, 1, 1), 1);
    EXPECT_FLOAT_EQ(p.mean.at(6, 1, 1), 15.0f);
    EXPECT_EQ(p.count.at(6, 1, 1), 2);
    EXPECT_FLOAT_EQ(p.mean.at(12, 1, 1), 20.0f);
    EXPECT_EQ(p.count.at(15, 10, 10), 0);  // world (14.5, 9.5, 9.5): outside both
    EXPECT_FLOAT_EQ(p.mean.at(15, 10, 10), 0.0f);
  }
}

TEST(RelativeToFrame0, MakesFrame0TheIdentity) {
  std::vector<Eigen::Isometry3d> poses = {Translation(1, 2, 3), Translation(4, 5, 6)};
  poses[1].linear() = Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  const auto rel = RelativeToFrame0(poses);
  EXPECT_TRUE(rel[0].matrix().isIdentity());
  // The relative transform frame1_from_frame0 is preserved.
  EXPECT_LT(((rel[1] * rel[0].inverse()).matrix() - (poses[1] * poses[0].inverse()).matrix())
                .norm(),
            1e-12);
}

}  // namespace
}  // namespace dsr
