// A variance-stabilising transform of the intensities, applied before registering
// (docs/design.md section 2.9).
//
// Linear-envelope ultrasound has multiplicative speckle: the noise's standard deviation
// grows with the brightness. Where it differs between neighbouring voxels (at every edge,
// where the registration's information is), a frame's interpolated gradient correlates with
// its own sample's noise and the Gauss-Newton fixed point is biased (docs/accuracy_us.md).
// The square root makes that noise roughly homoscedastic:
//   T(I) = sqrt(c I),  c = the largest intensity inside any frame's mask,
// which maps [0, c] onto itself (slope 1 at c / 4), so that grey-level options (a robust
// loss's scale) keep their order of magnitude. A gain a stays a gain under T (sqrt(a) on the
// transformed scale); an offset does not stay an offset, so with photometric parameters the
// transformed model is an approximation, and the pipeline estimates the gains and offsets
// reported (and used by fusion) on the input's grey levels at the final poses.
#ifndef DSR_MODEL_INTENSITY_TRANSFORM_H_
#define DSR_MODEL_INTENSITY_TRANSFORM_H_

#include <cmath>
#include <string>
#include <vector>

#include "dsr/geometry/volume.h"
#include "dsr/model/photometric.h"

namespace dsr {

enum class IntensityTransform {
  kNone,
  kSqrt,
};

// "none" / "sqrt" (the tools' --intensity_transform values).
constexpr const char* IntensityTransformToString(IntensityTransform transform) {
  return transform == IntensityTransform::kSqrt ? "sqrt" : "none";
}
// The inverse of IntensityTransformToString; false (and *transform untouched) otherwise.
bool StringToIntensityTransform(const std::string& name, IntensityTransform* transform);

// The transform's constant c: the largest intensity inside any frame's mask (0 if none
// is positive).
double IntensityTransformScale(const std::vector<Image>& images, const std::vector<Mask>& masks);

// T(v) = sqrt(c v) and its inverse v = T^2 / c (c > 0; T(v) for v >= 0).
inline double ForwardIntensity(double value, double scale) { return std::sqrt(scale * value); }
inline double InverseIntensity(double value, double scale) { return value * value / scale; }

// A frame's gain and offset on the input's grey levels from its gain g and offset b on T's
// scale (its corrected intensity g T(I) + b), matched to first order at the frame's mean
// intensity `mean` (> 0): T^-1(g T(I) + b) = g^2 I + 2 g b sqrt(I / c) + b^2 / c, with sqrt(I)
// linearised at `mean`, is (g^2 + g b / sqrt(c mean)) I + g b sqrt(mean / c) + b^2 / c.
// Exact for b = 0; a start for the estimate on the input's grey levels, not the estimate.
inline void GainAndOffsetOnInputScale(double g, double b, double mean, double scale,
                                      double* gain, double* offset) {
  *gain = g * g + g * b / std::sqrt(scale * mean);
  *offset = g * b * std::sqrt(mean / scale) + b * b / scale;
}

// GainAndOffsetOnInputScale for every frame, at each frame's mean intensity inside its
// mask: a start for the photometric parameters on the input's grey levels from
// `on_transform` (one per frame, on T's scale). Frame 0 keeps the gauge; a frame whose mean
// is not positive, or whose mapped gain is not, starts at gain 1 and offset 0.
std::vector<Photometric> PhotometricOnInputScale(const std::vector<Photometric>& on_transform,
                                                 const std::vector<Image>& images,
                                                 const std::vector<Mask>& masks, double scale);

// `images` with T applied to every voxel, given `scale` = IntensityTransformScale. The
// square root needs intensities >= 0 inside the masks: otherwise false, with `error`
// naming the field (intensity_transform), the image (0-based) and its voxel. Voxels outside
// a mask (never observed) below 0 become T(0) = 0.
bool ApplyIntensityTransform(const std::vector<Image>& images,
                             const std::vector<Mask>& masks,
                             IntensityTransform transform,
                             double scale,
                             std::vector<Image>* transformed,
                             std::string* error);

}  // namespace dsr

#endif  // DSR_MODEL_INTENSITY_TRANSFORM_H_
