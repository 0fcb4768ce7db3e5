// The reduced normal equations: DSR's cost with the panorama intensities eliminated
// (docs/design.md section 4), streamed over the candidate voxels (stream/voxel_stream.h).
// A layer below the solvers because several read it: DSR minimises the cost
// (dsr_reduced/), the theorem (docs/design.md 4.3) makes its Gauss-Newton matrix DBA's Schur
// complement onto the poses, so DBA's mean gauge takes its prior's stiffness from it (dba/),
// and the pipeline's checks measure the poses with it.
//
// For fixed poses the optimal panorama is mu_j = (1/k_j) sum_i sigma_ij I_i(p_ij) (paper
// eq. 10); substituting it gives
//     f(T) = sum_j sum_i sigma_ij (I_i(p_ij) - mu_j)^2,   r_ij = I_i(p_ij) - mu_j,
//     d r_ij / d delta_a = sigma_aj (delta_ia - 1/k_j) J_aj,
//     H_ab = sum_j (delta_ab - 1/k_j) J_aj^T J_bj,   g_a = sum_j J_aj^T r_aj,
// over voxels with k_j >= 2 (others contribute nothing). Candidates follow the rule of
// model/observation.h, shared with DBA, so both modes minimise the same function.
//
// With photometric parameters (docs/design.md section 2.8) frame i's observation is
// corrected to c_ij = g_i I_i(p_ij) + b_i and its residual is in its own grey levels,
// r_ij = u_i (c_ij - mu_j) with u_i = 1 / g_i and mu_j = sum_i u_i^2 c_ij / sum_i u_i^2.
//
// With a robust loss (docs/design.md section 4.7) DSR solves by iteratively reweighted
// least squares: weights w_ij, fixed during one solve (ObservationWeights), give the
// weighted reduced cost
//     f_w(T) = sum_j sum_i w_ij u_i^2 (c_ij - mu_j)^2,   mu_j = sum_i w_ij u_i^2 c_ij / V_j,
//     V_j = sum_i w_ij u_i^2
// (u_i = 1 and c_ij = I_i(p_ij) without photometric parameters), with
// r~_ij = sqrt(w_ij) u_i (c_ij - mu_j) and, R_a the observation's row (J_a, or with
// photometric parameters [J_a, u_a (mu - b_a), u_a]),
//     d r~_i / d x_a = sqrt(w_i) (delta_ia - u_i u_a w_a / V) R_a,
//     H_ab = (delta_ab w_a - w_a u_a w_b u_b / V) R_a^T R_b,   g_a = w_a r_a R_a,
// r_a = u_a (c_a - mu) (the Jacobian with the intensity eliminated at M = mu, DBA's Schur
// complement).
#ifndef DSR_STREAM_REDUCED_SYSTEM_H_
#define DSR_STREAM_REDUCED_SYSTEM_H_

#include <cstdint>
#include <vector>

#include <Eigen/Geometry>

#include "dsr/geometry/se3.h"
#include "dsr/image/frame.h"
#include "dsr/model/observation.h"
#include "dsr/model/photometric.h"
#include "dsr/model/robust_loss.h"
#include "dsr/stream/voxel_stream.h"

