// Reduced DSR cost: per-voxel reference and streaming chunk cost (docs/design.md section 4).
#include "dsr/dsr_reduced/reduced_cost.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <utility>

#include <glog/logging.h>

namespace dsr {
namespace {

// Both reference costs: the residuals of one voxel's observers and their Jacobians.
// Without photometric parameters (`photometric` null) r_i = I_i - mean I, and with
// `weight` (n entries, > 0) sqrt(w_i) (I_i - sum w I / W), with Jacobians
// (delta_ia - 1/k) J_a, or sqrt(w_i) (delta_ia - w_a / W) J_a: the same numbers as before
// photometric parameters existed. With them ([log_gain, offset] per observer), in each
// frame's grey levels (docs/design.md 2.8): c_i = g_i I_i + b_i, u_i = 1 / g_i,
// V = sum w u^2 (w = 1 without weights), mu = sum w u^2 c / V,
//   r_i = sqrt(w_i) u_i (c_i - mu),
//   d r_i / d x_a = sqrt(w_i) (delta_ia - u_i u_a w_a / V) R_a,  R_a = [J_a, u_a (mu - b_a), u_a],
// the Jacobian with the intensity eliminated at M = mu: DBA's Schur complement (section 4.3).
// Where u or w vary it is not the full derivative of r (which also moves mu's weights);
// it differs from it by the projection onto the voxel's intensity direction, and
// J^T r is the exact gradient (tests check both against numeric differentiation).
// `pose_jacobians` / `photometric_jacobians` (either may be null, as may their entries) are
// n x 7 and n x 2 row-major per observer.
void EvaluateVoxel(const std::vector<const Frame*>& observers,
                   const Eigen::Vector3d& voxel_center_in_world,
                   double const* const* poses,
                   double const* const* photometric,
                   const double* weight,
                   double* residuals,
                   double** pose_jacobians,
                   double** photometric_jacobians) {
  const int n = static_cast<int>(observers.size());
  std::vector<double> value(n, 0.0), corrected(n, 0.0), unit(n, 1.0), offset(n, 0.0);
  std::vector<RowVector6d> jac(n, RowVector6d::Zero());
  std::vector<int> sigma(n, 0);
  int k = 0;
  double sum = 0.0;
  double weighted_sum = 0.0, total_weight = 0.0;  // with weights or photometric parameters
  for (int i = 0; i < n; ++i) {
    const Photometric correction =
        photometric != nullptr ? Photometric{photometric[i][0], photometric[i][1]} : Photometric();
    if (photometric != nullptr) {
      unit[i] = correction.unit();
      offset[i] = correction.offset;
    }
    if (ObserveSample(*observers[i], ParametersToPose(poses[i]), voxel_center_in_world,
                      &value[i], &jac[i])) {
      sigma[i] = 1;
      ++k;
      corrected[i] = photometric != nullptr ? correction.Correct(value[i]) : value[i];
      sum += corrected[i];
      const double w = (weight != nullptr ? weight[i] : 1.0) * unit[i] * unit[i];
      weighted_sum += w * corrected[i];
      total_weight += w;
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
  const bool plain = weight == nullptr && photometric == nullptr;
  const double mean = plain ? sum / k : weighted_sum / total_weight;
  const auto root_weight = [&](int i) { return weight != nullptr ? std::sqrt(weight[i]) : 1.0; };
  for (int i = 0; i < n; ++i) {
    if (!sigma[i]) {
      residuals[i] = 0.0;
    } else if (photometric != nullptr) {
      residuals[i] = root_weight(i) * (value[i] - unit[i] * (mean - offset[i]));
    } else {
      residuals[i] = root_weight(i) * (corrected[i] - mean);
    }
  }
  // d r_i / d x_a = sigma_i sigma_a factor(i, a) R_a.
  const auto factor = [&](int i, int a) {
    if (plain) return (i == a ? 1.0 : 0.0) - 1.0 / k;
    const double w_a = weight != nullptr ? weight[a] : 1.0;
    if (photometric == nullptr) return root_weight(i) * ((i == a ? 1.0 : 0.0) - w_a / total_weight);
    return root_weight(i) * ((i == a ? 1.0 : 0.0) - unit[i] * unit[a] * w_a / total_weight);
  };
  for (int a = 0; a < n; ++a) {
    if (!sigma[a]) continue;
    // d r_i / d delta_a = sigma_i sigma_a factor(i, a) J_a, then to the ambient block.
    if (pose_jacobians != nullptr && pose_jacobians[a] != nullptr) {
      const Eigen::Matrix<double, 1, kPoseAmbientSize> ambient =
          jac[a] * TangentToAmbientJacobian(poses[a]);
      Eigen::Map<Eigen::Matrix<double, Eigen::Dynamic, kPoseAmbientSize, Eigen::RowMajor>> out(
          pose_jacobians[a], n, kPoseAmbientSize);
      for (int i = 0; i < n; ++i) {
        if (sigma[i]) out.row(i) = factor(i, a) * ambient;
      }
    }
    // d r_i / d [log_gain_a, b_a] = sigma_i sigma_a factor(i, a) [u_a (mu - b_a), u_a].
    if (photometric_jacobians != nullptr && photometric_jacobians[a] != nullptr) {
      const double in_frame = unit[a] * (mean - offset[a]);
      for (int i = 0; i < n; ++i) {
        if (!sigma[i]) continue;
        const double f = factor(i, a);
        photometric_jacobians[a][2 * i] = f * in_frame;
        photometric_jacobians[a][2 * i + 1] = f * unit[a];
      }
    }
  }
}

}  // namespace

VoxelReducedCost::VoxelReducedCost(std::vector<const Frame*> observers,
                                   const Eigen::Vector3d& voxel_center_in_world,
                                   std::vector<double> weights)
    : observers_(std::move(observers)),
      voxel_center_in_world_(voxel_center_in_world),
      weights_(std::move(weights)) {
  CHECK(weights_.empty() || weights_.size() == observers_.size());
  set_num_residuals(static_cast<int>(observers_.size()));
  for (size_t i = 0; i < observers_.size(); ++i) {
    mutable_parameter_block_sizes()->push_back(kPoseAmbientSize);
  }
}

bool VoxelReducedCost::Evaluate(double const* const* parameters,
                                double* residuals,
                                double** jacobians) const {
  EvaluateVoxel(observers_, voxel_center_in_world_, parameters, nullptr,
                weights_.empty() ? nullptr : weights_.data(), residuals, jacobians, nullptr);
  return true;
}

VoxelReducedPhotometricCost::VoxelReducedPhotometricCost(
    std::vector<const Frame*> observers,
    const Eigen::Vector3d& voxel_center_in_world,
    std::vector<double> weights)
    : observers_(std::move(observers)),
      voxel_center_in_world_(voxel_center_in_world),
      weights_(std::move(weights)) {
  CHECK(weights_.empty() || weights_.size() == observers_.size());
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
  EvaluateVoxel(observers_, voxel_center_in_world_, parameters, parameters + n,
                weights_.empty() ? nullptr : weights_.data(), residuals, jacobians,
                jacobians != nullptr ? jacobians + n : nullptr);
  return true;
}

ReducedChunkCost::ReducedChunkCost(const std::vector<Frame>* frames,
                                   const CandidateSet* candidates,
                                   const Eigen::Isometry3d& frame0_from_world,
                                   int64_t begin,
                                   int64_t end,
                                   const StreamContext& context,
                                   bool photometric,
                                   const ObservationWeights* weights,
                                   Gauge gauge,
                                   std::shared_ptr<const ReducedCostBackend> backend)
    : StreamedPoseCost(static_cast<int>(frames->size()), frame0_from_world, photometric, gauge),
      begin_(begin),
      end_(end),
      backend_(backend != nullptr ? std::move(backend) : DefaultReducedCostBackend()) {
  inputs_.frames = frames;
  inputs_.candidates = candidates;
  inputs_.weights = weights;
  inputs_.context = context;
}

void ReducedChunkCost::Accumulate(const std::vector<Eigen::Isometry3d>& frame_from_world,
                                  const std::vector<Photometric>& photometric,
                                  bool with_jacobian,
                                  NormalEquations* out) const {
  // A NaN cost fails the evaluation (StreamedPoseCost::Evaluate): Ceres then treats the
  // point as it treats any failed evaluation. Nothing else of a failed pass is kept.
  if (!backend_->Evaluate(inputs_, frame_from_world, photometric, begin_, end_, with_jacobian,
                          out)) {
    *out = NormalEquations();
    out->cost = std::numeric_limits<double>::quiet_NaN();
  }
}

}  // namespace dsr
