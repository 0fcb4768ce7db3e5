#include "pipeline/divergence_guard.h"

#include <algorithm>
#include <limits>
#include <sstream>

#include <Eigen/Core>

namespace dsr {

std::vector<double> TiedFractions(const std::vector<Frame>& frames,
                                  const CandidateSet& candidates) {
  const int m = static_cast<int>(frames.size());
  const Eigen::MatrixXi overlap = CandidateOverlap(candidates);
  // Widest paths from frame 0 (Prim on the maximum spanning tree; m <= 32).
  std::vector<double> width(m, 0.0);
  std::vector<bool> done(m, false);
  width[0] = std::numeric_limits<double>::infinity();
  for (int step = 0; step < m; ++step) {
    int best = -1;
    for (int i = 0; i < m; ++i) {
      if (!done[i] && (best < 0 || width[i] > width[best])) best = i;
    }
    if (!(width[best] > 0.0)) break;  // the rest is not connected to frame 0
    done[best] = true;
    for (int i = 0; i < m; ++i) {
      if (!done[i]) width[i] = std::max(width[i], std::min<double>(width[best], overlap(best, i)));
    }
  }
  const double voxel_volume = candidates.grid.spacing_mm.prod();
  std::vector<double> fraction(m, 0.0);
  fraction[0] = 1.0;
  for (int i = 1; i < m; ++i) {
    const double fov_voxels = static_cast<double>(frames[i].num_valid_cells()) *
                              frames[i].geometry().spacing_mm.prod() / voxel_volume;
    if (fov_voxels > 0.0) fraction[i] = std::min(1.0, width[i] / fov_voxels);
  }
  return fraction;
}

bool DivergenceGuard::Diverged(const std::vector<Frame>& frames,
                               const CandidateSet& candidates,
                               std::string* why) {
  const std::vector<double> tied = TiedFractions(frames, candidates);
  if (initial_.empty()) {
    initial_ = tied;
    return false;
  }
  const auto percent = [](double f) { return static_cast<int>(100.0 * f + 0.5); };
  for (size_t i = 1; i < tied.size(); ++i) {
    if (!(tied[i] < min_kept_ * initial_[i])) continue;
    std::ostringstream s;
    s << "diverged: frame " << i << " slid out of the overlap (its best chain of overlapping "
      << "frames to frame 0 covers " << percent(tied[i]) << "% of its field of view, down "
      << "from " << percent(initial_[i]) << "% at the initial poses; --min_kept_overlap="
      << min_kept_ << "); give better initial poses with --init";
    *why = s.str();
    return true;
  }
  return false;
}

}  // namespace dsr
