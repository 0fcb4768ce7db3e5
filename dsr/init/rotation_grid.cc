#include "dsr/init/rotation_grid.h"

#include <algorithm>
#include <cmath>

#include <Eigen/Geometry>
#include <glog/logging.h>

namespace dsr {

double RotationBallFraction(double angle_rad) {
  return (angle_rad - std::sin(angle_rad)) / M_PI;
}

double RotationAngleBetween(const Eigen::Matrix3d& a, const Eigen::Matrix3d& b) {
  const double cosine = 0.5 * ((a.transpose() * b).trace() - 1.0);
  return std::acos(std::clamp(cosine, -1.0, 1.0));
}

std::vector<Eigen::Matrix3d> RotationsInBall(const Eigen::Matrix3d& centre,
                                             double max_angle_rad,
                                             int count) {
  CHECK(max_angle_rad > 0.0 && max_angle_rad <= M_PI) << max_angle_rad;
  CHECK_GE(count, 1);
  const double fraction = RotationBallFraction(max_angle_rad);
  const int64_t n = std::max<int64_t>(count, std::llround(count / fraction));
  constexpr double kPhi = 1.4142135623730951;   // sqrt(2)
  constexpr double kPsi = 1.533751168755204288;  // psi^4 = psi + 4
  // Half-angle test on |w|: angle(q) <= max  <=>  |w| >= cos(max / 2).
  const double min_w = std::cos(0.5 * max_angle_rad);
  std::vector<Eigen::Matrix3d> rotations = {centre};
  for (int64_t i = 0; i < n; ++i) {
    const double s = static_cast<double>(i) + 0.5;
    const double r = std::sqrt(s / n), big_r = std::sqrt(1.0 - s / n);
    const double alpha = 2.0 * M_PI * s / kPhi, beta = 2.0 * M_PI * s / kPsi;
    // (x, y, z, w); which coordinate plays w does not matter for the density.
    const Eigen::Quaterniond q(big_r * std::cos(beta), r * std::sin(alpha), r * std::cos(alpha),
                               big_r * std::sin(beta));
    if (std::abs(q.w()) < min_w) continue;
    rotations.push_back(centre * q.normalized().toRotationMatrix());
  }
  return rotations;
}

}  // namespace dsr
