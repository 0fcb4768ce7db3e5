// A fusion run as every front end makes it (dsr_fuse, dsr.fuse): frames (files or images in
// memory) and a poses file matched to them by name, the panorama's grid and memory checked
// before it is allocated, the fusion (with the poses file's gains and offsets), and the
// outputs. A front end keeps its arguments and its conversions.
#ifndef DSR_APP_FUSION_RUN_H_
#define DSR_APP_FUSION_RUN_H_

#include <cstdint>
#include <string>
#include <vector>

#include "dsr/app/options.h"
#include "dsr/app/output_plan.h"
#include "dsr/app/run_options.h"
#include "dsr/geometry/field_of_view.h"
#include "dsr/io/io_poses.h"
#include "dsr/model/panorama.h"

namespace dsr {

class FusionRun {
 public:
  // The options of the fusion (--blend, --feather_voxels, --panorama_spacing, --mask_rule,
  // --mask_erosion, --num_threads) from `settings`.
  explicit FusionRun(const Settings& settings);

  // The files of --images, --masks and --poses (`poses_path`) and the outputs (`out`,
  // `out_count`; "" for none), every file planned and checked before anything is read.
  bool PlanFiles(const Settings& settings, const std::string& poses_path, const std::string& out,
                 const std::string& out_count, std::string* error);
  // Reads the planned frames and masks, then the poses file, matched to the images by name.
  bool ReadFiles(std::string* error);

  // Instead: frames in memory, each with a mask (`mask_rules`: which rule made each, empty
  // when given), and their poses (`poses_name` names them in messages), matched to `names`.
  // `later_phases`: views of T > 1 phases, each view's phases 1..T-1 (--phases selects,
  // unless `phases_selected`: views read by ReadViewPhases hold its selection already).
  bool SetFrames(std::vector<Image> images, std::vector<Mask> masks,
                 std::vector<MaskRule> mask_rules, std::vector<std::string> names,
                 PosesFile poses, const std::string& poses_name, std::string* error,
                 std::vector<std::vector<Image>> later_phases = {},
                 bool phases_selected = false);

  // The frames at their poses, the panorama's grid, and its memory (the mean, the count and
  // what writing them adds), before the panorama is allocated.
  bool Prepare(std::string* error);
  // Fuses (with the poses file's gains and offsets when it has them); views of T > 1 phases
  // phase by phase (fused() is phase 0's, later_means() the other phases' means).
  void Fuse();
  // Writes the planned outputs (atomically).
  bool Write(std::string* error) const;
  // "3 frames, mean blend, panorama ...; wrote out.nii.gz" and the field-of-view line.
  std::vector<std::string> SummaryLines() const;

  const PanoramaImages& fused() const { return fused_; }
  const std::vector<Image>& later_means() const { return later_means_; }
  const ImageGeometry& grid() const { return grid_; }

 private:
  RunConfig config_;  // the fields of the options table (frames, panorama, fusion)
  std::string blend_, poses_path_, out_, out_count_;
  OutputPlan plan_;
  std::vector<std::string> image_paths_, mask_paths_, names_;
  std::vector<Image> images_;
  std::vector<std::vector<Image>> later_phases_;  // views of T > 1 phases: phases 1..T-1
  std::vector<Mask> masks_;
  std::vector<MaskRule> mask_rules_;
  PosesFile poses_;
  std::vector<Frame> frames_;
  std::vector<Eigen::Isometry3d> frame_from_world_;
  ImageGeometry grid_;
  std::vector<Photometric> photometric_;
  PanoramaImages fused_;
  std::vector<Image> later_means_;
};

}  // namespace dsr

#endif  // DSR_APP_FUSION_RUN_H_
