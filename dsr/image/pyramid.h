// Gaussian image pyramid for coarse-to-fine registration.
//
// One level down: the image is smoothed with a Gaussian of standard deviation `sigma`
// (fine voxels, per axis) by normalised convolution inside the field of view,
//   I_s = G * (I M) / G * M,
// so that the field-of-view edge does not darken, then sampled at every second voxel:
// coarse voxel c sits at fine index 2c (same origin and direction, spacing doubled,
// size = floor((n - 1) / 2) + 1). The coarse image keeps the smoothed values wherever the
// smoothed mask is positive (a few voxels past the field of view, for resampling). The
// coarse mask is the fine mask at 2c: a coarse voxel is in the field of view when the fine
// voxel it sits on is, and its value is then a normalised average of field-of-view voxels.
// No erosion is added: Frame keeps every gradient, and so every valid cell, one voxel
// inside the mask at each level (image/frame.h), and an erosion here would compound level
// by level and cut the coarse levels' overlap. An axis with a single voxel is neither
// smoothed nor halved.
#ifndef DSR_IMAGE_PYRAMID_H_
#define DSR_IMAGE_PYRAMID_H_

#include <vector>

#include "dsr/geometry/volume.h"

namespace dsr {

struct ImageLevel {
  Image image;
  Mask mask;
  // A view's later phases at this level (docs/design.md section 12), on `image`'s grid:
  // phase p at later_phases[p - 1]; empty for a 3D frame.
  std::vector<Image> later_phases;
};

// The normalised 1-D Gaussian the smoothing uses, in float: radius max(1, ceil(3 sigma)),
// weights exp(-d^2 / (2 sigma^2)) over their double sum (index d + radius).
std::vector<float> GaussianKernel(double sigma);

// Smooths `image` inside `mask` by normalised convolution (see above) without
// resampling; voxels where the smoothed mask is 0 become 0. `sigma_voxels` <= 0 copies.
// Bit-identical for every num_threads (each output voxel is one thread's sum).
Image SmoothInsideMask(const Image& image, const Mask& mask, double sigma_voxels, int num_threads);

// The same with its own standard deviation along each index axis (sigma_voxels[a], voxels
// of axis a; <= 0: that axis is not smoothed; all <= 0 copies), e.g. a Gaussian of a given
// width in mm on an anisotropic grid (mm / spacing_mm[a]). With three equal values it is
// the single-sigma overload, bit for bit.
Image SmoothInsideMask(const Image& image,
                       const Mask& mask,
                       const Eigen::Vector3d& sigma_voxels,
                       int num_threads);

// One level down (see above).
ImageLevel Downsample(const Image& image, const Mask& mask, double sigma_voxels, int num_threads);

// Levels finest first: levels[0] = the input smoothed by `finest_sigma_voxels` when > 0,
// else empty (the input itself is the finest level: no copy of it is made);
// levels[l] = Downsample(level l-1). Stops early when an axis would drop below
// `min_size` voxels; returns at least one level.
std::vector<ImageLevel> BuildPyramid(const Image& image,
                                     const Mask& mask,
                                     int num_levels,
                                     double sigma_voxels,
                                     double finest_sigma_voxels,
                                     int min_size,
                                     int num_threads);

}  // namespace dsr

#endif  // DSR_IMAGE_PYRAMID_H_
