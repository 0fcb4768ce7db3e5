// The observation model shared by every solver mode (docs/design.md section 2).
//
// Code names -> docs/design.md symbols:
//   voxel_center_in_world   p_j       panorama voxel centre (world = frame 0 physical, mm)
//   frame_from_world[i]     T_i       pose of frame i (world -> frame i physical)
//   sample_in_frame         p_ij      = T_i p_j
//   intensity               I_i(p_ij) trilinear value
//   jacobian                J_ij      = grad I_i(p_ij)^T [I_3, -[p_ij]x]   (1x6, [rho; phi])
//   observed                sigma_ij  p_ij in a valid cell of frame i: its 8 corners are
//                                     voxels that, with their 6 neighbours, lie inside
//                                     frame i's mask (image/frame.h, docs/design.md 2.3)
//
// The candidate rule (the one rule every mode uses, so all modes minimise the same
// function): at the poses a solve starts from, frame i is a candidate observer of voxel j
// when p_ij falls within `margin` cells of frame i's valid region; only voxels with at
// least two candidate observers enter the problem. During the solve the candidates are
// fixed and sigma_ij is re-evaluated at the current poses. A coarse-to-fine or outer loop
// rebuilds the candidates at the start of each solve with this same rule.
#ifndef DSR_MODEL_OBSERVATION_H_
#define DSR_MODEL_OBSERVATION_H_

#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "dsr/geometry/se3.h"
#include "dsr/geometry/volume.h"
#include "dsr/image/frame.h"

namespace dsr {

// Maximum number of frames: candidate observers are stored as one bit per frame.
constexpr int kMaxFrames = 32;

// Samples frame i at world point p_j under T_i. Returns sigma_ij; when false, the outputs
// are untouched. `jacobian` (d I_i(p_ij) / d delta_i) may be null.
inline bool ObserveSample(const Frame& frame,
                          const Eigen::Isometry3d& frame_from_world,
                          const Eigen::Vector3d& voxel_center_in_world,
                          double* intensity,
                          RowVector6d* jacobian) {
  const Eigen::Vector3d sample_in_frame = frame_from_world * voxel_center_in_world;
  Eigen::Vector3d gradient_mm;
  if (!frame.Sample(sample_in_frame, intensity, jacobian ? &gradient_mm : nullptr)) {
    return false;
  }
  if (jacobian != nullptr) {
    jacobian->head<3>() = gradient_mm.transpose();
    // g^T (-[p]x) = (p x g)^T
    jacobian->tail<3>() = sample_in_frame.cross(gradient_mm).transpose();
  }
  return true;
}

// Candidate observations (see the rule above). Voxels are listed in increasing panorama
// linear index; `observers[v]` has bit i set when frame i is a candidate for voxel v.
struct CandidateSet {
  ImageGeometry grid;  // the panorama grid
  int num_frames = 0;
  std::vector<int64_t> voxel;
  std::vector<uint32_t> observers;

  int64_t num_voxels() const { return static_cast<int64_t>(voxel.size()); }
  int64_t NumObservations() const;  // total candidate (i, j) pairs
  Eigen::Vector3d VoxelCenter(int64_t v) const;
};

// With keep_one_row_in > 1, only the voxels of 1 in keep_one_row_in of the grid's rows (along
// its x axis): rows (j, k) with j + 7 k a multiple of it, spread evenly over every slice, for
// estimates that need far fewer observations than the solves (the brightness detection).
CandidateSet BuildCandidates(const std::vector<Frame>& frames,
                             const std::vector<Eigen::Isometry3d>& frame_from_world,
                             const ImageGeometry& grid,
                             int margin_cells,
                             int keep_one_row_in = 1);

// The candidates in every `keep_one_in`-th cube of `cube` voxels on a side: those whose cube
// indices (along x, y and z) sum to a multiple of keep_one_in, spread evenly over the grid.
// Whole cubes, so that statistics clustered in such cubes (the pose uncertainty's) keep
// their clusters; about 1 / keep_one_in of the voxels, for estimates that need far fewer
// observations than the solves.
CandidateSet CandidatesInCubes(const CandidateSet& candidates, int cube, int keep_one_in);

// The candidates in 1 row in keep_one_row_in of the grid's rows (along its x axis), the rows
// BuildCandidates keeps with that argument (j + 7 k a multiple of it): whole rows, for
// statistics over neighbours along a row (the structure check's lag pairs).
CandidateSet CandidatesInRows(const CandidateSet& candidates, int keep_one_row_in);

// Number of candidate voxels shared by each pair of frames (m x m, symmetric; diagonal =
// voxels each frame is a candidate for). Used to report disconnected frames.
Eigen::MatrixXi CandidateOverlap(const CandidateSet& candidates);

// Checks that the overlap graph (edge when two frames share >= `min_shared_voxels`
// candidate voxels) connects every frame; otherwise `error` names the frames that are
// not connected to frame 0.
bool CheckConnected(const CandidateSet& candidates,
                    int64_t min_shared_voxels,
                    std::string* error);
// The same on an overlap matrix already computed by CandidateOverlap.
bool CheckConnected(const Eigen::MatrixXi& overlap,
                    int64_t min_shared_voxels,
                    std::string* error);
// The frames that overlap graph does not connect to frame 0 (increasing; empty when it
// connects every frame).
std::vector<int> FramesNotConnected(const Eigen::MatrixXi& overlap, int64_t min_shared_voxels);
// "frame 2" or "frames 1,3,4" (messages naming frames; `frames` non-empty).
std::string FramesPhrase(const std::vector<int>& frames);

// Re-expresses poses so that world = frame 0's physical space: T_i <- T_i T_0^-1.
std::vector<Eigen::Isometry3d> RelativeToFrame0(
    const std::vector<Eigen::Isometry3d>& frame_from_world);

}  // namespace dsr

#endif  // DSR_MODEL_OBSERVATION_H_
