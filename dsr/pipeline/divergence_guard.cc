#include "dsr/pipeline/divergence_guard.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

#include <Eigen/Core>

#include "dsr/stream/reduced_system.h"
#include "dsr/stream/voxel_stream.h"

namespace dsr {

std::vector<double> TiedFractions(const std::vector<Frame>& frames,
                                  const CandidateSet& candidates) {
  return TiedFractions(frames, CandidateOverlap(candidates), candidates.grid.spacing_mm);
}

std::vector<double> TiedFractions(const std::vector<Frame>& frames,
                                  const Eigen::MatrixXi& overlap,
                                  const Eigen::Vector3d& panorama_spacing_mm) {
  const int m = static_cast<int>(frames.size());
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
  const double voxel_volume = panorama_spacing_mm.prod();
  std::vector<double> fraction(m, 0.0);
  fraction[0] = 1.0;
  for (int i = 1; i < m; ++i) {
    const double fov_voxels = static_cast<double>(frames[i].num_valid_cells()) *
                              frames[i].geometry().spacing_mm.prod() / voxel_volume;
    if (fov_voxels > 0.0) fraction[i] = std::min(1.0, width[i] / fov_voxels);
  }
  return fraction;
}

std::vector<double> FrameMisfits(const std::vector<Frame>& frames,
                                 const CandidateSet& candidates,
                                 const std::vector<Eigen::Isometry3d>& frame_from_world,
                                 const StreamContext& context,
                                 const std::vector<Photometric>& photometric) {
  NormalEquations system;
  if (photometric.empty()) {
    // One cost-only pass of the DSR stream, which splits the cost by frame.
    AccumulateReducedSystem(frames, candidates, frame_from_world, 0, candidates.num_voxels(),
                            /*with_jacobian=*/false, context, &system);
  } else {
    // The same pass with the photometric term: DSR's residuals of the corrected
    // observations (docs/design.md 2.8), each in its frame's own intensity units.
    CHECK_EQ(photometric.size(), frames.size());
    AccumulateReducedPhotometricSystem(frames, candidates, frame_from_world, photometric, 0,
                                       candidates.num_voxels(), /*with_jacobian=*/false,
                                       context, &system);
  }
  return MisfitsFromFrameCosts(system.frame_cost, system.frame_observations);
}

std::vector<double> MisfitsFromFrameCosts(const std::vector<double>& frame_cost,
                                          const std::vector<int64_t>& frame_observations) {
  CHECK_EQ(frame_cost.size(), frame_observations.size());
  std::vector<double> misfit(frame_cost.size(), 0.0);
  for (size_t i = 0; i < frame_cost.size(); ++i) {
    if (frame_observations[i] > 0) misfit[i] = std::sqrt(frame_cost[i] / frame_observations[i]);
  }
  return misfit;
}

// The misfits' reference is their lower quartile, so that up to three quarters of the
// frames may be off.
double LowerQuartile(const std::vector<double>& values) {
  std::vector<double> sorted = values;
  std::sort(sorted.begin(), sorted.end());
  return sorted[(sorted.size() - 1) / 4];
}

bool MisfitOutlier(const std::vector<double>& misfits, double max_ratio, std::string* why,
                   const std::vector<bool>* exempt) {
  const std::vector<int> outliers = MisfitOutliers(misfits, max_ratio, exempt);
  if (outliers.empty()) return false;
  const double reference = LowerQuartile(misfits);
  const int worst = outliers.front();
  std::ostringstream s;
  s.precision(3);
  s << "frame " << worst << " does not match the others at the final poses: its RMS "
    << "difference to the panorama is " << misfits[worst] << ", " << misfits[worst] / reference
    << " times the frames' lower quartile (" << reference << "; max_misfit_ratio="
    << max_ratio << "), a wrong local minimum; give better initial poses (init)";
  *why = s.str();
  return true;
}

std::vector<int> MisfitOutliers(const std::vector<double>& misfits, double max_ratio,
                                const std::vector<bool>* exempt) {
  std::vector<int> outliers;
  if (!(max_ratio > 0.0) || misfits.empty()) return outliers;
  const double reference = LowerQuartile(misfits);
  for (size_t i = 0; i < misfits.size(); ++i) {
    if (exempt != nullptr && (*exempt)[i]) continue;
    if (misfits[i] > max_ratio * reference) outliers.push_back(static_cast<int>(i));
  }
  std::stable_sort(outliers.begin(), outliers.end(),
                   [&](int a, int b) { return misfits[a] > misfits[b]; });
  return outliers;
}

bool DivergenceGuard::Diverged(const std::vector<Frame>& frames,
                               const CandidateSet& candidates,
                               std::string* why,
                               std::vector<int>* slid) {
  return Diverged(frames, CandidateOverlap(candidates), candidates.grid.spacing_mm, why, slid);
}

bool DivergenceGuard::Diverged(const std::vector<Frame>& frames,
                               const Eigen::MatrixXi& overlap,
                               const Eigen::Vector3d& panorama_spacing_mm,
                               std::string* why,
                               std::vector<int>* slid) {
  const std::vector<double> tied = TiedFractions(frames, overlap, panorama_spacing_mm);
  if (initial_.empty()) {
    initial_ = tied;
    return false;
  }
  const auto percent = [](double f) { return static_cast<int>(100.0 * f + 0.5); };
  bool diverged = false;
  for (size_t i = 1; i < tied.size(); ++i) {
    if (!(tied[i] < min_kept_ * initial_[i])) continue;
    if (slid != nullptr) slid->push_back(static_cast<int>(i));
    if (diverged) continue;  // `why` names the first such frame
    diverged = true;
    std::ostringstream s;
    s << "diverged: frame " << i << " slid out of the overlap (its best chain of overlapping "
      << "frames to frame 0 covers " << percent(tied[i]) << "% of its field of view, down "
      << "from " << percent(initial_[i]) << "% at the initial poses; min_kept_overlap="
      << min_kept_ << "); give better initial poses (init)";
    *why = s.str();
  }
  return diverged;
}

}  // namespace dsr
