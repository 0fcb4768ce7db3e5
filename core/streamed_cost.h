// A Ceres residual block over every free pose whose normal equations are streamed, not
// stored (DESIGN.md section 4, "fast path"): shared by DSR's chunk cost and APE's.
//
// Evaluate() asks the subclass for the normal equations (H, g, f) of its voxels at the
// current poses (core/voxel_stream.h) and returns a compressed residual r' with Jacobian R
// such that R^T R = H, R^T r' = g and |r'|^2 = f: R from the symmetric eigen-decomposition
// of H, plus one residual sqrt(max(0, f - |r'|^2)) with a zero Jacobian row. The
// Gauss-Newton / Levenberg-Marquardt model Ceres builds is then exactly the uncompressed
// one, and nothing per observation is kept (the idea of square-root bundle adjustment's
// landmark marginalisation).
//
// Parameter blocks: the poses of frames 1..m-1 in order (7 ambient each, core/se3.h);
// frame 0 is the constant pose given at construction (the gauge). num_residuals =
// 6 (m - 1) + 1.
#ifndef DSR_CORE_STREAMED_COST_H_
#define DSR_CORE_STREAMED_COST_H_

#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <ceres/ceres.h>

#include "core/frame.h"
#include "core/solve_options.h"
#include "core/voxel_stream.h"

namespace dsr {

// r' (n + 1) and R ((n + 1) x n) for normal equations over n tangent parameters.
void CompressNormalEquations(const Eigen::MatrixXd& hessian,
                             const Eigen::VectorXd& gradient,
                             double cost,
                             Eigen::VectorXd* residual,
                             Eigen::MatrixXd* jacobian);

class StreamedPoseCost : public ceres::CostFunction {
 public:
  StreamedPoseCost(int num_frames, const Eigen::Isometry3d& frame0_from_world);
  bool Evaluate(double const* const* parameters,
                double* residuals,
                double** jacobians) const final;
  // Intensity differences of the latest evaluation (NormalEquations::observations). Ceres
  // evaluates the few streamed blocks from one thread (the solvers set num_threads = 1 and
  // thread inside the stream), so a plain member is safe.
  int64_t last_observations() const { return last_observations_; }

 protected:
  // Normal equations over all m frames (6m x 6m) at `frame_from_world` (frame 0 first).
  virtual void Accumulate(const std::vector<Eigen::Isometry3d>& frame_from_world,
                          bool with_jacobian,
                          NormalEquations* out) const = 0;

 private:
  int num_frames_;
  Eigen::Isometry3d frame0_from_world_;
  mutable int64_t last_observations_ = 0;
};

// Solves min over the poses of frames 1..m-1 (frame 0 constant) of the sum of the
// streamed blocks `make_block(begin, end)` returns for `num_blocks` equal ranges of
// [0, num_voxels): Ceres with a dense linear solver (or solve.linear_solver), the progress
// line labelled `label`, and the shared pose stopping rule (core/convergence.h). A solve
// that runs but is not usable returns true with report->usable = false.
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

#endif  // DSR_CORE_STREAMED_COST_H_
