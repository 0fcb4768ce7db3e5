// A stopping rule in image units, shared by every mode: a solve has converged when the
// distance still to go to its fixed point, estimated from its last accepted steps, moves no
// frame's field of view by more than a tolerance (in voxels), or when Levenberg-Marquardt /
// dogleg rejects several steps in a row (the cost no longer decreases measurably: at the
// noise floor, the Gauss-Newton model built from the interpolated gradient volumes no
// longer predicts the trilinear cost's change). docs/design.md 7.4.
//
// Ceres's own tolerances stay active; they are relative to the cost and to the parameter
// vector, whose size depends on where the world origin lies, so they are poor rules for
// poses. This one measures what a user cares about: how far the frames still move.
#ifndef DSR_SOLVE_CONVERGENCE_H_
#define DSR_SOLVE_CONVERGENCE_H_

#include <functional>
#include <string>
#include <vector>

#include <Eigen/Geometry>
#include <ceres/iteration_callback.h>
#include <ceres/solver.h>

#include "dsr/image/frame.h"

namespace dsr {

// Largest motion, in voxels of `frame`'s grid, of the corners of the frame's valid
// bounding box between two world->frame poses: max over corners x of |a (b^-1 x) - x|
// measured in index units (0 for a frame without valid cells).
double MaxCornerMotionVoxels(const Frame& frame,
                             const Eigen::Isometry3d& a,
                             const Eigen::Isometry3d& b);

// The largest MaxCornerMotionVoxels of frames 1..m-1 between two sets of poses, each taken
// relative to its frame 0 (T_i T_0^-1) when frame 0's pose differs between them (a solve in
// the mean gauge, solve/gauge.h): how far a step moved the fields of view against frame 0's.
double LargestMotionVoxels(const std::vector<Frame>& frames,
                           const std::vector<Eigen::Isometry3d>& a,
                           const std::vector<Eigen::Isometry3d>& b);

// The distance, in voxels of field-of-view motion, a solve still has to go after an
// accepted step that moved a field of view by at most `motion`, the accepted step before it
// having moved one by `previous_motion` (0: there was none). With noise, Gauss-Newton
// converges linearly near its fixed point (J^T J holds the noise gradients' energy, which
// the cost's curvature does not, so every step falls short by about the same fraction): each
// step is about rho times the one before, and the steps still to come add up to
// motion rho / (1 - rho). rho is motion / previous_motion clamped to [1/2, 19/20] (1/2 with
// no previous step), so the estimate lies between the step itself and 19 times it.
double RemainingMotionVoxels(double motion, double previous_motion);

// Terminates a Ceres solve by the rule above. `pose_blocks[i]` points to frame i's
// ambient pose parameters ([qx qy qz qw tx ty tz], geometry/se3.h); null for frame 0 when it
// is the gauge (not a parameter: the identity), and only for it. Requires
// Solver::Options::update_state_every_iteration.
class PoseStepCallback final : public ceres::IterationCallback {
 public:
  PoseStepCallback(const std::vector<Frame>* frames,
                   std::vector<const double*> pose_blocks,
                   double tolerance_voxels,
                   int max_rejected_steps);
  ceres::CallbackReturnType operator()(const ceres::IterationSummary& summary) override;
  // Adds this callback to `options` when the rule is on (a tolerance > 0 or a rejection
  // limit > 0), with update_state_every_iteration, which the rule needs.
  void AddTo(ceres::Solver::Options* options);
  // With a tolerance: `trial_ends_solve` says whether the step Ceres just tried would have
  // ended the solve by the rule had it been accepted (the streamed blocks measure it:
  // stream/streamed_cost.h). A rejected such step ends it too: the model's step from the
  // current poses is already within the tolerance of its fixed point, and Levenberg-Marquardt
  // only shortens the next ones (on the paper's clinical-size sequence, four more rejected
  // steps of the same length, each an evaluation, ended level 1 at the same poses).
  void SetTrialEndsSolve(std::function<bool()> trial_ends_solve) {
    trial_ends_solve_ = std::move(trial_ends_solve);
  }
  // Why it stopped the solve; empty when it did not.
  const std::string& reason() const { return reason_; }

 private:
  std::vector<Eigen::Isometry3d> Current() const;

  const std::vector<Frame>* frames_;
  std::vector<const double*> pose_blocks_;
  double tolerance_voxels_;
  int max_rejected_steps_;
  std::vector<Eigen::Isometry3d> previous_;
  double previous_motion_ = 0.0;  // the last accepted step's motion (0: none yet)
  int rejected_in_a_row_ = 0;
  std::function<bool()> trial_ends_solve_;
  std::string reason_;
};

}  // namespace dsr

#endif  // DSR_SOLVE_CONVERGENCE_H_
