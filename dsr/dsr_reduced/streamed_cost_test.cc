// Reuse of streamed passes (stream/streamed_cost.h: speculative Jacobians at trial points,
// no Jacobians at the point that ends the solve) changes how often the voxels are
// streamed, never what Ceres sees: DSR (several chunks) and APE solves with and without
// it take the same steps, reach bit-identical poses and costs, and stop for the same
// reason, with fewer passes.
#include <cstdlib>

#include <gtest/gtest.h>

#include "dsr/baselines/baselines.h"
#include "dsr/dsr_reduced/dsr_solver.h"
#include "dsr/tests/support/test_problems.h"

namespace dsr {
namespace {

using testing_problems::Candidates;
using testing_problems::MakeSequence;
using testing_problems::Perturbed;
using testing_problems::SequenceOptions;

testing_problems::TestSequence Sequence(uint64_t seed) {
  SequenceOptions o;
  o.num_frames = 4;
  o.size = 18;
  o.noise_sigma = 8.0;
  o.seed = seed;
  return MakeSequence(o);
}

void ExpectSameSolve(const SolveReport& with, const SolveReport& without, bool fewer_passes) {
  ASSERT_EQ(with.iterations.size(), without.iterations.size());
  for (size_t i = 0; i < with.iterations.size(); ++i) {
    EXPECT_EQ(with.iterations[i].step_accepted, without.iterations[i].step_accepted) << i;
    EXPECT_EQ(with.iterations[i].step_norm, without.iterations[i].step_norm) << i;
    // The cost Ceres reads back from the compressed residual: the lazy final point's
    // residual is built from another point's model, so its square may round differently.
    EXPECT_NEAR(with.iterations[i].cost, without.iterations[i].cost,
                1e-14 * without.iterations[i].cost)
        << i;
  }
  ASSERT_EQ(with.frame_from_world.size(), without.frame_from_world.size());
  for (size_t i = 0; i < with.frame_from_world.size(); ++i) {
    EXPECT_TRUE(with.frame_from_world[i].matrix() == without.frame_from_world[i].matrix())
        << "frame " << i;
  }
  EXPECT_EQ(with.termination, without.termination);
  EXPECT_EQ(with.usable, without.usable);
  // Fewer passes over the voxels with reuse (a pass with Jacobians counted as two). Not
  // guaranteed for every solve: a speculated trial that is rejected costs an extra half.
  if (!fewer_passes) return;
  EXPECT_LT(2 * with.jacobian_passes + with.cost_passes,
            2 * without.jacobian_passes + without.cost_passes);
}

// Solves with `solve` given the options' SolveOptions, with and without reuse.
template <class Options, class Solve>
void SolveBothWays(Options options, const Solve& solve, SolveReport* with, SolveReport* without) {
  std::string error;
  options.solve.reuse_evaluations = true;
  ASSERT_TRUE(solve(options, with, &error)) << error;
  options.solve.reuse_evaluations = false;
  ASSERT_TRUE(solve(options, without, &error)) << error;
}

// In either pose gauge (solve/gauge.h): in the mean gauge frame 0's pose is a block too, and
// the lazy final point measures the step against frame 0's, like the stopping rule.
TEST(StreamedCost, ReusingPassesDoesNotChangeDsrSolves) {
  for (Gauge gauge : {Gauge::kFrame0, Gauge::kMean}) {
    int by_step_rule = 0;
    const uint64_t first_seed = gauge == Gauge::kFrame0 ? 3 : 6;
    for (uint64_t seed : {first_seed, uint64_t{4}}) {
      const auto s = Sequence(seed);
      const auto init = Perturbed(s.ground_truth, 0.04, 1.5, seed + 10);
      const CandidateSet cand = Candidates(s, init);
      DsrOptions options;
      options.num_chunks = 3;
      options.gauge = gauge;
      options.solve.progress = getenv("DSR_TEST_LOG") != nullptr;
      options.solve.max_iterations = 30;
      // Coarse enough that the pose step rule can end these small noisy solves.
      options.solve.step_tolerance = 0.3;
      SolveReport with, without;
      SolveBothWays(options, [&](const DsrOptions& o, SolveReport* r, std::string* e) {
        return SolveDsr(s.frames, cand, init, o, r, e);
      }, &with, &without);
      ASSERT_GT(without.num_iterations, 2);
      EXPECT_EQ(without.cost_passes, without.num_iterations * 3);  // one per trial, per chunk
      if (without.termination.find("pose step tolerance") != std::string::npos) ++by_step_rule;
      ExpectSameSolve(with, without, /*fewer_passes=*/true);
    }
    // Seed 3 (frame-0 gauge) or 6 (mean gauge) ends by the pose step rule (the lazy final
    // point is taken), seed 4 by rejected steps: both endings are compared.
    EXPECT_EQ(by_step_rule, 1) << GaugeToString(gauge);
  }
}

TEST(StreamedCost, ReusingPassesDoesNotChangeApeSolves) {
  const auto s = Sequence(5);
  const auto init = Perturbed(s.ground_truth, 0.04, 1.5, 15);
  const CandidateSet cand = Candidates(s, init);
  BaselineOptions options;
  options.solve.progress = false;
  options.solve.max_iterations = 30;
  SolveReport with, without;
  SolveBothWays(options, [&](const BaselineOptions& o, SolveReport* r, std::string* e) {
    return SolveApe(s.frames, cand, init, o, r, e);
  }, &with, &without);
  ExpectSameSolve(with, without, /*fewer_passes=*/false);
}

TEST(StreamedCost, StepRuleOffMeansNoLazyFinalPoint) {
  // Without the pose step rule nothing stops Ceres at a small step, so every accepted
  // point must get its own Jacobians: the solve still matches the one without reuse.
  const auto s = Sequence(6);
  const auto init = Perturbed(s.ground_truth, 0.04, 1.5, 16);
  const CandidateSet cand = Candidates(s, init);
  DsrOptions options;
  options.solve.progress = false;
  options.solve.max_iterations = 12;
  options.solve.step_tolerance = 0.0;
  SolveReport with, without;
  SolveBothWays(options, [&](const DsrOptions& o, SolveReport* r, std::string* e) {
    return SolveDsr(s.frames, cand, init, o, r, e);
  }, &with, &without);
  ExpectSameSolve(with, without, /*fewer_passes=*/false);
}

TEST(StreamedCost, DsrReportsTheFrameCostsOfItsFinalPoses) {
  // The pipeline's misfit check reuses them instead of streaming once more.
  SequenceOptions o;
  o.num_frames = 4;
  o.size = 18;
  o.seed = 7;
  o.lattice = true;  // an exact minimum away from field-of-view edges: the solve ends by
                     // the pose step rule (see dsr_theorem_test)
  const auto s = MakeSequence(o);
  const auto init = Perturbed(s.ground_truth, 0.02, 0.5, 17);
  const CandidateSet cand = testing_problems::InteriorCandidates(s, init, 1.5);
  DsrOptions options;
  options.num_chunks = 2;
  options.solve.progress = false;
  SolveReport report;
  std::string error;
  ASSERT_TRUE(SolveDsr(s.frames, cand, init, options, &report, &error)) << error;
  ASSERT_NE(report.termination.find("pose step tolerance"), std::string::npos)
      << report.termination;
  ASSERT_EQ(report.final_frame_cost.size(), s.frames.size());
  ReducedSystem at_final;
  AccumulateReducedSystem(s.frames, cand, report.frame_from_world, 0, cand.num_voxels(), false,
                          StreamContext{2}, &at_final);
  EXPECT_EQ(report.final_frame_observations, at_final.frame_observations);
  for (size_t i = 0; i < s.frames.size(); ++i) {
    // Two chunks summed vs one pass: the same terms, added in another order.
    EXPECT_NEAR(report.final_frame_cost[i], at_final.frame_cost[i], 1e-12 * at_final.cost) << i;
  }
}

}  // namespace
}  // namespace dsr
