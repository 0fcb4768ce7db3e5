#include "dsr/pipeline/registration.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <iomanip>
#include <limits>
#include <sstream>

#include <glog/logging.h>

#include "dsr/baselines/baselines.h"
#include "dsr/dba/dba_problem.h"
#include "dsr/dsr_reduced/dsr_solver.h"
#include "dsr/dsr_reduced/reduced_cost.h"
#include "dsr/image/pyramid.h"
#include "dsr/init/pair_graph.h"
#include "dsr/init/recovery.h"
#include "dsr/model/panorama.h"
#include "dsr/pipeline/divergence_guard.h"
#include "dsr/pipeline/input_checks.h"
#include "dsr/pipeline/pair_check.h"
#include "dsr/solve/convergence.h"
#include "dsr/util/parallel.h"

namespace dsr {
namespace {

double Seconds(std::chrono::steady_clock::time_point since) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - since).count();
}

BaselineOptions ToBaselineOptions(const RegistrationOptions& options, const SolveOptions& solve) {
  BaselineOptions baseline;
  baseline.solve = solve;
  baseline.panorama_spacing = options.panorama_spacing;
  baseline.min_shared_voxels = options.min_shared_voxels;
  baseline.num_chunks = options.dsr_num_chunks;
  return baseline;
}

// The solver options of modes dsr and dba (without their start).
DsrOptions ToDsrOptions(const RegistrationOptions& options, const SolveOptions& solve) {
  DsrOptions dsr;
  dsr.solve = solve;
  dsr.num_chunks = options.dsr_num_chunks;
  dsr.reference_cost = options.dsr_reference_cost;
  dsr.photometric = options.photometric == PhotometricModel::kAffine;
  dsr.loss = options.loss;
  return dsr;
}

DbaOptions ToDbaOptions(const RegistrationOptions& options, const SolveOptions& solve) {
  DbaOptions dba;
  dba.solve = solve;
  dba.memory_budget_bytes = options.dba_memory_budget_bytes;
  dba.photometric = options.photometric == PhotometricModel::kAffine;
  dba.loss = options.loss;
  return dba;
}

// Runs the mode's solver once with the candidates fixed. With photometric parameters they
// start at `photometric` (one per frame, frame 0 the gauge; empty: every gain 1, offset 0)
// and the estimate is in report->photometric.
bool SolveOnce(const RegistrationOptions& options,
               const SolveOptions& solve,
               const std::vector<Frame>& frames,
               const CandidateSet& candidates,
               const std::vector<Eigen::Isometry3d>& initial,
               const std::vector<Photometric>& photometric,
               SolveReport* report,
               std::vector<float>* dba_intensities,
               std::string* error) {
  if (options.mode == "dsr") {
    DsrOptions dsr = ToDsrOptions(options, solve);
    if (dsr.photometric) dsr.initial_photometric = photometric;
    return SolveDsr(frames, candidates, initial, dsr, report, error);
  }
  if (options.mode == "dba") {
    DbaOptions dba = ToDbaOptions(options, solve);
    if (dba.photometric) dba.initial_photometric = photometric;
    return SolveDba(frames, candidates, initial, dba, report, dba_intensities, error);
  }
  BaselineOptions baseline = ToBaselineOptions(options, solve);
  if (options.mode == "ape") return SolveApe(frames, candidates, initial, baseline, report, error);
  if (options.mode == "pairwise") return SolvePairwise(frames, initial, baseline, report, error);
  if (options.mode == "lie_normalization") {
    return SolveLieNormalization(frames, candidates, initial, baseline, report, error);
  }
  if (options.mode == "sequential") return SolveSequential(frames, initial, baseline, report, error);
  *error = "--mode=" + options.mode + ": unknown mode";
  return false;
}

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

// Checks that the overlap determines every free pose: the Gauss-Newton matrix of the
// shared cost at `poses`, Jacobi-scaled (so millimetres and radians compare), must not be
// numerically singular. Otherwise `why` names the frame the weakest direction moves most.
bool PosesDetermined(const std::vector<Frame>& frames,
                     const CandidateSet& candidates,
                     const std::vector<Eigen::Isometry3d>& poses,
                     int num_threads,
                     double* conditioning,
                     std::string* why) {
  const int m = static_cast<int>(frames.size());
  const int n = 6 * (m - 1);
  ReducedSystem system;
  AccumulateReducedSystem(frames, candidates, poses, 0, candidates.num_voxels(), true,
                          num_threads, &system);
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

}  // namespace

