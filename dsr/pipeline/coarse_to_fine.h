// One round of the registration: the coarse-to-fine solves from given poses, with their
// checks (pipeline/registration.h has the whole pipeline and the recovery between rounds;
// pipeline/registration_options.h its options).
//
//   for each pyramid level, coarsest first:
//     BuildLevelFrames     the level's frames; a level where a frame has no valid cell is
//                          skipped (an error at the finest)
//     SolveLevel           repeat at most max_rebuilds + 1 times:
//       BuildLevelProblem    the solve's world (mean gauge with every phase sampled: the
//                            frames' mean frame),
//                            panorama grid and candidates at the current poses, the
//                            divergence guard, the overlap's connectivity, and (once) that
//                            the overlap determines every pose
//       SolveOnce            the mode's solver (pipeline/modes.h) with the candidates fixed
//                          until a solve moves no field-of-view corner by more than
//                          rebuild_tolerance
//     CheckCoarseLevel     (with check_every_level) misfit, pair and settling checks
//   CheckFinalPoses        the guard, misfit and pair checks of the final poses, and the
//                          pose uncertainty
// A check that fails ends the round as not usable, naming the frames it flagged, so that
// the pipeline can recover them.
#ifndef DSR_PIPELINE_COARSE_TO_FINE_H_
#define DSR_PIPELINE_COARSE_TO_FINE_H_

#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "dsr/geometry/volume.h"
#include "dsr/image/frame.h"
#include "dsr/image/pyramid.h"
#include "dsr/model/observation.h"
#include "dsr/model/photometric.h"
#include "dsr/pipeline/divergence_guard.h"
#include "dsr/pipeline/modes.h"
#include "dsr/pipeline/registration_options.h"
#include "dsr/pipeline/registration_result.h"
#include "dsr/pipeline/uncertainty.h"
#include "dsr/stream/voxel_stream.h"

namespace dsr {

// The pyramids of every frame, finest level first (level 0 empty: the input itself).
// Every level of every frame is in the frame's local coordinates: its physical
// coordinates minus centre[i], the centre of its input grid (LocalCentre), so that the
// solves' Jacobians, [I, -[p]x] at the sampled points p, and their conditioning do not
// depend on where the images' origins lie (docs/design.md 1.2).
// A cardiac sequence's later phases (docs/design.md section 12) at the coarse levels are
// freed once a round has passed the level (ReleaseLaterPhaseLevel): at the finest level
// only the inputs' own phases stay in memory. A round that comes back to the coarse levels
// (a recovery) builds them again, the same voxels (BuildLaterPhaseLevels).
struct Pyramids {
  std::vector<std::vector<ImageLevel>> levels;  // [frame][level]
  int num_levels = 0;                           // common to every frame
  std::vector<Eigen::Vector3d> centre;          // per frame, physical mm
};

// The centre of a grid in its physical coordinates, o + D S (n - 1) / 2.
Eigen::Vector3d LocalCentre(const ImageGeometry& geometry);

// The pyramids of `images` for options' levels and smoothing; with `later_phases` (views of
// T > 1 phases, [view][phase - 1]; null or empty: 3D), every level also holds each later
// phase's image (ImageLevel::later_phases).
Pyramids BuildPyramids(const std::vector<Image>& images,
                       const std::vector<Mask>& masks,
                       const RegistrationOptions& options,
                       const std::vector<std::vector<Image>>* later_phases = nullptr);

// Builds levels first_level.. of every view's later phases anew (those of `later_phases`,
// [view][phase - 1]; none: nothing), in the levels' local coordinates, replacing what the
// levels held.
void BuildLaterPhaseLevels(const std::vector<std::vector<Image>>* later_phases,
                           const std::vector<Mask>& masks,
                           const RegistrationOptions& options,
                           int first_level,
                           Pyramids* pyramids);

// Frees every view's later phases at `level`.
void ReleaseLaterPhaseLevel(int level, Pyramids* pyramids);

// The frames the global search works on: the coarsest pyramid level, halved further until
// no axis is longer than options.search_max_axis.
std::vector<Frame> SearchFrames(const std::vector<Image>& images,
                                const std::vector<Mask>& masks,
                                const Pyramids& pyramids,
                                const RegistrationOptions& options);

class CoarseToFine {
 public:
  // With `check_every_level`, the checks also run after each coarse level; frames marked
  // in `misfit_exempt` are never the misfit check's outlier; `search_frames` are the pair
  // check's. `later_phases` (null or empty: 3D views) are the views' later phases
  // ([view][phase - 1], docs/design.md section 12): the levels' frames then hold every
  // phase, and every solve and check that streams the cost sums them (the search frames are
  // phase 0's). Everything passed must outlive the object.
  CoarseToFine(const std::vector<Image>& images,
               const std::vector<std::vector<Image>>* later_phases,
               const std::vector<Mask>& masks,
               const RegistrationOptions& options,
               bool check_every_level,
               const std::vector<bool>& misfit_exempt,
               const std::vector<Frame>& search_frames,
               Pyramids* pyramids);

