// SE(3) for the pose blocks (docs/design.md section 1).
//
// A pose `frame_from_world` (T_i in docs/design.md) maps a world point to frame i's physical
// coordinates (mm): sample_in_frame = frame_from_world * voxel_center_in_world (p_ij = T_i p_j).
//
// Tangent vector delta = [rho; phi] (translation first, as in the paper's code). Exp is
// the group exponential: Exp(delta) = (R = exp([phi]x), t = V(phi) rho). Perturbation is
// on the left: T <- Exp(delta) * T. Then d (T p) / d delta at delta = 0 is [I_3, -[T p]x].
//
// Ceres parameter block layout (PoseManifold): 7 doubles [qx, qy, qz, qw, tx, ty, tz],
// the unit quaternion of R in Eigen's coeffs() order followed by t.
//
// Placing a 1x6 tangent Jacobian J (w.r.t. delta) into Ceres's 1x7 ambient block: Ceres
// multiplies the ambient Jacobian G by PlusJacobian P (7x6). We pass G = J * M, with M the
// 6x7 MinusJacobian at the same point, which satisfies M P = I_6, so G P = J exactly.
// `TangentToAmbientJacobian` returns that M.
#ifndef DSR_GEOMETRY_SE3_H_
#define DSR_GEOMETRY_SE3_H_

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <ceres/manifold.h>

namespace dsr {

using Vector6d = Eigen::Matrix<double, 6, 1>;
using Matrix6d = Eigen::Matrix<double, 6, 6>;
using RowVector6d = Eigen::Matrix<double, 1, 6>;

constexpr int kPoseAmbientSize = 7;
constexpr int kPoseTangentSize = 6;

// [v]x, the cross-product matrix: Hat(v) * w = v x w.
Eigen::Matrix3d Hat(const Eigen::Vector3d& v);

// Rotation exponential / logarithm (angle-axis), with small-angle series.
Eigen::Matrix3d ExpSO3(const Eigen::Vector3d& phi);
Eigen::Vector3d LogSO3(const Eigen::Matrix3d& rotation);
// Left Jacobian of SO(3), V(phi) = sum_k [phi]x^k / (k+1)!, and its inverse.
Eigen::Matrix3d LeftJacobianSO3(const Eigen::Vector3d& phi);
Eigen::Matrix3d InverseLeftJacobianSO3(const Eigen::Vector3d& phi);

// Group exponential and logarithm, delta = [rho; phi].
Eigen::Isometry3d ExpSE3(const Vector6d& delta);
Vector6d LogSE3(const Eigen::Isometry3d& transform);

// Projects a 3x3 matrix to the nearest rotation (SVD) and rebuilds a proper isometry.
Eigen::Isometry3d Orthonormalized(const Eigen::Isometry3d& transform);

// d (Exp(delta) p) / d delta at delta = 0: [I_3, -[p]x]  (3x6).
Eigen::Matrix<double, 3, 6> PointJacobian(const Eigen::Vector3d& point);

// Parameter block <-> isometry.
void PoseToParameters(const Eigen::Isometry3d& frame_from_world, double* x);
Eigen::Isometry3d ParametersToPose(const double* x);

// M = MinusJacobian(x) (6x7, row-major), see the header comment.
Eigen::Matrix<double, 6, 7, Eigen::RowMajor> TangentToAmbientJacobian(const double* x);

// ceres::Manifold with the left perturbation Plus(x, delta) = Exp(delta) * T(x) and
// Minus(y, x) = Log(T(y) * T(x)^-1). Ambient 7, tangent 6 ([rho; phi]).
class PoseManifold final : public ceres::Manifold {
 public:
  int AmbientSize() const override { return kPoseAmbientSize; }
  int TangentSize() const override { return kPoseTangentSize; }
  bool Plus(const double* x, const double* delta, double* x_plus_delta) const override;
  bool PlusJacobian(const double* x, double* jacobian) const override;
  bool RightMultiplyByPlusJacobian(const double* x,
                                   int num_rows,
                                   const double* ambient_matrix,
                                   double* tangent_matrix) const override;
  bool Minus(const double* y, const double* x, double* y_minus_x) const override;
  bool MinusJacobian(const double* x, double* jacobian) const override;
};

}  // namespace dsr

#endif  // DSR_GEOMETRY_SE3_H_