std::vector<std::string> ModeNames() {
  return {"dsr", "dba", "pairwise", "lie_normalization", "sequential", "ape"};
}

bool StringToPhotometricModel(const std::string& name, PhotometricModel* model) {
  for (PhotometricModel m : {PhotometricModel::kNone, PhotometricModel::kAffine}) {
    if (name == PhotometricModelToString(m)) {
      *model = m;
      return true;
    }
  }
  return false;
}

bool ModeEstimatesPhotometric(const std::string& mode) { return mode == "dsr" || mode == "dba"; }

std::vector<std::string> InitialisationNames() {
  return {"auto", "identity", "pairwise", "global"};
}

bool SetInitialisation(const std::string& name, int max_recoveries, RegistrationOptions* options) {
  options->init = name == "pairwise" ? InitialPoses::kPairwise
                  : name == "global" ? InitialPoses::kGlobal
                                     : InitialPoses::kGiven;
  options->max_recoveries = name == "identity" || name == "pairwise" ? 0 : max_recoveries;
  const std::vector<std::string> names = InitialisationNames();
  return std::find(names.begin(), names.end(), name) != names.end();
}

bool RegistrationOptions::Validate(std::string* error) const {
  const std::vector<std::string> modes = ModeNames();
  if (std::find(modes.begin(), modes.end(), mode) == modes.end()) {
    std::string list;
    for (const std::string& m : modes) list += (list.empty() ? "" : "|") + m;
    *error = "--mode=" + mode + ": unknown mode (one of " + list + ")";
    return false;
  }
  if (!solve.Validate(error)) return false;
  auto bad = [&](const std::string& flag, const std::string& value, const std::string& rule) {
    *error = "--" + flag + "=" + value + ": " + rule;
    return false;
  };
  if (!(panorama_spacing > 0.0) || !std::isfinite(panorama_spacing)) {
    return bad("panorama_spacing", std::to_string(panorama_spacing), "must be a positive number");
  }
  if (pyramid_levels < 1 || pyramid_levels > 8) {
    return bad("pyramid_levels", std::to_string(pyramid_levels), "must be in 1..8");
  }
  if (!(pyramid_sigma_voxels >= 0.0) || !std::isfinite(pyramid_sigma_voxels)) {
    return bad("pyramid_sigma", std::to_string(pyramid_sigma_voxels), "must be >= 0");
  }
  if (!(finest_sigma_voxels >= 0.0) || !std::isfinite(finest_sigma_voxels)) {
    return bad("smoothing", std::to_string(finest_sigma_voxels), "must be >= 0");
  }
  if (pyramid_min_size < 4) {
    return bad("pyramid_min_size", std::to_string(pyramid_min_size), "must be >= 4");
  }
  if (coarse_max_iterations < 1) {
    return bad("coarse_max_iterations", std::to_string(coarse_max_iterations), "must be >= 1");
  }
  if (max_rebuilds < 0) return bad("max_rebuilds", std::to_string(max_rebuilds), "must be >= 0");
  if (!(rebuild_tolerance_voxels > 0.0)) {
    return bad("rebuild_tolerance", std::to_string(rebuild_tolerance_voxels), "must be > 0");
  }
  if (!(unsettled_motion_voxels >= 0.0 && std::isfinite(unsettled_motion_voxels))) {
    *error = "RegistrationOptions::unsettled_motion_voxels=" +
             std::to_string(unsettled_motion_voxels) + ": must be finite and >= 0";
    return false;
  }
  if (!(min_kept_overlap >= 0.0 && min_kept_overlap < 1.0)) {
    return bad("min_kept_overlap", std::to_string(min_kept_overlap), "must be in [0, 1)");
  }
  if (!(max_misfit_ratio == 0.0 || (max_misfit_ratio > 1.0 && std::isfinite(max_misfit_ratio)))) {
    return bad("max_misfit_ratio", std::to_string(max_misfit_ratio), "must be 0 (off) or > 1");
  }
  if (!(max_pair_mismatch_ratio == 0.0 ||
        (max_pair_mismatch_ratio > 1.0 && std::isfinite(max_pair_mismatch_ratio)))) {
    return bad("max_pair_mismatch_ratio", std::to_string(max_pair_mismatch_ratio),
               "must be 0 (off) or > 1");
  }
  if (min_shared_voxels < 1) {
    return bad("min_shared_voxels", std::to_string(min_shared_voxels), "must be >= 1");
  }
  if (max_recoveries < 0 || max_recoveries > 10) {
    return bad("max_recoveries", std::to_string(max_recoveries), "must be in [0, 10]");
  }
  if (max_recoveries > 0 && max_misfit_ratio == 0.0 && min_kept_overlap == 0.0 &&
      max_pair_mismatch_ratio == 0.0) {
    return bad("max_recoveries", std::to_string(max_recoveries),
               "recovery needs a check that flags frames: --max_misfit_ratio, "
               "--max_pair_mismatch_ratio or --min_kept_overlap must not be 0");
  }
  if (search_max_axis_voxels < 8) {
    return bad("search_max_axis", std::to_string(search_max_axis_voxels), "must be >= 8");
  }
  if ((max_recoveries > 0 || init == InitialPoses::kGlobal) && !search.Validate(error)) {
    return false;
  }
  if (!loss.Validate(error)) return false;
  if (!loss.IsSquared() && !ModeEstimatesPhotometric(mode)) {
    return bad("loss", RobustLossKindName(loss.kind),
               "needs --mode=dsr or dba (--mode=" + mode + " is a baseline with squared differences)");
  }
  const bool affine = photometric == PhotometricModel::kAffine;
  if (affine && !ModeEstimatesPhotometric(mode)) {
    return bad("photometric", PhotometricModelToString(photometric),
               "needs --mode=dsr or dba (--mode=" + mode +
                   " is a baseline without photometric parameters; use --photometric=none)");
  }
  // Each solver's own rules first without the photometric parameters, so that an error of
  // theirs with them is the flag's.
  if (mode == "dsr" || mode == "dba") {
    RegistrationOptions plain = *this;
    plain.photometric = PhotometricModel::kNone;
    const bool valid = mode == "dsr" ? ToDsrOptions(plain, solve).Validate(error)
                                     : ToDbaOptions(plain, solve).Validate(error);
    if (!valid) return false;
    if (affine && !(mode == "dsr" ? ToDsrOptions(*this, solve).Validate(error)
                                  : ToDbaOptions(*this, solve).Validate(error))) {
      *error = "--photometric=affine: " + *error;
      return false;
    }
  }
  if (mode != "dsr" && mode != "dba" && !ToBaselineOptions(*this, solve).Validate(error)) {
    return false;
  }
  return true;
}

