// The panorama grid and the closed-form panorama (docs/design.md section 2; paper eq. 10).
//
// Grid: axis-aligned in world (identity direction), spacing = frame 0 spacing times
// `spacing_factor`, extent = the bounding box of every frame's valid field of view mapped
// to world by the given poses; the origin sits half a voxel off frame 0's lattice on every
// axis when frame 0's axes are world axes (docs/design.md section 2.5). Voxel centres are
// p_j = origin + spacing .* ijk.
#ifndef DSR_MODEL_PANORAMA_H_
#define DSR_MODEL_PANORAMA_H_

#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "dsr/geometry/volume.h"
#include "dsr/image/frame.h"
#include "dsr/model/observation.h"
#include "dsr/model/photometric.h"

namespace dsr {

// Panoramas above this many voxels are refused (a wrong pose or spacing, not a real case).
constexpr int64_t kMaxPanoramaVoxels = int64_t{1} << 31;

// The coarsest panorama spacing that still resolves frame 0: a panorama voxel (frame 0's
// smallest spacing times `spacing_factor`) of at most an eighth of frame 0's shortest
// extent. False with `error` naming panorama_spacing and the largest factor allowed.
bool CheckPanoramaSpacing(const ImageGeometry& frame0, double spacing_factor, std::string* error);

// Where the registration's panorama grid samples frame 0, whose lattice it is built on
// (docs/design.md section 2.5), when frame 0's axes are world axes (otherwise the origin
// is the fields of view's box corner, and kAllPhases still sweeps the phases; the
// registration's mean gauge builds its grids so, on the frames' mean frame):
//   kHalfVoxel  half a voxel off frame 0's lattice on every axis, at every voxel: frame 0's
//               samples are averages of its 8 neighbours (the default; best where the
//               frames' fine detail is independent noise, as in the paper's protocol);
//   kAllPhases  at every sub-voxel phase, like any other frame: the grid's spacing is
//               frame 0's times (1 + 1/n) on every axis, n frame 0's longest valid extent in
//               voxels, so that the phase sweeps [0, 1) once across frame 0's longest axis
//               (for texture the frames share, such as ultrasound speckle, where smoothing
//               frame 0 alone and not the others biases every frame-0-relative pose).
enum class PanoramaSampling {
  kHalfVoxel,
  kAllPhases,
};
// "half_voxel" / "all_phases" (the tools' --panorama_sampling values).
constexpr const char* PanoramaSamplingToString(PanoramaSampling sampling) {
  return sampling == PanoramaSampling::kAllPhases ? "all_phases" : "half_voxel";
}
// The inverse of PanoramaSamplingToString; false (and *sampling untouched) otherwise.
bool StringToPanoramaSampling(const std::string& name, PanoramaSampling* sampling);

// Builds the grid: the world's axes, spacing frame 0's times `spacing_factor` (times the
// factor of kAllPhases), covering every frame's valid field of view at the poses. Fails
// when a frame has no valid cell or the grid would exceed kMaxPanoramaVoxels (error names
// the spacing and the extent).
bool BuildPanoramaGrid(const std::vector<Frame>& frames,
                       const std::vector<Eigen::Isometry3d>& frame_from_world,
                       double spacing_factor,
                       ImageGeometry* grid,
                       std::string* error,
                       PanoramaSampling sampling = PanoramaSampling::kHalfVoxel);

struct PanoramaImages {
  Image mean;        // mu_j = (1/k_j) sum_i sigma_ij I_i(p_ij); 0 where k_j = 0
  Volume<uint8_t> count;  // k_j, number of frames observing each voxel
  int64_t seen_voxels = 0;    // voxels with k_j >= 1
  int64_t frame0_voxels = 0;  // voxels frame 0 observes
  // Field-of-view enlargement as the paper reports it: voxels seen by any frame / voxels
  // in frame 0's field of view (0 when frame 0 sees none).
  double EnlargementRatio() const {
    return frame0_voxels > 0 ? static_cast<double>(seen_voxels) / frame0_voxels : 0.0;
  }
};

// Closed-form panorama over every voxel of `grid` (not only candidates): each frame's
// valid samples at the given poses, averaged. Multithreaded over slabs, deterministic.
// With `photometric` (one per frame; empty: none) each sample of frame i is corrected to
// c_ij = gain_i I_i(p_ij) + offset_i first (frame 0's intensity scale, docs/design.md
// section 2.8) and weighted by u_i^2 = 1 / gain_i^2, so mean = sum_i sigma_ij u_i^2 c_ij /
// sum_i sigma_ij u_i^2, the model's closed-form intensity. Without it (or with the gauge
// on every frame) the result is bit for bit the uncorrected mean.
PanoramaImages FusePanoramaMean(const std::vector<Frame>& frames,
                                const std::vector<Eigen::Isometry3d>& frame_from_world,
                                const ImageGeometry& grid,
                                int num_threads,
                                const std::vector<Photometric>& photometric = {});

// Feathered panorama: the observations weighted by how deep they lie inside their frame's
// field of view, w_ij = min(1, d_i(p_ij) / feather_voxels), with d_i the city-block
// distance (frame voxels, trilinearly interpolated) from a valid cell to the nearest
// invalid one. Weights fall to zero towards each field-of-view edge, so the seams of the
// mean panorama vanish; with feather_voxels <= 0 every weight is 1 and this is the mean.
// `mean` holds sum w I / sum w; `count` and the voxel counts are as for the mean.
// `photometric` corrects and weights each sample as for FusePanoramaMean
// (sum w u^2 c / sum w u^2).
PanoramaImages FusePanoramaFeather(const std::vector<Frame>& frames,
                                   const std::vector<Eigen::Isometry3d>& frame_from_world,
                                   const ImageGeometry& grid,
                                   double feather_voxels,
                                   int num_threads,
                                   const std::vector<Photometric>& photometric = {});

// Fusion of whole images (dsr_fuse, the Python module), before the panorama is allocated:
// each image with its mask as a Frame (in parallel), each with at least one valid cell
// (else an error naming `names[i]`), the spacing checked against frame 0
// (CheckPanoramaSpacing), the poses made relative to frame 0 (`relative`), and the grid
// that covers every frame at them (BuildPanoramaGrid). False with a one-line `error`.
bool PrepareFusion(const std::vector<Image>& images,
                   const std::vector<Mask>& masks,
                   const std::vector<std::string>& names,
                   const std::vector<Eigen::Isometry3d>& frame_from_world,
                   double spacing_factor,
                   int num_threads,
                   std::vector<Frame>* frames,
                   std::vector<Eigen::Isometry3d>* relative,
                   ImageGeometry* grid,
                   std::string* error);

// FusePanoramaFeather when `feather`, else FusePanoramaMean.
PanoramaImages FusePanorama(const std::vector<Frame>& frames,
                            const std::vector<Eigen::Isometry3d>& frame_from_world,
                            const ImageGeometry& grid,
                            bool feather,
                            double feather_voxels,
                            int num_threads,
                            const std::vector<Photometric>& photometric = {});

// The fused panorama as a Frame in world coordinates (what a frame is registered to, in the
// sequential baseline and in recovery): the mean image, with the voxels some frame observes
// (count > 0) as its field of view, unobserved gaps included as outside. Frame's gradients
// never read outside it (image/frame.h), so no erosion is needed.
Frame PanoramaAsFrame(const PanoramaImages& fused);

// Frame resampled onto `grid` under its pose: its trilinear value where sigma = 1, else 0.
Image ResampleOntoGrid(const Frame& frame,
                       const Eigen::Isometry3d& frame_from_world,
                       const ImageGeometry& grid,
                       int num_threads);

// City-block distance of each valid cell of `frame` to the nearest invalid cell (or the
// grid border), in cells; 0 on invalid cells. On the frame's grid.
Volume<float> ValidCellDistance(const Frame& frame);

}  // namespace dsr

#endif  // DSR_MODEL_PANORAMA_H_