  // Runs the round from `start_poses` (frame 0 = identity). With photometric parameters
  // they start at gain 1 and offset 0, each solve from the previous one's estimate, and end
  // in result->photometric. Returns false for bad input or set-up problems; a round that is
  // not usable returns true with result->usable = false, result->failure and
  // result->flagged_frames. Solves are appended to result->solves.
  bool Run(const std::vector<Eigen::Isometry3d>& start_poses,
           RegistrationResult* result,
           std::string* error);

 private:
  // What a step tells the level loop.
  enum class Next {
    kGoOn,       // the step passed
    kSkipLevel,  // skip this level: the next starts from the poses this one started from
    kEnd,        // the round ended as not usable (result->failure says why)
    kError,      // bad input or a set-up problem (*error says why)
  };

  Next BuildLevelFrames(int level, std::vector<Frame>* frames);
  Next SolveLevel(int level, const std::vector<Frame>& frames);
  Next BuildLevelProblem(int level,
                         int rebuild,
                         const std::vector<Frame>& frames,
                         LevelSolve* record,
                         CandidateSet* candidates,
                         ImageGeometry* grid);
  // BuildLevelProblem's checks of the level problem at `poses` (in its world), which end
  // the round (after `last_level`'s solves), skip the level, or refuse the input:
  // the divergence guard on the candidates' overlap (with recovery, naming the frames the
  // misfit and structure checks flag too);
  Next GuardLevelOverlap(int last_level,
                         const std::vector<Frame>& frames,
                         const Eigen::MatrixXi& overlap,
                         const ImageGeometry& grid,
                         const CandidateSet& candidates,
                         const std::vector<Eigen::Isometry3d>& poses);
  // the overlap's connectivity along a spanning tree (min_shared_voxels);
  Next CheckLevelConnected(int level, int last_level, const Eigen::MatrixXi& overlap);
  // once per round, at a level's first solve, that the overlap determines every pose;
  Next CheckLevelDetermined(int level,
                            const std::vector<Frame>& frames,
                            const CandidateSet& candidates,
                            const std::vector<Eigen::Isometry3d>& poses);
  // at a level's first solve after a coarser level's structure check could not judge some
  // frame, the structure check of the poses the level starts from.
  Next JudgeLevelStart(int level,
                       int last_level,
                       const std::vector<Frame>& frames,
                       const CandidateSet& candidates,
                       const std::vector<Eigen::Isometry3d>& poses);
  Next SolveOnce(int level,
                 const std::vector<Frame>& frames,
                 const ImageGeometry& grid,
                 CandidateSet candidates,
                 LevelSolve record);
  // With photometric kAuto, once (the first round whose final poses pass every check):
  // estimates every frame's gain and offset at the final poses and records in the result
  // whether some frame's brightness differs from frame 0's (kBrightnessTolerance); the
  // pipeline then registers again with affine from there (RegisterScaled), and every later
  // round follows the choice.
  void DetectBrightness(const std::vector<Frame>& frames);
  // With photometric kAuto, undecided, when the structure check flags frames at a level:
  // true (and the solves estimate gains and offsets from here on, recorded in the result)
  // when every frame lines up once the gains and offsets estimated at these poses correct
  // it; false when the structure stands (a wrong minimum) or the choice is made.
  bool StructureExplainedByBrightness(int level,
                                      const std::vector<Frame>& frames,
                                      const CandidateSet& candidates);
  // With photometric kAuto, undecided, at the last coarse level (1) once its checks pass
  // (where recovery is on; else after its solves):
  // where the gains and offsets estimated at its poses change some frame's intensities by
  // more than kBrightnessTolerance plus kBrightnessPrecision standard errors, the finest
  // level estimates them (recorded in the result, and the determination check still judges
  // its poses); otherwise the final poses decide (DetectBrightness).
  void DetectBrightnessEarly(int level, const std::vector<Frame>& frames);
  // After an early choice (DetectBrightnessEarly's, or the pipeline's after a first round
  // without gains and offsets failed at a coarse level), at the final poses:
  // DetectBrightness's estimate there confirms it, or finds no change over
  // kBrightnessTolerance; then the result says none, and the pipeline registers again
  // without them from there (RunRounds).
  void ConfirmBrightness(const std::vector<Frame>& frames);
  // The gains and offsets that best explain `frames` at SolvePoses() (an every-phase grid),
  // and the largest change they make to a frame's intensities (over its spread), its frame
  // and its standard error; in `frame_changes` (when given) every frame's largest change
  // and its standard error (frame 0: 0). With `refine`, more rows of the grid where the
  // change is not clearly on one side of kBrightnessTolerance. False when no estimate could
  // be made.
  bool EstimateBrightness(const std::vector<Frame>& frames,
                          std::vector<Photometric>* photometric,
                          double* largest_change,
                          int* worst,
                          double* standard_error = nullptr,
                          bool refine = true,
                          std::vector<std::pair<double, double>>* frame_changes = nullptr);
  // With photometric kAuto, undecided, after the first round ended not usable at a coarse
  // level (before any recovery):
  // result->brightness_suspected where the gains and offsets estimated at the poses reached
  // change at least half of the frames 1..m-1 by more than kBrightnessTolerance plus
  // kBrightnessPrecision standard errors (DetectBrightnessEarly's rule, frame by frame).
  void SuspectBrightness(const std::vector<Frame>& frames);
  bool AutoPhotometricUndecided() const;
  void UseAffine();
  Next CheckCoarseLevel(int level, const std::vector<Frame>& frames);
  Next CheckFinalPoses(const std::vector<Frame>& frames);
  // CheckFinalPoses's candidates at the final `poses` (in the last problem's world): the
  // last solve's, or built anew when it moved the frames by more than rebuild_tolerance.
  Next FinalCandidates(const std::vector<Frame>& frames,
                       const std::vector<Eigen::Isometry3d>& poses,
                       CandidateSet* candidates);
  // At the final poses, where phase 0 passed the structure check: each later phase's
  // structure check against the other frames' same phase; a phase out of line is refused
  // naming the phase (no frame to re-place).
  Next CheckLaterPhases(const std::vector<Frame>& frames,
                        const CandidateSet& candidates,
                        const std::vector<Eigen::Isometry3d>& poses);
  // CheckFinalPoses's determination check (modes dsr and dba with the squared loss), on
  // `all_sums` when given (the pose uncertainty's sums over all the candidates), on the
  // corrected frames where gains and offsets are estimated.
  Next CheckFinalDetermination(const std::vector<Frame>& frames,
                               const CandidateSet& candidates,
                               const std::vector<Eigen::Isometry3d>& poses,
                               const UncertaintySums* all_sums);
  // Whether the pose uncertainty is estimated at the final poses (--uncertainty, modes dsr
  // and dba, without photometric parameters or a robust loss: its noise model has neither).
  bool EstimatesUncertainty() const;
  // The pose uncertainty from the sums over the final candidates (null when not
  // estimated: the note says why).
  void EstimateUncertainty(const std::vector<Frame>& frames, const UncertaintySums* sums);
  // Ends the round as not usable after the solves of `level`, naming `flagged`.
  Next Diverged(int level, const std::string& why, std::vector<int> flagged);
  // The result's grid, in frame 0's world, from the finest level's last solve grid: that
  // grid itself, or where solves ran in the mean frame one built on frame 0's lattice at
  // poses_ (should the grid be too large there, the solve's grid placed in frame 0's world).
  ImageGeometry OutputGrid(const std::vector<Frame>& frames, const ImageGeometry& solve_grid) const;
  // poses_ in the world of the current level problem: poses_[i] * solve_world_.
  std::vector<Eigen::Isometry3d> SolvePoses() const;

