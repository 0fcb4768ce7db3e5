// The vocabulary of a registration's settings: RegistrationOptions, the enums and constants
// its fields take (where the registration starts, which photometric model the solves
// estimate), and RegistrationOptions::Validate, which refuses a setting by its field path
// (util/option_fields.h). Flag-free: the tools parse their flags into these fields. The
// pipeline that takes them is pipeline/registration.h; what it returns is
// pipeline/registration_result.h.
#ifndef DSR_PIPELINE_REGISTRATION_OPTIONS_H_
#define DSR_PIPELINE_REGISTRATION_OPTIONS_H_

#include <cstdint>
#include <string>

#include "dsr/init/placement_search.h"
#include "dsr/model/intensity_transform.h"
#include "dsr/model/panorama.h"
#include "dsr/model/robust_loss.h"
#include "dsr/pipeline/modes.h"
#include "dsr/solve/gauge.h"
#include "dsr/solve/solve_options.h"

namespace dsr {

// Where the registration starts (before any recovery).
enum class InitialPoses {
  kGiven,     // the poses passed to Register (e.g. identity, or a file)
  kPairwise,  // the pairwise baseline's poses from the given ones: the paper's initialiser
  kGlobal,    // the pair graph of init/pair_graph.h: every pair searched globally, placed
              // along a maximum-confidence spanning tree, refined by a robust pose graph
};

// Which photometric model the solves of modes dsr and dba estimate (docs/design.md section
// 2.8): none, or per frame a gain and an offset (frame i observes the panorama as
// exp(log_gain_i) I_i + offset_i; frame 0 the gauge, 1 and 0).
// kAuto: none, unless brightness differs between the frames; then affine (docs/design.md
// 2.8). Detected three ways: at the final poses of the first round that passes every check
// (the gains and offsets estimated there change some frame's intensities by more than
// kBrightnessTolerance; one more round with them follows from those poses, unless the last
// coarse level found them clearly over it and the finest level estimated them, which the
// final poses confirm or, finding none, undo by one more round without); at a level where
// the structure check flags frames that the estimated gains and offsets line up (affine from
// that level on); and, when the registration fails without them, once more with them from
// the same start. RegistrationResult::photometric_choice says which model, and why.
enum class PhotometricModel {
  kNone,
  kAffine,
  kAuto,
};

// The tools' --photometric default (dsr_register, dsr_compare). Note: the one place to
// change it; with kAffine the tools fall back to kNone for the baseline modes unless
// --photometric is given explicitly (then a baseline mode is refused). None: on data
// without brightness changes affine is not as accurate and far slower (its extra freedom
// lets coarse solves slide, and recoveries follow; docs/accuracy_us.md).
constexpr PhotometricModel kDefaultPhotometricModel = PhotometricModel::kAuto;

// "none" / "affine" / "auto" (the tools' --photometric values).
constexpr const char* PhotometricModelToString(PhotometricModel model) {
  return model == PhotometricModel::kAffine ? "affine"
         : model == PhotometricModel::kAuto ? "auto"
                                             : "none";
}
// A frame's brightness differs from frame 0's when its estimated correction g I + o changes
// its intensities by more than this fraction of their spread (the larger change at its mean
// minus and plus one standard deviation). On sequences without brightness changes the
// estimates at the coarsest level stay within a tenth of it (docs/design.md 2.8).
constexpr double kBrightnessTolerance = 0.03;
// The inverse of PhotometricModelToString; false (and *model untouched) for any other text.
bool StringToPhotometricModel(const std::string& name, PhotometricModel* model);
struct RegistrationOptions {
  // The solver of every level (pipeline/modes.h): the reduced problem (default), full
  // bundle adjustment, or a baseline of baselines/baselines.h.
  Mode mode = Mode::kDsr;
  // kPairwise runs the whole pipeline once with Mode::kPairwise from the given poses and
  // starts from its result.
  InitialPoses init = InitialPoses::kGiven;
  // Recovery (init/recovery.h): when the checks below flag frames after a level's solves,
  // those frames are re-placed by the global search against the panorama of the others (or,
  // when more than a third are flagged or that finds nothing better, every frame by the
  // pair graph, once) and the registration starts again from the coarsest level, at most
  // this many times
  // (0: a flagged frame ends the registration as not usable). With recovery on, the checks
  // also run after every coarse level, so that a wrong minimum is caught early and cheaply,
  // and a coarse level that did not settle (its last solve, every rebuild used, still moved
  // a frame by more than unsettled_motion_voxels, in the level's voxels, and by more than
  // rebuild_tolerance) is recovered at once (docs/design.md section 10).
  int max_recoveries = 0;
  double unsettled_motion_voxels = 1.0;
  // The global search of recovery and of InitialPoses::kGlobal. It runs on the coarsest
  // pyramid level, halved further until no axis of a frame is longer than
  // search_max_axis.
  PlacementSearchOptions search;
  int search_max_axis = 32;
  SolveOptions solve;             // per solve; max_iterations is the finest level's limit
  double panorama_spacing = 1.0;  // multiple of frame 0's spacing (at every level)
  // Where the solves' panorama grids sample frame 0 (model/panorama.h): half a voxel off
  // its lattice (default), or at every sub-voxel phase (for texture the frames share, such
  // as ultrasound speckle; docs/accuracy_us.md). Fusion's grid is not affected. With every
  // phase, DSR's and DBA's solves in the mean gauge build their grids on the frames' mean
  // frame, no frame's lattice (docs/design.md 4.8).
  PanoramaSampling panorama_sampling = PanoramaSampling::kHalfVoxel;
  // The pose gauge of the DSR and DBA solves (solve/gauge.h; docs/design.md 4.8), one for
  // both so that they minimise one function: every pose free with a prior on their mean
  // (default; with kAllPhases sampling each solve's grid is then built on the frames' mean
  // frame); or frame 0 constant. The other modes hold frame 0 constant whatever it says.
  // The poses of every level are relative to frame 0's in either.
  Gauge gauge = Gauge::kMean;

