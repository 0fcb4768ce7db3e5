// What a registration returns: RegistrationResult (the final poses, whether they are usable
// and why not, the photometric parameters, the checks' statistics, the recoveries, the pose
// uncertainty) and LevelSolve, the record of one solve. Filled by Register
// (pipeline/registration.h) and, round by round, by CoarseToFine
// (pipeline/coarse_to_fine.h); read by the tools, the report (pipeline/report.h) and the
// experiments (pipeline/experiment.h).
#ifndef DSR_PIPELINE_REGISTRATION_RESULT_H_
#define DSR_PIPELINE_REGISTRATION_RESULT_H_

#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "dsr/geometry/volume.h"
#include "dsr/init/recovery.h"
#include "dsr/model/intensity_transform.h"
#include "dsr/model/photometric.h"
#include "dsr/pipeline/structure_check.h"
#include "dsr/pipeline/uncertainty.h"
#include "dsr/solve/solve_options.h"

namespace dsr {

// One solve of the pipeline.
struct LevelSolve {
  int level = 0;    // 0 = finest
  int rebuild = 0;  // 0 = first solve of the level
  Eigen::Vector3d panorama_spacing_mm = Eigen::Vector3d::Ones();
  int64_t candidate_voxels = 0;
  int64_t candidate_observations = 0;
  double max_motion_voxels = 0.0;  // largest field-of-view corner motion of this solve
  SolveReport report;
};

// Wall time of the checks of a registration (docs/design.md section 8), summed over its
// levels and rounds; part of RegistrationResult::seconds.
struct CheckSeconds {
  double structure = 0.0;      // the structure check (FrameStructures), every time it ran
  double determination = 0.0;  // the Gauss-Newton conditioning and the final poses' check
  double brightness = 0.0;     // photometric auto's estimates of gains and offsets
  double uncertainty = 0.0;    // the pose uncertainty (--uncertainty)
  double other = 0.0;          // the overlap guard, misfits, final candidates
  double total() const { return structure + determination + brightness + uncertainty + other; }
};

struct RegistrationResult {
  std::vector<Eigen::Isometry3d> frame_from_world;  // final poses, frame 0 = identity
  // With RegistrationOptions::photometric kAffine, the final gain and offset of every frame
  // (frame 0: 1 and 0; offsets in the input's intensity units): frame i's corrected
  // intensity gain * I_i + offset is on frame 0's scale, the convention of the poses file's
  // "gain" and "offset" (io/io_poses.h). Empty otherwise. When the registration is not
  // usable, the estimate at the poses it ended at (empty if no solve ran).
  std::vector<Photometric> photometric;
  std::vector<LevelSolve> solves;
  bool usable = false;        // every solve usable and the final cost finite
  // Per frame, RMS difference to the per-voxel mean at the final poses (FrameMisfits; of the
  // corrected intensities, on frame 0's scale, with photometric parameters).
  std::vector<double> frame_misfits;
  // Per frame, the structure statistics at the final poses (pipeline/structure_check.h;
  // corrected intensities with photometric parameters); empty when no final check ran.
  std::vector<FrameStructure> frame_structure;
  // Per frame, the determination check's predicted error at the final poses, in the frame's
  // voxels (UndeterminedPoses); empty when it did not run or could not judge.
  std::vector<double> pose_error_voxels;
  // With RegistrationOptions::detect_dropouts, per view the share of its field of view
  // left out as a dropout (0 where none was found); empty when detection was off. The masks
  // the registration used: the given ones less the dropouts (empty when none was found).
  std::vector<double> dropout_fraction;
  std::vector<Mask> masks_used;
  std::string failure;        // why not usable
  // Not usable because the data do not determine some pose (the determination check): no
  // start or recovery is tried (the photometric model's last resort is, judged by the same
  // check).
  bool poses_undetermined = false;
  // With RegistrationOptions::photometric kAuto: whether brightness differences were
  // detected (the solves then estimate gains and offsets), and a line saying which model the
  // solves used and why (empty when no detection ran).
  bool photometric_detected = false;
  std::string photometric_choice;
  // Chosen before the final poses (at the last coarse level, or after a first round without
  // gains and offsets failed), for the final poses to confirm; false once they have.
  // photometric_early_evidence: what chose them, as the choice's reason ends when the final
  // poses do not confirm it ("pyramid level 1's poses had put it at 8.6%").
  bool photometric_unconfirmed = false;
  std::string photometric_early_evidence;
  // Undecided, in a first round that failed at a coarse level: the gains and offsets
  // estimated at the poses it reached change at least half of the frames 1..m-1 by clearly
  // more than kBrightnessTolerance (CoarseToFine::SuspectBrightness; the pipeline then runs
  // the round with them before any recovery).
  bool brightness_suspected = false;
  double seconds = 0.0;       // wall time of the pipeline (pyramid + solves)
  double pyramid_seconds = 0.0;
  CheckSeconds check_seconds;
  int total_iterations = 0;
  // Frames the checks named when not usable (a wrong minimum, or slid out of the overlap),
  // and whether the misfit check named them.
  std::vector<int> flagged_frames;
  bool flagged_by_misfit = false;
  // The initialiser's run (InitialPoses other than kGiven), not counted above.
  double init_seconds = 0.0;
  int init_iterations = 0;
  std::vector<Eigen::Isometry3d> init_frame_from_world;
  // One record per recovery: why, after which level, the frames re-placed and their scores.
  struct Recovery {
    int after_level = 0;
    std::string why;
    // The flagged frames re-placed against the panorama of the others (empty when more
    // than a third were flagged), and whether every frame was then placed by the pair graph.
    std::vector<FrameReplacement> frames;
    bool global = false;
    // Every frame the misfit check flagged was kept without a search (it matches the
    // panorama of the others as well as they match each other): a frame whose content gives
    // it a high misfit, not a wrong minimum. Those frames are exempt from the misfit check
    // from here on, and the registration goes on from the same poses.
    bool misfit_accepted = false;
    double seconds = 0.0;  // the search (the solves that follow are counted above)
  };
  std::vector<Recovery> recoveries;
  // The final poses' uncertainty (uncertainty, a usable dsr or dba result);
  // covariance is empty when not estimated, with the reason in uncertainty_note.
  PoseUncertainty uncertainty;
  std::string uncertainty_note;
  // The intensity transform the solves registered (RegistrationOptions) and its constant
  // c (0 without).
  IntensityTransform intensity_transform = IntensityTransform::kNone;
  double intensity_transform_scale = 0.0;
  // The last solve's panorama grid in frame 0's world (where solves ran in the frames' mean
  // frame, one built at the final poses in frame 0's world by the same rule) and, for
  // --mode=dba, the last solve's optimised intensities (0 at voxels that are not
  // candidates; empty for other modes) on that solve's grid placed in frame 0's world by
  // frame 0's pose after it: `grid` itself with frame 0 held, turned and shifted by frame
  // 0's last motion in the mean gauge (dba_intensities.geometry).
  ImageGeometry grid;
  Image dba_intensities;
  // With views of T > 1 phases, DBA's intensities of phases 1..T-1 on the same grid.
  std::vector<Image> dba_later_phases;
};

}  // namespace dsr

#endif  // DSR_PIPELINE_REGISTRATION_RESULT_H_
