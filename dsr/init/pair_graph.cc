#include "dsr/init/pair_graph.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>

#include <glog/logging.h>

#include "dsr/baselines/baselines.h"
#include "dsr/geometry/se3.h"
#include "dsr/init/rotation_grid.h"
#include "dsr/model/observation.h"
#include "dsr/util/clock.h"

namespace dsr {
namespace {

// An edge agrees with the tree's placement when their relative poses differ by less than
// this many search voxels in translation (at the frame's centre) and this many degrees.
constexpr double kInlierVoxels = 3.0;
constexpr double kInlierDegrees = 10.0;
// Pairs searched first: each frame with this many next frames in the given order.
constexpr int kIndexSpan = 2;
// A frame whose best pair NCC is this far below the frames' median has all its pairs searched.
constexpr double kWeakNccMargin = 0.05;

}  // namespace

bool GlobalInitialPoses(const std::vector<Frame>& frames,
                        const PlacementSearchOptions& options,
                        std::vector<Eigen::Isometry3d>* frame_from_world,
                        PairGraphReport* report,
                        std::string* error) {
  const auto start = std::chrono::steady_clock::now();
  const int m = static_cast<int>(frames.size());
  *report = PairGraphReport();
  PlacementSearchOptions pair_options = options;
  pair_options.rotations = options.pair_rotations;
  // 1. Pairs searched globally: first each frame with its kIndexSpan nearest frames in the
  // given order (consecutive acquisitions usually overlap most), then every other pair of
  // each frame whose best pair is weak (below the frames' median best NCC by
  // kWeakNccMargin) or missing, so that frames in any order still find their partners.
  std::vector<std::vector<bool>> searched(m, std::vector<bool>(m, false));
  const auto search = [&](int i, int k) {
    if (searched[i][k]) return;
    searched[i][k] = searched[k][i] = true;
    PairEdge edge;
    edge.i = i;
    edge.k = k;
    const std::vector<Placement> found =
        SearchPlacement(frames[i], frames[k], Eigen::Matrix3d::Identity(), {}, pair_options);
    edge.ncc = -std::numeric_limits<double>::infinity();
    if (!found.empty()) {
      edge.k_from_i = found.front().moving_from_fixed;
      edge.ncc = found.front().ncc;
      edge.overlap_fraction = found.front().overlap_fraction;
    }
    VLOG(1) << "pair " << i << "-" << k << ": NCC " << edge.ncc << ", overlap "
            << edge.overlap_fraction;
    report->edges.push_back(edge);
  };
  for (int i = 0; i < m; ++i) {
    for (int k = i + 1; k < std::min(m, i + 1 + kIndexSpan); ++k) search(i, k);
  }
  const auto best_ncc = [&]() {
    std::vector<double> best(m, -std::numeric_limits<double>::infinity());
    for (const PairEdge& e : report->edges) {
      best[e.i] = std::max(best[e.i], e.ncc);
      best[e.k] = std::max(best[e.k], e.ncc);
    }
    return best;
  };
  const std::vector<double> best = best_ncc();
  std::vector<double> sorted = best;
  std::sort(sorted.begin(), sorted.end());
  const double median = sorted[(m - 1) / 2];
  for (int f = 0; f < m; ++f) {
    if (std::isfinite(best[f]) && best[f] >= median - kWeakNccMargin) continue;
    for (int k = 0; k < m; ++k) {
      if (k != f) search(std::min(f, k), std::max(f, k));
    }
  }
  // 2. Maximum-NCC spanning tree from frame 0 (Prim), placing each frame as it joins.
  std::vector<Eigen::Isometry3d> poses(m, Eigen::Isometry3d::Identity());
  std::vector<bool> placed(m, false);
  placed[0] = true;
  for (int step = 1; step < m; ++step) {
    PairEdge* best = nullptr;
    for (PairEdge& e : report->edges) {
      if (placed[e.i] == placed[e.k] || !std::isfinite(e.ncc)) continue;
      if (best == nullptr || e.ncc > best->ncc) best = &e;
    }
    if (best == nullptr) {
      for (int f = 0; f < m; ++f) {
        if (placed[f]) continue;
        *error = "frame " + std::to_string(f) +
                 " overlaps no placed frame at any searched rotation (the global search "
                 "covers rotations within --search_rotation_deg of frame 0's)";
        return false;
      }
    }
    best->in_tree = true;
    // T_k = Z_ki T_i.
    if (placed[best->i]) {
      poses[best->k] = best->k_from_i * poses[best->i];
      placed[best->k] = true;
    } else {
      poses[best->i] = best->k_from_i.inverse() * poses[best->k];
      placed[best->i] = true;
    }
  }
  // 3. The pairs that agree with the tree, in a robust pose graph. Residuals are scaled to
  // search voxels and rotation-grid units, so the Cauchy scale 1 means "one voxel".
  const double voxel_mm = frames[0].geometry().spacing_mm.maxCoeff();
  Vector6d sqrt_information;
  sqrt_information << Eigen::Vector3d::Constant(1.0 / voxel_mm),
      Eigen::Vector3d::Constant(1.0 / (kInlierDegrees / 3.0 * M_PI / 180.0));
  std::vector<RelativePose> measurements;
  for (PairEdge& e : report->edges) {
    if (!std::isfinite(e.ncc)) continue;
    const Eigen::Isometry3d tree_k_from_i = poses[e.k] * poses[e.i].inverse();
    const Eigen::Vector3d centre = frames[e.i].geometry().IndexToPhysical(
        frames[e.i].ValidIndexBox().center());
    const double translation = (tree_k_from_i * centre - e.k_from_i * centre).norm();
    const double rotation =
        RotationAngleBetween(tree_k_from_i.linear(), e.k_from_i.linear()) * 180.0 / M_PI;
    e.inlier = e.in_tree ||
               (translation < kInlierVoxels * voxel_mm && rotation < kInlierDegrees);
    if (!e.inlier) continue;
    RelativePose z;
    z.i = e.i;
    z.k = e.k;
    z.k_from_i = e.k_from_i;
    z.sqrt_information = sqrt_information;
    measurements.push_back(z);
  }
  SolveOptions graph;
  graph.progress = false;
  SolveReport graph_report;
  std::vector<Eigen::Isometry3d> solved;
  if (!SolvePoseGraph(measurements, poses, graph, &solved, &graph_report, error,
                      /*cauchy_scale=*/1.0)) {
    return false;
  }
  *frame_from_world = graph_report.usable ? RelativeToFrame0(solved) : poses;
  report->seconds = SecondsSince(start);
  return true;
}

}  // namespace dsr