namespace dsr {

// The weights of the reweighted reduced cost: one per candidate observation (voxel v of a
// CandidateSet and each of its candidate observers), voxel v's in increasing frame order at
// weight[offset[v] .. offset[v + 1]). Floats: 4 bytes per candidate observation, plus
// the offsets (8 bytes per candidate voxel).
struct ObservationWeights {
  std::vector<int64_t> offset;  // num_voxels + 1 entries
  std::vector<float> weight;
  ObservationWeights() = default;
  // Every weight 1 (the plain cost).
  explicit ObservationWeights(const CandidateSet& candidates);
  // Index in `weight` of frame `frame`'s observation of voxel v, whose candidate
  // observers are `observers` (bit `frame` must be set).
  int64_t Index(int64_t v, uint32_t observers, int frame) const {
    return offset[v] + __builtin_popcount(observers & ((1u << frame) - 1u));
  }
};

// The reduced normal equations over all m frames (6m x 6m; frame 0's rows included);
// `observations` counts sum of k_j over voxels with k_j >= 2.
using ReducedSystem = NormalEquations;

// Streams voxels [begin, end) of `candidates` at the given poses (stream/voxel_stream.h)
// through DSR's per-voxel term SsdToMeanTerm (stream/ssd_to_mean_term.h): bit-identical
// for any `context.num_threads`. With `with_jacobian` false only the cost (and observation
// count) is computed; hessian/gradient are left empty. `batched_hessian` false adds H and
// g voxel by voxel instead of in batches (stream/hessian_batch.h): the slow twin tests
// compare the fast path with. Frames of T > 1 phases (image/frame.h): the sum over the phases
// of each phase's system (docs/design.md section 12); so do the photometric form and
// AccumulateDsrCostSystem without weights. Observation weights are one phase's: the weighted
// form and UpdateObservationWeights take one phase's frames (PhaseFrames).
void AccumulateReducedSystem(const std::vector<Frame>& frames,
                             const CandidateSet& candidates,
                             const std::vector<Eigen::Isometry3d>& frame_from_world,
                             int64_t begin,
                             int64_t end,
                             bool with_jacobian,
                             const StreamContext& context,
                             ReducedSystem* out,
                             bool batched_hessian = true);

// The same with photometric parameters (one per frame, frame 0 first; docs/design.md
// section 2.8): the normal equations have 8 parameters per frame (pose tangent, log gain,
// offset), 8m x 8m, with the residuals r_ij = u_i (c_ij - mu_j) above. `batched_hessian`
// false: the voxel-by-voxel twin.
void AccumulateReducedPhotometricSystem(const std::vector<Frame>& frames,
                                        const CandidateSet& candidates,
                                        const std::vector<Eigen::Isometry3d>& frame_from_world,
                                        const std::vector<Photometric>& photometric,
                                        int64_t begin,
                                        int64_t end,
                                        bool with_jacobian,
                                        const StreamContext& context,
                                        ReducedSystem* out,
                                        bool batched_hessian = true);

// The weighted system (the normal equations of f_w above; p = 6 per frame, or 8 with
// `photometric`, one per frame, non-empty) with the weights of `weights` (built for
// `candidates`), added voxel by voxel: H's per-voxel form (delta_ab w_a - w_a w_b / W) is
// not the batched (delta_ab d + s) of stream/hessian_batch.h. The per-frame costs are the
// weighted ones, sum_j w_ij r_ij^2.
void AccumulateWeightedReducedSystem(const std::vector<Frame>& frames,
                                     const CandidateSet& candidates,
                                     const std::vector<Eigen::Isometry3d>& frame_from_world,
                                     const std::vector<Photometric>& photometric,
                                     const ObservationWeights& weights,
                                     int64_t begin,
                                     int64_t end,
                                     bool with_jacobian,
                                     const StreamContext& context,
                                     ReducedSystem* out);

// The system of the cost a DSR problem solves, over voxels [begin, end): with `weights`
// (non-null) f_w, else with `photometric` (one per frame) f with photometric parameters,
// else (photometric empty) f. One of the three functions above.
void AccumulateDsrCostSystem(const std::vector<Frame>& frames,
                             const CandidateSet& candidates,
                             const std::vector<Eigen::Isometry3d>& frame_from_world,
                             const std::vector<Photometric>& photometric,
                             const ObservationWeights* weights,
                             int64_t begin,
                             int64_t end,
                             bool with_jacobian,
                             const StreamContext& context,
                             ReducedSystem* out);

// What a reweighting pass measured at its poses.
struct ReweightStats {
  // sum_j sum_i rho(r_ij^2) with r_ij = c_ij - mu_j, mu_j the weighted mean with the new
  // weights, over voxels with k_j >= 2 (not halved: Ceres's cost is half of it).
  double robust_cost = 0.0;
  // Largest change of a weight (all candidate observations).
  double max_weight_change = 0.0;
  int64_t observations = 0;  // sum of k_j over voxels with k_j >= 2
};

// Most IRLS steps of a voxel's location per reweighting pass (RobustLocation; they stop
// early once the location settles).
constexpr int kLocationIterations = 10;

// The reweighting step of IRLS at fixed poses (and photometric parameters, empty for
// none): for each candidate voxel with k_j >= 2 valid observations, the robust location
// of its corrected observations (RobustLocation under `loss`, starting from the weighted
// mean with the current weights, at most kLocationIterations steps) and the weights
// w_ij = rho'(r_ij^2) there; every other candidate observation (sigma_ij = 0 now, or k_j
// < 2) gets weight 1. Streams the voxels like the cost (stream/voxel_stream.h); the result is
// identical for any `context.num_threads`. Weights are stored as floats, at least FLT_MIN.
void UpdateObservationWeights(const std::vector<Frame>& frames,
                              const CandidateSet& candidates,
                              const std::vector<Eigen::Isometry3d>& frame_from_world,
                              const std::vector<Photometric>& photometric,
                              const RobustLoss& loss,
                              const StreamContext& context,
                              ObservationWeights* weights,
                              ReweightStats* stats);

// UpdateObservationWeights phase by phase for frames of T phases (`weights`: T of them, in
// phase order; one phase: the call itself); the stats summed over the phases (robust cost,
// observations) or their largest (weight change).
void UpdateObservationWeightsByPhase(const std::vector<Frame>& frames,
                                     const CandidateSet& candidates,
                                     const std::vector<Eigen::Isometry3d>& frame_from_world,
                                     const std::vector<Photometric>& photometric,
                                     const RobustLoss& loss,
                                     const StreamContext& context,
                                     std::vector<ObservationWeights>* weights,
                                     ReweightStats* stats);

// The stiffness of the mean gauge's prior (MeanPosePrior, solve/gauge.h) at
// `frame_from_world`: MeanGaugeStiffness of the system of the cost a solve minimises there
// (AccumulateDsrCostSystem over every candidate voxel, with `photometric` and `weights` as
// there; 6 or 8 parameters per frame). It is DSR's Gauss-Newton matrix and DBA's Schur
// complement onto the poses (the theorem), so both modes' priors take it from this one pass.
// With frames of T phases, the sum of the T phases' systems, `weights` (null or) T of them.
Vector6d MeanGaugeStiffnessAt(const std::vector<Frame>& frames,
                              const CandidateSet& candidates,
                              const std::vector<Eigen::Isometry3d>& frame_from_world,
                              const std::vector<Photometric>& photometric,
                              const ObservationWeights* weights,
                              const StreamContext& context);

}  // namespace dsr

#endif  // DSR_STREAM_REDUCED_SYSTEM_H_
