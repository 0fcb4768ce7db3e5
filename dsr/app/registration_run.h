// A registration run as every front end makes it (dsr_register, dsr.register): the options,
// the files it reads and writes checked before anything is read, the frames (files, or
// images in memory), the checks before any work (the pipeline's input checks, memory), the
// registration, the outputs (each written atomically, the poses file last) and the summary.
// A front end keeps its arguments and its conversions; everything else is here.
//
//   RegistrationRun run(kDsrRegister);
//   if (!run.PlanFiles(settings, RegistrationOutputsFrom(settings), &error) ||
//       !run.ReadFiles(&error) || !run.Check(&error) || !run.Run(&error)) ...   // bad input
//   if (!run.result().usable) ...                                                // failed
//   if (!run.Write(&error)) ...                                                  // failed
#ifndef DSR_APP_REGISTRATION_RUN_H_
#define DSR_APP_REGISTRATION_RUN_H_

#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "dsr/app/options.h"
#include "dsr/app/output_plan.h"
#include "dsr/app/run_options.h"
#include "dsr/eval/eval.h"
#include "dsr/geometry/field_of_view.h"
#include "dsr/io/io_poses.h"
#include "dsr/pipeline/registration.h"

namespace dsr {

// Where a registration's results go (dsr_register's output options), and the ground truth
// its summary measures against.
struct RegistrationOutputs {
  std::string poses;          // --out_poses
  std::string panorama;       // --out_panorama
  std::string tfm_dir;        // --out_tfm_dir: FrameTransformName(i) per frame
  std::string resampled_dir;  // --out_resampled_dir: ResampledFrameName(i) per frame
  std::string report_dir;     // --report_dir
  std::string report_frames;  // --report_frames: "" = 0, the middle and the last frame
  std::string report_pair = "0,1";
  std::string gt_poses;       // --gt_poses (an input)
};
RegistrationOutputs RegistrationOutputsFrom(const Settings& settings);

// The files written per frame into --out_tfm_dir and --out_resampled_dir.
std::string FrameTransformName(int frame);  // "frame_03.tfm"
std::string ResampledFrameName(int frame);  // "frame_03_in_panorama.nii.gz"

class RegistrationRun {
 public:
  // `front_end`: whose option names the messages use (FieldPathsAsOptions).
  explicit RegistrationRun(uint32_t front_end) : front_end_(front_end) {}

  // The run's options (RunOptionsFrom), the files of --images and --masks, the report's
  // frames, and every file the run reads and writes, checked (OutputPlan::Check) before
  // anything is read. False with a one-line `error` (bad input).
  bool PlanFiles(const Settings& settings, const RegistrationOutputs& outputs,
                 std::string* error);
  // Reads the planned frames and masks (a frame without a mask gets its field of view by
  // --mask_rule), --init's poses file and --gt_poses, matched to the images by name. The
  // frames' names in the poses file are their file names.
  bool ReadFiles(std::string* error);

  // Instead of PlanFiles and ReadFiles: frames in memory (the Python package), each with a
  // mask (`mask_rules` says which rule made each, empty when they were given), their names
  // in the poses file, and the start (empty: --init's: identity, or a poses file matched to
  // `names`).
  // `later_phases`: views of T > 1 phases, each view's phases 1..T-1 (--phases selects).
  bool SetFrames(const Settings& settings, std::vector<Image> images, std::vector<Mask> masks,
                 std::vector<MaskRule> mask_rules, std::vector<std::string> names,
                 std::vector<Eigen::Isometry3d> start, std::string* error,
                 std::vector<std::vector<Image>> later_phases = {});

  // Before any work: the pipeline's checks of the frames and poses (a message about frame
  // N names its file), and the memory of the finest level's panorama (and --out_panorama's).
  bool Check(std::string* error);

  // Registers. False for set-up problems (bad input; `error` names the frame's file); a
  // registration that ran but gave no result returns true with result().usable false.
  bool Run(std::string* error);

  // Writes the outputs, each atomically, the poses file last: a run whose panorama,
  // transforms, resampled frames or report could not be written leaves the previous poses
  // file as it was. Call after a usable Run.
  bool Write(std::string* error);

  // The summary, one line each (without the tool's name): recoveries (RecoveryLines) come
  // first, as the registration ends; the rest after Write, then --gt_poses' errors
  // (gt_errors) and where the report is (report_index).
  std::vector<std::string> RecoveryLines() const;
  std::vector<std::string> SummaryLines(double seconds, double load_seconds) const;

  // The frames' names in the poses file (default: the image files' names).
  void set_names(std::vector<std::string> names) { names_ = std::move(names); }
  // The start instead of --init's (after ReadFiles): one pose per frame.
  void set_start(std::vector<Eigen::Isometry3d> start) { start_ = std::move(start); }
  // The inputs PlanFiles found (frames, masks, --init's and --gt_poses' files), remembered.
  void RememberInputs(InputRegistry* registry) const;

  RegistrationOptions& options() { return options_; }
  const RegistrationResult& result() const { return result_; }
  const std::vector<std::string>& names() const { return names_; }
  const std::vector<std::string>& image_paths() const { return image_paths_; }
  // The phases each view registers (1: 3D views).
  int num_phases() const;
  // "field of view: ..." (FieldOfViewSummary of the masks), and "preset echo: ..." (Settings::
  // PresetSummary, "" without a preset).
  std::string FieldOfViewLine() const;
  const std::string& preset_summary() const { return preset_summary_; }
  // --gt_poses' errors (after Write, with --gt_poses).
  const PoseErrorSummary& gt_errors() const { return gt_errors_; }
  const std::string& report_index() const { return report_index_; }  // "" without a report

 private:
  bool SetOptions(const Settings& settings, std::string* error);
  bool ParseReportFrames(std::string* error);
  void PlanFolderOutputs(OutputPlan* plan) const;
  bool ReadPoseFiles(std::string* error);
  bool CheckPanoramaMemory(std::string* error) const;
  bool UsePhases(const std::vector<int>& selected, std::string* error);
  std::vector<Image> FusedPanorama(const std::vector<Frame>& frames);
  bool WriteFrameFiles(const std::vector<Frame>& frames, std::string* error) const;
  bool WriteReport(const std::vector<Frame>& frames, const Image& panorama, std::string* error);
  std::string PhotometricLine() const;

  uint32_t front_end_;
  RegistrationOptions options_;
  std::string init_file_, preset_summary_;
  RunConfig config_;  // the fields of the options table (frames, panorama, fusion)
  RegistrationOutputs outputs_;
  OutputPlan plan_;
  std::vector<std::string> image_paths_, mask_paths_, names_;
  std::vector<int> outlined_, pair_;  // --report_frames, --report_pair
  std::vector<Image> images_;
  // Views recorded over T > 1 phases: each view's phases 1..T-1 (empty: 3D views).
  std::vector<std::vector<Image>> later_phases_;
  std::vector<Mask> masks_;
  std::vector<MaskRule> mask_rules_;
  std::vector<Eigen::Isometry3d> start_;
  PosesFile ground_truth_;
  RegistrationResult result_;
  // What Write found.
  bool fused_ = false;
  double enlargement_ = 0.0;
  std::string report_index_;
  PoseErrorSummary gt_errors_;
};

}  // namespace dsr

#endif  // DSR_APP_REGISTRATION_RUN_H_
