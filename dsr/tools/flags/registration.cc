// The registration's options as flags (tools/flags/flags.h): dsr_register's, and
// dsr_compare's for every method it runs.
#include <cmath>

#include "dsr/tools/flags/flags.h"
#include "dsr/tools/tool_util.h"

DEFINE_string(init, "auto", "Initial poses: 'auto' (identity; frames the checks flag after a "
              "level are re-placed by a global search against the others and the "
              "registration starts again, at most --max_recoveries times), 'identity' "
              "(no recovery; dsr_compare's default, the paper's comparison), 'pairwise' (the "
              "pairwise baseline's poses, itself started from identity: the paper's "
              "initialisation; no recovery), 'global' (every pair searched globally, frames "
              "placed along the most confident pairs, then recovery as auto) or, in "
              "dsr_register, a poses JSON file (docs/design.md) with one entry per image, "
              "matched to --images by its image names as dsr_fuse --poses does (then "
              "recovery as auto).");
DEFINE_int32(max_recoveries, dsr::kDefaultMaxRecoveries, "--init=auto, global or FILE: how "
             "many times flagged frames may be re-placed, in [0, 10] (0 = a flagged frame is "
             "a failure, exit 1).");
DEFINE_string(loss, "squared",
              "Loss of the intensity differences (modes dsr and dba; docs/design.md 4.7): "
              "squared, or huber / cauchy with --loss_scale (grey levels of the input) for "
              "outliers such as shadows and reverberation. DBA applies it through Ceres, DSR "
              "by iteratively reweighted solves. --uncertainty is then not estimated.");
DEFINE_double(loss_scale, 0.0, "Scale of --loss=huber or cauchy, in grey levels of the input "
              "(residuals larger than about this are down-weighted); > 0.");
DEFINE_string(photometric, dsr::PhotometricModelToString(dsr::kDefaultPhotometricModel),
              "Photometric model of the modes dsr and dba (docs/design.md section 2.8): none; "
              "affine: every solve also estimates each frame's gain and offset against "
              "frame 0 (frame i's intensities on frame 0's scale are gain * I_i + offset), "
              "for frames whose brightness differs; or auto (default): none, unless the gains "
              "and offsets estimated at the final poses change some frame's intensities by "
              "more than 3% of their spread, or explain what the structure check finds at a "
              "level, or the registration fails without them; then affine (the summary says "
              "which and why). The baselines have none: the default runs them without, an "
              "explicit affine or auto with a baseline mode is refused. With affine, the poses "
              "files carry each frame's \"gain\" and \"offset\", the "
              "panorama and the report's pictures use the corrected intensities, the misfit "
              "check compares them, and --uncertainty is not estimated; dsr_compare names "
              "the rows METHOD+affine and adds the mean absolute gain and offset errors "
              "(mae_gain, mae_offset) when the ground truth has them.");
DEFINE_string(preset, "none",
              "A named set of defaults for a kind of data (flags given explicitly still win): "
              "none, or echo, for 3D ultrasound with speckle and brightness changes between "
              "acquisitions: --photometric=affine --intensity_transform=sqrt "
              "--panorama_sampling=all_phases (docs/accuracy_us.md). The summary lists what it "
              "set.");
DEFINE_string(intensity_transform, "none",
              "Intensities the registration works on (docs/design.md section 2.9): none, or "
              "sqrt: sqrt(c I), c the largest intensity inside the masks, a variance-"
              "stabilising transform for linear-envelope ultrasound, whose speckle multiplies "
              "the intensity (log-compressed B-mode does not need it). Needs intensities >= 0 "
              "inside the masks. The solves' costs and --loss_scale are then on the "
              "transform's scale; gains, offsets, misfits, the panorama and every output image "
              "stay on the input's grey levels (with --photometric=affine the gains and offsets "
              "are estimated again on them at the final poses). dsr_compare names the rows "
              "METHOD+sqrt.");
DEFINE_string(panorama_sampling, "half_voxel",
              "Where the registration's panorama grid samples frame 0 (docs/design.md 2.5): "
              "half_voxel (half a voxel off its lattice everywhere: its samples average 8 "
              "voxels; best where fine detail is independent noise, as in the paper's "
              "protocol) or all_phases (every sub-voxel phase, like the other frames: the "
              "grid's spacing is frame 0's times 1 + 1/n, n its longest extent in voxels; for "
              "texture the frames share, such as ultrasound speckle). The fused panorama's "
              "grid is not affected.");
DEFINE_string(gauge, "mean",
              "The pose gauge of the DSR and DBA solves, one for both so that they minimise "
              "one function (docs/design.md 4.8): mean (every pose free, frame 0's too, with "
              "a prior holding the frames' mean centre and orientation in the world, so that "
              "no frame alone takes the pull of what moves all frames together) or frame0 "
              "(frame 0's pose constant, the rule before; the baselines always use it). "
              "Output poses are relative to frame 0 either way.");
