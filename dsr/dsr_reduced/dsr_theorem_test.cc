// The paper's theorem (docs/design.md section 4), checked on several small problems:
//  1. DBA's undamped Gauss-Newton pose step after Schur elimination of the intensities
//     equals the DSR step, whatever the current intensities;
//  2. the fast chunked cost and the per-voxel reference give the same cost, gradient and
//     Gauss-Newton matrix;
//  3. f(T) equals the DBA cost minimised over the intensities (at M = the per-voxel mean);
//  4. full solves of DBA (Ceres Schur) and DSR (fast and reference cost) from the same
//     initial poses converge to the same poses, although Levenberg-Marquardt's damping of
//     the intensity blocks makes their intermediate iterates differ;
//  5. all of it with tied poses: views of T phases, one pose each (TiedPoses).
#include <ceres/ceres.h>
#include <ceres/gradient_checker.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <random>
#include <utility>

#include "dsr/dba/dba_problem.h"
#include "dsr/dsr_reduced/dsr_solver.h"
#include "dsr/dsr_reduced/photometric_at_poses.h"
#include "dsr/dsr_reduced/reduced_cost.h"
#include "dsr/solve/gauge.h"
#include "dsr/tests/support/fixed_point_options.h"
#include "dsr/tests/support/pose_matchers.h"
#include "dsr/tests/support/tolerances.h"
#include "dsr/tests/support/kernel_paths.h"
#include "dsr/tests/support/sanitizer.h"
#include "dsr/tests/support/test_problems.h"

