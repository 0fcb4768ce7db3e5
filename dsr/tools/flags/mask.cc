// Mask erosion (tools/flags/flags.h).
#include "dsr/tools/flags/flags.h"
#include "dsr/tools/tool_util.h"

DEFINE_int32(mask_erosion, 1, "Mask erosion in voxels (6-neighbourhood per voxel), in [0, 50]. "
             "dsr_register and dsr_fuse without --masks: of each image's field of view by "
             "--mask_rule. "
             "dsr_simulate and dsr_compare: of the masks of the simulated frames; 0 gives the "
             "exact field of view (the registration's gradients never read outside a mask, so "
             "no erosion is needed for them).");

namespace {
bool ValidateMaskErosion(const char* flag, int32_t v) {
  return dsr::CheckFlag(v >= 0 && v <= 50, flag, v, "must be in [0, 50]");
}
}  // namespace
DEFINE_validator(mask_erosion, &ValidateMaskErosion);
