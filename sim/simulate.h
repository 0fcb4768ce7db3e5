// The paper's simulation protocol (DESIGN.md section 6): frames cut from a source volume
// with a TEE-like pyramidal field of view at random rigid poses, intensities 0..255,
// additive Gaussian noise inside the field of view, zero outside.
//
// Frame geometry: `frame_size` voxels, isotropic spacing s (frame_spacing_mm, or the
// source's spacing along its first axis), origin 0, identity direction: the probe's own
// coordinates. The pyramid's apex is the centre of the k = 0 face, depth runs along +k.
// A voxel (i, j, k) is in the field of view when
//   k >= min_depth_voxels,  |i - cx| <= k tan(azimuth/2),  |j - cy| <= k tan(elevation/2),
// with cx = (size_x - 1)/2, cy = (size_y - 1)/2 (the spacing is isotropic, so the test in
// mm from the apex is the same in voxels).
//
// Poses (T_i = frame_from_world, world = the source's physical space, mm):
//   frame_from_world_i = Translate(c_f) * R_i * Translate(t_i - c_s)
// with c_f the frame grid's physical centre, c_s the source grid's physical centre,
// R_i = Rz(gamma) Ry(beta) Rx(alpha) with the three Euler angles uniform in
// [-max_rotation_deg, +max_rotation_deg], and t_i uniform in
// [-max_translation_voxels, +max_translation_voxels] * s per world axis. So the frame centre
// sees the world point c_s - t_i and the frame is rotated about it. Every frame, frame 0
// included, gets a random pose; consumers re-express poses relative to frame 0 (DESIGN.md
// section 1: world = frame 0). Draw order from std::mt19937_64(seed): per frame alpha,
// beta, gamma, t_x, t_y, t_z; then the noise of frame 0, 1, ... in voxel order.
//
// Intensities: the source's trilinear value at world_from_frame * x (Frame::InterpolateValue
// on an all-ones mask), plus N(0, noise_sigma), clamped to 0..255, for field-of-view
// voxels; 0 outside. Simulate fails if a field-of-view voxel maps outside the source grid.
//
// Masks: the field of view eroded by 1 voxel (6-neighbourhood; voxels on the grid border are
// dropped too). The registration reads central-difference gradients at the 8 corners of a
// valid trilinear cell, i.e. the 6 neighbours of mask voxels: with the erosion these are
// always field-of-view voxels, never the zeros outside the pyramid.
#ifndef DSR_SIM_SIMULATE_H_
#define DSR_SIM_SIMULATE_H_

#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "core/volume.h"

namespace dsr {

struct SimulationOptions {
  int num_frames = 11;                   // >= 2 (the paper: 11)
  double max_rotation_deg = 12.0;        // per Euler angle, in [0, 180]
  double max_translation_voxels = 15.0;  // per world axis, in frame voxels, >= 0
  double noise_sigma = 25.0;             // intensity units, >= 0
  uint64_t seed = 1;
  Eigen::Vector3i frame_size = Eigen::Vector3i(96, 96, 80);  // voxels, depth along k
  double frame_spacing_mm = 0.0;  // 0: the source's spacing along its first axis
  double azimuth_deg = 75.0;      // full opening angles of the pyramid, in (0, 180)
  double elevation_deg = 75.0;
  double min_depth_voxels = 4.0;  // near-field cut, in [0, frame_size[2] - 3]

  // Checks ranges and cross-field rules. The message names the dsr_simulate flag
  // (e.g. "--num_frames=1: must be in [2, 1000]").
  bool Validate(std::string* error) const;
};

struct SimulatedSequence {
  std::vector<Image> frames;  // on the frame grid, 0..255, 0 outside the FOV
  std::vector<Mask> masks;    // eroded field of view (identical for all frames)
  std::vector<Eigen::Isometry3d> frame_from_world;  // world = the source's physical space
};

// The frame grid for `source` (see the header comment). options must be valid.
ImageGeometry SimulatedFrameGeometry(const ImageGeometry& source, const SimulationOptions& options);

// The pyramidal field of view on `frame` (before erosion), 1 inside.
Mask PyramidFieldOfView(const ImageGeometry& frame, const SimulationOptions& options);

// The mask written with each frame: `field_of_view` eroded by 1 voxel (6-neighbourhood),
// grid-border voxels removed.
Mask ErodeFieldOfView(const Mask& field_of_view);

// The ground-truth poses Simulate draws for `source` (the same first draws of the seeded
// generator). options must be valid.
std::vector<Eigen::Isometry3d> SimulatedPoses(const ImageGeometry& source,
                                              const SimulationOptions& options);

// Runs the protocol. Returns false with a one-line `error` when options are invalid, the
// source is empty or has an invalid grid, the eroded field of view is empty, or a
// field-of-view voxel of some frame maps outside the source grid (source too small for
// these poses and this frame size). `sequence` is only written on success.
bool Simulate(const Image& source,
              const SimulationOptions& options,
              SimulatedSequence* sequence,
              std::string* error);

}  // namespace dsr

#endif  // DSR_SIM_SIMULATE_H_
