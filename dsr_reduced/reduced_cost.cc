// Reduced DSR cost: per-voxel reference and streaming chunk cost (docs/design.md section 4).
#include "dsr_reduced/reduced_cost.h"

#include <algorithm>
#include <cmath>
#include <cstring>

#include <glog/logging.h>

namespace dsr {
namespace {

// The DSR term of one voxel observed by k >= 2 frames: r_a = I_a - mu,
//   cost += sum_a r_a^2,  g_a += J_a^T r_a,  H_ab += (delta_ab - 1/k) J_a^T J_b,
// and frame a's share r_a^2 of the cost (for the per-frame misfits). H and g are added in
// batches by the stream from the Jacobians and the residuals the term writes (fast path),
// or here voxel by voxel (the twin tests compare with).
struct DsrVoxelTerm {
  static constexpr int kFrameParameters = 6;
  bool batched_hessian = true;
  bool batched_gradient = true;
  HessianWeights Weights(int k) const { return {1.0, -1.0 / k}; }

  // The voxel's numbers are read through restrict pointers and summed in locals: the
  // accumulator's doubles could otherwise alias them, and every store to the gradient
  // would reload the observations (callgrind: 76 instructions per observation, now 53
  // with the per-voxel loop).
  void operator()(const VoxelObservations& obs, bool with_jacobian, VoxelAccumulator* acc) const {
    const int k = obs.k;
    const int* __restrict frame = obs.frame;
    const double* __restrict value = obs.value;
    double mean = 0.0;
    for (int a = 0; a < k; ++a) mean += value[a];
    mean /= k;
    // With a batched gradient the residuals go straight to the batch for the stream.
    double local[kMaxFrames];
    double* __restrict residual = obs.residual != nullptr ? obs.residual : local;
    double cost = 0.0;
    for (int a = 0; a < k; ++a) {
      const double r = value[a] - mean;
      residual[a] = r;
      cost += r * r;
      acc->frame_cost[frame[a]] += r * r;
      ++acc->frame_observations[frame[a]];
    }
    acc->cost += cost;
    acc->observations += k;
    if (!with_jacobian || obs.residual != nullptr) return;
    double* __restrict g = acc->gradient.data();
    for (int a = 0; a < k; ++a) AddGradient(g, frame[a], obs.jac[a], residual[a]);
    if (batched_hessian) return;
    const double inv_k = 1.0 / k;
    double* h = acc->hessian.data();
    const int n = acc->n;
    for (int a = 0; a < k; ++a) {
      AddOuter(h, n, frame[a], frame[a], obs.jac[a], obs.jac[a], 1.0 - inv_k);
      for (int b = a + 1; b < k; ++b) AddOuter(h, n, frame[a], frame[b], obs.jac[a], obs.jac[b], -inv_k);
    }
  }
};

// The DSR term with photometric parameters (docs/design.md section 2.8): the corrected
// observations c_a = g_a I_a + b_a (g = gain, b = offset of the observing frame), r_a =
// c_a - mean c, and the wide Jacobians J'_a = [g_a J_a, g_a I_a, 1] in the place of J_a:
//   d r_a / d x_b = (delta_ab - 1/k) J'_b  (x_b: frame b's pose tangent, log gain, offset),
//   cost += sum_a r_a^2,  g_b += J'_b^T r_b,  H_ab += (delta_ab - 1/k) J'_a^T J'_b,
// the same form as DsrVoxelTerm with 8 x 8 blocks, batched by the stream the same way.
struct DsrPhotometricVoxelTerm {
  static constexpr int kFrameParameters = kWideJacobianSize;
  bool batched_hessian = true;
  bool batched_gradient = true;
  double gain[kMaxFrames];
  double offset[kMaxFrames];
  HessianWeights Weights(int k) const { return {1.0, -1.0 / k}; }

