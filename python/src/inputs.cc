// The images and masks a call is given as (array, geometry) pairs, read with the rules
// --images and --masks have (ReadArrays); paths as a list option's value (JoinPaths); and
// the registry of the files this process read (ReadInputs), which no write replaces.
#include "module_internal.h"

#include <string>
#include <utility>
#include <vector>

#include "dsr/app/output_plan.h"
#include "dsr/geometry/field_of_view.h"
#include "dsr/geometry/volume.h"
#include "dsr/io/io_frames.h"

namespace dsr {
namespace python_internal {

std::string JoinPaths(const py::list& paths) {
  std::string out;
  for (const std::string& p : paths.cast<std::vector<std::string>>()) {
    out += (out.empty() ? "" : ",") + p;
  }
  return out;
}

void ReadArrays(int min_frames,
                const py::list& images,
                const py::list& masks,
                const FieldOfViewOptions& fov,
                std::vector<Image>* frames,
                std::vector<Mask>* frame_masks,
                std::vector<MaskRule>* mask_rules,
                std::vector<std::vector<Image>>* later_phases) {
  std::string error;
  const int m = static_cast<int>(images.size());
  if (m < min_frames) {
    BadInput("images: need at least " + std::to_string(min_frames) + " images, got " +
             std::to_string(m));
  }
  if (!masks.empty() && static_cast<int>(masks.size()) != m) {
    BadInput("masks: " + std::to_string(masks.size()) + " masks for " + std::to_string(m) +
             " images");
  }
  mask_rules->assign(masks.empty() ? m : 0, MaskRule::kHull);
  if (later_phases != nullptr) later_phases->assign(m, {});
  for (int i = 0; i < m; ++i) {
    const auto [array, geometry] = images[i].cast<std::pair<py::array, Geometry>>();
    const std::string what = "image " + std::to_string(i);
    if (later_phases != nullptr && array.ndim() == 4) {  // a view's phases, leading axis
      if (array.shape(3) == 1) {
        BadInput(what + ": 4D array of shape (" + std::to_string(array.shape(0)) + ", " +
                 std::to_string(array.shape(1)) + ", " + std::to_string(array.shape(2)) +
                 ", 1): a view's phases go along the first axis, (T, z, y, x); a last axis of "
                 "1 looks like a channel axis (squeeze it)");
      }
      for (ssize_t t = 0; t < array.shape(0); ++t) {
        const py::array phase = array.attr("__getitem__")(t);
        Image volume = ToVolume<float>(phase, geometry, what + " phase " + std::to_string(t),
                                       /*refuse_constant=*/array.shape(0) > 1);
        if (t == 0) {
          frames->push_back(std::move(volume));
        } else {
          (*later_phases)[i].push_back(std::move(volume));
        }
      }
      if (array.shape(0) == 0) BadInput(what + ": an array of 0 phases");
    } else {
      frames->push_back(ToVolume<float>(array, geometry, what));
    }
    if (masks.empty()) {
      frame_masks->emplace_back();
      if (!MaskFromImage(frames->back(), fov, "image " + std::to_string(i), &frame_masks->back(),
                         &(*mask_rules)[i], &error)) {
        BadInput(error);
      }
      continue;
    }
    const auto [mask, mask_geometry] = masks[i].cast<std::pair<py::array, Geometry>>();
    const std::string mask_what = "mask " + std::to_string(i);
    frame_masks->push_back(later_phases != nullptr ? ToMaskPhases(mask, mask_geometry, mask_what)
                                                   : ToMask(mask, mask_geometry, mask_what));
    if (!frame_masks->back().geometry.SameGrid(frames->back().geometry, 1e-3)) {
      BadInput("mask " + std::to_string(i) + ": not on its image's voxel grid");
    }
  }
}

InputRegistry& ReadInputs() {
  static InputRegistry* const registry = new InputRegistry();
  return *registry;
}

}  // namespace python_internal
}  // namespace dsr
