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

ReducedChunkCost::ReducedChunkCost(const std::vector<Frame>* frames,
                                   const CandidateSet* candidates,
                                   const Eigen::Isometry3d& frame0_from_world,
                                   int64_t begin,
                                   int64_t end,
                                   int num_threads)
    : StreamedPoseCost(static_cast<int>(frames->size()), frame0_from_world),
      frames_(frames),
      candidates_(candidates),
      begin_(begin),
      end_(end),
      num_threads_(num_threads) {}

void ReducedChunkCost::Accumulate(const std::vector<Eigen::Isometry3d>& frame_from_world,
                                  bool with_jacobian,
                                  NormalEquations* out) const {
  AccumulateReducedSystem(*frames_, *candidates_, frame_from_world, begin_, end_, with_jacobian,
                          num_threads_, out);
}

}  // namespace dsr