  void operator()(const VoxelObservations& obs, bool with_jacobian, VoxelAccumulator* acc) const {
    const int k = obs.k;
    const int* __restrict frame = obs.frame;
    const double* __restrict value = obs.value;
    double corrected[kMaxFrames];
    double mean = 0.0;
    for (int a = 0; a < k; ++a) {
      corrected[a] = gain[frame[a]] * value[a] + offset[frame[a]];
      mean += corrected[a];
    }
    mean /= k;
    double local[kMaxFrames];
    double* __restrict residual = obs.residual != nullptr ? obs.residual : local;
    double cost = 0.0;
    for (int a = 0; a < k; ++a) {
      const double r = corrected[a] - mean;
      residual[a] = r;
      cost += r * r;
      acc->frame_cost[frame[a]] += r * r;
      ++acc->frame_observations[frame[a]];
    }
    acc->cost += cost;
    acc->observations += k;
    if (!with_jacobian) return;
    double (*__restrict wide)[kWideJacobianSize] = obs.wide_jac;
    for (int a = 0; a < k; ++a) {
      const double g = gain[frame[a]];
      for (int e = 0; e < kJacobianSize; ++e) wide[a][e] = g * obs.jac[a][e];
      wide[a][6] = g * value[a];
      wide[a][7] = 1.0;
    }
    if (obs.residual != nullptr) return;  // the stream adds g and H
    constexpr int W = kWideJacobianSize;
    double* __restrict grad = acc->gradient.data();
    for (int a = 0; a < k; ++a) {
      for (int e = 0; e < W; ++e) grad[W * frame[a] + e] += residual[a] * wide[a][e];
    }
    if (batched_hessian) return;
    // The slow twin: every pair's 8 x 8 block (the diagonal ones whole, above their
    // diagonal is what the stream reads).
    const double inv_k = 1.0 / k;
    double* h = acc->hessian.data();
    const int n = acc->n;
    for (int a = 0; a < k; ++a) {
      for (int b = a; b < k; ++b) {
        const double w = (a == b ? 1.0 : 0.0) - inv_k;
        for (int i = 0; i < W; ++i) {
          double* row = h + static_cast<int64_t>(W * frame[a] + i) * n + W * frame[b];
          for (int j = 0; j < W; ++j) row[j] += w * wide[a][i] * wide[b][j];
        }
      }
    }
  }
};

// Both reference costs: the residuals r_i = c_i - mean c of one voxel's observers and their
// Jacobians, with c_i = a_i I_i + b_i from `photometric` ([log_gain, offset] per observer)
// or c_i = I_i when it is null (then a_i = 1 exactly, so the plain cost is unchanged).
// `pose_jacobians` / `photometric_jacobians` (either may be null, as may their entries) are
// n x 7 and n x 2 row-major per observer.
void EvaluateVoxel(const std::vector<const Frame*>& observers,
                   const Eigen::Vector3d& voxel_center_in_world,
                   double const* const* poses,
                   double const* const* photometric,
                   double* residuals,
                   double** pose_jacobians,
                   double** photometric_jacobians) {
  const int n = static_cast<int>(observers.size());
  std::vector<double> value(n, 0.0), corrected(n, 0.0), gain(n, 1.0);
  std::vector<RowVector6d> jac(n, RowVector6d::Zero());
  std::vector<int> sigma(n, 0);
  int k = 0;
  double sum = 0.0;
  for (int i = 0; i < n; ++i) {
    const Photometric correction =
        photometric != nullptr ? Photometric{photometric[i][0], photometric[i][1]} : Photometric();
    if (photometric != nullptr) gain[i] = correction.gain();
    if (ObserveSample(*observers[i], ParametersToPose(poses[i]), voxel_center_in_world,
                      &value[i], &jac[i])) {
      sigma[i] = 1;
      ++k;
      corrected[i] = photometric != nullptr ? correction.Correct(value[i]) : value[i];
      sum += corrected[i];
    }
  }
  for (int a = 0; a < n; ++a) {
    if (pose_jacobians != nullptr && pose_jacobians[a] != nullptr) {
      std::memset(pose_jacobians[a], 0, sizeof(double) * n * kPoseAmbientSize);
    }
    if (photometric_jacobians != nullptr && photometric_jacobians[a] != nullptr) {
      std::memset(photometric_jacobians[a], 0, sizeof(double) * n * 2);
    }
  }
  if (k < 2) {  // mu_j = the lone observation (or none): no residual, no Jacobian.
    std::fill(residuals, residuals + n, 0.0);
    return;
  }
  const double mean = sum / k;
  for (int i = 0; i < n; ++i) residuals[i] = sigma[i] ? corrected[i] - mean : 0.0;
  for (int a = 0; a < n; ++a) {
    if (!sigma[a]) continue;
    // d r_i / d delta_a = sigma_i sigma_a (delta_ia - 1/k) a_a J_a, then to the ambient block.
    if (pose_jacobians != nullptr && pose_jacobians[a] != nullptr) {
      const Eigen::Matrix<double, 1, kPoseAmbientSize> ambient =
          gain[a] * jac[a] * TangentToAmbientJacobian(poses[a]);
      Eigen::Map<Eigen::Matrix<double, Eigen::Dynamic, kPoseAmbientSize, Eigen::RowMajor>> out(
          pose_jacobians[a], n, kPoseAmbientSize);
      for (int i = 0; i < n; ++i) {
        if (sigma[i]) out.row(i) = ((i == a ? 1.0 : 0.0) - 1.0 / k) * ambient;
      }
    }
    // d r_i / d [log_gain_a, b_a] = sigma_i sigma_a (delta_ia - 1/k) [a_a I_a, 1].
    if (photometric_jacobians != nullptr && photometric_jacobians[a] != nullptr) {
      for (int i = 0; i < n; ++i) {
        if (!sigma[i]) continue;
        const double w = (i == a ? 1.0 : 0.0) - 1.0 / k;
        photometric_jacobians[a][2 * i] = w * gain[a] * value[a];
        photometric_jacobians[a][2 * i + 1] = w;
      }
    }
  }
}

}  // namespace

VoxelReducedCost::VoxelReducedCost(std::vector<const Frame*> observers,
                                   const Eigen::Vector3d& voxel_center_in_world)
    : observers_(std::move(observers)), voxel_center_in_world_(voxel_center_in_world) {
  set_num_residuals(static_cast<int>(observers_.size()));
  for (size_t i = 0; i < observers_.size(); ++i) {
    mutable_parameter_block_sizes()->push_back(kPoseAmbientSize);
  }
}

bool VoxelReducedCost::Evaluate(double const* const* parameters,
                                double* residuals,
                                double** jacobians) const {
  EvaluateVoxel(observers_, voxel_center_in_world_, parameters, nullptr, residuals, jacobians,
                nullptr);
  return true;
}

VoxelReducedPhotometricCost::VoxelReducedPhotometricCost(
    std::vector<const Frame*> observers, const Eigen::Vector3d& voxel_center_in_world)
    : observers_(std::move(observers)), voxel_center_in_world_(voxel_center_in_world) {
  set_num_residuals(static_cast<int>(observers_.size()));
  for (size_t i = 0; i < observers_.size(); ++i) {
    mutable_parameter_block_sizes()->push_back(kPoseAmbientSize);
  }
  for (size_t i = 0; i < observers_.size(); ++i) mutable_parameter_block_sizes()->push_back(2);
}

bool VoxelReducedPhotometricCost::Evaluate(double const* const* parameters,
                                           double* residuals,
                                           double** jacobians) const {
  const int n = static_cast<int>(observers_.size());
  EvaluateVoxel(observers_, voxel_center_in_world_, parameters, parameters + n, residuals,
                jacobians, jacobians != nullptr ? jacobians + n : nullptr);
  return true;
}

void AccumulateReducedSystem(const std::vector<Frame>& frames,
                             const CandidateSet& candidates,
                             const std::vector<Eigen::Isometry3d>& frame_from_world,
                             int64_t begin,
                             int64_t end,
                             bool with_jacobian,
                             int num_threads,
                             ReducedSystem* out,
                             bool batched_hessian) {
  DsrVoxelTerm term;
  term.batched_hessian = batched_hessian;
  term.batched_gradient = batched_hessian;
  StreamNormalEquations(frames, candidates, frame_from_world, begin, end, with_jacobian,
                        num_threads, term, out);
}

void AccumulateReducedPhotometricSystem(const std::vector<Frame>& frames,
                                        const CandidateSet& candidates,
                                        const std::vector<Eigen::Isometry3d>& frame_from_world,
                                        const std::vector<Photometric>& photometric,
                                        int64_t begin,
                                        int64_t end,
                                        bool with_jacobian,
                                        int num_threads,
                                        ReducedSystem* out,
                                        bool batched_hessian) {
  CHECK_EQ(photometric.size(), frames.size());
  DsrPhotometricVoxelTerm term;
  term.batched_hessian = batched_hessian;
  term.batched_gradient = batched_hessian;
  for (size_t i = 0; i < photometric.size(); ++i) {
    term.gain[i] = photometric[i].gain();
    term.offset[i] = photometric[i].offset;
  }
  StreamNormalEquations(frames, candidates, frame_from_world, begin, end, with_jacobian,
                        num_threads, term, out);
}

ReducedChunkCost::ReducedChunkCost(const std::vector<Frame>* frames,
                                   const CandidateSet* candidates,
                                   const Eigen::Isometry3d& frame0_from_world,
                                   int64_t begin,
                                   int64_t end,
                                   int num_threads,
                                   bool photometric)
    : StreamedPoseCost(static_cast<int>(frames->size()), frame0_from_world, photometric),
      frames_(frames),
      candidates_(candidates),
      begin_(begin),
      end_(end),
      num_threads_(num_threads) {}

void ReducedChunkCost::Accumulate(const std::vector<Eigen::Isometry3d>& frame_from_world,
                                  const std::vector<Photometric>& photometric,
                                  bool with_jacobian,
                                  NormalEquations* out) const {
  if (!photometric.empty()) {
    AccumulateReducedPhotometricSystem(*frames_, *candidates_, frame_from_world, photometric,
                                       begin_, end_, with_jacobian, num_threads_, out);
    return;
  }
  AccumulateReducedSystem(*frames_, *candidates_, frame_from_world, begin_, end_, with_jacobian,
                          num_threads_, out);
}

}  // namespace dsr
