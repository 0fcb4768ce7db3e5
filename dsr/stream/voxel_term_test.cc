// The per-voxel term extension point (stream/voxel_term.h): a second term plugs into the
// stream. PairwiseDifferenceTerm (test-only) writes DSR's objective another way, as
// (1/k) sum_{a<b} (I_a - I_b)^2 per voxel with its own gradient and Gauss-Newton matrix
// added voxel by voxel (no batched form). Per voxel that is algebraically DSR's
// sum_a (I_a - mu)^2 (sum_{a<b} (I_a - I_b)^2 = k sum_a (I_a - mu)^2), so the stream must
// give the same cost, gradient and Gauss-Newton matrix with it as with SsdToMeanTerm; and
// its Jacobians must be the derivatives of its own cost (numeric differences).
#include <gtest/gtest.h>

#include <cmath>
#include <map>
#include <string>
#include <tuple>
#include <vector>

#include "dsr/stream/ssd_to_mean_term.h"
#include "dsr/stream/voxel_stream.h"
#include "dsr/stream/voxel_term.h"
#include "dsr/tests/support/kernel_paths.h"
#include "dsr/tests/support/test_problems.h"

namespace dsr {
namespace {

using testing_kernels::AvailablePaths;
using testing_problems::InteriorCandidates;
using testing_problems::LinearRampFrame;
using testing_problems::MakeSequence;
using testing_problems::Perturbed;
using testing_problems::SequenceOptions;
using testing_problems::TestSequence;

// Residuals of the pairwise form keyed by (voxel, frame a, frame b), for the numeric check.
using PairResiduals = std::map<std::tuple<int64_t, int, int>, double>;

// r_ab = (I_a - I_b) / sqrt(k) for each pair a < b of a voxel's k observers:
//   cost += sum r_ab^2,  g_a += r_ab J_a / sqrt(k),  g_b -= r_ab J_b / sqrt(k),
//   H_aa += J_a^T J_a / k,  H_bb += J_b^T J_b / k,  H_ab -= J_a^T J_b / k.
// Each pair's r^2 is split evenly between its two frames; observations count the pairs.
struct PairwiseDifferenceTerm {
  bool batched_hessian = false;
  bool batched_gradient = false;
  HessianWeights Weights(int) const { return {}; }  // not batched
  // Set: every pair's residual is recorded (one thread only: the map is not locked).
  PairResiduals* record = nullptr;

