// The pair check of the registration pipeline: do the frames agree with each other pair
// by pair at the final poses?
//
// The misfit check (pipeline/divergence_guard.h) compares each frame's misfit with the
// other frames'. It cannot see a registration whose frames split into two groups, each
// consistent inside but offset from the other (say 5 and 6 frames 10 mm apart): every
// frame's misfit rises alike. Nor one where most frames drifted. Pair by pair, such a
// result is plain: two frames of one group match each other to the noise, two frames of
// different groups do not.
//
// For every pair of frames whose fields of view overlap enough, the mismatch is 1 - the
// masked NCC of the two frames over their overlap at the poses (init/placement_search.h,
// ScorePlacement), on the coarse search level (smoothed: a well-registered pair scores
// close to 1 whatever the noise, a grossly misplaced one clearly lower). NCC is blind to a
// gain and an offset between frames, so the check means the same at any intensity scale.
// A pair disagrees when its mismatch exceeds max_ratio times the lower quartile of the
// mismatches (robust to up to three quarters of the pairs being off; never below
// kMinReferenceMismatch, so that noise-free data does not make every pair suspect).
//
// Measured on 200 registrations of simulated sequences (phantom and MNI, paper, walk and
// wide protocols, with and without masks): the largest ratio of a correct result was 3.6;
// the two wrong results that the misfit check passed had ratios of 10 and 19.
#ifndef DSR_PIPELINE_PAIR_CHECK_H_
#define DSR_PIPELINE_PAIR_CHECK_H_

#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "dsr/image/frame.h"

namespace dsr {

// Pairs whose overlap is below this fraction of both fields of view are not judged: a thin
// overlap lies along field-of-view edges, where the coarse level's smoothing differs
// between frames (with 0.1, a correct coarse-level result on a wide-protocol sequence was
// failed by a pair overlapping by 12%).
constexpr double kPairCheckMinOverlap = 0.25;
// Floor of the reference mismatch (1 - NCC of 0.998).
constexpr double kMinReferenceMismatch = 0.002;

struct PairMismatch {
  int first = 0;
  int second = 0;
  double overlap_fraction = 0.0;  // of the frame whose field of view it covers most
  double mismatch = 0.0;          // 1 - NCC over the overlap
};

// The judged pairs (overlap at least kPairCheckMinOverlap and a finite NCC), i < j.
// `frames` are on one pyramid level; poses map world to frame in mm. Deterministic.
std::vector<PairMismatch> PairMismatches(const std::vector<Frame>& frames,
                                         const std::vector<Eigen::Isometry3d>& frame_from_world,
                                         int num_threads);

// True when some pair disagrees (see above), with `why` naming the worst pair and
// `flagged` the frames to re-place, most disagreeing first: the frames outside the largest
// group of frames joined by agreeing pairs, and the frames that disagree with more of the
// frames they overlap than they agree with; when neither names a frame, both frames of the
// worst pair. Fewer than 3 judged pairs, or max_ratio 0, never report.
bool PairDisagreement(const std::vector<PairMismatch>& pairs,
                      int num_frames,
                      double max_ratio,
                      std::vector<int>* flagged,
                      std::string* why);

}  // namespace dsr

#endif  // DSR_PIPELINE_PAIR_CHECK_H_