namespace dsr {
namespace {

using testing_problems::Candidates;
using testing_problems::DenseJacobian;
using testing_problems::InteriorCandidates;
using testing_problems::MakeSequence;
using testing_problems::MaxPoseDifference;
using testing_problems::MovedTogether;
using testing_problems::Perturbed;
using testing_problems::PoseDifference;
using testing_problems::SequenceOptions;
using testing_poses::FramesFromWorldNear;
using testing_solve::FixedPointOptions;
using testing_tolerances::kFixedPointRotationRad;
using testing_tolerances::kFixedPointTranslationMm;
using testing_tolerances::kStepRelativeTolerance;
using testing_tolerances::kSystemRelativeTolerance;

struct Case {
  int num_frames, size;
  double noise;
  int erosion;
};

std::vector<Case> Cases() {
  return {{2, 12, 0.0, 1}, {3, 14, 5.0, 1}, {4, 16, 25.0, 3}};
}

SequenceOptions OptionsFor(const Case& c, uint64_t seed) {
  SequenceOptions o;
  o.num_frames = c.num_frames;
  o.size = c.size;
  o.noise_sigma = c.noise;
  o.erosion = c.erosion;
  o.seed = seed;
  return o;
}

// DBA's Gauss-Newton step over the free blocks `blocks` (poses and photometric blocks, in
// the step's order) with the intensities eliminated (Schur complement), solved densely;
// intensity columns with zero curvature (voxels nobody observes now) are dropped. Every
// residual block counts (the mean gauge's prior too).
Eigen::VectorXd DbaSchurStep(DbaProblem* dba, std::vector<double*> blocks) {
  int np = 0;
  for (double* block : blocks) np += dba->problem().ParameterBlockTangentSize(block);
  for (int64_t v = 0; v < dba->num_intensities(); ++v) blocks.push_back(dba->intensity(v));
  Eigen::VectorXd e;
  double cost;
  const Eigen::MatrixXd j = DenseJacobian(&dba->problem(), blocks, &e, &cost);
  const Eigen::MatrixXd jp = j.leftCols(np), jm = j.rightCols(j.cols() - np);
  const Eigen::VectorXd hmm = jm.colwise().squaredNorm().transpose();  // diagonal H_MM
  Eigen::MatrixXd s = jp.transpose() * jp;
  Eigen::VectorXd b = -jp.transpose() * e;
  const Eigen::MatrixXd hpm = jp.transpose() * jm;
  const Eigen::VectorXd bm = -jm.transpose() * e;
  for (int c = 0; c < jm.cols(); ++c) {
    if (hmm[c] == 0.0) continue;
    s -= hpm.col(c) * hpm.col(c).transpose() / hmm[c];
    b -= hpm.col(c) * bm[c] / hmm[c];
  }
  return s.ldlt().solve(b);
}

// The step above in frame 0's gauge. With `photometric`, each free frame's [log_gain,
// offset] follows its pose (8 per frame, the layout of the photometric reduced system).
Eigen::VectorXd DbaSchurStep(DbaProblem* dba, int num_frames, bool photometric = false) {
  std::vector<double*> blocks;
  for (int i = 1; i < num_frames; ++i) {
    blocks.push_back(dba->pose_parameters(i));
    if (photometric) blocks.push_back(dba->photometric_parameters(i));
  }
  return DbaSchurStep(dba, std::move(blocks));
}

// `per_frame`: 6, or 8 with photometric parameters (frame 0's are the gauge).
Eigen::VectorXd ReducedStep(const ReducedSystem& system, int per_frame = 6) {
  const int n = static_cast<int>(system.gradient.size()) - per_frame;
  return system.hessian.bottomRightCorner(n, n).ldlt().solve(-system.gradient.tail(n));
}

double RelativeDifference(const Eigen::VectorXd& a, const Eigen::VectorXd& b) {
  return (a - b).norm() / std::max(1e-300, b.norm());
}

TEST(Theorem, DbaSchurStepEqualsReducedStepForAnyIntensities) {
  uint64_t seed = 11;
  for (const Case& c : Cases()) {
    const auto s = MakeSequence(OptionsFor(c, seed++));
    const auto poses = Perturbed(s.ground_truth, 0.02, 0.7, seed++);
    const CandidateSet cand = Candidates(s, poses);
    ASSERT_GT(cand.num_voxels(), 100);
    ReducedSystem reduced;
    AccumulateReducedSystem(s.frames, cand, poses, 0, cand.num_voxels(), true, StreamContext{2},
                            &reduced);
    const Eigen::VectorXd dsr_step = ReducedStep(reduced);

    DbaProblem dba(s.frames, cand, poses);
    const Eigen::VectorXd dba_step = DbaSchurStep(&dba, c.num_frames);
    EXPECT_LT(RelativeDifference(dba_step, dsr_step), kStepRelativeTolerance)
        << "m=" << c.num_frames << "\nDBA " << dba_step.transpose() << "\nDSR "
        << dsr_step.transpose();

    // Replace the intensities by arbitrary values: the pose step must not change.
    std::mt19937_64 rng(seed++);
    std::uniform_real_distribution<double> u(-500.0, 500.0);
    for (int64_t v = 0; v < dba.num_intensities(); ++v) *dba.intensity(v) = u(rng);
    const Eigen::VectorXd dba_step_random = DbaSchurStep(&dba, c.num_frames);
    EXPECT_LT(RelativeDifference(dba_step_random, dsr_step), kStepRelativeTolerance)
        << "m=" << c.num_frames;
  }
}

// Frames 1.. of `s` seen through gains `g` and offsets `o` (one per frame; frame 0's are
// not used): frame i's intensities become g_i I + o_i.
void SeeThroughGains(const double* g, const double* o, testing_problems::TestSequence* s) {
  for (size_t i = 1; i < s->frames.size(); ++i) {
    Image image = s->images[i];
    for (float& v : image.voxels) v = static_cast<float>(g[i] * v + o[i]);
    s->frames[i] = Frame(image, s->masks[i]);
  }
}

// Photometric parameters away from the gauge: log gains within +/-0.2, offsets +/-10.
std::vector<Photometric> RandomPhotometric(int m, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> log_gain(-0.2, 0.2), offset(-10.0, 10.0);
  std::vector<Photometric> out(m);
  for (int i = 1; i < m; ++i) out[i] = {log_gain(rng), offset(rng)};
  return out;
}

// The theorem's step with photometric parameters: DBA's Schur-reduced Gauss-Newton step
// over poses and [log_gain, offset] equals DSR's from the 8 x 8-block reduced system.
TEST(Theorem, PhotometricDbaSchurStepEqualsReducedStep) {
  uint64_t seed = 111;
  for (const Case& c : Cases()) {
    const auto s = MakeSequence(OptionsFor(c, seed++));
    const auto poses = Perturbed(s.ground_truth, 0.02, 0.7, seed++);
    const auto photometric = RandomPhotometric(c.num_frames, seed++);
    const CandidateSet cand = Candidates(s, poses);
    ReducedSystem reduced;
    AccumulateReducedPhotometricSystem(s.frames, cand, poses, photometric, 0, cand.num_voxels(),
                                       true, StreamContext{2}, &reduced);
    ASSERT_EQ(reduced.gradient.size(), 8 * c.num_frames);
    const Eigen::VectorXd dsr_step = ReducedStep(reduced, 8);
    DbaProblem dba(s.frames, cand, poses, photometric);
    const Eigen::VectorXd dba_step = DbaSchurStep(&dba, c.num_frames, true);
    EXPECT_LT(RelativeDifference(dba_step, dsr_step), kStepRelativeTolerance)
        << "m=" << c.num_frames << "\nDBA " << dba_step.transpose() << "\nDSR "
        << dsr_step.transpose();
    // The step moves the photometric parameters too (they are not at their optimum).
    EXPECT_GT(dsr_step.segment<2>(6).norm(), 0.0);
    // Unlike the plain residual, u (M - b) - I is bilinear in the gain and M, so DBA's
    // step depends on M: the identity holds at the eliminated intensities (DbaProblem
    // starts there), the weighted mean mu, not at any M (docs/design.md 2.8).
    std::mt19937_64 rng(seed++);
    std::uniform_real_distribution<double> u(-500.0, 500.0);
    for (int64_t v = 0; v < dba.num_intensities(); ++v) *dba.intensity(v) = u(rng);
    EXPECT_GT(RelativeDifference(DbaSchurStep(&dba, c.num_frames, true), dsr_step), 1e-3)
        << "m=" << c.num_frames;
  }
}

// The theorem's step in the mean gauge (docs/design.md 4.8): every pose free, frame 0's
// too, and one MeanPosePrior block in each problem, built from the same start, centres and
// stiffness. DBA's Schur-reduced Gauss-Newton step over every pose (and, with photometric
// parameters, those of frames 1..m-1) equals DSR's, from a start where frame 0 is not the
// identity; with photometric parameters at the eliminated intensities (DbaProblem starts
// there), as in frame 0's gauge.
TEST(Theorem, MeanGaugeDbaSchurStepEqualsReducedStepWithThePrior) {
  uint64_t seed = 131;
  for (bool photometric : {false, true}) {
    for (const Case& c : Cases()) {
      const auto s = MakeSequence(OptionsFor(c, seed++));
      const auto poses = MovedTogether(Perturbed(s.ground_truth, 0.02, 0.7, seed), seed + 1);
      seed += 2;
      const std::vector<Photometric> start =
          photometric ? RandomPhotometric(c.num_frames, seed++) : std::vector<Photometric>();
      const CandidateSet cand = Candidates(s, poses);
      DsrOptions options;
      options.gauge = Gauge::kMean;
      options.photometric = photometric;
      options.initial_photometric = start;
      options.solve.num_threads = 2;
      DsrProblem dsr(s.frames, cand, poses, options);
      DbaProblem dba(s.frames, cand, poses, start, RobustLoss(), Gauge::kMean,
                     StreamContextFor(options.solve));
      // Both in the order of DSR's fast path: every pose, then the photometric blocks.
      std::vector<double*> dsr_blocks, dba_blocks;
      for (int i = 0; i < c.num_frames; ++i) {
        dsr_blocks.push_back(dsr.pose_parameters(i));
        dba_blocks.push_back(dba.pose_parameters(i));
      }
      for (int i = 1; photometric && i < c.num_frames; ++i) {
        dsr_blocks.push_back(dsr.photometric_parameters(i));
        dba_blocks.push_back(dba.photometric_parameters(i));
      }
      Eigen::VectorXd r;
      double cost;
      const Eigen::MatrixXd j = DenseJacobian(&dsr.problem(), dsr_blocks, &r, &cost);
      const Eigen::VectorXd dsr_step = (j.transpose() * j).ldlt().solve(-j.transpose() * r);
      const Eigen::VectorXd dba_step = DbaSchurStep(&dba, dba_blocks);
      EXPECT_LT(RelativeDifference(dba_step, dsr_step), kStepRelativeTolerance)
          << "m=" << c.num_frames << " photometric=" << photometric << "\nDBA "
          << dba_step.transpose() << "\nDSR " << dsr_step.transpose();
      // Frame 0 takes part in the step.
      EXPECT_GT(dsr_step.head<6>().norm(), 0.05 * dsr_step.head(6 * c.num_frames).norm())
          << "m=" << c.num_frames;
    }
  }
}

// With photometric parameters f(T, a, b) is DBA's cost minimised over the intensities too:
// at M = the u^2-weighted mean of the corrected observations, where DbaProblem starts.
TEST(Theorem, PhotometricReducedCostIsTheDbaCostMinimisedOverIntensities) {
  uint64_t seed = 121;
  for (const Case& c : Cases()) {
    const auto s = MakeSequence(OptionsFor(c, seed++));
    const auto poses = Perturbed(s.ground_truth, 0.02, 0.7, seed++);
    const auto photometric = RandomPhotometric(c.num_frames, seed++);
    const CandidateSet cand = Candidates(s, poses);
    ReducedSystem reduced;
    AccumulateReducedPhotometricSystem(s.frames, cand, poses, photometric, 0, cand.num_voxels(),
                                       false, StreamContext{1}, &reduced);
    DbaProblem dba(s.frames, cand, poses, photometric);
    double dba_cost = 0.0;
    dba.problem().Evaluate(ceres::Problem::EvaluateOptions(), &dba_cost, nullptr, nullptr,
                           nullptr);
    EXPECT_NEAR(2.0 * dba_cost, reduced.cost, 1e-9 * reduced.cost);
    for (double step : {1.0, -1.0}) {
      *dba.intensity(cand.num_voxels() / 2) += step;
      double perturbed_cost = 0.0;
      dba.problem().Evaluate(ceres::Problem::EvaluateOptions(), &perturbed_cost, nullptr,
                             nullptr, nullptr);
      EXPECT_GT(perturbed_cost, dba_cost);
      *dba.intensity(cand.num_voxels() / 2) -= step;
    }
  }
}

TEST(Theorem, ReducedCostIsTheDbaCostMinimisedOverIntensities) {
  uint64_t seed = 21;
  for (const Case& c : Cases()) {
    const auto s = MakeSequence(OptionsFor(c, seed++));
    const auto poses = Perturbed(s.ground_truth, 0.02, 0.7, seed++);
    const CandidateSet cand = Candidates(s, poses);
    ReducedSystem reduced;
    AccumulateReducedSystem(s.frames, cand, poses, 0, cand.num_voxels(), false, StreamContext{1},
                            &reduced);
    // DbaProblem starts at M = the per-voxel mean, the minimiser over M for these poses.
    DbaProblem dba(s.frames, cand, poses);
    double dba_cost = 0.0;
    dba.problem().Evaluate(ceres::Problem::EvaluateOptions(), &dba_cost, nullptr, nullptr,
                           nullptr);
    EXPECT_NEAR(2.0 * dba_cost, reduced.cost, 1e-9 * reduced.cost);
    // Any other M costs more.
    *dba.intensity(cand.num_voxels() / 2) += 1.0;
    double perturbed_cost = 0.0;
    dba.problem().Evaluate(ceres::Problem::EvaluateOptions(), &perturbed_cost, nullptr, nullptr,
                           nullptr);
    EXPECT_GT(perturbed_cost, dba_cost);
  }
}


struct ModePoses {
  std::vector<Eigen::Isometry3d> dba, dsr_fast, dsr_reference;
};

ModePoses SolveAllModes(const testing_problems::TestSequence& s,
                        const CandidateSet& cand,
                        const std::vector<Eigen::Isometry3d>& init,
                        int max_iterations,
                        Gauge gauge = Gauge::kFrame0) {
  ModePoses out;
  std::string error;
  SolveReport report;
  DbaOptions dba;
  dba.gauge = gauge;
  // DBA's damping also acts on every intensity block, which slows its approach (linear
  // convergence with a rate near 0.9 on these problems): give it more iterations.
  dba.solve = FixedPointOptions(max_iterations > 1 ? 10 * max_iterations : 1);
  EXPECT_TRUE(SolveDba(s.frames, cand, init, dba, &report, nullptr, &error)) << error;
  EXPECT_TRUE(report.usable) << report.termination;
  out.dba = report.frame_from_world;
  DsrOptions fast;
  fast.gauge = gauge;
  fast.solve = FixedPointOptions(max_iterations);
  EXPECT_TRUE(SolveDsr(s.frames, cand, init, fast, &report, &error)) << error;
  EXPECT_TRUE(report.usable) << report.termination;
  out.dsr_fast = report.frame_from_world;
  DsrOptions reference = fast;
  reference.reference_cost = true;
  EXPECT_TRUE(SolveDsr(s.frames, cand, init, reference, &report, &error)) << error;
  EXPECT_TRUE(report.usable) << report.termination;
  out.dsr_reference = report.frame_from_world;
  return out;
}

// Full solves need problems whose minimum is sharp: with trilinear interpolation the cost is
// only piecewise smooth and the Jacobians come from gradient volumes (docs/design.md section 2),
// so on a generic problem a monotone trust-region method stops, in either mode, at
// whichever shallow dip next to the Gauss-Newton fixed point its path meets (the two modes
// take different damped paths; the dips differ by ~1e-5 rad). Lattice-aligned frames make
// the fixed point exact: every residual vanishes at the ground truth (test_problems.h).
// The solves also must not cross a field-of-view edge (InteriorCandidates).
SequenceOptions LatticeOptionsFor(const Case& c, uint64_t seed) {
  SequenceOptions o = OptionsFor(c, seed);
  o.lattice = true;
  return o;
}

// Full solves of DBA, DSR and its reference on the lattice sequence `o` from the ground
// truth perturbed with `init_seed` reach the same poses, the ground truth itself.
void ExpectFullSolvesMeetAtTheTruth(const SequenceOptions& o, uint64_t init_seed) {
  const auto s = MakeSequence(o);
  const auto init = Perturbed(s.ground_truth, 0.02, 0.5, init_seed);
  const CandidateSet cand = InteriorCandidates(s, init, 1.5);
  ASSERT_GT(cand.num_voxels(), 200);
  // DSR needs up to ~600 iterations here (DBA took 571 on the second case): the Gauss-Newton
  // model of interpolated central differences converges only linearly on the exact cost.
  const ModePoses converged = SolveAllModes(s, cand, init, 1000);
  for (const auto* other : {&converged.dsr_fast, &converged.dsr_reference}) {
    EXPECT_THAT(*other, FramesFromWorldNear(converged.dba, kFixedPointRotationRad,
                                            kFixedPointTranslationMm))
        << "m=" << o.num_frames;
  }
  // On these problems the shared fixed point is the ground truth itself.
  for (const auto* poses : {&converged.dba, &converged.dsr_fast, &converged.dsr_reference}) {
    EXPECT_THAT(*poses, FramesFromWorldNear(s.ground_truth, kFixedPointRotationRad,
                                            kFixedPointTranslationMm))
        << "m=" << o.num_frames << " mode " << (poses - &converged.dba);
  }
  // The solve moved the poses far more than that: the agreement is not the start's.
  EXPECT_GT(MaxPoseDifference(converged.dba, init).second, 0.1);
}

TEST(Theorem, FullSolvesOfBothModesConvergeToTheSamePoses) {
  DSR_SKIP_HEAVY_UNDER_SANITIZER();
  uint64_t seed = 51;
  for (const Case& c :
       {Case{3, 16, 0.0, 1}, Case{4, 16, 5.0, 1}, Case{4, 16, 0.0, 2}, Case{5, 16, 2.0, 1}}) {
    const SequenceOptions o = LatticeOptionsFor(c, seed++);
    ExpectFullSolvesMeetAtTheTruth(o, seed++);
  }
}

// The same in the mean gauge (docs/design.md 4.8): DBA with the prior and both DSR costs
// with it, from a start where every frame, frame 0 included, is off, reach the same poses
// in the start's world (frame 0 moved), and relative to frame 0 the ground truth.
TEST(Theorem, MeanGaugeFullSolvesOfBothModesConvergeToTheSamePoses) {
  DSR_SKIP_HEAVY_UNDER_SANITIZER();
  uint64_t seed = 81;
  for (const Case& c : {Case{3, 16, 0.0, 1}, Case{4, 16, 5.0, 1}}) {
    const auto s = MakeSequence(LatticeOptionsFor(c, seed++));
    const auto init = MovedTogether(Perturbed(s.ground_truth, 0.02, 0.5, seed), seed + 1);
    seed += 2;
    const CandidateSet cand = InteriorCandidates(s, init, 1.5);
    ASSERT_GT(cand.num_voxels(), 200);
    const ModePoses converged = SolveAllModes(s, cand, init, 1000, Gauge::kMean);
    EXPECT_GT(PoseDifference(converged.dba[0], init[0]).second, 1e-3) << "frame 0 stayed";
    for (const auto* other : {&converged.dsr_fast, &converged.dsr_reference}) {
      EXPECT_THAT(*other, FramesFromWorldNear(converged.dba, kFixedPointRotationRad,
                                              kFixedPointTranslationMm))
          << "m=" << c.num_frames;
    }
    for (const auto* poses : {&converged.dba, &converged.dsr_fast, &converged.dsr_reference}) {
      EXPECT_THAT(RelativeToFrame0(*poses),
                  FramesFromWorldNear(s.ground_truth, kFixedPointRotationRad,
                                      kFixedPointTranslationMm))
          << "m=" << c.num_frames << " mode " << (poses - &converged.dba);
    }
  }
}

TEST(Theorem, DampedIteratesDifferButTheFixedPointIsShared) {
  const Case c{3, 14, 0.0, 1};
  const auto s = MakeSequence(LatticeOptionsFor(c, 61));
  const auto init = Perturbed(s.ground_truth, 0.02, 0.5, 62);
  const CandidateSet cand = InteriorCandidates(s, init, 1.5);
  // After one Levenberg-Marquardt step the modes disagree: DBA's damping also acts on the
  // intensity blocks, so its eliminated system is not DSR's damped system
  // (docs/design.md section 4.4).
  const ModePoses first = SolveAllModes(s, cand, init, 1);
  const auto [rotation_1, translation_1] = MaxPoseDifference(first.dba, first.dsr_fast);
  EXPECT_GT(std::max(rotation_1, translation_1), 1e-6)
      << "one damped step: DBA and DSR iterates should differ";
  // Both DSR costs take the same damped step: they are one model.
  EXPECT_THAT(first.dsr_reference, FramesFromWorldNear(first.dsr_fast, 1e-10, 1e-8));
  // Converged, they agree (as in the test above).
  const ModePoses converged = SolveAllModes(s, cand, init, 200);
  EXPECT_THAT(converged.dsr_fast,
              FramesFromWorldNear(converged.dba, kFixedPointRotationRad, kFixedPointTranslationMm));
}

// The theorem with photometric parameters (docs/design.md section 2.8): frames seen through
// gains and offsets, DBA with a [log_gain, offset] block per frame and DSR's per-voxel
// reference with the same blocks (intensities eliminated in closed form as the mean of the
// corrected observations) converge to the same poses and the same parameters, and, on
// these lattice-aligned problems, to the truth.
TEST(Theorem, PhotometricFullSolvesOfBothModesAgree) {
  DSR_SKIP_HEAVY_UNDER_SANITIZER();
  const Case c{4, 16, 5.0, 1};
  auto s = MakeSequence(LatticeOptionsFor(c, 71));
  const double g[] = {1.0, 1.25, 0.85, 1.1}, o[] = {0.0, 9.0, -6.0, 3.0};
  SeeThroughGains(g, o, &s);
  const auto init = Perturbed(s.ground_truth, 0.02, 0.5, 72);
  const CandidateSet cand = InteriorCandidates(s, init, 1.5);
  ASSERT_GT(cand.num_voxels(), 200);
  std::string error;
  SolveReport dba_report, dsr_report;
  DbaOptions dba;
  dba.photometric = true;
  dba.solve = FixedPointOptions(2000);
  ASSERT_TRUE(SolveDba(s.frames, cand, init, dba, &dba_report, nullptr, &error)) << error;
  ASSERT_TRUE(dba_report.usable) << dba_report.termination;
  DsrOptions dsr;
  dsr.photometric = true;
  dsr.reference_cost = true;
  dsr.solve = FixedPointOptions(1000);
  ASSERT_TRUE(SolveDsr(s.frames, cand, init, dsr, &dsr_report, &error)) << error;
  ASSERT_TRUE(dsr_report.usable) << dsr_report.termination;
  EXPECT_THAT(dsr_report.frame_from_world,
              FramesFromWorldNear(dba_report.frame_from_world, kFixedPointRotationRad,
                                  kFixedPointTranslationMm));
  ASSERT_EQ(dba_report.photometric.size(), 4u);
  ASSERT_EQ(dsr_report.photometric.size(), 4u);
  for (int i = 0; i < c.num_frames; ++i) {
    EXPECT_NEAR(dba_report.photometric[i].log_gain, dsr_report.photometric[i].log_gain, 1e-8);
    EXPECT_NEAR(dba_report.photometric[i].offset, dsr_report.photometric[i].offset, 1e-6);
    EXPECT_NEAR(dsr_report.photometric[i].gain(), 1.0 / g[i], 1e-6) << i;
    EXPECT_NEAR(dsr_report.photometric[i].offset, -o[i] / g[i], 1e-5) << i;
  }
  EXPECT_LT(MaxPoseDifference(dsr_report.frame_from_world, s.ground_truth).second,
            kFixedPointTranslationMm);
  // DSR's fast path (8 x 8 blocks, streamed) reaches the same point.
  dsr.reference_cost = false;
  SolveReport fast_report;
  ASSERT_TRUE(SolveDsr(s.frames, cand, init, dsr, &fast_report, &error)) << error;
  ASSERT_TRUE(fast_report.usable) << fast_report.termination;
  EXPECT_THAT(fast_report.frame_from_world,
              FramesFromWorldNear(dba_report.frame_from_world, kFixedPointRotationRad,
                                  kFixedPointTranslationMm));
  ASSERT_EQ(fast_report.photometric.size(), 4u);
  for (int i = 0; i < c.num_frames; ++i) {
    EXPECT_NEAR(fast_report.photometric[i].log_gain, dba_report.photometric[i].log_gain, 1e-8);
    EXPECT_NEAR(fast_report.photometric[i].offset, dba_report.photometric[i].offset, 1e-6);
  }
}

// Noise-free frames seen through gains 0.85-1.2 and offsets: DSR's fast path recovers them
// to well within 1 %, from a start 0.6 mm and 1.2 degrees away, with the default
// stopping rules. Lattice-aligned frames, whose minimum is the truth (on generic ones of
// this size, interpolation moves the minimum by ~0.15 mm with or without gains).
TEST(ReducedCost, PhotometricFastPathRecoversSimulatedGains) {
  const Case c{4, 18, 0.0, 1};
  auto s = MakeSequence(LatticeOptionsFor(c, 121));
  const double g[] = {1.0, 0.85, 1.2, 1.1}, o[] = {0.0, -8.0, 6.0, 10.0};
  SeeThroughGains(g, o, &s);
  const auto init = Perturbed(s.ground_truth, 0.017, 0.5, 122);
  const CandidateSet cand = InteriorCandidates(s, init, 1.5);
  DsrOptions dsr;
  dsr.photometric = true;
  dsr.solve.num_threads = 2;
  dsr.solve.max_iterations = 200;
  SolveReport report;
  std::string error;
  ASSERT_TRUE(SolveDsr(s.frames, cand, init, dsr, &report, &error)) << error;
  ASSERT_TRUE(report.usable) << report.termination;
  for (int i = 1; i < c.num_frames; ++i) {
    // Frame i observes g_i I + o_i; its correction maps that back to frame 0's scale.
    EXPECT_NEAR(report.photometric[i].gain() * g[i], 1.0, 0.01) << i;
    EXPECT_NEAR(report.photometric[i].gain() * o[i] + report.photometric[i].offset, 0.0, 1.0) << i;
  }
  EXPECT_THAT(report.frame_from_world, FramesFromWorldNear(s.ground_truth, 1e-4, 0.01));
  // The per-frame costs of the final pass, as the misfit check reads them (near 0 here).
  ASSERT_EQ(report.final_frame_cost.size(), 4u);
  for (int i = 0; i < c.num_frames; ++i) {
    EXPECT_LT(report.final_frame_cost[i], 1e-3 * report.final_frame_observations[i]) << i;
  }
}

// The gains and offsets at fixed poses (SolvePhotometricAtPoses, what the pipeline states
// on the input's grey levels after registering transformed intensities): at the truth they
// are the simulated ones, with the fast path and the per-voxel reference alike, and the
// poses are left as given; at other poses they minimise the cost in the gains and offsets.
TEST(ReducedCost, PhotometricAtFixedPosesMinimisesTheCostInGainsAndOffsets) {
  const Case c{4, 16, 0.0, 1};
  auto s = MakeSequence(LatticeOptionsFor(c, 131));
  const double g[] = {1.0, 1.2, 0.85, 1.1}, o[] = {0.0, -7.0, 9.0, 4.0};
  SeeThroughGains(g, o, &s);
  const CandidateSet at_truth = InteriorCandidates(s, s.ground_truth, 1.5);
  std::string error;
  for (bool reference : {false, true}) {
    DsrOptions dsr;
    dsr.reference_cost = reference;
    dsr.solve = FixedPointOptions(100);
    SolveReport report;
    ASSERT_TRUE(SolvePhotometricAtPoses(s.frames, at_truth, s.ground_truth, dsr, &report, &error))
        << error;
    ASSERT_TRUE(report.usable) << report.termination;
    ASSERT_EQ(report.photometric.size(), 4u);
    EXPECT_EQ(report.photometric[0].log_gain, 0.0);
    EXPECT_EQ(report.photometric[0].offset, 0.0);
    for (int i = 1; i < c.num_frames; ++i) {
      EXPECT_NEAR(report.photometric[i].gain(), 1.0 / g[i], 1e-6) << i << " " << reference;
      // Offsets to the float round-off of intensities near 100 (the frames are stored as float).
      EXPECT_NEAR(report.photometric[i].offset, -o[i] / g[i], 1e-4) << i << " " << reference;
    }
    EXPECT_THAT(report.frame_from_world, FramesFromWorldNear(s.ground_truth, 0.0, 0.0));
  }
  // At other poses, on generic frames with noise: the fast path and the reference agree,
  // and the cost's gradient in the photometric parameters vanishes there (the Jacobians of
  // the gains and offsets are exact: docs/design.md 2.8).
  auto noisy = MakeSequence(OptionsFor({4, 16, 5.0, 1}, 133));
  SeeThroughGains(g, o, &noisy);
  const auto poses = Perturbed(noisy.ground_truth, 0.01, 0.3, 134);
  const CandidateSet cand = InteriorCandidates(noisy, poses, 1.5);
  std::vector<SolveReport> reports(2);
  for (int reference = 0; reference < 2; ++reference) {
    DsrOptions dsr;
    dsr.reference_cost = reference == 1;
    dsr.solve = FixedPointOptions(100);
    ASSERT_TRUE(SolvePhotometricAtPoses(noisy.frames, cand, poses, dsr, &reports[reference],
                                        &error))
        << error;
    ASSERT_TRUE(reports[reference].usable) << reports[reference].termination;
  }
  const auto gradient = [&](const std::vector<Photometric>& photometric) {
    DsrOptions dsr;
    dsr.reference_cost = true;
    dsr.photometric = true;
    dsr.initial_photometric = photometric;
    DsrProblem problem(noisy.frames, cand, poses, dsr);
    ceres::Problem::EvaluateOptions evaluate;
    for (int i = 1; i < c.num_frames; ++i) {
      evaluate.parameter_blocks.push_back(problem.photometric_parameters(i));
    }
    double cost = 0.0;
    std::vector<double> g;
    EXPECT_TRUE(problem.problem().Evaluate(evaluate, &cost, nullptr, &g, nullptr));
    return Eigen::Map<Eigen::VectorXd>(g.data(), static_cast<int>(g.size())).eval();
  };
  const Eigen::VectorXd at_start = gradient(std::vector<Photometric>(c.num_frames));
  const Eigen::VectorXd at_estimate = gradient(reports[1].photometric);
  EXPECT_LT(at_estimate.norm(), 1e-6 * at_start.norm()) << at_estimate.transpose();
  for (int i = 1; i < c.num_frames; ++i) {
    EXPECT_NEAR(reports[0].photometric[i].log_gain, reports[1].photometric[i].log_gain, 1e-9) << i;
    EXPECT_NEAR(reports[0].photometric[i].offset, reports[1].photometric[i].offset, 1e-7) << i;
  }
}

// The gains and offsets at fixed poses by variable projection on the samples in memory
// (EstimatePhotometricAtPoses, the brightness detection's estimate) against its slow twin,
// one Ceres solve of the same cost (SolvePhotometricAtPoses): the simulated gains and offsets
// at the truth, and the same minimiser at other poses on noisy frames; with phases, the
// tied views' one gain and offset. Deterministic for any thread count.
TEST(ReducedCost, PhotometricByVariableProjectionIsTheCeresSolvesMinimiser) {
  const Case c{4, 16, 0.0, 1};
  auto s = MakeSequence(LatticeOptionsFor(c, 131));
  const double g[] = {1.0, 1.2, 0.85, 1.1}, o[] = {0.0, -7.0, 9.0, 4.0};
  SeeThroughGains(g, o, &s);
  std::string error;
  PhotometricEstimate at_truth;
  ASSERT_TRUE(EstimatePhotometricAtPoses(s.frames, InteriorCandidates(s, s.ground_truth, 1.5),
                                         s.ground_truth, StreamContext{2}, &at_truth, &error))
      << error;
  EXPECT_TRUE(at_truth.converged);
  for (int i = 1; i < c.num_frames; ++i) {
    EXPECT_NEAR(at_truth.photometric[i].gain(), 1.0 / g[i], 1e-6) << i;
    EXPECT_NEAR(at_truth.photometric[i].offset, -o[i] / g[i], 1e-4) << i;
  }
  auto noisy = MakeSequence(OptionsFor({4, 16, 5.0, 1}, 133));
  SeeThroughGains(g, o, &noisy);
  const auto poses = Perturbed(noisy.ground_truth, 0.01, 0.3, 134);
  const CandidateSet cand = InteriorCandidates(noisy, poses, 1.5);
  DsrOptions dsr;
  dsr.solve = FixedPointOptions(100);
  SolveReport report;
  ASSERT_TRUE(SolvePhotometricAtPoses(noisy.frames, cand, poses, dsr, &report, &error)) << error;
  PhotometricEstimate estimate, one_thread;
  ASSERT_TRUE(EstimatePhotometricAtPoses(noisy.frames, cand, poses, StreamContext{2}, &estimate,
                                         &error))
      << error;
  ASSERT_TRUE(EstimatePhotometricAtPoses(noisy.frames, cand, poses, StreamContext{1}, &one_thread,
                                         &error))
      << error;
  EXPECT_TRUE(estimate.converged);
  EXPECT_LE(estimate.iterations, 10);
  // The estimate holds its samples in float (the frames' precision), the Ceres solve in
  // double: the two minimisers agree to that rounding (measured: 5e-8 in a log gain, 3e-6
  // grey levels in an offset, 2e-8 of the cost), far below any error of the method.
  EXPECT_NEAR(estimate.cost, 2.0 * report.final_cost, 2e-7 * estimate.cost);
  for (int i = 1; i < c.num_frames; ++i) {
    EXPECT_NEAR(estimate.photometric[i].log_gain, report.photometric[i].log_gain, 5e-7) << i;
    EXPECT_NEAR(estimate.photometric[i].offset, report.photometric[i].offset, 3e-5) << i;
    EXPECT_EQ(estimate.photometric[i].log_gain, one_thread.photometric[i].log_gain) << i;
  }
  // From a start near the minimiser (an estimate on 1 row in 3): the same minimiser, in
  // fewer passes.
  PhotometricEstimate rows, warm;
  ASSERT_TRUE(EstimatePhotometricAtPoses(noisy.frames, CandidatesInRows(cand, 3), poses,
                                         StreamContext{2}, &rows, &error))
      << error;
  ASSERT_TRUE(EstimatePhotometricAtPoses(noisy.frames, cand, poses, StreamContext{2}, &warm,
                                         &error, &rows.photometric))
      << error;
  EXPECT_TRUE(warm.converged);
  EXPECT_LT(warm.iterations, estimate.iterations);
  for (int i = 1; i < c.num_frames; ++i) {
    EXPECT_NEAR(warm.photometric[i].log_gain, estimate.photometric[i].log_gain, 1e-8) << i;
    EXPECT_NEAR(warm.photometric[i].offset, estimate.photometric[i].offset, 1e-6) << i;
  }
  // The standard error states the spread of the estimate over the noise: over 24 noise
  // draws of one sequence seen through the gains and offsets, at its true poses, the
  // standard deviation of frame 1's change at a grey level of 100 against the draws' mean
  // stated error.
  const auto clean = MakeSequence(OptionsFor({4, 24, 0.0, 1}, 135));
  std::vector<double> changes;
  double stated = 0.0;
  for (int seed = 0; seed < 24; ++seed) {
    auto draw = clean;
    std::mt19937_64 rng(700 + seed);
    std::normal_distribution<double> noise(0.0, 5.0);
    for (size_t i = 0; i < draw.frames.size(); ++i) {
      for (float& v : draw.images[i].voxels) v += static_cast<float>(noise(rng));
      draw.frames[i] = Frame(draw.images[i], draw.masks[i]);
    }
    SeeThroughGains(g, o, &draw);
    PhotometricEstimate e;
    ASSERT_TRUE(EstimatePhotometricAtPoses(draw.frames,
                                           InteriorCandidates(draw, draw.ground_truth, 1.5),
                                           draw.ground_truth, StreamContext{2}, &e, &error))
        << error;
    changes.push_back(e.Change(1, 100.0));
    stated += e.ChangeStandardError(1, 100.0) / 24.0;
  }
  double mean = 0.0, variance = 0.0;
  for (double x : changes) mean += x / changes.size();
  for (double x : changes) variance += (x - mean) * (x - mean) / (changes.size() - 1);
  const double measured = std::sqrt(variance);
  EXPECT_GT(stated, 0.5 * measured) << "stated " << stated << ", measured " << measured;
  EXPECT_LT(stated, 2.0 * measured) << "stated " << stated << ", measured " << measured;
}

// The photometric reference cost's Jacobians against Ceres's numeric differentiation, on
// a voxel with three observers, at poses and parameters away from the identity. The frames
// are a linear ramp, where the gradient volumes' central differences are the exact
// derivative of the interpolant (elsewhere they differ by design: docs/design.md 2.3).
TEST(ReducedCost, PhotometricReferenceJacobiansMatchNumeric) {
  const Frame frame = testing_problems::LinearRampFrame(40.0);
  const ImageGeometry& g = frame.geometry();
  const Eigen::Vector3d p = g.IndexToPhysical(Eigen::Vector3d(7.3, 8.1, 6.6));
  std::array<Eigen::Isometry3d, 3> poses;
  Vector6d d;
  d << 0.0, 0.0, 0.0, 0.0, 0.0, 0.0;
  poses[0] = ExpSE3(d);
  d << 0.4, -0.3, 0.2, 0.05, -0.04, 0.03;
  poses[1] = ExpSE3(d);
  d << -0.2, 0.5, -0.1, -0.03, 0.02, 0.06;
  poses[2] = ExpSE3(d);
  VoxelReducedPhotometricCost cost({&frame, &frame, &frame}, p);
  PoseManifold manifold;
  std::vector<const ceres::Manifold*> manifolds = {&manifold, &manifold, &manifold,
                                                   nullptr, nullptr, nullptr};
  std::array<std::array<double, kPoseAmbientSize>, 3> x;
  for (int i = 0; i < 3; ++i) PoseToParameters(poses[i], x[i].data());
  double photometric[3][2] = {{0.0, 0.0}, {0.15, 4.0}, {-0.1, -2.5}};
  const double* parameters[] = {x[0].data(), x[1].data(), x[2].data(),
                                photometric[0], photometric[1], photometric[2]};
  // The voxel's intensity column in the residuals' units: u_i = 1 / gain_i.
  const Eigen::Vector3d direction(1.0, std::exp(-0.15), std::exp(0.1));
  // 1e-3: the frame holds floats, as in dba_test's residual checks.
  testing_problems::ExpectEliminatedJacobianMatchesNumeric(cost, manifolds, parameters,
                                                          direction, 1e-3);
  // At gains 1 and offsets 0 it is the plain reference cost.
  VoxelReducedCost plain({&frame, &frame, &frame}, p);
  double zero[3][2] = {{0.0, 0.0}, {0.0, 0.0}, {0.0, 0.0}};
  const double* with_zero[] = {x[0].data(), x[1].data(), x[2].data(), zero[0], zero[1], zero[2]};
  double r_photometric[3], r_plain[3];
  ASSERT_TRUE(cost.Evaluate(with_zero, r_photometric, nullptr));
  ASSERT_TRUE(plain.Evaluate(with_zero, r_plain, nullptr));
  for (int i = 0; i < 3; ++i) EXPECT_EQ(r_photometric[i], r_plain[i]);
}

TEST(ReducedCost, FastPathMatchesPerVoxelReference) {
  uint64_t seed = 31;
  for (const Case& c : Cases()) {
    const auto s = MakeSequence(OptionsFor(c, seed++));
    for (int trial = 0; trial < 3; ++trial) {
      const auto poses = Perturbed(s.ground_truth, 0.03, 1.0, seed++);
      const CandidateSet cand = Candidates(s, poses);
      // Reference: per-voxel residual blocks, Jacobian from Ceres.
      DsrOptions ref_options;
      ref_options.reference_cost = true;
      DsrProblem reference(s.frames, cand, poses, ref_options);
      std::vector<double*> blocks;
      for (int i = 1; i < c.num_frames; ++i) blocks.push_back(reference.pose_parameters(i));
      Eigen::VectorXd r;
      double ref_cost;
      const Eigen::MatrixXd j = DenseJacobian(&reference.problem(), blocks, &r, &ref_cost);
      const Eigen::MatrixXd ref_h = j.transpose() * j;
      const Eigen::VectorXd ref_g = j.transpose() * r;

      // Fast path, through Ceres as well (compressed residual and Jacobian), in 1 and 3 chunks.
      for (int chunks : {1, 3}) {
        DsrOptions fast_options;
        fast_options.num_chunks = chunks;
        fast_options.solve.num_threads = 2;
        DsrProblem fast(s.frames, cand, poses, fast_options);
        std::vector<double*> fast_blocks;
        for (int i = 1; i < c.num_frames; ++i) fast_blocks.push_back(fast.pose_parameters(i));
        Eigen::VectorXd fr;
        double fast_cost;
        const Eigen::MatrixXd fj = DenseJacobian(&fast.problem(), fast_blocks, &fr, &fast_cost);
        EXPECT_NEAR(fast_cost, ref_cost, kSystemRelativeTolerance * ref_cost);
        EXPECT_LT(RelativeDifference(fj.transpose() * fr, ref_g), kSystemRelativeTolerance * 10)
            << "chunks=" << chunks;
        EXPECT_LT((fj.transpose() * fj - ref_h).norm() / ref_h.norm(), kSystemRelativeTolerance)
            << "chunks=" << chunks;
      }
    }
  }
}

// The photometric fast path (8 x 8 blocks, through Ceres: compressed residual and
// Jacobians of the poses and of the [log_gain, offset] blocks) against the per-voxel
// photometric reference, at parameters away from the gauge.
TEST(ReducedCost, PhotometricFastPathMatchesPerVoxelReference) {
  uint64_t seed = 131;
  for (const Case& c : Cases()) {
    const auto s = MakeSequence(OptionsFor(c, seed++));
    const auto poses = Perturbed(s.ground_truth, 0.03, 1.0, seed++);
    const CandidateSet cand = Candidates(s, poses);
    DsrOptions ref_options;
    ref_options.reference_cost = true;
    ref_options.photometric = true;
    ref_options.initial_photometric = RandomPhotometric(c.num_frames, seed++);
    DsrProblem reference(s.frames, cand, poses, ref_options);
    std::vector<double*> blocks;
    for (int i = 1; i < c.num_frames; ++i) {
      blocks.push_back(reference.pose_parameters(i));
      blocks.push_back(reference.photometric_parameters(i));
    }
    Eigen::VectorXd r;
    double ref_cost;
    const Eigen::MatrixXd j = DenseJacobian(&reference.problem(), blocks, &r, &ref_cost);
    const Eigen::MatrixXd ref_h = j.transpose() * j;
    const Eigen::VectorXd ref_g = j.transpose() * r;
    ASSERT_EQ(ref_h.rows(), 8 * (c.num_frames - 1));
    for (int chunks : {1, 3}) {
      DsrOptions fast_options = ref_options;
      fast_options.reference_cost = false;
      fast_options.num_chunks = chunks;
      fast_options.solve.num_threads = 2;
      DsrProblem fast(s.frames, cand, poses, fast_options);
      std::vector<double*> fast_blocks;
      for (int i = 1; i < c.num_frames; ++i) {
        fast_blocks.push_back(fast.pose_parameters(i));
        fast_blocks.push_back(fast.photometric_parameters(i));
      }
      Eigen::VectorXd fr;
      double fast_cost;
      const Eigen::MatrixXd fj = DenseJacobian(&fast.problem(), fast_blocks, &fr, &fast_cost);
      EXPECT_NEAR(fast_cost, ref_cost, kSystemRelativeTolerance * ref_cost);
      EXPECT_LT(RelativeDifference(fj.transpose() * fr, ref_g), kSystemRelativeTolerance * 10)
          << "chunks=" << chunks;
      EXPECT_LT((fj.transpose() * fj - ref_h).norm() / ref_h.norm(), kSystemRelativeTolerance)
          << "chunks=" << chunks;
    }
  }
}

// At gain 1 and offset 0 the photometric system's pose rows are the plain system's.
TEST(ReducedCost, PhotometricSystemAtTheGaugeContainsThePlainOne) {
  const auto s = MakeSequence(OptionsFor({4, 14, 5.0, 1}, 141));
  const auto poses = Perturbed(s.ground_truth, 0.02, 0.7, 142);
  const CandidateSet cand = Candidates(s, poses);
  ReducedSystem plain, wide;
  AccumulateReducedSystem(s.frames, cand, poses, 0, cand.num_voxels(), true, StreamContext{2},
                          &plain);
  AccumulateReducedPhotometricSystem(s.frames, cand, poses, std::vector<Photometric>(4), 0,
                                     cand.num_voxels(), true, StreamContext{2}, &wide);
  EXPECT_EQ(plain.cost, wide.cost);
  EXPECT_EQ(plain.frame_cost, wide.frame_cost);
  for (int a = 0; a < 4; ++a) {
    EXPECT_LT((wide.gradient.segment<6>(8 * a) - plain.gradient.segment<6>(6 * a)).norm(),
              1e-12 * plain.gradient.norm());
    for (int b = 0; b < 4; ++b) {
      EXPECT_LT((wide.hessian.block<6, 6>(8 * a, 8 * b) - plain.hessian.block<6, 6>(6 * a, 6 * b))
                    .norm(),
                1e-12 * plain.hessian.norm());
    }
  }
}

// The photometric system's batched kernels (width 8) against its voxel-by-voxel twin, on
// every kernel path this CPU has.
TEST(ReducedCost, PhotometricBatchedHessianMatchesTheTwinOnEveryKernelPath) {
  uint64_t seed = 151;
  for (const Case& c : Cases()) {
    const auto s = MakeSequence(OptionsFor(c, seed++));
    const auto poses = Perturbed(s.ground_truth, 0.03, 1.0, seed++);
    const auto photometric = RandomPhotometric(c.num_frames, seed++);
    const CandidateSet cand = Candidates(s, poses);
    ReducedSystem twin;
    AccumulateReducedPhotometricSystem(s.frames, cand, poses, photometric, 0, cand.num_voxels(),
                                       true, StreamContext{2, KernelPath::kPortable}, &twin, false);
    ASSERT_GT(twin.hessian.norm(), 0.0);
    for (KernelPath path : testing_kernels::AvailablePaths()) {
      ReducedSystem batched;
      AccumulateReducedPhotometricSystem(s.frames, cand, poses, photometric, 0, cand.num_voxels(),
                                         true, StreamContext{2, path}, &batched, true);
      EXPECT_LT((batched.hessian - twin.hessian).norm() / twin.hessian.norm(), 1e-12)
          << KernelPathToString(path) << " m=" << c.num_frames;
      EXPECT_LT((batched.gradient - twin.gradient).norm() / twin.gradient.norm(), 1e-12)
          << KernelPathToString(path) << " m=" << c.num_frames;
      EXPECT_NEAR(batched.cost, twin.cost, 1e-12 * twin.cost) << KernelPathToString(path);
      EXPECT_TRUE(batched.hessian.isApprox(batched.hessian.transpose(), 0.0));
    }
  }
}

TEST(ReducedCost, AccumulationIsIdenticalForAnyThreadCount) {
  const auto s = MakeSequence(OptionsFor({4, 14, 5.0, 1}, 41));
  const auto poses = Perturbed(s.ground_truth, 0.02, 0.7, 42);
  const CandidateSet cand = Candidates(s, poses);
  ReducedSystem one, two, four;
  AccumulateReducedSystem(s.frames, cand, poses, 0, cand.num_voxels(), true, StreamContext{1},
                          &one);
  AccumulateReducedSystem(s.frames, cand, poses, 0, cand.num_voxels(), true, StreamContext{2},
                          &two);
  AccumulateReducedSystem(s.frames, cand, poses, 0, cand.num_voxels(), true, StreamContext{4},
                          &four);
  EXPECT_EQ(one.cost, two.cost);
  EXPECT_EQ(one.cost, four.cost);
  EXPECT_TRUE(one.hessian == two.hessian && one.hessian == four.hessian);
  EXPECT_TRUE(one.gradient == two.gradient && one.gradient == four.gradient);
}

TEST(ReducedCost, BatchedHessianMatchesTheVoxelByVoxelTwin) {
  uint64_t seed = 71;
  for (const Case& c : Cases()) {
    const auto s = MakeSequence(OptionsFor(c, seed++));
    const auto poses = Perturbed(s.ground_truth, 0.03, 1.0, seed++);
    const CandidateSet cand = Candidates(s, poses);
    // The whole set, and an odd sub-range (partial batches flushed at its end).
    for (const auto& [begin, end] : {std::pair<int64_t, int64_t>{0, cand.num_voxels()},
                                     std::pair<int64_t, int64_t>{3, cand.num_voxels() / 2 + 1}}) {
      ReducedSystem batched, twin;
      AccumulateReducedSystem(s.frames, cand, poses, begin, end, true, StreamContext{2}, &batched,
                              true);
      AccumulateReducedSystem(s.frames, cand, poses, begin, end, true, StreamContext{2}, &twin,
                              false);
      ASSERT_GT(twin.hessian.norm(), 0.0);
      EXPECT_LT((batched.hessian - twin.hessian).norm() / twin.hessian.norm(),
                kSystemRelativeTolerance)
          << "m=" << c.num_frames << " voxels [" << begin << ", " << end << ")";
      // The gradient is summed per group too; the cost does not go through the batches.
      ASSERT_GT(twin.gradient.norm(), 0.0);
      EXPECT_LT((batched.gradient - twin.gradient).norm() / twin.gradient.norm(),
                kSystemRelativeTolerance)
          << "m=" << c.num_frames << " voxels [" << begin << ", " << end << ")";
      EXPECT_EQ(batched.cost, twin.cost);
      EXPECT_EQ(batched.frame_cost, twin.frame_cost);
      EXPECT_TRUE(batched.hessian.isApprox(batched.hessian.transpose(), 0.0));
    }
  }
}

TEST(ReducedCost, FrameCostsSplitTheCostByFrame) {
  const auto s = MakeSequence(OptionsFor({4, 16, 25.0, 3}, 81));
  const auto poses = Perturbed(s.ground_truth, 0.03, 1.0, 82);
  const CandidateSet cand = Candidates(s, poses);
  ReducedSystem system;
  AccumulateReducedSystem(s.frames, cand, poses, 0, cand.num_voxels(), false, StreamContext{2},
                          &system);
  // Reference: each voxel's residuals from the per-voxel cost, added to their frames.
  std::vector<double> frame_cost(4, 0.0);
  std::vector<int64_t> frame_count(4, 0);
  for (int64_t v = 0; v < cand.num_voxels(); ++v) {
    std::vector<const Frame*> observers;
    std::vector<int> index;
    std::vector<std::array<double, kPoseAmbientSize>> parameters;
    for (int i = 0; i < 4; ++i) {
      if (!(cand.observers[v] >> i & 1u)) continue;
      observers.push_back(&s.frames[i]);
      index.push_back(i);
      parameters.emplace_back();
      PoseToParameters(poses[i], parameters.back().data());
    }
    VoxelReducedCost cost(observers, cand.VoxelCenter(v));
    std::vector<const double*> blocks;
    for (const auto& x : parameters) blocks.push_back(x.data());
    std::vector<double> r(observers.size());
    ASSERT_TRUE(cost.Evaluate(blocks.data(), r.data(), nullptr));
    for (size_t a = 0; a < r.size(); ++a) {
      frame_cost[index[a]] += r[a] * r[a];
      // A residual of exactly 0 may be an observation or no observation; count those seen.
      if (r[a] != 0.0) ++frame_count[index[a]];
    }
  }
  double sum = 0.0;
  int64_t count = 0;
  for (int i = 0; i < 4; ++i) {
    sum += system.frame_cost[i];
    count += system.frame_observations[i];
    EXPECT_NEAR(system.frame_cost[i], frame_cost[i], 1e-9 * frame_cost[i]) << "frame " << i;
    // Residuals of exactly 0 are counted by the stream only: at most a handful.
    EXPECT_GE(system.frame_observations[i], frame_count[i]);
    EXPECT_LE(system.frame_observations[i], frame_count[i] + frame_count[i] / 100 + 1);
    EXPECT_GT(system.frame_observations[i], 0);
  }
  EXPECT_NEAR(sum, system.cost, 1e-12 * system.cost);
  EXPECT_EQ(count, system.observations);
}

TEST(ReducedCost, CompressionReproducesTheNormalEquations) {
  std::mt19937_64 rng(5);
  std::normal_distribution<double> n01;
  Eigen::MatrixXd a(40, 12);
  for (int i = 0; i < a.size(); ++i) a.data()[i] = n01(rng);
  Eigen::VectorXd e(40);
  for (int i = 0; i < 40; ++i) e[i] = n01(rng);
  const Eigen::MatrixXd h = a.transpose() * a;
  const Eigen::VectorXd g = a.transpose() * e;
  const double f = e.squaredNorm();
  Eigen::VectorXd r;
  Eigen::MatrixXd j;
  ReducedChunkCost::Compress(h, g, f, &r, &j);
  EXPECT_LT((j.transpose() * j - h).norm(), 1e-10 * h.norm());
  EXPECT_LT((j.transpose() * r - g).norm(), 1e-10 * g.norm());
  EXPECT_NEAR(r.squaredNorm(), f, 1e-10 * f);
}

// ECG-gated views (docs/design.md section 12): every view has T phases and one pose, the
// panorama one intensity per (voxel, phase). DSR sums each phase's reduced cost over the
// views' shared pose blocks; DBA has an intensity block per (voxel, phase) and every phase's
// residuals on the view's pose block. The theorem holds phase by phase, so it holds for
// the sum.

SequenceOptions PhasedOptionsFor(const Case& c, uint64_t seed, int phases) {
  SequenceOptions o = OptionsFor(c, seed);
  o.num_phases = phases;
  return o;
}

// DsrProblem's dense (compressed) Jacobian over `blocks` and its Gauss-Newton step.
Eigen::VectorXd DsrStep(DsrProblem* dsr, const std::vector<double*>& blocks, double* cost) {
  Eigen::VectorXd r;
  const Eigen::MatrixXd j = DenseJacobian(&dsr->problem(), blocks, &r, cost);
  return (j.transpose() * j).ldlt().solve(-j.transpose() * r);
}

TEST(TiedPoses, DbaSchurStepEqualsReducedStepOverPhases) {
  uint64_t seed = 211;
  // Under the sanitizers the two smaller cases (4 minutes of the pass for the third, whose
  // dense DBA Jacobian has 3 intensity columns per voxel; it runs the same code).
  const std::vector<Case> all = Cases();
  const std::vector<Case> cases(
      all.begin(), all.begin() + testing_support::FullUnlessSanitized<size_t>(all.size(), 2));
  for (Gauge gauge : {Gauge::kFrame0, Gauge::kMean}) {
    for (bool photometric : {false, true}) {
      for (const Case& c : cases) {
        const auto s = MakeSequence(PhasedOptionsFor(c, seed++, 3));
        ASSERT_EQ(NumPhases(s.frames), 3);
        std::vector<Eigen::Isometry3d> poses = Perturbed(s.ground_truth, 0.02, 0.7, seed++);
        if (gauge == Gauge::kMean) poses = MovedTogether(poses, seed++);
        const std::vector<Photometric> start =
            photometric ? RandomPhotometric(c.num_frames, seed++) : std::vector<Photometric>();
        const CandidateSet cand = Candidates(s, poses);
        DsrOptions options;
        options.gauge = gauge;
        options.photometric = photometric;
        options.initial_photometric = start;
        options.solve.num_threads = 2;
        DsrProblem dsr(s.frames, cand, poses, options);
        DbaProblem dba(s.frames, cand, poses, start, RobustLoss(), gauge,
                       StreamContextFor(options.solve));
        EXPECT_EQ(dba.num_intensities(), 3 * cand.num_voxels());
        // The free blocks in the order of DSR's fast path: poses, then photometric blocks.
        std::vector<double*> dsr_blocks, dba_blocks;
        for (int i = gauge == Gauge::kMean ? 0 : 1; i < c.num_frames; ++i) {
          dsr_blocks.push_back(dsr.pose_parameters(i));
          dba_blocks.push_back(dba.pose_parameters(i));
        }
        for (int i = 1; photometric && i < c.num_frames; ++i) {
          dsr_blocks.push_back(dsr.photometric_parameters(i));
          dba_blocks.push_back(dba.photometric_parameters(i));
        }
        double cost;
        const Eigen::VectorXd dsr_step = DsrStep(&dsr, dsr_blocks, &cost);
        const Eigen::VectorXd dba_step = DbaSchurStep(&dba, dba_blocks);
        EXPECT_LT(RelativeDifference(dba_step, dsr_step), kStepRelativeTolerance)
            << "m=" << c.num_frames << " photometric=" << photometric << " mean gauge="
            << (gauge == Gauge::kMean) << "\nDBA " << dba_step.transpose() << "\nDSR "
            << dsr_step.transpose();
        // Whatever the (voxel, phase) intensities are (with photometric blocks the step
        // is the reduced one at the eliminated intensities only, where DbaProblem starts:
        // their derivatives depend on M).
        if (photometric) continue;
        std::mt19937_64 rng(seed++);
        std::uniform_real_distribution<double> u(-500.0, 500.0);
        for (int64_t v = 0; v < dba.num_intensities(); ++v) *dba.intensity(v) = u(rng);
        EXPECT_LT(RelativeDifference(DbaSchurStep(&dba, dba_blocks), dsr_step),
                  kStepRelativeTolerance)
            << "m=" << c.num_frames << " with random intensities";
      }
    }
  }
}

// The tied cost is the sum of the phases' costs, each the 3D problem of that phase's
// volumes (frames built from the phase images themselves, not from Frame::Phase), and the
// fast path equals the per-voxel reference over the phases.
TEST(TiedPoses, ReducedCostIsTheSumOfThePhasesCosts) {
  uint64_t seed = 241;
  for (const Case& c : Cases()) {
    const auto s = MakeSequence(PhasedOptionsFor(c, seed++, 4));
    const auto poses = Perturbed(s.ground_truth, 0.02, 0.7, seed++);
    const CandidateSet cand = Candidates(s, poses);
    std::vector<double*> blocks;
    DsrOptions options;
    options.solve.num_threads = 2;
    DsrProblem tied(s.frames, cand, poses, options);
    for (int i = 1; i < c.num_frames; ++i) blocks.push_back(tied.pose_parameters(i));
    Eigen::VectorXd r;
    double tied_cost;
    const Eigen::MatrixXd j = DenseJacobian(&tied.problem(), blocks, &r, &tied_cost);
    double sum = 0.0;
    Eigen::VectorXd gradient = Eigen::VectorXd::Zero(j.cols());
    Eigen::MatrixXd hessian = Eigen::MatrixXd::Zero(j.cols(), j.cols());
    std::vector<double> phase_costs;
    for (int p = 0; p < 4; ++p) {
      std::vector<Frame> frames;
      for (int i = 0; i < c.num_frames; ++i) frames.emplace_back(s.phase_images[i][p], s.masks[i]);
      DsrProblem one(frames, cand, poses, options);
      std::vector<double*> one_blocks;
      for (int i = 1; i < c.num_frames; ++i) one_blocks.push_back(one.pose_parameters(i));
      Eigen::VectorXd rp;
      double cost;
      const Eigen::MatrixXd jp = DenseJacobian(&one.problem(), one_blocks, &rp, &cost);
      sum += cost;
      phase_costs.push_back(cost);
      gradient += jp.transpose() * rp;
      hessian += jp.transpose() * jp;
    }
    EXPECT_NEAR(tied_cost, sum, kSystemRelativeTolerance * sum) << "m=" << c.num_frames;
    EXPECT_LT(RelativeDifference(j.transpose() * r, gradient), kSystemRelativeTolerance);
    EXPECT_LT((j.transpose() * j - hessian).norm(), kSystemRelativeTolerance * hessian.norm());
    // The phases differ (the beating blobs): no phase's cost is a quarter of the sum.
    const auto [lo, hi] = std::minmax_element(phase_costs.begin(), phase_costs.end());
    EXPECT_GT(*hi - *lo, 1e-3 * sum) << "m=" << c.num_frames;

    DsrOptions reference = options;
    reference.reference_cost = true;
    DsrProblem per_voxel(s.frames, cand, poses, reference);
    std::vector<double*> reference_blocks;
    for (int i = 1; i < c.num_frames; ++i) reference_blocks.push_back(per_voxel.pose_parameters(i));
    double reference_cost;
    const Eigen::MatrixXd jr = DenseJacobian(&per_voxel.problem(), reference_blocks, &r,
                                             &reference_cost);
    EXPECT_NEAR(reference_cost, tied_cost, kSystemRelativeTolerance * sum);
    EXPECT_LT(RelativeDifference(jr.transpose() * r, gradient), kSystemRelativeTolerance);
    EXPECT_LT((jr.transpose() * jr - hessian).norm(), kSystemRelativeTolerance * hessian.norm());
  }
}

// Full solves over 3 phases per view: DBA (an intensity block per voxel and phase), DSR's
// fast path and its per-voxel reference reach the same poses, the ground truth (lattice
// sequences: every residual of every phase vanishes there).
TEST(TiedPoses, FullSolvesOfBothModesConvergeToTheSamePoses) {
  DSR_SKIP_HEAVY_UNDER_SANITIZER();
  uint64_t seed = 271;
  for (const Case& c : {Case{3, 16, 0.0, 1}, Case{4, 16, 5.0, 1}}) {
    SequenceOptions o = LatticeOptionsFor(c, seed++);
    o.num_phases = 3;
    ExpectFullSolvesMeetAtTheTruth(o, seed++);
  }
}

// A robust loss over phases: DSR's reweighted solves (one set of weights per phase) and
// DBA with Ceres's loss reach the same fixed point.
TEST(TiedPoses, RobustSolvesOfBothModesAgree) {
  DSR_SKIP_HEAVY_UNDER_SANITIZER();
  SequenceOptions o = LatticeOptionsFor(Case{3, 16, 5.0, 1}, 301);
  o.num_phases = 2;
  const auto s = MakeSequence(o);
  const auto init = Perturbed(s.ground_truth, 0.02, 0.5, 302);
  const CandidateSet cand = InteriorCandidates(s, init, 1.5);
  RobustLoss loss;
  std::string error;
  ASSERT_TRUE(MakeRobustLoss("cauchy", 5.0, &loss, &error)) << error;
  SolveReport report;
  DbaOptions dba;
  dba.loss = loss;
  dba.solve = FixedPointOptions(4000);
  ASSERT_TRUE(SolveDba(s.frames, cand, init, dba, &report, nullptr, &error)) << error;
  const auto dba_poses = report.frame_from_world;
  DsrOptions dsr;
  dsr.loss = loss;
  dsr.solve = FixedPointOptions(1000);
  ASSERT_TRUE(SolveDsr(s.frames, cand, init, dsr, &report, &error)) << error;
  EXPECT_TRUE(report.usable) << report.termination;
  EXPECT_THAT(report.frame_from_world,
              FramesFromWorldNear(dba_poses, kFixedPointRotationRad, kFixedPointTranslationMm));
  EXPECT_THAT(report.frame_from_world, FramesFromWorldNear(s.ground_truth, kFixedPointRotationRad,
                                                           kFixedPointTranslationMm));
}

}  // namespace
}  // namespace dsr
