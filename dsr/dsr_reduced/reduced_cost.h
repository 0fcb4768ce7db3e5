// DSR: the reduced problem with the panorama intensities eliminated (docs/design.md section 4),
// as Ceres cost functions. The cost f(T), its photometric form, the weighted f_w of a
// robust loss and their streamed normal equations are in stream/reduced_system.h.
//
// Two cost functions:
//  * VoxelReducedCost: the faithful per-voxel reference (one residual per candidate
//    observer). Ceres stores its Jacobians, so it is for small problems and tests.
//  * ReducedChunkCost: the fast path. One residual block over all free poses streams a
//    range of voxels, accumulates H_c, g_c, f_c and returns a compressed residual r' and
//    Jacobian R with R^T R = H_c, R^T r' = g_c, |r'|^2 = f_c (R from the eigen-decomposition
//    of H_c plus one extra residual sqrt(f_c - |r'|^2) with a zero Jacobian row), so the
//    Gauss-Newton/LM model equals the uncompressed one. Nothing per observation is stored.
//
// Both have a weighted variant (f_w): the per-voxel reference with the voxel's weights,
// and the chunk cost with the weights of the whole candidate set. The chunk cost's passes
// are evaluated by a cost-evaluation backend (dsr_reduced/reduced_cost_backend.h; by
// default the CPU stream).
#ifndef DSR_DSR_REDUCED_REDUCED_COST_H_
#define DSR_DSR_REDUCED_REDUCED_COST_H_

#include <memory>
#include <vector>

#include <ceres/ceres.h>

#include "dsr/dsr_reduced/reduced_cost_backend.h"
#include "dsr/geometry/se3.h"
#include "dsr/image/frame.h"
#include "dsr/model/observation.h"
#include "dsr/model/photometric.h"
#include "dsr/model/robust_loss.h"
#include "dsr/stream/reduced_system.h"
#include "dsr/stream/streamed_cost.h"
#include "dsr/stream/voxel_stream.h"

namespace dsr {

// Reference: residuals r_ij for the candidate observers of one voxel. Parameter blocks are
// the observers' poses (7 ambient each) in increasing frame order. With `weights` (one per
// observer, > 0; empty: the plain cost), the weighted residuals r~_ij of f_w
// (stream/reduced_system.h).
class VoxelReducedCost final : public ceres::CostFunction {
 public:
  VoxelReducedCost(std::vector<const Frame*> observers,
                   const Eigen::Vector3d& voxel_center_in_world,
                   std::vector<double> weights = {});
  bool Evaluate(double const* const* parameters,
                double* residuals,
                double** jacobians) const override;

 private:
  std::vector<const Frame*> observers_;  // not owned
  Eigen::Vector3d voxel_center_in_world_;
  std::vector<double> weights_;
};

// The reference with photometric parameters (docs/design.md section 2.8): residuals in
// each observer's grey levels, r_i = u_i (c_i - mu) with c_i = a_i I_i(p_ij) + b_i,
// a_i = exp(log_gain_i), u_i = 1 / a_i and mu = sum u^2 c / S, S = sum u^2 over the voxel's
// observers. Parameter blocks: the observers' poses (7 ambient each), then their
// [log_gain, offset] blocks (2 each), both in increasing frame order. The Jacobian is the
// one with the intensity eliminated at M = mu (DBA's Schur complement):
//   d r_i / d delta_a = (delta_ia - u_i u_a / S) J_a,
//   d r_i / d [log_gain_a, b_a] = (delta_ia - u_i u_a / S) [u_a (mu - b_a), u_a];
// it is the full derivative of r projected off the direction u (r's own derivative also
// moves mu's weights), so J^T r is the exact gradient of |r|^2 / 2.
// With `weights` (one per observer, > 0; empty: unweighted), the weighted residuals.
class VoxelReducedPhotometricCost final : public ceres::CostFunction {
 public:
  VoxelReducedPhotometricCost(std::vector<const Frame*> observers,
                              const Eigen::Vector3d& voxel_center_in_world,
                              std::vector<double> weights = {});
  bool Evaluate(double const* const* parameters,
                double* residuals,
                double** jacobians) const override;

 private:
  std::vector<const Frame*> observers_;  // not owned
  Eigen::Vector3d voxel_center_in_world_;
  std::vector<double> weights_;
};

// Fast path: a chunk of voxels [begin, end) as one streamed residual block over the free
// poses (frames 1..m-1, in order, or 0..m-1 in the mean gauge; stream/streamed_cost.h) and,
// with `photometric`, the photometric blocks of frames 1..m-1 after them. In the frame-0
// gauge frame 0's pose is the constant `frame0_from_world`; its photometric parameters are
// the gauge in either. num_residuals = p (m - 1) + 1, p = 6 or 8. With
// `weights` (not owned; must not change while the block lives, since its passes are
// cached), the weighted cost f_w. `backend` evaluates every pass (null: the CPU one,
// DefaultReducedCostBackend); a pass it cannot evaluate fails that Ceres evaluation.
class ReducedChunkCost final : public StreamedPoseCost {
 public:
  ReducedChunkCost(const std::vector<Frame>* frames,
                   const CandidateSet* candidates,
                   const Eigen::Isometry3d& frame0_from_world,
                   int64_t begin,
                   int64_t end,
                   const StreamContext& context,
                   bool photometric = false,
                   const ObservationWeights* weights = nullptr,
                   Gauge gauge = Gauge::kFrame0,
                   std::shared_ptr<const ReducedCostBackend> backend = nullptr);

  // Writes r' and R (tangent columns, row-major (6(m-1)+1) x 6(m-1)) for a system.
  static void Compress(const Eigen::MatrixXd& hessian_free,
                       const Eigen::VectorXd& gradient_free,
                       double cost,
                       Eigen::VectorXd* residual,
                       Eigen::MatrixXd* jacobian) {
    CompressNormalEquations(hessian_free, gradient_free, cost, residual, jacobian);
  }

 private:
  void Accumulate(const std::vector<Eigen::Isometry3d>& frame_from_world,
                  const std::vector<Photometric>& photometric,
                  bool with_jacobian,
                  NormalEquations* out) const override;

  ReducedCostInputs inputs_;  // frames, candidates, weights (not owned) and the context
  int64_t begin_, end_;
  std::shared_ptr<const ReducedCostBackend> backend_;
};

}  // namespace dsr

#endif  // DSR_DSR_REDUCED_REDUCED_COST_H_
