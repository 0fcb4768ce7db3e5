// The panorama grid's spacing and the thread count (tools/flags/flags.h).
#include <cmath>

#include "dsr/tools/flags/flags.h"
#include "dsr/tools/tool_util.h"

DEFINE_double(panorama_spacing, 1.0, "Panorama voxel spacing as a multiple of frame 0's "
              "spacing (at every pyramid level), in [0.001, 1000], and at most an eighth of "
              "frame 0's shortest extent. Larger = fewer voxels, less memory; a panorama that "
              "would not fit in memory is refused.");
DEFINE_int32(num_threads, 0, "Threads, >= 0 (0 = all hardware threads).");

namespace {
// Spacing factors outside this range are typos: a grid a thousand times finer or coarser
// than the frames' is no panorama of them.
bool ValidatePanoramaSpacing(const char* flag, double v) {
  return dsr::CheckFlag(v >= 1e-3 && v <= 1e3, flag, v,
                        "must be in [0.001, 1000] (a multiple of frame 0's spacing)");
}
bool ValidateNumThreads(const char* flag, int32_t v) {
  return dsr::CheckFlag(v >= 0, flag, v, "must be >= 0");
}
}  // namespace
DEFINE_validator(panorama_spacing, &ValidatePanoramaSpacing);
DEFINE_validator(num_threads, &ValidateNumThreads);