  // Pyramid (image/pyramid.h). Level 0 is the input resolution.
  int pyramid_levels = 3;
  double pyramid_sigma = 1.0;   // smoothing before each halving
  double smoothing = 0.0;    // smoothing of the finest level itself
  int pyramid_min_size = 12;           // no level with an axis shorter than this
  // Iteration limit of each solve on the coarser levels (the finest uses solve.max_iterations).
  int coarse_max_iterations = 50;

  // Candidate rebuilds per level (outer loop) and when to stop them.
  int max_rebuilds = 4;
  double rebuild_tolerance = 0.05;

  // Frames must share at least this many candidate voxels along a spanning tree.
  int64_t min_shared_voxels = 64;
  // Divergence guard (pipeline/divergence_guard.h): the registration is not usable when a
  // frame's overlap chain to frame 0 thins below this fraction of its value at the initial
  // poses (the frame slid out of the overlap). Checked at every candidate rebuild and at
  // the final poses. 0 turns the guard off.
  double min_kept_overlap = 0.25;
  // Structure check of the poses after every checked level (pipeline/structure_check.h;
  // docs/design.md 8.4): the registration is not usable when more than this fraction of a
  // frame's own structure (its samples' covariance at a lag beyond noise and interpolation)
  // remains in its differences to the per-voxel mean, and stands out of what noise alone
  // gives (a frame, or a group of frames, in a wrong minimum). In [0, 1); 0 turns it off.
  // Correct registrations of three sources leave at most 0.7 %, wrong minima 8-177 %.
  double max_structure_fraction = 0.05;
  // Two former checks, ratios to the other frames' (pairs') lower quartile, off by default:
  // on sources with large uniform regions the quartile says nothing about misregistration,
  // and they refused correct results (docs/design.md 8.5). Misfit: a frame's RMS difference
  // to the per-voxel mean above this multiple of the frames' lower quartile. Pair: two
  // overlapping frames' 1 - NCC (search level) above this multiple of the pairs' lower
  // quartile. 0 (off) or > 1.
  double max_misfit_ratio = 0.0;
  double max_pair_mismatch_ratio = 0.0;
  // Determination check of the final poses (pipeline/uncertainty.h, UndeterminedPoses;
  // docs/design.md 8.7; modes dsr and dba, without photometric parameters or a robust
  // loss, which its noise model does not have): the registration is not usable when the
  // data leave some frame's pose undetermined, i.e. the cost does not curve up along some
  // motion of it, or the error the image noise alone puts on it (one standard deviation,
  // RMS over its field of view) exceeds this many of its voxels (symmetric anatomy). >= 0;
  // 0 turns it off. Correct registrations of three sources predict 0.01-0.1 voxel.
  double max_pose_error_voxels = 1.0;

