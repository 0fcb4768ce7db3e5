// dsr_register: registers several 3D images simultaneously (pipeline/registration.h) and
// writes the poses (docs/design.md section 1), optionally the panorama, and, with
// --gt_poses, prints per-frame errors against ground truth (eval/eval.h).
#include <chrono>
#include <cinttypes>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <set>
#include <tuple>

#include <gflags/gflags.h>
#include <glog/logging.h>

#include "dsr/eval/eval.h"
#include "dsr/io/io_image.h"
#include "dsr/io/io_poses.h"
#include "dsr/io/io_transform.h"
#include "dsr/model/panorama.h"
#include "dsr/pipeline/input_checks.h"
#include "dsr/pipeline/registration.h"
#include "dsr/pipeline/report.h"
#include "dsr/solve/solve_options.h"
#include "dsr/tools/output_plan.h"
#include "dsr/tools/tool_util.h"
#include "dsr/util/parallel.h"

DEFINE_string(images, "", "Frame images (.nii, .nii.gz, .mha, .mhd, .nrrd, .nhdr), frame 0 "
              "first (it fixes the world): comma-separated, or @LIST: the file LIST with one "
              "path per line (for names that contain commas). Required, at least 2 and at "
              "most 32 (kMaxFrames).");
DEFINE_string(masks, "", "Field-of-view masks, one per image, on the image's grid (non-zero = "
              "inside), comma-separated or @LIST as --images. Empty: each image's non-zero "
              "voxels eroded by --mask_erosion voxels.");
DEFINE_int32(mask_erosion, 1, "Erosion (voxels) of the non-zero region when no --masks are "
             "given, in [0, 50].");
DEFINE_string(mode, "dsr", "Solver: dsr (reduced problem, intensities eliminated), dba "
              "(full direct bundle adjustment in Ceres; small problems only), or one of the "
              "paper's baselines: pairwise, lie_normalization, sequential, ape.");
DEFINE_string(loss, "squared",
              "Loss of the intensity differences (modes dsr and dba; docs/design.md 4.7): "
              "squared, or huber / cauchy with --loss_scale (grey levels of the input) for "
              "outliers such as shadows and reverberation. DBA applies it through Ceres, DSR "
              "by iteratively reweighted solves. --uncertainty is then not estimated.");
DEFINE_double(loss_scale, 0.0, "Scale of --loss=huber or cauchy, in grey levels of the input "
              "(residuals larger than about this are down-weighted); > 0.");
DEFINE_string(photometric, dsr::PhotometricModelToString(dsr::kDefaultPhotometricModel),
              "Photometric model (docs/design.md section 2.8): none, or affine: every solve "
              "also estimates each frame's gain and offset against frame 0 (frame i's "
              "intensities on frame 0's scale are gain * I_i + offset), for frames whose "
              "brightness differs. --mode=dsr or dba only (an explicit affine with a baseline "
              "mode is refused). With affine, --out_poses and the report carry each frame's "
              "\"gain\" and \"offset\", the panorama and the report's pictures use the "
              "corrected intensities, the misfit check compares them, and --uncertainty is "
              "not estimated.");
namespace {
bool ValidatePhotometric(const char* flag, const std::string& v) {
  dsr::PhotometricModel model;
  return dsr::CheckFlag(dsr::StringToPhotometricModel(v, &model), flag, v,
                        "must be none or affine");
}
}  // namespace
DEFINE_validator(photometric, &ValidatePhotometric);
DEFINE_string(init, "auto", "Initial poses: 'auto' (identity; frames the checks flag after a "
              "level are re-placed by a global search against the others and the "
              "registration starts again, at most --max_recoveries times), 'identity' "
              "(no recovery), 'pairwise' (the pairwise baseline's poses, itself started from "
              "identity: the paper's initialisation; no recovery), 'global' (every pair "
              "searched globally, frames placed along the most confident pairs, then "
              "recovery as auto) or a poses JSON file (docs/design.md) with one entry per "
              "image, matched to --images by its image names as dsr_fuse --poses does (then "
              "recovery as auto).");
DEFINE_int32(max_recoveries, dsr::kDefaultMaxRecoveries, "--init=auto, global or FILE: how "
             "many times flagged frames may be re-placed, in [0, 10] (0 = a flagged frame is "
             "a failure, exit 1).");
