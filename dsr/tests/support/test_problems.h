// Small synthetic registration problems for solver tests, without files or the simulator:
// a smooth analytic "world" intensity (random Gaussian blobs plus a slow ramp), sampled
// exactly at every frame voxel's world position under known poses, so ground truth is
// exact and interpolation never compounds.
#ifndef DSR_TESTS_SUPPORT_TEST_PROBLEMS_H_
#define DSR_TESTS_SUPPORT_TEST_PROBLEMS_H_

#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include <ceres/ceres.h>
#include <gtest/gtest.h>
#include <ceres/gradient_checker.h>
#include <Eigen/Geometry>

#include "dsr/geometry/se3.h"
#include "dsr/image/frame.h"
#include "dsr/model/observation.h"
#include "dsr/model/panorama.h"

namespace dsr {
namespace testing_problems {

struct Blob {
  Eigen::Vector3d center;
  double amplitude, sigma;
};

struct TestSequence {
  std::vector<Frame> frames;
  std::vector<Image> images;  // phase 0's
  std::vector<std::vector<Image>> phase_images;  // [frame][phase]
  std::vector<Mask> masks;
  std::vector<Eigen::Isometry3d> ground_truth;  // frame_from_world, world = frame 0 (T_0 = I)
};

struct SequenceOptions {
  int num_frames = 4;
  int size = 20;               // frames are size^3 voxels
  double spacing = 1.0;        // mm
  double noise_sigma = 0.0;
  double frame_offset = 5.0;   // mm between consecutive frame centres along x
  double max_rotation = 0.05;  // rad, per axis
  double max_translation = 1.5;  // mm, per axis
  // Valid cells' corners fill the box eroded by this many voxels (at least 1: the grid
  // border is never a corner). The mask is the box eroded by one voxel less: a corner's
  // central differences read its 6 neighbours, which must lie inside the mask
  // (image/frame.h).
  int erosion = 1;
  // Fields of view that cut through the structure, as exported ultrasound volumes have:
  // each frame is 0 outside a ball (radius 0.45 size, about the frame's centre) and its
  // mask is exactly that ball (`erosion` is then unused).
  bool ball_field_of_view = false;
  uint64_t seed = 1;
  // Lattice-aligned frames: no rotation, translations in whole voxels, noise attached to
  // the world lattice point. All frames are then crops of one discrete volume, so at the
  // ground truth every observer of a point interpolates the same data: every residual is 0
  // and the ground truth is the exact minimum of the cost and a Gauss-Newton fixed point.
  bool lattice = false;
  // Phases of the heart cycle per view (Frame::num_phases): phase p's scene has every third
  // blob's amplitude scaled by 1 + 0.4 sin(2 pi p / num_phases + its own phase), the rest
  // still; each phase has its own noise. 1: the 3D sequence (the same draws as before).
  int num_phases = 1;
};

// Unit-variance noise that depends only on the world lattice point near `x` (mm).
inline double LatticeNoise(const Eigen::Vector3d& x, double spacing, uint64_t seed) {
  uint64_t h = seed * 0x9E3779B97F4A7C15ull;
  for (int a = 0; a < 3; ++a) {
    h ^= static_cast<uint64_t>(std::llround(x[a] / spacing) + (1 << 20));
    h *= 0xBF58476D1CE4E5B9ull;
    h ^= h >> 31;
  }
  std::mt19937_64 rng(h);
  return std::normal_distribution<double>(0.0, 1.0)(rng);
}

inline TestSequence MakeSequence(const SequenceOptions& o) {
  std::mt19937_64 rng(o.seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  const double extent = o.size * o.spacing;
  std::vector<Blob> blobs;
  for (int b = 0; b < 60; ++b) {
    blobs.push_back({Eigen::Vector3d(u(rng) * (extent + o.num_frames * o.frame_offset),
                                     u(rng) * extent, u(rng) * extent),
                     60.0 * u(rng), (2.5 + 1.5 * std::abs(u(rng))) * o.spacing});
  }
  int phase = 0;  // the phase world_intensity shows
  auto world_intensity = [&](const Eigen::Vector3d& x) {
    double v = 100.0 + 0.5 * x[0] - 0.3 * x[1] + 0.2 * x[2];
    for (size_t b = 0; b < blobs.size(); ++b) {
      const double beat = o.num_phases > 1 && b % 3 == 0
                              ? 1.0 + 0.4 * std::sin(2.0 * M_PI * phase / o.num_phases + b)
                              : 1.0;
      v += beat * blobs[b].amplitude *
           std::exp(-(x - blobs[b].center).squaredNorm() / (2.0 * blobs[b].sigma * blobs[b].sigma));
    }
    return v;
  };
  TestSequence s;
  std::normal_distribution<double> noise(0.0, 1.0);
  const Eigen::Vector3d frame_center = Eigen::Vector3d::Constant(0.5 * (o.size - 1) * o.spacing);
  std::vector<Eigen::Isometry3d> raw;
  for (int i = 0; i < o.num_frames; ++i) {
    Vector6d d;
    d << o.max_translation * u(rng), o.max_translation * u(rng), o.max_translation * u(rng),
        o.max_rotation * u(rng), o.max_rotation * u(rng), o.max_rotation * u(rng);
    if (o.lattice) {
      for (int a = 0; a < 3; ++a) d[a] = o.spacing * std::round(d[a] / o.spacing);
      d.tail<3>().setZero();
    }
    Eigen::Isometry3d center_from_world = Eigen::Isometry3d::Identity();
    center_from_world.translation() =
        -Eigen::Vector3d((i - 0.5 * (o.num_frames - 1)) * o.frame_offset, 0.0, 0.0);
    Eigen::Isometry3d frame_from_center = Eigen::Isometry3d::Identity();
    frame_from_center.translation() = frame_center;
    raw.push_back(frame_from_center * ExpSE3(d) * center_from_world);
  }
  for (int i = 0; i < o.num_frames; ++i) {
    ImageGeometry g;
    g.size = Eigen::Vector3i::Constant(o.size);
    g.spacing_mm = Eigen::Vector3d::Constant(o.spacing);
    const Eigen::Isometry3d world_from_frame = raw[i].inverse();
    std::vector<Image> phases;
    for (phase = 0; phase < o.num_phases; ++phase) {
      Image image(g);
      for (int k = 0; k < o.size; ++k)
        for (int j = 0; j < o.size; ++j)
          for (int a = 0; a < o.size; ++a)
            image.at(a, j, k) = static_cast<float>(
                world_intensity(world_from_frame * g.IndexToPhysical(Eigen::Vector3d(a, j, k))) +
                o.noise_sigma *
                    (o.lattice ? LatticeNoise(world_from_frame * g.IndexToPhysical(
                                                  Eigen::Vector3d(a, j, k)) + frame_center,
                                              o.spacing, o.seed + 7919 * phase)
                               : noise(rng)));
      phases.push_back(std::move(image));
    }
    Image& image = phases.front();
    Mask mask(g, 0);
    if (o.ball_field_of_view) {
      const double radius = 0.45 * o.size;
      const Eigen::Vector3d center = Eigen::Vector3d::Constant(0.5 * (o.size - 1));
      for (int k = 0; k < o.size; ++k)
        for (int j = 0; j < o.size; ++j)
          for (int a = 0; a < o.size; ++a) {
            const bool inside = (Eigen::Vector3d(a, j, k) - center).norm() <= radius;
            mask.at(a, j, k) = inside ? 1 : 0;
            for (Image& phase_image : phases) {
              if (!inside) phase_image.at(a, j, k) = 0.0f;
            }
          }
    } else {
      const int e = std::max(0, o.erosion - 1);
      for (int k = e; k < o.size - e; ++k)
        for (int j = e; j < o.size - e; ++j)
          for (int a = e; a < o.size - e; ++a) mask.at(a, j, k) = 1;
    }
    s.frames.emplace_back(phases, mask);
    s.images.push_back(image);
    s.phase_images.push_back(std::move(phases));
    s.masks.push_back(std::move(mask));
  }
  s.ground_truth = RelativeToFrame0(raw);
  return s;
}

// 4 noisy frames of 16^3 (sigma 10, rotations within 0.2 rad, masks eroded by 2): the
// small sequence the kernel-path tests compare the paths on.
inline TestSequence KernelTestSequence(uint64_t seed) {
  SequenceOptions o;
  o.num_frames = 4;
  o.size = 16;
  o.noise_sigma = 10.0;
  o.max_rotation = 0.2;
  o.erosion = 2;
  o.seed = seed;
  return MakeSequence(o);
}

// Ground truth with every free pose perturbed by up to `rotation` rad / `translation` mm.
inline std::vector<Eigen::Isometry3d> Perturbed(const std::vector<Eigen::Isometry3d>& poses,
                                                double rotation,
                                                double translation,
                                                uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  std::vector<Eigen::Isometry3d> out = poses;
  for (size_t i = 1; i < out.size(); ++i) {
    Vector6d d;
    d << translation * u(rng), translation * u(rng), translation * u(rng), rotation * u(rng),
        rotation * u(rng), rotation * u(rng);
    out[i] = ExpSE3(d) * out[i];
  }
  return out;
}

// `poses` with every frame, frame 0 included, moved by one random world motion G
// (T_i -> T_i G; up to 0.7 mm and 0.02 rad per tangent component): the same registration
// in another world, where frame 0 is not the identity (for the mean gauge, solve/gauge.h).
inline std::vector<Eigen::Isometry3d> MovedTogether(std::vector<Eigen::Isometry3d> poses,
                                                    uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  Vector6d d;
  d << 0.7 * u(rng), 0.7 * u(rng), 0.7 * u(rng), 0.02 * u(rng), 0.02 * u(rng), 0.02 * u(rng);
  const Eigen::Isometry3d world_motion = ExpSE3(d);
  for (Eigen::Isometry3d& pose : poses) pose = pose * world_motion;
  return poses;
}

// Candidates at `poses` on a 1 mm grid (the shared rule), expecting the grid to build.
inline CandidateSet CandidatesAt(const std::vector<Frame>& frames,
                                 const std::vector<Eigen::Isometry3d>& poses) {
  ImageGeometry grid;
  std::string error;
  EXPECT_TRUE(BuildPanoramaGrid(frames, poses, 1.0, &grid, &error)) << error;
  return BuildCandidates(frames, poses, grid, 0);
}

// Candidates and grid at `poses` with the shared rule.
inline CandidateSet Candidates(const TestSequence& s,
                               const std::vector<Eigen::Isometry3d>& poses,
                               int margin = 0) {
  ImageGeometry grid;
  std::string error;
  if (!BuildPanoramaGrid(s.frames, poses, 1.0, &grid, &error)) return CandidateSet();
  return BuildCandidates(s.frames, poses, grid, margin);
}

// Candidates (shared rule) that keep only observers whose sample at `poses` lies at least
// `inset` cells inside the valid region. Solves that must reach a fixed point exactly use
// them: a sample that becomes valid or invalid makes the cost jump (sigma_ij switches), and
// a trust-region method that meets such a jump stops there, in any mode; solves that move
// no sample by `inset` cells never meet one.
inline CandidateSet InteriorCandidates(const TestSequence& s,
                                const std::vector<Eigen::Isometry3d>& poses,
                                double inset) {
  const CandidateSet all = Candidates(s, poses);
  CandidateSet out = all;
  out.voxel.clear();
  out.observers.clear();
  for (int64_t v = 0; v < all.num_voxels(); ++v) {
    uint32_t kept = 0;
    for (int i = 0; i < all.num_frames; ++i) {
      if (!(all.observers[v] >> i & 1u)) continue;
      const Eigen::Vector3d u = s.frames[i].ToIndex(poses[i] * all.VoxelCenter(v));
      bool interior = true;
      for (int corner = 0; corner < 8 && interior; ++corner) {
        const Eigen::Vector3d d(corner & 1 ? inset : -inset, corner & 2 ? inset : -inset,
                                corner & 4 ? inset : -inset);
        interior = s.frames[i].IsValidIndex(u + d);
      }
      if (interior) kept |= 1u << i;
    }
    if (__builtin_popcount(kept) >= 2) {
      out.voxel.push_back(all.voxel[v]);
      out.observers.push_back(kept);
    }
  }
  return out;
}

// Rotation angle (rad) and translation (mm) between two poses.
inline std::pair<double, double> PoseDifference(const Eigen::Isometry3d& a,
                                                const Eigen::Isometry3d& b) {
  const Eigen::Isometry3d d = a * b.inverse();
  return {LogSO3(d.linear()).norm(), (a.translation() - b.translation()).norm()};
}

// Largest rotation and translation difference over frames.
inline std::pair<double, double> MaxPoseDifference(const std::vector<Eigen::Isometry3d>& a,
                                                   const std::vector<Eigen::Isometry3d>& b) {
  double r = 0.0, t = 0.0;
  for (size_t i = 0; i < a.size(); ++i) {
    const auto [dr, dt] = PoseDifference(a[i], b[i]);
    r = std::max(r, dr);
    t = std::max(t, dt);
  }
  return {r, t};
}

// Dense Jacobian (tangent columns) of a Ceres problem at its current state.
inline Eigen::MatrixXd DenseJacobian(ceres::Problem* problem,
                              const std::vector<double*>& blocks,
                              Eigen::VectorXd* residuals,
                              double* cost) {
  ceres::Problem::EvaluateOptions options;
  options.parameter_blocks = blocks;
  std::vector<double> r;
  ceres::CRSMatrix crs;
  problem->Evaluate(options, cost, &r, nullptr, &crs);
  Eigen::MatrixXd j = Eigen::MatrixXd::Zero(crs.num_rows, crs.num_cols);
  for (int row = 0; row < crs.num_rows; ++row) {
    for (int k = crs.rows[row]; k < crs.rows[row + 1]; ++k) j(row, crs.cols[k]) = crs.values[k];
  }
  *residuals = Eigen::Map<Eigen::VectorXd>(r.data(), r.size());
  return j;
}

// A 16^3 frame (spacing 0.9, 1.1, 1.3 mm, all inside its mask) holding the linear ramp
// slope . x + `base`: its gradient volumes' central differences are the exact derivative of
// the interpolant, so analytic Jacobians can be checked numerically on it.
inline Frame LinearRampFrame(double base) {
  ImageGeometry g;
  g.size = Eigen::Vector3i(16, 16, 16);
  g.spacing_mm = Eigen::Vector3d(0.9, 1.1, 1.3);
  Image image(g);
  const Eigen::Vector3d slope(1.2, -0.7, 0.4);
  for (int k = 0; k < 16; ++k)
    for (int j = 0; j < 16; ++j)
      for (int i = 0; i < 16; ++i)
        image.at(i, j, k) =
            static_cast<float>(slope.dot(g.IndexToPhysical(Eigen::Vector3d(i, j, k))) + base);
  return Frame(image, Mask(g, 1));
}

// Checks a reduced cost whose Jacobian is the one with the voxel's intensity eliminated
// (DBA's Schur complement at M = mu; docs/design.md 2.8) against Ceres's numeric
// derivatives at `parameters`: that Jacobian is the full derivative of the residuals
// projected off `direction` (the voxel's intensity column, one entry per residual), and
// its J^T r is the exact gradient of |r|^2 / 2. Both within `relative_tolerance` of the
// numeric values' norms. All blocks, in tangent coordinates (`manifolds` as for
// ceres::GradientChecker).
inline void ExpectEliminatedJacobianMatchesNumeric(
    const ceres::CostFunction& cost,
    const std::vector<const ceres::Manifold*>& manifolds,
    const double* const* parameters,
    const Eigen::VectorXd& direction,
    double relative_tolerance) {
  ceres::NumericDiffOptions numeric_options;
  ceres::GradientChecker checker(&cost, &manifolds, numeric_options);
  ceres::GradientChecker::ProbeResults results;
  // The probe's own verdict compares with the full derivative: not this check.
  checker.Probe(parameters, 1.0, &results);
  ASSERT_TRUE(results.return_value);
  const int rows = static_cast<int>(results.residuals.size());
  ASSERT_EQ(direction.size(), rows);
  int cols = 0;
  for (const auto& block : results.local_jacobians) cols += static_cast<int>(block.cols());
  Eigen::MatrixXd analytic(rows, cols), numeric(rows, cols);
  for (size_t b = 0, c = 0; b < results.local_jacobians.size(); ++b) {
    const int w = static_cast<int>(results.local_jacobians[b].cols());
    analytic.middleCols(c, w) = results.local_jacobians[b];
    numeric.middleCols(c, w) = results.local_numeric_jacobians[b];
    c += w;
  }
  const Eigen::VectorXd d = direction / direction.norm();
  const Eigen::MatrixXd projected = numeric - d * (d.transpose() * numeric);
  EXPECT_LT((analytic - projected).norm(), relative_tolerance * numeric.norm())
      << "analytic\n" << analytic << "\nprojected numeric\n" << projected;
  const Eigen::VectorXd gradient = numeric.transpose() * results.residuals;
  EXPECT_LT((analytic.transpose() * results.residuals - gradient).norm(),
            relative_tolerance * gradient.norm());
  // The projection matters here: the check is not the plain one in disguise.
  EXPECT_GT((projected - numeric).norm(), 10.0 * relative_tolerance * numeric.norm());
}

}  // namespace testing_problems
}  // namespace dsr

#endif  // DSR_TESTS_SUPPORT_TEST_PROBLEMS_H_
