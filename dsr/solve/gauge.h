// The gauge of a pose solve (docs/design.md sections 1 and 7.5): the cost does not change, or
// hardly, when every frame moves together, so one such motion must be fixed.
//  * kFrame0: frame 0's pose is a constant (the convention of every output).
//  * kMean: every frame's pose is free, and a prior on the frames' mean displacement since
//    the start of the solve (MeanPosePrior) holds their common motion. Its gradient is the
//    same in every frame's tangent at the start, so the reaction to whatever pushes all
//    frames together is shared by all of them rather than taken by frame 0 alone. The
//    solver re-expresses the result with frame 0 as the identity.
#ifndef DSR_SOLVE_GAUGE_H_
#define DSR_SOLVE_GAUGE_H_

#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <ceres/cost_function.h>

#include "dsr/geometry/se3.h"

namespace dsr {

enum class Gauge { kFrame0, kMean };

// "frame0" / "mean" (the tools' --gauge values).
constexpr const char* GaugeToString(Gauge gauge) {
  return gauge == Gauge::kMean ? "mean" : "frame0";
}
// The inverse of GaugeToString; false (and *gauge untouched) for any other text.
bool StringToGauge(const std::string& name, Gauge* gauge);

// Frame i's displacement in the world since `initial`: e_i = [T_i^-1 c - T_i0^-1 c; 2 v],
// the motion of its field of view's centre c (in frame i's coordinates) and, with (w, v) the
// unit quaternion of R_i0^T R_i taken with w >= 0, its rotation in the world (2 v is the
// rotation vector to first order). Moving every frame by one world motion G (T_i -> T_i G)
// gives every frame the same rotation part and, for a translation, the same centre part.
// With `tangent_jacobian`, its derivative with respect to T_i's left tangent:
// [-R^T, R^T [c]x; 0, (w I + [v]x) R^T].
Vector6d PoseDisplacement(const Eigen::Isometry3d& pose, const Eigen::Isometry3d& initial,
                          const Eigen::Vector3d& centre, Matrix6d* tangent_jacobian = nullptr);

// The frames' mean frame in the world, world_from_mean: its rotation is the chordal mean of
// the frames' orientations (the rotation nearest to sum_i R_i^T in the Frobenius norm, R_i
// frame_from_world's), its origin the mean of the world positions T_i^-1 centres[i]. Moving
// every frame by one world motion G (T_i -> T_i G) gives G^-1 times it; frames that share
// an orientation give that orientation. The registration's mean gauge builds each solve's
// panorama grid on it (pipeline/coarse_to_fine.h), so that the grid's axes and lattice are
// no one frame's.
Eigen::Isometry3d MeanFrame(const std::vector<Eigen::Isometry3d>& frame_from_world,
                            const std::vector<Eigen::Vector3d>& centres);

// The prior of Gauge::kMean: 6 residuals r = S (1/m) sum_i e_i (PoseDisplacement of each
// frame from its pose at construction, about `centres[i]`), S = diag(sqrt(stiffness)): the
// frames' mean centre and mean orientation stay put in the world. Parameter blocks: the m
// poses (7 ambient each, geometry/se3.h), frame 0 first. r = 0 at the initial poses.
class MeanPosePrior final : public ceres::CostFunction {
 public:
  MeanPosePrior(std::vector<Eigen::Isometry3d> initial_frame_from_world,
                std::vector<Eigen::Vector3d> centres,
                const Vector6d& stiffness);
  bool Evaluate(double const* const* parameters,
                double* residuals,
                double** jacobians) const override;

 private:
  std::vector<Eigen::Isometry3d> initial_;
  std::vector<Eigen::Vector3d> centres_;
  Vector6d sqrt_stiffness_;
};

// The stiffness of MeanPosePrior for normal equations `hessian` over m frames with p
// parameters each (pose tangent first): m times the mean diagonal of the frames' translation
// rows for the three translation rows, likewise for rotation. The prior then adds d / m to
// each frame's diagonal d (little damping in Levenberg-Marquardt's diag(J^T J) scaling) and
// curvature d along the common motion, which the data hardly constrain. A row whose data
// diagonal is 0 gets stiffness 1.
Vector6d MeanGaugeStiffness(const Eigen::MatrixXd& hessian, int num_frames, int p);

}  // namespace dsr

#endif  // DSR_SOLVE_GAUGE_H_
