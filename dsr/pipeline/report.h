// Pictures and a report folder that show whether a registration is right (like
// the paper's Fig. 2 and Fig. 3), plus per-frame ITK transforms for other tools.
//
//   panorama_slices.png  three orthogonal slices through the panorama's centre with the
//                        outlines of chosen frames' fields of view in colour (Fig. 3)
//   pair_AA_BB.png       two frames on a slice through their overlap, before and after
//                        registration: a checkerboard and a magenta/green overlay (Fig. 2)
//   convergence.png      cost and step norm per iteration over every solve
//   transforms/frame_XX.tfm, poses.json, index.md (links the pictures, lists the poses and,
//                        with ground truth, the per-frame errors)
#ifndef DSR_PIPELINE_REPORT_H_
#define DSR_PIPELINE_REPORT_H_

#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "dsr/eval/eval.h"
#include "dsr/geometry/volume.h"
#include "dsr/image/frame.h"
#include "dsr/image/picture.h"
#include "dsr/io/io_poses.h"
#include "dsr/model/photometric.h"
#include "dsr/pipeline/registration_result.h"

namespace dsr {

// Grey panorama slices (window: 1st..99th percentile of the seen voxels) with the
// field-of-view outline of each frame in `outlined` drawn in its own colour.
Picture RenderPanoramaSlices(const Image& panorama,
                             const std::vector<Frame>& frames,
                             const std::vector<Eigen::Isometry3d>& frame_from_world,
                             const std::vector<int>& outlined);

// Frames a and b on the axial panorama slice through the centre of their overlap (at the
// `after` poses): top row before (poses `before`), bottom row after; left a checkerboard of
// 8-pixel tiles alternating a and b, right a colour overlay (a magenta, b green: aligned
// structures turn grey). With `photometric` (one per frame; empty: none) both frames are
// shown corrected to frame 0's intensity scale (gain I + offset) in both rows, so that the
// picture compares their geometry, not their brightness.
Picture RenderPairComparison(const std::vector<Frame>& frames,
                             int a,
                             int b,
                             const std::vector<Eigen::Isometry3d>& before,
                             const std::vector<Eigen::Isometry3d>& after,
                             const ImageGeometry& grid,
                             const std::vector<Photometric>& photometric = {});

// Cost (log scale) and step norm per iteration over every solve, in solve order; solves
// are separated by vertical lines.
Picture RenderConvergence(const std::vector<LevelSolve>& solves);

struct ReportInputs {
  std::vector<std::string> image_names;
  std::vector<Frame> frames;  // full resolution
  std::vector<Eigen::Isometry3d> initial;  // relative to frame 0
  const RegistrationResult* result = nullptr;
  Image panorama;  // on result->grid, or DBA's intensities on their own (Image::geometry)
  std::vector<int> outlined;  // frames outlined on the panorama slices
  int pair_a = 0, pair_b = 1;
  const PoseErrorSummary* errors = nullptr;  // ground-truth errors, or null
  std::string mode;
};
// With photometric parameters (result->photometric not empty) the pair picture shows
// corrected intensities, poses.json carries each frame's "gain" and "offset" and index.md
// lists them; `panorama` should then be fused from corrected intensities too.

// Fills poses->gain and ->offset from per-frame photometric parameters (both emptied when
// `photometric` is empty): the poses file's convention is the pipeline's, frame i's
// corrected intensity gain * I_i + offset on frame 0's scale (io/io_poses.h).
void PhotometricToPoses(const std::vector<Photometric>& photometric, PosesFile* poses);

// The poses file of a registration: its poses under `image_names`, the pose covariance and
// predicted TRE when estimated, and the gains and offsets when estimated.
PosesFile ResultPoses(const RegistrationResult& result,
                      const std::vector<std::string>& image_names);

// The files WriteReport writes, relative to its folder, in the order it writes them (the
// tools plan their outputs with it): panorama_slices.png, pair_AA_BB.png, convergence.png,
// poses.json, transforms/frame_XX.tfm for each of `num_frames` frames, index.md.
std::vector<std::string> ReportFiles(int num_frames, int pair_a, int pair_b);

// Writes the report folder (created if missing); every file atomically. Returns the path
// of index.md in `index_path`.
bool WriteReport(const std::string& dir,
                 const ReportInputs& inputs,
                 std::string* index_path,
                 std::string* error);

}  // namespace dsr

#endif  // DSR_PIPELINE_REPORT_H_
