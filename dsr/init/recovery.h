// Recovery of frames that a solve left in a wrong minimum (docs/design.md section 10,
// "Recovery").
//
// The pipeline's checks (pipeline/divergence_guard.h) name the frames that do not agree
// with the others after a solve: a misfit far above the frames' lower quartile, or a
// frame that slid out of the overlap. Each such frame is re-placed by the global search
// (init/placement_search.h) against the mean panorama of the frames that passed, at their
// current poses, on a coarse pyramid level; its current pose is refined and scored beside
// the search's candidates, so a frame is only moved to a placement that matches the
// panorama better. The pipeline then solves again from the new poses.
#ifndef DSR_INIT_RECOVERY_H_
#define DSR_INIT_RECOVERY_H_

#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "dsr/image/frame.h"
#include "dsr/init/placement_search.h"

namespace dsr {

// See ReplaceFrames.
constexpr double kKeepNccMargin = 0.02;

struct FrameReplacement {
  int frame = 0;
  double ncc_before = 0.0;  // masked NCC against the panorama at the current pose
  double ncc_after = 0.0;   // at the chosen placement
  double rotation_change_deg = 0.0;    // between the current pose and the chosen one
  double translation_change_mm = 0.0;  // of the frame's field-of-view centre in world
  bool moved = false;     // false: kept (the current pose scored best, or no search)
  bool searched = false;  // false: kept without a search (it matched like the passed ones)
  double reference_ncc = 0.0;  // how well the passed frames match each other
};

// Re-places each frame of `flagged` (see above). A flagged frame that already matches the
// panorama about as well as the passed frames match each other (its NCC within
// kKeepNccMargin of theirs: the median over a few passed frames of each one's NCC against
// the panorama of the other passed frames) is kept without a search: one wrong frame raises
// the misfits of the frames it overlaps, which are then flagged with it.
//
// A searched frame's candidates are the search's peaks, its current pose and its pose in
// `start_frame_from_world` (where the solve that flagged it began: a frame that slid away
// during a solve was often started in the right basin), each refined against the panorama
// and ranked by NCC.
//
// When more than `max_searches` frames (>= 0; -1: no limit) would need a search, nothing is
// searched and the result is false with `error` saying so: the caller's other remedy (the
// pair graph) is then the cheaper one.
bool ReplaceFrames(const std::vector<Frame>& frames,
                   const std::vector<Eigen::Isometry3d>& frame_from_world,
                   const std::vector<Eigen::Isometry3d>& start_frame_from_world,
                   const std::vector<int>& flagged,
                   const PlacementSearchOptions& options,
                   int max_searches,
                   std::vector<Eigen::Isometry3d>* replaced,
                   std::vector<FrameReplacement>* records,
                   std::string* error);

}  // namespace dsr

#endif  // DSR_INIT_RECOVERY_H_
