// dsr_register: registers several 3D images simultaneously (pipeline/registration.h) and
// writes the poses (docs/design.md section 1), optionally the panorama, and, with
// --gt_poses, prints per-frame errors against ground truth (eval/eval.h).
#include <chrono>
#include <cinttypes>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <tuple>

#include <gflags/gflags.h>
#include <glog/logging.h>

#include "dsr/eval/eval.h"
#include "dsr/io/io_frames.h"
#include "dsr/io/io_image.h"
#include "dsr/io/io_poses.h"
#include "dsr/io/io_transform.h"
#include "dsr/model/panorama.h"
#include "dsr/pipeline/input_checks.h"
#include "dsr/pipeline/registration.h"
#include "dsr/pipeline/report.h"
#include "dsr/solve/solve_options.h"
#include "dsr/tools/flags.h"
#include "dsr/app/output_plan.h"
#include "dsr/tools/tool_util.h"
#include "dsr/util/clock.h"
#include "dsr/util/parallel.h"



namespace {

using dsr::Fail;

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

// The files written into --out_tfm_dir, --out_resampled_dir and --report_dir
// (pipeline/report.h, ReportFiles).
void PlanFolderOutputs(int m, const std::vector<int>& pair, dsr::OutputPlan* plan) {
  char name[64];
  if (!dsr::StringFlag("out_tfm_dir").empty()) {
    plan->AddOutputFolder("out_tfm_dir", dsr::StringFlag("out_tfm_dir"), dsr::StringFlag("out_tfm_dir"));
    for (int i = 0; i < m; ++i) {
      std::snprintf(name, sizeof(name), "frame_%02d.tfm", i);
      plan->AddDerivedFile("out_tfm_dir", dsr::StringFlag("out_tfm_dir"), name);
    }
  }
  if (!dsr::StringFlag("out_resampled_dir").empty()) {
    plan->AddOutputFolder("out_resampled_dir", dsr::StringFlag("out_resampled_dir"), dsr::StringFlag("out_resampled_dir"));
    for (int i = 0; i < m; ++i) {
      std::snprintf(name, sizeof(name), "frame_%02d_in_panorama.nii.gz", i);
      plan->AddDerivedImage("out_resampled_dir", dsr::StringFlag("out_resampled_dir"), name);
    }
  }
  if (!dsr::StringFlag("report_dir").empty()) {
    const std::string& dir = dsr::StringFlag("report_dir");
    plan->AddOutputFolder("report_dir", dir, dir);
    plan->AddOutputFolder("report_dir", dir, (std::filesystem::path(dir) / "transforms").string());
    for (const std::string& file : dsr::ReportFiles(m, pair[0], pair[1])) {
      plan->AddDerivedFile("report_dir", dir, file);
    }
  }
}

// The files named by --images and --masks and the report's frames, checked before any file
// is read.
struct Inputs {
  std::vector<std::string> image_paths, mask_paths;
  std::vector<int> outlined, pair;  // --report_frames, --report_pair: indices into --images
};

bool ParseInputs(Inputs* in, std::string* error) {
  if (!dsr::FrameFilesFrom(dsr::ToolSettings(), 2, &in->image_paths, &in->mask_paths, error)) return false;
  const int m = static_cast<int>(in->image_paths.size());
  for (const auto& [flag, text, list] :
       {std::tuple<const char*, std::string, std::vector<int>*>{"report_frames", dsr::StringFlag("report_frames"), &in->outlined},
        {"report_pair", dsr::StringFlag("report_pair"), &in->pair}}) {
    for (const std::string& item : dsr::SplitCommaList(text)) {
      char* end = nullptr;
      const long v = std::strtol(item.c_str(), &end, 10);
      if (end == item.c_str() || *end != '\0' || v < 0 || v >= m) {
        *error = std::string("--") + flag + "=" + text + ": '" + item +
                 "' is not a frame index in [0, " + std::to_string(m - 1) + "]";
        return false;
      }
      list->push_back(static_cast<int>(v));
    }
  }
  if (in->outlined.empty()) {
    in->outlined = m > 2 ? std::vector<int>{0, m / 2, m - 1} : std::vector<int>{0, 1};
  }
  if (in->pair.size() != 2 || in->pair[0] == in->pair[1]) {
    *error = "--report_pair=" + dsr::StringFlag("report_pair") + ": must be two different frame indices 'a,b'";
    return false;
  }
  if (!dsr::StringFlag("out_panorama").empty() && !dsr::HasSupportedImageExtension(dsr::StringFlag("out_panorama"))) {
    *error = "--out_panorama=" + dsr::StringFlag("out_panorama") +
             ": unsupported extension (.nii, .nii.gz, .mha, .mhd, .nrrd, .nhdr)";
    return false;
  }
  return true;
}

// Every file this run reads and writes, checked before anything is read or created.
bool PlanFiles(const Inputs& in, const std::string& init_file, dsr::OutputPlan* plan,
               std::string* error) {
  plan->AddFrameInputs(in.image_paths, in.mask_paths, dsr::StringFlag("images"), dsr::StringFlag("masks"));
  if (!init_file.empty()) plan->AddInputFile("init", init_file);
  plan->AddInputFile("gt_poses", dsr::StringFlag("gt_poses"));
  plan->AddOutputFile("out_poses", dsr::StringFlag("out_poses"));
  plan->AddOutputImage("out_panorama", dsr::StringFlag("out_panorama"));
  PlanFolderOutputs(static_cast<int>(in.image_paths.size()), in.pair, plan);
  return plan->Check(error);
}

// --init's poses file and --gt_poses, matched to --images.
bool ReadPoseFiles(const Inputs& in, const std::string& init_file,
                   std::vector<Eigen::Isometry3d>* initial, dsr::PosesFile* gt,
                   std::string* error) {
  const int m = static_cast<int>(in.image_paths.size());
  initial->assign(m, Eigen::Isometry3d::Identity());
  if (!init_file.empty()) {
    dsr::PosesFile init;
    if (!dsr::ReadPoses(init_file, m, &init, error)) {
      *error = "--init: " + *error;
      return false;
    }
    if (!dsr::MatchPosesToImages("init", init_file, in.image_paths, &init, error)) return false;
    *initial = init.frame_from_world;
  }
  if (!dsr::StringFlag("gt_poses").empty() &&
      (!dsr::ReadPoses(dsr::StringFlag("gt_poses"), m, gt, error) ||
       !dsr::MatchPosesToImages("gt_poses", dsr::StringFlag("gt_poses"), in.image_paths, gt, error))) {
    if (error->rfind("--gt_poses", 0) != 0) *error = "--gt_poses: " + *error;
    return false;
  }
  return true;
}

// Memory, before any work (the finest level's panorama voxels at --panorama_spacing): the
// candidate set holds about 12 bytes for each panorama voxel of frame 0's field of view
// (an index and the observer bits, for the voxels other frames overlap), and
// --out_panorama a mean and a count for each voxel of the frames' bounding box.
bool CheckPanoramaMemory(const std::vector<dsr::Image>& images, const std::vector<dsr::Mask>& masks,
                         const std::vector<Eigen::Isometry3d>& initial, std::string* error) {
  const dsr::ImageGeometry& g0 = images[0].geometry;
  const double voxel_mm3 = g0.spacing_mm.prod() * std::pow(dsr::DoubleFlag("panorama_spacing"), 3);
  double bytes =
      12.0 * static_cast<double>(dsr::CountInside(masks[0])) * g0.spacing_mm.prod() / voxel_mm3;
  if (!dsr::StringFlag("out_panorama").empty()) {
    Eigen::AlignedBox3d box;
    const std::vector<Eigen::Isometry3d> frame_from_world = dsr::RelativeToFrame0(initial);
    for (size_t i = 0; i < images.size(); ++i) {
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
  std::snprintf(spacing, sizeof(spacing), "--panorama_spacing=%g", dsr::DoubleFlag("panorama_spacing"));
  return dsr::CheckMemoryEstimate(spacing, bytes, "the panorama at the finest level", error);
}

// One line per recovery: the frames re-placed or kept, and why.
void PrintRecoveries(const dsr::RegistrationResult& result) {
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
}

// What the outputs tell the summary.
struct Written {
  bool fused = false;  // the panorama was fused (for --out_panorama, the resampled frames or the report)
  double enlargement = 0.0;
  std::string report_index;
  dsr::PoseErrorSummary gt_errors;
};

// The outputs (each written atomically), the poses file last: a run whose panorama,
// transforms, resampled frames or report could not be written leaves the previous poses
// file as it was (exit 1, no new result).
bool WriteOutputs(const Inputs& in, const std::vector<dsr::Image>& images,
                  const std::vector<dsr::Mask>& masks, const std::vector<Eigen::Isometry3d>& initial,
                  const dsr::PosesFile& gt, const dsr::RegistrationOptions& options,
                  const dsr::RegistrationResult& result, const dsr::OutputPlan& plan,
                  Written* written, std::string* error) {
  const int m = static_cast<int>(images.size());
  if (!plan.CreateFolders(error)) return false;
  written->fused = !dsr::StringFlag("out_panorama").empty() || !dsr::StringFlag("out_resampled_dir").empty() ||
                   !dsr::StringFlag("report_dir").empty();
  std::vector<dsr::Frame> frames;
  dsr::Image panorama;
  if (written->fused) {
    frames.resize(m);
    dsr::ParallelFor(0, m, options.solve.num_threads,
                     [&](int64_t i) { frames[i] = dsr::Frame(images[i], masks[i]); });
    // With photometric parameters, of the corrected intensities (result.photometric;
    // empty otherwise).
    const dsr::PanoramaImages fused =
        dsr::FusePanorama(frames, result.frame_from_world, result.grid, dsr::ToolConfig().feather,
                          dsr::DoubleFlag("feather_voxels"), options.solve.num_threads, result.photometric);
    written->enlargement = fused.EnlargementRatio();
    panorama = options.mode == dsr::Mode::kDba && !dsr::ToolConfig().feather ? result.dba_intensities
                                                                       : fused.mean;
  }
  if (!dsr::StringFlag("out_panorama").empty() && !dsr::WriteImage(panorama, dsr::StringFlag("out_panorama"), error)) {
    return false;
  }
  const std::filesystem::path tfm_dir(dsr::StringFlag("out_tfm_dir")), resampled_dir(dsr::StringFlag("out_resampled_dir"));
  for (int i = 0; i < m; ++i) {
    char name[64];
    if (!dsr::StringFlag("out_tfm_dir").empty()) {
      std::snprintf(name, sizeof(name), "frame_%02d.tfm", i);
      if (!dsr::WriteItkTransform(result.frame_from_world[i], (tfm_dir / name).string(), error)) {
        return false;
      }
    }
    if (!dsr::StringFlag("out_resampled_dir").empty()) {
      std::snprintf(name, sizeof(name), "frame_%02d_in_panorama.nii.gz", i);
      const dsr::Image resampled = dsr::ResampleOntoGrid(frames[i], result.frame_from_world[i],
                                                         result.grid, options.solve.num_threads);
      if (!dsr::WriteImage(resampled, (resampled_dir / name).string(), error)) return false;
    }
  }
  if (!dsr::StringFlag("gt_poses").empty()) {
    written->gt_errors = dsr::ComparePoses(result.frame_from_world, gt.frame_from_world, masks);
  }
  std::vector<std::string> image_names;
  for (const std::string& p : in.image_paths) {
    image_names.push_back(std::filesystem::path(p).filename().string());
  }
  if (!dsr::StringFlag("report_dir").empty()) {
    dsr::ReportInputs report;
    report.image_names = image_names;
    report.frames = frames;
    report.initial = result.init_frame_from_world.empty() ? dsr::RelativeToFrame0(initial)
                                                          : result.init_frame_from_world;
    report.result = &result;
    report.panorama = panorama;
    report.outlined = in.outlined;
    report.pair_a = in.pair[0];
    report.pair_b = in.pair[1];
    report.errors = dsr::StringFlag("gt_poses").empty() ? nullptr : &written->gt_errors;
    report.mode = dsr::ModeToString(options.mode);
    if (!dsr::WriteReport(dsr::StringFlag("report_dir"), report, &written->report_index, error)) return false;
  }
  return dsr::WritePoses(dsr::ResultPoses(result, image_names), dsr::StringFlag("out_poses"), error);
}

void PrintSummary(const dsr::RegistrationOptions& options, const dsr::RegistrationResult& result,
                  const std::vector<dsr::MaskRule>& mask_rules, const dsr::PosesFile& gt,
                  const Written& written, double seconds, double load_seconds) {
  const dsr::LevelSolve& last = result.solves.back();
  std::printf("dsr_register: %s, %zu frames, %zu solves over %d pyramid levels, %d iterations, "
              "final cost %.6e (%" PRId64 " voxels, %" PRId64 " observations), %s\n",
              dsr::ModeToString(options.mode), result.frame_from_world.size(),
              result.solves.size(), result.solves.front().level + 1, result.total_iterations,
              last.report.final_cost, last.candidate_voxels, last.candidate_observations,
              last.report.termination.c_str());
  std::printf("dsr_register: %s\n",
              dsr::FieldOfViewSummary(mask_rules, dsr::ToolConfig().field_of_view.mask_rule).c_str());
  std::printf("dsr_register: time %.2f s (load %.2f s, pyramid %.2f s, solves %.2f s), peak "
              "memory %.0f MiB; wrote %s\n",
              seconds, load_seconds, result.pyramid_seconds,
              result.seconds - result.pyramid_seconds,
              static_cast<double>(dsr::PeakResidentBytes()) / 1048576.0, dsr::StringFlag("out_poses").c_str());
  if (result.intensity_transform != dsr::IntensityTransform::kNone) {
    std::printf("dsr_register: registered %s(c I), c = %g (--intensity_transform): the cost "
                "above is on that scale; gains, offsets and images are on the input's grey "
                "levels\n",
                dsr::IntensityTransformToString(result.intensity_transform),
                result.intensity_transform_scale);
  }
  if (!dsr::StructureSummary(result.frame_structure).empty()) {
    std::printf("dsr_register: %s\n", dsr::StructureSummary(result.frame_structure).c_str());
  }
  if (!result.pose_error_voxels.empty()) {
    const auto worst =
        std::max_element(result.pose_error_voxels.begin(), result.pose_error_voxels.end());
    std::printf("dsr_register: determination check (docs/design.md 8.7): the image noise puts "
                "at most about %.2g voxels of error on a pose (frame %d)\n",
                *worst, static_cast<int>(worst - result.pose_error_voxels.begin()));
  }
  if (!dsr::ToolSettings().PresetSummary().empty()) {
    std::printf("dsr_register: %s\n", dsr::ToolSettings().PresetSummary().c_str());
  }
  if (!result.photometric_choice.empty()) {
    std::printf("dsr_register: photometric model %s\n",
                dsr::FieldPathsAsFlags(result.photometric_choice).c_str());
  }
  if (!result.photometric.empty()) {
    std::printf("dsr_register: %s\n",
                PhotometricSummary(result.photometric, dsr::StringFlag("gt_poses").empty() ? nullptr : &gt)
                    .c_str());
  }
  if (dsr::BoolFlag("uncertainty")) {
    std::printf("dsr_register: %s\n",
                dsr::FieldPathsAsFlags(
                    dsr::UncertaintySummary(result.uncertainty, result.uncertainty_note))
                    .c_str());
  }
  if (written.fused) {
    std::printf("dsr_register: field-of-view enlargement %.2f (voxels seen by any frame / "
                "voxels in frame 0's field of view)\n", written.enlargement);
  }
  if (!dsr::StringFlag("gt_poses").empty()) {
    std::printf("errors against %s (frame-0-relative):\n%s", dsr::StringFlag("gt_poses").c_str(),
                written.gt_errors.Table().c_str());
  }
  if (!written.report_index.empty()) {
    std::printf("dsr_register: report in %s\n", written.report_index.c_str());
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
      dsr::kDsrRegister, {"images", "out_poses"}, &argc, &argv);
  const auto start = std::chrono::steady_clock::now();
  std::string error, init_file;
  // Options first, so that flag errors come before any file is read.
  dsr::RegistrationOptions options;
  if (!dsr::RunOptionsFrom(dsr::ToolSettings(), &options, &init_file, &error)) return Fail(error);
  Inputs in;
  dsr::OutputPlan plan;
  if (!ParseInputs(&in, &error) || !PlanFiles(in, init_file, &plan, &error)) return Fail(error);
  std::vector<dsr::Image> images;
  std::vector<dsr::Mask> masks;
  std::vector<Eigen::Isometry3d> initial;
  dsr::PosesFile gt;
  std::vector<dsr::MaskRule> mask_rules;
  if (!dsr::ReadFrames(in.image_paths, in.mask_paths, dsr::ToolConfig().field_of_view,
                       dsr::IntFlag("num_threads"), &images, &masks, &mask_rules, &error) ||
      !ReadPoseFiles(in, init_file, &initial, &gt, &error)) {
    return Fail(error);
  }
  const double load_seconds = dsr::SecondsSince(start);
  // The pipeline's own checks of the frames first (Register repeats them), so that a
  // broken header or pose is named as such, not as a panorama too large for memory.
  if (!dsr::CheckRegistrationInputs(images, initial, options, &error)) {
    return Fail(dsr::WithFrameFile(error, in.image_paths));
  }
  if (!CheckPanoramaMemory(images, masks, initial, &error)) return Fail(error);
  dsr::RegistrationResult result;
  if (!dsr::Register(images, masks, initial, options, &result, &error)) {
    return Fail(dsr::WithFrameFile(error, in.image_paths));
  }
  PrintRecoveries(result);
  if (!result.usable) return Fail(result.failure, dsr::kExitFailed);
  Written written;
  if (!WriteOutputs(in, images, masks, initial, gt, options, result, plan, &written, &error)) {
    return Fail(error, dsr::kExitFailed);
  }
  PrintSummary(options, result, mask_rules, gt, written, dsr::SecondsSince(start), load_seconds);
  return EXIT_SUCCESS;
}

}  // namespace

int main(int argc, char** argv) { return dsr::RunToolMain(argc, argv, &Main); }
