// DSR at field-of-view edges that cut through structure (frames 0 outside a ball, masks
// equal to that ball: test_problems.h `ball_field_of_view`), where the gradient rule of
// image/frame.h matters (docs/design.md section 2.3): the gradient g and Gauss-Newton
// matrix H the solver uses are the derivatives of the cost it evaluates, and a noise-free
// solve reaches the ground truth. Both tests fail under the former rule (sigma_ij from the
// 8 corners alone, so central differences at the edge read the zero background): see the
// tolerances below, and solves that stopped 0.15-0.6 mm (mean TRE) off the ground truth.
#include <gtest/gtest.h>

#include "dsr/dsr_reduced/dsr_solver.h"
#include "dsr/dsr_reduced/reduced_cost.h"
#include "dsr/eval/eval.h"
#include "dsr/tests/support/tolerances.h"
#include "dsr/tests/support/sanitizer.h"
#include "dsr/tests/support/test_problems.h"

namespace dsr {
namespace {

using testing_problems::Candidates;
using testing_problems::InteriorCandidates;
using testing_problems::MakeSequence;
using testing_problems::MaxPoseDifference;
using testing_problems::Perturbed;
using testing_problems::SequenceOptions;
using testing_problems::TestSequence;

// What "agree" can mean: the cost f = sum r^2 samples trilinear interpolants, so it is only
// piecewise smooth (its exact derivative is the interpolant's slope, constant along each
// cell axis), while g and H are built from interpolated central-difference gradient volumes,
// a smooth surrogate that differs per sample by about (w - 1/2) d2I/du2 (w: the sample's
// offset in its cell). Summed over samples at diverse offsets (frames rotated up to 0.3 rad
// per axis) these differences mostly cancel, so on noise-free frames g and H agree with
// central differences of f to a few per cent: relative errors at most 0.094 (g) and 0.117
// (H) over the trials below, against 0.22-2.8 and 0.99-15 under the former rule, which
// thus fails both bounds on every trial. Noise would add the derivative of the
// interpolated noise's variance with the sub-voxel offset, which the surrogate leaves out
// by design: these checks are noise-free.
constexpr double kGradientTolerance = 0.15;
constexpr double kGaussNewtonTolerance = 0.25;
// No sample may switch sigma_ij between the +-h evaluations (a jump in f): candidates keep
// only samples at least kInsetCells inside the valid cells, and the steps move no sample
// by more than |p_ij| h (< 30 mm x 1e-4 rad = 3e-3 cells): far below the inset, far above
// the rounding of f (double sums of float voxels).
constexpr double kInsetCells = 0.05;
constexpr double kTranslationStepMm = 1e-3;
constexpr double kRotationStepRad = 1e-4;
// TRE bound (eval/eval.h; mm, at every field-of-view voxel): on noise-free lattice
// problems every residual vanishes at the ground truth, so a solve ends there up to
// rounding.
using testing_tolerances::kNoiseFreeAccuracyMm;

SequenceOptions EdgeOptions(int num_frames, bool lattice, uint64_t seed) {
  SequenceOptions o;
  o.num_frames = num_frames;
  o.size = 18;
  o.ball_field_of_view = true;
  o.lattice = lattice;
  o.max_rotation = lattice ? 0.0 : 0.3;
  o.seed = seed;
  return o;
}

// The free poses' part (frames 1..m-1) of a 6m system.
Eigen::VectorXd Free(const Eigen::VectorXd& v) { return v.tail(v.size() - 6); }
Eigen::MatrixXd Free(const Eigen::MatrixXd& h) {
  return h.bottomRightCorner(h.rows() - 6, h.cols() - 6);
}

// Poses with frame 1 + c / 6 moved by `sign` steps along tangent axis c % 6 (left
// perturbation Exp(delta) T, tangent [rho; phi]; geometry/se3.h). Returns the step.
double Moved(int c, double sign, std::vector<Eigen::Isometry3d>* poses) {
  const int axis = c % 6;
  const double h = axis < 3 ? kTranslationStepMm : kRotationStepRad;
  Vector6d delta = Vector6d::Zero();
  delta[axis] = sign * h;
  (*poses)[1 + c / 6] = ExpSE3(delta) * (*poses)[1 + c / 6];
  return h;
}

TEST(FieldOfViewEdge, GradientAndGaussNewtonMatrixMatchCentralDifferences) {
  uint64_t seed = 101;
  // Under the sanitizers 2 trials: the same code, not the spread over many problems.
  const int trials = testing_support::FullUnlessSanitized(8, 2);
  for (int trial = 0; trial < trials; ++trial) {
    const TestSequence s = MakeSequence(EdgeOptions(3, false, seed++));
    const auto poses = Perturbed(s.ground_truth, 0.03, 1.0, seed++);
    const CandidateSet cand = InteriorCandidates(s, poses, kInsetCells);
    ASSERT_GT(cand.num_voxels(), 500);
    // g and H as the solver gets them (the streamed fast path, this CPU's kernels).
    ReducedSystem system;
    AccumulateReducedSystem(s.frames, cand, poses, 0, cand.num_voxels(), true, StreamContext{2},
                            &system);
    const int n = 6 * (static_cast<int>(s.frames.size()) - 1);

    // df/ddelta = 2 J^T r = 2 g, against central differences of f.
    const auto cost = [&](const std::vector<Eigen::Isometry3d>& at) {
      ReducedSystem f;
      AccumulateReducedSystem(s.frames, cand, at, 0, cand.num_voxels(), false, StreamContext{2},
                              &f);
      return f.cost;
    };
    Eigen::VectorXd numeric_gradient(n);
    for (int c = 0; c < n; ++c) {
      auto plus = poses, minus = poses;
      const double h = Moved(c, 1.0, &plus);
      Moved(c, -1.0, &minus);
      numeric_gradient[c] = (cost(plus) - cost(minus)) / (2.0 * h);
    }
    EXPECT_LT((2.0 * Free(system.gradient) - numeric_gradient).norm() / numeric_gradient.norm(),
              kGradientTolerance)
        << "trial " << trial << "\nanalytic " << 2.0 * Free(system.gradient).transpose()
        << "\nnumeric  " << numeric_gradient.transpose();

    // The Gauss-Newton matrix H = J^T J, against J from central differences of the
    // residuals r_ij = I_i(p_ij) - mu_j (the per-voxel reference cost's residual vector).
    DsrOptions reference_options;
    reference_options.reference_cost = true;
    DsrProblem reference(s.frames, cand, poses, reference_options);
    ceres::Problem::EvaluateOptions evaluate;
    for (size_t i = 1; i < s.frames.size(); ++i) {
      evaluate.parameter_blocks.push_back(reference.pose_parameters(i));
    }
    const auto residuals = [&](const std::vector<Eigen::Isometry3d>& at) {
      for (size_t i = 1; i < at.size(); ++i) PoseToParameters(at[i], reference.pose_parameters(i));
      std::vector<double> r;
      double f;
      reference.problem().Evaluate(evaluate, &f, &r, nullptr, nullptr);
      return Eigen::VectorXd(Eigen::Map<Eigen::VectorXd>(r.data(), r.size()));
    };
    Eigen::MatrixXd numeric_jacobian(residuals(poses).size(), n);
    for (int c = 0; c < n; ++c) {
      auto plus = poses, minus = poses;
      const double h = Moved(c, 1.0, &plus);
      Moved(c, -1.0, &minus);
      numeric_jacobian.col(c) = (residuals(plus) - residuals(minus)) / (2.0 * h);
    }
    const Eigen::MatrixXd numeric_hessian = numeric_jacobian.transpose() * numeric_jacobian;
    EXPECT_LT((Free(system.hessian) - numeric_hessian).norm() / numeric_hessian.norm(),
              kGaussNewtonTolerance)
        << "trial " << trial;
  }
}

// Noise-free and lattice-aligned (test_problems.h): the ground truth is the exact minimum.
// The solves use every candidate (samples cross the field-of-view edge as the poses move)
// and, as the pipeline does, rebuild the candidates at the poses reached until a solve no
// longer moves them.
TEST(FieldOfViewEdge, NoiseFreeSolveReachesGroundTruth) {
  uint64_t seed = 201;
  for (const int num_frames : {3, 4, 5}) {
    const TestSequence s = MakeSequence(EdgeOptions(num_frames, true, seed++));
    std::vector<Eigen::Isometry3d> poses = Perturbed(s.ground_truth, 0.02, 0.5, seed++);
    DsrOptions options;
    options.solve.progress = false;
    options.solve.num_threads = 2;
    options.solve.function_tolerance = 1e-20;
    options.solve.gradient_tolerance = 1e-20;
    options.solve.parameter_tolerance = 1e-15;
    options.solve.step_tolerance = 0.0;
    double moved = 1.0;
    for (int rebuild = 0; rebuild < 5 && moved > 1e-9; ++rebuild) {
      const CandidateSet cand = Candidates(s, poses);
      SolveReport report;
      std::string error;
      ASSERT_TRUE(SolveDsr(s.frames, cand, poses, options, &report, &error)) << error;
      ASSERT_TRUE(report.usable) << report.termination;
      moved = MaxPoseDifference(report.frame_from_world, poses).second;
      poses = report.frame_from_world;
    }
    const PoseErrorSummary error = ComparePoses(poses, s.ground_truth, s.masks, 1);
    EXPECT_LT(error.tre_max_mm, kNoiseFreeAccuracyMm) << "m=" << num_frames << "\n"
                                                      << error.Table();
    // The start was far from it.
    EXPECT_GT(ComparePoses(Perturbed(s.ground_truth, 0.02, 0.5, seed - 1), s.ground_truth,
                           s.masks, 1)
                  .tre_mean_mm,
              0.1);
  }
}

}  // namespace
}  // namespace dsr
