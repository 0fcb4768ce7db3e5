// Near-uniform samples of the rotations within an angle of a centre rotation, for the
// global search of init/placement_search.h.
//
// Points on the unit quaternion sphere S^3 by the super-Fibonacci spiral (M. Alexa,
// "Super-Fibonacci Spirals: Fast, Low-Discrepancy Sampling of SO(3)", CVPR 2022): for
// s = i + 1/2, i = 0..N-1,
//   r = sqrt(s / N), R = sqrt(1 - s / N), alpha = 2 pi s / sqrt(2), beta = 2 pi s / psi,
//   q = (r sin alpha, r cos alpha, R sin beta, R cos beta),
// with psi the real root of psi^4 = psi + 4 (1.5337511687...). The spiral covers SO(3)
// with near-constant density (q and -q are the same rotation; the spiral covers both
// hemispheres evenly). The rotations within `max_angle` of the identity take the
// fraction (max_angle - sin max_angle) / pi of SO(3) (Haar measure), so N is chosen for
// about `count` of them to fall inside; they are then turned onto the centre.
#ifndef DSR_INIT_ROTATION_GRID_H_
#define DSR_INIT_ROTATION_GRID_H_

#include <vector>

#include <Eigen/Core>

namespace dsr {

// Rotations R = centre * Q with angle(Q) <= max_angle_rad (in (0, pi]), about `count`
// of them (>= 1), the centre itself first. Deterministic. Their covering radius is about
// (6 pi fraction / count)^(1/3) rad for the fraction above, e.g. about 6 degrees for
// 500 rotations within 45 degrees.
std::vector<Eigen::Matrix3d> RotationsInBall(const Eigen::Matrix3d& centre,
                                             double max_angle_rad,
                                             int count);

// Fraction of SO(3) (Haar measure) within `angle_rad` of the identity: (a - sin a) / pi.
double RotationBallFraction(double angle_rad);

// Angle (rad, in [0, pi]) of the rotation a^T b.
double RotationAngleBetween(const Eigen::Matrix3d& a, const Eigen::Matrix3d& b);

}  // namespace dsr

#endif  // DSR_INIT_ROTATION_GRID_H_
