#include "dsr/pipeline/coarse_to_fine.h"

#include <algorithm>
#include <cmath>
#include <iomanip>
#include <limits>
#include <memory>
#include <sstream>
#ifdef __GLIBC__
#include <malloc.h>  // malloc_trim
#endif

#include <glog/logging.h>

#include "dsr/dsr_reduced/photometric_at_poses.h"
#include "dsr/model/panorama.h"
#include "dsr/pipeline/pair_check.h"
#include "dsr/pipeline/uncertainty.h"
#include "dsr/solve/convergence.h"
#include "dsr/solve/gauge.h"
#include "dsr/stream/reduced_system.h"
#include "dsr/stream/streamed_cost.h"
#include "dsr/util/clock.h"
#include "dsr/util/parallel.h"

namespace dsr {
namespace {

// Frames of one pyramid level. When `release` is set, the level's images are freed once
// the frames hold their copies (no recovery can come back to them); otherwise the frames
// read the stored level's voxels, as they read the input's where it is the level (both
// outlive the run), without a copy.
// With `later_phases` (views of T > 1 phases, [view][phase - 1]), frames of every phase.
std::vector<Frame> LevelFrames(const std::vector<Image>& images,
                               const std::vector<std::vector<Image>>* later_phases,
                               const std::vector<Mask>& masks,
                               Pyramids* pyramids,
                               int level,
                               bool release,
                               int num_threads) {
  const int m = static_cast<int>(images.size());
  std::vector<Frame> frames(m);
  ParallelFor(0, m, num_threads, [&](int64_t i) {
    ImageLevel& stored = pyramids->levels[i][level];
    const bool input_is_level = level == 0 && stored.image.empty();
    if (input_is_level) {
      frames[i] = Frame::Borrowing(images[i], LaterPhasesOf(later_phases, i), masks[i])
                      .Translated(-pyramids->centre[i]);
    } else if (release) {
      frames[i] = Frame(stored.image, stored.later_phases, stored.mask);
    } else {
      frames[i] = Frame::Borrowing(stored.image, stored.later_phases, stored.mask);
    }
    if (release) stored = ImageLevel();
  });
  return frames;
}

// Checks that the overlap determines every free pose: the Gauss-Newton matrix of the
// shared cost at `poses`, Jacobi-scaled (so millimetres and radians compare), must not be
// numerically singular. Otherwise `why` names the frame the weakest direction moves most.
bool PosesDetermined(const std::vector<Frame>& frames,
                     const CandidateSet& candidates,
                     const std::vector<Eigen::Isometry3d>& poses,
                     const StreamContext& context,
                     double* conditioning,
                     std::string* why) {
  const int m = static_cast<int>(frames.size());
  const int n = 6 * (m - 1);
  ReducedSystem system;
  AccumulateReducedSystem(frames, candidates, poses, 0, candidates.num_voxels(), true, context,
                          &system);
  const Eigen::MatrixXd h = system.hessian.bottomRightCorner(n, n);
  Eigen::VectorXd scale(n);
  for (int c = 0; c < n; ++c) {
    if (!(h(c, c) > 0.0)) {
      *why = "the overlap is too small or too featureless to determine all 6 degrees of "
             "freedom of frame " + std::to_string(1 + c / 6) +
             " (no image gradient along one of them)";
      *conditioning = 0.0;
      return false;
    }
    scale[c] = 1.0 / std::sqrt(h(c, c));
  }
  const Eigen::MatrixXd scaled = scale.asDiagonal() * h * scale.asDiagonal();
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(scaled);
  const double ratio = eig.eigenvalues()[0] / std::max(1e-300, eig.eigenvalues()[n - 1]);
  *conditioning = ratio;
  // Well-posed problems sit many orders of magnitude above this (see the log at --v=1).
  constexpr double kMinRatio = 1e-10;
  if (ratio >= kMinRatio) return true;
  const Eigen::VectorXd weakest = eig.eigenvectors().col(0);
  int frame = 1;
  double largest = -1.0;
  for (int i = 1; i < m; ++i) {
    const double norm = weakest.segment<6>(6 * (i - 1)).norm();
    if (norm > largest) {
      largest = norm;
      frame = i;
    }
  }
  std::ostringstream s;
  s << "the overlap is too small or too featureless to determine all 6 degrees of freedom "
       "of frame "
    << frame << " (scaled Gauss-Newton matrix conditioning " << ratio << " < " << kMinRatio
    << ")";
  *why = s.str();
  return false;
}

// `frame_from_world` in another world: T_i W, W mapping that world to this one.
std::vector<Eigen::Isometry3d> InWorld(std::vector<Eigen::Isometry3d> frame_from_world,
                                       const Eigen::Isometry3d& world) {
  for (Eigen::Isometry3d& pose : frame_from_world) pose = pose * world;
  return frame_from_world;
}

}  // namespace

Eigen::Vector3d LocalCentre(const ImageGeometry& geometry) {
  return geometry.IndexToPhysical(0.5 * (geometry.size.cast<double>() - Eigen::Vector3d::Ones()));
}

namespace {

std::vector<ImageLevel> PyramidOf(const Image& image,
                                  const Mask& mask,
                                  const RegistrationOptions& options) {
  return BuildPyramid(image, mask, options.pyramid_levels, options.pyramid_sigma,
                      options.smoothing, options.pyramid_min_size, options.solve.num_threads);
}

}  // namespace

void BuildLaterPhaseLevels(const std::vector<std::vector<Image>>* later_phases,
                           const std::vector<Mask>& masks,
                           const RegistrationOptions& options,
                           int first_level,
                           Pyramids* pyramids) {
  for (size_t i = 0; i < pyramids->levels.size(); ++i) {
    std::vector<ImageLevel>& levels = pyramids->levels[i];
    for (size_t l = first_level; l < levels.size(); ++l) levels[l].later_phases.clear();
    // Every later phase's pyramid on the same grids (same mask, same sizes).
    for (const Image& later : LaterPhasesOf(later_phases, i)) {
      std::vector<ImageLevel> phase = PyramidOf(later, masks[i], options);
      CHECK_EQ(phase.size(), levels.size());
      for (size_t l = first_level; l < phase.size(); ++l) {
        phase[l].image.geometry.origin_mm -= pyramids->centre[i];
        levels[l].later_phases.push_back(std::move(phase[l].image));
      }
    }
  }
}

void ReleaseLaterPhaseLevel(int level, Pyramids* pyramids) {
  for (std::vector<ImageLevel>& levels : pyramids->levels) {
    std::vector<Image>().swap(levels[level].later_phases);
  }
#ifdef __GLIBC__
  malloc_trim(0);  // give the freed images' pages back: they are what the peak would hold
#endif
}

Pyramids BuildPyramids(const std::vector<Image>& images,
                       const std::vector<Mask>& masks,
                       const RegistrationOptions& options,
                       const std::vector<std::vector<Image>>* later_phases) {
  const int m = static_cast<int>(images.size());
  Pyramids pyramids;
  pyramids.levels.resize(m);
  pyramids.num_levels = options.pyramid_levels;
  for (int i = 0; i < m; ++i) {
    pyramids.levels[i] = PyramidOf(images[i], masks[i], options);
    pyramids.num_levels =
        std::min(pyramids.num_levels, static_cast<int>(pyramids.levels[i].size()));
    pyramids.centre.push_back(LocalCentre(images[i].geometry));
    for (ImageLevel& level : pyramids.levels[i]) {
      level.image.geometry.origin_mm -= pyramids.centre[i];
      level.mask.geometry.origin_mm -= pyramids.centre[i];
    }
  }
  BuildLaterPhaseLevels(later_phases, masks, options, 0, &pyramids);
  return pyramids;
}

std::vector<Frame> SearchFrames(const std::vector<Image>& images,
                                const std::vector<Mask>& masks,
                                const Pyramids& pyramids,
                                const RegistrationOptions& options) {
  const int m = static_cast<int>(images.size());
  const int coarsest = pyramids.num_levels - 1;
  std::vector<Frame> frames(m);
  ParallelFor(0, m, options.solve.num_threads, [&](int64_t i) {
    const ImageLevel& stored = pyramids.levels[i][coarsest];
    ImageLevel level = stored;
    if (stored.image.empty()) {  // the input is the level: in local coordinates
      level = ImageLevel{images[i], masks[i], {}};
      level.image.geometry.origin_mm -= pyramids.centre[i];
      level.mask.geometry.origin_mm -= pyramids.centre[i];
    }
    while (level.image.geometry.size.maxCoeff() > options.search_max_axis &&
           level.image.geometry.size.minCoeff() >= 8) {
      ImageLevel next = Downsample(level.image, level.mask, options.pyramid_sigma, 1);
      if (CountInside(next.mask) == 0) break;
      level = std::move(next);
    }
    frames[i] = Frame(level.image, level.mask);
  });
  return frames;
}

CoarseToFine::CoarseToFine(const std::vector<Image>& images,
                           const std::vector<std::vector<Image>>* later_phases,
                           const std::vector<Mask>& masks,
                           const RegistrationOptions& options,
                           bool check_every_level,
                           const std::vector<bool>& misfit_exempt,
                           const std::vector<Frame>& search_frames,
                           Pyramids* pyramids)
    : images_(images),
      later_phases_(later_phases),
      masks_(masks),
      options_(options),
      stream_(StreamContextFor(options.solve)),
      check_every_level_(check_every_level),
      misfit_exempt_(misfit_exempt),
      search_frames_(search_frames),
      pyramids_(pyramids),
      solver_(MakeLevelSolver(options)),
      m_(static_cast<int>(images.size())),
      affine_(options.photometric == PhotometricModel::kAffine),
      mean_world_(ModeTakesGauge(options.mode) && options.gauge == Gauge::kMean &&
                  options.panorama_sampling == PanoramaSampling::kAllPhases),
      guard_(options.min_kept_overlap) {}

bool CoarseToFine::Run(const std::vector<Eigen::Isometry3d>& start_poses,
                       RegistrationResult* result,
                       std::string* error) {
  result_ = result;
  error_ = error;
  if (options_.photometric == PhotometricModel::kAuto && result->photometric_detected) UseAffine();
  poses_ = round_start_ = start_poses;
  solve_world_ = Eigen::Isometry3d::Identity();
  unjudged_ = false;
  photometric_.clear();
  result->photometric.clear();
  result->usable = true;
  result->flagged_frames.clear();
  result->flagged_by_misfit = false;
  result->poses_undetermined = false;
  result->brightness_suspected = false;
  result->failure.clear();
  const bool phased = later_phases_ != nullptr && !later_phases_->empty();
  bool released = false;  // by a round before (every view's levels go together)
  for (int level = 1; level < pyramids_->num_levels; ++level) {
    released = released || pyramids_->levels[0][level].later_phases.empty();
  }
  if (phased && released) BuildLaterPhaseLevels(later_phases_, masks_, options_, 1, pyramids_);
  for (int level = pyramids_->num_levels - 1; level >= 0; --level) {
    // The level passed before is left behind (its frames are gone): its later phases too.
    if (phased && level + 1 < pyramids_->num_levels) ReleaseLaterPhaseLevel(level + 1, pyramids_);
    std::vector<Frame> frames;
    Next next = BuildLevelFrames(level, &frames);
    if (next == Next::kSkipLevel) continue;
    if (next == Next::kGoOn) next = SolveLevel(level, frames);
    // A level skipped after some of its solves still has its checks (of the poses it
    // started from, with its last solve's candidates).
    if (next == Next::kGoOn || next == Next::kSkipLevel) {
      next = level > 0 ? CheckCoarseLevel(level, frames) : CheckFinalPoses(frames);
      if (next == Next::kGoOn && level > 0) DetectBrightnessEarly(level, frames);
    }
    if (next == Next::kEnd) {
      SuspectBrightness(frames);
      return true;
    }
    if (next == Next::kError) return false;
  }
  result->frame_from_world = poses_;
  result->photometric = photometric_;
  return true;
}

CoarseToFine::Next CoarseToFine::Diverged(int level,
                                          const std::string& why,
                                          std::vector<int> flagged) {
  result_->usable = false;
  result_->failure =
      "not usable after the solve at pyramid level " + std::to_string(level) + ": " + why;
  result_->flagged_frames = std::move(flagged);
  result_->frame_from_world = poses_;
  result_->photometric = photometric_;
  return Next::kEnd;
}

ImageGeometry CoarseToFine::OutputGrid(const std::vector<Frame>& frames,
                                       const ImageGeometry& solve_grid) const {
  if (!mean_world_) return solve_grid;
  ImageGeometry grid;
  std::string error;
  if (BuildPanoramaGrid(frames, poses_, options_.panorama_spacing, &grid, &error,
                        options_.panorama_sampling)) {
    return grid;
  }
  // The solve's grid itself, placed in frame 0's world (oblique there).
  grid = solve_grid;
  grid.direction = solve_world_.linear() * solve_grid.direction;
  grid.origin_mm = solve_world_ * solve_grid.origin_mm;
  return grid;
}

std::vector<Eigen::Isometry3d> CoarseToFine::SolvePoses() const {
  return InWorld(poses_, solve_world_);
}

CoarseToFine::Next CoarseToFine::BuildLevelFrames(int level, std::vector<Frame>* frames) {
  const bool release = options_.max_recoveries == 0;
  *frames = LevelFrames(images_, later_phases_, masks_, pyramids_, level, release,
                        options_.solve.num_threads);
  int empty_frame = -1;
  for (int i = m_ - 1; i >= 0; --i) {
    if ((*frames)[i].num_valid_cells() == 0) empty_frame = i;
  }
  if (empty_frame < 0) return Next::kGoOn;
  if (level > 0) {
    LOG(INFO) << "skipping pyramid level " << level << ": frame " << empty_frame
              << " has no valid cell at this resolution";
    return Next::kSkipLevel;
  }
  *error_ = "frame " + std::to_string(empty_frame) +
            " has no valid voxel (a cell whose 8 corners are inside the field-of-view "
            "mask): the mask is too small";
  return Next::kError;
}

CoarseToFine::Next CoarseToFine::SolveLevel(int level, const std::vector<Frame>& frames) {
  level_solve_ = options_.solve;
  if (level > 0) {
    level_solve_.max_iterations =
        std::min(level_solve_.max_iterations, options_.coarse_max_iterations);
  }
  const std::vector<Eigen::Isometry3d> level_start = poses_;
  const std::vector<Photometric> level_start_photometric = photometric_;
  // The pair-based baselines build their own pair grids and candidates in every solve:
  // rebuilding the shared candidates between their solves would only repeat them.
  max_rebuilds_ = ModeIsPairBased(options_.mode) ? 0 : options_.max_rebuilds;
  last_candidates_ = CandidateSet();
  last_motion_ = std::numeric_limits<double>::infinity();
  last_frame_motion_.assign(m_, 0.0);
  solved_ = false;
  for (int rebuild = 0; rebuild <= max_rebuilds_; ++rebuild) {
    LevelSolve record;
    record.level = level;
    record.rebuild = rebuild;
    CandidateSet candidates;
    ImageGeometry grid;
    Next next = BuildLevelProblem(level, rebuild, frames, &record, &candidates, &grid);
    if (next == Next::kSkipLevel) {
      poses_ = level_start;
      photometric_ = level_start_photometric;
      return Next::kSkipLevel;
    }
    if (next != Next::kGoOn) return next;
    next = SolveOnce(level, frames, grid, std::move(candidates), std::move(record));
    if (next != Next::kGoOn) return next;
    if (last_motion_ <= options_.rebuild_tolerance) break;
  }
  return Next::kGoOn;
}

CoarseToFine::Next CoarseToFine::BuildLevelProblem(int level,
                                                   int rebuild,
                                                   const std::vector<Frame>& frames,
                                                   LevelSolve* record,
                                                   CandidateSet* candidates,
                                                   ImageGeometry* grid) {
  const int last_level = result_->solves.empty() ? level : result_->solves.back().level;
  Eigen::Isometry3d world = Eigen::Isometry3d::Identity();
  if (mean_world_) {
    std::vector<Eigen::Vector3d> centres;
    for (const Frame& frame : frames) centres.push_back(frame.ValidCentre());
    world = MeanFrame(poses_, centres);
  }
  const std::vector<Eigen::Isometry3d> poses = InWorld(poses_, world);
  if (!BuildPanoramaGrid(frames, poses, options_.panorama_spacing, grid, error_,
                         options_.panorama_sampling)) {
    if (result_->solves.empty()) return Next::kError;  // the initial poses: bad input
    // The poses a solve reached spread the frames over a space no panorama can hold.
    const std::string why = "diverged: the solve moved the frames far apart (" + *error_ + ")";
    error_->clear();
    return Diverged(last_level, why, {});
  }
  record->panorama_spacing_mm = grid->spacing_mm;
  *candidates = BuildCandidates(frames, poses, *grid, /*margin_cells=*/0);
  record->candidate_voxels = candidates->num_voxels();
  record->candidate_observations = candidates->NumObservations();
  const Eigen::MatrixXi overlap = CandidateOverlap(*candidates);
  Next next = GuardLevelOverlap(last_level, frames, overlap, *grid, *candidates, poses);
  if (next != Next::kGoOn) return next;
  next = CheckLevelConnected(level, last_level, overlap);
  if (next != Next::kGoOn) return next;
  if (rebuild == 0) {
    next = CheckLevelDetermined(level, frames, *candidates, poses);
    if (next != Next::kGoOn) return next;
  }
  solve_world_ = world;
  if (rebuild != 0) return Next::kGoOn;
  return JudgeLevelStart(level, last_level, frames, *candidates, poses);
}

CoarseToFine::Next CoarseToFine::GuardLevelOverlap(int last_level,
                                                   const std::vector<Frame>& frames,
                                                   const Eigen::MatrixXi& overlap,
                                                   const ImageGeometry& grid,
                                                   const CandidateSet& candidates,
                                                   const std::vector<Eigen::Isometry3d>& poses) {
  std::string why;
  std::vector<int> slid;
  if (options_.min_kept_overlap <= 0.0 ||
      !guard_.Diverged(frames, overlap, grid.spacing_mm, &why, &slid)) {
    return Next::kGoOn;
  }
  // With recovery, frames in a wrong minimum that did not slide are named too, so that
  // one recovery re-places them all (else the next solve finds them, and by then the
  // pair graph is the only remedy left).
  if (check_every_level_) {
    std::vector<int> off;
    if (options_.max_misfit_ratio > 0.0) {
      off = MisfitOutliers(FrameMisfits(frames, candidates, poses, stream_, photometric_),
                           options_.max_misfit_ratio, &misfit_exempt_);
    }
    if (options_.max_structure_fraction > 0.0) {
      for (int f : StructureOutliers(
               FrameStructures(frames, candidates, poses, stream_, photometric_),
               options_.max_structure_fraction, &misfit_exempt_)) {
        off.push_back(f);
      }
    }
    for (int f : off) {
      if (std::find(slid.begin(), slid.end(), f) == slid.end()) slid.push_back(f);
    }
  }
  return Diverged(last_level, why, slid);
}

CoarseToFine::Next CoarseToFine::CheckLevelConnected(int level,
                                                     int last_level,
                                                     const Eigen::MatrixXi& overlap) {
  std::string connect_error;
  if (CheckConnected(overlap, options_.min_shared_voxels, &connect_error)) return Next::kGoOn;
  if (level == 0 && !result_->solves.empty()) {
    // Not the input's poses: solves, or a recovery between rounds, left these frames
    // apart. The round ends as not usable, naming them (a recovery may re-place them).
    const std::vector<int> apart = FramesNotConnected(overlap, options_.min_shared_voxels);
    std::ostringstream why;
    why << FramesPhrase(apart)
        << (apart.size() > 1 ? " no longer overlap" : " no longer overlaps")
        << " frame 0 or the frames connected to it (fewer than "
        << options_.min_shared_voxels << " shared panorama voxels at the finest level)";
    return Diverged(last_level, why.str(), apart);
  }
  if (level > 0) {
    // Coarse levels have few voxels: a small overlap may only be countable at finer
    // levels, and a coarse solve on a thin overlap may have drifted. Skip the level and
    // start the next one from the poses this level started from.
    LOG(INFO) << "skipping pyramid level " << level << ": " << connect_error;
    return Next::kSkipLevel;
  }
  *error_ = connect_error + " (pyramid level " + std::to_string(level) + ")";
  return Next::kError;
}

CoarseToFine::Next CoarseToFine::CheckLevelDetermined(
    int level,
    const std::vector<Frame>& frames,
    const CandidateSet& candidates,
    const std::vector<Eigen::Isometry3d>& poses) {
  // Checked once, on the coarsest level that has a usable overlap (cheap there); finer
  // levels see the same overlap with more detail.
  if (determined_checked_) return Next::kGoOn;
  ScopedSeconds timer(&result_->check_seconds.determination);
  double conditioning = 0.0;
  std::string why;
  if (!PosesDetermined(frames, candidates, poses, stream_, &conditioning, &why)) {
    if (level > 0) {
      LOG(INFO) << "skipping pyramid level " << level << ": " << why;
      return Next::kSkipLevel;
    }
    *error_ = why + " at the initial poses of the finest level";
    return Next::kError;
  }
  VLOG(1) << "level " << level << ": scaled Gauss-Newton conditioning " << conditioning;
  determined_checked_ = true;
  return Next::kGoOn;
}

CoarseToFine::Next CoarseToFine::JudgeLevelStart(int level,
                                                 int last_level,
                                                 const std::vector<Frame>& frames,
                                                 const CandidateSet& candidates,
                                                 const std::vector<Eigen::Isometry3d>& poses) {
  if (!unjudged_) return Next::kGoOn;
  // The coarser level's check could not judge some frames (their structure does not reach
  // as far as its lag, 2 sqrt 3 of its voxels: the phantom's at 16 mm); this level's finer
  // frames judge the poses it reached before its solve is paid for, so that a frame in a
  // wrong minimum is re-placed after the coarser level, where that is cheap.
  unjudged_ = false;
  std::vector<FrameStructure> structure;
  {
    ScopedSeconds timer(&result_->check_seconds.structure);
    structure = FrameStructures(frames, candidates, poses, stream_, photometric_);
  }
  std::string why;
  const std::vector<int> outliers =
      StructureOutliers(structure, options_.max_structure_fraction, &misfit_exempt_);
  if (StructureOutlier(structure, options_.max_structure_fraction, &why, &misfit_exempt_) &&
      !StructureExplainedByBrightness(level, frames, candidates)) {
    return Diverged(last_level,
                    why + " (judged on pyramid level " + std::to_string(level) +
                        "'s frames before its solve)",
                    outliers);
  }
  return Next::kGoOn;
}

CoarseToFine::Next CoarseToFine::SolveOnce(int level,
                                           const std::vector<Frame>& frames,
                                           const ImageGeometry& grid,
                                           CandidateSet candidates,
                                           LevelSolve record) {
  std::ostringstream prefix;
  prefix << "level " << level << "." << record.rebuild << " ";
  level_solve_.progress_prefix = options_.solve.progress_prefix + prefix.str();
  std::vector<float> intensities;
  const bool want_intensities = options_.mode == Mode::kDba && level == 0;
  if (!solver_(level_solve_, frames, candidates, SolvePoses(), photometric_, &record.report,
               want_intensities ? &intensities : nullptr, error_)) {
    return Next::kError;
  }
  // The solver's poses are in the problem's world (frame 0 moved in the mean gauge).
  const Eigen::Isometry3d solved_frame0 = record.report.frame_from_world[0];
  const std::vector<Eigen::Isometry3d> next = RelativeToFrame0(record.report.frame_from_world);
  std::vector<double> frame_motion(m_, 0.0);
  for (int i = 1; i < m_; ++i) {
    frame_motion[i] = MaxCornerMotionVoxels(frames[i], poses_[i], next[i]);
    record.max_motion_voxels = std::max(record.max_motion_voxels, frame_motion[i]);
  }
  result_->total_iterations += record.report.num_iterations;
  const bool usable = record.report.usable;
  if (usable) {
    poses_ = next;
    solve_world_ = solved_frame0;  // next[i] * frame 0's pose = the solver's pose i
    if (affine_) {
      CHECK_EQ(static_cast<int>(record.report.photometric.size()), m_)
          << "a photometric solve returned no estimate";
      photometric_ = record.report.photometric;
    }
  }
  if (level == 0) {
    result_->grid = OutputGrid(frames, grid);
    if (!intensities.empty()) {
      // DBA's intensities belong to the candidates' voxel centres in the solve's world,
      // which frame 0's pose after the solve maps to frame 0's coordinates (the identity
      // when frame 0 was held there): their image is the solve's grid placed by it.
      ImageGeometry placed = grid;
      placed.direction = solved_frame0.linear() * grid.direction;
      placed.origin_mm = solved_frame0 * grid.origin_mm;
      // One image per phase (DBA's intensities come phase by phase, n each).
      const int64_t n = candidates.num_voxels();
      result_->dba_intensities = Image(placed, 0.0f);
      result_->dba_later_phases.assign(intensities.size() / n - 1, Image(placed, 0.0f));
      for (int64_t v = 0; v < n; ++v) {
        result_->dba_intensities.voxels[candidates.voxel[v]] = intensities[v];
        for (size_t p = 0; p < result_->dba_later_phases.size(); ++p) {
          result_->dba_later_phases[p].voxels[candidates.voxel[v]] = intensities[(p + 1) * n + v];
        }
      }
    }
  }
  const double motion = record.max_motion_voxels;
  result_->solves.push_back(std::move(record));
  if (!usable) {
    result_->usable = false;
    result_->failure = "the solve at pyramid level " + std::to_string(level) +
                       " is not usable: " + result_->solves.back().report.termination;
    result_->frame_from_world = poses_;
    result_->photometric = photometric_;
    return Next::kEnd;
  }
  solved_ = true;
  last_candidates_ = std::move(candidates);
  last_motion_ = motion;
  last_frame_motion_ = std::move(frame_motion);
  return Next::kGoOn;
}

// EstimateBrightness's samples: about this many panorama voxels (rows of the grid); where the
// largest change they measure is not kBrightnessPrecision standard errors off the tolerance
// (on either side: a wrong side one time in 30,000), as many more as that standard error
// says are needed (below), up to all of them.
// Measured with 50,000 voxels: 0.4 % standard error on the paper's phantom sequence (the
// change 0.9 %), 1.1 % on an ultrasound-like MNI152 one (the change 40 %).
constexpr double kBrightnessVoxels = 80000.0;
constexpr double kBrightnessPrecision = 4.0;
// Where the first rows do not decide, the next take this many times the voxels the standard
// error's 1 / sqrt(voxels) law asks for: the error is itself estimated, from the rows.
constexpr double kBrightnessSpare = 1.5;

void CoarseToFine::UseAffine() {
  if (affine_) return;
  RegistrationOptions affine = options_;
  affine.photometric = PhotometricModel::kAffine;
  solver_ = MakeLevelSolver(affine);
  affine_ = true;
}

namespace {

// Every frame's structure statistics at verbosity 1, each line led by `what`.
void LogStructure(const std::string& what, const std::vector<FrameStructure>& structure) {
  if (!VLOG_IS_ON(1)) return;
  for (size_t f = 0; f < structure.size(); ++f) {
    VLOG(1) << what << " structure: frame " << f << " fraction " << structure[f].fraction
            << " significance " << structure[f].significance
            << (structure[f].judged ? "" : " (not judged)") << " pairs " << structure[f].pairs;
  }
}

// Each frame's mean and standard deviation over its valid cells (phase 0), from every
// kSpreadStride-th voxel where the frame has more than kSpreadVoxels (a prime stride: no
// alignment with the grid's rows; half a million samples fix both to a fraction of a per
// cent).
constexpr int64_t kSpreadVoxels = 2000000;
constexpr int64_t kSpreadStride = 7;
std::vector<std::pair<double, double>> FrameSpreads(const std::vector<Frame>& frames,
                                                    int num_threads) {
  std::vector<std::pair<double, double>> spread(frames.size(), {0.0, 0.0});
  ParallelFor(0, static_cast<int64_t>(frames.size()), num_threads, [&](int64_t i) {
    const Frame& f = frames[i];
    double sum = 0.0, sum2 = 0.0;
    int64_t n = 0;
    const int64_t voxels = f.geometry().NumVoxels();
    const int64_t stride = voxels > kSpreadVoxels ? kSpreadStride : 1;
    for (int64_t l = 0; l < voxels; l += stride) {
      if (!f.IsValidCell(l)) continue;
      const double v = f.values()[l];
      sum += v;
      sum2 += v * v;
      ++n;
    }
    if (n < 2) return;
    const double mean = sum / n;
    spread[i] = {mean, std::sqrt(std::max(0.0, sum2 / n - mean * mean))};
  });
  return spread;
}

// Each frame's change of intensity by `estimate`, at its mean minus and plus one standard
// deviation of its field of view (`spread`), over that deviation: the larger of the two and
// its standard error (frame 0, and frames without spread: 0).
std::vector<std::pair<double, double>> FrameChanges(
    const PhotometricEstimate& estimate, const std::vector<std::pair<double, double>>& spread) {
  std::vector<std::pair<double, double>> changes(spread.size(), {0.0, 0.0});
  for (size_t i = 1; i < spread.size(); ++i) {
    const double mean = spread[i].first, deviation = spread[i].second;
    if (!(deviation > 0.0)) continue;
    for (double x : {mean - deviation, mean + deviation}) {
      const double change = std::abs(estimate.Change(static_cast<int>(i), x)) / deviation;
      if (change > changes[i].first) {
        changes[i] = {change, estimate.ChangeStandardError(static_cast<int>(i), x) / deviation};
      }
    }
  }
  return changes;
}

}  // namespace

bool CoarseToFine::EstimateBrightness(const std::vector<Frame>& frames,
                                      std::vector<Photometric>* photometric,
                                      double* largest_change,
                                      int* worst,
                                      double* largest_error,
                                      bool refine,
                                      std::vector<std::pair<double, double>>* frame_changes) {
  ScopedSeconds timer(&result_->check_seconds.brightness);
  // The gains and offsets that best explain the frames at the poses reached, on a grid that
  // samples every frame at every sub-voxel phase (model/panorama.h): on frame 0's lattice,
  // half a voxel off it, frame 0's samples are the smoothest (trilinear interpolation at the
  // cell centre averages 8 voxels), and the others' gains come out about 1.5 % low with an
  // offset.
  const std::vector<Eigen::Isometry3d> poses = SolvePoses();
  ImageGeometry grid;
  std::string grid_error;
  if (!BuildPanoramaGrid(frames, poses, options_.panorama_spacing, &grid, &grid_error,
                         PanoramaSampling::kAllPhases)) {
    return false;  // no grid at these poses: the level's checks say why
  }
  const std::vector<std::pair<double, double>> spread =
      FrameSpreads(frames, options_.solve.num_threads);
  // Rows of the grid, about kBrightnessVoxels of the voxels the last solve had (two
  // parameters per frame need far fewer observations than the poses), more where the
  // estimate is not precise enough.
  const double voxels =
      static_cast<double>(std::max<int64_t>(1, result_->solves.back().candidate_voxels));
  std::vector<Photometric> start;  // the estimate on fewer rows, where there is one
  for (int keep = std::max(1, static_cast<int>(voxels / kBrightnessVoxels));;) {
    PhotometricEstimate estimate;
    std::string estimate_error;
    if (!EstimatePhotometricAtPoses(frames, BuildCandidates(frames, poses, grid, 0, keep), poses,
                                    stream_, &estimate, &estimate_error,
                                    start.empty() ? nullptr : &start)) {
      if (keep > 1) {
        keep = std::max(1, keep / 4);
        continue;
      }
      VLOG(1) << "brightness not estimated: " << estimate_error;
      return false;
    }
    start = estimate.photometric;
    const std::vector<std::pair<double, double>> changes = FrameChanges(estimate, spread);
    *largest_change = 0.0;
    *worst = 0;
    double standard_error = 0.0;
    for (int i = 1; i < m_; ++i) {
      if (changes[i].first > *largest_change) {
        *largest_change = changes[i].first;
        *worst = i;
        standard_error = changes[i].second;
      }
    }
    if (frame_changes != nullptr) *frame_changes = changes;
    VLOG(1) << "brightness on 1 in " << keep << " rows (" << estimate.voxels << " voxels, "
            << estimate.iterations << " iterations): largest change " << *largest_change
            << " (frame " << *worst << "), standard error " << standard_error;
    // Decided when the largest change stands kBrightnessPrecision standard errors off the
    // tolerance, on either side.
    const double gap = std::abs(*largest_change - kBrightnessTolerance);
    if (keep == 1 || !refine || gap >= kBrightnessPrecision * standard_error) {
      *photometric = estimate.photometric;
      if (largest_error != nullptr) *largest_error = standard_error;
      return true;
    }
    // The standard error falls as one over the root of the voxels: the rows that bring it to
    // gap / kBrightnessPrecision, with kBrightnessSpare to spare (all rows where the gap is 0).
    double more = kBrightnessSpare * std::pow(kBrightnessPrecision * standard_error / gap, 2);
    if (!(more > 1.0 && more < keep)) more = keep;  // also a gap of 0 or an error not finite
    keep = std::clamp(static_cast<int>(keep / more), 1, keep - 1);
  }
}

bool CoarseToFine::AutoPhotometricUndecided() const {
  return options_.photometric == PhotometricModel::kAuto && result_->photometric_choice.empty() &&
         !affine_ && ModeEstimatesPhotometric(options_.mode);
}

void CoarseToFine::DetectBrightness(const std::vector<Frame>& frames) {
  if (result_->photometric_unconfirmed && solved_) {
    ConfirmBrightness(frames);
    return;
  }
  if (!AutoPhotometricUndecided() || !solved_) return;
  // At the final poses, once every check passed (at a coarse level, or at poses a check
  // refuses, the estimates also explain whatever is not yet in line: on the phantom's paper
  // protocol the coarsest level's changed intensities by up to 3.4 % of their spread where
  // the poses were right, 26-42 % where they were a wrong minimum).
  std::vector<Photometric> estimate;
  double largest = 0.0;
  int worst = 0;
  if (!EstimateBrightness(frames, &estimate, &largest, &worst)) return;
  result_->photometric_detected = largest > kBrightnessTolerance;
  std::ostringstream why;
  why.precision(2);
  why << (result_->photometric_detected ? "affine" : "none") << " (photometric=auto: at the "
      << (result_->photometric_detected ? "first round's " : "") << "final poses the gains and "
      << "offsets change a frame's intensities by up to " << 100.0 * largest
      << "% of their spread, frame " << worst << "; the limit is "
      << 100.0 * kBrightnessTolerance << "%)";
  result_->photometric_choice = why.str();
}

void CoarseToFine::ConfirmBrightness(const std::vector<Frame>& frames) {
  // The same estimate as DetectBrightness's, at the final poses the solves with gains and
  // offsets reached (it estimates them afresh from the frames' own intensities).
  result_->photometric_unconfirmed = false;
  std::vector<Photometric> estimate;
  double largest = 0.0;
  int worst = 0;
  std::ostringstream why;
  why.precision(2);
  if (!EstimateBrightness(frames, &estimate, &largest, &worst)) {
    return;  // no estimate at these poses: the coarse level's stands
  }
  if (largest > kBrightnessTolerance) {
    // "...; the limit is 3%)" becomes "...; at the final poses they change a frame's
    // intensities by up to X%, frame W; the limit is 3%)".
    std::string& choice = result_->photometric_choice;
    why << "; at the final poses they change a frame's intensities by up to " << 100.0 * largest
        << "%, frame " << worst;
    const size_t limit = choice.rfind("; the limit is");
    choice.insert(limit == std::string::npos ? choice.size() : limit, why.str());
    return;
  }
  // Not brightness: what the coarse level measured was its poses' error. The pipeline
  // registers once more without them from these poses (RunRounds).
  result_->photometric_detected = false;
  why << "none (photometric=auto: at the final poses the gains and offsets change a frame's "
      << "intensities by up to " << 100.0 * largest << "% of their spread, frame " << worst
      << "; the limit is " << 100.0 * kBrightnessTolerance << "%; "
      << result_->photometric_early_evidence << ")";
  result_->photometric_choice = why.str();
}

void CoarseToFine::DetectBrightnessEarly(int level, const std::vector<Frame>& frames) {
  // The last coarse level's poses are within a fraction of its voxels, and the estimate
  // there reads every row of a small grid. The coarsest level's are not close enough: on
  // sequences without brightness differences its estimates changed intensities by up to 6 %
  // (3 standard errors over the limit), against 0.4-1.5 % at level 1, and 44-89 % at level 1
  // where the gains differ by up to 15 %. Only a change clearly over the limit decides here, so
  // that the finest level estimates the gains and offsets (the final poses would otherwise have
  // found them and registered again); anything else is left to the final poses. The final
  // poses still judge (ConfirmBrightness): a coarse level's pose error can look like
  // brightness, which its standard error (of the noise) does not count.
  if (level != 1 || !AutoPhotometricUndecided() || !solved_) return;
  std::vector<Photometric> estimate;
  double largest = 0.0, standard_error = 0.0;
  int worst = 0;
  if (!EstimateBrightness(frames, &estimate, &largest, &worst, &standard_error,
                          /*refine=*/false) ||
      largest - kBrightnessPrecision * standard_error <= kBrightnessTolerance) {
    return;
  }
  result_->photometric_detected = true;
  std::ostringstream why;
  why.precision(2);
  why << "affine (photometric=auto: at pyramid level " << level << " the gains and offsets "
      << "change a frame's intensities by up to " << 100.0 * largest << "% of their spread, "
      << "frame " << worst << " (standard error " << 100.0 * standard_error << "%); the limit "
      << "is " << 100.0 * kBrightnessTolerance << "%)";
  result_->photometric_choice = why.str();
  result_->photometric_unconfirmed = true;
  std::ostringstream evidence;
  evidence.precision(2);
  evidence << "pyramid level 1's poses had put it at " << 100.0 * largest << "%";
  result_->photometric_early_evidence = evidence.str();
  UseAffine();
  photometric_ = estimate;
}

void CoarseToFine::SuspectBrightness(const std::vector<Frame>& frames) {
  // A frame that slid or sits in a wrong minimum gets whatever gain explains its wrong place,
  // and the frames around it some of that; brightness differences between acquisitions give
  // every frame its own gain. Without them the coarsest level's estimates reached 6 % (3
  // standard errors over the limit) where the poses were right; with gains within 15 % they
  // are tens of per cent.
  if (result_->usable || !AutoPhotometricUndecided() || !result_->recoveries.empty() ||
      result_->solves.empty() || result_->solves.back().level == 0 || m_ < 3) {
    return;
  }
  std::vector<Photometric> estimate;
  double largest = 0.0;
  int worst = 0;
  std::vector<std::pair<double, double>> changes;
  if (!EstimateBrightness(frames, &estimate, &largest, &worst, nullptr, /*refine=*/false,
                          &changes)) {
    // A frame slid so far that nothing fixes its gain (an ultrasound-like chest CT
    // sequence): the round's start poses, where the frames overlapped.
    const std::vector<Eigen::Isometry3d> reached = poses_;
    poses_ = round_start_;
    const bool estimated = EstimateBrightness(frames, &estimate, &largest, &worst, nullptr,
                                              /*refine=*/false, &changes);
    poses_ = reached;
    if (!estimated) return;
  }
  int clear = 0;
  for (int i = 1; i < m_; ++i) {
    if (changes[i].first - kBrightnessPrecision * changes[i].second > kBrightnessTolerance) {
      ++clear;
    }
  }
  VLOG(1) << "after the failed round: " << clear << " of " << m_ - 1 << " frames' brightness "
          << "clearly changed (the largest by " << largest << ", frame " << worst << ")";
  result_->brightness_suspected = 2 * clear >= m_ - 1;
}

bool CoarseToFine::StructureExplainedByBrightness(int level,
                                                  const std::vector<Frame>& frames,
                                                  const CandidateSet& candidates) {
  if (!AutoPhotometricUndecided()) return false;
  // Frames of different brightness (gains, offsets) leave structure in each other's
  // differences that is not anatomy out of line. If the frames line up once the gains and
  // offsets that best explain them are estimated at these poses, that was it: the solves
  // estimate them from here on. A wrong minimum stays: a gain or an offset cannot line up
  // anatomy (the structure fraction is a ratio of the frame's own covariances, which its
  // gain scales alike).
  std::vector<Photometric> estimate;
  double largest = 0.0;
  int worst = 0;
  if (!EstimateBrightness(frames, &estimate, &largest, &worst)) return false;
  std::vector<FrameStructure> corrected;
  {
    ScopedSeconds timer(&result_->check_seconds.structure);
    corrected = FrameStructures(frames, candidates, SolvePoses(), stream_, estimate);
  }
  if (VLOG_IS_ON(1)) {
    for (size_t f = 0; f < corrected.size(); ++f) {
      VLOG(1) << "level " << level << " structure with the estimated gains and offsets: frame "
              << f << " fraction " << corrected[f].fraction << " significance "
              << corrected[f].significance << " (gain " << estimate[f].gain() << ", offset "
              << estimate[f].offset << ")";
    }
  }
  if (!StructureOutliers(corrected, options_.max_structure_fraction, &misfit_exempt_).empty()) {
    return false;
  }
  result_->photometric_detected = true;
  std::ostringstream why;
  why.precision(2);
  why << "affine (photometric=auto: at pyramid level " << level << " the frames' differences "
      << "showed structure that the gains and offsets explain, changing a frame's intensities "
      << "by up to " << 100.0 * largest << "% of their spread, frame " << worst << ")";
  result_->photometric_choice = why.str();
  UseAffine();
  photometric_ = estimate;
  return true;
}

CoarseToFine::Next CoarseToFine::CheckCoarseLevel(int level, const std::vector<Frame>& frames) {
  // With recovery, a frame in a wrong minimum is caught here, on a coarse level, where
  // re-placing it and starting again costs little. The misfits are those of the last
  // solve's candidates (at the poses it reached, up to the rebuild tolerance).
  if (!check_every_level_ || !solved_) return Next::kGoOn;
  std::string why;
  if (options_.max_misfit_ratio > 0.0) {
    const std::vector<double> misfits =
        FrameMisfits(frames, last_candidates_, SolvePoses(), stream_, photometric_);
    if (MisfitOutlier(misfits, options_.max_misfit_ratio, &why, &misfit_exempt_)) {
      result_->flagged_by_misfit = true;
      return Diverged(level, why,
                      MisfitOutliers(misfits, options_.max_misfit_ratio, &misfit_exempt_));
    }
  }
  if (options_.max_structure_fraction > 0.0) {
    std::vector<FrameStructure> structure;
    {
      ScopedSeconds timer(&result_->check_seconds.structure);
      structure = FrameStructures(frames, last_candidates_, SolvePoses(), stream_, photometric_);
    }
    unjudged_ = std::any_of(structure.begin(), structure.end(),
                            [](const FrameStructure& f) { return !f.judged; });
    LogStructure("level " + std::to_string(level), structure);
    const std::vector<int> outliers =
        StructureOutliers(structure, options_.max_structure_fraction, &misfit_exempt_);
    if (StructureOutlier(structure, options_.max_structure_fraction, &why, &misfit_exempt_) &&
        !StructureExplainedByBrightness(level, frames, last_candidates_)) {
      return Diverged(level, why, outliers);
    }
  }
  std::vector<int> flagged;
  if (options_.max_pair_mismatch_ratio > 0.0 &&
      PairDisagreement(PairMismatches(search_frames_, poses_, options_.solve.num_threads), m_,
                       options_.max_pair_mismatch_ratio, &flagged, &why)) {
    return Diverged(level, why, flagged);
  }
  // A coarse level whose last solve (every rebuild used) still slid frames by more than
  // unsettled_motion_voxels has found no minimum: on the benchmarks' wide protocol no such
  // level was followed by a usable registration, and the finer levels then cost the most
  // for nothing. The sliding frames are named (with more than a third, the pair graph
  // places all). Creeping by less (photometric parameters make coarse levels converge
  // slowly) goes on to the finer levels. Only where rebuilds were allowed: the pair-based
  // baselines solve once per level and move their frames by whole voxels in that one solve.
  const double unsettled_voxels =
      std::max(options_.rebuild_tolerance, options_.unsettled_motion_voxels);
  if (max_rebuilds_ > 0 && last_motion_ > unsettled_voxels) {
    std::vector<int> sliding;
    for (int i = 1; i < m_; ++i) {
      if (last_frame_motion_[i] > unsettled_voxels) sliding.push_back(i);
    }
    std::ostringstream unsettled;
    unsettled << "pyramid level " << level << " did not settle: its last solve (of "
              << max_rebuilds_ + 1 << ") still moved " << sliding.size()
              << (sliding.size() == 1 ? " frame" : " frames") << " by up to "
              << std::setprecision(3) << last_motion_ << " voxels (more than "
              << unsettled_voxels << ")";
    return Diverged(level, unsettled.str(), sliding);
  }
  return Next::kGoOn;
}

CoarseToFine::Next CoarseToFine::FinalCandidates(const std::vector<Frame>& frames,
                                                 const std::vector<Eigen::Isometry3d>& poses,
                                                 CandidateSet* candidates) {
  // When the last solve moved no field-of-view corner by more than the rebuild tolerance,
  // its candidates stand for the final poses' (as the rebuild rule has it); otherwise
  // candidates are built at the final poses.
  if (last_motion_ <= options_.rebuild_tolerance) {
    *candidates = std::move(last_candidates_);
    return Next::kGoOn;
  }
  ImageGeometry final_grid;
  if (!BuildPanoramaGrid(frames, poses, options_.panorama_spacing, &final_grid, error_,
                         options_.panorama_sampling)) {
    const std::string why = "diverged: the solve moved the frames far apart (" + *error_ + ")";
    error_->clear();
    return Diverged(0, why, {});
  }
  *candidates = BuildCandidates(frames, poses, final_grid, 0);
  return Next::kGoOn;
}

CoarseToFine::Next CoarseToFine::CheckFinalPoses(const std::vector<Frame>& frames) {
  // The final candidates and poses, both in the last problem's world (the poses relative to
  // frame 0 are the same in any).
  const std::vector<Eigen::Isometry3d> poses = SolvePoses();
  CandidateSet final_candidates;
  Next next;
  {
    ScopedSeconds timer(&result_->check_seconds.other);
    next = FinalCandidates(frames, poses, &final_candidates);
  }
  if (next != Next::kGoOn) return next;
  std::string why;
  std::vector<int> slid;
  if (options_.min_kept_overlap > 0.0 && guard_.Diverged(frames, final_candidates, &why, &slid)) {
    return Diverged(0, why, slid);
  }
  // DSR's last pass was at the final poses over these candidates when the solve kept it
  // (stream/streamed_cost.h): its per-frame costs are the misfits' sums. With photometric
  // parameters the misfits are always measured here, on corrected intensities.
  const SolveReport& last = result_->solves.back().report;
  const bool reuse_last_pass = options_.mode == Mode::kDsr && !affine_ &&
                               last_motion_ <= options_.rebuild_tolerance &&
                               static_cast<int>(last.final_frame_cost.size()) == m_;
  if (reuse_last_pass) {
    result_->frame_misfits =
        MisfitsFromFrameCosts(last.final_frame_cost, last.final_frame_observations);
  } else {
    ScopedSeconds timer(&result_->check_seconds.other);
    result_->frame_misfits =
        FrameMisfits(frames, final_candidates, poses, stream_, photometric_);
  }
  if (MisfitOutlier(result_->frame_misfits, options_.max_misfit_ratio, &why, &misfit_exempt_)) {
    result_->flagged_by_misfit = true;
    return Diverged(0, why, MisfitOutliers(result_->frame_misfits, options_.max_misfit_ratio,
                                           &misfit_exempt_));
  }
  // The structure statistics are measured on every run (the summary reports them), the
  // check only where it is on.
  {
    ScopedSeconds timer(&result_->check_seconds.structure);
    result_->frame_structure =
        FrameStructures(frames, final_candidates, poses, stream_, photometric_);
  }
  const std::vector<int> outliers = StructureOutliers(
      result_->frame_structure, options_.max_structure_fraction, &misfit_exempt_);
  if (StructureOutlier(result_->frame_structure, options_.max_structure_fraction, &why,
                       &misfit_exempt_) &&
      !StructureExplainedByBrightness(0, frames, final_candidates)) {
    return Diverged(0, why, outliers);
  }
  next = CheckLaterPhases(frames, final_candidates, poses);
  if (next != Next::kGoOn) return next;
  std::vector<int> flagged;
  if (options_.max_pair_mismatch_ratio > 0.0 &&
      PairDisagreement(PairMismatches(search_frames_, poses_, options_.solve.num_threads), m_,
                       options_.max_pair_mismatch_ratio, &flagged, &why)) {
    return Diverged(0, why, flagged);
  }
  // --uncertainty's sums over all the final candidates serve the determination check too:
  // one pass, one covariance.
  std::unique_ptr<UncertaintySums> all_sums;
  if (EstimatesUncertainty()) {
    ScopedSeconds timer(&result_->check_seconds.uncertainty);
    all_sums = std::make_unique<UncertaintySums>(
        SumForUncertainty(frames, final_candidates, poses, stream_.num_threads));
  }
  next = CheckFinalDetermination(frames, final_candidates, poses, all_sums.get());
  if (next != Next::kGoOn) return next;
  DetectBrightness(frames);
  EstimateUncertainty(frames, all_sums.get());
  return Next::kGoOn;
}

CoarseToFine::Next CoarseToFine::CheckLaterPhases(const std::vector<Frame>& frames,
                                                   const CandidateSet& candidates,
                                                   const std::vector<Eigen::Isometry3d>& poses) {
  // Every view's phases share its one pose (docs/design.md section 12). Where phase 0 lines
  // up, a later phase that does not (the probe moved within the loop: the tied model is
  // false for that view, and its pose is the best compromise of phases that disagree) shows
  // its anatomy in its differences to the other views' same phase, as a frame in a wrong
  // minimum does. No start fixes it: refused naming the phase and the frames that show it.
  if (!(options_.max_structure_fraction > 0.0)) return Next::kGoOn;
  const int phases = NumPhases(frames);
  for (int p = 1; p < phases; ++p) {
    std::vector<FrameStructure> structure;
    {
      ScopedSeconds timer(&result_->check_seconds.structure);
      structure = FrameStructures(PhaseFrames(frames, p), candidates, poses, stream_,
                                  photometric_);
    }
    LogStructure("phase " + std::to_string(p), structure);
    const std::vector<int> outliers =
        StructureOutliers(structure, options_.max_structure_fraction, &misfit_exempt_);
    if (outliers.empty()) continue;
    const int worst = outliers.front();
    const FrameStructure& s = structure[worst];
    std::ostringstream why;
    why.precision(3);
    why << "phase " << p << " does not line up across the frames at the poses their phase 0 "
        << "fixes: " << 100.0 * s.fraction << "% of frame " << worst << "'s own structure "
        << "remains in its differences to the panorama (" << s.significance
        << " standard errors of noise alone; max_structure_fraction="
        << options_.max_structure_fraction << "; frame" << (outliers.size() > 1 ? "s " : " ");
    for (size_t k = 0; k < outliers.size(); ++k) why << (k > 0 ? ", " : "") << outliers[k];
    why << " above it). A view's phases share one pose: the probe moved during the loop in "
        << "one of the views, or a phase is not of its view; register the phases that agree "
        << "(--phases), or one phase";
    return Diverged(0, why.str(), {});
  }
  return Next::kGoOn;
}

CoarseToFine::Next CoarseToFine::CheckFinalDetermination(
    const std::vector<Frame>& frames,
    const CandidateSet& candidates,
    const std::vector<Eigen::Isometry3d>& poses,
    const UncertaintySums* all_sums) {
  // Poses the data do not fix (a symmetric object): refused without naming frames to
  // re-place, since no start would fix them either. With gains and offsets too, on the
  // corrected frames (three views of 32^3 voxels, gains 15.7 and 0.0001 at poses 37 mm off,
  // were accepted while the check skipped such runs: the cost does not curve up along two
  // frames' rotations there).
  if (options_.max_pose_error_voxels > 0.0 && ModeEstimatesPhotometric(options_.mode) &&
      options_.loss.IsSquared()) {
    ScopedSeconds timer(&result_->check_seconds.determination);
    std::vector<UndeterminedPose> undetermined;
    std::string not_judged;
    if (UndeterminedPoses(frames, candidates, poses, masks_, stream_,
                          options_.max_pose_error_voxels, &undetermined, &not_judged,
                          &result_->pose_error_voxels, all_sums,
                          affine_ && static_cast<int>(photometric_.size()) == m_
                              ? &photometric_
                              : nullptr) &&
        !undetermined.empty()) {
      std::ostringstream why;
      why << UndeterminedPhrase(undetermined)
          << " (max_pose_error_voxels=" << options_.max_pose_error_voxels << ")";
      result_->poses_undetermined = true;
      return Diverged(0, why.str(), {});
    }
  }
  return Next::kGoOn;
}

bool CoarseToFine::EstimatesUncertainty() const {
  return options_.uncertainty && !affine_ && options_.loss.IsSquared() &&
         (options_.mode == Mode::kDsr || options_.mode == Mode::kDba);
}

void CoarseToFine::EstimateUncertainty(const std::vector<Frame>& frames,
                                       const UncertaintySums* sums) {
  if (!options_.uncertainty) return;
  ScopedSeconds timer(&result_->check_seconds.uncertainty);
  if (affine_) {
    // The estimate linearises the poses' stopping rule alone (pipeline/uncertainty.h); the
    // gains and offsets solved with them would change both its gradient and its derivative.
    result_->uncertainty_note =
        "the pose uncertainty does not model the photometric parameters "
        "(photometric=affine)";
  } else if (!options_.loss.IsSquared()) {
    // Its noise model is the squared differences' (pipeline/uncertainty.h).
    result_->uncertainty_note = "the pose uncertainty does not model the robust loss (loss=" +
                                std::string(RobustLossKindName(options_.loss.kind)) + ")";
  } else if (sums != nullptr &&
             !EstimatePoseUncertainty(*sums, frames, masks_, &result_->uncertainty,
                                      &result_->uncertainty_note)) {
    result_->uncertainty = PoseUncertainty();
  }
}

}  // namespace dsr
