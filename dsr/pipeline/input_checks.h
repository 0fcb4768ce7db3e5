// Checks of a registration's inputs that need the frames, made before any work, and the
// intensity normalisation that makes the solver's tolerances independent of the
// intensities' unit.
//
// Each check names the option or the frame that is actually wrong, where otherwise a later
// step would fail with a message that blames something else (a 1e-9 mm spacing read as
// frames that do not overlap; a smoothing that erases every structure read as a
// featureless overlap; an initial translation of 1e300 mm read as a panorama too large
// for its spacing).
#ifndef DSR_PIPELINE_INPUT_CHECKS_H_
#define DSR_PIPELINE_INPUT_CHECKS_H_

#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "dsr/geometry/volume.h"

namespace dsr {

// Frames of one sequence share a scale: a frame whose voxel spacing differs from frame
// 0's by more than this factor along any axis is refused (a header in another unit, or
// broken).
constexpr double kMaxSpacingRatio = 1000.0;
// The initial poses may place a frame's centre at most this many of the frames' largest
// extents away from frame 0's centre.
constexpr double kMaxInitialSpread = 1000.0;

struct RegistrationOptions;

// The checks above and of the headers and poses: the finest level's smoothing
// (--smoothing) must leave structure, at most a quarter of frame 0's shortest axis; the
// panorama voxel (frame 0's spacing times --panorama_spacing) at most an eighth of frame 0's
// shortest extent; the frames' centres not too far apart. No voxel is read: a front end
// checks these before its memory estimate and leaves the voxels to Register. Returns false
// with `error` naming the frame (by index) or the option's flag.
bool CheckRegistrationGeometry(const std::vector<Image>& images,
                               const std::vector<Eigen::Isometry3d>& initial_frame_from_world,
                               const RegistrationOptions& options,
                               std::string* error);

// CheckRegistrationGeometry, then: no frame has an outlier voxel that holds more than half of
// its squared deviation from its median (one voxel would outweigh the rest in the cost; a
// read of every voxel, 0.12 s at clinical size). What Register checks.
bool CheckRegistrationInputs(const std::vector<Image>& images,
                             const std::vector<Eigen::Isometry3d>& initial_frame_from_world,
                             const RegistrationOptions& options,
                             std::string* error);

// Intensity normalisation. The solver's absolute tolerances (Ceres's gradient tolerance,
// the Levenberg-Marquardt diagonal's bounds) assume intensity differences of a usual size:
// at 1e-12 times the usual intensities a solve stops after 0 iterations at the initial
// poses. The registration therefore multiplies every frame by 2^exponent (exact in floating
// point: the solve sees the same numbers up to the power of two) when the robust spread of
// the intensities (the median absolute deviation from the median over the frames'
// field-of-view voxels; their mean absolute deviation when that is 0) lies outside
// [kMinIntensitySpread, kMaxIntensitySpread], chosen to bring it to about
// kTargetIntensitySpread. Within the band the exponent is 0 and nothing changes. The poses
// do not depend on a common intensity scale: the cost scales by 4^exponent.
constexpr double kMinIntensitySpread = 1.0 / 16.0;
constexpr double kMaxIntensitySpread = 16384.0;
constexpr double kTargetIntensitySpread = 64.0;

// The robust spread described above, from at most about a million voxels evenly spread
// over the frames (deterministic). 0 when every field-of-view voxel has the same value.
double IntensitySpread(const std::vector<Image>& images, const std::vector<Mask>& masks);
// The exponent described above (0 inside the band or for a spread of 0).
int IntensityScaleExponent(double spread);

}  // namespace dsr

#endif  // DSR_PIPELINE_INPUT_CHECKS_H_