DEFINE_double(search_rotation_deg, 45.0, "Global search (recovery, --init=global): rotations "
              "within this angle of frame 0's orientation, in (0, 180].");
DEFINE_int32(search_rotations, 200, "Global search: about this many rotations sampled, in "
             "[1, 100000] (more: finer, slower).");
DEFINE_int32(pair_search_rotations, 60, "Global search of --init=global and of a recovery "
             "that places every frame: about this many rotations per pair of frames, in "
             "[1, 100000].");
DEFINE_int32(search_max_axis, 32, "Global search: on the coarsest pyramid level, halved further "
             "until no frame axis is longer than this many voxels, >= 8 (larger: finer, slower).");
DEFINE_double(panorama_spacing, 1.0, "Panorama voxel spacing as a multiple of frame 0's "
              "spacing (at every pyramid level), > 0. Larger = fewer voxels, less memory.");
DEFINE_string(out_poses, "", "Output poses JSON (T maps world = frame 0 to each frame, "
              "frame 0 = identity). Required.");
DEFINE_string(out_panorama, "", "Optional output image of the panorama on the final grid: "
              "the per-voxel mean of the observations (paper eq. 10; with "
              "--photometric=affine of the corrected ones); with --mode=dba the optimised "
              "intensities.");
DEFINE_string(gt_poses, "", "Optional ground-truth poses JSON (e.g. dsr_simulate's "
              "gt_poses.json): prints per-frame errors and the mean absolute errors; "
              "matched to --images by its image names as --init.");
DEFINE_string(linear_solver, "", "Ceres linear solver. dba: DENSE_SCHUR (default), "
              "SPARSE_SCHUR, ITERATIVE_SCHUR, DENSE_QR, SPARSE_NORMAL_CHOLESKY. dsr: DENSE_QR "
              "(default), DENSE_NORMAL_CHOLESKY.");
DEFINE_string(trust_region, "LEVENBERG_MARQUARDT", "LEVENBERG_MARQUARDT or DOGLEG.");
DEFINE_int32(max_iterations, 100, "Iteration limit of each solve on the finest level, >= 1.");
DEFINE_int32(coarse_max_iterations, 50, "Iteration limit of each solve on coarser levels, >= 1.");
DEFINE_double(function_tolerance, 1e-8, "Ceres function tolerance (relative cost change).");
DEFINE_double(gradient_tolerance, 1e-12, "Ceres gradient tolerance.");
DEFINE_double(parameter_tolerance, 1e-10, "Ceres parameter tolerance (relative step).");
DEFINE_double(step_tolerance, 5e-3, "A solve stops when an accepted step moves no frame's field "
              "of view by more than this many voxels (0 = off), >= 0.");
DEFINE_int32(max_rejected_steps, 5, "A solve stops after this many rejected steps in a row "
             "(0 = off), >= 0.");
DEFINE_int32(num_threads, 0, "Threads, 0 = all hardware threads.");
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
              "(exit 1), not a result; in [0, 1), 0 = off.");
DEFINE_double(max_misfit_ratio, 2.0, "Misfit check: final poses at which a frame's RMS "
              "difference to the panorama exceeds this multiple of the frames' lower quartile "
              "(a frame stuck in a wrong minimum) are a failure (exit 1), not a result; 0 = off "
              "or > 1.");
DEFINE_double(max_pair_mismatch_ratio, 5.0, "Pair check: poses at which two overlapping "
              "frames match each other (1 - NCC over their overlap, on the coarsest level) "
              "worse than this multiple of the pairs' lower quartile (frames split into groups "
              "that disagree) are a failure (exit 1), not a result; 0 = off or > 1.");
DEFINE_int32(num_chunks, 1, "dsr: residual blocks the candidate voxels are split into, >= 1.");
DEFINE_bool(reference_cost, false, "dsr: use the per-voxel reference cost (stores Jacobians; "
            "small problems only).");
DEFINE_double(memory_budget_mb, 0.0, "dba: refuse problems estimated above this many MiB; "
              "0 = half the machine's RAM.");