namespace {

// The pyramids of every frame, finest level first (level 0 empty: the input itself).
struct Pyramids {
  std::vector<std::vector<ImageLevel>> levels;  // [frame][level]
  int num_levels = 0;                           // common to every frame
};

// Frames of one pyramid level. When `release` is set, the level's images are freed once
// the frames hold their copies (no recovery can come back to them).
std::vector<Frame> LevelFrames(const std::vector<Image>& images,
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
    frames[i] = input_is_level ? Frame(images[i], masks[i]) : Frame(stored.image, stored.mask);
    if (release) stored = ImageLevel();
  });
  return frames;
}

// The frames the global search works on: the coarsest pyramid level, halved further until
// no axis is longer than options.search_max_axis_voxels.
std::vector<Frame> SearchFrames(const std::vector<Image>& images,
                                const std::vector<Mask>& masks,
                                const Pyramids& pyramids,
                                const RegistrationOptions& options) {
  const int m = static_cast<int>(images.size());
  const int coarsest = pyramids.num_levels - 1;
  std::vector<Frame> frames(m);
  ParallelFor(0, m, options.solve.num_threads, [&](int64_t i) {
    const ImageLevel& stored = pyramids.levels[i][coarsest];
    ImageLevel level = stored.image.empty() ? ImageLevel{images[i], masks[i]} : stored;
    while (level.image.geometry.size.maxCoeff() > options.search_max_axis_voxels &&
           level.image.geometry.size.minCoeff() >= 8) {
      ImageLevel next = Downsample(level.image, level.mask, options.pyramid_sigma_voxels, 1);
      if (CountInside(next.mask) == 0) break;
      level = std::move(next);
    }
    frames[i] = Frame(level.image, level.mask);
  });
  return frames;
}

