#include "dsr/init/recovery.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include <glog/logging.h>

#include "dsr/init/rotation_grid.h"
#include "dsr/model/panorama.h"

namespace dsr {

namespace {

// The mean panorama of `frames` at their poses as a Frame in world coordinates
// (PanoramaAsFrame: not eroded, which on a coarse level would leave little, the frames' own
// valid cells being only a part of their grids there). False with `error` when it cannot
// be built.
bool PanoramaFrame(const std::vector<Frame>& frames,
                   const std::vector<Eigen::Isometry3d>& frame_from_world,
                   int num_threads,
                   Frame* panorama,
                   std::string* error) {
  ImageGeometry grid;
  if (!BuildPanoramaGrid(frames, frame_from_world, 1.0, &grid, error)) return false;
  *panorama = PanoramaAsFrame(FusePanoramaMean(frames, frame_from_world, grid, num_threads));
  if (panorama->num_valid_cells() == 0) {
    *error = "the panorama of the frames that passed the checks is empty";
    return false;
  }
  return true;
}

// How well a placed frame matches the others: the median, over up to kReferenceFrames of
// the passed frames, of each one's NCC against the panorama of the other passed frames
// (-inf with fewer than two passed frames).
constexpr int kReferenceFrames = 4;
double ReferenceNcc(const std::vector<Frame>& passed,
                    const std::vector<Eigen::Isometry3d>& passed_poses,
                    const PlacementSearchOptions& options) {
  const int n = static_cast<int>(passed.size());
  std::vector<double> scores;
  for (int r = 0; r < std::min(n, kReferenceFrames) && n >= 2; ++r) {
    const int p = r * n / std::min(n, kReferenceFrames);
    std::vector<Frame> others;
    std::vector<Eigen::Isometry3d> others_poses;
    for (int i = 0; i < n; ++i) {
      if (i == p) continue;
      others.push_back(passed[i]);
      others_poses.push_back(passed_poses[i]);
    }
    Frame panorama;
    std::string ignored;
    if (!PanoramaFrame(others, others_poses, options.num_threads, &panorama, &ignored)) continue;
    scores.push_back(
        ScorePlacement(panorama, passed[p], passed_poses[p], ScoreMinOverlap(options)).ncc);
  }
  if (scores.empty()) return -std::numeric_limits<double>::infinity();
  std::sort(scores.begin(), scores.end());
  return scores[(scores.size() - 1) / 2];
}

}  // namespace

bool ReplaceFrames(const std::vector<Frame>& frames,
                   const std::vector<Eigen::Isometry3d>& frame_from_world,
                   const std::vector<Eigen::Isometry3d>& start_frame_from_world,
                   const std::vector<int>& flagged,
                   const PlacementSearchOptions& options,
                   int max_searches,
                   std::vector<Eigen::Isometry3d>* replaced,
                   std::vector<FrameReplacement>* records,
                   std::string* error) {
  const int m = static_cast<int>(frames.size());
  CHECK_EQ(frame_from_world.size(), frames.size());
  CHECK_EQ(start_frame_from_world.size(), frames.size());
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
  Frame panorama;
  if (!PanoramaFrame(passed, passed_poses, options.num_threads, &panorama, error)) {
    *error = "recovery: " + *error;
    return false;
  }
  const double reference = ReferenceNcc(passed, passed_poses, options);

  // World = the panorama's physical space, so moving_from_fixed is frame_from_world.
  std::vector<double> ncc_before(m, 0.0);
  int searches = 0;
  for (int f : flagged) {
    ncc_before[f] = ScorePlacement(panorama, frames[f], frame_from_world[f],
                                   ScoreMinOverlap(options)).ncc;
    if (!(std::isfinite(reference) && ncc_before[f] >= reference - kKeepNccMargin)) ++searches;
  }
  if (max_searches >= 0 && searches > max_searches) {
    *error = "recovery: " + std::to_string(searches) + " flagged frames need a search (more "
             "than " + std::to_string(max_searches) + ")";
    return false;
  }
  *replaced = frame_from_world;
  records->clear();
  for (int f : flagged) {
    const Eigen::Isometry3d current = frame_from_world[f];
    FrameReplacement record;
    record.frame = f;
    record.ncc_before = ncc_before[f];
    record.ncc_after = record.ncc_before;
    record.reference_ncc = reference;
    if (std::isfinite(reference) && record.ncc_before >= reference - kKeepNccMargin) {
      VLOG(1) << "recovery: frame " << f << " kept without a search (NCC " << record.ncc_before
              << ", the passed frames' " << reference << ")";
      records->push_back(record);
      continue;
    }
    record.searched = true;
    const std::vector<Placement> candidates =
        SearchPlacement(panorama, frames[f], Eigen::Matrix3d::Identity(),
                        {current, start_frame_from_world[f]}, options);
    // Best NCC first; extra start 0 (the current pose, refined) first means kept.
    const Placement* best = candidates.empty() ? nullptr : &candidates.front();
    if (best != nullptr && best->extra_start != 0) {
      const Eigen::Isometry3d& chosen = best->moving_from_fixed;
      const Eigen::Vector3d centre_in_frame = frames[f].ValidCentre();
      record.moved = true;
      record.ncc_after = best->ncc;
      record.rotation_change_deg =
          RotationAngleBetween(current.linear(), chosen.linear()) * 180.0 / M_PI;
      record.translation_change_mm =
          (current.inverse() * centre_in_frame - chosen.inverse() * centre_in_frame).norm();
      (*replaced)[f] = chosen;
    } else if (best != nullptr) {
      record.ncc_after = best->ncc;
    }
    VLOG(1) << "recovery: frame " << f << " NCC " << record.ncc_before << " -> "
            << record.ncc_after << " (passed frames " << reference << ")"
            << (record.moved ? " (moved)" : " (kept)");
    records->push_back(record);
  }
  return true;
}

}  // namespace dsr
