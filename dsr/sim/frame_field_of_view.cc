// The simulated frames' grid and their pyramidal field of view (simulate.h):
// SimulatedFrameGeometry, PyramidFieldOfView and ErodeFieldOfView.
#include "dsr/sim/simulate.h"

#include <algorithm>
#include <cmath>

#include <glog/logging.h>

namespace dsr {

ImageGeometry SimulatedFrameGeometry(const ImageGeometry& source, const SimulationOptions& o) {
  ImageGeometry g;
  g.size = o.frame_size;
  g.spacing_mm =
      Eigen::Vector3d::Constant(o.frame_spacing > 0.0 ? o.frame_spacing : source.spacing_mm[0]);
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
                                     m.at(i, j - 1, k) && m.at(i, j + 1, k) && m.at(i, j, k - 1) &&
                                     m.at(i, j, k + 1)
                                 ? 1
                                 : 0;
        }
      }
    }
  }
  return mask;
}

}  // namespace dsr
