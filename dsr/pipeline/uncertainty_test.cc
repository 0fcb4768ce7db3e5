// Pose uncertainty (pipeline/uncertainty.h): the predicted TRE and the normalised squared
// error against closed forms, and the estimate on simulated frames (positive definite,
// gauge frame zero, growing with the noise).
#include <algorithm>
#include <cmath>

#include <Eigen/Eigenvalues>
#include <gtest/gtest.h>

#include "dsr/dsr_reduced/reduced_cost.h"
#include "dsr/geometry/se3.h"
#include "dsr/model/observation.h"
#include "dsr/model/panorama.h"
#include "dsr/pipeline/experiment.h"
#include "dsr/pipeline/registration.h"
#include "dsr/pipeline/uncertainty.h"
#include "dsr/sim/phantom.h"
#include "dsr/sim/simulate.h"
#include "dsr/tests/support/sanitizer.h"

namespace dsr {
namespace {

TEST(PredictedTre, MatchesClosedFormsOfGaussianErrors) {
  // Translation only, isotropic: the mean norm of a 3-D Gaussian is sigma sqrt(8 / pi).
  Matrix6d c = Matrix6d::Zero();
  c.topLeftCorner<3, 3>() = 0.01 * Eigen::Matrix3d::Identity();
  const std::vector<Eigen::Vector3d> points = {Eigen::Vector3d(1, 2, 3), Eigen::Vector3d(-4, 0, 2)};
  EXPECT_NEAR(PredictedTre(c, points), 0.1 * std::sqrt(8.0 / M_PI),
              0.05 * 0.1 * std::sqrt(8.0 / M_PI));
  // Rotation about z only, points on a circle of radius 20 mm in the xy plane: each moves
  // by |phi_z| 20, a half-normal of mean sigma 20 sqrt(2 / pi).
  c.setZero();
  c(5, 5) = 1e-6;
  std::vector<Eigen::Vector3d> ring;
  for (int a = 0; a < 16; ++a)
    ring.emplace_back(20.0 * std::cos(a * M_PI / 8), 20.0 * std::sin(a * M_PI / 8), 0.0);
  const double expected = 1e-3 * 20.0 * std::sqrt(2.0 / M_PI);
  EXPECT_NEAR(PredictedTre(c, ring), expected, 0.06 * expected);
  EXPECT_EQ(PredictedTre(c, {}), 0.0);
}

TEST(NormalisedSquaredError, IsTheMahalanobisNormOfTheTangentError) {
  Vector6d e;
  e << 0.2, -0.1, 0.05, 0.001, 0.002, -0.003;
  Vector6d variances;
  variances << 0.04, 0.01, 0.01, 1e-6, 4e-6, 1e-6;
  const Matrix6d c = variances.asDiagonal();
  Eigen::Isometry3d truth = Eigen::Isometry3d::Identity();
  truth.linear() = ExpSO3(Eigen::Vector3d(0.1, 0.2, -0.3));
  truth.translation() = Eigen::Vector3d(5, -3, 2);
  const double expected = e.cwiseProduct(e).cwiseQuotient(variances).sum();
  EXPECT_NEAR(NormalisedSquaredError(ExpSE3(e) * truth, truth, c), expected, 1e-9 * expected);
}

SimulatedSequence Sequence(double noise_sigma) {
  PhantomOptions phantom;
  phantom.size = 96;
  SimulationOptions o;
  o.num_frames = 4;
  o.frame_size = Eigen::Vector3i(40, 40, 32);
  o.sigma = noise_sigma;
  o.max_translation_voxels = 4.0;
  o.max_rotation_deg = 6.0;
  o.min_depth_voxels = 2.0;
  o.mask_erosion = 0;
  o.seed = 8;
  SimulatedSequence s;
  std::string error;
  EXPECT_TRUE(Simulate(MakePhantom(phantom), o, &s, &error)) << error;
  return s;
}

RegistrationResult RegisterWithUncertainty(const SimulatedSequence& s) {
  RegistrationOptions o;
  o.solve.progress = false;
  o.solve.num_threads = 2;
  o.pyramid_levels = 2;
  o.pyramid_min_size = 8;
  o.uncertainty = true;
  RegistrationResult result;
  std::string error;
  const std::vector<Eigen::Isometry3d> identity(s.frames.size(), Eigen::Isometry3d::Identity());
  EXPECT_TRUE(Register(s.frames, s.masks, identity, o, &result, &error)) << error;
  EXPECT_TRUE(result.usable) << result.failure;
  return result;
}

// The reduced gradient g (6m) at `poses` straight from its definition, over the
// observations in `use` (voxel v, frame f): g_f = sum_j J_fj^T (I_f(p_fj) - mu_j).
Eigen::VectorXd GradientOver(const std::vector<Frame>& frames, const CandidateSet& candidates,
                             const std::vector<Eigen::Isometry3d>& poses,
                             const std::vector<std::vector<bool>>& use) {
  const int m = static_cast<int>(frames.size());
  Eigen::VectorXd g = Eigen::VectorXd::Zero(6 * m);
  for (int64_t v = 0; v < candidates.num_voxels(); ++v) {
    std::vector<double> value;
    std::vector<RowVector6d> jacobian;
    std::vector<int> frame;
    for (int f = 0; f < m; ++f) {
      if (!use[v][f]) continue;
      double x = 0.0;
      RowVector6d j;
      EXPECT_TRUE(ObserveSample(frames[f], poses[f], candidates.VoxelCenter(v), &x, &j));
      value.push_back(x);
      jacobian.push_back(j);
      frame.push_back(f);
    }
    const int k = static_cast<int>(value.size());
    if (k < 2) continue;
    double mean = 0.0;
    for (double x : value) mean += x / k;
    for (int a = 0; a < k; ++a)
      g.segment<6>(6 * frame[a]) += jacobian[a].transpose() * (value[a] - mean);
  }
  return g;
}

// GradientJacobian against its slow, obviously correct twin: forward differences of the
// whole reduced gradient from its definition (every frame's block, the panorama means
// recomputed, one pass per column), over the observations that are valid at the poses and
// at the step (a sample entering or leaving a field of view is a jump, not a slope; the
// fast path leaves such samples out of that difference too), at the registered poses of a
// noisy sequence. And what separates it from the Gauss-Newton matrix: with noise its
// diagonal is well below Gauss-Newton's (the noisy gradient volumes inflate J^T J; the
// residual curvature takes that back).
TEST(PoseUncertainty, GradientJacobianIsTheDerivativeOfTheGradient) {
  DSR_SKIP_HEAVY_UNDER_SANITIZER();
  const SimulatedSequence s = Sequence(25.0);
  const RegistrationResult r = RegisterWithUncertainty(s);
  std::vector<Frame> frames;
  for (size_t i = 0; i < s.frames.size(); ++i) frames.emplace_back(s.frames[i], s.masks[i]);
  const std::vector<Eigen::Isometry3d>& poses = r.frame_from_world;
  ImageGeometry grid;
  std::string error;
  ASSERT_TRUE(BuildPanoramaGrid(frames, poses, 1.0, &grid, &error)) << error;
  const CandidateSet candidates = BuildCandidates(frames, poses, grid, 0);
  const int m = static_cast<int>(frames.size());
  const int n = 6 * m;
  const std::vector<double> step_mm(m, 0.05), step_rad(m, 0.05 / 30.0);
  const auto moved_pose = [&](int f, int c) {
    std::vector<Eigen::Isometry3d> moved = poses;
    Vector6d delta = Vector6d::Zero();
    delta[c] = c < 3 ? step_mm[f] : step_rad[f];
    moved[f] = ExpSE3(delta) * moved[f];
    return moved;
  };
  const auto valid = [&](int64_t v, int f, const Eigen::Isometry3d& pose) {
    double x = 0.0;
    return ((candidates.observers[v] >> f) & 1) != 0 &&
           ObserveSample(frames[f], pose, candidates.VoxelCenter(v), &x, nullptr);
  };
  Eigen::MatrixXd numeric(n, n);
  for (int k = 0; k < n; ++k) {
    const int f = k / 6, c = k % 6;
    const std::vector<Eigen::Isometry3d> plus = moved_pose(f, c);
    std::vector<std::vector<bool>> use(candidates.num_voxels(), std::vector<bool>(m));
    for (int64_t v = 0; v < candidates.num_voxels(); ++v) {
      for (int b = 0; b < m; ++b)
        use[v][b] = valid(v, b, poses[b]) && (b != f || valid(v, b, plus[b]));
    }
    numeric.col(k) = (GradientOver(frames, candidates, plus, use) -
                      GradientOver(frames, candidates, poses, use)) /
                     (c < 3 ? step_mm[f] : step_rad[f]);
  }
  ReducedSystem at;
  AccumulateReducedSystem(frames, candidates, poses, 0, candidates.num_voxels(), true,
                          StreamContext{2}, &at);
  const Eigen::MatrixXd a = GradientJacobian(frames, candidates, poses, step_mm, step_rad, 2);
  double exact_trace = 0.0, gauss_newton_trace = 0.0;  // translation diagonals, all frames
  for (int f = 0; f < m; ++f) {
    const Matrix6d gn = at.hessian.block<6, 6>(6 * f, 6 * f);
    const double scale = gn.diagonal().cwiseAbs().maxCoeff();
    for (int b = 0; b < m; ++b) {
      const Matrix6d block = numeric.block<6, 6>(6 * f, 6 * b);
      const Matrix6d fast = a.block<6, 6>(6 * f, 6 * b);
      EXPECT_LT((block - fast).cwiseAbs().maxCoeff(), 1e-6 * scale)
          << "block (" << f << ", " << b << ")\nnumeric\n" << block << "\nfast\n" << fast;
    }
    for (int c = 0; c < 3; ++c) {
      exact_trace += a(6 * f + c, 6 * f + c);
      gauss_newton_trace += gn(c, c);
    }
  }
  // Measured 0.81 here (0.5-0.65 on the paper's 96x96x80 frames at this noise).
  EXPECT_LT(exact_trace, 0.95 * gauss_newton_trace) << exact_trace / gauss_newton_trace;
  EXPECT_TRUE(GradientJacobian(frames, candidates, poses, step_mm, step_rad, 1) == a)
      << "bit-identical for any thread count";

  // The one-pass sums take the same derivative from each sample's slopes: the limit of the
  // differences as their step shrinks (a forward step sees the trilinear interpolant's
  // second-order terms and the cell faces it crosses: 0.9 % of the Gauss-Newton scale at a
  // twentieth of a voxel here, 0.25 % at a tenth of that, 0.08 % at a hundredth).
  const UncertaintySums sums = SumForUncertainty(frames, candidates, poses, 2);
  const Eigen::MatrixXd slopes = sums.Curvature();
  const auto largest_difference = [&](const Eigen::MatrixXd& other) {
    double largest = 0.0;
    for (int f = 0; f < m; ++f) {
      const double scale = at.hessian.block<6, 6>(6 * f, 6 * f).diagonal().cwiseAbs().maxCoeff();
      for (int b = 0; b < m; ++b) {
        largest = std::max(largest, (other.block<6, 6>(6 * f, 6 * b) -
                                     slopes.block<6, 6>(6 * f, 6 * b)).cwiseAbs().maxCoeff() /
                                        scale);
      }
    }
    return largest;
  };
  std::vector<double> small_mm(m), small_rad(m);
  for (int f = 0; f < m; ++f) {
    small_mm[f] = 0.01 * step_mm[f];
    small_rad[f] = 0.01 * step_rad[f];
  }
  const double at_step = largest_difference(numeric);
  const double at_small_step =
      largest_difference(GradientJacobian(frames, candidates, poses, small_mm, small_rad, 2));
  EXPECT_LT(at_step, 2e-2);
  EXPECT_LT(at_small_step, 2e-3);
  EXPECT_LT(at_small_step, 0.3 * at_step);
  // Its other sums are the stream's: cost and observations over the same voxels.
  EXPECT_NEAR(sums.cost, at.cost, 1e-9 * at.cost);
  EXPECT_EQ(sums.observations, at.observations);
  EXPECT_EQ(sums.voxels, at.voxels);
  const UncertaintySums one_thread = SumForUncertainty(frames, candidates, poses, 1);
  EXPECT_TRUE(one_thread.Curvature() == slopes && one_thread.GradientCovariance() ==
              sums.GradientCovariance()) << "bit-identical for any thread count";
  // Every group's share adds up to the whole, and leaving one out leaves the others.
  int64_t voxels = 0;
  for (int g = 0; g < kUncertaintyGroups; ++g) voxels += sums.group_voxels[g];
  EXPECT_EQ(voxels, sums.voxels);
  EXPECT_TRUE((sums.Curvature(3) + sums.curvature[3]).isApprox(slopes, 1e-12));
}

// The determination check on a subset of the cubes (about 4 per free pose parameter) gives
// the verdict and, within the subset's spread, the errors of the check on all of them; with
// the sums over all of them given (as --uncertainty shares them) it judges on those alone,
// as without a subset.
TEST(PoseUncertainty, DeterminationOnASubsetAgreesWithAllTheCandidates) {
  DSR_SKIP_HEAVY_UNDER_SANITIZER();
  const SimulatedSequence s = Sequence(25.0);
  const RegistrationResult r = RegisterWithUncertainty(s);
  std::vector<Frame> frames;
  for (size_t i = 0; i < s.frames.size(); ++i) frames.emplace_back(s.frames[i], s.masks[i]);
  const std::vector<Eigen::Isometry3d>& poses = r.frame_from_world;
  ImageGeometry grid;
  std::string error;
  // A fine panorama, so that the candidates fill enough cubes for a subset.
  ASSERT_TRUE(BuildPanoramaGrid(frames, poses, 0.5, &grid, &error)) << error;
  const CandidateSet candidates = BuildCandidates(frames, poses, grid, 0);
  const int n = 6 * (static_cast<int>(frames.size()) - 1);
  ASSERT_GE(candidates.num_voxels() / 512.0 / (4.0 * n), 2.0) << "too few cubes for a subset";
  std::vector<UndeterminedPose> undetermined;
  std::string why;
  std::vector<double> subset_error, all_error, shared_error;
  ASSERT_TRUE(UndeterminedPoses(frames, candidates, poses, s.masks, StreamContext{2}, 1.0,
                                &undetermined, &why, &subset_error))
      << why;
  EXPECT_TRUE(undetermined.empty());
  const UncertaintySums all = SumForUncertainty(frames, candidates, poses, 2);
  ASSERT_TRUE(UndeterminedPoses(frames, candidates, poses, s.masks, StreamContext{2}, 1.0,
                                &undetermined, &why, &all_error, &all))
      << why;
  EXPECT_TRUE(undetermined.empty());
  ASSERT_EQ(subset_error.size(), frames.size());
  ASSERT_EQ(all_error.size(), frames.size());
  for (size_t i = 1; i < frames.size(); ++i) {
    EXPECT_GT(all_error[i], 0.0);
    EXPECT_NE(subset_error[i], all_error[i]) << "the subset judged, not all the candidates";
    EXPECT_NEAR(subset_error[i], all_error[i], 0.3 * all_error[i]) << "frame " << i;
  }
  // A limit the subset cannot vouch for: all of the candidates judge.
  const double limit = 1.05 * *std::max_element(all_error.begin(), all_error.end());
  ASSERT_TRUE(UndeterminedPoses(frames, candidates, poses, s.masks, StreamContext{2}, limit,
                                &undetermined, &why, &shared_error))
      << why;
  EXPECT_TRUE(undetermined.empty());
  EXPECT_TRUE(shared_error == all_error);
  ASSERT_TRUE(UndeterminedPoses(frames, candidates, poses, s.masks, StreamContext{2},
                                0.9 * limit, &undetermined, &why, &shared_error))
      << why;
  EXPECT_FALSE(undetermined.empty()) << "only all of the candidates refuse";
}

// With gains and offsets (runs that estimate them), the sums are those of the corrected
// frames gain * I + offset, built as such (the slow twin: every voxel corrected first), and
// the check judges on them.
TEST(PoseUncertainty, CorrectedSumsAreThoseOfCorrectedFrames) {
  const SimulatedSequence s = Sequence(10.0);
  const int m = static_cast<int>(s.frames.size());
  std::vector<Photometric> photometric(m);
  for (int i = 1; i < m; ++i) {
    photometric[i].log_gain = (i % 2 == 0 ? 0.2 : -0.3);
    photometric[i].offset = 4.0 * i - 7.0;
  }
  std::vector<Frame> frames, corrected;
  std::vector<Image> corrected_images = s.frames;
  for (int i = 0; i < m; ++i) {
    frames.emplace_back(s.frames[i], s.masks[i]);
    for (float& v : corrected_images[i].voxels) {
      v = static_cast<float>(photometric[i].Correct(v));
    }
    corrected.emplace_back(corrected_images[i], s.masks[i]);
  }
  const std::vector<Eigen::Isometry3d>& poses = s.frame_from_world;
  ImageGeometry grid;
  std::string error;
  ASSERT_TRUE(BuildPanoramaGrid(frames, poses, 1.0, &grid, &error)) << error;
  const CandidateSet candidates = BuildCandidates(frames, poses, grid, 0);
  for (int keep : {1, 3}) {
    const UncertaintySums fast =
        SumForUncertainty(frames, candidates, poses, 2, keep, &photometric);
    const UncertaintySums twin = SumForUncertainty(corrected, candidates, poses, 2, keep);
    EXPECT_EQ(fast.voxels, twin.voxels);
    EXPECT_EQ(fast.observations, twin.observations);
    EXPECT_NEAR(fast.cost, twin.cost, 1e-5 * twin.cost) << "keep " << keep;
    const Eigen::MatrixXd a = twin.Curvature(), b = twin.GradientCovariance();
    EXPECT_LT((fast.Curvature() - a).cwiseAbs().maxCoeff(), 1e-5 * a.cwiseAbs().maxCoeff());
    EXPECT_LT((fast.GradientCovariance() - b).cwiseAbs().maxCoeff(),
              1e-5 * b.cwiseAbs().maxCoeff());
    // The correction does change them (unit gains would leave them as they were).
    const UncertaintySums plain = SumForUncertainty(frames, candidates, poses, 2, keep);
    EXPECT_GT(std::abs(plain.cost - twin.cost), 1e-3 * twin.cost);
  }
  std::vector<UndeterminedPose> undetermined;
  std::string why;
  ASSERT_TRUE(UndeterminedPoses(frames, candidates, poses, s.masks, StreamContext{2}, 1.0,
                                &undetermined, &why, nullptr, nullptr, &photometric))
      << why;
  EXPECT_TRUE(undetermined.empty());
}

TEST(PoseUncertainty, IsPositiveDefiniteAndGrowsWithTheNoise) {
  const RegistrationResult low = RegisterWithUncertainty(Sequence(10.0));
  const RegistrationResult high = RegisterWithUncertainty(Sequence(40.0));
  for (const RegistrationResult* r : {&low, &high}) {
    ASSERT_EQ(r->uncertainty.covariance.size(), 4u) << r->uncertainty_note;
    EXPECT_TRUE(r->uncertainty.covariance[0].isZero(0.0));
    EXPECT_EQ(r->uncertainty.predicted_tre_mm[0], 0.0);
    EXPECT_GT(r->uncertainty.noise_sigma, 0.0);
    for (int i = 1; i < 4; ++i) {
      const Matrix6d& c = r->uncertainty.covariance[i];
      EXPECT_TRUE(c.isApprox(c.transpose(), 1e-12));
      EXPECT_GT(Eigen::SelfAdjointEigenSolver<Matrix6d>(c).eigenvalues().minCoeff(), 0.0);
      EXPECT_GT(r->uncertainty.predicted_tre_mm[i], 1e-4);
      EXPECT_LT(r->uncertainty.predicted_tre_mm[i], 1.0);
    }
  }
  // Four times the noise: a larger predicted error (not exactly four times: the frames are
  // clamped to 0..255 and smoothed by resampling, and the curvature A depends on the noise).
  for (int i = 1; i < 4; ++i) {
    const double ratio = high.uncertainty.predicted_tre_mm[i] / low.uncertainty.predicted_tre_mm[i];
    EXPECT_GT(ratio, 1.4) << "frame " << i;
    EXPECT_LT(ratio, 6.0) << "frame " << i;
  }
  // Off by default: nothing estimated.
  RegistrationOptions o;
  EXPECT_FALSE(o.uncertainty);
}

// dsr_compare's row (pipeline/experiment.h) carries the mean predicted TRE and the mean
// normalised squared error for dsr, NaN for a method without the estimate; the CSV has
// both columns, empty for the latter.
TEST(PoseUncertainty, ComparisonRowsCarryIt) {
  const SimulatedSequence s = Sequence(10.0);
  ExperimentSequence sequence{"seq", s.frames, s.masks, s.frame_from_world, {}};
  RegistrationOptions o;
  o.solve.progress = false;
  o.solve.num_threads = 2;
  o.pyramid_levels = 2;
  o.pyramid_min_size = 8;
  o.uncertainty = true;
  ComparisonRow dsr = RunMethod(sequence, o);
  // A baseline has no estimate (Validate refuses uncertainty for it): its row runs without.
  o.mode = dsr::Mode::kApe;
  o.uncertainty = false;
  ComparisonRow ape = RunMethod(sequence, o);
  ASSERT_TRUE(dsr.ok) << dsr.failure;
  ASSERT_TRUE(ape.ok) << ape.failure;
  const RegistrationResult direct = RegisterWithUncertainty(s);
  double predicted = 0.0;
  for (int i = 1; i < 4; ++i) predicted += direct.uncertainty.predicted_tre_mm[i] / 3.0;
  EXPECT_NEAR(dsr.predicted_tre_mm, predicted, 1e-12);
  EXPECT_GT(dsr.nees, 0.0);
  EXPECT_TRUE(std::isfinite(dsr.nees));
  EXPECT_TRUE(std::isnan(ape.predicted_tre_mm));
  EXPECT_TRUE(std::isnan(ape.nees));
  dsr.method = "dsr";
  ape.method = "ape";
  const std::string csv = ComparisonCsv({dsr, ape});
  EXPECT_NE(csv.find(",predicted_tre_mm,nees,mae_gain,mae_offset,failure,recoveries,"),
            std::string::npos)
      << csv;
  EXPECT_NE(csv.find(",,,,,0,"), std::string::npos)
      << "ape: empty predicted_tre_mm, nees, mae_gain, mae_offset, failure; 0 recoveries";
}

}  // namespace
}  // namespace dsr
