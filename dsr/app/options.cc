// The options table (dsr/app/options.h). The help texts are the command-line tools' --help
// and the docs' option reference; the rules are checked whenever a value is set.
#include "dsr/app/options.h"

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <iterator>
#include <limits>
#include <type_traits>

#include <ceres/types.h>

#include "dsr/app/flagfile.h"
#include "dsr/app/inputs.h"
#include "dsr/app/run_options.h"
#include "dsr/util/cpu.h"
#include "dsr/util/option_fields.h"

namespace dsr {
namespace {

int32_t I(const OptionValue& v) { return std::get<int32_t>(v); }
double D(const OptionValue& v) { return std::get<double>(v); }
const std::string& S(const OptionValue& v) { return std::get<std::string>(v); }

std::string Rule(bool ok, const char* rule) { return ok ? "" : rule; }
bool InRange(double v, double lo, double hi) { return std::isfinite(v) && v >= lo && v <= hi; }
bool NonNegative(double v) { return std::isfinite(v) && v >= 0.0; }

// Whether `text` names a value of the enum its parser reads.
template <typename E>
bool Names(bool (*parse)(const std::string&, E*), const std::string& text) {
  E value;
  return parse(text, &value);
}
bool IsPhotometricModel(const std::string& s) { return Names(&StringToPhotometricModel, s); }
bool IsIntensityTransform(const std::string& s) { return Names(&StringToIntensityTransform, s); }
bool IsPanoramaSampling(const std::string& s) { return Names(&StringToPanoramaSampling, s); }
bool IsGauge(const std::string& s) { return Names(&StringToGauge, s); }
bool IsMaskRule(const std::string& s) { return Names(&StringToMaskRule, s); }
bool IsPoseModel(const std::string& s) { return Names(&StringToPoseModel, s); }
bool IsSourceInterpolation(const std::string& s) { return Names(&StringToSourceInterpolation, s); }
bool IsIntensityMapping(const std::string& s) { return Names(&StringToIntensityMapping, s); }
bool IsLinearSolver(const std::string& s) {
  ceres::LinearSolverType type;
  return ceres::StringToLinearSolverType(s, &type);
}
bool IsTrustRegion(const std::string& s) {
  ceres::TrustRegionStrategyType type;
  return ceres::StringToTrustRegionStrategyType(s, &type);
}
bool IsSize3(const std::string& s, int lo, int hi) {
  Eigen::Vector3i size;
  return ParseSize3(s, &size, lo, hi);
}
std::string CheckPreset(const std::string& s) {
  if (s == "none") return "";
  for (const Preset& preset : Presets()) {
    if (s == preset.name) return "";
  }
  return "must be none or echo";
}
std::string CheckKernels(const std::string& s) {
  KernelPath path;
  if (!StringToKernelPath(s, &path)) return "must be " + KernelPathNames();
  return KernelPathAvailable(path) ? "" : "this CPU does not run them";
}

// An option's field: the value converted to the field's type.
template <typename T>
void Assign(const OptionValue& v, T* field) {
  std::visit(
      [field](const auto& value) {
        using V = std::decay_t<decltype(value)>;
        if constexpr (std::is_convertible_v<V, T>) *field = static_cast<T>(value);
      },
      v);
}

void ApplyLinearSolver(const OptionValue& v, RunConfig* c) {
  std::optional<ceres::LinearSolverType>& solver = c->registration.solve.linear_solver;
  solver.reset();
  ceres::LinearSolverType type;
  if (!S(v).empty() && ceres::StringToLinearSolverType(S(v), &type)) solver = type;
}
void ApplyKernels(const OptionValue& v, RunConfig* c) {
  StringToKernelPath(S(v), &c->registration.solve.kernels);
  c->registration.search.refine.kernels = c->registration.solve.kernels;
}
void ApplyNumThreads(const OptionValue& v, RunConfig* c) {
  c->num_threads = c->registration.solve.num_threads = c->registration.search.num_threads = I(v);
}

#define DSR_RULE(condition, rule) \
  +[](const OptionValue& v) { return Rule(condition, rule); }
#define DSR_CHECK(expression) +[](const OptionValue& v) { return expression; }
#define DSR_APPLY(statement) +[](const OptionValue& v, RunConfig* c) { statement; }
// A field's apply and keeps_library_default (two members of an OptionSpec).
#define DSR_WRITES(path, write)                           \
  DSR_APPLY(write(&c->path)), +[](const OptionValue& v) { \
    const RunConfig library;                              \
    RunConfig c = library;                                \
    write(&c.path);                                       \
    return c.path == library.path;                        \
  }
#define DSR_FIELD(path) DSR_WRITES(path, [&v](auto* field) { Assign(v, field); })
#define DSR_NAMED_FIELD(path, parse) DSR_WRITES(path, [&v](auto* field) { parse(S(v), field); })

// The table itself: data, one entry per option, grouped as the option reference lists them.
// Laid out by hand, one field per line (scripts/lint.sh leaves it to its authors).
// clang-format off
const OptionSpec kOptionTable[] = {
  // Inputs
  {"images", OptionType::kString, "", "Inputs", kDsrRegister | kDsrFuse,
   "Frame images (.nii, .nii.gz, .mha, .mhd, .nrrd, .nhdr), frame 0 first (it fixes the "
   "world): comma-separated, or @LIST: the file LIST with one path per line (for names "
   "that contain commas). At most 32 (kMaxFrames); dsr_register needs at least 2. "
   "Required.",
   nullptr,
   nullptr},
  {"masks", OptionType::kString, "", "Inputs", kDsrRegister | kDsrFuse,
   "Field-of-view masks, one per image, on the image's grid (non-zero = inside), "
   "comma-separated or @LIST as --images. Empty: each image's field of view by --mask_rule"
   " (default: the convex hull of its non-zero voxels) eroded by --mask_erosion voxels.",
   nullptr,
   nullptr},
  {"phases", OptionType::kString, "all", "Inputs", kDsrRegister | kDsrFuse | kPyRegister | kPyFuse,
   "Views recorded over the heart cycle: each image a 4D file (NIfTI with a time axis, NRRD "
   "with a list axis, 3D Slicer's .seq.nrrd) or one 3D file per phase joined by ';' "
   "(\"v0_p0.nii.gz;v0_p1.nii.gz\"). Every view needs the same phases, aligned by index; "
   "each view keeps one pose and its mask stays 3D. The phases registered: all, or "
   "0-based indices 'i,j,...' in that order (the first is the one the global search, "
   "recovery and the report look at), each index decimal digits only, the items separated "
   "by single commas (no spaces, signs or empty items: '0,2' but not '0, 2', '+1' or "
   "'0,2,'). 3D images have one phase.",
   DSR_RULE(ParsePhaseList(S(v), nullptr),
            "must be all or comma-separated phase indices (digits only: no space, sign or "
            "empty item) without a repeat"),
   DSR_APPLY(ParsePhaseList(S(v), &c->phases))},
  {"mask_rule", OptionType::kString, "hull", "Inputs",
   kDsrRegister | kDsrFuse | kDsrCompare | kPyRegister | kPyFuse,
   "Without --masks (dsr_compare: with --sequence_masks=false), each frame's field of view"
   " before the --mask_erosion erosion: hull = the convex hull of its non-zero voxels (3D "
   "echo and cut CT/MR fields of view are convex, so tissue as dark as the background "
   "stays inside; specks of under 1% of the largest component are ignored), or the nonzero"
   " rule where no hull fits (data on one plane or line); nonzero = the non-zero voxels "
   "and the zeros they enclose (zeros that reach the grid border through zeros are "
   "outside).",
   DSR_RULE(IsMaskRule(S(v)), "must be hull or nonzero"),
   DSR_NAMED_FIELD(field_of_view.mask_rule, StringToMaskRule)},
  {"mask_erosion", OptionType::kInt32, "1", "Inputs",
   kDsrRegister | kDsrFuse | kDsrSimulate | kDsrCompare | kPyRegister | kPyFuse | kPySimulate,
   "Mask erosion in voxels (6-neighbourhood per voxel), in [0, 50]. dsr_register and "
   "dsr_fuse without --masks: of each image's field of view by --mask_rule. dsr_simulate "
   "and dsr_compare: of the masks of the simulated frames; 0 gives the exact field of view"
   " (the registration's gradients never read outside a mask, so no erosion is needed for "
   "them).",
   DSR_RULE(I(v) >= 0 && I(v) <= 50, "must be in [0, 50]"),
   DSR_APPLY(c->field_of_view.mask_erosion = c->simulation.mask_erosion = I(v))},
  {"gt_poses", OptionType::kString, "", "Inputs", kDsrRegister,
   "Optional ground-truth poses JSON (e.g. dsr_simulate's gt_poses.json): prints per-frame"
   " errors and the mean absolute errors; matched to --images by its image names as "
   "--init.",
   nullptr,
   nullptr},
  // Registration
  {"mode", OptionType::kString, "dsr", "Registration", kDsrRegister | kPyRegister,
   "Solver: dsr (reduced problem, intensities eliminated), dba (full direct bundle "
   "adjustment in Ceres; small problems only), or one of the paper's baselines: pairwise, "
   "lie_normalization, sequential, ape.",
   nullptr,
   nullptr},
  {"init", OptionType::kString, "auto", "Registration", kDsrRegister | kDsrCompare | kPyRegister,
   "Initial poses: 'auto' (identity; frames the checks flag after a level are re-placed by"
   " a global search against the others and the registration starts again, at most "
   "--max_recoveries times), 'identity' (no recovery; dsr_compare's default, the paper's "
   "comparison), 'pairwise' (the pairwise baseline's poses, itself started from identity: "
   "the paper's initialisation; no recovery), 'global' (every pair searched globally, "
   "frames placed along the most confident pairs, then recovery as auto) or, in "
   "dsr_register, a poses JSON file (docs/design.md) with one entry per image, matched to "
   "--images by its image names as dsr_fuse --poses does (then recovery as auto).",
   nullptr,
   nullptr},
  {"max_recoveries", OptionType::kInt32, "2", "Registration",
   kDsrRegister | kDsrCompare | kPyRegister,
   "--init=auto, global or FILE: how many times flagged frames may be re-placed, in [0, "
   "10] (0 = a flagged frame is a failure, exit 1).",
   nullptr,
   nullptr},
  {"preset", OptionType::kString, "none", "Registration",
   kDsrRegister | kDsrCompare | kPyRegister,
   "A named set of defaults for a kind of data (flags given explicitly still win): none, "
   "or echo, for 3D ultrasound with speckle and brightness changes between acquisitions: "
   "--photometric=affine --intensity_transform=sqrt --panorama_sampling=all_phases "
   "--detect_dropouts (docs/accuracy_us.md). The summary lists what it set.",
   DSR_CHECK(CheckPreset(S(v))),
   nullptr},
  {"photometric", OptionType::kString, "auto", "Registration",
   kDsrRegister | kDsrCompare | kPyRegister,
   "Photometric model of the modes dsr and dba (docs/design.md section 2.8): none; affine:"
   " every solve also estimates each frame's gain and offset against frame 0 (frame i's "
   "intensities on frame 0's scale are gain * I_i + offset), for frames whose brightness "
   "differs; or auto (default): none, unless the gains and offsets estimated at the final "
   "poses change some frame's intensities by more than 3% of their spread (where the last "
   "coarse level finds them clearly over that, the finest level estimates them at once and"
   " the final poses confirm it), or explain what the structure check finds at a level, or"
   " the registration fails without them; then affine (the summary says which and why). "
   "The baselines have none: the default runs "
   "them without, an explicit affine or auto with a baseline mode is refused. With affine,"
   " the poses files carry each frame's \"gain\" and \"offset\", the panorama and the "
   "report's pictures use the corrected intensities, the misfit check compares them, and "
   "--uncertainty is not estimated; dsr_compare names the rows METHOD+affine and adds the "
   "mean absolute gain and offset errors (mae_gain, mae_offset) when the ground truth has "
   "them.",
   DSR_RULE(IsPhotometricModel(S(v)), "must be none, affine or auto"),
   nullptr},
  {"intensity_transform", OptionType::kString, "none", "Registration",
   kDsrRegister | kDsrCompare | kPyRegister,
   "Intensities the registration works on (docs/design.md section 2.9): none, or sqrt: "
   "sqrt(c I), c the largest intensity inside the masks, a variance-stabilising transform "
   "for linear-envelope ultrasound, whose speckle multiplies the intensity (log-compressed"
   " B-mode does not need it). Needs intensities >= 0 inside the masks. The solves' costs "
   "and --loss_scale are then on the transform's scale; gains, offsets, misfits, the "
   "panorama and every output image stay on the input's grey levels (with "
   "--photometric=affine the gains and offsets are estimated again on them at the final "
   "poses). dsr_compare names the rows METHOD+sqrt.",
   DSR_RULE(IsIntensityTransform(S(v)), "must be none or sqrt"),
   DSR_NAMED_FIELD(registration.intensity_transform, StringToIntensityTransform)},
  {"loss", OptionType::kString, "squared", "Registration",
   kDsrRegister | kDsrCompare | kPyRegister,
   "Loss of the intensity differences (modes dsr and dba; docs/design.md 4.7): squared, or"
   " huber / cauchy with --loss_scale (grey levels of the input) for outliers such as "
   "shadows and reverberation. DBA applies it through Ceres, DSR by iteratively reweighted"
   " solves. --uncertainty is then not estimated.",
   nullptr,
   nullptr},
  {"loss_scale", OptionType::kDouble, "0.0", "Registration",
   kDsrRegister | kDsrCompare | kPyRegister,
   "Scale of --loss=huber or cauchy, in grey levels of the input (residuals larger than "
   "about this are down-weighted); > 0.",
   nullptr,
   nullptr},
  {"gauge", OptionType::kString, "mean", "Registration", kDsrRegister | kDsrCompare | kPyRegister,
   "The pose gauge of the DSR and DBA solves, one for both so that they minimise one "
   "function (docs/design.md 4.8): mean (every pose free, frame 0's too, with a prior "
   "holding the frames' mean centre and orientation in the world, so that no frame alone "
   "takes the pull of what moves all frames together) or frame0 (frame 0's pose constant, "
   "the rule before; the baselines always use it, and refuse an explicit mean). Output "
   "poses are relative to frame 0 either way.",
   DSR_RULE(IsGauge(S(v)), "must be frame0 or mean"),
   DSR_NAMED_FIELD(registration.gauge, StringToGauge)},
  {"panorama_sampling", OptionType::kString, "half_voxel", "Registration",
   kDsrRegister | kDsrCompare | kPyRegister,
   "Where the registration's panorama grid samples frame 0 (docs/design.md 2.5): "
   "half_voxel (half a voxel off its lattice everywhere: its samples average 8 voxels; "
   "best where fine detail is independent noise, as in the paper's protocol) or all_phases"
   " (every sub-voxel phase, like the other frames: the grid's spacing is frame 0's times "
   "1 + 1/n, n its longest extent in voxels; for texture the frames share, such as "
   "ultrasound speckle). The fused panorama's grid is not affected.",
   DSR_RULE(IsPanoramaSampling(S(v)), "must be half_voxel or all_phases"),
   DSR_NAMED_FIELD(registration.panorama_sampling, StringToPanoramaSampling)},
  {"panorama_spacing", OptionType::kDouble, "1.0", "Registration",
   kDsrRegister | kDsrFuse | kDsrCompare | kPyRegister | kPyFuse,
   "Panorama voxel spacing as a multiple of frame 0's spacing (at every pyramid level), in"
   " [0.001, 1000], and at most an eighth of frame 0's shortest extent. Larger = fewer "
   "voxels, less memory; a panorama that would not fit in memory is refused.",
   DSR_RULE(D(v) >= 1e-3 && D(v) <= 1e3,
            "must be in [0.001, 1000] (a multiple of frame 0's spacing)"),
   DSR_APPLY(c->registration.panorama_spacing = c->panorama_spacing = D(v))},
  // Checks
  {"min_kept_overlap", OptionType::kDouble, "0.25", "Checks",
   kDsrRegister | kDsrCompare | kPyRegister,
   "Divergence guard: poses at which a frame's best chain of overlapping frames to frame 0"
   " covers less than this fraction of what it covered at the initial poses (the frame "
   "slid out of the overlap) are a failure (exit 1), not a result; in [0, 1), 0 = off. "
   "dsr_compare: off by default (every method's poses are measured, diverged or not), 0.25"
   " with --init=auto or global unless any check that flags frames is set (this one, "
   "--max_structure_fraction, --max_pose_error_voxels, --max_misfit_ratio, "
   "--max_pair_mismatch_ratio): then each has its own value, 0 where not given.",
   nullptr,
   DSR_FIELD(registration.min_kept_overlap)},
  {"max_structure_fraction", OptionType::kDouble, "0.05", "Checks",
   kDsrRegister | kDsrCompare | kPyRegister,
   "Structure check (docs/design.md 8.4): poses at which more than this fraction of a "
   "frame's own structure (its samples' covariance at a lag beyond noise and "
   "interpolation) remains in its differences to the panorama, standing out of what noise "
   "alone gives, are a failure (exit 1), not a result; in [0, 1), 0 = off. dsr_compare: as"
   " --min_kept_overlap (0.05 with --init=auto or global).",
   nullptr,
   DSR_FIELD(registration.max_structure_fraction)},
  {"max_pose_error_voxels", OptionType::kDouble, "1.0", "Checks",
   kDsrRegister | kDsrCompare | kPyRegister,
   "Determination check (docs/design.md 8.7; dsr and dba with the squared --loss, on the "
   "gain-corrected intensities where gains and offsets are estimated): final poses at "
   "which the data leave some frame's pose undetermined "
   "(the cost does not curve up along some motion of it, or the error the image noise "
   "alone puts on it exceeds this many of its voxels: a symmetric or featureless object) "
   "are a failure (exit 1) naming the frame and whether its rotation or translation; >= 0,"
   " 0 = off. dsr_compare: as --min_kept_overlap (1 with --init=auto or global).",
   nullptr,
   DSR_FIELD(registration.max_pose_error_voxels)},
  {"detect_dropouts", OptionType::kBool, "false", "Registration",
   kDsrRegister | kDsrCompare | kPyRegister,
   "Dropouts (docs/design.md 2.10; on with --preset=echo): in each view whose field of view "
   "is an ultrasound sector (it widens from an apex), leave out of its mask the beams along "
   "which only noise remains (probe contact lost); the summary names the share of each view "
   "left out. A view alone cannot tell lost contact from tissue that returns nothing, so "
   "it is off for other data.",
   nullptr,
   DSR_FIELD(registration.detect_dropouts)},
  {"max_misfit_ratio", OptionType::kDouble, "0.0", "Checks",
   kDsrRegister | kDsrCompare | kPyRegister,
   "Former misfit check, off by default (docs/design.md 8.5): poses at which a frame's RMS"
   " difference to the panorama exceeds this multiple of the frames' lower quartile are a "
   "failure (exit 1); 0 = off or > 1.",
   nullptr,
   DSR_FIELD(registration.max_misfit_ratio)},
  {"max_pair_mismatch_ratio", OptionType::kDouble, "0.0", "Checks",
   kDsrRegister | kDsrCompare | kPyRegister,
   "Former pair check, off by default (docs/design.md 8.5): poses at which two overlapping"
   " frames match each other (1 - NCC over their overlap, on the coarsest level) worse "
   "than this multiple of the pairs' lower quartile are a failure (exit 1); 0 = off or > "
   "1.",
   nullptr,
   DSR_FIELD(registration.max_pair_mismatch_ratio)},
  {"uncertainty", OptionType::kBool, "false", "Checks", kDsrRegister | kDsrCompare | kPyRegister,
   "Estimate each frame's pose covariance and predicted TRE (modes dsr and dba; "
   "docs/design.md section 8.6). dsr_register writes them into --out_poses "
   "(\"covariance\", \"predicted_tre_mm\"), the summary and the report; dsr_compare adds "
   "the mean predicted TRE and the mean normalised squared pose error (6 when calibrated) "
   "to results.csv (predicted_tre_mm, nees). Noise only: not a wrong minimum, brightness "
   "changes or interpolation bias.",
   nullptr,
   DSR_FIELD(registration.uncertainty)},
  // Global search
  {"search_rotation_deg", OptionType::kDouble, "45.0", "Global search",
   kDsrRegister | kDsrCompare | kPyRegister,
   "Global search (recovery, --init=global): rotations within this angle of frame 0's "
   "orientation, in (0, 180].",
   nullptr,
   DSR_FIELD(registration.search.rotation_deg)},
  {"search_rotations", OptionType::kInt32, "200", "Global search",
   kDsrRegister | kDsrCompare | kPyRegister,
   "Global search: about this many rotations sampled, in [1, 100000] (more: finer, "
   "slower).",
   nullptr,
   DSR_FIELD(registration.search.rotations)},
  {"search_pair_rotations", OptionType::kInt32, "60", "Global search",
   kDsrRegister | kDsrCompare | kPyRegister,
   "Global search of --init=global and of a recovery that places every frame: about this "
   "many rotations per pair of frames, in [1, 100000].",
   nullptr,
   DSR_FIELD(registration.search.pair_rotations)},
  {"search_max_axis", OptionType::kInt32, "32", "Global search",
   kDsrRegister | kDsrCompare | kPyRegister,
   "Global search: on the coarsest pyramid level, halved further until no frame axis is "
   "longer than this many voxels, >= 8 (larger: finer, slower).",
   nullptr,
   DSR_FIELD(registration.search_max_axis)},
  // Pyramid
  {"pyramid_levels", OptionType::kInt32, "3", "Pyramid", kDsrRegister | kDsrCompare | kPyRegister,
   "Pyramid levels (1 = full resolution only), in 1..8.",
   nullptr,
   DSR_FIELD(registration.pyramid_levels)},
  {"pyramid_min_size", OptionType::kInt32, "12", "Pyramid",
   kDsrRegister | kDsrCompare | kPyRegister,
   "No pyramid level has an axis shorter than this many voxels (levels are dropped "
   "instead), >= 4.",
   nullptr,
   DSR_FIELD(registration.pyramid_min_size)},
  {"pyramid_sigma", OptionType::kDouble, "1.0", "Pyramid",
   kDsrRegister | kDsrCompare | kPyRegister,
   "Gaussian sigma (voxels) before each halving, >= 0.",
   nullptr,
   DSR_FIELD(registration.pyramid_sigma)},
  {"smoothing", OptionType::kDouble, "0.0", "Pyramid", kDsrRegister | kDsrCompare | kPyRegister,
   "Gaussian sigma (voxels) applied to the finest level, >= 0.",
   nullptr,
   DSR_FIELD(registration.smoothing)},
  {"max_rebuilds", OptionType::kInt32, "4", "Pyramid", kDsrRegister | kDsrCompare | kPyRegister,
   "Candidate-set rebuilds per level after the first solve, >= 0.",
   nullptr,
   DSR_FIELD(registration.max_rebuilds)},
  {"rebuild_tolerance", OptionType::kDouble, "0.05", "Pyramid",
   kDsrRegister | kDsrCompare | kPyRegister,
   "A level stops rebuilding when its last solve moved no field-of-view corner by more "
   "than this many voxels, > 0.",
   nullptr,
   DSR_FIELD(registration.rebuild_tolerance)},
  // Solver
  {"max_iterations", OptionType::kInt32, "100", "Solver",
   kDsrRegister | kDsrCompare | kPyRegister,
   "Iteration limit of each solve on the finest level, >= 1.",
   nullptr,
   DSR_FIELD(registration.solve.max_iterations)},
  {"coarse_max_iterations", OptionType::kInt32, "50", "Solver",
   kDsrRegister | kDsrCompare | kPyRegister,
   "Iteration limit of each solve on coarser levels, >= 1.",
   nullptr,
   DSR_FIELD(registration.coarse_max_iterations)},
  {"function_tolerance", OptionType::kDouble, "1e-8", "Solver",
   kDsrRegister | kDsrCompare | kPyRegister,
   "Ceres function tolerance (relative cost change).",
   nullptr,
   DSR_FIELD(registration.solve.function_tolerance)},
  {"gradient_tolerance", OptionType::kDouble, "1e-12", "Solver",
   kDsrRegister | kDsrCompare | kPyRegister,
   "Ceres gradient tolerance.",
   nullptr,
   DSR_FIELD(registration.solve.gradient_tolerance)},
  {"parameter_tolerance", OptionType::kDouble, "1e-10", "Solver",
   kDsrRegister | kDsrCompare | kPyRegister,
   "Ceres parameter tolerance (relative step).",
   nullptr,
   DSR_FIELD(registration.solve.parameter_tolerance)},
  {"step_tolerance", OptionType::kDouble, "5e-3", "Solver",
   kDsrRegister | kDsrCompare | kPyRegister,
   "A solve stops when the distance still to go to its fixed point, estimated from the "
   "last accepted steps (docs/design.md 7.4), moves no frame's field of view by more than "
   "this many voxels (0 = off), >= 0.",
   nullptr,
   DSR_FIELD(registration.solve.step_tolerance)},
  {"max_rejected_steps", OptionType::kInt32, "5", "Solver",
   kDsrRegister | kDsrCompare | kPyRegister,
   "A solve stops after this many rejected steps in a row (0 = off), >= 0.",
   nullptr,
   DSR_FIELD(registration.solve.max_rejected_steps)},
  {"linear_solver", OptionType::kString, "", "Solver", kDsrRegister | kDsrCompare | kPyRegister,
   "Ceres linear solver. dba: DENSE_SCHUR (default), SPARSE_SCHUR, ITERATIVE_SCHUR, "
   "DENSE_QR, SPARSE_NORMAL_CHOLESKY. dsr: DENSE_QR (default), DENSE_NORMAL_CHOLESKY.",
   DSR_RULE(S(v).empty() || IsLinearSolver(S(v)), "not a Ceres linear solver name"),
   &ApplyLinearSolver},
  {"trust_region", OptionType::kString, "LEVENBERG_MARQUARDT", "Solver",
   kDsrRegister | kDsrCompare | kPyRegister,
   "LEVENBERG_MARQUARDT or DOGLEG.",
   DSR_RULE(IsTrustRegion(S(v)), "must be LEVENBERG_MARQUARDT or DOGLEG"),
   DSR_NAMED_FIELD(registration.solve.trust_region, ceres::StringToTrustRegionStrategyType)},
  {"kernels", OptionType::kString, "auto", "Solver", kDsrRegister | kDsrCompare | kPyRegister,
   "SIMD kernels of the streamed costs (dsr, ape, pairs): auto (the widest this CPU runs),"
   " portable (plain C++, the tests' twin), avx2 or avx512. Results agree to rounding.",
   DSR_CHECK(CheckKernels(S(v))),
   &ApplyKernels},
  {"num_chunks", OptionType::kInt32, "1", "Solver", kDsrRegister | kDsrCompare | kPyRegister,
   "dsr and ape: residual blocks the candidate voxels are split into, >= 1.",
   nullptr,
   DSR_FIELD(registration.dsr.num_chunks)},
  {"reference_cost", OptionType::kBool, "false", "Solver",
   kDsrRegister | kDsrCompare | kPyRegister,
   "dsr: use the per-voxel reference cost (stores Jacobians; small problems only).",
   nullptr,
   DSR_FIELD(registration.dsr.reference_cost)},
  {"memory_budget_mb", OptionType::kDouble, "0.0", "Solver",
   kDsrRegister | kDsrCompare | kPyRegister,
   "dba: refuse problems estimated above this many MiB; 0 = half the machine's RAM.",
   DSR_RULE(D(v) >= 0.0 && std::isfinite(D(v)), "must be >= 0"),
   DSR_FIELD(registration.dba.memory_budget_mb)},
  {"num_threads", OptionType::kInt32, "0", "Solver",
   kDsrRegister | kDsrFuse | kDsrCompare | kPyRegister | kPyFuse,
   "Threads, >= 0 (0 = all hardware threads).",
   DSR_RULE(I(v) >= 0, "must be >= 0"),
   &ApplyNumThreads},
  {"progress", OptionType::kBool, "true", "Solver", kDsrRegister | kDsrCompare,
   "Print one line per solver iteration on stderr (dsr_compare: off by default).",
   nullptr,
   DSR_FIELD(registration.solve.progress)},
  // Outputs
  {"out_poses", OptionType::kString, "", "Outputs", kDsrRegister,
   "Output poses JSON (T maps world = frame 0 to each frame, frame 0 = identity). "
   "Required.",
   nullptr,
   nullptr},
  {"out_panorama", OptionType::kString, "", "Outputs", kDsrRegister,
   "Optional output image of the panorama on the final grid: the per-voxel mean of the "
   "observations (paper eq. 10; with --photometric=affine of the corrected ones); with "
   "--mode=dba the optimised intensities.",
   nullptr,
   nullptr},
  {"out_tfm_dir", OptionType::kString, "", "Outputs", kDsrRegister,
   "Optional folder (created if missing) for one ITK transform per frame, frame_XX.tfm "
   "(world -> frame, LPS): resampling frame XX with it in 3D Slicer, ITK/SimpleITK, ANTs "
   "or elastix lands it on the panorama.",
   nullptr,
   nullptr},
  {"out_resampled_dir", OptionType::kString, "", "Outputs", kDsrRegister,
   "Optional folder (created if missing) for each frame resampled onto the panorama grid, "
   "frame_XX_in_panorama.nii.gz (0 outside its field of view), in the frame's own "
   "intensities (with --photometric=affine, --out_poses' gain * value + offset puts them "
   "on frame 0's scale).",
   nullptr,
   nullptr},
  {"report_dir", OptionType::kString, "", "Outputs", kDsrRegister,
   "Optional folder (created if missing) for a report: pictures (panorama slices with "
   "field-of-view outlines, a frame pair before/after, convergence), poses, transforms and"
   " index.md.",
   nullptr,
   nullptr},
  {"report_frames", OptionType::kString, "", "Outputs", kDsrRegister,
   "Frames outlined on the report's panorama slices, comma-separated indices; empty = 0, "
   "the middle and the last frame.",
   nullptr,
   nullptr},
  {"report_pair", OptionType::kString, "0,1", "Outputs", kDsrRegister,
   "The two frames the report compares before/after, 'a,b'.",
   nullptr,
   nullptr},
  {"report_phase", OptionType::kInt32, "0", "Outputs", kDsrRegister,
   "Views with phases: the phase the report's pictures show, as its position in --phases "
   "(0: the first registered phase).",
   DSR_RULE(I(v) >= 0, "must be >= 0"),
   DSR_FIELD(report_phase)},
  // Fusion
  {"poses", OptionType::kString, "", "Fusion", kDsrFuse,
   "Poses JSON (dsr_register --out_poses), one entry per image. Its entries are matched to"
   " --images by their \"image\" names (the image's path as given, its file name, or its "
   "file name without the extension) and reordered to --images' order; a name that matches"
   " no image, or an image matched by no entry, is an error. A file whose names are all "
   "empty is used in its order. When its entries have \"gain\" and \"offset\" "
   "(dsr_register --photometric=affine), each frame's samples are corrected to gain * "
   "value + offset (frame 0's intensity scale) before they are fused. Required.",
   nullptr,
   nullptr},
  {"out", OptionType::kString, "", "Fusion", kDsrFuse,
   "Output panorama image (.nii, .nii.gz, .mha, .nrrd). Required.",
   nullptr,
   nullptr},
  {"out_count", OptionType::kString, "", "Fusion", kDsrFuse,
   "Optional output image of k_j, the number of frames observing each panorama voxel "
   "(integer values 0..frames, stored as float voxels).",
   nullptr,
   nullptr},
  {"blend", OptionType::kString, "mean", "Fusion",
   kDsrRegister | kDsrFuse | kPyRegister | kPyFuse,
   "Panorama blending: mean (paper eq. 10: the per-voxel mean of the observations) or "
   "feather (weights fall off towards each field-of-view edge, so seams vanish).",
   DSR_RULE(S(v) == "mean" || S(v) == "feather", "must be mean or feather"),
   DSR_APPLY(c->feather = S(v) == "feather")},
  {"feather_voxels", OptionType::kDouble, "8.0", "Fusion",
   kDsrRegister | kDsrFuse | kPyRegister | kPyFuse,
   "--blend=feather: depth (frame voxels) over which a frame's weight rises from 0 at its "
   "field-of-view edge to 1, > 0.",
   DSR_RULE(D(v) > 0.0 && std::isfinite(D(v)), "must be > 0"),
   DSR_FIELD(feather_voxels)},
  // Simulation
  {"out_dir", OptionType::kString, "", "Simulation", kDsrSimulate | kDsrCompare,
   "Output folder, created if missing: dsr_simulate writes frame_XX.nii.gz, mask_XX.nii.gz"
   " and gt_poses.json there, dsr_compare results.csv, results.md and poses/. Required.",
   nullptr,
   nullptr},
  {"source", OptionType::kString, "", "Simulation", kDsrSimulate | kDsrCompare | kPySimulate,
   "Source volume to cut the frames from (.nii, .nii.gz, .mha, .mhd, .nrrd, .nhdr). Empty:"
   " the built-in heart-like phantom (see --phantom_size, --phantom_seed).",
   DSR_CHECK(InputFileRule(S(v))),
   nullptr},
  {"write_source", OptionType::kBool, "false", "Simulation", kDsrSimulate,
   "Also write the source volume as DIR/source.nii.gz.",
   nullptr,
   nullptr},
  {"seed", OptionType::kUint64, "1", "Simulation", kDsrSimulate | kDsrCompare | kPySimulate,
   "Random seed of the poses, the noise and the ultrasound-like effects: same seed, same "
   "sequence (dsr_compare: of its first simulated sequence; sequence s uses --seed + s).",
   nullptr,
   DSR_FIELD(simulation.seed)},
  {"num_frames", OptionType::kInt32, "11", "Simulation", kDsrSimulate | kDsrCompare | kPySimulate,
   "Number of frames m, in [2, 1000] (the paper: 11; a registration takes at most 32).",
   DSR_RULE(I(v) >= 2 && I(v) <= 1000, "must be in [2, 1000]"),
   DSR_FIELD(simulation.num_frames)},
  {"sigma", OptionType::kDouble, "25.0", "Simulation", kDsrSimulate | kDsrCompare | kPySimulate,
   "Standard deviation of the additive Gaussian noise inside the field of view, in "
   "intensity units (0..255 scale), >= 0 (the paper: 25).",
   DSR_RULE(NonNegative(D(v)), "must be finite and >= 0"),
   DSR_FIELD(simulation.sigma)},
  {"pose_model", OptionType::kString, "random", "Simulation",
   kDsrSimulate | kDsrCompare | kPySimulate,
   "How the frames' poses are drawn: random (the paper: every frame independently uniform "
   "in the pose box of --max_rotation_deg and --max_translation_voxels) or walk (frame 0 "
   "as random, then each frame the previous one rotated about its centre by at most "
   "--step_rotation_deg about a random axis and shifted by at most "
   "--step_translation_voxels in a random direction, like a probe moved between "
   "acquisitions; clamped to the pose box).",
   DSR_RULE(IsPoseModel(S(v)), "must be random or walk"),
   DSR_NAMED_FIELD(simulation.pose_model, StringToPoseModel)},
  {"max_rotation_deg", OptionType::kDouble, "12.0", "Simulation",
   kDsrSimulate | kDsrCompare | kPySimulate,
   "Each of the three Euler angles of a frame's rotation is within [-this, +this] degrees "
   "(uniform with --pose_model=random), in [0, 180] (the paper: 12). Larger motions need "
   "room in the source: for 96x96x80 frames the default 192^3 phantom fits 45 degrees with"
   " 10 voxels, but 25 degrees with 20 voxels only just (an unlucky draw leaves it by a "
   "voxel): use --phantom_size=208 there.",
   DSR_RULE(InRange(D(v), 0.0, 180.0), "must be in [0, 180]"),
   DSR_FIELD(simulation.max_rotation_deg)},
  {"max_translation_voxels", OptionType::kDouble, "15.0", "Simulation",
   kDsrSimulate | kDsrCompare | kPySimulate,
   "Each world-axis component of a frame's translation is within [-this, +this] frame "
   "voxels (uniform with --pose_model=random), >= 0 (the paper: 15).",
   DSR_RULE(NonNegative(D(v)), "must be finite and >= 0"),
   DSR_FIELD(simulation.max_translation_voxels)},
  {"step_rotation_deg", OptionType::kDouble, "6.0", "Simulation",
   kDsrSimulate | kDsrCompare | kPySimulate,
   "--pose_model=walk: the rotation between consecutive frames, about a uniformly random "
   "axis through the previous frame's centre, is uniform in [0, this] degrees, in [0, "
   "180].",
   DSR_RULE(InRange(D(v), 0.0, 180.0), "must be in [0, 180]"),
   DSR_FIELD(simulation.step_rotation_deg)},
  {"step_translation_voxels", OptionType::kDouble, "6.0", "Simulation",
   kDsrSimulate | kDsrCompare | kPySimulate,
   "--pose_model=walk: the shift of the frame centre between consecutive frames, in a "
   "uniformly random direction, is uniform in [0, this] frame voxels, >= 0.",
   DSR_RULE(NonNegative(D(v)), "must be finite and >= 0"),
   DSR_FIELD(simulation.step_translation_voxels)},
  {"frame_size", OptionType::kString, "96,96,80", "Simulation",
   kDsrSimulate | kDsrCompare | kPySimulate,
   "Frame grid size in voxels 'nx,ny,nz', each in [4, 2048]; the pyramid's depth runs "
   "along z from the apex at the centre of the z = 0 face.",
   DSR_RULE(IsSize3(S(v), 4, 2048), "must be three integers 'nx,ny,nz', each in [4, 2048]"),
   DSR_APPLY(ParseSize3(S(v), &c->simulation.frame_size, 4, 2048))},
  {"frame_spacing", OptionType::kDouble, "0.0", "Simulation",
   kDsrSimulate | kDsrCompare | kPySimulate,
   "Isotropic frame voxel spacing in mm, 0 or in [1e-6, 1e6]; 0 = the source's spacing "
   "along x.",
   DSR_RULE(D(v) == 0.0 || (D(v) >= kMinFrameSpacingMm && D(v) <= kMaxFrameSpacingMm),
            "must be 0 (the source's spacing) or in [1e-06, 1e+06] mm"),
   DSR_FIELD(simulation.frame_spacing)},
  {"azimuth_deg", OptionType::kDouble, "75.0", "Simulation",
   kDsrSimulate | kDsrCompare | kPySimulate,
   "Full lateral (x) opening angle of the pyramidal field of view, in (0, 180).",
   DSR_RULE(std::isfinite(D(v)) && D(v) > 0.0 && D(v) < 180.0, "must be in (0, 180)"),
   DSR_FIELD(simulation.azimuth_deg)},
  {"elevation_deg", OptionType::kDouble, "75.0", "Simulation",
   kDsrSimulate | kDsrCompare | kPySimulate,
   "Full elevational (y) opening angle of the pyramidal field of view, in (0, 180).",
   DSR_RULE(std::isfinite(D(v)) && D(v) > 0.0 && D(v) < 180.0, "must be in (0, 180)"),
   DSR_FIELD(simulation.elevation_deg)},
  {"min_depth_voxels", OptionType::kDouble, "4.0", "Simulation",
   kDsrSimulate | kDsrCompare | kPySimulate,
   "Near-field cut: slices with depth z < this are outside the field of view; in [0, nz - "
   "3].",
   DSR_RULE(NonNegative(D(v)), "must be finite and >= 0"),
   DSR_FIELD(simulation.min_depth_voxels)},
  {"phantom_size", OptionType::kInt32, "192", "Simulation",
   kDsrSimulate | kDsrCompare | kPySimulate,
   "Built-in phantom size in voxels per axis (1 mm spacing), in [16, 512]. The default "
   "fits the default frames and motions; 208 fits them at --max_rotation_deg=25 "
   "--max_translation_voxels=20.",
   DSR_RULE(I(v) >= 16 && I(v) <= 512, "must be in [16, 512]"),
   DSR_FIELD(phantom.size)},
  {"phantom_seed", OptionType::kUint64, "1", "Simulation",
   kDsrSimulate | kDsrCompare | kPySimulate,
   "Seed of the built-in phantom's layout jitter and texture. Kept apart from --seed so "
   "that sequences with different --seed are cut from the same volume, as in the paper.",
   nullptr,
   DSR_FIELD(phantom.seed)},
  {"interpolation", OptionType::kString, "linear", "Simulation",
   kDsrSimulate | kDsrCompare | kPySimulate,
   "How a frame voxel samples the source at its world point: linear (trilinear, the "
   "default) or cubic (Keys' cubic convolution, a = -0.5, over 4x4x4 voxels, indices "
   "clamped at the source's border). Either way the frames are exact samples of one "
   "continuous interpolant of the source.",
   DSR_RULE(IsSourceInterpolation(S(v)), "must be linear or cubic"),
   DSR_NAMED_FIELD(simulation.interpolation, StringToSourceInterpolation)},
  {"gain_range", OptionType::kDouble, "0.0", "Simulation",
   kDsrSimulate | kDsrCompare | kPySimulate,
   "Ultrasound-like effect (off at 0): each frame's intensities are multiplied by a gain "
   "drawn uniformly in [1 - this, 1 + this], in [0, 0.9]. With --gain_range or "
   "--offset_range, gt_poses.json gets per-frame \"gain\" and \"offset\": the correction "
   "that puts frame i on frame 0's intensity scale, gain_i * I_i + offset_i (frame 0: 1 "
   "and 0).",
   DSR_RULE(InRange(D(v), 0.0, 0.9), "must be in [0, 0.9]"),
   DSR_FIELD(simulation.gain_range)},
  {"offset_range", OptionType::kDouble, "0.0", "Simulation",
   kDsrSimulate | kDsrCompare | kPySimulate,
   "Ultrasound-like effect (off at 0): each frame's intensities get an offset drawn "
   "uniformly in [-this, this] grey levels (after the gain), in [0, 100].",
   DSR_RULE(InRange(D(v), 0.0, 100.0), "must be in [0, 100]"),
   DSR_FIELD(simulation.offset_range)},
  {"speckle_looks", OptionType::kInt32, "0", "Simulation",
   kDsrSimulate | kDsrCompare | kPySimulate,
   "Ultrasound-like effect (off at 0): multiplicative speckle of mean 1, drawn anew for "
   "each frame on its own grid (it follows the probe, not the tissue; see "
   "--speckle_world_fraction): the mean of this many looks of |z|^2, each z a complex "
   "Gaussian field smoothed over --speckle_correlation_voxels; a gamma distribution with "
   "variance 1/looks. 0 or in [1, 64].",
   DSR_RULE(I(v) >= 0 && I(v) <= 64, "must be 0 (no speckle) or in [1, 64]"),
   DSR_FIELD(simulation.speckle_looks)},
  {"speckle_correlation_voxels", OptionType::kDouble, "1.0", "Simulation",
   kDsrSimulate | kDsrCompare | kPySimulate,
   "With --speckle_looks: standard deviation, in frame voxels, of the Gaussian that "
   "smooths each look's complex field (the speckle's correlation at a lag of d voxels is "
   "about exp(-d^2 / (2 this^2)) for this >= 1), in [0, 4]; 0: independent voxels.",
   DSR_RULE(InRange(D(v), 0.0, 4.0), "must be in [0, 4]"),
   DSR_FIELD(simulation.speckle_correlation_voxels)},
  {"speckle_world_fraction", OptionType::kDouble, "0.0", "Simulation",
   kDsrSimulate | kDsrCompare | kPySimulate,
   "With --speckle_looks: the fraction rho of each look's complex field that is fixed in "
   "the world (the tissue) and shared by all frames, the rest drawn per frame: z = "
   "sqrt(rho) z_world + sqrt(1 - rho) z_frame, so the speckle keeps its mean and variance "
   "and two frames' speckle at one world point correlates by about rho^2. In [0, 1]; 0: "
   "independent per frame (the former sequences); > 0 needs --speckle_looks >= 1.",
   DSR_RULE(InRange(D(v), 0.0, 1.0), "must be in [0, 1]"),
   DSR_FIELD(simulation.speckle_world_fraction)},
  {"attenuation_db_per_cm", OptionType::kDouble, "0.0", "Simulation",
   kDsrSimulate | kDsrCompare | kPySimulate,
   "Ultrasound-like effect (off at 0): depth attenuation; a voxel at distance r cm from "
   "the pyramid's apex (the centre of the z = 0 face) is multiplied by 10^(-this * r / "
   "20), in [0, 10] dB/cm. Applied, like the speckle, before the gain, the offset and the "
   "noise.",
   DSR_RULE(InRange(D(v), 0.0, 10.0), "must be in [0, 10]"),
   DSR_FIELD(simulation.attenuation_db_per_cm)},
  {"echogenicity_range", OptionType::kDouble, "0.0", "Simulation",
   kDsrSimulate | kDsrCompare | kPySimulate,
   "Real-echo effect (off at 0): view-dependent echogenicity; an interface (the noise-free "
   "frame's gradient, its top 10 % fully) is brighter by up to this share where the beam "
   "meets it head on and darker by as much where the beam runs along it (x 1 + this cos "
   "2 phi, phi the angle between the gradient and the beam from the apex), in [0, 0.9].",
   DSR_RULE(InRange(D(v), 0.0, 0.9), "must be in [0, 0.9]"),
   DSR_FIELD(simulation.echogenicity_range)},
  {"shadow_strength", OptionType::kDouble, "0.0", "Simulation",
   kDsrSimulate | kDsrCompare | kPySimulate,
   "Real-echo effect (off at 0): acoustic shadows; each voxel a beam crosses with a value "
   "above --shadow_threshold lets 1 - this x min(1, (value - threshold) / (255 - "
   "threshold)) of it through, so what lies behind a bright reflector darkens, differently "
   "in every view. In [0, 1].",
   DSR_RULE(InRange(D(v), 0.0, 1.0), "must be in [0, 1]"),
   DSR_FIELD(simulation.shadow_strength)},
  {"shadow_threshold", OptionType::kDouble, "200.0", "Simulation",
   kDsrSimulate | kDsrCompare | kPySimulate,
   "With --shadow_strength: the grey level above which a voxel casts a shadow, in [0, 250].",
   DSR_RULE(InRange(D(v), 0.0, 250.0), "must be in [0, 250]"),
   DSR_FIELD(simulation.shadow_threshold)},
  {"psf_lateral_mm", OptionType::kDouble, "0.0", "Simulation",
   kDsrSimulate | kDsrCompare | kPySimulate,
   "Real-echo effect (off at 0): a lateral point-spread function that widens with depth; "
   "each slice at depth k is smoothed across the beam by a Gaussian of this standard "
   "deviation (mm) times k / (depth - 1), inside the field of view, in [0, 20].",
   DSR_RULE(InRange(D(v), 0.0, 20.0), "must be in [0, 20]"),
   DSR_FIELD(simulation.psf_lateral_mm)},
  {"dropout_fraction", OptionType::kDouble, "0.0", "Simulation",
   kDsrSimulate | kDsrCompare | kPySimulate,
   "Real-echo effect (off at 0): signal dropouts; a view (with chance "
   "--dropout_view_fraction) loses contact over a wedge of its sector covering between "
   "half of this and this share of the azimuth opening, where only the noise remains. In "
   "[0, 0.9].",
   DSR_RULE(InRange(D(v), 0.0, 0.9), "must be in [0, 0.9]"),
   DSR_FIELD(simulation.dropout_fraction)},
  {"dropout_view_fraction", OptionType::kDouble, "0.33", "Simulation",
   kDsrSimulate | kDsrCompare | kPySimulate,
   "With --dropout_fraction: the chance that a view has a dropout wedge, in [0, 1].",
   DSR_RULE(InRange(D(v), 0.0, 1.0), "must be in [0, 1]"),
   DSR_FIELD(simulation.dropout_view_fraction)},
  {"dropouts_out_of_masks", OptionType::kBool, "false", "Simulation",
   kDsrSimulate | kDsrCompare | kPySimulate,
   "With --dropout_fraction: the masks leave out each view's dropout wedge (the "
   "simulator's own knowledge of where the signal is lost, for comparisons).",
   nullptr,
   DSR_FIELD(simulation.dropouts_out_of_masks)},
  {"intensity_mapping", OptionType::kString, "none", "Simulation",
   kDsrSimulate | kDsrCompare | kPySimulate,
   "How the source's intensities are mapped before the frames are cut: none (as they are) "
   "or echo (echocardiography-like, for any source: the source is mapped once on its own "
   "grid to 255 clamp((1 - w) max(0, S - r) / (255 - r) + w min(1, |grad G * S| / g99), 0,"
   " 1), with r = --echo_reject (darker regions such as a blood pool, lungs or CSF go "
   "black), G a Gaussian of --echo_edge_sigma_mm, g99 the 99th percentile of the gradient "
   "magnitude over the non-zero source voxels and w = --echo_edge_weight (bright "
   "interfaces); the effects and the noise are then applied to the frames as without it).",
   DSR_RULE(IsIntensityMapping(S(v)), "must be none or echo"),
   DSR_NAMED_FIELD(simulation.intensity_mapping, StringToIntensityMapping)},
  {"echo_reject", OptionType::kDouble, "76.5", "Simulation",
   kDsrSimulate | kDsrCompare | kPySimulate,
   "--intensity_mapping=echo: source values up to this (grey levels) map to black, as "
   "below an echo machine's reject; the rest is rescaled to the full scale. In [0, 250]; "
   "the default is 30 % of full scale.",
   DSR_RULE(InRange(D(v), 0.0, 250.0), "must be in [0, 250]"),
   DSR_FIELD(simulation.echo_reject)},
  {"echo_edge_sigma_mm", OptionType::kDouble, "1.0", "Simulation",
   kDsrSimulate | kDsrCompare | kPySimulate,
   "--intensity_mapping=echo: standard deviation in mm (physical, also on anisotropic "
   "sources) of the Gaussian that smooths the source before its gradient is taken for the "
   "interfaces, in [0, 20]; 0: the raw source.",
   DSR_RULE(InRange(D(v), 0.0, 20.0), "must be in [0, 20]"),
   DSR_FIELD(simulation.echo_edge_sigma_mm)},
  {"echo_edge_weight", OptionType::kDouble, "0.35", "Simulation",
   kDsrSimulate | kDsrCompare | kPySimulate,
   "--intensity_mapping=echo: the share of the full scale that the interfaces add "
   "(gradient magnitude at or above its 99th percentile: the whole share), in [0, 1]; 0: "
   "no interfaces.",
   DSR_RULE(InRange(D(v), 0.0, 1.0), "must be in [0, 1]"),
   DSR_FIELD(simulation.echo_edge_weight)},
  {"num_phases", OptionType::kInt32, "1", "Simulation", kDsrSimulate | kPySimulate,
   "Beating source (ECG-gated loops): the number T of phases of one heart cycle recorded "
   "per view, in [1, 64]; all phases of a view share its pose and mask. Phase p samples the "
   "source at x - d_p(x), a smooth radial contraction of a ball around the source's centre "
   "(--beat_radius_mm) by up to --beat_amplitude_mm at t = p/T = 1/2, zero at phase 0 and "
   "outside the ball; each phase draws its own noise and per-frame speckle. 1: a still "
   "source (the former sequences). With T > 1 dsr_simulate writes each view as a 4D NIfTI "
   "frame_XX.nii.gz (its phases along the 4th axis; dsr_register reads it as one view) and "
   "dsr.simulate returns \"phases\".",
   DSR_RULE(I(v) >= 1 && I(v) <= 64, "must be in [1, 64]"),
   DSR_FIELD(simulation.num_phases)},
  {"beat_amplitude_mm", OptionType::kDouble, "4.0", "Simulation", kDsrSimulate | kPySimulate,
   "With --num_phases > 1: the largest displacement of the beat (end-systole), in mm, in [0, "
   "50]; 0: still anatomy in every phase. At most 0.25 times the beat's radius, so that it "
   "folds no tissue.",
   DSR_RULE(InRange(D(v), 0.0, 50.0), "must be in [0, 50]"),
   DSR_FIELD(simulation.beat_amplitude_mm)},
  {"beat_radius_mm", OptionType::kDouble, "0.0", "Simulation", kDsrSimulate | kPySimulate,
   "With --num_phases > 1: the radius of the moving ball around the source's centre, in mm, 0 "
   "or in [0.001, 1e6]; 0: a quarter of the frame depth (20 mm for the default frames). "
   "Anatomy outside it stays still.",
   DSR_RULE(D(v) == 0.0 || InRange(D(v), 1e-3, 1e6), "must be 0 or in [0.001, 1e+06]"),
   DSR_FIELD(simulation.beat_radius_mm)},
  // Comparison
  {"methods", OptionType::kString, "dsr,ape,sequential,lie_normalization,pairwise", "Comparison",
   kDsrCompare,
   "Comma-separated methods: dsr, dba, ape, sequential, lie_normalization, pairwise.",
   nullptr,
   nullptr},
  {"sequences", OptionType::kString, "", "Comparison", kDsrCompare,
   "Comma-separated sequence folders written by dsr_simulate (frame_XX.nii.gz, "
   "mask_XX.nii.gz, gt_poses.json). Empty: simulate --num_sequences sequences from the "
   "built-in phantom or --source with the simulation flags (those of dsr_simulate).",
   nullptr,
   nullptr},
  {"num_sequences", OptionType::kInt32, "5", "Comparison", kDsrCompare,
   "Sequences to simulate when --sequences is empty, in [1, 100] (the paper: 5); sequence "
   "s uses seed --seed + s.",
   nullptr,
   nullptr},
  {"sequence_masks", OptionType::kBool, "true", "Comparison", kDsrCompare,
   "--sequences: register with each folder's mask_XX images; false: with each frame's "
   "field of view by --mask_rule eroded by --mask_erosion voxels, as dsr_register does "
   "without --masks.",
   nullptr,
   nullptr},
};
// clang-format on

#undef DSR_RULE
#undef DSR_CHECK
#undef DSR_APPLY
#undef DSR_FIELD
#undef DSR_NAMED_FIELD
#undef DSR_WRITES

}  // namespace

const char* OptionTypeName(OptionType type) {
  switch (type) {
    case OptionType::kBool: return "bool";
    case OptionType::kInt32: return "int32";
    case OptionType::kUint64: return "uint64";
    case OptionType::kDouble: return "double";
    case OptionType::kString: return "string";
  }
  return "";
}

namespace {
constexpr std::pair<FrontEnd, const char*> kFrontEndNames[] = {
    {kDsrRegister, "dsr_register"},      {kDsrFuse, "dsr_fuse"},
    {kDsrSimulate, "dsr_simulate"},      {kDsrCompare, "dsr_compare"},
    {kPyRegister, "python:register"},    {kPyFuse, "python:fuse"},
    {kPySimulate, "python:simulate"},
};
}  // namespace

std::vector<std::string> FrontEndNames(uint32_t front_ends) {
  std::vector<std::string> names;
  for (const auto& [bit, name] : kFrontEndNames) {
    if (front_ends & bit) names.push_back(name);
  }
  return names;
}

uint32_t FrontEndFromName(const std::string& name) {
  for (const auto& [bit, text] : kFrontEndNames) {
    if (name == text) return bit;
  }
  return 0;
}

const std::vector<OptionSpec>& OptionTable() {
  static const std::vector<OptionSpec>* const table =
      new std::vector<OptionSpec>(std::begin(kOptionTable), std::end(kOptionTable));
  return *table;
}

const OptionSpec* FindOption(std::string_view name) {
  for (const OptionSpec& spec : OptionTable()) {
    if (name == spec.name) return &spec;
  }
  return nullptr;
}

std::string OptionValueText(const OptionValue& value) {
  return std::visit(
      [](const auto& v) -> std::string {
        using V = std::decay_t<decltype(v)>;
        if constexpr (std::is_same_v<V, bool>) {
          return v ? "true" : "false";
        } else if constexpr (std::is_same_v<V, std::string>) {
          return v;
        } else if constexpr (std::is_same_v<V, double>) {
          // The shortest text that reads back as the same double.
          char text[40];
          for (int digits = 1; digits <= 17; ++digits) {
            std::snprintf(text, sizeof(text), "%.*g", digits, v);
            if (std::strtod(text, nullptr) == v) break;
          }
          return text;
        } else {
          return std::to_string(v);
        }
      },
      value);
}

namespace {
// The text as a value of `type`, as gflags reads it: false when it is not one.
bool ParseTyped(OptionType type, const std::string& text, OptionValue* value) {
  const char* begin = text.c_str();
  char* end = nullptr;
  errno = 0;
  switch (type) {
    case OptionType::kBool: {
      std::string lower = text;
      std::transform(lower.begin(), lower.end(), lower.begin(), ::tolower);
      for (const char* yes : {"1", "t", "true", "y", "yes"}) {
        if (lower == yes) return *value = true, true;
      }
      for (const char* no : {"0", "f", "false", "n", "no"}) {
        if (lower == no) return *value = false, true;
      }
      return false;
    }
    case OptionType::kInt32: {
      const long long v = std::strtoll(begin, &end, 10);
      if (text.empty() || *end != '\0' || errno != 0 || v < std::numeric_limits<int32_t>::min() ||
          v > std::numeric_limits<int32_t>::max()) {
        return false;
      }
      return *value = static_cast<int32_t>(v), true;
    }
    case OptionType::kUint64: {
      const size_t first = text.find_first_not_of(" \t");
      if (first == std::string::npos || text[first] == '-') return false;
      const unsigned long long v = std::strtoull(begin, &end, 10);
      if (*end != '\0' || errno != 0) return false;
      return *value = static_cast<uint64_t>(v), true;
    }
    case OptionType::kDouble: {
      const double v = std::strtod(begin, &end);
      if (text.empty() || *end != '\0' || (errno == ERANGE && std::abs(v) > 1.0)) return false;
      return *value = v, true;
    }
    case OptionType::kString:
      return *value = text, true;
  }
  return false;
}
}  // namespace

bool ParseOptionValue(const OptionSpec& spec, const std::string& text, OptionValue* value,
                      std::string* error) {
  const std::string prefix = std::string("--") + spec.name + "=" + text + ": ";
  OptionValue parsed;
  if (!ParseTyped(spec.type, text, &parsed)) {
    *error = prefix + "not a valid " + OptionTypeName(spec.type);
    return false;
  }
  const std::string broken = spec.check == nullptr ? "" : spec.check(parsed);
  if (!broken.empty()) {
    *error = prefix + broken;
    return false;
  }
  *value = std::move(parsed);
  return true;
}

const std::vector<FrontEndDefault>& FrontEndDefaults() {
  static const std::vector<FrontEndDefault>* const defaults = new std::vector<FrontEndDefault>{
      {kDsrCompare, "init", "identity"},
      {kDsrCompare, "min_kept_overlap", "0"},
      {kDsrCompare, "max_misfit_ratio", "0"},
      {kDsrCompare, "max_pair_mismatch_ratio", "0"},
      {kDsrCompare, "max_structure_fraction", "0"},
      {kDsrCompare, "max_pose_error_voxels", "0"},
      {kDsrCompare, "progress", "false"},
      {kPyFuse, "blend", "feather"},
  };
  return *defaults;
}

const char* DefaultFor(const OptionSpec& spec, uint32_t front_end) {
  for (const FrontEndDefault& d : FrontEndDefaults()) {
    if (d.front_end == front_end && std::string_view(d.name) == spec.name) return d.value;
  }
  return spec.default_text;
}

Settings Settings::For(uint32_t front_end) {
  Settings settings;
  for (const FrontEndDefault& d : FrontEndDefaults()) {
    if (d.front_end != front_end) continue;
    std::string error;
    if (!settings.SetDefault(d.name, d.value, &error)) {
      std::fprintf(stderr, "dsr: internal error: a front end's default: %s\n", error.c_str());
      std::abort();
    }
  }
  return settings;
}

const std::vector<Preset>& Presets() {
  static const std::vector<Preset>* const presets = new std::vector<Preset>{
      {"echo",
       {{"photometric", "affine"},
        {"intensity_transform", "sqrt"},
        {"panorama_sampling", "all_phases"},
        {"detect_dropouts", "true"}}},
  };
  return *presets;
}

Settings::Settings() {
  for (const OptionSpec& spec : OptionTable()) {
    OptionValue value;
    ParseTyped(spec.type, spec.default_text, &value);  // the table's test checks every default
    values_.emplace(spec.name, std::move(value));
  }
}

bool Settings::Set(const std::string& name, const std::string& text, std::string* error) {
  if (!SetDefault(name, text, error)) return false;
  set_.insert(name);
  return true;
}

bool Settings::SetDefault(const std::string& name, const std::string& text, std::string* error) {
  const OptionSpec* spec = FindOption(name);
  if (spec == nullptr) {
    *error = "--" + name + "=" + text + ": unknown option";
    return false;
  }
  if (!ParseOptionValue(*spec, text, &values_.find(name)->second, error)) return false;
  if (name == "preset") UpdatePreset();
  return true;
}

bool Settings::ReadFlagfile(const std::string& path, uint32_t front_end, std::string* error) {
  const FlagLookup lookup = [front_end](const std::string& name, bool* is_bool) {
    const OptionSpec* spec = FindOption(name);
    if (spec == nullptr || (spec->front_ends & front_end) == 0) return false;
    *is_bool = spec->type == OptionType::kBool;
    return true;
  };
  std::vector<std::string> lines;
  if (!ExpandFlagfile(path, lookup, &lines, error)) return false;
  for (const std::string& line : lines) {
    std::string name, value;
    bool has_value = false;
    SplitFlagArgument(line, &name, &value, &has_value);  // ExpandFlagfile checked the form
    if (!has_value) {  // --bool or --nobool
      const bool negated = FindOption(name) == nullptr;
      if (negated) name = name.substr(2);
      value = negated ? "false" : "true";
    }
    if (!Set(name, value, error)) {
      *error = "--flagfile=" + path + ": " + *error;
      return false;
    }
  }
  return true;
}

bool Settings::IsDefault(const std::string& name) const { return set_.count(name) == 0; }

const OptionValue& Settings::Value(const std::string& name) const {
  if (IsDefault(name)) {
    const auto preset = preset_values_.find(name);
    if (preset != preset_values_.end()) return preset->second;
  }
  const auto found = values_.find(name);
  if (found == values_.end()) {
    std::fprintf(stderr, "dsr: internal error: no option --%s in the options table\n",
                 name.c_str());
    std::abort();
  }
  return found->second;
}

bool Settings::Bool(const std::string& name) const { return std::get<bool>(Value(name)); }
int32_t Settings::Int(const std::string& name) const { return std::get<int32_t>(Value(name)); }
uint64_t Settings::Uint64(const std::string& name) const {
  return std::get<uint64_t>(Value(name));
}
double Settings::Double(const std::string& name) const { return std::get<double>(Value(name)); }
const std::string& Settings::String(const std::string& name) const {
  return std::get<std::string>(Value(name));
}

std::string Settings::SetOptionsText() const {
  std::string text;
  for (const OptionSpec& spec : OptionTable()) {
    if (IsDefault(spec.name)) continue;
    text += std::string(text.empty() ? "" : " ") + "--" + spec.name + "=" +
            OptionValueText(Value(spec.name));
  }
  return text;
}

std::string Settings::PresetSummary() const {
  const std::string& preset = String("preset");
  if (preset == "none") return "";
  std::string set;
  for (const OptionSpec& spec : OptionTable()) {
    if (preset_values_.count(spec.name) == 0 || !IsDefault(spec.name)) continue;
    set += std::string(set.empty() ? "" : " ") + "--" + spec.name + "=" +
           OptionValueText(preset_values_.at(spec.name));
  }
  return "preset " + preset + ": " + (set.empty() ? "every flag it sets was given" : set);
}

void Settings::UpdatePreset() {
  preset_values_.clear();
  for (const Preset& preset : Presets()) {
    if (String("preset") != preset.name) continue;
    for (const auto& [name, text] : preset.values) {
      OptionValue value;
      std::string error;
      if (ParseOptionValue(*FindOption(name), text, &value, &error)) {
        preset_values_[name] = value;
      }
    }
  }
}

void Settings::ApplyTo(RunConfig* config) const {
  for (const OptionSpec& spec : OptionTable()) {
    if (spec.apply != nullptr) spec.apply(Value(spec.name), config);
  }
}

std::string FieldPathsAsOptions(const std::string& message, uint32_t front_ends) {
  return RewriteFieldPaths(message, [front_ends](const std::string& path) {
    std::string joined = path;
    std::replace(joined.begin(), joined.end(), '.', '_');
    const size_t last = path.rfind('.');
    for (const std::string& name : {joined, path.substr(last == std::string::npos ? 0 : last + 1),
                                    path.substr(0, path.find('.'))}) {
      const OptionSpec* spec = FindOption(name);
      if (spec != nullptr && (spec->front_ends & front_ends) != 0) return "--" + name;
    }
    return path;
  });
}

}  // namespace dsr
