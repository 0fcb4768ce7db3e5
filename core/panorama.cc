// Panorama grid construction and the closed-form (mean) panorama, eq. 10 of the paper.
#include "core/panorama.h"

#include <algorithm>
#include <cmath>
#include <sstream>

#include <glog/logging.h>

#include "core/parallel.h"

namespace dsr {

bool BuildPanoramaGrid(const std::vector<Frame>& frames,
                       const std::vector<Eigen::Isometry3d>& frame_from_world,
                       double spacing_factor,
                       ImageGeometry* grid,
                       std::string* error) {
  CHECK(!frames.empty());
  CHECK_EQ(frames.size(), frame_from_world.size());
  Eigen::AlignedBox3d box;
  for (size_t i = 0; i < frames.size(); ++i) {
    const Eigen::AlignedBox3d fov = frames[i].ValidIndexBox();
    if (fov.isEmpty()) {
      *error = "frame " + std::to_string(i) + " has no valid field-of-view cell";
      return false;
    }
    const Eigen::Isometry3d world_from_frame = frame_from_world[i].inverse();
    for (int c = 0; c < 8; ++c) {
      const Eigen::Vector3d corner = fov.corner(static_cast<Eigen::AlignedBox3d::CornerType>(c));
      box.extend(world_from_frame * frames[i].geometry().IndexToPhysical(corner));
    }
  }
  ImageGeometry g;
  g.spacing_mm = frames[0].geometry().spacing_mm * spacing_factor;
  g.direction.setIdentity();
  g.origin_mm = box.min();
  double num_voxels = 1.0;
  for (int a = 0; a < 3; ++a) {
    const double n = std::ceil((box.max()[a] - box.min()[a]) / g.spacing_mm[a] - 1e-9) + 1.0;
    num_voxels *= n;
    g.size[a] = static_cast<int>(std::min(n, 2e9));
  }
  if (!(num_voxels <= static_cast<double>(kMaxPanoramaVoxels))) {
    std::ostringstream s;
    s << "panorama grid of " << g.size[0] << "x" << g.size[1] << "x" << g.size[2]
      << " voxels (spacing " << g.spacing_mm.transpose() << " mm, extent "
      << (box.max() - box.min()).transpose()
      << " mm) is too large; check the poses or use a coarser --panorama_spacing";
    *error = s.str();
    return false;
  }
  *grid = g;
  return true;
}

PanoramaImages FusePanoramaMean(const std::vector<Frame>& frames,
                                const std::vector<Eigen::Isometry3d>& frame_from_world,
                                const ImageGeometry& grid,
                                int num_threads) {
  PanoramaImages out;
  out.mean = Image(grid, 0.0f);
  out.count = Volume<uint8_t>(grid, 0);
  const int64_t slice = int64_t{grid.size[0]} * grid.size[1];
  ParallelFor(0, grid.size[2], num_threads, [&](int64_t k) {
    for (int j = 0; j < grid.size[1]; ++j) {
      for (int i = 0; i < grid.size[0]; ++i) {
        const Eigen::Vector3d p = grid.IndexToPhysical(Eigen::Vector3d(i, j, k));
        double sum = 0.0;
        int count = 0;
        for (size_t f = 0; f < frames.size(); ++f) {
          double value;
          if (frames[f].Sample(frame_from_world[f] * p, &value, nullptr)) {
            sum += value;
            ++count;
          }
        }
        const int64_t l = k * slice + grid.LinearIndex(i, j, 0);
        out.count.voxels[l] = static_cast<uint8_t>(count);
        out.mean.voxels[l] = count > 0 ? static_cast<float>(sum / count) : 0.0f;
      }
    }
  });
  return out;
}

}  // namespace dsr
