// A Ceres residual block over every free pose whose normal equations are streamed, not
// stored (docs/design.md section 4.6, the fast path): shared by DSR's chunk cost and APE's.
//
// Evaluate() asks the subclass for the normal equations (H, g, f) of its voxels at the
// current poses (stream/voxel_stream.h) and returns a compressed residual r' with Jacobian R
// such that R^T R = H, R^T r' = g and |r'|^2 = f: R from the symmetric eigen-decomposition
// of H, plus one residual sqrt(max(0, f - |r'|^2)) with a zero Jacobian row. The
// Gauss-Newton / Levenberg-Marquardt model Ceres builds is then exactly the uncompressed
// one, and nothing per observation is kept (the idea of square-root bundle adjustment's
// landmark marginalisation).
//
// Parameter blocks: the poses of frames 1..m-1 in order (7 ambient each, geometry/se3.h);
// frame 0 is the constant pose given at construction (the gauge). In the mean gauge
// (solve/gauge.h) frame 0's pose is a block too, first, and the pose gauge is a prior
// elsewhere in the problem. With photometric parameters (docs/design.md section 2.8), then
// the [log_gain, offset] blocks of frames 1..m-1 (frame 0's: the gauge, 0 and 0, in either
// pose gauge), and the subclass's normal equations have 8 parameters per frame (the pose
// tangent, log gain, offset). num_residuals = n + 1 with n = p (m - 1), p = 6 or 8, plus 6
// in the mean gauge.
#ifndef DSR_STREAM_STREAMED_COST_H_
#define DSR_STREAM_STREAMED_COST_H_

#include <algorithm>
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <ceres/ceres.h>

#include "dsr/image/frame.h"
#include "dsr/model/photometric.h"
#include "dsr/solve/gauge.h"
#include "dsr/solve/solve_options.h"
#include "dsr/stream/voxel_stream.h"

namespace dsr {

// r' (n + 1) and R ((n + 1) x n) for normal equations over n tangent parameters.
void CompressNormalEquations(const Eigen::MatrixXd& hessian,
                             const Eigen::VectorXd& gradient,
                             double cost,
                             Eigen::VectorXd* residual,
                             Eigen::MatrixXd* jacobian);

// How a streamed block reuses its passes over the voxels (each pass is the expensive part
// of an iteration). Ceres's trust-region loop evaluates the cost alone at a trial point
// and, when the step is accepted, the cost with Jacobians at the same point. So:
//  * speculate: a trial point's pass also computes the Jacobians (it reads the same data;
//    about 2x a cost-only pass) and keeps them; an accepted step then costs one pass, not
//    two. After a rejected step the next trial is evaluated cost-only, and speculation
//    resumes after the next accepted step.
//  * lazy final Jacobian (`lazy_final`): a trial point whose step leaves less than
//    `step_tolerance_voxels` still to go (RemainingMotionVoxels) ends the solve if it is
//    accepted (the rule of solve/convergence.h, which then stops Ceres before it uses the
//    Jacobians again). Its pass is cost-only, and the Jacobians Ceres asks for there are
//    those of the previous point with the new point's exact cost.
// Neither changes any cost Ceres sees or any pose it reaches (the cost-only and the
// Jacobian passes give bit-identical costs); tests compare solves with and without. Whether
// a trial would end the solve is measured whenever `frames` is set and
// step_tolerance_voxels > 0, reuse or not (last_trial_ends_solve).
struct StreamedEvaluationPolicy {
  bool speculate = false;
  bool lazy_final = false;
  const std::vector<Frame>* frames = nullptr;  // frame 0 first; not owned
  double step_tolerance_voxels = 0.0;
};

// Passes over the voxels a block made.
struct StreamedPassCounts {
  int jacobian_passes = 0;
  int cost_passes = 0;
};

// The policy the solvers give their blocks: the solve's frames and pose step tolerance,
// and speculation and lazy final Jacobians when solve.reuse_evaluations.
StreamedEvaluationPolicy EvaluationPolicyFor(const std::vector<Frame>& frames,
                                             const SolveOptions& solve);

// The threads and kernels a solve's streams run with.
inline StreamContext StreamContextFor(const SolveOptions& solve) {
  return {solve.num_threads, solve.kernels};
}

class StreamedPoseCost : public ceres::CostFunction {
 public:
  // `frame0_from_world` is not used in the mean gauge (frame 0's pose is a block).
  StreamedPoseCost(int num_frames, const Eigen::Isometry3d& frame0_from_world,
                   bool photometric = false, Gauge gauge = Gauge::kFrame0);
  bool Evaluate(double const* const* parameters,
                double* residuals,
                double** jacobians) const final;
  // Intensity differences of the latest evaluation (NormalEquations::observations). Ceres
  // evaluates the few streamed blocks from one thread (the solvers set num_threads = 1 and
  // thread inside the stream), so plain members are safe.
  int64_t last_observations() const { return last_observations_; }
  void set_policy(const StreamedEvaluationPolicy& policy) { policy_ = policy; }
  const StreamedPassCounts& pass_counts() const { return counts_; }
  // Whether the latest evaluation was a trial point that would end the solve if accepted
  // (the lazy final Jacobian's test, with the policy's frames and tolerance): for the pose
  // step rule's rejected steps (PoseStepCallback::SetTrialEndsSolve).
  bool last_trial_ends_solve() const { return last_was_cost_only_ && trial_ends_solve_; }
  // The latest pass when it was made at exactly these free parameters (the pose blocks,
  // 7 each, and with photometric parameters the 2 each of frames 1..m-1), else null: e.g.
  // the pass at the final poses of a solve, whose per-frame costs the caller may reuse.
  const NormalEquations* PassAt(const std::vector<const double*>& free_blocks,
                                const std::vector<const double*>& photometric_blocks = {}) const;
  bool photometric() const { return photometric_; }
  // Evaluates the block with Jacobians at `parameters` (laid out as Evaluate takes them) and
  // keeps the pass as the current point's, so that Ceres's first evaluation there reuses it:
  // for a caller that needs the normal equations at a solve's initial point before the
  // solve (DsrProblem: the mean gauge's stiffness). Returns the pass (cost NaN when it
  // failed).
  const NormalEquations& EvaluateWithJacobiansAt(double const* const* parameters) const;

