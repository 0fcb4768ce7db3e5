// Global initial poses from a pair graph (docs/design.md section 9, "Global
// initialisation"), for frames in any order and with no starting poses:
//
//   1. pairs (i, k) are searched globally (init/placement_search.h): the best placement
//      Z_ki = frame_k_from_frame_i and its score, the masked NCC of the pair's overlap;
//      each frame with its two next frames in the given order first, then every pair of
//      a frame whose best pair is weak or missing (frames in any order find partners);
//   2. the frames are placed along the maximum-NCC spanning tree of the pair graph from
//      frame 0 (the most trusted pair results, not a chain in index order);
//   3. every pair whose placement agrees with the tree's (within a few search voxels and
//      rotation-grid spacings) enters a pose graph, solved robustly (Cauchy loss, Ceres,
//      baselines' SolvePoseGraph); the other pairs are rejected as outliers.
// The result is a start for the coarse-to-fine registration, not a registration.
#ifndef DSR_INIT_PAIR_GRAPH_H_
#define DSR_INIT_PAIR_GRAPH_H_

#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "dsr/image/frame.h"
#include "dsr/init/placement_search.h"

namespace dsr {

struct PairEdge {
  int i = 0, k = 0;  // i < k
  Eigen::Isometry3d k_from_i = Eigen::Isometry3d::Identity();
  double ncc = 0.0;  // -inf: the pair does not overlap enough at any placement
  double overlap_fraction = 0.0;
  bool in_tree = false;
  bool inlier = false;  // entered the pose graph
};

struct PairGraphReport {
  std::vector<PairEdge> edges;
  double seconds = 0.0;
};

// Poses (world = frame 0, frame 0 = identity) for `frames` (one coarse pyramid level of
// every frame). Returns false with `error` naming a frame that no searched pair connects.
bool GlobalInitialPoses(const std::vector<Frame>& frames,
                        const PlacementSearchOptions& options,
                        std::vector<Eigen::Isometry3d>* frame_from_world,
                        PairGraphReport* report,
                        std::string* error);

}  // namespace dsr

#endif  // DSR_INIT_PAIR_GRAPH_H_
