// The structure check of the registration pipeline: does a frame's residual look like noise,
// or like anatomy that does not line up (docs/design.md section 8.4)?
//
// At the poses reached, frame i's DSR residuals r_ij = c_ij - mu_j (its corrected sample
// minus the per-voxel mean of the observations) hold two things: the noise of the
// observations, and whatever of the anatomy frame i and the others disagree on. Noise is
// independent between samples that share no frame voxel, anatomy is not: it is the same a
// few voxels further on. So the two separate by their covariance at a lag L beyond the
// interpolation's footprint (two samples L panorama voxels apart along the grid's x axis,
// L at least 2 sqrt 3 frame voxels, so that they read disjoint trilinear cells of every
// frame): over the pairs of voxels L apart that frame i observes (both with k >= 2),
//
//   residual structure  a_i = mean(r_ij r_ij') - mean(r_ij) mean(r_ij')   (0 for noise)
//   signal structure    b_i = mean(c_ij c_ij') - mean(c_ij) mean(c_ij')
//
// and the structure fraction s_i = a_i / b_i is the share of frame i's own lag-L structure
// that its residuals show: about 0 when it lines up with the others whatever the noise level
// or the content (both are covariances of the same frame's samples, so the intensity unit,
// the gain and the amount of flat or dark tissue cancel), and a sizeable fraction of
// (1 - 1/k)^2 2 (1 - rho(d)) for a frame displaced by d, rho the anatomy's autocorrelation.
// Both are centred: a residual that is the same everywhere is a brightness offset between
// frames, not anatomy out of line. For the same reason a_i is taken less the part that a
// brightness field explains, a gain of frame i that varies linearly over it (regressors
// mu [1, x, y, z] at the lag; a gain, or attenuation with depth).
// No noise level is estimated: the lag removes it. What remains at correct poses is the
// model's own error (trilinear resampling, brightness the photometric model does not have),
// a small fraction of the structure.
//
// The estimate has a sampling spread: with n lag pairs and residual variance v, a_i's
// standard error under noise alone is about v / sqrt(n). A frame is judged only where the
// signal structure itself stands out of its own spread (else the frame is too flat to say
// anything), and flagged only where a_i stands out of its spread too.
#ifndef DSR_PIPELINE_STRUCTURE_CHECK_H_
#define DSR_PIPELINE_STRUCTURE_CHECK_H_

#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "dsr/image/frame.h"
#include "dsr/model/observation.h"
#include "dsr/model/photometric.h"
#include "dsr/stream/voxel_stream.h"

namespace dsr {

// How far a residual's structure must stand out of its sampling spread (in standard errors)
// to count, and how far a frame's signal structure must stand out of its own to be judged:
// at 5, noise alone passes one frame in millions.
constexpr double kStructureSignificance = 5.0;

struct FrameStructure {
  int64_t pairs = 0;              // voxel pairs L apart that the frame observes (k >= 2 at both)
  double residual_lag = 0.0;      // a_i: covariance of r and r' over the pairs
  double residual_variance = 0.0; // variance of r over the pairs' voxels
  double signal_lag = 0.0;        // b_i: lag covariance of the frame's corrected samples
  double signal_variance = 0.0;   // variance of those samples
  // a_i / b_i, or 0 when the frame is not judged (too few pairs, or its signal structure
  // does not stand out of its spread).
  double fraction = 0.0;
  bool judged = false;
  // a_i in standard errors of noise alone, v / sqrt(n).
  double significance = 0.0;
  // RMS residual (the misfit, in the corrected intensities' unit).
  double rms() const { return std::sqrt(residual_variance); }
};

// The lag in panorama voxels along the grid's x axis: the smallest L with L times the
// panorama spacing at least 2 sqrt 3 times the largest frame spacing, and at least 2.
int StructureLagVoxels(const std::vector<Frame>& frames, const ImageGeometry& grid);

// About this many lag pairs per frame are all the check needs: a frame whose structure
// fraction sits at the limit (5 %) stands out by 5 standard errors with n pairs when its
// signal structure is at least 100 / sqrt(n) of its residual variance, 0.2 at 250,000. The
// paper's frames have 300,000-500,000 at the finest level, clinical frames 3.4 million.
constexpr double kStructurePairsPerFrame = 250000.0;

// Every frame's structure statistics at `frame_from_world` over `candidates` (see above),
// with `photometric` corrections (one per frame; empty: none); over 1 row in keep of the
// candidates' grid (CandidatesInRows) where they hold keep >= 2 times `pairs_per_frame`
// observations per frame (the significance counts the pairs it used; 0: every row).
// Deterministic for any thread count (fixed blocks; pairs that straddle a block boundary are
// not counted).
std::vector<FrameStructure> FrameStructures(const std::vector<Frame>& frames,
                                            const CandidateSet& candidates,
                                            const std::vector<Eigen::Isometry3d>& frame_from_world,
                                            const StreamContext& context,
                                            const std::vector<Photometric>& photometric = {},
                                            double pairs_per_frame = kStructurePairsPerFrame);

// The frames whose structure fraction exceeds max_fraction and stands out of its spread,
// worst first, except those marked in `exempt` (when given). max_fraction 0: none.
std::vector<int> StructureOutliers(const std::vector<FrameStructure>& structure,
                                   double max_fraction,
                                   const std::vector<bool>* exempt = nullptr);

// True, with `why` naming the worst frame and its figures, when StructureOutliers is not
// empty.
bool StructureOutlier(const std::vector<FrameStructure>& structure,
                      double max_fraction,
                      std::string* why,
                      const std::vector<bool>* exempt = nullptr);

// One line for the tools' summaries: the largest structure fraction over the judged frames,
// its frame and significance, and how many frames were too flat to judge; "" when none was
// measured.
std::string StructureSummary(const std::vector<FrameStructure>& structure);

}  // namespace dsr

#endif  // DSR_PIPELINE_STRUCTURE_CHECK_H_