DEFINE_bool(progress, true, "Print one line per iteration on stderr.");
DEFINE_bool(uncertainty, false, "Estimate each frame's pose covariance and predicted TRE "
            "(--mode=dsr or dba; docs/design.md section 8.6) and write them into --out_poses "
            "(\"covariance\", \"predicted_tre_mm\"), the summary and the report. Noise only: "
            "not a wrong minimum, brightness changes or interpolation bias.");
DEFINE_string(blend, "mean", "Panorama blending for --out_panorama and the report: mean (paper "
              "eq. 10) or feather (weights fall off towards each field-of-view edge).");
DEFINE_double(feather_voxels, 8.0, "--blend=feather: depth (frame voxels) over which a frame's "
              "weight rises from 0 at its field-of-view edge to 1, > 0.");
DEFINE_string(out_tfm_dir, "", "Optional folder (created if missing) for one ITK transform per "
              "frame, frame_XX.tfm (world -> frame, LPS): resampling frame XX with it in 3D "
              "Slicer, ITK/SimpleITK, ANTs or elastix lands it on the panorama.");
DEFINE_string(out_resampled_dir, "", "Optional folder (created if missing) for each frame "
              "resampled onto the panorama grid, frame_XX_in_panorama.nii.gz (0 outside its "
              "field of view), in the frame's own intensities (with --photometric=affine, "
              "--out_poses' gain * value + offset puts them on frame 0's scale).");
DEFINE_string(report_dir, "", "Optional folder (created if missing) for a report: pictures "
              "(panorama slices with field-of-view outlines, a frame pair before/after, "
              "convergence), poses, transforms and index.md.");
DEFINE_string(report_frames, "", "Frames outlined on the report's panorama slices, "
              "comma-separated indices; empty = 0, the middle and the last frame.");
DEFINE_string(report_pair, "0,1", "The two frames the report compares before/after, 'a,b'.");

