// The paper's simulation protocol (docs/design.md section 6); conventions in simulate.h.
#include "sim/simulate.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <sstream>
#include <string>

#include <glog/logging.h>

#include "core/frame.h"
#include "core/parallel.h"

namespace dsr {
namespace {

constexpr int kMaxFrames = 1000;
constexpr int kMaxFrameSize = 2048;

constexpr int kMaxMaskErosion = 50;

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

// Keys' cubic convolution weights (a = -0.5) of the taps at offsets -1, 0, 1, 2 from
// floor(x), for t = x - floor(x) in [0, 1) (simulate.h).
void KeysWeights(double t, double w[4]) {
  const double t2 = t * t, t3 = t2 * t;
  w[0] = 0.5 * (-t3 + 2.0 * t2 - t);
  w[1] = 0.5 * (3.0 * t3 - 5.0 * t2 + 2.0);
  w[2] = 0.5 * (-3.0 * t3 + 4.0 * t2 + t);
  w[3] = 0.5 * (t3 - t2);
}

}  // namespace

const char* SourceInterpolationToString(SourceInterpolation interpolation) {
  switch (interpolation) {
    case SourceInterpolation::kLinear:
      return "linear";
    case SourceInterpolation::kCubic:
      return "cubic";
  }
  return "";
}

bool StringToSourceInterpolation(const std::string& text, SourceInterpolation* interpolation) {
  CHECK(interpolation != nullptr);
  for (SourceInterpolation m : {SourceInterpolation::kLinear, SourceInterpolation::kCubic}) {
    if (text == SourceInterpolationToString(m)) {
      *interpolation = m;
      return true;
    }
  }
  return false;
}

double CubicInterpolateValue(const Image& image, const Eigen::Vector3d& ijk) {
  CHECK(ijk.allFinite()) << ijk.transpose();
  CHECK(!image.empty());
  const Eigen::Vector3i& n = image.geometry.size;
  // Per axis: the 4 clamped tap indices and their weights.
  int index[3][4];
  double weight[3][4];
  for (int a = 0; a < 3; ++a) {
    // Clamping x first keeps the int conversion defined; it moves no tap of an x inside
    // the grid.
    const double x = std::clamp(ijk[a], -1.0, static_cast<double>(n[a]));
    const double lower = std::floor(x);
    KeysWeights(x - lower, weight[a]);
    for (int tap = 0; tap < 4; ++tap) {
      index[a][tap] = std::clamp(static_cast<int>(lower) - 1 + tap, 0, n[a] - 1);
    }
  }
  double value = 0.0;
  for (int tk = 0; tk < 4; ++tk) {
    double plane = 0.0;
    for (int tj = 0; tj < 4; ++tj) {
      double row = 0.0;
      for (int ti = 0; ti < 4; ++ti) {
        row += weight[0][ti] * image.at(index[0][ti], index[1][tj], index[2][tk]);
      }
      plane += weight[1][tj] * row;
    }
    value += weight[2][tk] * plane;
  }
  return value;
}

const char* PoseModelToString(PoseModel model) {
  switch (model) {
    case PoseModel::kRandom:
      return "random";
    case PoseModel::kWalk:
      return "walk";
  }
  return "";
}

bool StringToPoseModel(const std::string& text, PoseModel* model) {
  CHECK(model != nullptr);
  for (PoseModel m : {PoseModel::kRandom, PoseModel::kWalk}) {
    if (text == PoseModelToString(m)) {
      *model = m;
      return true;
    }
  }
  return false;
}

bool SimulationOptions::Validate(std::string* error) const {
  std::ostringstream s;
  auto range = [](double v, double lo, double hi) {
    return std::isfinite(v) && v >= lo && v <= hi;
  };
  if (num_frames < 2 || num_frames > kMaxFrames) {
    s << "--num_frames=" << num_frames << ": must be in [2, " << kMaxFrames << "]";
  } else if (!range(max_rotation_deg, 0.0, 180.0)) {
    s << "--max_rotation_deg=" << max_rotation_deg << ": must be in [0, 180]";
  } else if (!range(max_translation_voxels, 0.0, std::numeric_limits<double>::max())) {
    s << "--max_translation_voxels=" << max_translation_voxels << ": must be finite and >= 0";
  } else if (*PoseModelToString(pose_model) == '\0') {
    s << "--pose_model=" << static_cast<int>(pose_model) << ": must be random or walk";
  } else if (!range(step_rotation_deg, 0.0, 180.0)) {
    s << "--step_rotation_deg=" << step_rotation_deg << ": must be in [0, 180]";
  } else if (!range(step_translation_voxels, 0.0, std::numeric_limits<double>::max())) {
    s << "--step_translation_voxels=" << step_translation_voxels << ": must be finite and >= 0";
  } else if (!range(noise_sigma, 0.0, std::numeric_limits<double>::max())) {
    s << "--sigma=" << noise_sigma << ": must be finite and >= 0";
  } else if ((frame_size.array() < 4).any() || (frame_size.array() > kMaxFrameSize).any()) {
    s << "--frame_size=" << frame_size[0] << "," << frame_size[1] << "," << frame_size[2]
      << ": every size must be in [4, " << kMaxFrameSize << "]";
  } else if (!range(frame_spacing_mm, 0.0, std::numeric_limits<double>::max())) {
    s << "--frame_spacing=" << frame_spacing_mm << ": must be finite and >= 0 (0 = source spacing)";
  } else if (!(std::isfinite(azimuth_deg) && azimuth_deg > 0.0 && azimuth_deg < 180.0)) {
    s << "--azimuth_deg=" << azimuth_deg << ": must be in (0, 180)";
  } else if (!(std::isfinite(elevation_deg) && elevation_deg > 0.0 && elevation_deg < 180.0)) {
    s << "--elevation_deg=" << elevation_deg << ": must be in (0, 180)";
  } else if (!range(min_depth_voxels, 0.0, frame_size[2] - 3.0)) {
    s << "--min_depth_voxels=" << min_depth_voxels
      << ": must be in [0, frame depth - 3 = " << frame_size[2] - 3 << "]";
  } else if (mask_erosion_voxels < 0 || mask_erosion_voxels > kMaxMaskErosion) {
    s << "--mask_erosion=" << mask_erosion_voxels << ": must be in [0, " << kMaxMaskErosion
      << "]";
  } else if (*SourceInterpolationToString(interpolation) == '\0') {
    s << "--interpolation=" << static_cast<int>(interpolation) << ": must be linear or cubic";
  } else {
    return true;
  }
  if (error != nullptr) *error = s.str();
  return false;
}

ImageGeometry SimulatedFrameGeometry(const ImageGeometry& source, const SimulationOptions& o) {
  ImageGeometry g;
  g.size = o.frame_size;
  g.spacing_mm = Eigen::Vector3d::Constant(o.frame_spacing_mm > 0.0 ? o.frame_spacing_mm
                                                                    : source.spacing_mm[0]);
  return g;  // origin 0, identity direction
}

Mask PyramidFieldOfView(const ImageGeometry& g, const SimulationOptions& o) {
  Mask mask(g, 0);
  const double cx = 0.5 * (g.size[0] - 1), cy = 0.5 * (g.size[1] - 1);
  const double tan_azimuth = std::tan(0.5 * o.azimuth_deg * M_PI / 180.0);
  const double tan_elevation = std::tan(0.5 * o.elevation_deg * M_PI / 180.0);
  // Voxels exactly on a pyramid face are inside; the slack absorbs tan's rounding (e.g.
  // tan(45 deg) = 1 - 1e-16), so the shape does not depend on the last bit.
  constexpr double kSlack = 1e-9;
  for (int k = 0; k < g.size[2]; ++k) {
    if (k + kSlack < o.min_depth_voxels) continue;
    for (int j = 0; j < g.size[1]; ++j) {
      if (std::abs(j - cy) > k * tan_elevation + kSlack) continue;
      for (int i = 0; i < g.size[0]; ++i) {
        mask.at(i, j, k) = std::abs(i - cx) <= k * tan_azimuth + kSlack ? 1 : 0;
      }
    }
  }
  return mask;
}

Mask ErodeFieldOfView(const Mask& fov, int erosion_voxels) {
  CHECK_GE(erosion_voxels, 0);
  const Eigen::Vector3i& n = fov.geometry.size;
  Mask mask = fov;
  for (int pass = 0; pass < erosion_voxels; ++pass) {
    const Mask m = mask;
    std::fill(mask.voxels.begin(), mask.voxels.end(), 0);
    for (int k = 1; k + 1 < n[2]; ++k) {
      for (int j = 1; j + 1 < n[1]; ++j) {
        for (int i = 1; i + 1 < n[0]; ++i) {
          mask.at(i, j, k) = m.at(i, j, k) && m.at(i - 1, j, k) && m.at(i + 1, j, k) &&
                                     m.at(i, j - 1, k) && m.at(i, j + 1, k) &&
                                     m.at(i, j, k - 1) && m.at(i, j, k + 1)
                                 ? 1
                                 : 0;
        }
      }
    }
  }
  return mask;
}

std::vector<Eigen::Isometry3d> SimulatedPoses(const ImageGeometry& source,
                                              const SimulationOptions& options) {
  std::string error;
  CHECK(options.Validate(&error)) << error;
  std::mt19937_64 rng(options.seed);
  return DrawPoses(source, SimulatedFrameGeometry(source, options), options, &rng);
}

bool Simulate(const Image& source,
              const SimulationOptions& options,
              SimulatedSequence* sequence,
              std::string* error) {
  CHECK(sequence != nullptr);
  CHECK(error != nullptr);
  if (!options.Validate(error)) return false;
  if (source.empty() || static_cast<int64_t>(source.voxels.size()) != source.geometry.NumVoxels()) {
    *error = "source volume is empty or its voxel count does not match its grid";
    return false;
  }
  if (!source.geometry.Validate("source volume", error)) return false;

  const ImageGeometry g = SimulatedFrameGeometry(source.geometry, options);
  const Mask fov = PyramidFieldOfView(g, options);
  const Mask mask = ErodeFieldOfView(fov, options.mask_erosion_voxels);
  if (CountInside(mask) == 0) {
    *error = "the field of view is empty after the " +
             std::to_string(options.mask_erosion_voxels) +
             "-voxel erosion (--mask_erosion): increase --frame_size, --azimuth_deg or "
             "--elevation_deg, or decrease --min_depth_voxels or --mask_erosion";
    return false;
  }
  std::mt19937_64 rng(options.seed);
  const std::vector<Eigen::Isometry3d> poses = DrawPoses(source.geometry, g, options, &rng);

  const Frame source_frame(source, Mask(source.geometry, 1));
  const Eigen::Vector3d upper = source.geometry.size.cast<double>() - Eigen::Vector3d::Ones();
  // Slack for rounding: a voxel that maps to -1e-9 still samples the border voxel.
  constexpr double kIndexSlack = 1e-6;
  std::normal_distribution<double> normal(0.0, 1.0);
  SimulatedSequence out;
  for (int f = 0; f < options.num_frames; ++f) {
    Image frame(g, 0.0f);
    const Eigen::Isometry3d world_from_frame = poses[f].inverse();
    // Sample in parallel (each slice writes its own voxels and its own first-miss record),
    // then add noise in a fixed serial order so the result does not depend on threads.
    std::vector<int64_t> first_miss(g.size[2], -1);  // linear index of the first miss per slice
    ParallelFor(0, g.size[2], 0, [&](int64_t k) {
      for (int j = 0; j < g.size[1]; ++j) {
        for (int i = 0; i < g.size[0]; ++i) {
          const int64_t l = g.LinearIndex(i, j, static_cast<int>(k));
          if (!fov.voxels[l]) continue;
          const Eigen::Vector3d x_in_world =
              world_from_frame * g.IndexToPhysical(Eigen::Vector3d(i, j, static_cast<double>(k)));
          const Eigen::Vector3d ijk_source = source_frame.ToIndex(x_in_world);
          if ((ijk_source.array() < -kIndexSlack).any() ||
              (ijk_source.array() > upper.array() + kIndexSlack).any()) {
            if (first_miss[k] < 0) first_miss[k] = l;
            continue;
          }
          frame.voxels[l] = static_cast<float>(
              options.interpolation == SourceInterpolation::kCubic
                  ? CubicInterpolateValue(source, ijk_source)
                  : source_frame.InterpolateValue(ijk_source));
        }
      }
    });
    for (int k = 0; k < g.size[2]; ++k) {
      if (first_miss[k] < 0) continue;
      const int64_t l = first_miss[k];
      const Eigen::Vector3d ijk(l % g.size[0], (l / g.size[0]) % g.size[1], k);
      const Eigen::Vector3d ijk_source =
          source_frame.ToIndex(world_from_frame * g.IndexToPhysical(ijk));
      std::ostringstream s;
      s << "frame " << f << ": field-of-view voxel (" << ijk.transpose()
        << ") maps to source index (" << ijk_source.transpose() << "), outside the source grid ("
        << source.geometry.DebugString()
        << "); use a larger source (--phantom_size), a smaller --frame_size or smaller motions";
      *error = s.str();
      return false;
    }
    for (size_t l = 0; l < frame.voxels.size(); ++l) {
      if (!fov.voxels[l]) continue;
      const double noisy = frame.voxels[l] + options.noise_sigma * normal(rng);
      frame.voxels[l] = static_cast<float>(std::clamp(noisy, 0.0, 255.0));
    }
    out.frames.push_back(std::move(frame));
    out.masks.push_back(mask);
    out.frame_from_world.push_back(poses[f]);
  }
  *sequence = std::move(out);
  return true;
}

}  // namespace dsr
