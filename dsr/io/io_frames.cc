// Reading a registration's frames (io/io_frames.h).
#include "dsr/io/io_frames.h"

#include <iterator>
#include <utility>

#include "dsr/io/io_image.h"
#include "dsr/io/io_phases.h"
#include "dsr/util/parallel.h"

namespace dsr {

bool MaskFromImage(const Image& image,
                   const FieldOfViewOptions& field_of_view,
                   const std::string& name,
                   Mask* mask,
                   MaskRule* used,
                   std::string* error) {
  MaskRule rule = field_of_view.mask_rule;
  *mask = FieldOfViewFromImage(image, field_of_view, &rule);
  if (used) *used = rule;
  if (CountInside(*mask) > 0) return true;
  *error = name + ": no voxel left in the field of view (" +
           (rule == MaskRule::kHull ? "convex hull of the non-zero voxels" : "non-zero voxels") +
           " eroded by mask_erosion=" + std::to_string(field_of_view.mask_erosion) + ")";
  return false;
}

bool ReadFrames(const std::vector<std::string>& image_paths,
                const std::vector<std::string>& mask_paths,
                const FieldOfViewOptions& field_of_view,
                int num_threads,
                std::vector<Image>* images,
                std::vector<Mask>* masks,
                std::vector<MaskRule>* mask_rules,
                std::string* error,
                std::vector<std::vector<Image>>* later_phases,
                const std::vector<int>& phases) {
  const int m = static_cast<int>(image_paths.size());
  images->assign(m, Image());
  masks->assign(m, Mask());
  if (later_phases != nullptr) later_phases->assign(m, {});
  std::vector<MaskRule> rules(mask_paths.empty() ? m : 0, field_of_view.mask_rule);
  std::vector<std::string> read_errors(m);
  ParallelFor(0, m, num_threads, [&](int64_t i) {
    std::string& e = read_errors[i];
    if (later_phases == nullptr) {
      if (!ReadImage(image_paths[i], &(*images)[i], &e)) return;
    } else {
      std::vector<Image> view;
      if (!ReadView(image_paths[i], phases, &view, &e)) return;
      (*images)[i] = std::move(view[0]);
      (*later_phases)[i].assign(std::make_move_iterator(view.begin() + 1),
                                std::make_move_iterator(view.end()));
    }
    if (!mask_paths.empty()) {
      if (later_phases == nullptr) {
        ReadMask(mask_paths[i], (*images)[i].geometry, &(*masks)[i], &e);
      } else {
        ReadMaskPhases(mask_paths[i], (*images)[i].geometry, &(*masks)[i], &e);
      }
      return;
    }
    MaskFromImage((*images)[i], field_of_view, image_paths[i], &(*masks)[i], &rules[i], &e);
  });
  for (const std::string& e : read_errors) {
    if (!e.empty()) {
      *error = e;
      return false;
    }
  }
  if (mask_rules) *mask_rules = std::move(rules);
  return true;
}

}  // namespace dsr
