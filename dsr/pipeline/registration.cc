#include "dsr/pipeline/registration.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <optional>
#include <sstream>

#include <glog/logging.h>

#include "dsr/dsr_reduced/dsr_solver.h"
#include "dsr/geometry/lost_signal.h"
#include "dsr/image/pyramid.h"
#include "dsr/init/pair_graph.h"
#include "dsr/init/recovery.h"
#include "dsr/model/observation.h"
#include "dsr/model/panorama.h"
#include "dsr/pipeline/coarse_to_fine.h"
#include "dsr/pipeline/input_checks.h"
#include "dsr/util/clock.h"
#include "dsr/util/parallel.h"

namespace dsr {
namespace {

// Index of a frame whose field of view holds a single value (no image information), or -1.
int ConstantFrame(const std::vector<Image>& images, const std::vector<Mask>& masks) {
  for (size_t i = 0; i < images.size(); ++i) {
    float lo = std::numeric_limits<float>::max(), hi = std::numeric_limits<float>::lowest();
    for (size_t l = 0; l < images[i].voxels.size(); ++l) {
      if (masks[i].voxels[l] == 0) continue;
      lo = std::min(lo, images[i].voxels[l]);
      hi = std::max(hi, images[i].voxels[l]);
    }
    if (!(hi > lo)) return static_cast<int>(i);
  }
  return -1;
}

std::vector<std::string> InitialisationNames() {
  return {"auto", "identity", "pairwise", "global"};
}

}  // namespace

bool SetInitialisation(const std::string& name, int max_recoveries, RegistrationOptions* options) {
  options->init = name == "pairwise" ? InitialPoses::kPairwise
                  : name == "global" ? InitialPoses::kGlobal
                                     : InitialPoses::kGiven;
  options->max_recoveries = name == "identity" || name == "pairwise" ? 0 : max_recoveries;
  const std::vector<std::string> names = InitialisationNames();
  return std::find(names.begin(), names.end(), name) != names.end();
}

namespace {

// Recovery searches at most this many frames against the panorama of the others; beyond,
// the pair graph places every frame: one frame's search covers the whole panorama, so two
// or three of them already cost about what the pair graph of all frames costs.
constexpr int kMaxRePlacementSearches = 2;

// One registration as the steps below Register pass it on: what it registers, with which
// settings, and where its result and error go. A step that registers something else (the
// intensities scaled to a usual range, the pairwise initialiser's run, the photometric
// model's last resort) passes on a copy that points elsewhere.
struct RegistrationRun {
  // The intensities the solves register: the input's, or their transform
  // (RegistrationOptions::intensity_transform), brought to a usual scale further down.
  const std::vector<Image>* images = nullptr;
  // Views of T > 1 phases: phases 1..T-1 of each view, transformed and scaled as `images`
  // ([view][phase - 1]); null: 3D views (docs/design.md section 12).
  const std::vector<std::vector<Image>>* later_phases = nullptr;
  const std::vector<Mask>* masks = nullptr;
  const std::vector<Eigen::Isometry3d>* initial_frame_from_world = nullptr;
  const RegistrationOptions* options = nullptr;
  // What the search level is built from; null: `images` (with an intensity transform, the
  // input's intensities).
  const std::vector<Image>* search_images = nullptr;
  // When the registration started: its result's seconds count from here.
  std::chrono::steady_clock::time_point start;
  RegistrationResult* result = nullptr;
  std::string* error = nullptr;
};

bool RegisterScaled(const RegistrationRun& run);

// The pairwise initialiser (InitialPoses::kPairwise): the whole pipeline once with the
// pairwise baseline from the given poses, whose result becomes *start_poses. It registers
// the run's images as they are (already transformed and on a usual scale); its options are
// checked by Validate, since what it changes can break one of their rules (a robust loss,
// which a baseline refuses). Returns false for bad input; when its run is not usable, sets
// *ended and result->failure.
bool PairwiseStart(const RegistrationRun& run,
                   std::vector<Eigen::Isometry3d>* start_poses,
                   bool* ended) {
  const RegistrationOptions& options = *run.options;
  RegistrationOptions init_options = options;
  init_options.mode = Mode::kPairwise;
  init_options.init = InitialPoses::kGiven;
  init_options.max_recoveries = 0;
  init_options.photometric = PhotometricModel::kNone;  // a baseline's run
  init_options.uncertainty = false;                     // the final run's estimate only
  init_options.intensity_transform = IntensityTransform::kNone;  // `images` already are T(I)
  // The initial poses are judged by this run's own checks of its final poses.
  init_options.min_kept_overlap = 0.0;
  init_options.max_misfit_ratio = 0.0;
  init_options.max_pair_mismatch_ratio = 0.0;
  init_options.max_structure_fraction = 0.0;
  init_options.max_pose_error_voxels = 0.0;
  init_options.solve.linear_solver.reset();  // the mode's solver may be a Schur type
  init_options.solve.progress_prefix = options.solve.progress_prefix + "init ";
  RegistrationResult init;
  RegistrationRun init_run = run;
  init_run.options = &init_options;
  init_run.search_images = nullptr;  // no check of this run searches: no extra pyramids
  init_run.later_phases = nullptr;   // the baseline registers phase 0
  init_run.start = std::chrono::steady_clock::now();
  init_run.result = &init;
  if (!init_options.Validate(run.error) || !RegisterScaled(init_run)) {
    *run.error = "init=pairwise: " + *run.error;
    return false;
  }
  if (!init.usable) {
    run.result->failure = "init=pairwise: " + init.failure;
    *ended = true;
    return true;
  }
  *start_poses = init.frame_from_world;
  run.result->init_seconds = init.seconds;
  run.result->init_iterations = init.total_iterations;
  run.result->init_frame_from_world = *start_poses;
  return true;
}

// What recovery has used so far, across rounds.
struct RecoveryState {
  bool global_used = false;      // the pair graph (as --init=global or in a recovery)
  bool replaced_frames = false;  // flagged frames re-placed against the others
  std::vector<bool> misfit_exempt;
};

// One recovery after a round that ended not usable with flagged frames. With most frames
// passing, the flagged ones are re-placed against the panorama of the others; with more
// than a third flagged (or after that was tried) the panorama is not to be trusted, and
// every frame is placed from scratch by the pair graph (once). Returns true, with the next
// round's start in *poses, when a frame moved or its misfit was accepted; false when the
// failure stands.
bool Recover(const std::vector<Frame>& search_frames,
             const RegistrationOptions& options,
             RecoveryState* state,
             std::vector<Eigen::Isometry3d>* poses,
             RegistrationResult* result,
             std::string* error) {
  const int m = static_cast<int>(search_frames.size());
  const auto recovery_start = std::chrono::steady_clock::now();
  RegistrationResult::Recovery recovery;
  recovery.after_level = result->solves.empty() ? 0 : result->solves.back().level;
  recovery.why = result->failure;
  const bool most_passed = 3 * static_cast<int>(result->flagged_frames.size()) <= m;
  // Both remedies already used: the failure stands (no empty recovery record).
  if (!(most_passed && !state->replaced_frames) && state->global_used) return false;
  bool moved = false;
  std::vector<Eigen::Isometry3d> next;
  // Frames are re-placed against the others once; if the registration still fails, the
  // others were not to be trusted either.
  if (most_passed && !state->replaced_frames) {
    state->replaced_frames = true;
    std::string why;
    if (ReplaceFrames(search_frames, result->frame_from_world, *poses, result->flagged_frames,
                      options.search, kMaxRePlacementSearches, &next, &recovery.frames, &why)) {
      moved = std::any_of(recovery.frames.begin(), recovery.frames.end(),
                          [](const FrameReplacement& f) { return f.moved; });
      // Every frame the misfit check named matches the panorama of the others as well as
      // they match each other (kept without a search): its misfit comes from its content
      // (contrast, noise, what its field of view cuts), not from a wrong minimum. Go on
      // from the same poses without checking those frames' misfit. A frame kept after a
      // search found nothing better is no such evidence (its NCC is below the others'; the
      // panorama may be what misleads the search): the pair graph follows.
      const bool all_match =
          std::none_of(recovery.frames.begin(), recovery.frames.end(),
                       [](const FrameReplacement& f) { return f.moved || f.searched; });
      if (all_match && result->flagged_by_misfit) {
        for (int f : result->flagged_frames) state->misfit_exempt[f] = true;
        recovery.misfit_accepted = true;
      }
    } else {
      VLOG(1) << why;
    }
  }
  if (!moved && !recovery.misfit_accepted && !state->global_used) {
    state->global_used = true;
    recovery.global = true;
    PairGraphReport graph;
    if (!GlobalInitialPoses(search_frames, options.search, &next, &graph, error)) {
      LOG(INFO) << "recovery by the pair graph not possible: " << *error;
      error->clear();
    } else {
      moved = true;
    }
  }
  recovery.seconds = SecondsSince(recovery_start);
  const bool go_on = moved || recovery.misfit_accepted;
  result->recoveries.push_back(std::move(recovery));
  if (go_on) *poses = RelativeToFrame0(next);
  return go_on;
}

// Poses between the frames' physical coordinates and their local ones (Pyramids::centre,
// c_i): frame i's local coordinates are its physical ones minus c_i, the world's those of
// frame 0, so T_local = Translate(-c_i) T Translate(c_0).
std::vector<Eigen::Isometry3d> PosesToLocal(std::vector<Eigen::Isometry3d> frame_from_world,
                                            const std::vector<Eigen::Vector3d>& centre) {
  for (size_t i = 0; i < frame_from_world.size(); ++i) {
    frame_from_world[i] = Eigen::Translation3d(-centre[i]) * frame_from_world[i] *
                          Eigen::Translation3d(centre[0]);
  }
  return frame_from_world;
}
std::vector<Eigen::Isometry3d> PosesFromLocal(std::vector<Eigen::Isometry3d> frame_from_world,
                                              const std::vector<Eigen::Vector3d>& centre) {
  for (size_t i = 0; i < frame_from_world.size(); ++i) {
    frame_from_world[i] = Eigen::Translation3d(centre[i]) * frame_from_world[i] *
                          Eigen::Translation3d(-centre[0]);
  }
  return frame_from_world;
}

// A result of the solves in local coordinates, in the frames' physical ones: the final
// poses, the grid and DBA's intensities (world: + c_0), and the pose covariances. A left
// perturbation Exp(delta) of a local pose is Exp(Ad delta) of the physical one, Ad the adjoint of
// Translate(c_i): [rho; phi] -> [rho + c_i x phi; phi].
void ResultFromLocal(const std::vector<Eigen::Vector3d>& centre, RegistrationResult* result) {
  result->frame_from_world = PosesFromLocal(std::move(result->frame_from_world), centre);
  result->grid.origin_mm += centre[0];
  result->dba_intensities.geometry.origin_mm += centre[0];
  for (Image& phase : result->dba_later_phases) phase.geometry.origin_mm += centre[0];
  std::vector<Matrix6d>& covariance = result->uncertainty.covariance;
  for (size_t i = 0; i < covariance.size() && i < centre.size(); ++i) {
    Matrix6d adjoint = Matrix6d::Identity();
    adjoint.topRightCorner<3, 3>() = Hat(centre[i]);
    const Matrix6d moved = adjoint * covariance[i] * adjoint.transpose();
    covariance[i] = 0.5 * (moved + moved.transpose());  // exactly symmetric, as written
  }
}

// The coarse search level of the global search, recovery and the pair check (built before
// any solve releases the coarsest level; small). With an intensity transform, of the
// input's intensities: NCC ignores gains and offsets but not the transform, which weighs
// the dark tissue's noise more and put phantom pairs of the ultrasound-like protocol over
// the pair check's limit (docs/design.md 2.9).
std::vector<Frame> SearchLevel(const RegistrationRun& run, const Pyramids& pyramids) {
  const RegistrationOptions& options = *run.options;
  if (run.search_images == nullptr) {
    return SearchFrames(*run.images, *run.masks, pyramids, options);
  }
  return SearchFrames(*run.search_images, *run.masks,
                      BuildPyramids(*run.search_images, *run.masks, options), options);
}

// Photometric kAuto, undecided, after a first round without gains and offsets that failed
// at a coarse level where most frames' brightness clearly differs at the poses it reached
// (CoarseToFine::SuspectBrightness): frames of different brightness can slide, or settle
// nowhere, before any level lines them up (an ultrasound-like chest CT sequence: frame 1
// slid out of the overlap at the coarsest level). A recovery would keep the brightness
// that misled the solves and cost a search against the panorama or the pair graph (2-3 s
// there, then the whole registration again with gains and offsets: 2.6 times
// --preset=echo's time); the same round with them from the same start costs coarse solves
// where it fails too. The final poses judge whether they were needed
// (CoarseToFine::ConfirmBrightness).
bool TryGainsBeforeRecovery(const RegistrationOptions& options, const RegistrationResult& result) {
  return options.photometric == PhotometricModel::kAuto && options.max_recoveries > 0 &&
         result.brightness_suspected && result.photometric_choice.empty() &&
         result.photometric.empty();
}

// The result of a first round that failed without gains and offsets, as the next step
// finds it (the round with them that followed failed too): the recoveries go on from it,
// and the time and iterations of both rounds are counted.
void RestoreFailedRound(RegistrationResult failed, RegistrationResult* result) {
  failed.total_iterations = result->total_iterations;  // both counts run on over rounds
  failed.check_seconds = result->check_seconds;
  *result = std::move(failed);
}

// Rounds of coarse-to-fine solves from *poses (local coordinates), with a recovery between
// them, until one is usable or no recovery is left; the result of the last in *run.result.
bool RunRounds(const RegistrationRun& run,
               const std::vector<Frame>& search_frames,
               Pyramids* pyramids,
               RecoveryState* recovery,
               std::vector<Eigen::Isometry3d>* poses) {
  const RegistrationOptions& options = *run.options;
  RegistrationResult* result = run.result;
  bool affine_round = false;  // photometric kAuto: the round after brightness was detected
  bool plain_round = false;   // and after the final poses found none where a level had
  bool gains_round = false;   // and the first round once more with them (above)
  const std::vector<Eigen::Isometry3d> start = *poses;
  std::optional<RegistrationResult> failed_without_gains;  // until the gains round ends
  for (int round = 0;; ++round) {
    CoarseToFine levels(*run.images, run.later_phases, *run.masks, options,
                        options.max_recoveries > 0,
                        recovery->misfit_exempt, search_frames, pyramids);
    if (!levels.Run(*poses, result, run.error)) return false;
    if (round == 0 && !gains_round && TryGainsBeforeRecovery(options, *result)) {
      gains_round = true;
      failed_without_gains = *result;
      std::ostringstream choice;
      choice << "affine (photometric=auto: without gains and offsets the first round failed ("
             << result->failure << "), with them from the same start it did not; the limit is "
             << 100.0 * kBrightnessTolerance << "%)";
      result->photometric_choice = choice.str();
      result->photometric_early_evidence =
          "they had been tried since the first round without them failed";
      result->photometric_detected = true;  // the next round estimates them from its start
      result->photometric_unconfirmed = true;
      *poses = start;
      --round;
      continue;
    }
    if (failed_without_gains) {
      // With gains and offsets the round failed as well: not the brightness. The recoveries
      // go on without them, as from the first round (the last resort, RegisterAgainWithGains,
      // still tries them with recoveries).
      if (!result->usable) RestoreFailedRound(std::move(*failed_without_gains), result);
      failed_without_gains.reset();
    }
    if (result->usable && result->photometric_detected && result->photometric.empty() &&
        !affine_round) {
      // Brightness differs between frames, found at the final poses of a round that ran
      // without gains and offsets: once more with them, from the poses reached (not a
      // recovery: nothing was wrong with them). A round that switched to them at a level
      // (the structure check's second chance) needs none.
      affine_round = true;
      *poses = result->frame_from_world;
      --round;
      continue;
    }
    if (result->usable && !result->photometric_detected && !result->photometric.empty() &&
        options.photometric == PhotometricModel::kAuto && !plain_round) {
      // The last coarse level took its poses' error for brightness, which the final poses
      // do not confirm (CoarseToFine::ConfirmBrightness): once more without gains and
      // offsets, from the poses reached.
      plain_round = true;
      *poses = result->frame_from_world;
      --round;
      continue;
    }
    if (result->usable || round >= options.max_recoveries || result->flagged_frames.empty() ||
        !Recover(search_frames, options, recovery, poses, result, run.error)) {
      break;
    }
  }
  return true;
}

// The photometric model's last resort (photometric kAuto), after a registration that is
// not usable: the registration failed without gains and offsets, or took them on only
// later (at a level, or a round after a recovery had re-placed frames: a chest CT
// ultrasound-like sequence whose third round switched to them and failed). Frames of
// different brightness can slide, or settle nowhere, before any level lines them up. Once
// more with them from the same start; its result stands only if it passes every check,
// which guard it as they guard the first (the determination check among them: a symmetric
// object stays refused, while a wrong minimum that looked undetermined, the frames out of
// line, an ultrasound-like chest CT sequence 12 mm off, may end right).
bool RegisterAgainWithGains(const RegistrationRun& run) {
  RegistrationResult* result = run.result;
  RegistrationOptions affine = *run.options;
  affine.photometric = PhotometricModel::kAffine;
  RegistrationResult second;
  RegistrationRun second_run = run;
  second_run.options = &affine;
  second_run.start = std::chrono::steady_clock::now();
  second_run.result = &second;
  if (!RegisterScaled(second_run)) return false;
  second.seconds = SecondsSince(run.start);  // both attempts (its pyramid time: its own)
  second.init_seconds += result->init_seconds;
  second.total_iterations += result->total_iterations;
  second.check_seconds.structure += result->check_seconds.structure;
  second.check_seconds.determination += result->check_seconds.determination;
  second.check_seconds.brightness += result->check_seconds.brightness;
  second.check_seconds.uncertainty += result->check_seconds.uncertainty;
  second.check_seconds.other += result->check_seconds.other;
  second.photometric_detected = second.usable;
  second.photometric_choice =
      std::string(second.usable ? "affine" : "none") +
      " (photometric=auto: without gains and offsets from the start the registration "
      "failed: " +
      result->failure + (second.usable ? "; with them it passed every check)" : ")");
  if (!second.usable) {
    second.failure = result->failure + "; with gains and offsets estimated too: " + second.failure;
  }
  *result = std::move(second);
  return true;
}

// Register on intensities already brought to a usual scale (see Register): the start
// (given, pairwise or global), then rounds of coarse-to-fine solves with a recovery
// between them.
bool RegisterScaled(const RegistrationRun& run) {
  const RegistrationOptions& options = *run.options;
  const std::vector<Image>& images = *run.images;
  const std::vector<Mask>& masks = *run.masks;
  RegistrationResult* result = run.result;
  // The pairwise initialiser runs first (its own pyramids, freed before ours are built).
  std::vector<Eigen::Isometry3d> poses = RelativeToFrame0(*run.initial_frame_from_world);
  if (options.init == InitialPoses::kPairwise && options.mode != Mode::kPairwise) {
    bool ended = false;
    if (!PairwiseStart(run, &poses, &ended)) return false;
    if (ended) {
      result->frame_from_world = poses;
      result->seconds = SecondsSince(run.start);
      return true;
    }
  }
  Pyramids pyramids = BuildPyramids(images, masks, options, run.later_phases);
  result->pyramid_seconds = SecondsSince(run.start) - result->init_seconds;
  // From here on every pose is in the frames' local coordinates (Pyramids::centre).
  poses = PosesToLocal(poses, pyramids.centre);
  const int constant = ConstantFrame(images, masks);
  if (constant >= 0) {
    *run.error = "frame " + std::to_string(constant) +
                 " has the same value everywhere in its field of view: nothing to register";
    return false;
  }
  const std::vector<Frame> search_frames = SearchLevel(run, pyramids);
  RecoveryState recovery;
  recovery.misfit_exempt.assign(images.size(), false);
  recovery.global_used = options.init == InitialPoses::kGlobal;
  if (recovery.global_used) {
    const auto init_start = std::chrono::steady_clock::now();
    PairGraphReport graph;
    if (!GlobalInitialPoses(search_frames, options.search, &poses, &graph, run.error)) {
      *run.error = "init=global: " + *run.error;
      return false;
    }
    result->init_seconds = SecondsSince(init_start);
    result->init_frame_from_world = PosesFromLocal(poses, pyramids.centre);
  }
  if (!RunRounds(run, search_frames, &pyramids, &recovery, &poses)) return false;
  ResultFromLocal(pyramids.centre, result);
  result->seconds = SecondsSince(run.start);
  if (!result->usable && options.photometric == PhotometricModel::kAuto &&
      ModeEstimatesPhotometric(options.mode)) {
    return RegisterAgainWithGains(run);
  }
  return true;
}

// Costs, misfits and intensities of a registration on intensities scaled by 2^exponent,
// in the input's units.
void UnscaleResult(int exponent, RegistrationResult* result) {
  const auto cost = [&](double c) { return std::ldexp(c, -2 * exponent); };
  for (LevelSolve& solve : result->solves) {
    SolveReport& r = solve.report;
    r.initial_cost = cost(r.initial_cost);
    r.final_cost = cost(r.final_cost);
    for (IterationRecord& it : r.iterations) it.cost = cost(it.cost);
    for (double& c : r.final_frame_cost) c = cost(c);
  }
  for (double& misfit : result->frame_misfits) misfit = std::ldexp(misfit, -exponent);
  // Gains are ratios of intensities (unchanged); offsets are intensities.
  for (Photometric& p : result->photometric) p.offset = std::ldexp(p.offset, -exponent);
  for (float& v : result->dba_intensities.voxels) v = std::ldexp(v, -exponent);
  for (Image& phase : result->dba_later_phases) {
    for (float& v : phase.voxels) v = std::ldexp(v, -exponent);
  }
  result->uncertainty.noise_sigma = std::ldexp(result->uncertainty.noise_sigma, -exponent);
}

// Register on intensities `*run.images` (the input's, or their transform): those far from a
// usual scale are brought to it by a power of two (pipeline/input_checks.h); the reported
// costs are scaled back at the end.
bool RegisterOnUsualScale(const RegistrationRun& run) {
  const int exponent = IntensityScaleExponent(IntensitySpread(*run.images, *run.masks));
  if (exponent == 0) return RegisterScaled(run);
  LOG(INFO) << "intensities scaled by 2^" << exponent
            << " for the solves (their spread is far from a usual scale); the costs printed "
               "during the solves are in those units";
  std::vector<Image> scaled = *run.images;
  for (Image& image : scaled) {
    for (float& v : image.voxels) v = std::ldexp(v, exponent);
  }
  // Every phase by the same power of two (phase 0's spread decides it).
  std::vector<std::vector<Image>> scaled_phases;
  if (run.later_phases != nullptr) scaled_phases = *run.later_phases;
  for (std::vector<Image>& view : scaled_phases) {
    for (Image& image : view) {
      for (float& v : image.voxels) v = std::ldexp(v, exponent);
    }
  }
  // The loss's scale is in grey levels: it follows the intensities.
  RegistrationOptions scaled_options = *run.options;
  scaled_options.loss.scale = std::ldexp(run.options->loss.scale, exponent);
  RegistrationRun scaled_run = run;
  scaled_run.images = &scaled;
  if (run.later_phases != nullptr) scaled_run.later_phases = &scaled_phases;
  scaled_run.options = &scaled_options;
  if (!RegisterScaled(scaled_run)) return false;
  UnscaleResult(exponent, run.result);
  return true;
}

// After registering transformed intensities: the result's photometric parameters and
// misfits on the input's grey levels, at the final poses, on the finest level of the
// input (RegistrationOptions::intensity_transform), and DBA's intensities mapped back.
// When no panorama holds the final poses (a registration that diverged), the photometric
// parameters and misfits are dropped rather than left on the transform's scale.
bool ResultOnInputIntensities(const std::vector<Image>& input_images,
                              const std::vector<std::vector<Image>>& later_phases,
                              const std::vector<Mask>& masks,
                              const RegistrationOptions& options,
                              RegistrationResult* result,
                              std::string* error) {
  const double c = result->intensity_transform_scale;
  for (float& v : result->dba_intensities.voxels) {
    v = c > 0.0 ? static_cast<float>(InverseIntensity(std::max(0.0f, v), c)) : 0.0f;
  }
  for (Image& phase : result->dba_later_phases) {
    for (float& v : phase.voxels) {
      v = c > 0.0 ? static_cast<float>(InverseIntensity(std::max(0.0f, v), c)) : 0.0f;
    }
  }
  if (result->photometric.empty() && result->frame_misfits.empty()) return true;
  const int m = static_cast<int>(input_images.size());
  std::vector<Frame> frames(m);
  // The finest pyramid level of the input (image/pyramid.h: smoothed by options.smoothing).
  ParallelFor(0, m, options.solve.num_threads, [&](int64_t i) {
    const std::vector<Image>& later = LaterPhasesOf(&later_phases, i);
    if (options.smoothing <= 0.0) {
      frames[i] = Frame::Borrowing(input_images[i], later, masks[i]);
      return;
    }
    std::vector<Image> smoothed;
    for (const Image& phase : later) {
      smoothed.push_back(SmoothInsideMask(phase, masks[i], options.smoothing, 1));
    }
    frames[i] = Frame(SmoothInsideMask(input_images[i], masks[i], options.smoothing, 1),
                      smoothed, masks[i]);
  });
  const std::vector<Eigen::Isometry3d>& poses = result->frame_from_world;
  ImageGeometry grid;
  std::string grid_error;
  if (poses.size() != input_images.size() ||
      !BuildPanoramaGrid(frames, poses, options.panorama_spacing, &grid, &grid_error,
                         options.panorama_sampling)) {
    result->photometric.clear();
    result->frame_misfits.clear();
    return true;
  }
  const CandidateSet candidates = BuildCandidates(frames, poses, grid, /*margin_cells=*/0);
  if (!result->photometric.empty()) {
    DsrOptions dsr = ToDsrOptions(options, options.solve);
    dsr.solve.linear_solver.reset();  // mode dba's may be a Schur type
    dsr.solve.progress_prefix += "input's grey levels ";
    // Started from the estimate on T's scale, mapped (saves Ceres iterations, ~0.1 s each).
    dsr.initial_photometric = PhotometricOnInputScale(result->photometric, input_images, masks, c);
    SolveReport report;
    if (!SolvePhotometricAtPoses(frames, candidates, poses, dsr, &report, error)) return false;
    result->photometric = report.photometric;
    if (!report.usable && result->usable) {
      result->usable = false;
      result->failure = "the gains and offsets on the input's grey levels: " + report.termination;
    }
  }
  if (!result->frame_misfits.empty()) {
    result->frame_misfits = FrameMisfits(frames, candidates, poses,
                                         StreamContextFor(options.solve), result->photometric);
  }
  return true;
}

// Views of T > 1 phases (docs/design.md section 12): `later_phases` empty (3D views) or one
// entry per view, every view with the same T - 1 later phases, each on its view's grid; only
// modes dsr and dba tie a view's phases to one pose.
bool CheckLaterPhases(const std::vector<Image>& images,
                      const std::vector<std::vector<Image>>& later_phases,
                      const RegistrationOptions& options,
                      std::string* error) {
  if (later_phases.empty()) return true;
  if (later_phases.size() != images.size()) {
    *error = "phases given for " + std::to_string(later_phases.size()) + " views, but there are " +
             std::to_string(images.size()) + " views";
    return false;
  }
  const size_t later = later_phases[0].size();
  for (size_t i = 0; i < images.size(); ++i) {
    if (later_phases[i].size() != later) {
      *error = "frame " + std::to_string(i) + " has " +
               std::to_string(later_phases[i].size() + 1) + " phases, frame 0 has " +
               std::to_string(later + 1) +
               ": every frame needs the same phases of the heart cycle (aligned by index)";
      return false;
    }
    for (size_t p = 0; p < later; ++p) {
      if (!later_phases[i][p].geometry.SameGrid(images[i].geometry) ||
          later_phases[i][p].voxels.size() != images[i].voxels.size()) {
        *error = "frame " + std::to_string(i) + ": phase " + std::to_string(p + 1) +
                 " lies on another grid than its phase 0";
        return false;
      }
    }
  }
  if (later > 0 && options.mode != Mode::kDsr && options.mode != Mode::kDba) {
    *error = std::string("mode=") + ModeToString(options.mode) +
             " registers 3D frames; views with several phases need mode dsr or dba (or "
             "register one phase)";
    return false;
  }
  return true;
}

// The intensity transform of every later phase, with phase 0's constant `scale`.
bool TransformLaterPhases(const std::vector<std::vector<Image>>& later_phases,
                          const std::vector<Mask>& masks,
                          IntensityTransform transform,
                          double scale,
                          std::vector<std::vector<Image>>* transformed,
                          std::string* error) {
  transformed->assign(later_phases.size(), {});
  for (size_t i = 0; i < later_phases.size(); ++i) {
    const std::vector<Mask> view_masks(later_phases[i].size(), masks[i]);
    if (!ApplyIntensityTransform(later_phases[i], view_masks, transform, scale,
                                 &(*transformed)[i], error)) {
      return false;
    }
  }
  return true;
}

// The views' masks less their dropouts (geometry/lost_signal.h: FindLostSignalInViews);
// empty when no view has one. `fractions`: each view's share of its field of view left out.
std::vector<Mask> MasksLessDropouts(const std::vector<Image>& images,
                                    const std::vector<Mask>& masks,
                                    int num_threads,
                                    std::vector<double>* fractions) {
  const int m = static_cast<int>(images.size());
  std::vector<LostSignal> found = FindLostSignalInViews(images, masks, num_threads);
  fractions->assign(m, 0.0);
  bool any = false;
  for (int i = 0; i < m; ++i) {
    if (found[i].lost_voxels == 0) continue;
    any = true;
    (*fractions)[i] = static_cast<double>(found[i].lost_voxels) / found[i].fov_voxels;
    LOG(INFO) << "frame " << i << ": " << found[i].lost_bins << " of " << found[i].judged_bins
              << " beam bins without signal, " << 100.0 * (*fractions)[i]
              << " % of its field of view left out (sector widening "
              << found[i].sector.widening << ")";
  }
  if (!any) return {};
  // A view's dropout mask becomes its mask less the dropout in place: one more set of masks
  // in memory, not two.
  std::vector<Mask> out(m);
  ParallelFor(0, m, num_threads, [&](int64_t i) {
    if (found[i].lost_voxels == 0) {
      out[i] = masks[i];
      return;
    }
    out[i] = std::move(found[i].lost);
    std::vector<uint8_t>& voxels = out[i].voxels;
    const std::vector<uint8_t>& given = masks[i].voxels;
    for (size_t l = 0; l < voxels.size(); ++l) voxels[l] = given[l] && !voxels[l];
  });
  return out;
}

// The rest of Register, on the masks it chose: the intensity transform where asked, then
// the registration.
bool RegisterInputs(const std::vector<Image>& input_images,
                    const std::vector<std::vector<Image>>& later_phases,
                    RegistrationRun run) {
  const RegistrationOptions& options = *run.options;
  const std::vector<Mask>& masks = *run.masks;
  RegistrationResult* result = run.result;
  std::string* error = run.error;
  if (options.intensity_transform == IntensityTransform::kNone) return RegisterOnUsualScale(run);
  const double c = IntensityTransformScale(input_images, masks);
  std::vector<Image> transformed;
  std::vector<std::vector<Image>> transformed_phases;
  if (!ApplyIntensityTransform(input_images, masks, options.intensity_transform, c,
                               &transformed, error) ||
      !TransformLaterPhases(later_phases, masks, options.intensity_transform, c,
                            &transformed_phases, error)) {
    return false;
  }
  run.images = &transformed;
  if (run.later_phases != nullptr) run.later_phases = &transformed_phases;
  run.search_images = &input_images;
  if (!RegisterOnUsualScale(run)) return false;
  transformed = std::vector<Image>();  // freed before the input's frames are built
  transformed_phases = std::vector<std::vector<Image>>();
  result->intensity_transform = options.intensity_transform;
  result->intensity_transform_scale = c;
  if (!ResultOnInputIntensities(input_images, later_phases, masks, options, result, error)) {
    return false;
  }
  result->seconds = SecondsSince(run.start);
  return true;
}

}  // namespace

bool Register(const std::vector<Image>& input_images,
              const std::vector<Mask>& masks,
              const std::vector<Eigen::Isometry3d>& initial_frame_from_world,
              const RegistrationOptions& options,
              RegistrationResult* result,
              std::string* error) {
  return Register(input_images, {}, masks, initial_frame_from_world, options, result, error);
}

bool Register(const std::vector<Image>& input_images,
              const std::vector<std::vector<Image>>& later_phases,
              const std::vector<Mask>& masks,
              const std::vector<Eigen::Isometry3d>& initial_frame_from_world,
              const RegistrationOptions& options,
              RegistrationResult* result,
              std::string* error) {
  const auto start = std::chrono::steady_clock::now();
  const int m = static_cast<int>(input_images.size());
  if (m < 2) {
    *error = "need at least 2 frames, got " + std::to_string(m);
    return false;
  }
  if (m > kMaxFrames) {
    *error = "at most " + std::to_string(kMaxFrames) + " frames, got " + std::to_string(m);
    return false;
  }
  CHECK_EQ(masks.size(), input_images.size());
  CHECK_EQ(initial_frame_from_world.size(), input_images.size());
  if (!options.Validate(error)) return false;
  if (!CheckRegistrationInputs(input_images, initial_frame_from_world, options, error) ||
      !CheckLaterPhases(input_images, later_phases, options, error)) {
    return false;
  }
  *result = RegistrationResult();
  RegistrationRun run;
  run.images = &input_images;
  run.later_phases = later_phases.empty() ? nullptr : &later_phases;
  run.masks = &masks;
  run.initial_frame_from_world = &initial_frame_from_world;
  run.options = &options;
  run.start = start;
  run.result = result;
  run.error = error;
  // The masks less the dropouts stay here while the run goes on (it may start its result
  // again) and are handed to the result at the end.
  std::vector<double> dropout_fraction;
  std::vector<Mask> less_dropouts;
  if (options.detect_dropouts) {
    less_dropouts =
        MasksLessDropouts(input_images, masks, options.solve.num_threads, &dropout_fraction);
    if (!less_dropouts.empty()) run.masks = &less_dropouts;
  }
  const bool ok = RegisterInputs(input_images, later_phases, run);
  result->dropout_fraction = std::move(dropout_fraction);
  result->masks_used = std::move(less_dropouts);
  return ok;
}

}  // namespace dsr
