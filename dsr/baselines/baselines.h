// The paper's four baselines (docs/design.md section 5), over the same observation model,
// sampler, panorama grid rule, masks, initial poses and stopping rule as DSR:
//
//   pairwise           consecutive pairs (k-1, k) registered by SSD over their overlap,
//                      chained from frame 0.
//   lie_normalization  relative poses of every overlapping pair, then a pose graph on
//                      SE(3) that agrees best with all of them in the Lie algebra
//                      (Wachinger et al. 2007): min sum ||Log(Z_ki^-1 T_k T_i^-1)||^2.
//   sequential         frames added one at a time in index order, each registered to the
//                      panorama fused (mean, paper eq. 10) from the frames already placed
//                      (Mao et al. 2021).
//   ape                accumulated pairwise estimates (Wachinger & Navab 2012): Gauss-
//                      Newton/LM on the sum over all pairs i < k of the SSD over their
//                      overlap, sampled on the panorama grid. Per voxel
//                      sum_{i<k} (a_i - a_k)^2 = k_j sum_i (a_i - mu_j)^2, so APE weighs a
//                      voxel seen k_j times k_j times and costs O(k_j^2) per voxel.
//
// A pair registration (frames A and B, A fixed) is APE on the two-frame problem: its only
// pair term is (a_A - a_B)^2, sampled on the pair's panorama grid (the shared grid rule)
// at the voxels both observe, and divided by their number (mean squared difference: with
// two frames a plain sum would reward shrinking the overlap; see pair_methods.cc). APE
// and the pair solves use the streamed normal equations of stream/voxel_stream.h (nothing
// per observation is stored).
#ifndef DSR_BASELINES_BASELINES_H_
#define DSR_BASELINES_BASELINES_H_

#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "dsr/image/frame.h"
#include "dsr/model/observation.h"
#include "dsr/solve/solve_options.h"
#include "dsr/stream/streamed_cost.h"
#include "dsr/stream/voxel_stream.h"

namespace dsr {

struct BaselineOptions {
  SolveOptions solve;             // each Ceres solve (pair, APE, pose graph)
  double panorama_spacing = 1.0;  // grids of the pair problems and the sequential panorama
  int64_t min_shared_voxels = 64; // a pair overlaps when it shares this many voxels
  int num_chunks = 1;             // APE: streamed residual blocks
  bool Validate(std::string* error) const;
};

// ---- APE --------------------------------------------------------------------------------

// APE normal equations of candidate voxels [begin, end) over all m frames (6m x 6m):
// cost = sum_j sum_{i<k} sigma_ij sigma_kj (I_i(p_ij) - I_k(p_kj))^2; `observations`
// counts the pair differences, k_j (k_j - 1) / 2 per voxel. Deterministic for any threads.
// The Gauss-Newton matrix is summed pair by pair, as APE evaluates its objective;
// `batched_hessian` instead adds it in DSR's batched form, H_ab = (k delta_ab - 1) J_a^T J_b
// per voxel (the same matrix: docs/design.md section 5), for measurements only (bench/): it
// shows how much of APE's cost is its pair-by-pair Gauss-Newton matrix.
void AccumulateApeSystem(const std::vector<Frame>& frames,
                         const CandidateSet& candidates,
                         const std::vector<Eigen::Isometry3d>& frame_from_world,
                         int64_t begin,
                         int64_t end,
                         bool with_jacobian,
                         const StreamContext& context,
                         NormalEquations* out,
                         bool batched_hessian = false);

// Streamed APE block (stream/streamed_cost.h) over voxels [begin, end).
class ApeChunkCost final : public StreamedPoseCost {
 public:
  ApeChunkCost(const std::vector<Frame>* frames,
               const CandidateSet* candidates,
               const Eigen::Isometry3d& frame0_from_world,
               int64_t begin,
               int64_t end,
               const StreamContext& context);

