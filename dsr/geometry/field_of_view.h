// The field-of-view mask of a frame given without one, from its image alone
// (docs/design.md section 2.1).
//
// Two rules. MaskRule::kNonZero is MaskFromNonZero: outside are the zero voxels connected
// to the grid border through zero voxels. Where tissue inside the field of view is as dark
// as the background (lungs in a windowed CT, the blood pool in echo), noise clamped at 0
// leaves about half of its voxels exactly 0, those zeros percolate from the border, and
// the dark region is lost. MaskRule::kHull (the default) uses that 3D echo and cut CT/MR
// frames have convex acquisition fields of view (pyramid, sector, box): the field of view
// is the convex hull of the voxels MaskRule::kNonZero calls inside, ignoring stray specks (e.g.
// an annotation), then eroded as MaskFromNonZero erodes.
#ifndef DSR_GEOMETRY_FIELD_OF_VIEW_H_
#define DSR_GEOMETRY_FIELD_OF_VIEW_H_

#include <string>

#include "dsr/geometry/volume.h"

namespace dsr {

enum class MaskRule { kHull, kNonZero };

constexpr const char* MaskRuleToString(MaskRule rule) {
  return rule == MaskRule::kNonZero ? "nonzero" : "hull";
}
// The inverse of MaskRuleToString; false (and *rule untouched) for any other text.
bool StringToMaskRule(const std::string& name, MaskRule* rule);

// How a frame given without a mask gets one (the tools' --mask_rule and --mask_erosion).
struct FieldOfViewOptions {
  MaskRule mask_rule = MaskRule::kHull;
  int mask_erosion = 1;  // voxels, >= 0: the box half-width of ErodeMask
};

// A component of the non-zero voxels shorter than this fraction of the largest one is left
// out of the hull: an annotation or a stray speck does not inflate it, while a field of view
// cut in two by a solid dark band keeps both halves.
constexpr double kMinHullComponentFraction = 0.01;

// The convex-hull rule: the voxels MaskFromNonZero(image, 0) calls inside, their
// 26-connected components, those with at least kMinHullComponentFraction of the largest
// one's voxels; the mask is every voxel whose centre lies in the convex hull of the kept
// voxels' centres (computed in index space: the hull commutes with the affine map to
// physical space), then eroded by `erosion_voxels` (ErodeMask). Every kept voxel is
// inside before the erosion. False (and `mask` untouched) when no hull fits: the kept
// voxels' centres do not span 3 dimensions (fewer than 4, all on one line or one plane,
// e.g. a one-slice frame) or qhull fails; `why` (optional) then says which.
bool MaskFromConvexHull(const Image& image, int erosion_voxels, Mask* mask, std::string* why);

// The mask of `image` by `options.mask_rule`; kHull falls back to kNonZero where no hull
// fits (MaskFromConvexHull). `used` (optional): the rule that built the mask.
Mask FieldOfViewFromImage(const Image& image, const FieldOfViewOptions& options, MaskRule* used);

}  // namespace dsr

#endif  // DSR_GEOMETRY_FIELD_OF_VIEW_H_
