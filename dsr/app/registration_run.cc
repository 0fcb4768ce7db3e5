// A registration run (dsr/app/registration_run.h).
#include "dsr/app/registration_run.h"

#include <algorithm>
#include <cinttypes>
#include <cstdarg>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <tuple>

#include "dsr/app/inputs.h"
#include "dsr/app/run_options.h"
#include "dsr/io/io_frames.h"
#include "dsr/io/io_image.h"
#include "dsr/io/io_phases.h"
#include "dsr/io/io_transform.h"
#include "dsr/model/panorama.h"
#include "dsr/pipeline/input_checks.h"
#include "dsr/pipeline/report.h"
#include "dsr/solve/solve_options.h"
#include "dsr/util/parallel.h"

namespace dsr {

namespace fs = std::filesystem;

RegistrationOutputs RegistrationOutputsFrom(const Settings& settings) {
  RegistrationOutputs out;
  out.poses = settings.String("out_poses");
  out.panorama = settings.String("out_panorama");
  out.tfm_dir = settings.String("out_tfm_dir");
  out.resampled_dir = settings.String("out_resampled_dir");
  out.report_dir = settings.String("report_dir");
  out.report_frames = settings.String("report_frames");
  out.report_pair = settings.String("report_pair");
  out.gt_poses = settings.String("gt_poses");
  return out;
}

std::string FrameTransformName(int frame) {
  char name[32];
  std::snprintf(name, sizeof(name), "frame_%02d.tfm", frame);
  return name;
}

std::string ResampledFrameName(int frame) {
  char name[48];
  std::snprintf(name, sizeof(name), "frame_%02d_in_panorama.nii.gz", frame);
  return name;
}

bool RegistrationRun::SetOptions(const Settings& settings, std::string* error) {
  config_ = ConfigFrom(settings);
  preset_summary_ = settings.PresetSummary();
  return RunOptionsFrom(settings, &options_, &init_file_, error);
}

bool RegistrationRun::PlanFiles(const Settings& settings, const RegistrationOutputs& outputs,
                                std::string* error) {
  if (!SetOptions(settings, error) ||
      !FrameFilesFrom(settings, 2, &image_paths_, &mask_paths_, error)) {
    return false;
  }
  outputs_ = outputs;
  names_.clear();
  for (const std::string& p : image_paths_) {
    names_.push_back(fs::path(ViewFiles(p).front()).filename().string());
  }
  if (!ParseReportFrames(error)) return false;
  plan_ = OutputPlan();
  plan_.AddFrameInputs(image_paths_, mask_paths_, settings.String("images"),
                       settings.String("masks"));
  if (!init_file_.empty()) plan_.AddInputFile("init", init_file_);
  plan_.AddInputFile("gt_poses", outputs_.gt_poses);
  plan_.AddOutputFile("out_poses", outputs_.poses);
  plan_.AddOutputImage("out_panorama", outputs_.panorama);
  PlanFolderOutputs(&plan_);
  return plan_.Check(error);
}

bool RegistrationRun::ParseReportFrames(std::string* error) {
  const int m = static_cast<int>(image_paths_.size());
  outlined_.clear();
  pair_.clear();
  for (const auto& [flag, text, list] :
       {std::tuple<const char*, std::string, std::vector<int>*>{
            "report_frames", outputs_.report_frames, &outlined_},
        {"report_pair", outputs_.report_pair, &pair_}}) {
    for (const std::string& item : SplitCommaList(text)) {
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
  if (outlined_.empty()) {
    outlined_ = m > 2 ? std::vector<int>{0, m / 2, m - 1} : std::vector<int>{0, 1};
  }
  if (pair_.size() != 2 || pair_[0] == pair_[1]) {
    *error = "--report_pair=" + outputs_.report_pair +
             ": must be two different frame indices 'a,b'";
    return false;
  }
  if (!outputs_.panorama.empty() && !HasSupportedImageExtension(outputs_.panorama)) {
    *error = "--out_panorama=" + outputs_.panorama +
             ": unsupported extension (.nii, .nii.gz, .mha, .mhd, .nrrd, .nhdr)";
    return false;
  }
  return true;
}

// The files written into --out_tfm_dir, --out_resampled_dir and --report_dir
// (pipeline/report.h, ReportFiles).
void RegistrationRun::PlanFolderOutputs(OutputPlan* plan) const {
  const int m = static_cast<int>(image_paths_.size());
  if (!outputs_.tfm_dir.empty()) {
    plan->AddOutputFolder("out_tfm_dir", outputs_.tfm_dir, outputs_.tfm_dir);
    for (int i = 0; i < m; ++i) {
      plan->AddDerivedFile("out_tfm_dir", outputs_.tfm_dir, FrameTransformName(i));
    }
  }
  if (!outputs_.resampled_dir.empty()) {
    plan->AddOutputFolder("out_resampled_dir", outputs_.resampled_dir, outputs_.resampled_dir);
    for (int i = 0; i < m; ++i) {
      plan->AddDerivedImage("out_resampled_dir", outputs_.resampled_dir, ResampledFrameName(i));
    }
  }
  if (!outputs_.report_dir.empty()) {
    const std::string& dir = outputs_.report_dir;
    plan->AddOutputFolder("report_dir", dir, dir);
    plan->AddOutputFolder("report_dir", dir, (fs::path(dir) / "transforms").string());
    for (const std::string& file : ReportFiles(m, pair_[0], pair_[1])) {
      plan->AddDerivedFile("report_dir", dir, file);
    }
  }
}

void RegistrationRun::RememberInputs(InputRegistry* registry) const {
  for (const std::string& view : image_paths_) {
    for (const std::string& path : ViewFiles(view)) registry->AddImage("images", path);
  }
  for (const std::string& path : mask_paths_) registry->AddImage("masks", path);
  registry->AddFile("init", init_file_);
  registry->AddFile("gt_poses", outputs_.gt_poses);
}

// Only the phases --phases selects are read (ReadViewPhases), so UsePhases has none left to
// drop.
bool RegistrationRun::ReadFiles(std::string* error) {
  return ReadViewPhases(config_.phases, image_paths_, mask_paths_, config_.field_of_view,
                        config_.num_threads, &images_, &masks_, &mask_rules_, &later_phases_,
                        error) &&
         UsePhases({}, error) && ReadPoseFiles(error);
}

// The selection `selected` (--phases; empty: the views' phases as they are) of the views'
// phases, and --report_phase among them; 3D views (one phase each) keep no later phases.
bool RegistrationRun::UsePhases(const std::vector<int>& selected, std::string* error) {
  const std::vector<std::string>& files = image_paths_.empty() ? names_ : image_paths_;
  if (!UseViewPhases(selected, files, &images_, &later_phases_, error)) return false;
  if (config_.report_phase >= num_phases()) {
    *error = "--report_phase=" + std::to_string(config_.report_phase) + ": only " +
             std::to_string(num_phases()) + " phase" + (num_phases() > 1 ? "s are" : " is") +
             " registered";
    return false;
  }
  return true;
}

int RegistrationRun::num_phases() const {
  return later_phases_.empty() ? 1 : 1 + static_cast<int>(later_phases_[0].size());
}

// --init's poses file and --gt_poses, matched to the frames by name.
bool RegistrationRun::ReadPoseFiles(std::string* error) {
  const int m = static_cast<int>(images_.size());
  const std::vector<std::string>& match = image_paths_.empty() ? names_ : image_paths_;
  start_.assign(m, Eigen::Isometry3d::Identity());
  if (!init_file_.empty()) {
    PosesFile init;
    if (!ReadPoses(init_file_, m, &init, error)) {
      *error = "--init: " + *error;
      return false;
    }
    if (!MatchPosesToImages("init", init_file_, match, &init, error)) return false;
    start_ = init.frame_from_world;
  }
  if (!outputs_.gt_poses.empty() &&
      (!ReadPoses(outputs_.gt_poses, m, &ground_truth_, error) ||
       !MatchPosesToImages("gt_poses", outputs_.gt_poses, match, &ground_truth_, error))) {
    if (error->rfind("--gt_poses", 0) != 0) *error = "--gt_poses: " + *error;
    return false;
  }
  return true;
}

bool RegistrationRun::SetFrames(const Settings& settings, std::vector<Image> images,
                                std::vector<Mask> masks, std::vector<MaskRule> mask_rules,
                                std::vector<std::string> names,
                                std::vector<Eigen::Isometry3d> start, std::string* error,
                                std::vector<std::vector<Image>> later_phases) {
  if (!SetOptions(settings, error)) return false;
  images_ = std::move(images);
  later_phases_ = std::move(later_phases);
  masks_ = std::move(masks);
  mask_rules_ = std::move(mask_rules);
  names_ = std::move(names);
  image_paths_.clear();
  if (!UsePhases(config_.phases, error)) return false;
  if (!start.empty()) {
    start_ = std::move(start);
    return true;
  }
  return ReadPoseFiles(error);
}

bool RegistrationRun::Check(std::string* error) {
  // The pipeline's own checks of the frames' headers and poses first (Register repeats
  // them), so that a broken header or pose is named as such, not as a panorama too large
  // for memory. Their voxels are Register's to scan (once; its errors name the file too).
  if (!CheckRegistrationGeometry(images_, start_, options_, error)) {
    *error = WithFrameFile(*error, image_paths_);
    return false;
  }
  return CheckPanoramaMemory(error);
}

// Memory, before any work (the finest level's panorama voxels at --panorama_spacing): the
// candidate set holds about 12 bytes for each panorama voxel of frame 0's field of view
// (an index and the observer bits, for the voxels other frames overlap), and
// --out_panorama a mean per phase and a count for each voxel of the frames' bounding box.
bool RegistrationRun::CheckPanoramaMemory(std::string* error) const {
  const ImageGeometry& g0 = images_[0].geometry;
  const double voxel_mm3 = g0.spacing_mm.prod() * std::pow(config_.panorama_spacing, 3);
  double bytes =
      12.0 * static_cast<double>(CountInside(masks_[0])) * g0.spacing_mm.prod() / voxel_mm3;
  if (!outputs_.panorama.empty()) {
    Eigen::AlignedBox3d box;
    const std::vector<Eigen::Isometry3d> frame_from_world = RelativeToFrame0(start_);
    for (size_t i = 0; i < images_.size(); ++i) {
      const ImageGeometry& g = images_[i].geometry;
      const Eigen::Isometry3d world_from_frame = frame_from_world[i].inverse();
      for (int c = 0; c < 8; ++c) {
        const Eigen::Vector3d corner((c & 1) ? g.size[0] - 1 : 0, (c & 2) ? g.size[1] - 1 : 0,
                                     (c & 4) ? g.size[2] - 1 : 0);
        box.extend(world_from_frame * g.IndexToPhysical(corner));
      }
    }
    // Each phase's mean kept for writing, and the fusion's own count and weights.
    bytes += (4.0 * num_phases() + 4.0) * box.volume() / voxel_mm3;
  }
  char spacing[48];
  std::snprintf(spacing, sizeof(spacing), "--panorama_spacing=%g", config_.panorama_spacing);
  return CheckMemoryEstimate(spacing, bytes, "the panorama at the finest level", error);
}

bool RegistrationRun::Run(std::string* error) {
  if (Register(images_, later_phases_, masks_, start_, options_, &result_, error)) return true;
  *error = WithFrameFile(*error, image_paths_);
  return false;
}

bool RegistrationRun::Write(std::string* error) {
  const int m = static_cast<int>(images_.size());
  if (!plan_.CreateFolders(error)) return false;
  fused_ = !outputs_.panorama.empty() || !outputs_.resampled_dir.empty() ||
           !outputs_.report_dir.empty();
  std::vector<Frame> frames;
  std::vector<Image> panorama;  // one per phase
  if (fused_) {
    frames.resize(m);
    ParallelFor(0, m, options_.solve.num_threads, [&](int64_t i) {
      // The masks the registration used: a dropout is left out of the panorama too.
      const Mask& mask = result_.masks_used.empty() ? masks_[i] : result_.masks_used[i];
      frames[i] = Frame::Borrowing(images_[i], LaterPhasesOf(&later_phases_, i), mask);
    });
    panorama = FusedPanorama(frames);
  }
  // One phase: a 3D image, as WriteImage writes it; more: a 4D image (io/io_phases.h).
  if (!outputs_.panorama.empty() && !WritePhases(panorama, outputs_.panorama, error)) {
    return false;
  }
  if (!WriteFrameFiles(frames, error)) return false;
  if (!outputs_.gt_poses.empty()) {
    gt_errors_ = ComparePoses(result_.frame_from_world, ground_truth_.frame_from_world, masks_);
  }
  if (!outputs_.report_dir.empty() &&
      !WriteReport(PhaseFrames(frames, config_.report_phase), panorama[config_.report_phase],
                   error)) {
    return false;
  }
  return outputs_.poses.empty() || WritePoses(ResultPoses(result_, names_), outputs_.poses, error);
}

// Every phase's panorama of the views `frames` at the result's poses (with photometric
// parameters, of the corrected intensities): the fused mean, or with mode dba DBA's own
// intensities (unless feathered).
std::vector<Image> RegistrationRun::FusedPanorama(const std::vector<Frame>& frames) {
  std::vector<Image> panorama;
  for (int p = 0; p < NumPhases(frames); ++p) {
    const PanoramaImages fused = FusePanorama(
        PhaseFrames(frames, p), result_.frame_from_world, result_.grid, config_.feather,
        config_.feather_voxels, options_.solve.num_threads, result_.photometric);
    if (p == 0) enlargement_ = fused.EnlargementRatio();
    const bool dba = options_.mode == Mode::kDba && !config_.feather;
    panorama.push_back(!dba ? fused.mean
                       : p == 0 ? result_.dba_intensities
                                : result_.dba_later_phases.at(p - 1));
  }
  return panorama;
}

// Each frame's transform and resampled image (every phase).
bool RegistrationRun::WriteFrameFiles(const std::vector<Frame>& frames, std::string* error) const {
  for (size_t i = 0; i < images_.size(); ++i) {
    const int f = static_cast<int>(i);
    if (!outputs_.tfm_dir.empty() &&
        !WriteItkTransform(result_.frame_from_world[i],
                           (fs::path(outputs_.tfm_dir) / FrameTransformName(f)).string(), error)) {
      return false;
    }
    if (!outputs_.resampled_dir.empty()) {
      std::vector<Image> resampled;
      for (int p = 0; p < frames[i].num_phases(); ++p) {
        resampled.push_back(ResampleOntoGrid(frames[i].Phase(p), result_.frame_from_world[i],
                                             result_.grid, options_.solve.num_threads));
      }
      const fs::path path = fs::path(outputs_.resampled_dir) / ResampledFrameName(f);
      if (!WritePhases(resampled, path.string(), error)) return false;
    }
  }
  return true;
}

bool RegistrationRun::WriteReport(const std::vector<Frame>& frames, const Image& panorama,
                                  std::string* error) {
  ReportInputs report;
  report.image_names = names_;
  report.frames = frames;
  report.initial = result_.init_frame_from_world.empty() ? RelativeToFrame0(start_)
                                                         : result_.init_frame_from_world;
  report.result = &result_;
  report.panorama = panorama;
  report.outlined = outlined_;
  report.pair_a = pair_[0];
  report.pair_b = pair_[1];
  report.errors = outputs_.gt_poses.empty() ? nullptr : &gt_errors_;
  report.mode = ModeToString(options_.mode);
  return dsr::WriteReport(outputs_.report_dir, report, &report_index_, error);
}

std::vector<std::string> RegistrationRun::RecoveryLines() const {
  std::vector<std::string> lines;
  for (const RegistrationResult::Recovery& r : result_.recoveries) {
    std::string frames;
    for (const FrameReplacement& f : r.frames) {
      char line[160];
      if (f.moved) {
        std::snprintf(line, sizeof(line), "%sframe %d re-placed (NCC %.3f -> %.3f, moved %.1f "
                      "deg, %.1f mm)", frames.empty() ? "" : "; ", f.frame, f.ncc_before,
                      f.ncc_after, f.rotation_change_deg, f.translation_change_mm);
      } else {
        std::snprintf(line, sizeof(line), "%sframe %d kept (NCC %.3f%s)",
                      frames.empty() ? "" : "; ", f.frame, f.ncc_before,
                      f.searched ? ", no better placement found"
                                 : ", as good as a re-placed frame");
      }
      frames += line;
    }
    if (r.global) {
      frames += std::string(frames.empty() ? "" : "; ") + "every frame placed by the pair graph";
    }
    if (r.misfit_accepted) {
      frames += std::string(frames.empty() ? "" : "; ") +
                "misfit of the kept frames accepted, the registration goes on";
    }
    char head[64];
    std::snprintf(head, sizeof(head), "recovery after pyramid level %d (%.2f s): ", r.after_level,
                  r.seconds);
    lines.push_back(head + frames + "; because " + r.why);
  }
  return lines;
}

std::string RegistrationRun::FieldOfViewLine() const {
  return FieldOfViewSummary(mask_rules_, config_.field_of_view.mask_rule) +
         DropoutSummary(result_.dropout_fraction);
}

// Each frame's estimated gain and offset and, when the ground truth has them (on frame
// 0's scale, as MatchPosesToImages leaves them), the mean absolute errors over frames
// 1..m-1.
std::string RegistrationRun::PhotometricLine() const {
  const std::vector<Photometric>& photometric = result_.photometric;
  std::string line = "photometric (gain, offset) per frame:";
  char item[96];
  for (size_t i = 0; i < photometric.size(); ++i) {
    std::snprintf(item, sizeof(item), "%s %zu (%.4f, %.3f)", i == 0 ? "" : ";", i,
                  photometric[i].gain(), photometric[i].offset);
    line += item;
  }
  const size_t m = photometric.size();
  const std::vector<Photometric> truth = outputs_.gt_poses.empty()
                                             ? std::vector<Photometric>()
                                             : PhotometricFromPoses(ground_truth_);
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

namespace {

std::string Format(const char* format, ...) __attribute__((format(printf, 1, 2)));
std::string Format(const char* format, ...) {
  char text[512];
  va_list args;
  va_start(args, format);
  std::vsnprintf(text, sizeof(text), format, args);
  va_end(args);
  return text;
}

}  // namespace

std::vector<std::string> RegistrationRun::SummaryLines(double seconds, double load_seconds) const {
  const RegistrationResult& r = result_;
  const LevelSolve& last = r.solves.back();
  std::vector<std::string> lines = {
      Format("%s, %zu frames%s, %zu solves over %d pyramid levels, %d iterations, final cost "
             "%.6e (%" PRId64 " voxels, %" PRId64 " observations), %s",
             ModeToString(options_.mode), r.frame_from_world.size(),
             num_phases() > 1 ? Format(" x %d phases", num_phases()).c_str() : "",
             r.solves.size(),
             r.solves.front().level + 1, r.total_iterations, last.report.final_cost,
             last.candidate_voxels, last.candidate_observations, last.report.termination.c_str()),
      FieldOfViewLine(),
      Format("time %.2f s (load %.2f s, pyramid %.2f s, solves %.2f s, checks %.2f s), peak "
             "memory %.0f MiB; wrote %s", seconds, load_seconds, r.pyramid_seconds,
             r.seconds - r.pyramid_seconds - r.check_seconds.total(), r.check_seconds.total(),
             static_cast<double>(PeakResidentBytes()) / 1048576.0, outputs_.poses.c_str())};
  const CheckSeconds& c = r.check_seconds;
  lines.push_back(Format("checks %.2f s: structure %.2f s, determination %.2f s, brightness %.2f "
                         "s, uncertainty %.2f s, other %.2f s", c.total(), c.structure,
                         c.determination, c.brightness, c.uncertainty, c.other));
  if (r.intensity_transform != IntensityTransform::kNone) {
    lines.push_back(Format("registered %s(c I), c = %g (--intensity_transform): the cost above "
                           "is on that scale; gains, offsets and images are on the input's grey "
                           "levels", IntensityTransformToString(r.intensity_transform),
                           r.intensity_transform_scale));
  }
  const std::string structure = StructureSummary(r.frame_structure);
  if (!structure.empty()) lines.push_back(structure);
  if (!r.pose_error_voxels.empty()) {
    const auto worst = std::max_element(r.pose_error_voxels.begin(), r.pose_error_voxels.end());
    lines.push_back(Format("determination check (docs/design.md 8.7): the image noise puts at "
                           "most about %.2g voxels of error on a pose (frame %d)", *worst,
                           static_cast<int>(worst - r.pose_error_voxels.begin())));
  }
  if (!preset_summary_.empty()) lines.push_back(preset_summary_);
  if (!r.photometric_choice.empty()) {
    lines.push_back("photometric model " + FieldPathsAsOptions(r.photometric_choice, front_end_));
  }
  if (!r.photometric.empty()) lines.push_back(PhotometricLine());
  if (options_.uncertainty) {
    lines.push_back(
        FieldPathsAsOptions(UncertaintySummary(r.uncertainty, r.uncertainty_note), front_end_));
  }
  if (fused_) {
    lines.push_back(Format("field-of-view enlargement %.2f (voxels seen by any frame / voxels "
                           "in frame 0's field of view)", enlargement_));
  }
  return lines;
}

}  // namespace dsr
