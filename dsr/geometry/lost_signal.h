// Where a view carries no signal: the beams of an ultrasound sector along which contact was
// lost (docs/design.md section 2.10).
//
// A sector's beams leave its apex; where the probe loses contact with the tissue, a wedge of
// beams returns noise alone over its whole depth. Such a wedge is inside the field of view,
// yet what it shows is not the anatomy: left in the mask, its noise around the dark level
// disagrees with every other view that sees tissue there, and the cost is lowered by moving
// the view away from them. FindLostSignal finds the wedge from the data alone and leaves it
// out of the mask.
//
// The sector (FindSector): along the index axis and direction in which the field of view
// widens the most, the square root of a slice's voxel count grows linearly with depth
// (a pyramid's or cone's width); the line's zero is the apex's depth, and the slices'
// centroids, fitted linearly in depth, give its lateral place. A field of view that widens by
// less than kMinSectorWidening from its near to its far face (a box, a cut CT frame) has no
// sector, and nothing is left out.
//
// The beams (FindLostSignal): each voxel's offset from the apex, in physical units, over its
// depth along the depth axis gives two tangents; they are binned so that a bin is
// kBeamBinVoxels wide at the field of view's mean depth. A bin's depth profile p_d is the mean
// of its voxels in each slab of one voxel's depth. Noise alone is independent between slabs,
// so its profile's lag correlation rho_L = cov(p_d, p_{d+L}) / var(p_d) over the n pairs
// L = kLostSignalLagVoxels slabs apart is about N(0, 1/n), while tissue's profile is not: its
// interfaces, its speckle's slow part and its attenuation with depth correlate over a few
// voxels. A core bin has rho_L sqrt(n) < kLostSignalZ (its profile cannot be told from noise
// alone) and a mean below kDropoutCoreRatio of the median bin mean (lost contact returns far
// less than tissue; flat tissue is not lost). Cores grow through 8-neighbouring bins whose
// mean is below the geometric mean of the cores' median level and the view's median (closer
// to the lost level than to the view's, in decibels: the wedge's edge bins, part lost); a
// grown region of fewer than kMinDropoutShare of the judged bins is left in. Bins with fewer
// than kMinLostSignalSlabs slabs are not judged. The statistics read every s-th voxel along
// each axis (kLostSignalSampleVoxels); only a view with lost bins is labelled voxel by voxel.
//
// The views of one acquisition (FindLostSignalInViews) share the level of noise alone: lost
// contact returns the receiver's noise, whatever the tissue, while a view's median is its
// tissue's. In a view of mostly dark tissue a wedge's mean can exceed a quarter of that
// median (chest-CT views of the lungs: 6 grey levels in the wedge against a median of 12),
// so a core may also be as bright as the geometric mean of the shared level (the median of
// the cores of the dropouts the rule above finds in every view; none found: no shared level)
// and the view's median. One view (FindLostSignal) gives that level itself.
//
// A view alone cannot tell lost contact from tissue that returns nothing over a whole beam
// (a blood pool, a lung, the black background of a raw image): both are noise alone at the
// dark level. The pipeline therefore asks for it only where told (RegistrationOptions::
// detect_dropouts, on with the tools' --preset=echo).
#ifndef DSR_GEOMETRY_LOST_SIGNAL_H_
#define DSR_GEOMETRY_LOST_SIGNAL_H_

#include <cstdint>
#include <vector>

#include <Eigen/Core>

#include "dsr/geometry/volume.h"

namespace dsr {

// A field of view narrower than this at its near face than at its far face has no sector.
constexpr double kMinSectorWidening = 2.0;
// The lag (depth slabs) of a beam bin's profile correlation, its threshold in standard errors
// of noise alone, and the fewest slabs a bin needs to be judged.
constexpr int kLostSignalLagVoxels = 3;
constexpr double kLostSignalZ = 3.0;
constexpr int kMinLostSignalSlabs = 16;
// A beam bin's width at the field of view's mean depth, in voxels.
constexpr double kBeamBinVoxels = 1.0;
// The statistics read every s-th voxel along each axis, s the integer nearest the cube root
// of the grid's voxels over this (1 at the paper's 96x96x80, 2 at 176x176x200).
constexpr double kLostSignalSampleVoxels = 1 << 20;
// A lost beam's core returns less than this share of the view's median beam (12 dB less).
constexpr double kDropoutCoreRatio = 0.25;
// A dropout covers at least this share of the judged beam bins; a smaller dark spot is left
// in (it changes little either way, and is more often dark tissue than lost contact).
constexpr double kMinDropoutShare = 0.02;

struct Sector {
  bool found = false;
  int depth_axis = 2;  // index axis along which the field of view widens
  int direction = 1;   // +1: depth grows with the index along depth_axis, -1: it falls
  Eigen::Vector3d apex = Eigen::Vector3d::Zero();  // continuous index coordinates
  double widening = 0.0;  // the fitted far-face width over the near-face width
};

// The sector of `fov` (see the header comment); found is false when it widens by less than
// kMinSectorWidening along every axis or spans fewer than kMinLostSignalSlabs slices.
Sector FindSector(const Mask& fov);

struct LostSignal {
  Sector sector;
  Mask lost;             // 1 where contact was lost (inside the field of view); empty if none
  int64_t lost_voxels = 0;
  int64_t fov_voxels = 0;
  int judged_bins = 0;   // beam bins with enough slabs to be judged
  int lost_bins = 0;
};

// The beams of `image` inside `fov` along which only noise remains (header comment): one
// view, which gives the level of noise alone itself.
LostSignal FindLostSignal(const Image& image, const Mask& fov);

// The same for the views of one acquisition, with the level of noise alone they share
// (header comment); `num_threads` views at a time (0: every hardware thread).
std::vector<LostSignal> FindLostSignalInViews(const std::vector<Image>& images,
                                              const std::vector<Mask>& fovs,
                                              int num_threads);

}  // namespace dsr

#endif  // DSR_GEOMETRY_LOST_SIGNAL_H_
