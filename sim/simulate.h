// The paper's simulation protocol (DESIGN.md section 6): frames cut from a source volume
// with a TEE-like pyramidal field of view at random rigid poses, intensities 0..255,
// additive Gaussian noise inside the field of view, zero outside.
//
// Frame geometry: `frame_size` voxels, isotropic spacing, origin 0, identity direction
// (the probe's own coordinates). The pyramid's apex is the centre of the k = 0 face, depth
// runs along +k; a voxel is inside when depth >= min_depth and its lateral offsets satisfy
// |x - cx| <= depth tan(azimuth/2), |y - cy| <= depth tan(elevation/2).
// Poses: frame_from_world = Translate(frame centre) * Exp(random) * Translate(-source
// centre): each frame's centre sees the source centre up to a random rotation (Euler
// angles uniform in +/-max_rotation_deg) and translation (uniform in +/-max_translation
// voxels per axis). Every frame, frame 0 included, gets a random pose; world = the
// source's physical space.
// Masks: the field of view eroded by 1 voxel, so central-difference gradients used by the
// registration never read voxels outside the field of view.
#ifndef DSR_SIM_SIMULATE_H_
#define DSR_SIM_SIMULATE_H_

#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "core/volume.h"

namespace dsr {

struct SimulationOptions {
  int num_frames = 11;
  double max_rotation_deg = 12.0;
  double max_translation_voxels = 15.0;
  double noise_sigma = 25.0;
  uint64_t seed = 1;
  Eigen::Vector3i frame_size = Eigen::Vector3i(96, 96, 80);
  double frame_spacing_mm = 0.0;  // 0: the source's spacing along its first axis
  double azimuth_deg = 75.0;      // full opening angles of the pyramid
  double elevation_deg = 75.0;
  double min_depth_voxels = 4.0;  // near-field cut
  bool Validate(std::string* error) const;
};

struct SimulatedSequence {
  std::vector<Image> frames;
  std::vector<Mask> masks;
  std::vector<Eigen::Isometry3d> frame_from_world;
};

// The field-of-view mask of a frame grid (before erosion).
Mask PyramidFieldOfView(const ImageGeometry& frame_geometry, const SimulationOptions& options);

// Fails when a field-of-view voxel would sample outside the source (source too small for
// these poses and frame size).
bool Simulate(const Image& source,
              const SimulationOptions& options,
              SimulatedSequence* sequence,
              std::string* error);

}  // namespace dsr

#endif  // DSR_SIM_SIMULATE_H_