// The coarse-to-fine solves from `start_poses`: every level's solves with candidate
// rebuilds, the divergence guard at each rebuild and the checks of the final poses; with
// `check_every_level`, the misfit check also after each coarse level; frames marked in
// `misfit_exempt` are never the misfit check's outlier. With photometric parameters they
// start at gain 1 and offset 0, each solve from the previous one's estimate, and end in
// result->photometric. Returns false for bad input or set-up problems; a registration that
// is not usable returns true with result->usable = false, result->failure and
// result->flagged_frames.
bool SolveLevels(const std::vector<Image>& images,
                 const std::vector<Mask>& masks,
                 const std::vector<Eigen::Isometry3d>& start_poses,
                 const RegistrationOptions& options,
                 bool check_every_level,
                 const std::vector<bool>& misfit_exempt,
                 const std::vector<Frame>& search_frames,
                 Pyramids* pyramids,
                 RegistrationResult* result,
                 std::string* error) {
  const int m = static_cast<int>(images.size());
  std::vector<Eigen::Isometry3d> poses = start_poses;
  // The current gains and offsets (empty: 1 and 0, or no photometric parameters). The
  // checks compare frames on frame 0's intensity scale through them (FrameMisfits).
  std::vector<Photometric> photometric;
  const bool affine = options.photometric == PhotometricModel::kAffine;
  result->photometric.clear();
  result->usable = true;
  result->flagged_frames.clear();
  result->flagged_by_misfit = false;
  result->failure.clear();
  bool determined_checked = false;
  DivergenceGuard guard(options.min_kept_overlap);
  // Ends the registration as not usable: the poses reached do not register the frames.
  const auto diverged = [&](int level, const std::string& why, std::vector<int> flagged) {
    result->usable = false;
    result->failure = "not usable after the solve at pyramid level " + std::to_string(level) +
                      ": " + why;
    result->flagged_frames = std::move(flagged);
    result->frame_from_world = poses;
    result->photometric = photometric;
    return true;
  };
  const bool release = options.max_recoveries == 0;
  const int levels = pyramids->num_levels;
  for (int level = levels - 1; level >= 0; --level) {
    std::vector<Frame> frames =
        LevelFrames(images, masks, pyramids, level, release, options.solve.num_threads);
    int empty_frame = -1;
    for (int i = m - 1; i >= 0; --i) {
      if (frames[i].num_valid_cells() == 0) empty_frame = i;
    }
    if (empty_frame >= 0) {
      if (level > 0) {
        LOG(INFO) << "skipping pyramid level " << level << ": frame " << empty_frame
                  << " has no valid cell at this resolution";
        continue;
      }
      *error = "frame " + std::to_string(empty_frame) +
               " has no valid voxel (a cell whose 8 corners are inside the field-of-view "
               "mask): the mask is too small";
      return false;
    }
    SolveOptions solve = options.solve;
    if (level > 0) solve.max_iterations = std::min(solve.max_iterations, options.coarse_max_iterations);
    const std::vector<Eigen::Isometry3d> level_start = poses;
    const std::vector<Photometric> level_start_photometric = photometric;
    // The pair-based baselines build their own pair grids and candidates in every solve:
    // rebuilding the shared candidates between their solves would only repeat them.
    const bool pair_based = options.mode == "pairwise" || options.mode == "lie_normalization" ||
                            options.mode == "sequential";
    const int max_rebuilds = pair_based ? 0 : options.max_rebuilds;
    // The last solve's candidates and how far it moved the frames (for the checks).
    CandidateSet last_candidates;
    double last_motion = std::numeric_limits<double>::infinity();
    std::vector<double> last_frame_motion(m, 0.0);
    bool solved = false;
    for (int rebuild = 0; rebuild <= max_rebuilds; ++rebuild) {
      LevelSolve record;
      record.level = level;
      record.rebuild = rebuild;
      ImageGeometry grid;
      if (!BuildPanoramaGrid(frames, poses, options.panorama_spacing, &grid, error)) {
        if (result->solves.empty()) return false;  // the initial poses: bad input
        // The poses a solve reached spread the frames over a space no panorama can hold.
        const std::string why = "diverged: the solve moved the frames far apart (" + *error + ")";
        error->clear();
        return diverged(result->solves.back().level, why, {});
      }
      record.panorama_spacing_mm = grid.spacing_mm;
      CandidateSet candidates = BuildCandidates(frames, poses, grid, /*margin_cells=*/0);
      record.candidate_voxels = candidates.num_voxels();
      record.candidate_observations = candidates.NumObservations();
      const Eigen::MatrixXi overlap = CandidateOverlap(candidates);
      std::string why;
      std::vector<int> slid;
      if (options.min_kept_overlap > 0.0 &&
          guard.Diverged(frames, overlap, grid.spacing_mm, &why, &slid)) {
        // With recovery, frames in a wrong minimum that did not slide are named too, so that
        // one recovery re-places them all (else the next solve finds them, and by then the
        // pair graph is the only remedy left).
        if (check_every_level) {
          const std::vector<double> misfits =
              FrameMisfits(frames, candidates, poses, options.solve.num_threads, photometric);
          for (int f : MisfitOutliers(misfits, options.max_misfit_ratio, &misfit_exempt)) {
            if (std::find(slid.begin(), slid.end(), f) == slid.end()) slid.push_back(f);
          }
        }
        return diverged(result->solves.empty() ? level : result->solves.back().level, why, slid);
      }
      std::string connect_error;
      if (!CheckConnected(overlap, options.min_shared_voxels, &connect_error)) {
        if (level > 0) {
          // Coarse levels have few voxels: a small overlap may only be countable at finer
          // levels, and a coarse solve on a thin overlap may have drifted. Skip the level
          // and start the next one from the poses this level started from.
          LOG(INFO) << "skipping pyramid level " << level << ": " << connect_error;
          poses = level_start;
          photometric = level_start_photometric;
          break;
        }
        *error = connect_error + " (pyramid level " + std::to_string(level) + ")";
        return false;
      }
      // Checked once, on the coarsest level that has a usable overlap (cheap there); finer
      // levels see the same overlap with more detail.
      if (rebuild == 0 && !determined_checked) {
        double conditioning = 0.0;
        std::string why;
        if (!PosesDetermined(frames, candidates, poses, options.solve.num_threads,
                             &conditioning, &why)) {
          if (level > 0) {
            LOG(INFO) << "skipping pyramid level " << level << ": " << why;
            poses = level_start;
            photometric = level_start_photometric;
            break;
          }
          *error = why + " at the initial poses of the finest level";
          return false;
        }
        VLOG(1) << "level " << level << ": scaled Gauss-Newton conditioning " << conditioning;
        determined_checked = true;
      }
      std::ostringstream prefix;
      prefix << "level " << level << "." << rebuild << " ";
      solve.progress_prefix = options.solve.progress_prefix + prefix.str();
      std::vector<float> intensities;
      if (!SolveOnce(options, solve, frames, candidates, poses, photometric, &record.report,
                     options.mode == "dba" && level == 0 ? &intensities : nullptr, error)) {
        return false;
      }
      const std::vector<Eigen::Isometry3d> next = RelativeToFrame0(record.report.frame_from_world);
      std::vector<double> frame_motion(m, 0.0);
      for (int i = 1; i < m; ++i) {
        frame_motion[i] = MaxCornerMotionVoxels(frames[i], poses[i], next[i]);
        record.max_motion_voxels = std::max(record.max_motion_voxels, frame_motion[i]);
      }
      result->total_iterations += record.report.num_iterations;
      const bool usable = record.report.usable;
      if (usable) {
        poses = next;
        if (affine) {
          CHECK_EQ(static_cast<int>(record.report.photometric.size()), m)
              << "a photometric solve returned no estimate";
          photometric = record.report.photometric;
        }
      }
      if (level == 0) {
        result->grid = grid;
        if (!intensities.empty()) {
          result->dba_intensities = Image(grid, 0.0f);
          for (int64_t v = 0; v < candidates.num_voxels(); ++v) {
            result->dba_intensities.voxels[candidates.voxel[v]] = intensities[v];
          }
        }
      }
      const double motion = record.max_motion_voxels;
      result->solves.push_back(std::move(record));
      if (!usable) {
        result->usable = false;
        result->failure = "the solve at pyramid level " + std::to_string(level) +
                          " is not usable: " + result->solves.back().report.termination;
        result->frame_from_world = poses;
        result->photometric = photometric;
        return true;
      }
      solved = true;
      last_candidates = std::move(candidates);
      last_motion = motion;
      last_frame_motion = std::move(frame_motion);
      if (motion <= options.rebuild_tolerance_voxels) break;
    }
    if (level > 0) {
      // With recovery, a frame in a wrong minimum is caught here, on a coarse level, where
      // re-placing it and starting again costs little. The misfits are those of the last
      // solve's candidates (at the poses it reached, up to the rebuild tolerance).
      if (check_every_level && solved) {
        const std::vector<double> misfits =
            FrameMisfits(frames, last_candidates, poses, options.solve.num_threads, photometric);
        std::string why;
        if (MisfitOutlier(misfits, options.max_misfit_ratio, &why, &misfit_exempt)) {
          result->flagged_by_misfit = true;
          return diverged(level, why,
                          MisfitOutliers(misfits, options.max_misfit_ratio, &misfit_exempt));
        }
        std::vector<int> flagged;
        if (PairDisagreement(PairMismatches(search_frames, poses, options.solve.num_threads), m,
                             options.max_pair_mismatch_ratio, &flagged, &why)) {
          return diverged(level, why, flagged);
        }
        // A coarse level whose last solve (every rebuild used) still slid frames by more
        // than unsettled_motion_voxels has found no minimum: on the benchmarks' wide
        // protocol no such level was followed by a usable registration, and the finer
        // levels then cost the most for nothing. The sliding frames are named (with more
        // than a third, the pair graph places all). Creeping by less (photometric
        // parameters make coarse levels converge slowly) goes on to the finer levels.
        const double unsettled_voxels =
            std::max(options.rebuild_tolerance_voxels, options.unsettled_motion_voxels);
        // (Only where rebuilds were allowed: the pair-based baselines solve once per level
        // and move their frames by whole voxels in that one solve.)
        if (max_rebuilds > 0 && last_motion > unsettled_voxels) {
          std::vector<int> sliding;
          for (int i = 1; i < m; ++i) {
            if (last_frame_motion[i] > unsettled_voxels) sliding.push_back(i);
          }
          std::ostringstream unsettled;
          unsettled << "pyramid level " << level << " did not settle: its last solve (of "
                    << max_rebuilds + 1 << ") still moved " << sliding.size()
                    << (sliding.size() == 1 ? " frame" : " frames") << " by up to "
                    << std::setprecision(3) << last_motion << " voxels (more than "
                    << unsettled_voxels << ")";
          return diverged(level, unsettled.str(), sliding);
        }
      }
      continue;
    }
    // Checks of the final poses. When the last solve moved no field-of-view corner by more
    // than the rebuild tolerance, its candidates stand for the final poses' (as the rebuild
    // rule has it); otherwise candidates are built at the final poses.
    CandidateSet final_candidates;
    if (last_motion <= options.rebuild_tolerance_voxels) {
      final_candidates = std::move(last_candidates);
    } else {
      ImageGeometry final_grid;
      if (!BuildPanoramaGrid(frames, poses, options.panorama_spacing, &final_grid, error)) {
        const std::string why = "diverged: the solve moved the frames far apart (" + *error + ")";
        error->clear();
        return diverged(0, why, {});
      }
      final_candidates = BuildCandidates(frames, poses, final_grid, 0);
    }
    std::string why;
    std::vector<int> slid;
    if (options.min_kept_overlap > 0.0 && guard.Diverged(frames, final_candidates, &why, &slid)) {
      return diverged(0, why, slid);
    }
    // DSR's last pass was at the final poses over these candidates when the solve kept it
    // (stream/streamed_cost.h): its per-frame costs are the misfits' sums. With photometric
    // parameters the misfits are always measured here, on corrected intensities.
    const SolveReport& last = result->solves.back().report;
    const bool reuse_last_pass = options.mode == "dsr" && !affine &&
                                 last_motion <= options.rebuild_tolerance_voxels &&
                                 static_cast<int>(last.final_frame_cost.size()) == m;
    if (reuse_last_pass) {
      result->frame_misfits =
          MisfitsFromFrameCosts(last.final_frame_cost, last.final_frame_observations);
    } else {
      result->frame_misfits =
          FrameMisfits(frames, final_candidates, poses, options.solve.num_threads, photometric);
    }
    if (MisfitOutlier(result->frame_misfits, options.max_misfit_ratio, &why, &misfit_exempt)) {
      result->flagged_by_misfit = true;
      return diverged(0, why, MisfitOutliers(result->frame_misfits, options.max_misfit_ratio,
                                             &misfit_exempt));
    }
    std::vector<int> flagged;
    if (PairDisagreement(PairMismatches(search_frames, poses, options.solve.num_threads), m,
                         options.max_pair_mismatch_ratio, &flagged, &why)) {
      return diverged(0, why, flagged);
    }
    if (options.estimate_uncertainty && affine) {
      // The estimate linearises the poses' stopping rule alone (pipeline/uncertainty.h); the
      // gains and offsets solved with them would change both its gradient and its
      // derivative.
      result->uncertainty_note =
          "the pose uncertainty does not model the photometric parameters "
          "(--photometric=affine)";
    } else if (options.estimate_uncertainty && !options.loss.IsSquared()) {
      // Its noise model is the squared differences' (pipeline/uncertainty.h).
      result->uncertainty_note = "the pose uncertainty does not model the robust loss (--loss=" +
                                 std::string(RobustLossKindName(options.loss.kind)) + ")";
    } else if (options.estimate_uncertainty &&
               (options.mode == "dsr" || options.mode == "dba")) {
      if (!EstimatePoseUncertainty(frames, final_candidates, poses, masks,
                                   options.solve.num_threads, &result->uncertainty,
                                   &result->uncertainty_note)) {
        result->uncertainty = PoseUncertainty();
      }
    }
  }
  result->frame_from_world = poses;
  result->photometric = photometric;
  return true;
}

