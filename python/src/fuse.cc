// fuse: dsr_fuse's panorama of images at poses, with its inputs read as dsr_fuse reads them
// (ReadFusionInputs).
#include "module_internal.h"

#include <string>
#include <utility>
#include <vector>

#include "dsr/app/fusion_run.h"
#include "dsr/app/inputs.h"
#include "dsr/app/options.h"
#include "dsr/app/run_options.h"
#include "dsr/io/io_poses.h"
#include "dsr/model/panorama.h"

namespace dsr {
namespace python_internal {
namespace {

// The fusion's images and masks (at least one): file paths, read as dsr_fuse reads them
// (masks too), or (array, geometry) pairs, with `settings`' --mask_rule, --mask_erosion and
// --num_threads. `match_names`: what a poses file's entries are matched to (the paths, or
// `names`). True when the views hold --phases' selection already: files are read with it
// (ReadViewPhases, only those phases read), arrays are selected from by FusionRun.
bool ReadFusionInputs(const py::list& images,
                      const py::list& masks,
                      const std::vector<std::string>& names,
                      Settings settings,
                      std::vector<Image>* frames,
                      std::vector<Mask>* frame_masks,
                      std::vector<std::string>* match_names,
                      std::vector<std::vector<Image>>* later_phases) {
  std::string error;
  if (names.size() != images.size()) BadInput("names: need one name per image");
  *match_names = names;
  const RunConfig config = ConfigFrom(settings);
  std::vector<MaskRule> mask_rules;
  if (images.empty() || !py::isinstance<py::str>(images[0])) {
    ReadArrays(1, images, masks, config.field_of_view, frames, frame_masks, &mask_rules,
               later_phases);
    return false;
  }
  // As --images and --masks, so that the paths get dsr_fuse's checks and messages.
  std::vector<std::string> image_paths, mask_paths;
  if (!settings.Set("images", JoinPaths(images), &error) ||
      !settings.Set("masks", JoinPaths(masks), &error) ||
      !FrameFilesFrom(settings, 1, &image_paths, &mask_paths, &error) ||
      !ReadViewPhases(config.phases, image_paths, mask_paths, config.field_of_view,
                      config.num_threads, frames, frame_masks, &mask_rules, later_phases, &error)) {
    BadInput(error);
  }
  for (const std::string& path : image_paths) ReadInputs().AddImage("images", path);
  for (const std::string& path : mask_paths) ReadInputs().AddImage("masks", path);
  *match_names = image_paths;
  return true;
}

}  // namespace

py::tuple FuseImages(const py::list& images,
                     const py::list& masks,
                     const std::vector<std::string>& names,
                     const py::object& poses_in,
                     const Options& options_in) {
  const int m = static_cast<int>(images.size());
  std::string error, poses_name = "poses";
  PosesFile poses;
  if (py::isinstance<py::str>(poses_in)) {
    poses_name = poses_in.cast<std::string>();
    if (!ReadPoses(poses_name, m, &poses, &error)) BadInput("--poses: " + error);
    ReadInputs().AddFile("poses", poses_name);
  } else {
    poses = PosesFromDict(poses_in.cast<py::dict>());
  }
  std::vector<Image> frames_in;
  std::vector<Mask> masks_in;
  std::vector<std::string> match_names;
  std::vector<std::vector<Image>> later_phases;
  const Settings settings = MakeSettings(options_in, kPyFuse);
  RefuseNonFinite(settings, kPyFuse);  // (its double options' rules refuse inf and nan)
  const bool phases_selected = ReadFusionInputs(images, masks, names, settings, &frames_in,
                                                &masks_in, &match_names, &later_phases);
  FusionRun run(settings);
  if (!run.SetFrames(std::move(frames_in), std::move(masks_in), {}, match_names, std::move(poses),
                     poses_name, &error, std::move(later_phases), phases_selected) ||
      !run.Prepare(&error)) {
    BadInput(error);
  }
  {
    py::gil_scoped_release release;
    run.Fuse();
  }
  const PanoramaImages& fused = run.fused();
  std::vector<Image> means(1, fused.mean);  // every phase's mean: (T, z, y, x) when T > 1
  means.insert(means.end(), run.later_means().begin(), run.later_means().end());
  return py::make_tuple(PhasesToArray(std::move(means)),
                        py::make_tuple(ToArray(fused.count), FromGeometry(run.grid())),
                        fused.EnlargementRatio());
}

}  // namespace python_internal
}  // namespace dsr
