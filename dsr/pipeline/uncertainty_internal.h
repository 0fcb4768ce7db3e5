// The pose uncertainty's helpers shared by its sources (uncertainty_sums.cc, uncertainty.cc,
// uncertainty_determination.cc): the cubes' edge, and the field-of-view points and the free
// poses' covariance, defined in uncertainty.cc. Not for use outside dsr/pipeline.
#ifndef DSR_PIPELINE_UNCERTAINTY_INTERNAL_H_
#define DSR_PIPELINE_UNCERTAINTY_INTERNAL_H_

#include <vector>

#include <Eigen/Core>

#include "dsr/geometry/se3.h"
#include "dsr/geometry/volume.h"
#include "dsr/pipeline/uncertainty.h"

namespace dsr {
namespace uncertainty_internal {

// Edge of the cubes the gradient's covariance is estimated over (panorama voxels).
constexpr int kClusterVoxels = 8;

// Points of `mask` in the physical coordinates of `g`, the frame's geometry (the mask's
// grid, in the pipeline's local coordinates).
std::vector<Eigen::Vector3d> FieldOfViewPoints(const Mask& mask, const ImageGeometry& g);

// The free poses' covariance fraction A^-1 C_g A^-T from the sums, leaving out group
// `left_out` (-1: none), over frames 1..m-1 (frame 0's rows dropped: the gauge). False
// when A is not positive definite (in *curvature: A over the free poses, when measured).
bool FreePoseCovariance(const UncertaintySums& sums,
                        int left_out,
                        Eigen::MatrixXd* covariance,
                        Eigen::MatrixXd* curvature = nullptr);

// Frame i's covariance block (6x6, symmetrised) of a free-pose covariance.
Matrix6d FrameCovariance(const Eigen::MatrixXd& covariance, int i);

}  // namespace uncertainty_internal
}  // namespace dsr

#endif  // DSR_PIPELINE_UNCERTAINTY_INTERNAL_H_