 protected:
  // Normal equations over all m frames (p m x p m; p = 6, or 8 with photometric
  // parameters) at `frame_from_world` and `photometric` (frame 0 first; empty without
  // photometric parameters).
  virtual void Accumulate(const std::vector<Eigen::Isometry3d>& frame_from_world,
                          const std::vector<Photometric>& photometric,
                          bool with_jacobian,
                          NormalEquations* out) const = 0;

 private:
  // Writes the compressed residual and Jacobians of `system`; with `exact_cost`, |r'|^2
  // is its cost even when its model comes from another point.
  bool WriteJacobianEvaluation(const NormalEquations& system,
                               bool exact_cost,
                               double const* const* parameters,
                               double* residuals,
                               double** jacobians) const;

  int num_frames_;
  Eigen::Isometry3d frame0_from_world_;
  bool photometric_;
  int first_pose_block_frame_;  // 0 in the mean gauge, else 1
  int num_pose_blocks_;
  // The tangent parameters' positions in the subclass's (p m)-sized normal equations:
  // frames 1..m-1's, and frame 0's pose too in the mean gauge (never frame 0's photometric
  // parameters, the gauge).
  std::vector<int> kept_parameters_;
  StreamedEvaluationPolicy policy_;
  mutable int64_t last_observations_ = 0;
  mutable StreamedPassCounts counts_;
  // The latest pass: its parameters, its system, whether it holds Jacobians, and whether
  // it was a lazy final trial point.
  mutable std::vector<double> pass_parameters_;
  mutable NormalEquations pass_;
  mutable bool pass_has_jacobian_ = false;
  mutable bool pass_is_final_ = false;
  mutable bool trial_ends_solve_ = false;  // the latest trial's step, by the rule
  mutable double pass_motion_ = 0.0;  // the latest trial's step, in field-of-view voxels
  // The latest evaluation with Jacobians (the current accepted point) and its poses.
  mutable NormalEquations accepted_;
  mutable std::vector<Eigen::Isometry3d> accepted_poses_;
  mutable double accepted_motion_ = 0.0;  // the step that reached them (0: none)
  mutable bool last_was_cost_only_ = false;
  mutable bool speculate_next_ = true;
};

// Whether every block's latest trial would have ended the solve had it been accepted
// (StreamedPoseCost::last_trial_ends_solve): the pose step rule's test for a rejected step
// (PoseStepCallback::SetTrialEndsSolve), for the blocks of one solve.
template <class Cost>
bool EveryTrialEndsSolve(const std::vector<Cost*>& blocks) {
  return std::all_of(blocks.begin(), blocks.end(),
                     [](const Cost* block) { return block->last_trial_ends_solve(); });
}

// Solves min over the poses of frames 1..m-1 (frame 0 constant) of the sum of the
// streamed blocks `make_block(begin, end)` returns for `num_blocks` equal ranges of
// [0, num_voxels): Ceres with a dense linear solver (or solve.linear_solver), the progress
// line labelled `label`, and the shared pose stopping rule (solve/convergence.h). A solve
// that runs but is not usable returns true with report->usable = false. The blocks get the
// evaluation policy above when solve.reuse_evaluations.
using StreamedBlockFactory = std::function<StreamedPoseCost*(int64_t begin, int64_t end)>;
bool SolveStreamedPoses(const std::vector<Frame>& frames,
                        const std::vector<Eigen::Isometry3d>& initial_frame_from_world,
                        int64_t num_voxels,
                        int num_blocks,
                        const StreamedBlockFactory& make_block,
                        const SolveOptions& solve,
                        const std::string& label,
                        SolveReport* report,
                        std::string* error);

}  // namespace dsr

#endif  // DSR_STREAM_STREAMED_COST_H_
