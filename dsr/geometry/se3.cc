// SE(3) exponential/logarithm and the left-perturbation pose manifold (docs/design.md section 1).
//
// With theta = |phi|, K = [phi]x:  A = sin(theta)/theta, B = (1 - cos(theta))/theta^2,
// C = (theta - sin(theta))/theta^3;  R = I + A K + B K^2,  V = I + B K + C K^2,
// V^-1 = I - K/2 + (1 - A/(2B))/theta^2 K^2. Below kSmallAngle the coefficients are their
// Taylor series (two terms), accurate to double precision there.
#include "dsr/geometry/se3.h"

#include <cmath>

#include <Eigen/SVD>

namespace dsr {
namespace {

constexpr double kSmallAngle = 1e-4;  // |phi| below which Taylor series are used.

struct SO3Coefficients {
  double a, b, c;
};

SO3Coefficients Coefficients(double theta) {
  const double t2 = theta * theta;
  if (theta < kSmallAngle) {
    return {1.0 - t2 / 6.0, 0.5 - t2 / 24.0, 1.0 / 6.0 - t2 / 120.0};
  }
  const double s = std::sin(theta), h = std::sin(0.5 * theta);
  // 1 - cos(theta) = 2 sin^2(theta/2) avoids cancellation for small theta.
  return {s / theta, 2.0 * h * h / t2, (theta - s) / (t2 * theta)};
}

// Rotation vector of a unit quaternion, without sign canonicalisation (so that
// Plus(Minus(y, x), x) returns y itself, not -y).
Eigen::Vector3d QuaternionToRotationVector(const Eigen::Quaterniond& q) {
  const Eigen::Vector3d v = q.vec();
  const double v_norm = v.norm();
  if (v_norm < 1e-12) {
    // 2 atan2(|v|, w) v / |v| -> 2 v / w for small |v| (first order in v).
    return 2.0 * v / q.w();
  }
  return 2.0 * std::atan2(v_norm, q.w()) * v / v_norm;
}

Eigen::Quaterniond RotationVectorToQuaternion(const Eigen::Vector3d& phi) {
  const double theta = phi.norm();
  const double half = 0.5 * theta;
  // sin(theta/2)/theta, with its series below kSmallAngle.
  const double k = theta < kSmallAngle ? 0.5 - theta * theta / 48.0 : std::sin(half) / theta;
  return Eigen::Quaterniond(std::cos(half), k * phi[0], k * phi[1], k * phi[2]);
}

// d q' / d phi for q' = Exp(phi) * q at phi = 0, in [qx, qy, qz, qw] rows: 0.5 [wI - [v]x; -v^T].
Eigen::Matrix<double, 4, 3> QuaternionTangentBasis(const Eigen::Quaterniond& q) {
  Eigen::Matrix<double, 4, 3> basis;
  basis.topRows<3>() = 0.5 * (q.w() * Eigen::Matrix3d::Identity() - Hat(q.vec()));
  basis.row(3) = -0.5 * q.vec().transpose();
  return basis;
}

Eigen::Quaterniond ParameterQuaternion(const double* x) {
  return Eigen::Quaterniond(x[3], x[0], x[1], x[2]).normalized();
}

}  // namespace

Eigen::Matrix3d Hat(const Eigen::Vector3d& v) {
  Eigen::Matrix3d m;
  m << 0.0, -v[2], v[1], v[2], 0.0, -v[0], -v[1], v[0], 0.0;
  return m;
}

Eigen::Matrix3d ExpSO3(const Eigen::Vector3d& phi) {
  const SO3Coefficients k = Coefficients(phi.norm());
  const Eigen::Matrix3d hat = Hat(phi);
  return Eigen::Matrix3d::Identity() + k.a * hat + k.b * hat * hat;
}

Eigen::Vector3d LogSO3(const Eigen::Matrix3d& rotation) {
  Eigen::Quaterniond q(rotation);
  q.normalize();
  if (q.w() < 0.0) q.coeffs() = -q.coeffs();  // angle in [0, pi]
  return QuaternionToRotationVector(q);
}

Eigen::Matrix3d LeftJacobianSO3(const Eigen::Vector3d& phi) {
  const SO3Coefficients k = Coefficients(phi.norm());
  const Eigen::Matrix3d hat = Hat(phi);
  return Eigen::Matrix3d::Identity() + k.b * hat + k.c * hat * hat;
}

Eigen::Matrix3d InverseLeftJacobianSO3(const Eigen::Vector3d& phi) {
  const double theta = phi.norm();
  const Eigen::Matrix3d hat = Hat(phi);
  double d;  // (1 - A / (2B)) / theta^2
  if (theta < kSmallAngle) {
    d = 1.0 / 12.0 + theta * theta / 720.0;
  } else {
    const SO3Coefficients k = Coefficients(theta);
    d = (1.0 - k.a / (2.0 * k.b)) / (theta * theta);
  }
  return Eigen::Matrix3d::Identity() - 0.5 * hat + d * hat * hat;
}

Eigen::Isometry3d ExpSE3(const Vector6d& delta) {
  const Eigen::Vector3d rho = delta.head<3>(), phi = delta.tail<3>();
  Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
  t.linear() = ExpSO3(phi);
  t.translation() = LeftJacobianSO3(phi) * rho;
  return t;
}

Vector6d LogSE3(const Eigen::Isometry3d& transform) {
  Vector6d delta;
  const Eigen::Vector3d phi = LogSO3(transform.linear());
  delta.tail<3>() = phi;
  delta.head<3>() = InverseLeftJacobianSO3(phi) * transform.translation();
  return delta;
}

Eigen::Isometry3d Orthonormalized(const Eigen::Isometry3d& transform) {
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(transform.linear(),
                                        Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d r = svd.matrixU() * svd.matrixV().transpose();
  if (r.determinant() < 0.0) {
    Eigen::Matrix3d u = svd.matrixU();
    u.col(2) = -u.col(2);
    r = u * svd.matrixV().transpose();
  }
  Eigen::Isometry3d out = Eigen::Isometry3d::Identity();
  out.linear() = r;
  out.translation() = transform.translation();
  return out;
}

Eigen::Matrix<double, 3, 6> PointJacobian(const Eigen::Vector3d& point) {
  Eigen::Matrix<double, 3, 6> j;
  j.leftCols<3>().setIdentity();
  j.rightCols<3>() = -Hat(point);
  return j;
}

void PoseToParameters(const Eigen::Isometry3d& frame_from_world, double* x) {
  const Eigen::Quaterniond q(frame_from_world.linear());
  x[0] = q.x();
  x[1] = q.y();
  x[2] = q.z();
  x[3] = q.w();
  x[4] = frame_from_world.translation()[0];
  x[5] = frame_from_world.translation()[1];
  x[6] = frame_from_world.translation()[2];
}

Eigen::Isometry3d ParametersToPose(const double* x) {
  Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
  t.linear() = ParameterQuaternion(x).toRotationMatrix();
  t.translation() = Eigen::Vector3d(x[4], x[5], x[6]);
  return t;
}

Eigen::Matrix<double, 6, 7, Eigen::RowMajor> TangentToAmbientJacobian(const double* x) {
  // Minus(y, x) = Log(T(y) T(x)^-1) differentiated w.r.t. y at y = x:
  //   rows rho: [ [t]x * 4 Q^T , I ],  rows phi: [ 4 Q^T , 0 ]
  // with Q the 4x3 quaternion tangent basis (Q^T Q = I/4 for a unit quaternion).
  const Eigen::Quaterniond q(x[3], x[0], x[1], x[2]);
  const Eigen::Matrix<double, 3, 4> q_inverse = 4.0 * QuaternionTangentBasis(q).transpose();
  const Eigen::Vector3d t(x[4], x[5], x[6]);
  Eigen::Matrix<double, 6, 7, Eigen::RowMajor> m;
  m.setZero();
  m.block<3, 4>(0, 0) = Hat(t) * q_inverse;
  m.block<3, 3>(0, 4).setIdentity();
  m.block<3, 4>(3, 0) = q_inverse;
  return m;
}

bool PoseManifold::Plus(const double* x, const double* delta, double* x_plus_delta) const {
  const Eigen::Map<const Vector6d> d(delta);
  const Eigen::Vector3d phi = d.tail<3>();
  const Eigen::Quaterniond q = ParameterQuaternion(x);
  const Eigen::Quaterniond q_delta = RotationVectorToQuaternion(phi);
  const Eigen::Quaterniond q_new = (q_delta * q).normalized();
  const Eigen::Vector3d t(x[4], x[5], x[6]);
  const Eigen::Vector3d t_new = ExpSO3(phi) * t + LeftJacobianSO3(phi) * d.head<3>();
  x_plus_delta[0] = q_new.x();
  x_plus_delta[1] = q_new.y();
  x_plus_delta[2] = q_new.z();
  x_plus_delta[3] = q_new.w();
  x_plus_delta[4] = t_new[0];
  x_plus_delta[5] = t_new[1];
  x_plus_delta[6] = t_new[2];
  return true;
}

bool PoseManifold::PlusJacobian(const double* x, double* jacobian) const {
  // Rows [qx qy qz qw tx ty tz], columns [rho; phi]:
  //   q rows: [0, Q],   t rows: [I, -[t]x].
  Eigen::Map<Eigen::Matrix<double, 7, 6, Eigen::RowMajor>> j(jacobian);
  const Eigen::Quaterniond q(x[3], x[0], x[1], x[2]);
  const Eigen::Vector3d t(x[4], x[5], x[6]);
  j.setZero();
  j.block<4, 3>(0, 3) = QuaternionTangentBasis(q);
  j.block<3, 3>(4, 0).setIdentity();
  j.block<3, 3>(4, 3) = -Hat(t);
  return true;
}

bool PoseManifold::RightMultiplyByPlusJacobian(const double* x,
                                               int num_rows,
                                               const double* ambient_matrix,
                                               double* tangent_matrix) const {
  Eigen::Matrix<double, 7, 6, Eigen::RowMajor> plus_jacobian;
  PlusJacobian(x, plus_jacobian.data());
  using AmbientRows = Eigen::Matrix<double, Eigen::Dynamic, 7, Eigen::RowMajor>;
  using TangentRows = Eigen::Matrix<double, Eigen::Dynamic, 6, Eigen::RowMajor>;
  Eigen::Map<const AmbientRows> a(ambient_matrix, num_rows, 7);
  Eigen::Map<TangentRows> out(tangent_matrix, num_rows, 6);
  out.noalias() = a * plus_jacobian;
  return true;
}

bool PoseManifold::Minus(const double* y, const double* x, double* y_minus_x) const {
  const Eigen::Quaterniond qx = ParameterQuaternion(x), qy = ParameterQuaternion(y);
  Eigen::Quaterniond q_rel = qy * qx.conjugate();
  // Shortest rotation: keeps |phi| <= pi where V(phi) is well conditioned.
  if (q_rel.w() < 0.0) q_rel.coeffs() = -q_rel.coeffs();
  const Eigen::Vector3d phi = QuaternionToRotationVector(q_rel);
  const Eigen::Vector3d tx(x[4], x[5], x[6]), ty(y[4], y[5], y[6]);
  const Eigen::Vector3d t_rel = ty - q_rel.toRotationMatrix() * tx;
  Eigen::Map<Vector6d> out(y_minus_x);
  out.head<3>() = InverseLeftJacobianSO3(phi) * t_rel;
  out.tail<3>() = phi;
  return true;
}

bool PoseManifold::MinusJacobian(const double* x, double* jacobian) const {
  Eigen::Map<Eigen::Matrix<double, 6, 7, Eigen::RowMajor>> out(jacobian);
  out = TangentToAmbientJacobian(x);
  return true;
}

}  // namespace dsr