 private:
  void Accumulate(const std::vector<Eigen::Isometry3d>& frame_from_world,
                  const std::vector<Photometric>& photometric,  // empty: APE has none
                  bool with_jacobian,
                  NormalEquations* out) const override;
  const std::vector<Frame>* frames_;  // not owned
  const CandidateSet* candidates_;    // not owned
  int64_t begin_, end_;
  StreamContext context_;
};

// Reference (slow twin): one residual a_i - a_k per candidate pair of one voxel, through
// ObserveSample; parameter blocks are the observers' poses in increasing frame order.
class VoxelApeCost final : public ceres::CostFunction {
 public:
  VoxelApeCost(std::vector<const Frame*> observers, const Eigen::Vector3d& voxel_center_in_world);
  bool Evaluate(double const* const* parameters,
                double* residuals,
                double** jacobians) const override;

 private:
  std::vector<const Frame*> observers_;  // not owned
  Eigen::Vector3d voxel_center_in_world_;
};

// Simultaneous APE solve over the candidates (frame 0 constant).
bool SolveApe(const std::vector<Frame>& frames,
              const CandidateSet& candidates,
              const std::vector<Eigen::Isometry3d>& initial_frame_from_world,
              const BaselineOptions& options,
              SolveReport* report,
              std::string* error);

// ---- Pair registration and the pair-based baselines -------------------------------------

// Registers `moving` to `fixed` (held at `fixed_from_world`) by the mean squared
// difference over their overlap,
// starting from `*moving_from_world`, which receives the result. Returns false with an
// error when the pair shares fewer than min_shared_voxels voxels; a solve that is not
// usable returns true with report->usable = false.
bool RegisterPair(const Frame& fixed,
                  const Eigen::Isometry3d& fixed_from_world,
                  const Frame& moving,
                  const BaselineOptions& options,
                  Eigen::Isometry3d* moving_from_world,
                  SolveReport* report,
                  std::string* error);

bool SolvePairwise(const std::vector<Frame>& frames,
                   const std::vector<Eigen::Isometry3d>& initial_frame_from_world,
                   const BaselineOptions& options,
                   SolveReport* report,
                   std::string* error);

// Pairs (i < k) sharing at least min_shared_voxels candidate voxels are registered.
bool SolveLieNormalization(const std::vector<Frame>& frames,
                           const CandidateSet& candidates,
                           const std::vector<Eigen::Isometry3d>& initial_frame_from_world,
                           const BaselineOptions& options,
                           SolveReport* report,
                           std::string* error);

bool SolveSequential(const std::vector<Frame>& frames,
                     const std::vector<Eigen::Isometry3d>& initial_frame_from_world,
                     const BaselineOptions& options,
                     SolveReport* report,
                     std::string* error);

// ---- Lie normalisation's pose graph ------------------------------------------------------

// A measured relative pose Z_ki = T_k T_i^-1 (frame_k_from_frame_i) between frames i < k.
struct RelativePose {
  int i = 0, k = 0;
  Eigen::Isometry3d k_from_i = Eigen::Isometry3d::Identity();
  // Scales the residual [rho; phi] per component (1 / its standard deviation): all ones
  // for Lie normalisation, which weighs millimetres and radians alike.
  Vector6d sqrt_information = Vector6d::Ones();
};

// Global poses (frame 0 fixed at `initial[0]`) minimising sum over the measurements of
// ||Log(Z_ki^-1 T_k T_i^-1)||^2 (tangent [rho; phi], docs/design.md section 1), on the SE(3)
// manifold with Ceres, from `initial`. Each residual is scaled by its sqrt_information;
// with cauchy_scale > 0 the squared norms pass through Ceres's CauchyLoss of that scale
// (a robust graph: a wrong measurement pulls with a bounded force).
bool SolvePoseGraph(const std::vector<RelativePose>& measurements,
                    const std::vector<Eigen::Isometry3d>& initial,
                    const SolveOptions& solve,
                    std::vector<Eigen::Isometry3d>* frame_from_world,
                    SolveReport* report,
                    std::string* error,
                    double cauchy_scale = 0.0);

}  // namespace dsr

#endif  // DSR_BASELINES_BASELINES_H_
