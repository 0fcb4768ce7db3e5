// How a frame given without a mask gets its field of view (tools/flags/flags.h).
#include "dsr/geometry/field_of_view.h"
#include "dsr/tools/flags/flags.h"
#include "dsr/tools/tool_util.h"

DEFINE_string(mask_rule, "hull", "Without --masks (dsr_compare: with --sequence_masks=false), "
              "each frame's field of view before the --mask_erosion erosion: hull = the convex "
              "hull of its non-zero voxels (3D echo and cut CT/MR fields of view are convex, "
              "so tissue as dark as the background stays inside; specks of under 1% of the "
              "largest component are ignored), or the nonzero rule where no hull fits (data "
              "on one plane or line); nonzero = the non-zero voxels and the zeros they "
              "enclose (zeros that reach the grid border through zeros are outside).");

namespace {
bool ValidateMaskRule(const char* flag, const std::string& v) {
  dsr::MaskRule rule;
  return dsr::CheckFlag(dsr::StringToMaskRule(v, &rule), flag, v, "must be hull or nonzero");
}
}  // namespace
DEFINE_validator(mask_rule, &ValidateMaskRule);

namespace dsr {

FieldOfViewOptions FieldOfViewFromFlags() {
  FieldOfViewOptions options;
  StringToMaskRule(FLAGS_mask_rule, &options.mask_rule);  // validated
  options.mask_erosion = FLAGS_mask_erosion;
  return options;
}

}  // namespace dsr
