#include "core/streamed_cost.h"

#include <algorithm>
#include <cmath>

#include <Eigen/Eigenvalues>
#include <glog/logging.h>

#include "core/se3.h"

namespace dsr {
namespace {

// Eigenvalues of H below this fraction of the largest are treated as zero (rounding).
constexpr double kRelativeEigenvalueFloor = 1e-14;

}  // namespace

void CompressNormalEquations(const Eigen::MatrixXd& hessian,
                             const Eigen::VectorXd& gradient,
                             double cost,
                             Eigen::VectorXd* residual,
                             Eigen::MatrixXd* jacobian) {
  const int n = static_cast<int>(hessian.rows());
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eigen(hessian);
  const Eigen::VectorXd& lambda = eigen.eigenvalues();
  const Eigen::MatrixXd& v = eigen.eigenvectors();
  const double floor = kRelativeEigenvalueFloor * std::max(0.0, lambda.maxCoeff());
  residual->setZero(n + 1);
  jacobian->setZero(n + 1, n);
  double explained = 0.0;
  for (int e = 0; e < n; ++e) {
    if (!(lambda[e] > floor) || lambda[e] <= 0.0) continue;
    const double s = std::sqrt(lambda[e]);
    jacobian->row(e) = s * v.col(e).transpose();
    (*residual)[e] = v.col(e).dot(gradient) / s;
    explained += (*residual)[e] * (*residual)[e];
  }
  // |r|^2 = f: the part of the cost the linear model cannot change.
  (*residual)[n] = std::sqrt(std::max(0.0, cost - explained));
}

StreamedPoseCost::StreamedPoseCost(int num_frames, const Eigen::Isometry3d& frame0_from_world)
    : num_frames_(num_frames), frame0_from_world_(frame0_from_world) {
  const int free = num_frames - 1;
  CHECK_GE(free, 1);
  set_num_residuals(6 * free + 1);
  for (int i = 0; i < free; ++i) mutable_parameter_block_sizes()->push_back(kPoseAmbientSize);
}

bool StreamedPoseCost::Evaluate(double const* const* parameters,
                                double* residuals,
                                double** jacobians) const {
  const int m = num_frames_;
  const int free = m - 1;
  std::vector<Eigen::Isometry3d> poses(m);
  poses[0] = frame0_from_world_;
  for (int i = 1; i < m; ++i) poses[i] = ParametersToPose(parameters[i - 1]);
  const bool with_jacobian = jacobians != nullptr;
  NormalEquations system;
  Accumulate(poses, with_jacobian, &system);
  last_observations_ = system.observations;
  if (!std::isfinite(system.cost)) return false;
  const int n = 6 * free;
  if (!with_jacobian) {
    std::fill(residuals, residuals + n, 0.0);
    residuals[n] = std::sqrt(system.cost);
    return true;
  }
  Eigen::VectorXd r;
  Eigen::MatrixXd jac;
  CompressNormalEquations(system.hessian.bottomRightCorner(n, n), system.gradient.tail(n),
                          system.cost, &r, &jac);
  if (!r.allFinite() || !jac.allFinite()) return false;
  Eigen::Map<Eigen::VectorXd>(residuals, n + 1) = r;
  for (int i = 1; i < m; ++i) {
    if (jacobians[i - 1] == nullptr) continue;
    Eigen::Map<Eigen::Matrix<double, Eigen::Dynamic, kPoseAmbientSize, Eigen::RowMajor>> out(
        jacobians[i - 1], n + 1, kPoseAmbientSize);
    out.noalias() = jac.middleCols<6>(6 * (i - 1)) * TangentToAmbientJacobian(parameters[i - 1]);
  }
  return true;
}

}  // namespace dsr