  const std::vector<Image>& images_;
  const std::vector<std::vector<Image>>* later_phases_;
  const std::vector<Mask>& masks_;
  const RegistrationOptions& options_;
  const StreamContext stream_;  // options_.solve's threads and kernels
  const bool check_every_level_;
  const std::vector<bool>& misfit_exempt_;
  const std::vector<Frame>& search_frames_;
  Pyramids* pyramids_;
  // The mode's solver, and whether it estimates gains and offsets (photometric kAffine, or
  // kAuto once brightness differences are detected: DetectBrightness).
  LevelSolver solver_;
  const int m_;
  bool affine_;
  // DSR or DBA in the mean gauge with every phase sampled (PanoramaSampling::kAllPhases):
  // each level problem is built in the frames' mean frame, so that no frame's lattice is the
  // grid's (docs/design.md 4.8). With the half voxel the grid keeps frame 0's lattice.
  const bool mean_world_;

  // The round's state.
  RegistrationResult* result_ = nullptr;
  std::string* error_ = nullptr;
  std::vector<Eigen::Isometry3d> poses_;  // relative to frame 0's
  // The world the current level problem (grid, candidates, solve) is built in, as a map to
  // frame 0's coordinates: the identity, or in the mean gauge the frames' mean frame
  // (MeanFrame, solve/gauge.h) at the problem's start and, after a solve, where the solve
  // left it (frame 0 moves in that gauge). So no frame's axes and lattice are the grid's, as
  // no frame is held by the gauge. Every check with the problem's candidates evaluates
  // SolvePoses().
  Eigen::Isometry3d solve_world_ = Eigen::Isometry3d::Identity();
  // The current gains and offsets (empty: 1 and 0, or no photometric parameters). The
  // checks compare frames on frame 0's intensity scale through them (FrameMisfits).
  std::vector<Photometric> photometric_;
  DivergenceGuard guard_;
  bool determined_checked_ = false;
  // The last coarse level's structure check could not judge some frame (too smooth at its
  // lag): the next level judges the poses it starts from (BuildLevelProblem).
  bool unjudged_ = false;
  // The current level's solve options, and its last solve: candidates, how far it moved
  // the frames (largest, and per frame), whether any solve ran, and the rebuilds allowed.
  SolveOptions level_solve_;
  CandidateSet last_candidates_;
  double last_motion_ = 0.0;
  std::vector<double> last_frame_motion_;
  bool solved_ = false;
  int max_rebuilds_ = 0;
  std::vector<Eigen::Isometry3d> round_start_;  // the poses Run started from
};

}  // namespace dsr

#endif  // DSR_PIPELINE_COARSE_TO_FINE_H_
