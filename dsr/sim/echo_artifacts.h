// What real 3D transesophageal echo has beyond the ultrasound-like effects of
// SimulationOptions (docs/design.md section 6.7): view-dependent echogenicity, acoustic
// shadows, a lateral point-spread function that widens with depth, and signal dropouts. Each
// is off at its option's default, and a sequence without them is bit for bit the one the
// simulator made before they existed.
//
// They act on a frame's noise-free samples S (the source, or its echo map, interpolated at
// the frame's voxels; 0 outside the field of view `fov`), in this order, before the speckle,
// attenuation, gain, offset and noise. The beams leave the apex a = (cx, cy, 0) (frame
// index, the centre of the k = 0 face, simulate.h) and pass a voxel x along b(x) = (x - a) /
// |x - a|.
//  * Echogenicity (echogenicity_range e): an interface reflects more when the beam meets it
//    head on. With g the central-difference gradient of S (0 where a neighbour lies outside
//    the field of view) and g90 the 90th percentile of the non-zero |g| in the field of view,
//      S <- S (1 + e min(1, |g| / g90) cos(2 phi)),  cos(phi) = |g . b| / |g|,
//    so an interface across the beam (g along b) is brighter by up to e, one along it darker
//    by up to e, and flat regions (|g| small) keep their value.
//  * Shadows (shadow_strength s, shadow_threshold r): a bright reflector passes less of the
//    beam. Each voxel the beam crosses with S above r lets the fraction
//      t(S) = 1 - s min(1, (S - r) / (255 - r))
//    through; a voxel's transmission T is the product over the voxels before it on its
//    beam, computed slice by slice: T(i, j, k) = T(p) t(S(p)) with p the beam's point in
//    slice k - 1 (bilinear in that slice), T = 1 in slice 0. Then S <- S T. The reflector
//    itself keeps its brightness; what lies behind it darkens, differently in every view
//    because the beams differ.
//  * Lateral blur (psf_lateral_mm): each slice k (depth k along the beam's axis) is smoothed
//    along i and j by a Gaussian of standard deviation psf_lateral_mm k / (n_k - 1) mm (so
//    the value at the far face, none at the apex), a normalised convolution inside the field
//    of view (no zero from outside leaks in). Depth (k) is not blurred.
//  * Dropouts (dropout_fraction f, dropout_view_fraction q): per view, with probability q,
//    a wedge of the sector where contact is lost: the voxels whose azimuth angle
//    atan((i - cx) / k) lies in [theta0, theta0 + w), w uniform in [f/2, f] times the
//    azimuth opening, theta0 uniform where the wedge fits in the sector. There only noise
//    remains: the frame's value before noise is 0 (no gain, offset or speckle). The same
//    wedge holds for every phase of a view. Draws: a stream of its own per view
//    (StreamSeed(seed, "dropout_", view)): u (has a wedge), u (width), u (position).
#ifndef DSR_SIM_ECHO_ARTIFACTS_H_
#define DSR_SIM_ECHO_ARTIFACTS_H_

#include <cstdint>
#include <vector>

#include "dsr/geometry/volume.h"
#include "dsr/sim/simulate.h"

namespace dsr {

// True when any of the first three effects (echogenicity, shadows, lateral blur) is on.
bool HasBeamArtifacts(const SimulationOptions& options);

// The echogenicity, shadows and lateral blur above, in that order, on `frame` (its grid
// g, noise-free samples, 0 outside `fov`); each skipped when off. options must be valid.
void ApplyBeamArtifacts(const Mask& fov, const SimulationOptions& options, Image* frame);

// Each step alone, for tests and for ApplyBeamArtifacts.
void ApplyEchogenicity(const Mask& fov, double range, Image* frame);
void ApplyShadows(const Mask& fov, double strength, double threshold, Image* frame);
void ApplyLateralBlur(const Mask& fov, double sigma_mm_at_full_depth, Image* frame);

// View `view`'s dropout wedge on the frame grid `g` within `fov`: 1 where the signal is
// lost; empty when the view has none (or dropout_fraction is 0). `seed_stream` is the
// view's stream seed (Simulate: StreamSeed(seed, "dropout_", view)).
std::vector<uint8_t> DropoutWedge(const ImageGeometry& g, const Mask& fov,
                                  const SimulationOptions& options, uint64_t seed_stream);

}  // namespace dsr

#endif  // DSR_SIM_ECHO_ARTIFACTS_H_
