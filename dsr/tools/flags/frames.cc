// The frames a registration or a fusion reads, and how the panorama blends them
// (tools/flags/flags.h).
#include <cmath>
#include <set>

#include "dsr/tools/flags/flags.h"
#include "dsr/tools/tool_util.h"

DEFINE_string(images, "", "Frame images (.nii, .nii.gz, .mha, .mhd, .nrrd, .nhdr), frame 0 "
              "first (it fixes the world): comma-separated, or @LIST: the file LIST with one "
              "path per line (for names that contain commas). At most 32 (kMaxFrames); "
              "dsr_register needs at least 2. Required.");
DEFINE_string(masks, "", "Field-of-view masks, one per image, on the image's grid (non-zero = "
              "inside), comma-separated or @LIST as --images. Empty: each image's field of view "
              "by --mask_rule (default: the convex hull of its non-zero voxels) eroded by "
              "--mask_erosion voxels.");
DEFINE_string(blend, "mean", "Panorama blending: mean (paper eq. 10: the per-voxel mean of the "
              "observations) or feather (weights fall off towards each field-of-view edge, so "
              "seams vanish).");
DEFINE_double(feather_voxels, 8.0, "--blend=feather: depth (frame voxels) over which a frame's "
              "weight rises from 0 at its field-of-view edge to 1, > 0.");

namespace {
bool ValidateBlend(const char* flag, const std::string& v) {
  return dsr::CheckFlag(v == "mean" || v == "feather", flag, v, "must be mean or feather");
}
bool ValidateFeatherVoxels(const char* flag, double v) {
  return dsr::CheckFlag(v > 0.0 && std::isfinite(v), flag, v, "must be > 0");
}
}  // namespace
DEFINE_validator(blend, &ValidateBlend);
DEFINE_validator(feather_voxels, &ValidateFeatherVoxels);

namespace dsr {

bool FrameFilesFromFlags(int min_frames,
                         std::vector<std::string>* image_paths,
                         std::vector<std::string>* mask_paths,
                         std::string* error) {
  if (!ParseInputList("images", FLAGS_images, image_paths, error) ||
      !ParseInputList("masks", FLAGS_masks, mask_paths, error)) {
    return false;
  }
  const int m = static_cast<int>(image_paths->size());
  if (m < min_frames) {
    *error = m == 0 && min_frames == 1 ? "--images: no image given"
                                       : "--images: need at least " + std::to_string(min_frames) +
                                             " images, got " + std::to_string(m);
    return false;
  }
  if (m > kMaxFrames) {
    *error = "--images: at most " + std::to_string(kMaxFrames) + " frames, got " +
             std::to_string(m);
    return false;
  }
  if (!mask_paths->empty() && static_cast<int>(mask_paths->size()) != m) {
    *error = "--masks: " + std::to_string(mask_paths->size()) + " masks for " +
             std::to_string(m) + " images";
    return false;
  }
  std::set<std::string> unique;
  for (const std::string& p : *image_paths) {
    if (!unique.insert(CanonicalPath(p)).second) {
      *error = "--images: " + p + " is given twice";
      return false;
    }
  }
  return true;
}

bool FeatherBlend() { return FLAGS_blend == "feather"; }

}  // namespace dsr