DEFINE_double(search_rotation_deg, 45.0, "Global search (recovery, --init=global): rotations "
              "within this angle of frame 0's orientation, in (0, 180].");
DEFINE_int32(search_rotations, 200, "Global search: about this many rotations sampled, in "
             "[1, 100000] (more: finer, slower).");
DEFINE_int32(search_pair_rotations, 60, "Global search of --init=global and of a recovery "
             "that places every frame: about this many rotations per pair of frames, in "
             "[1, 100000].");
DEFINE_int32(search_max_axis, 32, "Global search: on the coarsest pyramid level, halved further "
             "until no frame axis is longer than this many voxels, >= 8 (larger: finer, slower).");
DEFINE_string(linear_solver, "", "Ceres linear solver. dba: DENSE_SCHUR (default), "
              "SPARSE_SCHUR, ITERATIVE_SCHUR, DENSE_QR, SPARSE_NORMAL_CHOLESKY. dsr: DENSE_QR "
              "(default), DENSE_NORMAL_CHOLESKY.");
DEFINE_string(trust_region, "LEVENBERG_MARQUARDT", "LEVENBERG_MARQUARDT or DOGLEG.");
DEFINE_string(kernels, "auto", "SIMD kernels of the streamed costs (dsr, ape, pairs): auto (the "
              "widest this CPU runs), portable (plain C++, the tests' twin), avx2 or avx512. "
              "Results agree to rounding.");
DEFINE_int32(max_iterations, 100, "Iteration limit of each solve on the finest level, >= 1.");
DEFINE_int32(coarse_max_iterations, 50, "Iteration limit of each solve on coarser levels, >= 1.");
DEFINE_double(function_tolerance, 1e-8, "Ceres function tolerance (relative cost change).");
DEFINE_double(gradient_tolerance, 1e-12, "Ceres gradient tolerance.");
DEFINE_double(parameter_tolerance, 1e-10, "Ceres parameter tolerance (relative step).");
DEFINE_double(step_tolerance, 5e-3, "A solve stops when the distance still to go to its fixed "
              "point, estimated from the last accepted steps (docs/design.md 7.4), moves no "
              "frame's field of view by more than this many voxels (0 = off), >= 0.");
DEFINE_int32(max_rejected_steps, 5, "A solve stops after this many rejected steps in a row "
             "(0 = off), >= 0.");
DEFINE_int32(pyramid_levels, 3, "Pyramid levels (1 = full resolution only), in 1..8.");
DEFINE_int32(pyramid_min_size, 12, "No pyramid level has an axis shorter than this many voxels "
             "(levels are dropped instead), >= 4.");
DEFINE_double(pyramid_sigma, 1.0, "Gaussian sigma (voxels) before each halving, >= 0.");
DEFINE_double(smoothing, 0.0, "Gaussian sigma (voxels) applied to the finest level, >= 0.");
DEFINE_int32(max_rebuilds, 4, "Candidate-set rebuilds per level after the first solve, >= 0.");
DEFINE_double(rebuild_tolerance, 0.05, "A level stops rebuilding when its last solve moved "
              "no field-of-view corner by more than this many voxels, > 0.");
DEFINE_double(min_kept_overlap, 0.25, "Divergence guard: poses at which a frame's best chain "
              "of overlapping frames to frame 0 covers less than this fraction of what it "
              "covered at the initial poses (the frame slid out of the overlap) are a failure "
              "(exit 1), not a result; in [0, 1), 0 = off. dsr_compare: off by default (every "
              "method's poses are measured, diverged or not), 0.25 with --init=auto or global "
              "unless any of the three checks is set.");
DEFINE_double(max_structure_fraction, 0.05, "Structure check (docs/design.md 8.4): poses at "
              "which more than this fraction of a frame's own structure (its samples' "
              "covariance at a lag beyond noise and interpolation) remains in its differences "
              "to the panorama, standing out of what noise alone gives, are a failure (exit 1), "
              "not a result; in [0, 1), 0 = off. dsr_compare: as --min_kept_overlap (0.05 with "
              "--init=auto or global).");
DEFINE_double(max_pose_error_voxels, 1.0, "Determination check (docs/design.md 8.7; dsr and "
              "dba without gains and offsets or a robust --loss): final poses at which the data "
              "leave some frame's pose undetermined (the cost does not curve up along some "
              "motion of it, or the error the image noise alone puts on it exceeds this many "
              "of its voxels: a symmetric or featureless object) are a failure (exit 1) naming "
              "the frame and whether its rotation or translation; >= 0, 0 = off.");