namespace {

using dsr::Fail;

// The pipeline names frames by index; a message that starts with "frame N" also gets the
// file, so that the line names what to fix.
std::string WithFrameFile(const std::string& message, const std::vector<std::string>& paths) {
  int frame = -1, consumed = 0;
  if (std::sscanf(message.c_str(), "frame %d %n", &frame, &consumed) < 1 || consumed == 0 ||
      frame < 0 || frame >= static_cast<int>(paths.size())) {
    return message;
  }
  return paths[frame] + ": " + message;
}

// One line: each frame's estimated gain and offset and, when the ground truth has them
// (on frame 0's scale, as MatchPosesToImages leaves them), the mean absolute errors over
// frames 1..m-1.
std::string PhotometricSummary(const std::vector<dsr::Photometric>& photometric,
                               const dsr::PosesFile* ground_truth) {
  std::string line = "photometric (gain, offset) per frame:";
  char item[96];
  for (size_t i = 0; i < photometric.size(); ++i) {
    std::snprintf(item, sizeof(item), "%s %zu (%.4f, %.3f)", i == 0 ? "" : ";", i,
                  photometric[i].gain(), photometric[i].offset);
    line += item;
  }
  const size_t m = photometric.size();
  const std::vector<dsr::Photometric> truth =
      ground_truth == nullptr ? std::vector<dsr::Photometric>()
                              : dsr::PhotometricFromPoses(*ground_truth);
  if (truth.size() == m && m > 1) {
    double gain_error = 0.0, offset_error = 0.0;
    for (size_t i = 1; i < m; ++i) {
      gain_error += std::abs(photometric[i].gain() - truth[i].gain());
      offset_error += std::abs(photometric[i].offset - truth[i].offset);
    }
    std::snprintf(item, sizeof(item), "; against --gt_poses: MAE gain %.4f, offset %.3f",
                  gain_error / (m - 1), offset_error / (m - 1));
    line += item;
  }
  return line;
}

double SecondsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

// The files written into --out_tfm_dir, --out_resampled_dir and --report_dir
// (pipeline/report.h, ReportFiles).
void PlanFolderOutputs(int m, const std::vector<int>& pair, dsr::OutputPlan* plan) {
  char name[64];
  if (!FLAGS_out_tfm_dir.empty()) {
    plan->AddOutputFolder("out_tfm_dir", FLAGS_out_tfm_dir, FLAGS_out_tfm_dir);
    for (int i = 0; i < m; ++i) {
      std::snprintf(name, sizeof(name), "frame_%02d.tfm", i);
      plan->AddDerivedFile("out_tfm_dir", FLAGS_out_tfm_dir, name);
    }
  }
  if (!FLAGS_out_resampled_dir.empty()) {
    plan->AddOutputFolder("out_resampled_dir", FLAGS_out_resampled_dir, FLAGS_out_resampled_dir);
    for (int i = 0; i < m; ++i) {
      std::snprintf(name, sizeof(name), "frame_%02d_in_panorama.nii.gz", i);
      plan->AddDerivedImage("out_resampled_dir", FLAGS_out_resampled_dir, name);
    }
  }
  if (!FLAGS_report_dir.empty()) {
    const std::string& dir = FLAGS_report_dir;
    plan->AddOutputFolder("report_dir", dir, dir);
    plan->AddOutputFolder("report_dir", dir, (std::filesystem::path(dir) / "transforms").string());
    for (const std::string& file : dsr::ReportFiles(m, pair[0], pair[1])) {
      plan->AddDerivedFile("report_dir", dir, file);
    }
  }
}

int Main(int argc, char** argv) {
  dsr::InitTool(
      "registers several 3D images simultaneously (DSR: direct simultaneous registration).\n"
      "  dsr_register --images=a.nii.gz,b.nii.gz,... --out_poses=poses.json [--masks=...]\n"
      "      [--mode=dsr|dba|pairwise|lie_normalization|sequential|ape]\n"
      "      [--init=auto|identity|pairwise|global|FILE] [--panorama_spacing=1] [--gt_poses=FILE]\n"
      "Exit status: 0 ok, 2 bad input, 1 the solve failed (no pose file written). "
      "--helpshort lists this tool's flags only.",
      {"images", "out_poses"}, &argc, &argv);
  const auto start = std::chrono::steady_clock::now();
  std::string error;

  // Options first, so that flag errors come before any file is read.
  dsr::RegistrationOptions options;
  if (!dsr::StringToMode(FLAGS_mode, &options.mode)) {
    std::string names;
    for (const std::string& name : dsr::ModeNames()) names += (names.empty() ? "" : "|") + name;
    return Fail("--mode=" + FLAGS_mode + ": unknown mode (one of " + names + ")");
  }
  options.solve.trust_region = FLAGS_trust_region;
  options.solve.linear_solver = FLAGS_linear_solver;
  options.solve.max_iterations = FLAGS_max_iterations;
  options.solve.function_tolerance = FLAGS_function_tolerance;
  options.solve.gradient_tolerance = FLAGS_gradient_tolerance;
  options.solve.parameter_tolerance = FLAGS_parameter_tolerance;
  options.solve.num_threads = FLAGS_num_threads;
  options.solve.step_tolerance_voxels = FLAGS_step_tolerance;
  options.solve.max_rejected_steps = FLAGS_max_rejected_steps;
  options.solve.log_progress = FLAGS_progress;
  options.panorama_spacing = FLAGS_panorama_spacing;
  options.pyramid_levels = FLAGS_pyramid_levels;
  options.pyramid_sigma_voxels = FLAGS_pyramid_sigma;
  options.pyramid_min_size = FLAGS_pyramid_min_size;
  options.finest_sigma_voxels = FLAGS_smoothing;
  options.coarse_max_iterations = FLAGS_coarse_max_iterations;
  options.max_rebuilds = FLAGS_max_rebuilds;
  options.rebuild_tolerance_voxels = FLAGS_rebuild_tolerance;
  options.min_kept_overlap = FLAGS_min_kept_overlap;
  options.max_misfit_ratio = FLAGS_max_misfit_ratio;
  options.max_pair_mismatch_ratio = FLAGS_max_pair_mismatch_ratio;
  options.dsr.num_chunks = FLAGS_num_chunks;
  options.dsr.reference_cost = FLAGS_reference_cost;
  options.estimate_uncertainty = FLAGS_uncertainty;
  // The default applies to the modes that estimate photometric parameters; a baseline mode
  // runs without them unless --photometric is given (then Validate refuses it).
  dsr::StringToPhotometricModel(FLAGS_photometric, &options.photometric);  // validated
  if (gflags::GetCommandLineFlagInfoOrDie("photometric").is_default &&
      !dsr::ModeEstimatesPhotometric(options.mode)) {
    options.photometric = dsr::PhotometricModel::kNone;
  }
  if (!dsr::MakeRobustLoss(FLAGS_loss, FLAGS_loss_scale, &options.loss, &error)) {
    return Fail(error);
  }
  if (FLAGS_uncertainty && !dsr::ModeEstimatesPhotometric(options.mode)) {
    return Fail("--uncertainty: needs --mode=dsr or dba (got --mode=" + FLAGS_mode + ")");
  }
  const bool init_from_file = !dsr::SetInitialisation(FLAGS_init, FLAGS_max_recoveries, &options);
  options.search.max_rotation_deg = FLAGS_search_rotation_deg;
  options.search.num_rotations = FLAGS_search_rotations;
  options.search_max_axis_voxels = FLAGS_search_max_axis;
  options.search.num_pair_rotations = FLAGS_pair_search_rotations;
  options.search.num_threads = FLAGS_num_threads;
  options.search.refine.log_progress = false;
  if (!(FLAGS_memory_budget_mb >= 0.0) || !std::isfinite(FLAGS_memory_budget_mb)) {
    return Fail("--memory_budget_mb=" + std::to_string(FLAGS_memory_budget_mb) + ": must be >= 0");
  }
  options.dba.memory_budget_bytes = FLAGS_memory_budget_mb * 1048576.0;
  if (FLAGS_num_threads < 0) {
    return Fail("--num_threads=" + std::to_string(FLAGS_num_threads) + ": must be >= 0");
  }
  if (FLAGS_mask_erosion < 0 || FLAGS_mask_erosion > 50) {
    return Fail("--mask_erosion=" + std::to_string(FLAGS_mask_erosion) + ": must be in [0, 50]");
  }
  if (!options.Validate(&error)) return Fail(error);
  if (FLAGS_blend != "mean" && FLAGS_blend != "feather") {
    return Fail("--blend=" + FLAGS_blend + ": must be mean or feather");
  }
  if (!(FLAGS_feather_voxels > 0.0) || !std::isfinite(FLAGS_feather_voxels)) {
    return Fail("--feather_voxels=" + std::to_string(FLAGS_feather_voxels) + ": must be > 0");
  }

  std::vector<std::string> image_paths, mask_paths;
  if (!dsr::ParseInputList("images", FLAGS_images, &image_paths, &error) ||
      !dsr::ParseInputList("masks", FLAGS_masks, &mask_paths, &error)) {
    return Fail(error);
  }
  const int m = static_cast<int>(image_paths.size());
  if (m < 2) return Fail("--images: need at least 2 images, got " + std::to_string(m));
  if (m > dsr::kMaxFrames) {
    return Fail("--images: at most " + std::to_string(dsr::kMaxFrames) + " frames, got " +
                std::to_string(m));
  }
  // Report frames and pair: indices into --images.
  std::vector<int> outlined, pair;
  for (const auto& [flag, text, list] :
       {std::tuple<const char*, std::string, std::vector<int>*>{"report_frames", FLAGS_report_frames, &outlined},
        {"report_pair", FLAGS_report_pair, &pair}}) {
    for (const std::string& item : dsr::SplitCommaList(text)) {
      char* end = nullptr;
      const long v = std::strtol(item.c_str(), &end, 10);
      if (end == item.c_str() || *end != '\0' || v < 0 || v >= m) {
        return Fail(std::string("--") + flag + "=" + text + ": '" + item +
                    "' is not a frame index in [0, " + std::to_string(m - 1) + "]");
      }
      list->push_back(static_cast<int>(v));
    }
  }
  if (outlined.empty()) outlined = m > 2 ? std::vector<int>{0, m / 2, m - 1} : std::vector<int>{0, 1};
  if (pair.size() != 2 || pair[0] == pair[1]) {
    return Fail("--report_pair=" + FLAGS_report_pair + ": must be two different frame indices 'a,b'");
  }
  if (!mask_paths.empty() && static_cast<int>(mask_paths.size()) != m) {
    return Fail("--masks: " + std::to_string(mask_paths.size()) + " masks for " +
                std::to_string(m) + " images");
  }
  std::set<std::string> unique_images;
  for (const std::string& p : image_paths) {
    if (!unique_images.insert(dsr::CanonicalPath(p)).second) {
      return Fail("--images: " + p + " is given twice");
    }
  }
  if (!FLAGS_out_panorama.empty() && !dsr::HasSupportedImageExtension(FLAGS_out_panorama)) {
    return Fail("--out_panorama=" + FLAGS_out_panorama +
                ": unsupported extension (.nii, .nii.gz, .mha, .mhd, .nrrd, .nhdr)");
  }
  // Every file this run reads and writes, before anything is read or created.
  dsr::OutputPlan plan;
  plan.AddFrameInputs(image_paths, mask_paths, FLAGS_images, FLAGS_masks);
  if (init_from_file) plan.AddInputFile("init", FLAGS_init);
  plan.AddInputFile("gt_poses", FLAGS_gt_poses);
  plan.AddOutputFile("out_poses", FLAGS_out_poses);
  plan.AddOutputImage("out_panorama", FLAGS_out_panorama);
  PlanFolderOutputs(m, pair, &plan);
  if (!plan.Check(&error)) return Fail(error);

  std::vector<dsr::Image> images;
  std::vector<dsr::Mask> masks;
  if (!dsr::ReadFrames(image_paths, mask_paths, FLAGS_mask_erosion, FLAGS_num_threads, &images,
                       &masks, &error)) {
    return Fail(error);
  }
  std::vector<Eigen::Isometry3d> initial(m, Eigen::Isometry3d::Identity());
  if (init_from_file) {
    dsr::PosesFile init;
    if (!dsr::ReadPoses(FLAGS_init, m, &init, &error)) return Fail("--init: " + error);
    if (!dsr::MatchPosesToImages("init", FLAGS_init, image_paths, &init, &error)) return Fail(error);
    initial = init.frame_from_world;
  }
  dsr::PosesFile gt;
  if (!FLAGS_gt_poses.empty() &&
      (!dsr::ReadPoses(FLAGS_gt_poses, m, &gt, &error) ||
       !dsr::MatchPosesToImages("gt_poses", FLAGS_gt_poses, image_paths, &gt, &error))) {
    return Fail(error.rfind("--gt_poses", 0) == 0 ? error : "--gt_poses: " + error);
  }
  const double load_seconds = SecondsSince(start);
  // The pipeline's own checks of the frames first (Register repeats them), so that a
  // broken header or pose is named as such, not as a panorama too large for memory.
  if (!dsr::CheckRegistrationInputs(images, initial, options, &error)) {
    return Fail(WithFrameFile(error, image_paths));
  }
  // Memory, before any work (the finest level's panorama voxels at --panorama_spacing): the
  // candidate set holds about 12 bytes for each panorama voxel of frame 0's field of view
  // (an index and the observer bits, for the voxels other frames overlap), and
  // --out_panorama a mean and a count for each voxel of the frames' bounding box.
  {
    const dsr::ImageGeometry& g0 = images[0].geometry;
    const double voxel_mm3 = g0.spacing_mm.prod() * std::pow(FLAGS_panorama_spacing, 3);
    double bytes = 12.0 * static_cast<double>(dsr::CountInside(masks[0])) * g0.spacing_mm.prod() /
                   voxel_mm3;
    if (!FLAGS_out_panorama.empty()) {
      Eigen::AlignedBox3d box;
      const std::vector<Eigen::Isometry3d> frame_from_world = dsr::RelativeToFrame0(initial);
      for (int i = 0; i < m; ++i) {
        const dsr::ImageGeometry& g = images[i].geometry;
        const Eigen::Isometry3d world_from_frame = frame_from_world[i].inverse();
        for (int c = 0; c < 8; ++c) {
          const Eigen::Vector3d corner((c & 1) ? g.size[0] - 1 : 0, (c & 2) ? g.size[1] - 1 : 0,
                                       (c & 4) ? g.size[2] - 1 : 0);
          box.extend(world_from_frame * g.IndexToPhysical(corner));
        }
      }
      bytes += 8.0 * box.volume() / voxel_mm3;
    }
    char spacing[32];
    std::snprintf(spacing, sizeof(spacing), "--panorama_spacing=%g", FLAGS_panorama_spacing);
    if (!dsr::CheckMemoryEstimate(spacing, bytes, "the panorama at the finest level", &error)) {
      return Fail(error);
    }
  }

  dsr::RegistrationResult result;
  if (!dsr::Register(images, masks, initial, options, &result, &error)) {
    return Fail(WithFrameFile(error, image_paths));
  }
  for (const dsr::RegistrationResult::Recovery& r : result.recoveries) {
    std::string frames;
    for (const dsr::FrameReplacement& f : r.frames) {
      char line[160];
      if (f.moved) {
        std::snprintf(line, sizeof(line), "%sframe %d re-placed (NCC %.3f -> %.3f, moved %.1f "
                      "deg, %.1f mm)", frames.empty() ? "" : "; ", f.frame, f.ncc_before,
                      f.ncc_after, f.rotation_change_deg, f.translation_change_mm);
      } else {
        std::snprintf(line, sizeof(line), "%sframe %d kept (NCC %.3f%s)",
                      frames.empty() ? "" : "; ", f.frame, f.ncc_before,
                      f.searched ? ", no better placement found" : ", as good as a re-placed frame");
      }
      frames += line;
    }
    if (r.global) frames += std::string(frames.empty() ? "" : "; ") + "every frame placed by the pair graph";
    if (r.misfit_accepted) {
      frames += std::string(frames.empty() ? "" : "; ") +
                "misfit of the kept frames accepted, the registration goes on";
    }
    std::printf("dsr_register: recovery after pyramid level %d (%.2f s): %s; because %s\n",
                r.after_level, r.seconds, frames.c_str(), r.why.c_str());
  }
  if (!result.usable) return Fail(result.failure, dsr::kExitFailed);

  // Note: the poses file is written last, so that a run whose panorama, transforms,
  // resampled frames or report could not be written leaves the previous poses file as it
  // was (exit 1, no new result).
  if (!plan.CreateFolders(&error)) return Fail(error, dsr::kExitFailed);
  const bool need_frames = !FLAGS_out_panorama.empty() || !FLAGS_out_resampled_dir.empty() ||
                          !FLAGS_report_dir.empty();
  std::vector<dsr::Frame> frames;
  dsr::Image panorama;
  double enlargement = 0.0;
  if (need_frames) {
    frames.resize(m);
    dsr::ParallelFor(0, m, options.solve.num_threads,
                     [&](int64_t i) { frames[i] = dsr::Frame(images[i], masks[i]); });
    // With photometric parameters, of the corrected intensities (result.photometric;
    // empty otherwise).
    const dsr::PanoramaImages fused =
        FLAGS_blend == "feather"
            ? dsr::FusePanoramaFeather(frames, result.frame_from_world, result.grid,
                                       FLAGS_feather_voxels, options.solve.num_threads,
                                       result.photometric)
            : dsr::FusePanoramaMean(frames, result.frame_from_world, result.grid,
                                    options.solve.num_threads, result.photometric);
    enlargement = fused.EnlargementRatio();
    panorama = options.mode == dsr::Mode::kDba && FLAGS_blend == "mean" ? result.dba_intensities : fused.mean;
  }
  if (!FLAGS_out_panorama.empty() && !dsr::WriteImage(panorama, FLAGS_out_panorama, &error)) {
    return Fail(error, dsr::kExitFailed);
  }
  const std::filesystem::path tfm_dir(FLAGS_out_tfm_dir), resampled_dir(FLAGS_out_resampled_dir);
  for (int i = 0; i < m; ++i) {
    char name[64];
    if (!FLAGS_out_tfm_dir.empty()) {
      std::snprintf(name, sizeof(name), "frame_%02d.tfm", i);
      if (!dsr::WriteItkTransform(result.frame_from_world[i], (tfm_dir / name).string(), &error)) {
        return Fail(error, dsr::kExitFailed);
      }
    }
    if (!FLAGS_out_resampled_dir.empty()) {
      std::snprintf(name, sizeof(name), "frame_%02d_in_panorama.nii.gz", i);
      const dsr::Image resampled = dsr::ResampleOntoGrid(frames[i], result.frame_from_world[i],
                                                         result.grid, options.solve.num_threads);
      if (!dsr::WriteImage(resampled, (resampled_dir / name).string(), &error)) {
        return Fail(error, dsr::kExitFailed);
      }
    }
  }
  dsr::PoseErrorSummary gt_errors;
  if (!FLAGS_gt_poses.empty()) {
    gt_errors = dsr::ComparePoses(result.frame_from_world, gt.frame_from_world, masks);
  }
  std::string report_index;
  if (!FLAGS_report_dir.empty()) {
    dsr::ReportInputs report;
    for (const std::string& p : image_paths) {
      report.image_names.push_back(std::filesystem::path(p).filename().string());
    }
    report.frames = frames;
    report.initial = result.init_frame_from_world.empty() ? dsr::RelativeToFrame0(initial)
                                                          : result.init_frame_from_world;
    report.result = &result;
    report.panorama = panorama;
    report.outlined = outlined;
    report.pair_a = pair[0];
    report.pair_b = pair[1];
    report.errors = FLAGS_gt_poses.empty() ? nullptr : &gt_errors;
    report.mode = dsr::ModeToString(options.mode);
    if (!dsr::WriteReport(FLAGS_report_dir, report, &report_index, &error)) {
      return Fail(error, dsr::kExitFailed);
    }
  }
  dsr::PosesFile out;
  out.frame_from_world = result.frame_from_world;
  for (const std::string& p : image_paths) {
    out.images.push_back(std::filesystem::path(p).filename().string());
  }
  const dsr::PoseUncertainty& uncertainty = result.uncertainty;
  if (!uncertainty.covariance.empty()) {
    out.covariance = uncertainty.covariance;
    out.predicted_tre_mm = uncertainty.predicted_tre_mm;
  }
  // The pipeline's gains and offsets are relative to frame 0, as the file's are.
  dsr::PhotometricToPoses(result.photometric, &out);
  if (!dsr::WritePoses(out, FLAGS_out_poses, &error)) return Fail(error, dsr::kExitFailed);

  const dsr::LevelSolve& last = result.solves.back();
  std::printf("dsr_register: %s, %d frames, %zu solves over %d pyramid levels, %d iterations, "
              "final cost %.6e (%" PRId64 " voxels, %" PRId64 " observations), %s\n",
              dsr::ModeToString(options.mode), m, result.solves.size(), result.solves.front().level + 1,
              result.total_iterations, last.report.final_cost, last.candidate_voxels,
              last.candidate_observations, last.report.termination.c_str());
  std::printf("dsr_register: time %.2f s (load %.2f s, pyramid %.2f s, solves %.2f s), peak "
              "memory %.0f MiB; wrote %s\n",
              SecondsSince(start), load_seconds, result.pyramid_seconds,
              result.seconds - result.pyramid_seconds,
              static_cast<double>(dsr::PeakResidentBytes()) / 1048576.0, FLAGS_out_poses.c_str());
  if (!result.photometric.empty()) {
    std::printf("dsr_register: %s\n",
                PhotometricSummary(result.photometric, FLAGS_gt_poses.empty() ? nullptr : &gt)
                    .c_str());
  }
  if (FLAGS_uncertainty) {
    std::printf("dsr_register: %s\n", dsr::UncertaintySummary(result.uncertainty, result.uncertainty_note).c_str());
  }
  if (need_frames) {
    std::printf("dsr_register: field-of-view enlargement %.2f (voxels seen by any frame / "
                "voxels in frame 0's field of view)\n", enlargement);
  }
  if (!FLAGS_gt_poses.empty()) {
    std::printf("errors against %s (frame-0-relative):\n%s", FLAGS_gt_poses.c_str(),
                gt_errors.Table().c_str());
  }
  if (!report_index.empty()) std::printf("dsr_register: report in %s\n", report_index.c_str());
  return EXIT_SUCCESS;
}

}  // namespace

int main(int argc, char** argv) { return dsr::RunToolMain(argc, argv, &Main); }
