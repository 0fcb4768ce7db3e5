#include "init/recovery.h"

#include <algorithm>
#include <cmath>

#include <glog/logging.h>

#include "core/panorama.h"
#include "init/rotation_grid.h"

namespace dsr {

bool ReplaceFrames(const std::vector<Frame>& frames,
                   const std::vector<Eigen::Isometry3d>& frame_from_world,
                   const std::vector<int>& flagged,
                   const PlacementSearchOptions& options,
                   std::vector<Eigen::Isometry3d>* replaced,
                   std::vector<FrameReplacement>* records,
                   std::string* error) {
  const int m = static_cast<int>(frames.size());
  CHECK_EQ(frame_from_world.size(), frames.size());
  std::vector<bool> is_flagged(m, false);
  for (int f : flagged) {
    CHECK(f >= 0 && f < m) << f;
    is_flagged[f] = true;
  }
  std::vector<Frame> passed;
  std::vector<Eigen::Isometry3d> passed_poses;
  for (int i = 0; i < m; ++i) {
    if (is_flagged[i]) continue;
    passed.push_back(frames[i]);
    passed_poses.push_back(frame_from_world[i]);
  }
  if (passed.empty()) {
    *error = "recovery: every frame was flagged, no panorama to place them against";
    return false;
  }
  ImageGeometry grid;
  if (!BuildPanoramaGrid(passed, passed_poses, 1.0, &grid, error)) {
    *error = "recovery: " + *error;
    return false;
  }
  const PanoramaImages fused = FusePanoramaMean(passed, passed_poses, grid, options.num_threads);
  // The panorama's field of view: voxels a passed frame observes, eroded by one voxel so
  // that its gradients use observed voxels only (as a frame's mask).
  Image seen(grid, 0.0f);
  for (size_t l = 0; l < seen.voxels.size(); ++l) seen.voxels[l] = fused.count.voxels[l] > 0;
  const Frame panorama(fused.mean, MaskFromNonZero(seen, 1));
  if (panorama.num_valid_cells() == 0) {
    *error = "recovery: the panorama of the frames that passed the checks is empty";
    return false;
  }

  *replaced = frame_from_world;
  records->clear();
  for (int f : flagged) {
    // World = the panorama's physical space, so moving_from_fixed is frame_from_world.
    const Eigen::Isometry3d current = frame_from_world[f];
    const std::vector<Placement> candidates = SearchPlacement(
        panorama, frames[f], Eigen::Matrix3d::Identity(), {current}, options);
    FrameReplacement record;
    record.frame = f;
    record.ncc_before =
        ScorePlacement(panorama, frames[f], current, options.min_overlap_fraction).ncc;
    record.ncc_after = record.ncc_before;
    if (!candidates.empty() && candidates.front().from_search) {
      const Eigen::Isometry3d& chosen = candidates.front().moving_from_fixed;
      const Eigen::Vector3d centre_in_frame =
          frames[f].geometry().IndexToPhysical(frames[f].ValidIndexBox().center());
      record.moved = true;
      record.ncc_after = candidates.front().ncc;
      record.rotation_change_deg =
          RotationAngleBetween(current.linear(), chosen.linear()) * 180.0 / M_PI;
      record.translation_change_mm =
          (current.inverse() * centre_in_frame - chosen.inverse() * centre_in_frame).norm();
      (*replaced)[f] = chosen;
    } else if (!candidates.empty()) {
      record.ncc_after = candidates.front().ncc;
    }
    VLOG(1) << "recovery: frame " << f << " NCC " << record.ncc_before << " -> "
            << record.ncc_after << (record.moved ? " (moved)" : " (kept)");
    records->push_back(record);
  }
  return true;
}

}  // namespace dsr