DEFINE_double(max_misfit_ratio, 0.0, "Former misfit check, off by default (docs/design.md "
              "8.5): poses at which a frame's RMS difference to the panorama exceeds this "
              "multiple of the frames' lower quartile are a failure (exit 1); 0 = off or > 1.");
DEFINE_double(max_pair_mismatch_ratio, 0.0, "Former pair check, off by default (docs/design.md "
              "8.5): poses at which two overlapping frames match each other (1 - NCC over "
              "their overlap, on the coarsest level) worse than this multiple of the pairs' "
              "lower quartile are a failure (exit 1); 0 = off or > 1.");
DEFINE_int32(num_chunks, 1, "dsr and ape: residual blocks the candidate voxels are split into, "
             ">= 1.");
DEFINE_bool(reference_cost, false, "dsr: use the per-voxel reference cost (stores Jacobians; "
            "small problems only).");
DEFINE_double(memory_budget_mb, 0.0, "dba: refuse problems estimated above this many MiB; "
              "0 = half the machine's RAM.");
DEFINE_bool(progress, true, "Print one line per solver iteration on stderr (dsr_compare: off "
            "by default).");
DEFINE_bool(uncertainty, false, "Estimate each frame's pose covariance and predicted TRE "
            "(modes dsr and dba; docs/design.md section 8.6). dsr_register writes them into "
            "--out_poses (\"covariance\", \"predicted_tre_mm\"), the summary and the report; "
            "dsr_compare adds the mean predicted TRE and the mean normalised squared pose "
            "error (6 when calibrated) to results.csv (predicted_tre_mm, nees). Noise only: "
            "not a wrong minimum, brightness changes or interpolation bias.");

namespace {
bool ValidatePreset(const char* flag, const std::string& v) {
  return dsr::CheckFlag(v == "none" || v == "echo", flag, v, "must be none or echo");
}
bool ValidatePhotometric(const char* flag, const std::string& v) {
  dsr::PhotometricModel model;
  return dsr::CheckFlag(dsr::StringToPhotometricModel(v, &model), flag, v,
                        "must be none, affine or auto");
}
bool ValidateIntensityTransform(const char* flag, const std::string& v) {
  dsr::IntensityTransform transform;
  return dsr::CheckFlag(dsr::StringToIntensityTransform(v, &transform), flag, v,
                        "must be none or sqrt");
}
bool ValidatePanoramaSampling(const char* flag, const std::string& v) {
  dsr::PanoramaSampling sampling;
  return dsr::CheckFlag(dsr::StringToPanoramaSampling(v, &sampling), flag, v,
                        "must be half_voxel or all_phases");
}
bool ValidateGauge(const char* flag, const std::string& v) {
  dsr::Gauge gauge;
  return dsr::CheckFlag(dsr::StringToGauge(v, &gauge), flag, v, "must be frame0 or mean");
}
bool ValidateLinearSolver(const char* flag, const std::string& v) {
  ceres::LinearSolverType type;
  return dsr::CheckFlag(v.empty() || ceres::StringToLinearSolverType(v, &type), flag, v,
                        "not a Ceres linear solver name");
}
bool ValidateTrustRegion(const char* flag, const std::string& v) {
  ceres::TrustRegionStrategyType type;
  return dsr::CheckFlag(ceres::StringToTrustRegionStrategyType(v, &type), flag, v,
                        "must be LEVENBERG_MARQUARDT or DOGLEG");
}
bool ValidateKernels(const char* flag, const std::string& v) {
  dsr::KernelPath path;
  if (!dsr::CheckFlag(dsr::StringToKernelPath(v, &path), flag, v,
                      "must be " + dsr::KernelPathNames())) {
    return false;
  }
  return dsr::CheckFlag(dsr::KernelPathAvailable(path), flag, v, "this CPU does not run them");
}
bool ValidateMemoryBudget(const char* flag, double v) {
  return dsr::CheckFlag(v >= 0.0 && std::isfinite(v), flag, v, "must be >= 0");
}
}  // namespace
DEFINE_validator(preset, &ValidatePreset);
DEFINE_validator(photometric, &ValidatePhotometric);
DEFINE_validator(intensity_transform, &ValidateIntensityTransform);
DEFINE_validator(panorama_sampling, &ValidatePanoramaSampling);
DEFINE_validator(gauge, &ValidateGauge);
DEFINE_validator(linear_solver, &ValidateLinearSolver);
DEFINE_validator(trust_region, &ValidateTrustRegion);
DEFINE_validator(kernels, &ValidateKernels);
DEFINE_validator(memory_budget_mb, &ValidateMemoryBudget);