// Recovery searches at most this many frames against the panorama of the others; beyond,
// the pair graph places every frame. Measured at the paper's size on 2 cores: one frame's
// search 1.4-4.5 s (it covers the whole panorama), the pair graph of 11 frames about 5 s.
constexpr int kMaxRePlacementSearches = 2;

// Register on intensities already brought to a usual scale (see Register).
bool RegisterScaled(const std::vector<Image>& images,
                    const std::vector<Mask>& masks,
                    const std::vector<Eigen::Isometry3d>& initial_frame_from_world,
                    const RegistrationOptions& options,
                    std::chrono::steady_clock::time_point start,
                    RegistrationResult* result,
                    std::string* error) {
  const int m = static_cast<int>(images.size());
  // The pairwise initialiser runs first (its own pyramids, freed before ours are built).
  std::vector<Eigen::Isometry3d> start_poses = RelativeToFrame0(initial_frame_from_world);
  if (options.init == InitialPoses::kPairwise && options.mode != "pairwise") {
    RegistrationOptions init_options = options;
    init_options.mode = "pairwise";
    init_options.init = InitialPoses::kGiven;
    init_options.max_recoveries = 0;
    init_options.photometric = PhotometricModel::kNone;  // a baseline's run
    // The initial poses are judged by this run's own checks of its final poses.
    init_options.min_kept_overlap = 0.0;
    init_options.max_misfit_ratio = 0.0;
    init_options.max_pair_mismatch_ratio = 0.0;
    init_options.solve.linear_solver = "";  // the mode's solver may be a Schur type
    init_options.solve.progress_prefix = options.solve.progress_prefix + "init ";
    RegistrationResult init;
    if (!Register(images, masks, initial_frame_from_world, init_options, &init, error)) {
      *error = "--init=pairwise: " + *error;
      return false;
    }
    if (!init.usable) {
      result->failure = "--init=pairwise: " + init.failure;
      result->frame_from_world = start_poses;
      result->seconds = Seconds(start);
      return true;
    }
    start_poses = init.frame_from_world;
    result->init_seconds = init.seconds;
    result->init_iterations = init.total_iterations;
    result->init_frame_from_world = start_poses;
  }

  // Pyramids, coarsest level last.
  Pyramids pyramids;
  pyramids.levels.resize(m);
  pyramids.num_levels = options.pyramid_levels;
  for (int i = 0; i < m; ++i) {
    pyramids.levels[i] = BuildPyramid(images[i], masks[i], options.pyramid_levels,
                                      options.pyramid_sigma_voxels, options.finest_sigma_voxels,
                                      options.pyramid_min_size, options.solve.num_threads);
    pyramids.num_levels =
        std::min(pyramids.num_levels, static_cast<int>(pyramids.levels[i].size()));
  }
  result->pyramid_seconds = Seconds(start) - result->init_seconds;

  const int constant = ConstantFrame(images, masks);
  if (constant >= 0) {
    *error = "frame " + std::to_string(constant) +
             " has the same value everywhere in its field of view: nothing to register";
    return false;
  }
  // The coarse search level: of the global search, recovery and the pair check (built
  // before any solve releases the coarsest level; small).
  const std::vector<Frame> search_frames = SearchFrames(images, masks, pyramids, options);
  const auto global_poses = [&](std::vector<Eigen::Isometry3d>* poses) {
    PairGraphReport graph;
    return GlobalInitialPoses(search_frames, options.search, poses, &graph, error);
  };
  bool global_used = options.init == InitialPoses::kGlobal;
  bool replaced_frames = false;
  if (global_used) {
    const auto init_start = std::chrono::steady_clock::now();
    if (!global_poses(&start_poses)) {
      *error = "--init=global: " + *error;
      return false;
    }
    result->init_seconds = Seconds(init_start);
    result->init_frame_from_world = start_poses;
  }
  std::vector<Eigen::Isometry3d> poses = start_poses;
  std::vector<bool> misfit_exempt(m, false);
  for (int round = 0;; ++round) {
    if (!SolveLevels(images, masks, poses, options, options.max_recoveries > 0, misfit_exempt,
                     search_frames, &pyramids, result, error)) {
      return false;
    }
    if (result->usable || round >= options.max_recoveries || result->flagged_frames.empty()) {
      break;
    }
    // Recovery. With most frames passing, the flagged ones are re-placed against the
    // panorama of the others; with more than a third flagged (or after that was tried) the
    // panorama is not to be trusted, and every frame is placed from scratch by the pair
    // graph (once).
    const auto recovery_start = std::chrono::steady_clock::now();
    RegistrationResult::Recovery recovery;
    recovery.after_level = result->solves.empty() ? 0 : result->solves.back().level;
    recovery.why = result->failure;
    const bool most_passed = 3 * static_cast<int>(result->flagged_frames.size()) <= m;
    // Both remedies already used: the failure stands (no empty recovery record).
    if (!(most_passed && !replaced_frames) && global_used) break;
    bool moved = false;
    std::vector<Eigen::Isometry3d> next;
    // Frames are re-placed against the others once; if the registration still fails, the
    // others were not to be trusted either.
    if (most_passed && !replaced_frames) {
      replaced_frames = true;
      std::string why;
      if (ReplaceFrames(search_frames, result->frame_from_world, poses, result->flagged_frames,
                        options.search, kMaxRePlacementSearches, &next, &recovery.frames,
                        &why)) {
        moved = std::any_of(recovery.frames.begin(), recovery.frames.end(),
                            [](const FrameReplacement& f) { return f.moved; });
        // Every frame the misfit check named matches the panorama of the others as well as
        // they match each other (kept without a search): its misfit comes from its content
        // (contrast, noise, what its field of view cuts), not from a wrong minimum. Go on
        // from the same poses without checking those frames' misfit. A frame kept after a
        // search found nothing better is no such evidence (its NCC is below the others';
        // the panorama may be what misleads the search): the pair graph follows.
        const bool all_match = std::none_of(
            recovery.frames.begin(), recovery.frames.end(),
            [](const FrameReplacement& f) { return f.moved || f.searched; });
        if (all_match && result->flagged_by_misfit) {
          for (int f : result->flagged_frames) misfit_exempt[f] = true;
          recovery.misfit_accepted = true;
        }
      } else {
        VLOG(1) << why;
      }
    }
    if (!moved && !recovery.misfit_accepted && !global_used) {
      global_used = true;
      recovery.global = true;
      if (!global_poses(&next)) {
        LOG(INFO) << "recovery by the pair graph not possible: " << *error;
        error->clear();
      } else {
        moved = true;
      }
    }
    recovery.seconds = Seconds(recovery_start);
    result->recoveries.push_back(recovery);
    if (!moved && !recovery.misfit_accepted) break;  // nothing better: the failure stands
    poses = RelativeToFrame0(next);
  }
  result->seconds = Seconds(start);
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
  result->uncertainty.noise_sigma = std::ldexp(result->uncertainty.noise_sigma, -exponent);
}

}  // namespace

