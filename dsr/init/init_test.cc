// Global initialisation (init/): the rotation grid, the global placement search of a pair
// with a known large offset, the pair-graph initialiser (frames in any order), and the
// pipeline's recovery of a frame started far off.
#include <algorithm>
#include <cmath>
#include <numeric>
#include <random>

#include <gtest/gtest.h>

#include "dsr/eval/eval.h"
#include "dsr/geometry/se3.h"
#include "dsr/image/frame.h"
#include "dsr/image/pyramid.h"
#include "dsr/init/pair_graph.h"
#include "dsr/init/placement_search.h"
#include "dsr/init/recovery.h"
#include "dsr/init/rotation_grid.h"
#include "dsr/pipeline/registration.h"
#include "dsr/sim/phantom.h"
#include "dsr/sim/simulate.h"
#include "dsr/tests/support/sanitizer.h"

namespace dsr {
namespace {

constexpr double kDegree = M_PI / 180.0;

Eigen::Matrix3d RandomRotation(std::mt19937_64* rng, double max_angle) {
  std::normal_distribution<double> n(0.0, 1.0);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  const Eigen::Vector3d axis = Eigen::Vector3d(n(*rng), n(*rng), n(*rng)).normalized();
  return ExpSO3(axis * max_angle * std::cbrt(u(*rng)));
}

TEST(RotationGrid, SamplesTheBallEvenly) {
  const Eigen::Matrix3d centre = ExpSO3(Eigen::Vector3d(0.3, -0.2, 0.1));
  const double max_angle = 45.0 * kDegree;
  const std::vector<Eigen::Matrix3d> rotations = RotationsInBall(centre, max_angle, 500);
  // About the requested count; all inside the ball, the centre first.
  EXPECT_NEAR(static_cast<double>(rotations.size()), 500.0, 50.0);
  EXPECT_LT(RotationAngleBetween(rotations.front(), centre), 1e-12);
  for (const Eigen::Matrix3d& r : rotations) {
    EXPECT_NEAR((r.transpose() * r - Eigen::Matrix3d::Identity()).norm(), 0.0, 1e-12);
    EXPECT_LE(RotationAngleBetween(r, centre), max_angle + 1e-9);
  }
  // Covering: every rotation of the ball has a sample within about the predicted radius
  // ((6 pi fraction / count)^(1/3) = 5.6 degrees); a uniform grid's worst gap is below
  // twice it.
  const double predicted = std::cbrt(6.0 * M_PI * RotationBallFraction(max_angle) / 500.0);
  std::mt19937_64 rng(7);
  double worst = 0.0;
  for (int t = 0; t < 2000; ++t) {
    const Eigen::Matrix3d probe = centre * RandomRotation(&rng, max_angle);
    double nearest = M_PI;
    for (const Eigen::Matrix3d& r : rotations)
      nearest = std::min(nearest, RotationAngleBetween(r, probe));
    worst = std::max(worst, nearest);
  }
  EXPECT_LT(worst, 2.0 * predicted) << "predicted covering radius " << predicted;
  EXPECT_NEAR(RotationBallFraction(M_PI), 1.0, 1e-12);
}

// A frame cut from `source` at `frame_from_world` with the simulator's pyramidal field of
// view (zero outside), and its mask.
struct CutFrame {
  Image image;
  Mask mask;
};

CutFrame Cut(const Image& source,
             const SimulationOptions& o,
             const Eigen::Isometry3d& frame_from_world) {
  const ImageGeometry g = SimulatedFrameGeometry(source.geometry, o);
  const Mask fov = PyramidFieldOfView(g, o);
  Mask all(source.geometry, 1);
  const Frame world(source, all);
  CutFrame out{Image(g, 0.0f), ErodeFieldOfView(fov, 1)};
  const Eigen::Isometry3d world_from_frame = frame_from_world.inverse();
  for (int k = 0; k < g.size[2]; ++k) {
    for (int j = 0; j < g.size[1]; ++j) {
      for (int i = 0; i < g.size[0]; ++i) {
        const int64_t l = g.LinearIndex(i, j, k);
        if (!fov.voxels[l]) continue;
        const Eigen::Vector3d x = world_from_frame * g.IndexToPhysical(Eigen::Vector3d(i, j, k));
        out.image.voxels[l] = static_cast<float>(world.InterpolateValue(world.ToIndex(x)));
      }
    }
  }
  return out;
}

Frame Coarse(const CutFrame& f, int halvings) {
  ImageLevel level{f.image, f.mask, {}};
  for (int h = 0; h < halvings; ++h) level = Downsample(level.image, level.mask, 1.0, 1);
  return Frame(level.image, level.mask);
}

const Image& Phantom128() {
  static const Image source = [] {
    PhantomOptions p;
    p.size = 128;
    return MakePhantom(p);
  }();
  return source;
}

SimulationOptions PairOptions() {
  SimulationOptions o;
  o.frame_size = Eigen::Vector3i(64, 64, 56);
  o.min_depth_voxels = 2.0;
  return o;
}

// Frame B is frame A turned by 40 degrees about an oblique axis through A's field of view
// and shifted by 20 voxels, both at half resolution (2 mm voxels).
struct FortyDegreePair {
  Frame fixed, moving;
  Eigen::Isometry3d b_from_a;
  Eigen::Vector3d pivot;  // B's field-of-view centre (mm)
};

const FortyDegreePair& FortyDegreeTwentyVoxelPair() {
  static const FortyDegreePair pair = [] {
    const Image& source = Phantom128();
    const SimulationOptions o = PairOptions();
    const ImageGeometry g = SimulatedFrameGeometry(source.geometry, o);
    // A looks at the source centre; B's view is A's turned about a point inside A's field
    // of view and shifted, so that about half of B's field of view is in A's.
    const Eigen::Vector3d frame_centre =
        g.IndexToPhysical(0.5 * (g.size.cast<double>() - Eigen::Vector3d::Ones()));
    const Eigen::Vector3d source_centre = source.geometry.IndexToPhysical(
        0.5 * (source.geometry.size.cast<double>() - Eigen::Vector3d::Ones()));
    Eigen::Isometry3d a_from_world = Eigen::Isometry3d::Identity();
    a_from_world.translation() = frame_centre - source_centre;
    FortyDegreePair p;
    p.b_from_a = Eigen::Isometry3d::Identity();
    p.pivot = frame_centre + Eigen::Vector3d(0, 0, 8);
    p.b_from_a.linear() = ExpSO3(Eigen::Vector3d(1.0, -1.0, 0.5).normalized() * 40.0 * kDegree);
    p.b_from_a.translation() =
        p.pivot - p.b_from_a.linear() * p.pivot + Eigen::Vector3d(12.0, -10.0, 12.5);
    p.fixed = Coarse(Cut(source, o, a_from_world), 1);
    p.moving = Coarse(Cut(source, o, p.b_from_a * a_from_world), 1);
    return p;
  }();
  return pair;
}

PlacementSearchOptions FortyDegreeSearch() {
  PlacementSearchOptions search;
  search.rotation_deg = 45.0;
  search.rotations = 200;
  search.num_threads = 2;
  search.refine.progress = false;
  return search;
}

// The search (centred on the identity, within 45 degrees) finds B_from_A to within a voxel
// and a degree after refinement.
TEST(PlacementSearch, FindsAFortyDegreeTwentyVoxelOffset) {
  DSR_SKIP_HEAVY_UNDER_SANITIZER();
  const FortyDegreePair& p = FortyDegreeTwentyVoxelPair();
  ASSERT_NEAR(Eigen::Vector3d(12.0, -10.0, 12.5).norm(), 20.0, 0.01);  // "20 voxels"
  const PlacementSearchOptions search = FortyDegreeSearch();
  const std::vector<Placement> found =
      SearchPlacement(p.fixed, p.moving, Eigen::Matrix3d::Identity(), {}, search);
  ASSERT_FALSE(found.empty());
  const Eigen::Isometry3d error = found.front().moving_from_fixed * p.b_from_a.inverse();
  // At the field-of-view centre of B, in mm (1 mm voxels at the input, 2 mm searched).
  EXPECT_LT((error * p.pivot - p.pivot).norm(), 1.0);
  EXPECT_LT(LogSO3(error.linear()).norm(), 1.0 * kDegree);
  EXPECT_GT(found.front().ncc, 0.8);
  // Identity, where a local solver would start, is far worse.
  const Placement at_identity = ScorePlacement(p.fixed, p.moving, Eigen::Isometry3d::Identity(),
                                               search.min_overlap_fraction);
  EXPECT_LT(at_identity.ncc, found.front().ncc - 0.2);
}

// The coarse screen only drops rotations: every placement it keeps is the unscreened
// search's for that rotation (same translation, same NCC up to the FFTs' round-off on
// another padded grid), and the unscreened search's best rotations are among the kept.
TEST(PlacementSearch, CoarseScreenKeepsTheBestRotationsUnchanged) {
  DSR_SKIP_HEAVY_UNDER_SANITIZER();
  const FortyDegreePair& p = FortyDegreeTwentyVoxelPair();
  PlacementSearchOptions all = FortyDegreeSearch();
  all.rotations = 100;
  all.num_screened = 0;
  PlacementSearchOptions screened = all;
  screened.num_screened = 12;
  const std::vector<Placement> every =
      SearchPeaks(p.fixed, p.moving, Eigen::Matrix3d::Identity(), all);
  const std::vector<Placement> kept =
      SearchPeaks(p.fixed, p.moving, Eigen::Matrix3d::Identity(), screened);
  ASSERT_GT(every.size(), 80u);
  ASSERT_EQ(kept.size(), 12u);
  const auto same_rotation = [](const Placement& a, const Placement& b) {
    // (the angle's acos resolves about 1e-8 rad near 0)
    return RotationAngleBetween(a.moving_from_fixed.linear(), b.moving_from_fixed.linear()) <
           1e-6;
  };
  for (const Placement& k : kept) {
    const auto twin = std::find_if(every.begin(), every.end(),
                                   [&](const Placement& e) { return same_rotation(e, k); });
    ASSERT_NE(twin, every.end());
    EXPECT_NEAR(k.ncc, twin->ncc, 1e-9);
    EXPECT_EQ(k.overlap, twin->overlap);
    EXPECT_LT((k.moving_from_fixed.translation() - twin->moving_from_fixed.translation()).norm(),
              1e-6);
  }
  // The unscreened best (the true rotation's neighbourhood) survived the screen.
  EXPECT_TRUE(same_rotation(kept.front(), every.front()));
}

SimulatedSequence SmallSequence(uint64_t seed, int num_frames = 5) {
  SimulationOptions o;
  o.num_frames = num_frames;
  o.frame_size = Eigen::Vector3i(48, 48, 40);
  o.max_rotation_deg = 10.0;
  o.max_translation_voxels = 6.0;
  o.sigma = 10.0;
  o.min_depth_voxels = 2.0;
  o.seed = seed;
  SimulatedSequence s;
  std::string error;
  EXPECT_TRUE(Simulate(Phantom128(), o, &s, &error)) << error;
  return s;
}

RegistrationOptions SmallOptions() {
  RegistrationOptions o;
  o.solve.progress = false;
  o.solve.num_threads = 2;
  o.pyramid_levels = 2;
  o.pyramid_min_size = 8;
  o.search.rotations = 200;
  o.search.num_threads = 2;
  o.search.refine.progress = false;
  return o;
}

// Global initialisation, then the registration, with frames 1..3 given in another order:
// each frame ends at the same pose.
TEST(PairGraph, ShuffledFramesGiveTheSamePoses) {
  DSR_SKIP_HEAVY_UNDER_SANITIZER();
  const SimulatedSequence s = SmallSequence(11, 4);
  RegistrationOptions o = SmallOptions();
  o.search.rotations = 150;
  SetInitialisation("global", 2, &o);
  const std::vector<Eigen::Isometry3d> identity(s.frames.size(), Eigen::Isometry3d::Identity());
  RegistrationResult in_order;
  std::string error;
  ASSERT_TRUE(Register(s.frames, s.masks, identity, o, &in_order, &error)) << error;
  ASSERT_TRUE(in_order.usable) << in_order.failure;
  const PoseErrorSummary errors =
      ComparePoses(in_order.frame_from_world, s.frame_from_world, s.masks);
  EXPECT_LT(errors.tre_mean_mm, 0.1);

  const std::vector<int> order = {0, 3, 1, 2};
  std::vector<Image> frames;
  std::vector<Mask> masks;
  for (int f : order) {
    frames.push_back(s.frames[f]);
    masks.push_back(s.masks[f]);
  }
  RegistrationResult shuffled;
  ASSERT_TRUE(Register(frames, masks, identity, o, &shuffled, &error)) << error;
  ASSERT_TRUE(shuffled.usable) << shuffled.failure;
  for (size_t n = 0; n < order.size(); ++n) {
    const Eigen::Isometry3d d =
        shuffled.frame_from_world[n] * in_order.frame_from_world[order[n]].inverse();
    EXPECT_LT(LogSE3(d).norm(), 0.05) << "frame " << order[n];
  }
}

// A frame started 60 degrees off: without recovery the registration is refused (the frame
// is flagged); with recovery it is re-placed and the registration reaches ground truth.
TEST(Recovery, RePlacesAFrameStartedSixtyDegreesOff) {
  DSR_SKIP_HEAVY_UNDER_SANITIZER();
  const SimulatedSequence s = SmallSequence(5);
  std::vector<Eigen::Isometry3d> start = RelativeToFrame0(s.frame_from_world);
  const int off = 3;
  const Eigen::Vector3d centre = s.frames[off].geometry.IndexToPhysical(
      0.5 * (s.frames[off].geometry.size.cast<double>() - Eigen::Vector3d::Ones()));
  Eigen::Isometry3d turn = Eigen::Isometry3d::Identity();
  // About a tilted axis across the depth direction: the local solver alone ends in a wrong
  // minimum from there (about the depth axis or a single lateral axis it comes back).
  turn.linear() = ExpSO3(Eigen::Vector3d(1.0, 1.0, 0.0).normalized() * 60.0 * kDegree);
  turn.translation() = centre - turn.linear() * centre;
  start[off] = turn * start[off];

  RegistrationOptions o = SmallOptions();
  RegistrationResult refused;
  std::string error;
  ASSERT_TRUE(Register(s.frames, s.masks, start, o, &refused, &error)) << error;
  EXPECT_FALSE(refused.usable);
  EXPECT_NE(std::find(refused.flagged_frames.begin(), refused.flagged_frames.end(), off),
            refused.flagged_frames.end());

  o.max_recoveries = 2;
  RegistrationResult recovered;
  ASSERT_TRUE(Register(s.frames, s.masks, start, o, &recovered, &error)) << error;
  ASSERT_TRUE(recovered.usable) << recovered.failure;
  ASSERT_FALSE(recovered.recoveries.empty());
  // Frame 3 re-placed against the others, or (when its wrong pose got a neighbour flagged
  // too: 2 of 5 frames) every frame placed by the pair graph.
  bool replaced = recovered.recoveries.front().global;
  for (const FrameReplacement& f : recovered.recoveries.front().frames) {
    replaced = replaced || (f.frame == off && f.moved);
  }
  EXPECT_TRUE(replaced);
  const PoseErrorSummary errors =
      ComparePoses(recovered.frame_from_world, s.frame_from_world, s.masks);
  EXPECT_LT(errors.tre_mean_mm, 0.1);
}

// The re-placement itself: frame 3 turned 60 degrees off its true pose is placed against
// the panorama of the others (at their true poses) to within the search level's reach of
// the local solver; a frame that was not off is kept without a search.
TEST(Recovery, ReplaceFramesFindsTheFrameAgainstThePanorama) {
  DSR_SKIP_HEAVY_UNDER_SANITIZER();
  const SimulatedSequence s = SmallSequence(5);
  const std::vector<Eigen::Isometry3d> truth = RelativeToFrame0(s.frame_from_world);
  std::vector<Frame> frames;
  for (size_t f = 0; f < s.frames.size(); ++f)
    frames.push_back(Coarse({s.frames[f], s.masks[f]}, 1));
  std::vector<Eigen::Isometry3d> poses = truth;
  const int off = 3;
  const Eigen::Vector3d centre = frames[off].ValidCentre();
  Eigen::Isometry3d turn = Eigen::Isometry3d::Identity();
  turn.linear() = ExpSO3(Eigen::Vector3d(1.0, 1.0, 0.0).normalized() * 60.0 * kDegree);
  turn.translation() = centre - turn.linear() * centre;
  poses[off] = turn * poses[off];
  PlacementSearchOptions search;
  search.num_threads = 2;
  search.refine.progress = false;
  std::vector<Eigen::Isometry3d> replaced;
  std::vector<FrameReplacement> records;
  std::string error;
  // The solve "started" at the wrong poses too: the search alone has to find frame 3.
  // Frame 3 needs a search: with none allowed, nothing is searched.
  EXPECT_FALSE(ReplaceFrames(frames, poses, poses, {off, 1}, search, 0, &replaced, &records,
                             &error));
  EXPECT_NE(error.find("1 flagged frames need a search (more than 0)"), std::string::npos)
      << error;
  ASSERT_TRUE(ReplaceFrames(frames, poses, poses, {off, 1}, search, 1, &replaced, &records,
                            &error))
      << error;
  ASSERT_EQ(records.size(), 2u);
  EXPECT_TRUE(records[0].moved);
  EXPECT_GT(records[0].ncc_after, records[0].ncc_before);
  EXPECT_FALSE(records[1].searched);  // frame 1 matches the panorama as the others do
  EXPECT_TRUE(replaced[1].matrix() == poses[1].matrix());
  const Eigen::Isometry3d error_pose = replaced[off] * truth[off].inverse();
  const Eigen::Vector3d centre_in_world = truth[off].inverse() * centre;
  // Within the local solver's reach at the search level (2 mm voxels here).
  EXPECT_LT((error_pose * centre_in_world - centre_in_world).norm(), 2.0);
  EXPECT_LT(LogSO3(error_pose.linear()).norm(), 2.0 * kDegree);
}

// A frame at its right pose whose misfit is high for another reason (here it is blurred,
// as a frame of another resolution would be: its differences to the others at every edge
// are large, its NCC with them is not lower) is flagged by the misfit check; recovery finds
// it matching the panorama as well as the other frames do, accepts its misfit and goes on,
// instead of failing after the pair graph gives the same poses again.
TEST(Recovery, AcceptsTheMisfitOfAFrameThatMatchesTheOthers) {
  SimulatedSequence s = SmallSequence(3);
  const int blurred = 2;
  s.frames[blurred] = SmoothInsideMask(s.frames[blurred], s.masks[blurred], 1.5, 2);
  const std::vector<Eigen::Isometry3d> identity(s.frames.size(), Eigen::Isometry3d::Identity());
  RegistrationOptions o = SmallOptions();
  // This test is about the former misfit check (off by default), whose ratio to the other
  // frames' lower quartile flags a frame for its content; the structure check leaves the
  // blurred frame's differences alone (they are fine detail, not structure at its lag).
  o.max_misfit_ratio = 2.0;
  RegistrationResult refused;
  std::string error;
  ASSERT_TRUE(Register(s.frames, s.masks, identity, o, &refused, &error)) << error;
  ASSERT_FALSE(refused.usable);
  EXPECT_TRUE(refused.flagged_by_misfit) << refused.failure;
  EXPECT_EQ(refused.flagged_frames, std::vector<int>({blurred})) << refused.failure;

  o.max_recoveries = 2;
  RegistrationResult accepted;
  ASSERT_TRUE(Register(s.frames, s.masks, identity, o, &accepted, &error)) << error;
  ASSERT_TRUE(accepted.usable) << accepted.failure;
  ASSERT_EQ(accepted.recoveries.size(), 1u);
  const RegistrationResult::Recovery& r = accepted.recoveries.front();
  EXPECT_TRUE(r.misfit_accepted);
  EXPECT_FALSE(r.global);
  ASSERT_EQ(r.frames.size(), 1u);
  EXPECT_EQ(r.frames[0].frame, blurred);
  EXPECT_FALSE(r.frames[0].moved);
  EXPECT_FALSE(r.frames[0].searched);
  EXPECT_LT(ComparePoses(accepted.frame_from_world, s.frame_from_world, s.masks).tre_mean_mm, 0.1);
}

// Recovery changes nothing where nothing is flagged: the same poses, bit for bit.
// A coarse level whose last solve still moved frames by more than the rebuild tolerance
// has not settled: with recovery, the registration stops there and recovers (the still
// moving frames named), instead of spending the finer levels on it. A tolerance no solve
// can meet (and no sliding threshold) makes every coarse level unsettled: each round ends
// at the coarsest level, and once the recoveries are spent the failure says why; without
// recovery the rule is off.
TEST(Recovery, AnUnsettledCoarseLevelIsRecoveredAtOnce) {
  const SimulatedSequence s = SmallSequence(3);
  const std::vector<Eigen::Isometry3d> identity(s.frames.size(), Eigen::Isometry3d::Identity());
  RegistrationOptions o = SmallOptions();
  o.max_rebuilds = 1;
  o.rebuild_tolerance = 1e-12;
  o.unsettled_motion_voxels = 0.0;
  RegistrationResult plain;
  std::string error;
  ASSERT_TRUE(Register(s.frames, s.masks, identity, o, &plain, &error)) << error;
  ASSERT_TRUE(plain.usable) << plain.failure;
  EXPECT_EQ(plain.solves.back().level, 0);

  o.max_recoveries = 1;
  RegistrationResult unsettled;
  ASSERT_TRUE(Register(s.frames, s.masks, identity, o, &unsettled, &error)) << error;
  EXPECT_FALSE(unsettled.usable);
  EXPECT_NE(unsettled.failure.find("pyramid level 1 did not settle"), std::string::npos)
      << unsettled.failure;
  ASSERT_EQ(unsettled.recoveries.size(), 1u);
  EXPECT_NE(unsettled.recoveries[0].why.find("did not settle"), std::string::npos);
  // Every solve was on the coarsest level (pyramid_levels = 2: level 1).
  for (const LevelSolve& solve : unsettled.solves) EXPECT_EQ(solve.level, 1);
  EXPECT_FALSE(unsettled.flagged_frames.empty());
  for (int f : unsettled.flagged_frames) EXPECT_GT(f, 0);
}

TEST(Recovery, LeavesAGoodRegistrationAlone) {
  const SimulatedSequence s = SmallSequence(3);
  const std::vector<Eigen::Isometry3d> identity(s.frames.size(), Eigen::Isometry3d::Identity());
  RegistrationOptions o = SmallOptions();
  RegistrationResult plain, with_recovery;
  std::string error;
  ASSERT_TRUE(Register(s.frames, s.masks, identity, o, &plain, &error)) << error;
  ASSERT_TRUE(plain.usable) << plain.failure;
  o.max_recoveries = 2;
  ASSERT_TRUE(Register(s.frames, s.masks, identity, o, &with_recovery, &error)) << error;
  ASSERT_TRUE(with_recovery.usable);
  EXPECT_TRUE(with_recovery.recoveries.empty());
  for (size_t f = 0; f < s.frames.size(); ++f) {
    EXPECT_TRUE(plain.frame_from_world[f].matrix() == with_recovery.frame_from_world[f].matrix());
  }
}

}  // namespace
}  // namespace dsr