namespace dsr {

namespace {
// --preset=echo's flags and values.
constexpr std::pair<const char*, const char*> kEchoPreset[] = {
    {"photometric", "affine"},
    {"intensity_transform", "sqrt"},
    {"panorama_sampling", "all_phases"},
};
}  // namespace

std::string PresetFlagValue(const char* flag, const std::string& value) {
  if (FLAGS_preset != "echo" || !FlagIsDefault(flag)) return value;
  for (const auto& [name, preset] : kEchoPreset) {
    if (std::string(name) == flag) return preset;
  }
  return value;
}

std::string PresetSummary() {
  if (FLAGS_preset == "none") return "";
  std::string set;
  for (const auto& [name, value] : kEchoPreset) {
    if (FlagIsDefault(name)) set += std::string(set.empty() ? "" : " ") + "--" + name + "=" + value;
  }
  return "preset " + FLAGS_preset + ": " + (set.empty() ? "every flag it sets was given" : set);
}

PhotometricModel PhotometricFromFlags(Mode mode) {
  PhotometricModel model = PhotometricModel::kNone;
  StringToPhotometricModel(ModeEstimatesPhotometric(mode)
                               ? PresetFlagValue("photometric", FLAGS_photometric)
                               : FLAGS_photometric,
                           &model);  // validated
  if (FlagIsDefault("photometric") && !ModeEstimatesPhotometric(mode)) {
    model = PhotometricModel::kNone;
  }
  return model;
}

bool RegistrationOptionsFromFlags(RegistrationOptions* options,
                                  std::string* init_file,
                                  std::string* error) {
  SolveOptions& solve = options->solve;
  ceres::StringToTrustRegionStrategyType(FLAGS_trust_region, &solve.trust_region);  // validated
  solve.linear_solver.reset();
  if (!FLAGS_linear_solver.empty()) {
    ceres::LinearSolverType type;
    ceres::StringToLinearSolverType(FLAGS_linear_solver, &type);  // validated
    solve.linear_solver = type;
  }
  solve.max_iterations = FLAGS_max_iterations;
  solve.function_tolerance = FLAGS_function_tolerance;
  solve.gradient_tolerance = FLAGS_gradient_tolerance;
  solve.parameter_tolerance = FLAGS_parameter_tolerance;
  solve.num_threads = FLAGS_num_threads;
  StringToKernelPath(FLAGS_kernels, &solve.kernels);  // validated
  solve.step_tolerance = FLAGS_step_tolerance;
  solve.max_rejected_steps = FLAGS_max_rejected_steps;
  solve.progress = FLAGS_progress;
  options->panorama_spacing = FLAGS_panorama_spacing;
  StringToPanoramaSampling(PresetFlagValue("panorama_sampling", FLAGS_panorama_sampling),
                           &options->panorama_sampling);  // validated
  StringToGauge(FLAGS_gauge, &options->gauge);  // validated
  options->pyramid_levels = FLAGS_pyramid_levels;
  options->pyramid_sigma = FLAGS_pyramid_sigma;
  options->pyramid_min_size = FLAGS_pyramid_min_size;
  options->smoothing = FLAGS_smoothing;
  options->coarse_max_iterations = FLAGS_coarse_max_iterations;
  options->max_rebuilds = FLAGS_max_rebuilds;
  options->rebuild_tolerance = FLAGS_rebuild_tolerance;
  options->min_kept_overlap = FLAGS_min_kept_overlap;
  options->max_misfit_ratio = FLAGS_max_misfit_ratio;
  options->max_pair_mismatch_ratio = FLAGS_max_pair_mismatch_ratio;
  options->max_structure_fraction = FLAGS_max_structure_fraction;
  options->max_pose_error_voxels = FLAGS_max_pose_error_voxels;
  options->dsr.num_chunks = FLAGS_num_chunks;
  options->dsr.reference_cost = FLAGS_reference_cost;
  options->dba.memory_budget_mb = FLAGS_memory_budget_mb;
  options->uncertainty = FLAGS_uncertainty;
  StringToIntensityTransform(PresetFlagValue("intensity_transform", FLAGS_intensity_transform),
                             &options->intensity_transform);  // validated
  if (!MakeRobustLoss(FLAGS_loss, FLAGS_loss_scale, &options->loss, error)) return false;
  init_file->clear();
  if (!SetInitialisation(FLAGS_init, FLAGS_max_recoveries, options)) *init_file = FLAGS_init;
  options->search.rotation_deg = FLAGS_search_rotation_deg;
  options->search.rotations = FLAGS_search_rotations;
  options->search_max_axis = FLAGS_search_max_axis;
  options->search.pair_rotations = FLAGS_search_pair_rotations;
  options->search.num_threads = FLAGS_num_threads;
  options->search.refine.progress = false;
  options->search.refine.kernels = solve.kernels;
  return true;
}

}  // namespace dsr