bool Register(const std::vector<Image>& input_images,
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
  if (!CheckRegistrationInputs(input_images, initial_frame_from_world, options, error)) {
    return false;
  }
  *result = RegistrationResult();
  // Intensities far from a usual scale are brought to it by a power of two
  // (pipeline/input_checks.h); the reported costs are scaled back at the end.
  const int exponent = IntensityScaleExponent(IntensitySpread(input_images, masks));
  if (exponent == 0) {
    return RegisterScaled(input_images, masks, initial_frame_from_world, options, start, result,
                          error);
  }
  LOG(INFO) << "intensities scaled by 2^" << exponent
            << " for the solves (their spread is far from a usual scale); the costs printed "
               "during the solves are in those units";
  std::vector<Image> scaled = input_images;
  for (Image& image : scaled) {
    for (float& v : image.voxels) v = std::ldexp(v, exponent);
  }
  // The loss's scale is in grey levels: it follows the intensities.
  RegistrationOptions scaled_options = options;
  scaled_options.loss.scale = std::ldexp(options.loss.scale, exponent);
  if (!RegisterScaled(scaled, masks, initial_frame_from_world, scaled_options, start, result,
                      error)) {
    return false;
  }
  UnscaleResult(exponent, result);
  return true;
}

}  // namespace dsr
