// SE(3) exponential/logarithm and the left-perturbation PoseManifold (docs/design.md section 1).
#include "dsr/geometry/se3.h"

#include <random>

#include <ceres/manifold_test_utils.h>
#include <gtest/gtest.h>

namespace dsr {
namespace {

// Ceres's manifold checks use Ridders numeric differentiation; 1e-9 is what its own
// quaternion manifold tests use for unit-scale parameters.
constexpr double kManifoldTolerance = 1e-9;
// Exp/Log round trips are analytic up to rounding of a few trigonometric terms.
constexpr double kRoundTripTolerance = 1e-12;

Vector6d RandomTangent(std::mt19937_64& rng, double max_rho, double max_phi) {
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  Vector6d d;
  for (int a = 0; a < 3; ++a) d[a] = max_rho * u(rng);
  Eigen::Vector3d axis(u(rng), u(rng), u(rng));
  axis.normalize();
  d.tail<3>() = axis * (max_phi * std::abs(u(rng)));
  return d;
}

Eigen::Matrix<double, 7, 1> ParametersOf(const Eigen::Isometry3d& t) {
  Eigen::Matrix<double, 7, 1> x;
  PoseToParameters(t, x.data());
  return x;
}

TEST(Se3, ExpLogRoundTrip) {
  std::mt19937_64 rng(1);
  for (int n = 0; n < 1000; ++n) {
    const Vector6d d = RandomTangent(rng, 100.0, 3.0);
    EXPECT_LT((LogSE3(ExpSE3(d)) - d).norm(), kRoundTripTolerance * 100.0) << d.transpose();
  }
}

TEST(Se3, SmallAngleLimits) {
  for (double angle : {0.0, 1e-12, 1e-8, 1e-5, 9.9e-5, 1e-4, 1.01e-4, 1e-3}) {
    Vector6d d;
    d << 1.0, -2.0, 3.0, angle, -0.5 * angle, 0.25 * angle;
    const Eigen::Isometry3d t = ExpSE3(d);
    // Rotation matches Eigen's AngleAxis; translation V rho is continuous across the branch.
    const Eigen::Vector3d phi = d.tail<3>();
    const Eigen::Matrix3d reference =
        phi.norm() > 0 ? Eigen::AngleAxisd(phi.norm(), phi.normalized()).toRotationMatrix()
                       : Eigen::Matrix3d::Identity();
    EXPECT_LT((t.linear() - reference).norm(), 1e-15 + 1e-12 * angle);
    EXPECT_LT((LogSE3(t) - d).norm(), 1e-12);
    EXPECT_LT((t.linear().transpose() * t.linear() - Eigen::Matrix3d::Identity()).norm(), 1e-14);
  }
}

TEST(Se3, RotationNearPi) {
  const Eigen::Vector3d axis = Eigen::Vector3d(1.0, 2.0, -0.5).normalized();
  for (double angle : {M_PI - 1e-3, M_PI - 1e-7, M_PI}) {
    Vector6d d;
    d << 3.0, 1.0, -2.0, angle * axis;
    const Vector6d back = LogSE3(ExpSE3(d));
    // At exactly pi the axis sign is ambiguous; compare the group elements instead.
    EXPECT_LT((ExpSE3(back).matrix() - ExpSE3(d).matrix()).norm(), 1e-9) << angle;
  }
}

TEST(Se3, PointJacobianMatchesNumericDerivative) {
  std::mt19937_64 rng(2);
  for (int n = 0; n < 100; ++n) {
    const Eigen::Isometry3d t = ExpSE3(RandomTangent(rng, 50.0, 1.0));
    const Eigen::Vector3d p(10.0, -20.0, 35.0);
    const Eigen::Vector3d tp = t * p;
    Eigen::Matrix<double, 3, 6> numeric;
    const double h = 1e-6;
    for (int a = 0; a < 6; ++a) {
      Vector6d d = Vector6d::Zero();
      d[a] = h;
      numeric.col(a) = ((ExpSE3(d) * t) * p - (ExpSE3(-d) * t) * p) / (2 * h);
    }
    EXPECT_LT((numeric - PointJacobian(tp)).norm(), 1e-6);
  }
}

TEST(PoseManifold, InvariantsHoldOnRandomPoints) {
  using namespace ceres;  // NOLINT: the macro names Ceres's matchers unqualified.
  PoseManifold manifold;
  std::mt19937_64 rng(3);
  for (int n = 0; n < 1000; ++n) {
    const Eigen::Isometry3d t = ExpSE3(RandomTangent(rng, 20.0, 3.0));
    const Eigen::Matrix<double, 7, 1> x = ParametersOf(t);
    const Vector6d delta = RandomTangent(rng, 5.0, 1.0);
    Eigen::Matrix<double, 7, 1> y;
    manifold.Plus(x.data(), RandomTangent(rng, 5.0, 2.0).data(), y.data());
    const ceres::Vector cx = x, cdelta = delta, cy = y;
    EXPECT_THAT_MANIFOLD_INVARIANTS_HOLD(manifold, cx, cdelta, cy, kManifoldTolerance);
  }
}

TEST(PoseManifold, InvariantsHoldOnChosenCases) {
  using namespace ceres;  // NOLINT: the macro names Ceres's matchers unqualified.
  PoseManifold manifold;
  const Eigen::Vector3d axis = Eigen::Vector3d(0.3, -1.0, 0.2).normalized();
  std::vector<Eigen::Isometry3d> points;
  points.push_back(Eigen::Isometry3d::Identity());
  for (double angle : {M_PI - 1e-4, 1e-5, 3e-6}) {
    Vector6d d;
    d << 1.0, 2.0, 3.0, angle * axis;
    points.push_back(ExpSE3(d));
  }
  Vector6d far;
  far << 1e4, -2e4, 5e3, 0.1, 0.2, 0.3;  // large translation
  points.push_back(ExpSE3(far));
  std::vector<Vector6d> deltas;
  Vector6d tiny;
  tiny << 1e-3, 0.0, -1e-3, 1e-5, -1e-5, 2e-6;  // |phi| around 1e-5
  deltas.push_back(tiny);
  Vector6d medium;
  medium << 0.5, -1.0, 2.0, 0.3, -0.2, 0.1;
  deltas.push_back(medium);
  for (const auto& t : points) {
    const Eigen::Matrix<double, 7, 1> x = ParametersOf(t);
    for (const auto& delta : deltas) {
      Eigen::Matrix<double, 7, 1> y;
      manifold.Plus(x.data(), medium.data(), y.data());
      // Large translations scale numeric-differentiation error; relative tolerance.
      const double tolerance = kManifoldTolerance * std::max(1.0, t.translation().norm());
      const ceres::Vector cx = x, cdelta = delta, cy = y;
      EXPECT_THAT_MANIFOLD_INVARIANTS_HOLD(manifold, cx, cdelta, cy, tolerance);
    }
  }
}

TEST(PoseManifold, PlusIsLeftPerturbation) {
  PoseManifold manifold;
  std::mt19937_64 rng(4);
  const Eigen::Isometry3d t = ExpSE3(RandomTangent(rng, 10.0, 1.0));
  const Vector6d delta = RandomTangent(rng, 2.0, 0.5);
  const Eigen::Matrix<double, 7, 1> x = ParametersOf(t);
  Eigen::Matrix<double, 7, 1> y;
  manifold.Plus(x.data(), delta.data(), y.data());
  EXPECT_LT((ParametersToPose(y.data()).matrix() - (ExpSE3(delta) * t).matrix()).norm(), 1e-12);
}

TEST(PoseManifold, TangentToAmbientJacobianInvertsPlusJacobian) {
  PoseManifold manifold;
  std::mt19937_64 rng(5);
  for (int n = 0; n < 100; ++n) {
    const Eigen::Matrix<double, 7, 1> x = ParametersOf(ExpSE3(RandomTangent(rng, 30.0, 3.0)));
    Eigen::Matrix<double, 7, 6, Eigen::RowMajor> plus;
    manifold.PlusJacobian(x.data(), plus.data());
    const Matrix6d product = TangentToAmbientJacobian(x.data()) * plus;
    EXPECT_LT((product - Matrix6d::Identity()).norm(), 1e-12);
  }
}

}  // namespace
}  // namespace dsr
