// The panorama grid and the closed-form panorama (DESIGN.md section 2; paper eq. 10).
//
// Grid: axis-aligned in world (identity direction), spacing = frame 0 spacing times
// `spacing_factor`, extent = the bounding box of every frame's valid field of view mapped
// to world by the given poses. Voxel centres are p_j = origin + spacing .* ijk.
#ifndef DSR_CORE_PANORAMA_H_
#define DSR_CORE_PANORAMA_H_

#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "core/frame.h"
#include "core/observation.h"
#include "core/volume.h"

namespace dsr {

// Panoramas above this many voxels are refused (a wrong pose or spacing, not a real case).
constexpr int64_t kMaxPanoramaVoxels = int64_t{1} << 31;

// Builds the grid. Fails when a frame has no valid cell or the grid would exceed
// kMaxPanoramaVoxels (error names the spacing and the extent).
bool BuildPanoramaGrid(const std::vector<Frame>& frames,
                       const std::vector<Eigen::Isometry3d>& frame_from_world,
                       double spacing_factor,
                       ImageGeometry* grid,
                       std::string* error);

struct PanoramaImages {
  Image mean;        // mu_j = (1/k_j) sum_i sigma_ij I_i(p_ij); 0 where k_j = 0
  Volume<uint8_t> count;  // k_j, number of frames observing each voxel
};

// Closed-form panorama over every voxel of `grid` (not only candidates): each frame's
// valid samples at the given poses, averaged. Multithreaded over slabs, deterministic.
PanoramaImages FusePanoramaMean(const std::vector<Frame>& frames,
                                const std::vector<Eigen::Isometry3d>& frame_from_world,
                                const ImageGeometry& grid,
                                int num_threads);

}  // namespace dsr

#endif  // DSR_CORE_PANORAMA_H_
