// The divergence guard of the registration pipeline.
//
// A direct method minimises a sum of squared intensity differences over the overlap. A
// frame (or a group of frames) that slides out of the overlap takes its differences along,
// so the cost can fall while the registration fails: the solve ends "converged" with
// frames far off. The guard measures, for every frame, how well it stays tied to frame 0:
// the widest path to frame 0 in the overlap graph (the path whose thinnest pairwise
// overlap is largest), as a fraction of the frame's field of view. A registration whose
// poses bring this fraction below min_kept times its value at the initial poses has
// diverged. A group of frames that drifts off together (each still overlapping the
// others of the group) is caught too, since its path to frame 0 thins out.
//
// Not caught by the overlap: a frame stuck in a wrong local minimum that still overlaps the
// others (e.g. rotated by a large angle inside the same field of view). For that, the final
// poses are also checked by each frame's misfit against the others (MisfitOutlier).
#ifndef DSR_PIPELINE_DIVERGENCE_GUARD_H_
#define DSR_PIPELINE_DIVERGENCE_GUARD_H_

#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "dsr/image/frame.h"
#include "dsr/model/observation.h"
#include "dsr/model/photometric.h"
#include "dsr/stream/voxel_stream.h"

namespace dsr {

// For each frame i, the widest-path overlap between frame 0 and frame i in the overlap
// graph of `candidates` (CandidateOverlap), divided by frame i's field of view counted in
// panorama voxels (its valid cells times its cell volume over the panorama voxel volume),
// capped at 1. Frame 0 gets 1. A frame not connected to frame 0 gets 0.
std::vector<double> TiedFractions(const std::vector<Frame>& frames,
                                  const CandidateSet& candidates);
// The same on CandidateOverlap(candidates), given the panorama spacing.
std::vector<double> TiedFractions(const std::vector<Frame>& frames,
                                  const Eigen::MatrixXi& overlap,
                                  const Eigen::Vector3d& panorama_spacing_mm);

// For each frame, the root mean square of its differences to the per-voxel mean of the
// observations (the DSR residuals), over the candidate voxels that at least two frames
// observe at `frame_from_world`. 0 for a frame with no such voxel. Deterministic (for any
// thread count). With `photometric` (one per frame; empty: none) they are DSR's residuals
// with photometric parameters (docs/design.md section 2.8): the corrected observations
// c_i = gain_i I_i(p_ij) + offset_i against their mean, on frame 0's intensity scale.
std::vector<double> FrameMisfits(const std::vector<Frame>& frames,
                                 const CandidateSet& candidates,
                                 const std::vector<Eigen::Isometry3d>& frame_from_world,
                                 const StreamContext& context,
                                 const std::vector<Photometric>& photometric = {});
// The same from per-frame sums of squared residuals and their counts (a DSR pass's
// NormalEquations::frame_cost and frame_observations).
std::vector<double> MisfitsFromFrameCosts(const std::vector<double>& frame_cost,
                                          const std::vector<int64_t>& frame_observations);

// The lower quartile of `values` (non-empty): the element at rank (n - 1) / 4.
double LowerQuartile(const std::vector<double>& values);

// True (and `why` naming the worst frame) when some frame's misfit exceeds max_ratio times
// the lower quartile of the frames' misfits (robust to up to three quarters of the frames
// being off): that frame does not agree with the others, typically
// a wrong local minimum that still overlaps them (which the overlap guard below cannot
// see). max_ratio 0 never reports.
// Frames marked in `exempt` (when given; one entry per frame) are never the outlier; the
// lower quartile is still over every frame.
bool MisfitOutlier(const std::vector<double>& misfits, double max_ratio, std::string* why,
                   const std::vector<bool>* exempt = nullptr);
// Every frame whose misfit exceeds max_ratio times the lower quartile, worst first (empty
// when max_ratio is 0), except those marked in `exempt`: the frames recovery re-places
// (init/recovery.h).
std::vector<int> MisfitOutliers(const std::vector<double>& misfits, double max_ratio,
                                const std::vector<bool>* exempt = nullptr);

class DivergenceGuard {
 public:
  // min_kept in [0, 1); 0 never reports a divergence.
  explicit DivergenceGuard(double min_kept) : min_kept_(min_kept) {}

  // The first call records the fractions at the initial poses and returns false. Later
  // calls return true, with `why` naming the frame, when some frame's fraction (at the
  // poses `candidates` was built at) fell below min_kept times its initial value.
  // `slid`, when given, receives every such frame.
  bool Diverged(const std::vector<Frame>& frames, const CandidateSet& candidates,
                std::string* why, std::vector<int>* slid = nullptr);
  // The same on CandidateOverlap(candidates), given the panorama spacing.
  bool Diverged(const std::vector<Frame>& frames, const Eigen::MatrixXi& overlap,
                const Eigen::Vector3d& panorama_spacing_mm, std::string* why,
                std::vector<int>* slid = nullptr);

 private:
  double min_kept_;
  std::vector<double> initial_;
};

}  // namespace dsr

#endif  // DSR_PIPELINE_DIVERGENCE_GUARD_H_
