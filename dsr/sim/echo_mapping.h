// The echo-like intensity mapping of a simulation source (docs/design.md section 6.6,
// SimulationOptions::intensity_mapping = kEcho).
//
// In transesophageal echo the blood pool is black (the scanner's reject and compression
// drop low-level echoes), tissue is bright, and interfaces (endocardium, pericardium),
// which reflect more than they scatter, are brighter still. The project's sources are a
// phantom, an MRI template and a CT whose dark regions (blood, CSF, lungs) are grey rather
// than black. The map, per source voxel with S its value (0..255),
//   E = 255 clamp((1 - w) max(0, S - r) / (255 - r) + w min(1, |grad G_sigma * S| / g99), 0, 1),
// where
//   r     = echo_reject: everything at or below it is black, the rest rescaled to 0..255;
//   G_sigma * S = the source smoothed by a Gaussian of echo_edge_sigma_mm per physical axis
//           (sigma_mm / spacing_mm[a] voxels along index axis a: sources may be anisotropic,
//           e.g. the CT's 0.63 x 0.63 x 5 mm; normalised convolution over the grid, so the
//           border does not darken: image/pyramid.h's SmoothInsideMask on an all-ones mask;
//           sigma 0: the source itself);
//   grad  = its physical gradient (grey levels per mm), M^T (dG/di, dG/dj, dG/dk) with
//           M = S^-1 D^-1 the physical-to-index matrix (the chain rule through
//           ijk = M (x - origin)): for an orthonormal direction D its norm is that of the
//           index derivatives divided by the spacings. The index derivatives are central
//           differences (one-sided on the grid's border faces, 0 along a single-voxel axis);
//   g99   = the 99th percentile of |grad| over the voxels with S > 0 (outside the anatomy
//           of a skull-stripped or cut source the background is 0 and carries no edges):
//           the order statistic of 0-based rank floor(0.99 (n - 1)) of those n values. If
//           it is 0 (n = 0, or fewer than 1 % of them have a gradient), min(1, g / 0) is
//           read as its limit: 1 where g > 0, 0 where g = 0;
//   w     = echo_edge_weight, the share of the full scale the edge term adds.
// So a flat region below r maps to exactly 0, a flat region at S > r to
// 255 (1 - w) (S - r) / (255 - r), and the strongest 1 % of interfaces gain 255 w.
#ifndef DSR_SIM_ECHO_MAPPING_H_
#define DSR_SIM_ECHO_MAPPING_H_

#include "dsr/geometry/volume.h"
#include "dsr/sim/simulate.h"

namespace dsr {

// E on the source's grid (same geometry), from options' echo_reject, echo_edge_sigma_mm
// and echo_edge_weight (intensity_mapping itself is not read). Bit-identical for every
// num_threads (<= 0: all hardware threads). When `gradient_p99` is not null it receives
// g99 (grey levels per mm). options must be valid and source non-empty. Memory beside the
// source: at the peak (the smoothing) three float grids of its size and an all-ones byte
// mask, 13 bytes per voxel; afterwards two float grids (the gradient magnitudes with the
// percentile's selection, then with the map).
Image EchoIntensityMap(const Image& source,
                       const SimulationOptions& options,
                       int num_threads,
                       double* gradient_p99 = nullptr);

}  // namespace dsr

#endif  // DSR_SIM_ECHO_MAPPING_H_
