// SE(3) logarithm on a unit quaternion and translation, templated for ceres::Jet
// (autodiff of Lie normalisation's pose graph). Same map as geometry/se3.h's LogSE3 on
// doubles, which tests compare it with: [rho; phi] with phi the rotation vector and
// rho = V(phi)^-1 t.
#ifndef DSR_BASELINES_LIE_LOG_H_
#define DSR_BASELINES_LIE_LOG_H_

#include <cmath>

#include <ceres/jet.h>

namespace dsr {

// q = [qx, qy, qz, qw] (unit), t = [tx, ty, tz]; out = [rho; phi] (6).
template <typename T>
void LogSE3Quaternion(const T* q, const T* t, T* out) {
  using std::atan2;
  using std::cos;
  using std::sin;
  using std::sqrt;
  // q and -q are the same rotation: take the one with w >= 0 (angle in [0, pi]).
  const T s = q[3] < T(0) ? T(-1) : T(1);
  const T v[3] = {s * q[0], s * q[1], s * q[2]};
  const T w = s * q[3];
  const T n2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
  T phi[3];
  if (n2 < T(1e-20)) {
    // theta / |v| = 2 atan2(|v|, w) / |v| = 2 / w + O(|v|^2): first order in v, so
    // autodiff gets the right derivative at the identity.
    for (int d = 0; d < 3; ++d) phi[d] = T(2) * v[d] / w;
  } else {
    const T n = sqrt(n2);
    const T scale = T(2) * atan2(n, w) / n;
    for (int d = 0; d < 3; ++d) phi[d] = scale * v[d];
  }
  const T theta2 = phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2];
  // V^-1 = I - 1/2 [phi]x + c [phi]x^2,
  // c = (1 - theta sin(theta) / (2 (1 - cos(theta)))) / theta^2.
  T c;
  if (theta2 < T(1e-8)) {
    c = T(1.0 / 12.0) + theta2 / T(720.0);
  } else {
    const T theta = sqrt(theta2);
    c = (T(1) - theta * sin(theta) / (T(2) * (T(1) - cos(theta)))) / theta2;
  }
  // [phi]x t and [phi]x^2 t = phi x (phi x t).
  const T pt[3] = {phi[1] * t[2] - phi[2] * t[1], phi[2] * t[0] - phi[0] * t[2],
                   phi[0] * t[1] - phi[1] * t[0]};
  const T ppt[3] = {phi[1] * pt[2] - phi[2] * pt[1], phi[2] * pt[0] - phi[0] * pt[2],
                    phi[0] * pt[1] - phi[1] * pt[0]};
  for (int d = 0; d < 3; ++d) {
    out[d] = t[d] - T(0.5) * pt[d] + c * ppt[d];
    out[3 + d] = phi[d];
  }
}

}  // namespace dsr

#endif  // DSR_BASELINES_LIE_LOG_H_