  // Dropouts (geometry/lost_signal.h; docs/design.md 2.10): in each view whose field of
  // view is an ultrasound sector, the beams along which only noise remains (contact lost)
  // are left out of its mask before anything else, in every mode; the result names the
  // share of each view left out (RegistrationResult::dropout_fraction). Off by default: a
  // view alone cannot tell lost contact from tissue that returns nothing, and on small views
  // of dark-background data leaving such beams out costs more than it gains (the tools'
  // --preset=echo turns it on).
  bool detect_dropouts = false;

  // Pose covariance and predicted TRE of the final poses (pipeline/uncertainty.h; modes dsr
  // and dba only, whose estimate it is; Validate refuses it for the baselines, naming
  // uncertainty): one cost pass over the finest level, one for the gradient's covariance and
  // one of 6 extra samples per observation for its derivative. Off by default (its cost).
  bool uncertainty = false;

  // Photometric parameters (modes dsr and dba only; Validate refuses kAffine for the
  // baselines, naming photometric). With kAffine every solve estimates a gain and an
  // offset per frame (DsrOptions/DbaOptions::photometric). They do not depend on the
  // resolution (the pyramid's normalised smoothing maps a I + b to a I_s + b), so each
  // solve starts from the previous solve's estimate, across candidate rebuilds and pyramid
  // levels (a skipped level reverts them with the poses); a recovery, which starts again
  // from the coarsest level with frames re-placed, starts them again at 1 and 0 (the
  // flagged frames' estimates came from a wrong minimum). The misfit check then measures
  // corrected intensities, and the pose uncertainty is not estimated (it does not model the
  // parameters; RegistrationResult::uncertainty_note says so). The library default is
  // kNone; the tools' is kDefaultPhotometricModel.
  PhotometricModel photometric = PhotometricModel::kNone;

  // The intensities the solves register (model/intensity_transform.h; docs/design.md
  // section 2.9): the input's (kNone, default), or T(I) = sqrt(c I) for linear-envelope
  // ultrasound, whose speckle multiplies the intensity (a variance-stabilising transform;
  // it needs intensities >= 0 inside the masks). The solves, the misfit check and the
  // uncertainty then work on T(I): the solves' costs, loss.scale and
  // uncertainty.noise_sigma are on T's scale; the search level (global search, recovery,
  // pair check) stays on the input's intensities. The result's photometric parameters, misfits
  // and DBA intensities are on the input's grey levels: with photometric kAffine the gains
  // and offsets are estimated again on the input's intensities at the final poses
  // (SolvePhotometricAtPoses), which is what fusion needs; T keeps a gain a gain but not an
  // offset an offset, so the solves' own model of offsets is an approximation.
  IntensityTransform intensity_transform = IntensityTransform::kNone;

  // The loss of the intensity differences (modes dsr and dba; model/robust_loss.h):
  // squared (default), or huber / cauchy with a scale in the input's grey levels, for
  // outliers such as shadows and reverberation. DBA applies it through Ceres; DSR by
  // iteratively reweighted solves (docs/design.md 4.7). The pose uncertainty is then not
  // estimated (a note says so).
  RobustLoss loss;

  // Mode-specific (the rest of DsrOptions and DbaOptions comes from the fields above).
  struct DsrSettings {
    int num_chunks = 1;           // streamed residual blocks (DSR's fast path, and APE's)
    bool reference_cost = false;  // the per-voxel reference cost instead of the fast path
  };
  struct DbaSettings {
    double memory_budget_mb = 0.0;  // MiB; <= 0: half the machine's RAM
  };
  DsrSettings dsr;
  DbaSettings dba;

  bool Validate(std::string* error) const;
};

}  // namespace dsr

#endif  // DSR_PIPELINE_REGISTRATION_OPTIONS_H_
