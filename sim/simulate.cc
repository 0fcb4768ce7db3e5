#include "sim/simulate.h"

#include <algorithm>
#include <cmath>
#include <random>
#include <sstream>

#include "core/frame.h"
#include "core/parallel.h"
#include "core/se3.h"

namespace dsr {

bool SimulationOptions::Validate(std::string* error) const {
  auto fail = [&](const std::string& m) {
    *error = m;
    return false;
  };
  if (num_frames < 2) return fail("--num_frames=" + std::to_string(num_frames) + ": must be >= 2");
  if (!(max_rotation_deg >= 0.0 && max_rotation_deg <= 90.0))
    return fail("--max_rotation_deg: must be in [0, 90]");
  if (!(max_translation_voxels >= 0.0)) return fail("--max_translation_voxels: must be >= 0");
  if (!(noise_sigma >= 0.0) || !std::isfinite(noise_sigma)) return fail("--sigma: must be >= 0");
  if ((frame_size.array() < 4).any()) return fail("--frame_size: every dimension must be >= 4");
  if (!(frame_spacing_mm >= 0.0)) return fail("--frame_spacing: must be >= 0 (0 = source spacing)");
  if (!(azimuth_deg > 0.0 && azimuth_deg < 170.0)) return fail("--azimuth_deg: must be in (0, 170)");
  if (!(elevation_deg > 0.0 && elevation_deg < 170.0)) return fail("--elevation_deg: must be in (0, 170)");
  if (!(min_depth_voxels >= 0.0 && min_depth_voxels < frame_size[2] - 2))
    return fail("--min_depth_voxels: must be in [0, frame depth - 2)");
  return true;
}

Mask PyramidFieldOfView(const ImageGeometry& g, const SimulationOptions& o) {
  Mask mask(g, 0);
  const double cx = 0.5 * (g.size[0] - 1), cy = 0.5 * (g.size[1] - 1);
  const double ta = std::tan(0.5 * o.azimuth_deg * M_PI / 180.0);
  const double te = std::tan(0.5 * o.elevation_deg * M_PI / 180.0);
  for (int k = 0; k < g.size[2]; ++k) {
    if (k < o.min_depth_voxels) continue;
    for (int j = 0; j < g.size[1]; ++j)
      for (int i = 0; i < g.size[0]; ++i)
        mask.at(i, j, k) = std::abs(i - cx) <= k * ta && std::abs(j - cy) <= k * te;
  }
  return mask;
}

bool Simulate(const Image& source,
              const SimulationOptions& o,
              SimulatedSequence* sequence,
              std::string* error) {
  if (!o.Validate(error)) return false;
  const double spacing = o.frame_spacing_mm > 0.0 ? o.frame_spacing_mm : source.geometry.spacing_mm[0];
  ImageGeometry g;
  g.size = o.frame_size;
  g.spacing_mm = Eigen::Vector3d::Constant(spacing);
  const Mask fov = PyramidFieldOfView(g, o);
  const Frame source_frame(source, Mask(source.geometry, 1));
  const Eigen::Vector3d source_center =
      source.geometry.IndexToPhysical(0.5 * (source.geometry.size.cast<double>() - Eigen::Vector3d::Ones()));
  const Eigen::Vector3d frame_center = g.IndexToPhysical(0.5 * (g.size.cast<double>() - Eigen::Vector3d::Ones()));

  std::mt19937_64 rng(o.seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  SimulatedSequence out;
  for (int f = 0; f < o.num_frames; ++f) {
    const double r = o.max_rotation_deg * M_PI / 180.0;
    const Eigen::Matrix3d rotation = (Eigen::AngleAxisd(r * u(rng), Eigen::Vector3d::UnitZ()) *
                                      Eigen::AngleAxisd(r * u(rng), Eigen::Vector3d::UnitY()) *
                                      Eigen::AngleAxisd(r * u(rng), Eigen::Vector3d::UnitX()))
                                         .toRotationMatrix();
    const Eigen::Vector3d shift = o.max_translation_voxels * spacing * Eigen::Vector3d(u(rng), u(rng), u(rng));
    Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
    pose.linear() = rotation;
    pose.translation() = frame_center + shift - rotation * source_center;
    out.frame_from_world.push_back(pose);
  }
  std::normal_distribution<double> noise(0.0, 1.0);
  for (int f = 0; f < o.num_frames; ++f) {
    Image frame(g, 0.0f);
    const Eigen::Isometry3d world_from_frame = out.frame_from_world[f].inverse();
    // Sample first (parallel, deterministic), then add noise in a fixed serial order.
    bool outside = false;
    ParallelFor(0, g.size[2], 0, [&](int64_t k) {
      for (int j = 0; j < g.size[1]; ++j)
        for (int i = 0; i < g.size[0]; ++i) {
          if (!fov.at(i, j, static_cast<int>(k))) continue;
          const Eigen::Vector3d u_src = source_frame.ToIndex(world_from_frame * g.IndexToPhysical(Eigen::Vector3d(i, j, k)));
          if ((u_src.array() < 0.0).any() || (u_src.array() > (source.geometry.size.cast<double>().array() - 1.0)).any()) {
            outside = true;
          }
          frame.at(i, j, static_cast<int>(k)) = static_cast<float>(source_frame.InterpolateValue(u_src));
        }
    });
    if (outside) {
      std::ostringstream s;
      s << "frame " << f << " samples outside the source volume (" << source.geometry.DebugString()
        << "); use a larger source, a smaller --frame_size or smaller motions";
      *error = s.str();
      return false;
    }
    for (size_t v = 0; v < frame.voxels.size(); ++v) {
      if (!fov.voxels[v]) continue;
      const double value = frame.voxels[v] + o.noise_sigma * noise(rng);
      frame.voxels[v] = static_cast<float>(std::clamp(value, 0.0, 255.0));
    }
    Mask mask = fov;
    // Erode by 1 voxel: a voxel stays when its 6 neighbours are inside.
    for (int k = 0; k < g.size[2]; ++k)
      for (int j = 0; j < g.size[1]; ++j)
        for (int i = 0; i < g.size[0]; ++i) {
          if (!fov.at(i, j, k)) continue;
          const bool interior = i > 0 && j > 0 && k > 0 && i < g.size[0] - 1 && j < g.size[1] - 1 &&
                                k < g.size[2] - 1 && fov.at(i - 1, j, k) && fov.at(i + 1, j, k) &&
                                fov.at(i, j - 1, k) && fov.at(i, j + 1, k) && fov.at(i, j, k - 1) &&
                                fov.at(i, j, k + 1);
          mask.at(i, j, k) = interior;
        }
    out.frames.push_back(std::move(frame));
    out.masks.push_back(std::move(mask));
  }
  *sequence = std::move(out);
  return true;
}

}  // namespace dsr
