// DBA (docs/design.md section 3): analytic Jacobians, elimination ordering, ground-truth
// recovery, the closed-form panorama at convergence, linear solvers, memory guard.
#include "dsr/dba/dba_problem.h"

#include <ceres/gradient_checker.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "dsr/tests/support/pose_matchers.h"
#include "dsr/tests/support/tolerances.h"
#include "dsr/tests/support/sanitizer.h"
#include "dsr/tests/support/test_problems.h"

namespace dsr {
namespace {

using testing_problems::Candidates;
using testing_problems::MakeSequence;
using testing_problems::Perturbed;
using testing_problems::SequenceOptions;
using testing_poses::FramesFromWorldNear;

// Tangent-space central differences through PoseManifold::Plus on a linear field agree
// with the analytic Jacobian to ~1e-7 (float voxels).
constexpr double kTangentNumericTolerance = 1e-6;
// ceres::GradientChecker (Ceres 2.1) differentiates in the 7-D ambient space; on this
// problem it reports a systematic 1.6e-4 relative difference in the rotation columns that
// does not change with the step size, while our own ambient differences times PlusJacobian
// match to 1e-7. Until that is understood the checker runs at this looser precision.
constexpr double kGradientCheckPrecision = 1e-3;

DbaOptions QuietOptions() {
  DbaOptions o;
  o.solve.progress = getenv("DSR_TEST_LOG") != nullptr;
  o.solve.num_threads = 2;
  return o;
}

TEST(DbaResidual, AnalyticJacobianMatchesNumeric) {
  const Frame frame = testing_problems::LinearRampFrame(10.0);
  const ImageGeometry& g = frame.geometry();
  Vector6d d;
  d << 0.4, -0.3, 0.2, 0.05, -0.04, 0.03;
  const Eigen::Isometry3d pose = ExpSE3(d);
  const Eigen::Vector3d p = pose.inverse() * g.IndexToPhysical(Eigen::Vector3d(7.3, 8.1, 6.6));
  DbaResidual residual(&frame, p);
  PoseManifold manifold;
  std::vector<const ceres::Manifold*> manifolds = {&manifold, nullptr};
  ceres::NumericDiffOptions numeric_options;
  ceres::GradientChecker checker(&residual, &manifolds, numeric_options);
  double x[kPoseAmbientSize];
  PoseToParameters(pose, x);
  double intensity = 42.0;
  const double* parameters[] = {x, &intensity};
  ceres::GradientChecker::ProbeResults results;
  EXPECT_TRUE(checker.Probe(parameters, kGradientCheckPrecision, &results)) << results.error_log;

  // The model Ceres's minimiser uses: d e(Plus(x, h e_a)) / dh in the tangent space.
  double residual_value;
  double j_pose[kPoseAmbientSize], j_intensity;
  double* jacobians[] = {j_pose, &j_intensity};
  ASSERT_TRUE(residual.Evaluate(parameters, &residual_value, jacobians));
  Eigen::Matrix<double, 7, 6, Eigen::RowMajor> plus_jacobian;
  manifold.PlusJacobian(x, plus_jacobian.data());
  const RowVector6d analytic =
      Eigen::Map<Eigen::Matrix<double, 1, kPoseAmbientSize>>(j_pose) * plus_jacobian;
  for (int a = 0; a < 6; ++a) {
    const double h = 1e-5;
    Vector6d delta = Vector6d::Zero();
    double xp[kPoseAmbientSize], xm[kPoseAmbientSize], rp, rm;
    delta[a] = h;
    manifold.Plus(x, delta.data(), xp);
    delta[a] = -h;
    manifold.Plus(x, delta.data(), xm);
    const double* pp[] = {xp, &intensity};
    const double* pm[] = {xm, &intensity};
    ASSERT_TRUE(residual.Evaluate(pp, &rp, nullptr));
    ASSERT_TRUE(residual.Evaluate(pm, &rm, nullptr));
    EXPECT_NEAR((rp - rm) / (2 * h), analytic[a], kTangentNumericTolerance * 20.0) << a;
  }
}

// The photometric residual e = M - (exp(log_gain) I + offset): every block's Jacobian
// against Ceres's numeric differentiation, on the pose manifold.
TEST(DbaPhotometricResidual, AnalyticJacobianMatchesNumeric) {
  const Frame frame = testing_problems::LinearRampFrame(10.0);
  const ImageGeometry& g = frame.geometry();
  Vector6d d;
  d << 0.4, -0.3, 0.2, 0.05, -0.04, 0.03;
  const Eigen::Isometry3d pose = ExpSE3(d);
  const Eigen::Vector3d p = pose.inverse() * g.IndexToPhysical(Eigen::Vector3d(7.3, 8.1, 6.6));
  DbaPhotometricResidual residual(&frame, p);
  PoseManifold manifold;
  std::vector<const ceres::Manifold*> manifolds = {&manifold, nullptr, nullptr};
  ceres::NumericDiffOptions numeric_options;
  ceres::GradientChecker checker(&residual, &manifolds, numeric_options);
  double x[kPoseAmbientSize];
  PoseToParameters(pose, x);
  double intensity = 42.0;
  double photometric[2] = {0.2, -3.0};
  const double* parameters[] = {x, &intensity, photometric};
  ceres::GradientChecker::ProbeResults results;
  EXPECT_TRUE(checker.Probe(parameters, kGradientCheckPrecision, &results)) << results.error_log;
  // The value itself, in the frame's grey levels: (M - offset) / gain - I, against the
  // plain residual's M - I.
  DbaResidual plain(&frame, p);
  const double* plain_parameters[] = {x, &intensity};
  double r_plain, r;
  ASSERT_TRUE(plain.Evaluate(plain_parameters, &r_plain, nullptr));
  ASSERT_TRUE(residual.Evaluate(parameters, &r, nullptr));
  const double sample = intensity - r_plain;
  EXPECT_NEAR(r, (intensity + 3.0) / std::exp(0.2) - sample, 1e-9);
}

TEST(DbaResidual, UnobservedSampleHasZeroResidualAndJacobian) {
  ImageGeometry g;
  g.size = Eigen::Vector3i(8, 8, 8);
  const Frame frame(Image(g, 5.0f), Mask(g, 1));
  DbaResidual residual(&frame, Eigen::Vector3d(100.0, 0.0, 0.0));
  double x[kPoseAmbientSize];
  PoseToParameters(Eigen::Isometry3d::Identity(), x);
  double intensity = 3.0, r = -1.0, j_pose[kPoseAmbientSize], j_intensity = -1.0;
  const double* parameters[] = {x, &intensity};
  double* jacobians[] = {j_pose, &j_intensity};
  ASSERT_TRUE(residual.Evaluate(parameters, &r, jacobians));
  EXPECT_EQ(r, 0.0);
  EXPECT_EQ(j_intensity, 0.0);
  for (double v : j_pose) EXPECT_EQ(v, 0.0);
}

TEST(DbaProblem, IntensitiesFormAnIndependentSetForElimination) {
  SequenceOptions so;
  so.num_frames = 3;
  so.size = 12;
  const auto s = MakeSequence(so);
  const CandidateSet c = Candidates(s, s.ground_truth);
  DbaProblem dba(s.frames, c, s.ground_truth);
  std::vector<ceres::ResidualBlockId> blocks;
  dba.problem().GetResidualBlocks(&blocks);
  ASSERT_EQ(static_cast<int64_t>(blocks.size()), c.NumObservations());
  for (auto id : blocks) {
    std::vector<double*> params;
    dba.problem().GetParameterBlocksForResidualBlock(id, &params);
    ASSERT_EQ(params.size(), 2u);
    EXPECT_EQ(dba.problem().ParameterBlockSize(params[0]), kPoseAmbientSize);
    EXPECT_EQ(dba.problem().ParameterBlockSize(params[1]), 1);  // exactly one intensity
  }
  EXPECT_TRUE(dba.problem().IsParameterBlockConstant(dba.pose_parameters(0)));
  // Ceres validates the ordering (group 0 must be an independent set) in Solve.
  ceres::Solver::Options options;
  options.linear_solver_type = ceres::DENSE_SCHUR;
  options.linear_solver_ordering = dba.MakeOrdering();
  options.max_num_iterations = 1;
  ceres::Solver::Summary summary;
  ceres::Solve(options, &dba.problem(), &summary);
  EXPECT_TRUE(summary.IsSolutionUsable()) << summary.message;
  EXPECT_EQ(summary.num_parameter_blocks_reduced, c.num_voxels() + 2);
}

// Eq. 10 holds where the intensity block is stationary, i.e. where the solve converges. On a
// generic problem the trust region can stop at a rejected step before that (the Jacobians
// are interpolated central differences, not the derivative of the piecewise-linear cost;
// docs/design.md section 2.3), leaving the intensities of the last accepted Gauss-Newton
// step, which match eq. 10 only to first order in that step. Lattice-aligned frames with
// noise make the fixed point exact (test_problems.h), so the solve converges fully.
TEST(Dba, PanoramaAtConvergenceIsThePerVoxelMean) {
  SequenceOptions so;
  so.num_frames = 3;
  so.size = 14;
  so.lattice = true;
  so.noise_sigma = 2.0;
  const auto s = MakeSequence(so);
  const auto init = Perturbed(s.ground_truth, 0.02, 0.5, 3);
  const CandidateSet c = Candidates(s, init);
  DbaOptions options = QuietOptions();
  options.solve.function_tolerance = 1e-14;
  options.solve.parameter_tolerance = 1e-14;
  options.solve.gradient_tolerance = 1e-16;
  options.solve.step_tolerance = 0.0;  // converge fully (solve/convergence.h off)
  options.solve.max_rejected_steps = 0;
  SolveReport report;
  std::vector<float> intensities;
  std::string error;
  ASSERT_TRUE(SolveDba(s.frames, c, init, options, &report, &intensities, &error)) << error;
  double max_difference = 0.0;
  for (int64_t v = 0; v < c.num_voxels(); ++v) {
    double sum = 0.0;
    int k = 0;
    for (int i = 0; i < c.num_frames; ++i) {
      double value;
      if ((c.observers[v] >> i & 1u) &&
          ObserveSample(s.frames[i], report.frame_from_world[i], c.VoxelCenter(v), &value,
                        nullptr)) {
        sum += value;
        ++k;
      }
    }
    if (k > 0) max_difference = std::max(max_difference, std::abs(intensities[v] - sum / k));
  }
  // Eq. 10 to 1e-6 relative to intensities of ~100 (the panorama is returned as float).
  EXPECT_LT(max_difference, 1e-6 * 256.0);
}

// Frames 1..3 seen through a gain and an offset (frame 0 is the gauge): with photometric
// blocks DBA finds the poses and the corrections to frame 0's scale (gain 1/g, offset -o/g)
// to 1e-6 relative (the issue asks 1 %). Lattice-aligned, noise-free frames make the truth
// the exact minimum (test_problems.h).
TEST(Dba, PhotometricBlocksRecoverGainsAndOffsets) {
  DSR_SKIP_HEAVY_UNDER_SANITIZER();
  SequenceOptions so;
  so.num_frames = 4;
  so.size = 16;
  so.lattice = true;
  so.seed = 9;
  const auto s = MakeSequence(so);
  const double g[] = {1.0, 1.3, 0.8, 1.1}, o[] = {0.0, 12.0, -7.0, 4.0};
  std::vector<Frame> frames;
  for (int i = 0; i < so.num_frames; ++i) {
    Image image = s.images[i];
    for (float& v : image.voxels) v = static_cast<float>(g[i] * v + o[i]);
    frames.emplace_back(image, s.masks[i]);
  }
  const auto init = Perturbed(s.ground_truth, 0.01, 0.3, 5);
  ImageGeometry grid;
  std::string error;
  ASSERT_TRUE(BuildPanoramaGrid(frames, init, 1.0, &grid, &error)) << error;
  const CandidateSet c = BuildCandidates(frames, init, grid, 0);
  DbaOptions options = QuietOptions();
  options.photometric = true;
  options.solve.max_iterations = 200;
  options.solve.function_tolerance = 1e-14;
  options.solve.parameter_tolerance = 1e-14;
  options.solve.gradient_tolerance = 1e-16;
  options.solve.step_tolerance = 0.0;
  options.solve.max_rejected_steps = 0;
  SolveReport report;
  ASSERT_TRUE(SolveDba(frames, c, init, options, &report, nullptr, &error)) << error;
  ASSERT_TRUE(report.usable) << report.termination;
  ASSERT_EQ(report.photometric.size(), 4u);
  EXPECT_EQ(report.photometric[0].gain(), 1.0);
  EXPECT_EQ(report.photometric[0].offset, 0.0);
  for (int i = 1; i < so.num_frames; ++i) {
    EXPECT_NEAR(report.photometric[i].gain(), 1.0 / g[i], 1e-6 / g[i]) << i;
    EXPECT_NEAR(report.photometric[i].offset, -o[i] / g[i], 1e-6 * std::abs(o[i] / g[i])) << i;
  }
  EXPECT_THAT(report.frame_from_world,
              FramesFromWorldNear(s.ground_truth, 1e-5, testing_tolerances::kNoiseFreeAccuracyMm));
  // Without them, the same solve does not reach the truth.
  options.photometric = false;
  ASSERT_TRUE(SolveDba(frames, c, init, options, &report, nullptr, &error)) << error;
  EXPECT_TRUE(report.photometric.empty());
  EXPECT_GT(testing_problems::MaxPoseDifference(report.frame_from_world, s.ground_truth).second,
            1e-2);
}

TEST(Dba, MemoryGuardRefusesProblemsOverTheBudget) {
  SequenceOptions so;
  so.num_frames = 3;
  so.size = 12;
  const auto s = MakeSequence(so);
  const CandidateSet c = Candidates(s, s.ground_truth);
  DbaOptions options = QuietOptions();
  options.memory_budget_mb = 1.0 / 1024.0;  // 1 KiB: far below any real problem
  SolveReport report;
  std::string error;
  EXPECT_FALSE(SolveDba(s.frames, c, s.ground_truth, options, &report, nullptr, &error));
  EXPECT_NE(error.find("MiB"), std::string::npos) << error;
  EXPECT_NE(error.find("mode=dsr"), std::string::npos) << error;
  EXPECT_NE(error.find("(panorama_spacing)"), std::string::npos) << error;
  const DbaMemoryEstimate e = EstimateDbaMemory(c, 3, ceres::DENSE_SCHUR);
  EXPECT_EQ(e.residual_blocks, c.NumObservations());
  EXPECT_GT(EstimateDbaMemory(c, 3, ceres::DENSE_QR).bytes, e.bytes);
}

// Every linear solver flag value runs and reaches the same poses. A lattice-aligned problem
// (test_problems.h) has its exact minimum at the ground truth, so each solver can be run
// to the end and compared to 1e-8 rad / 1e-7 mm rather than to a stopping tolerance.
TEST(Dba, EveryLinearSolverReachesTheSamePoses) {
  SequenceOptions so;
  so.num_frames = 3;
  so.size = 11;
  so.frame_offset = 3.0;
  so.noise_sigma = 2.0;
  so.lattice = true;
  so.seed = 7;
  const auto s = MakeSequence(so);
  const auto init = testing_problems::Perturbed(s.ground_truth, 0.01, 0.3, 8);
  const CandidateSet c = testing_problems::InteriorCandidates(s, init, 1.0);
  ASSERT_GT(c.num_voxels(), 50);
  for (ceres::LinearSolverType solver : {ceres::DENSE_SCHUR, ceres::SPARSE_SCHUR,
                                         ceres::ITERATIVE_SCHUR, ceres::DENSE_QR,
                                         ceres::SPARSE_NORMAL_CHOLESKY}) {
    DbaOptions options = QuietOptions();
    options.solve.linear_solver = solver;
    options.solve.max_iterations = 2000;
    options.solve.function_tolerance = 1e-20;
    options.solve.gradient_tolerance = 1e-20;
    options.solve.parameter_tolerance = 1e-15;
    options.solve.step_tolerance = 0.0;
    options.solve.max_rejected_steps = 0;
    SolveReport report;
    std::string error;
    ASSERT_TRUE(SolveDba(s.frames, c, init, options, &report, nullptr, &error)) << error;
    ASSERT_TRUE(report.usable) << solver << ": " << report.termination;
    EXPECT_THAT(report.frame_from_world, FramesFromWorldNear(s.ground_truth, 1e-8, 1e-7))
        << solver << ": " << report.termination;
  }
}

}  // namespace
}  // namespace dsr
