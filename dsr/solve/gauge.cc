#include "dsr/solve/gauge.h"

#include <cmath>

#include <Eigen/SVD>
#include <glog/logging.h>

namespace dsr {

bool StringToGauge(const std::string& name, Gauge* gauge) {
  for (Gauge g : {Gauge::kFrame0, Gauge::kMean}) {
    if (name == GaugeToString(g)) {
      *gauge = g;
      return true;
    }
  }
  return false;
}

Vector6d PoseDisplacement(const Eigen::Isometry3d& pose, const Eigen::Isometry3d& initial,
                          const Eigen::Vector3d& centre, Matrix6d* tangent_jacobian) {
  const Eigen::Matrix3d rotation_t = pose.linear().transpose();
  Eigen::Quaterniond q(initial.linear().transpose() * pose.linear());
  if (q.w() < 0.0) q.coeffs() = -q.coeffs();
  Vector6d e;
  e.head<3>() = pose.inverse() * centre - initial.inverse() * centre;
  e.tail<3>() = 2.0 * q.vec();
  if (tangent_jacobian != nullptr) {
    // Left perturbation T <- Exp(delta) T: T^-1 c <- T^-1 Exp(-delta) c, so the centre moves
    // by R^T (-rho + [c]x phi); R0^T R <- (R0^T R) Exp(R^T phi), so q <- q (1, R^T phi / 2).
    tangent_jacobian->topLeftCorner<3, 3>() = -rotation_t;
    tangent_jacobian->topRightCorner<3, 3>() = rotation_t * Hat(centre);
    tangent_jacobian->bottomLeftCorner<3, 3>().setZero();
    tangent_jacobian->bottomRightCorner<3, 3>() =
        (q.w() * Eigen::Matrix3d::Identity() + Hat(q.vec())) * rotation_t;
  }
  return e;
}

Eigen::Isometry3d MeanFrame(const std::vector<Eigen::Isometry3d>& frame_from_world,
                            const std::vector<Eigen::Vector3d>& centres) {
  CHECK(!frame_from_world.empty());
  CHECK_EQ(frame_from_world.size(), centres.size());
  Eigen::Matrix3d sum = Eigen::Matrix3d::Zero();
  Eigen::Vector3d origin = Eigen::Vector3d::Zero();
  for (size_t i = 0; i < frame_from_world.size(); ++i) {
    const Eigen::Isometry3d world_from_frame = frame_from_world[i].inverse();
    sum += world_from_frame.linear();
    origin += world_from_frame * centres[i];
  }
  // The nearest rotation to `sum`: U diag(1, 1, det(U V^T)) V^T.
  const Eigen::JacobiSVD<Eigen::Matrix3d> svd(sum, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d u = svd.matrixU();
  if ((u * svd.matrixV().transpose()).determinant() < 0.0) u.col(2) = -u.col(2);
  Eigen::Isometry3d mean = Eigen::Isometry3d::Identity();
  mean.linear() = u * svd.matrixV().transpose();
  mean.translation() = origin / static_cast<double>(frame_from_world.size());
  return mean;
}

MeanPosePrior::MeanPosePrior(std::vector<Eigen::Isometry3d> initial_frame_from_world,
                             std::vector<Eigen::Vector3d> centres,
                             const Vector6d& stiffness)
    : initial_(std::move(initial_frame_from_world)),
      centres_(std::move(centres)),
      sqrt_stiffness_(stiffness.cwiseSqrt()) {
  CHECK_GE(initial_.size(), 2u);
  CHECK_EQ(initial_.size(), centres_.size());
  set_num_residuals(6);
  for (size_t i = 0; i < initial_.size(); ++i) {
    mutable_parameter_block_sizes()->push_back(kPoseAmbientSize);
  }
}

bool MeanPosePrior::Evaluate(double const* const* parameters,
                             double* residuals,
                             double** jacobians) const {
  const int m = static_cast<int>(initial_.size());
  const Vector6d scale = sqrt_stiffness_ / m;
  Vector6d sum = Vector6d::Zero();
  for (int i = 0; i < m; ++i) {
    Matrix6d d_e;
    sum += PoseDisplacement(ParametersToPose(parameters[i]), initial_[i], centres_[i],
                            jacobians != nullptr && jacobians[i] != nullptr ? &d_e : nullptr);
    if (jacobians != nullptr && jacobians[i] != nullptr) {
      Eigen::Map<Eigen::Matrix<double, 6, kPoseAmbientSize, Eigen::RowMajor>> jacobian(
          jacobians[i]);
      jacobian = scale.asDiagonal() * d_e * TangentToAmbientJacobian(parameters[i]);
    }
  }
  Eigen::Map<Vector6d> residual(residuals);
  residual = scale.cwiseProduct(sum);
  return true;
}

Vector6d MeanGaugeStiffness(const Eigen::MatrixXd& hessian, int num_frames, int p) {
  CHECK_EQ(hessian.rows(), static_cast<Eigen::Index>(num_frames) * p);
  Eigen::Vector2d mean = Eigen::Vector2d::Zero();  // translation, rotation
  for (int i = 0; i < num_frames; ++i) {
    for (int k = 0; k < 6; ++k) mean[k / 3] += hessian(p * i + k, p * i + k);
  }
  mean /= 3.0 * num_frames;
  Vector6d stiffness;
  for (int k = 0; k < 6; ++k) {
    const double d = mean[k / 3];
    stiffness[k] = d > 0.0 && std::isfinite(d) ? num_frames * d : 1.0;
  }
  return stiffness;
}

}  // namespace dsr
