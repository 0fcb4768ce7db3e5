// The frames' poses (simulate.h): the draws of the pose models, random (the paper's
// protocol) and walk (a probe tilted and shifted between acquisitions), and SimulatedPoses.
#include "dsr/sim/simulate.h"

#include <algorithm>
#include <cmath>
#include <random>
#include <string>
#include <vector>

#include <glog/logging.h>

#include "dsr/sim/simulate_internal.h"

namespace dsr {
namespace {

using sim_internal::DrawPoses;

// Bisection steps that clamp a walk's rotation step to the Euler-angle box: 2^-50 of a step.
constexpr int kClampBisections = 50;
// Rounding slack of the Euler-angle box test: angles recomputed from a rotation matrix that
// was built from in-box angles may exceed the bound by a few ulps.
constexpr double kEulerSlack = 1e-12;

// Translate(c_f) * R * Translate(t - c_s).
Eigen::Isometry3d FrameFromWorld(const Eigen::Matrix3d& rotation,
                                 const Eigen::Vector3d& shift_mm,
                                 const Eigen::Vector3d& frame_center,
                                 const Eigen::Vector3d& source_center) {
  Eigen::Isometry3d frame_from_world = Eigen::Isometry3d::Identity();
  frame_from_world.linear() = rotation;
  frame_from_world.translation() = frame_center + rotation * (shift_mm - source_center);
  return frame_from_world;
}

// Whether R = Rz(gamma) Ry(beta) Rx(alpha) for some angles all within [-max, max]. The
// principal angles (beta in [-pi/2, pi/2]) and their only alternative
// (alpha +- pi, pi - beta, gamma +- pi) are both tried, so bounds >= 90 degrees work too.
bool InEulerBox(const Eigen::Matrix3d& r, double max_angle) {
  const double beta = -std::asin(std::clamp(r(2, 0), -1.0, 1.0));
  const double alpha = std::atan2(r(2, 1), r(2, 2));
  const double gamma = std::atan2(r(1, 0), r(0, 0));
  const double bound = max_angle + kEulerSlack;
  auto in = [bound](double a, double b, double g) {
    return std::abs(a) <= bound && std::abs(b) <= bound && std::abs(g) <= bound;
  };
  auto flip = [](double angle) { return angle > 0.0 ? angle - M_PI : angle + M_PI; };
  return in(alpha, beta, gamma) ||
         in(flip(alpha), (beta >= 0.0 ? M_PI : -M_PI) - beta, flip(gamma));
}

// A unit vector uniform on the sphere from two draws: z = u, azimuth = pi u.
Eigen::Vector3d DrawDirection(std::uniform_real_distribution<double>* u, std::mt19937_64* rng) {
  const double z = (*u)(*rng);
  const double azimuth = M_PI * (*u)(*rng);
  const double rho = std::sqrt(std::max(0.0, 1.0 - z * z));
  return Eigen::Vector3d(rho * std::cos(azimuth), rho * std::sin(azimuth), z);
}

}  // namespace

namespace sim_internal {

std::vector<Eigen::Isometry3d> DrawPoses(const ImageGeometry& source,
                                         const ImageGeometry& frame,
                                         const SimulationOptions& o,
                                         std::mt19937_64* rng) {
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  const Eigen::Vector3d source_center =
      source.IndexToPhysical(0.5 * (source.size.cast<double>() - Eigen::Vector3d::Ones()));
  const Eigen::Vector3d frame_center =
      frame.IndexToPhysical(0.5 * (frame.size.cast<double>() - Eigen::Vector3d::Ones()));
  const double max_angle = o.max_rotation_deg * M_PI / 180.0;
  const double max_shift_mm = o.max_translation_voxels * frame.spacing_mm[0];
  const double step_angle = o.step_rotation_deg * M_PI / 180.0;
  const double step_shift_mm = o.step_translation_voxels * frame.spacing_mm[0];
  std::vector<Eigen::Isometry3d> poses;
  // The current frame's R and t (frame 0 draws them; the walk steps from them).
  Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();
  Eigen::Vector3d shift_mm = Eigen::Vector3d::Zero();
  for (int f = 0; f < o.num_frames; ++f) {
    if (f == 0 || o.pose_model == PoseModel::kRandom) {
      // Sequenced draws (argument evaluation order is unspecified in C++).
      const double alpha = max_angle * u(*rng);
      const double beta = max_angle * u(*rng);
      const double gamma = max_angle * u(*rng);
      for (int a = 0; a < 3; ++a) shift_mm[a] = max_shift_mm * u(*rng);
      rotation = (Eigen::AngleAxisd(gamma, Eigen::Vector3d::UnitZ()) *
                  Eigen::AngleAxisd(beta, Eigen::Vector3d::UnitY()) *
                  Eigen::AngleAxisd(alpha, Eigen::Vector3d::UnitX()))
                     .toRotationMatrix();
    } else {
      const Eigen::Vector3d axis = DrawDirection(&u, rng);
      const double angle = step_angle * 0.5 * (1.0 + u(*rng));
      const Eigen::Vector3d direction = DrawDirection(&u, rng);
      const double length_mm = step_shift_mm * 0.5 * (1.0 + u(*rng));
      // R_i = R_{i-1} Q^T: Q acts on world_from_frame = R^T about the point the frame
      // centre sees (c_s - t), which the rotation leaves where it is.
      auto stepped = [&](double theta) {
        return Eigen::Matrix3d(rotation * Eigen::AngleAxisd(-theta, axis).toRotationMatrix());
      };
      double inside = angle;
      if (!InEulerBox(stepped(angle), max_angle)) {
        // theta = 0 (the previous rotation) is inside the box; keep the inside end.
        double lo = 0.0, hi = angle;
        for (int i = 0; i < kClampBisections; ++i) {
          const double mid = 0.5 * (lo + hi);
          (InEulerBox(stepped(mid), max_angle) ? lo : hi) = mid;
        }
        inside = lo;
      }
      rotation = stepped(inside);
      // t_i = t_{i-1} - d, clamped per axis to the box (moves each component towards the
      // previous, in-box value, so |t_i - t_{i-1}| <= |d|).
      shift_mm = (shift_mm - length_mm * direction).cwiseMax(-max_shift_mm).cwiseMin(max_shift_mm);
    }
    poses.push_back(FrameFromWorld(rotation, shift_mm, frame_center, source_center));
  }
  return poses;
}

}  // namespace sim_internal

std::vector<Eigen::Isometry3d> SimulatedPoses(const ImageGeometry& source,
                                              const SimulationOptions& options) {
  std::string error;
  CHECK(options.Validate(&error)) << error;
  std::mt19937_64 rng(options.seed);
  return DrawPoses(source, SimulatedFrameGeometry(source, options), options, &rng);
}

}  // namespace dsr