  void operator()(const VoxelObservations& obs, bool with_jacobian, VoxelAccumulator* acc) const {
    const int k = obs.k;
    const double scale = 1.0 / std::sqrt(static_cast<double>(k));
    acc->observations += int64_t{k} * (k - 1) / 2;
    for (int a = 0; a < k; ++a) {
      for (int b = a + 1; b < k; ++b) {
        const int fa = obs.frame[a], fb = obs.frame[b];
        const double r = scale * (obs.value[a] - obs.value[b]);
        if (record != nullptr) (*record)[{obs.voxel, fa, fb}] = r;
        acc->cost += r * r;
        acc->frame_cost[fa] += 0.5 * r * r;
        acc->frame_cost[fb] += 0.5 * r * r;
        if (!with_jacobian) continue;
        AddGradient(acc->gradient.data(), fa, obs.jac[a], scale * r);
        AddGradient(acc->gradient.data(), fb, obs.jac[b], -scale * r);
        const double inv_k = 1.0 / k;
        AddOuter(acc->hessian.data(), acc->n, fa, fa, obs.jac[a], obs.jac[a], inv_k);
        AddOuter(acc->hessian.data(), acc->n, fb, fb, obs.jac[b], obs.jac[b], inv_k);
        AddOuter(acc->hessian.data(), acc->n, fa, fb, obs.jac[a], obs.jac[b], -inv_k);
      }
    }
    for (int a = 0; a < k; ++a) ++acc->frame_observations[obs.frame[a]];
  }
};

// The interface check: both terms pass it, types missing a part do not.
struct NoWeights {
  bool batched_hessian = false, batched_gradient = false;
  void operator()(const VoxelObservations&, bool, VoxelAccumulator*) const {}
};
struct NotCallable {
  bool batched_hessian = false, batched_gradient = false;
  HessianWeights Weights(int) const { return {}; }
};
struct SevenParameters : PairwiseDifferenceTerm {
  static constexpr int kFrameParameters = 7;
};
static_assert(IsVoxelTerm<SsdToMeanTerm>::value, "DSR's term is a voxel term");
static_assert(IsVoxelTerm<PairwiseDifferenceTerm>::value, "the test's term is a voxel term");
static_assert(!IsVoxelTerm<NoWeights>::value, "Weights(k) is required");
static_assert(!IsVoxelTerm<NotCallable>::value, "the per-voxel call is required");
static_assert(!IsVoxelTerm<SevenParameters>::value, "6 or 8 parameters per frame");
static_assert(!IsVoxelTerm<int>::value, "not a term");

double Relative(const Eigen::MatrixXd& a, const Eigen::MatrixXd& b) {
  return (a - b).norm() / b.norm();
}

// The same objective through the two terms: the same normal equations to rounding (the
// sums are formed in another order), on every kernel path and with 1 and 2 threads.
TEST(VoxelTerm, PairwiseDifferenceTermGivesDsrsNormalEquations) {
  uint64_t seed = 11;
  for (const int num_frames : {2, 3, 5}) {
    SequenceOptions o;
    o.num_frames = num_frames;
    o.size = 16;
    o.noise_sigma = 10.0;
    o.seed = seed++;
    const TestSequence s = MakeSequence(o);
    const auto poses = Perturbed(s.ground_truth, 0.03, 1.0, seed++);
    const CandidateSet cand = testing_problems::Candidates(s, poses);
    ASSERT_GT(cand.num_voxels(), 500);
    for (const KernelPath path : AvailablePaths()) {
      for (const int threads : {1, 2}) {
        const StreamContext context{threads, path};
        NormalEquations ssd, pairwise;
        StreamNormalEquations(s.frames, cand, poses, 0, cand.num_voxels(), true, context,
                              SsdToMeanTerm(), &ssd);
        StreamNormalEquations(s.frames, cand, poses, 0, cand.num_voxels(), true, context,
                              PairwiseDifferenceTerm(), &pairwise);
        const std::string where = std::string(KernelPathToString(path)) +
                                  " m=" + std::to_string(num_frames) +
                                  " threads=" + std::to_string(threads);
        ASSERT_GT(ssd.cost, 0.0) << where;
        EXPECT_NEAR(pairwise.cost, ssd.cost, 1e-9 * ssd.cost) << where;
        EXPECT_LT(Relative(pairwise.gradient, ssd.gradient), 1e-9) << where;
        EXPECT_LT(Relative(pairwise.hessian, ssd.hessian), 1e-9) << where;
        EXPECT_EQ(pairwise.voxels, ssd.voxels) << where;
        // The cost-only pass gives the same cost as the pass with Jacobians.
        NormalEquations cost_only;
        StreamNormalEquations(s.frames, cand, poses, 0, cand.num_voxels(), false, context,
                              PairwiseDifferenceTerm(), &cost_only);
        EXPECT_EQ(cost_only.cost, pairwise.cost) << where;
      }
    }
  }
}

// Frames 1 + c / 6 moved by `sign` steps along tangent axis c % 6 (left perturbation
// Exp(delta) T, tangent [rho; phi]: geometry/se3.h). Returns the step.
double Moved(int c, double sign, std::vector<Eigen::Isometry3d>* poses) {
  const int axis = c % 6;
  const double h = axis < 3 ? 1e-3 : 1e-4;  // mm, rad
  Vector6d delta = Vector6d::Zero();
  delta[axis] = sign * h;
  (*poses)[1 + c / 6] = ExpSE3(delta) * (*poses)[1 + c / 6];
  return h;
}

// The term's Jacobians are the derivatives of its own cost: on linear ramps (whose
// gradient volumes are the interpolant's exact slope: test_problems.h), 2 g against central
// differences of the cost, and H = J^T J with J from central differences of its residuals
// r_ab. Candidates keep only samples well inside the valid cells, so that no sample
// switches sigma_ij between the +-h evaluations.
TEST(VoxelTerm, PairwiseDifferenceJacobiansMatchNumericDifferences) {
  TestSequence s;
  for (const double base : {40.0, 45.0, 38.0}) s.frames.push_back(LinearRampFrame(base));
  std::vector<Eigen::Isometry3d> identity(3, Eigen::Isometry3d::Identity());
  const auto poses = Perturbed(identity, 0.05, 1.0, 7);
  const CandidateSet cand = InteriorCandidates(s, poses, 0.05);
  ASSERT_GT(cand.num_voxels(), 500);
  const StreamContext context{1};  // one thread: the residual map is not locked
  const auto evaluate = [&](const std::vector<Eigen::Isometry3d>& at, bool with_jacobian,
                            PairResiduals* record) {
    PairwiseDifferenceTerm term;
    term.record = record;
    NormalEquations out;
    StreamNormalEquations(s.frames, cand, at, 0, cand.num_voxels(), with_jacobian, context, term,
                          &out);
    return out;
  };
  PairResiduals at_poses;
  const NormalEquations system = evaluate(poses, true, &at_poses);
  const int n = 6 * 2;  // frames 1 and 2
  Eigen::VectorXd numeric_gradient(n);
  Eigen::MatrixXd numeric_jacobian(at_poses.size(), n);
  for (int c = 0; c < n; ++c) {
    auto plus = poses, minus = poses;
    const double h = Moved(c, 1.0, &plus);
    Moved(c, -1.0, &minus);
    PairResiduals r_plus, r_minus;
    const double f_plus = evaluate(plus, false, &r_plus).cost;
    const double f_minus = evaluate(minus, false, &r_minus).cost;
    numeric_gradient[c] = (f_plus - f_minus) / (2.0 * h);
    ASSERT_EQ(r_plus.size(), at_poses.size());
    ASSERT_EQ(r_minus.size(), at_poses.size());
    int row = 0;
    for (auto p = r_plus.begin(), m = r_minus.begin(); p != r_plus.end(); ++p, ++m, ++row) {
      ASSERT_EQ(p->first, m->first);
      numeric_jacobian(row, c) = (p->second - m->second) / (2.0 * h);
    }
  }
  // 1e-3: the ramps are stored as floats (as in the reference costs' numeric checks).
  const Eigen::VectorXd analytic_gradient = 2.0 * system.gradient.tail(n);
  EXPECT_LT((analytic_gradient - numeric_gradient).norm(), 1e-3 * numeric_gradient.norm())
      << "analytic " << analytic_gradient.transpose() << "\nnumeric  "
      << numeric_gradient.transpose();
  const Eigen::MatrixXd numeric_hessian = numeric_jacobian.transpose() * numeric_jacobian;
  EXPECT_LT(Relative(system.hessian.bottomRightCorner(n, n), numeric_hessian), 1e-3);
  // The residuals are the cost's: sum r^2 = f.
  double sum = 0.0;
  for (const auto& entry : at_poses) sum += entry.second * entry.second;
  EXPECT_NEAR(sum, system.cost, 1e-12 * system.cost);
}

}  // namespace
}  // namespace dsr
