// The gains and offsets that best explain the frames at fixed poses (docs/design.md section
// 2.8), without Ceres: the minimiser of DSR's cost with photometric parameters over them
// alone, by variable projection on the frames' samples held in memory.
//
// DSR's photometric residual of frame a at voxel j is r_aj = I_aj - u_a (mu_j - b_a), with
// u_a = 1 / g_a and mu_j the u^2-weighted mean of the corrected observations g_c I_cj + b_c
// (dsr_reduced/reduced_cost.h). Written as alpha_a = u_a and beta_a = -u_a b_a, that is
//   r_aj = I_aj - alpha_a P_j - beta_a,   P_j = sum_c alpha_c (I_cj - beta_c) / sum_c alpha_c^2,
// the residual of frame a's samples as an affine function of a panorama P that is eliminated
// (P_j is the minimiser over P of the voxel's squared residuals, and equals mu_j): the cost is
// the variable projection of a problem linear in (alpha_a, beta_a) for fixed P. Gauss-Newton
// on the projected problem (the Schur complement of P, as the theorem has it for the poses,
// docs/design.md section 4) with z_j = [P_j, 1]:
//   H_ab = sum_j (delta_ab - alpha_a alpha_b / S_j) z_j z_j^T,   S_j = sum_c alpha_c^2,
//   g_a  = -sum_j r_aj z_j,
// frame 0 held at alpha = 1, beta = 0 (the gauge). The samples are taken once (the stream's
// sampler, values only) and every iteration is a pass over them in memory. Its slow twin is
// SolvePhotometricAtPoses (dsr_reduced/dsr_solver.h): one Ceres solve of the same cost.
//
// The estimate's covariance is the sandwich H^-1 (sum_B g_B g_B^T) H^-1 over cubes B of 8
// panorama voxels (robust to the correlation resampling puts between neighbouring residuals,
// as the pose uncertainty's, pipeline/uncertainty.h), at the minimiser.
#ifndef DSR_DSR_REDUCED_PHOTOMETRIC_AT_POSES_H_
#define DSR_DSR_REDUCED_PHOTOMETRIC_AT_POSES_H_

#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "dsr/image/frame.h"
#include "dsr/model/observation.h"
#include "dsr/model/photometric.h"
#include "dsr/stream/voxel_stream.h"

namespace dsr {

struct PhotometricEstimate {
  std::vector<Photometric> photometric;  // per frame; frame 0: gain 1, offset 0
  // Covariance of (alpha_a, beta_a) of frames 1..m-1 (2(m - 1) square, frame a's pair at
  // 2 (a - 1)): see above.
  Eigen::MatrixXd covariance;
  double cost = 0.0;  // sum of squared residuals at the estimate
  int64_t voxels = 0;
  int64_t observations = 0;
  int iterations = 0;
  bool converged = false;
  // The change the estimate makes to frame i's intensities at x (on frame 0's scale less
  // x: gain x + offset - x) and its standard error from `covariance`.
  double Change(int frame, double x) const;
  double ChangeStandardError(int frame, double x) const;
};

// The estimate above at `frame_from_world` over `candidates` (frames of T phases: every
// phase's samples, one pose and one gain and offset per view). False, with `error`, when
// the samples do not determine it (a frame with fewer than 3 observations, or a singular
// Gauss-Newton matrix). Gauss-Newton starts from `start` when given (one per frame: an
// estimate on fewer rows, which leaves fewer passes to go), else from gain 1 and offset 0.
bool EstimatePhotometricAtPoses(const std::vector<Frame>& frames,
                                const CandidateSet& candidates,
                                const std::vector<Eigen::Isometry3d>& frame_from_world,
                                const StreamContext& context,
                                PhotometricEstimate* estimate,
                                std::string* error,
                                const std::vector<Photometric>* start = nullptr);

}  // namespace dsr

#endif  // DSR_DSR_REDUCED_PHOTOMETRIC_AT_POSES_H_
