// DBA: full direct bundle adjustment (docs/design.md section 3, paper eq. 2).
//
//   min over T_1..T_{m-1}, M_1..M_n of  sum_j sum_i sigma_ij (M_j - I_i(p_ij))^2
//
// One SE(3) parameter block per frame (PoseManifold, layout [qx qy qz qw tx ty tz], left
// perturbation, tangent [rho; phi]; frame 0 constant = the gauge, or in the mean gauge
// every pose free with one MeanPosePrior block over them, solve/gauge.h), one 1-D block per
// candidate panorama voxel (the CandidateSet of model/observation.h, the rule shared with
// DSR), one residual block per candidate observation (i, j):
//   e_ij = M_j - I_i(p_ij),  d e / d delta_i = -J_ij,  d e / d M_j = 1,
// zero residual and zero Jacobian while sigma_ij = 0. Solved by Ceres's Schur solvers with
// every intensity block in elimination group 0 and the poses in group 1.
//
// With photometric parameters (DbaOptions::photometric), each frame also has a 2-D block
// [log_gain, offset] (model/photometric.h, Photometric; frame 0 constant, the gauge) beside
// its pose, in group 1: frame i sees M_j as a_i I_i + b_i, and its residual is in its own
// grey levels (docs/design.md 2.8), with a_i = exp(log_gain_i) and u_i = 1 / a_i,
//   e_ij = u_i (M_j - b_i) - I_i(p_ij),
//   d e / d delta_i = -J_ij,  d e / d M_j = u_i,
//   d e / d log_gain_i = -u_i (M_j - b_i),  d e / d b_i = -u_i.
//
// With a robust loss (DbaOptions::loss, model/robust_loss.h; docs/design.md section 4.7)
// every residual block gets the matching ceres::LossFunction: the objective becomes
// sum_j sum_i rho(e_ij^2).
//
// The mean gauge (DbaOptions::gauge; docs/design.md 4.8) is DSR's: the same prior, about
// the same field-of-view centres, with the same stiffness (MeanGaugeStiffnessAt,
// stream/reduced_system.h: DSR's Gauss-Newton matrix at the start, which the theorem makes
// DBA's Schur complement onto the poses), so that both modes minimise one function.
#ifndef DSR_DBA_DBA_PROBLEM_H_
#define DSR_DBA_DBA_PROBLEM_H_

#include <array>
#include <memory>
#include <string>
#include <vector>

#include <ceres/ceres.h>

#include "dsr/geometry/se3.h"
#include "dsr/image/frame.h"
#include "dsr/model/observation.h"
#include "dsr/model/photometric.h"
#include "dsr/model/robust_loss.h"
#include "dsr/solve/gauge.h"
#include "dsr/solve/solve_options.h"
#include "dsr/stream/voxel_stream.h"

namespace dsr {

// The residual of one candidate observation: SizedCostFunction<1, pose (7), intensity (1)>.
class DbaResidual final : public ceres::SizedCostFunction<1, kPoseAmbientSize, 1> {
 public:
  DbaResidual(const Frame* frame, const Eigen::Vector3d& voxel_center_in_world)
      : frame_(frame), voxel_center_in_world_(voxel_center_in_world) {}
  bool Evaluate(double const* const* parameters,
                double* residuals,
                double** jacobians) const override;

 private:
  const Frame* frame_;  // not owned
  Eigen::Vector3d voxel_center_in_world_;
};

// The residual with the frame's photometric block:
// SizedCostFunction<1, pose (7), intensity (1), [log_gain, offset] (2)>.
class DbaPhotometricResidual final
    : public ceres::SizedCostFunction<1, kPoseAmbientSize, 1, 2> {
 public:
  DbaPhotometricResidual(const Frame* frame, const Eigen::Vector3d& voxel_center_in_world)
      : frame_(frame), voxel_center_in_world_(voxel_center_in_world) {}
  bool Evaluate(double const* const* parameters,
                double* residuals,
                double** jacobians) const override;

 private:
  const Frame* frame_;  // not owned
  Eigen::Vector3d voxel_center_in_world_;
};

struct DbaOptions {
  SolveOptions solve;  // linear solver default: DENSE_SCHUR
  // Estimate a gain and an offset per frame with the poses (frame 0's fixed at 1 and 0).
  bool photometric = false;
  // With photometric: the start, one per frame (frame 0's must be the gauge, 0 and 0);
  // empty: every gain 1 and offset 0.
  std::vector<Photometric> initial_photometric;
  // The loss of every residual (default squared: no Ceres loss at all).
  RobustLoss loss;
  // Refuse problems whose estimated memory exceeds this many MiB; <= 0 means half the
  // machine's RAM.
  double memory_budget_mb = 0.0;
  // The pose gauge (solve/gauge.h), as DsrOptions::gauge: kMean frees frame 0's pose too
  // and adds DSR's prior on the frames' mean displacement (one extra streamed pass for its
  // stiffness). SolveDba then returns every pose in the world of the initial poses, the
  // candidates' world, where the intensities' voxel centres stay (RelativeToFrame0 gives the
  // outputs' convention; in frame 0's coordinates those centres move with frame 0). Frame
  // 0's photometric parameters stay the photometric gauge in both.
  Gauge gauge = Gauge::kFrame0;
  bool Validate(std::string* error) const;
};

// Estimated peak memory of building and solving a DBA problem, from counts measured on
// this implementation (see EstimateDbaMemory in dba_problem.cc for the per-item costs).
struct DbaMemoryEstimate {
  int64_t residual_blocks = 0;
  int64_t intensity_blocks = 0;
  int64_t bytes = 0;
  std::string ToString() const;
};
// `photometric`: with a [log_gain, offset] block per frame (DbaOptions::photometric).
// `num_phases`: the frames' phases (each candidate observation and intensity once per phase).
DbaMemoryEstimate EstimateDbaMemory(const CandidateSet& candidates,
                                    int num_frames,
                                    ceres::LinearSolverType linear_solver,
                                    bool photometric = false,
                                    int num_phases = 1);

// The Ceres problem, kept as an object so tests can evaluate its Jacobian.
class DbaProblem {
 public:
  // Builds the problem at `frame_from_world`. Intensities start at the per-voxel mean of
  // the observations at these poses (0 where none observes). With `photometric` (one entry
  // per frame, or empty for none), each frame gets a photometric block starting there
  // (frame 0's is held constant; give it the gauge, 0 and 0), and the intensities start at
  // the mean of the corrected observations. Every residual block gets `loss` (one shared
  // Ceres loss object, owned by this problem; none for squared).
  // Gauge::kFrame0 holds frame 0's pose constant. Gauge::kMean leaves it free and adds a
  // MeanPosePrior over every pose, anchored at `frame_from_world` about the frames'
  // ValidCentre(), with the stiffness DSR's problem has at these poses and photometric
  // parameters (MeanGaugeStiffnessAt, streamed with `context`): with a robust `loss`, that
  // of the weights DSR's first reweighted solve starts from (UpdateObservationWeights).
  DbaProblem(const std::vector<Frame>& frames,
             const CandidateSet& candidates,
             const std::vector<Eigen::Isometry3d>& frame_from_world,
             const std::vector<Photometric>& photometric = {},
             const RobustLoss& loss = RobustLoss(),
             Gauge gauge = Gauge::kFrame0,
             const StreamContext& context = StreamContext());

  ceres::Problem& problem() { return *problem_; }
  double* pose_parameters(int frame) { return poses_[frame].data(); }
  double* intensity(int64_t voxel) { return &intensities_[voxel]; }
  int64_t num_intensities() const { return static_cast<int64_t>(intensities_.size()); }
  int64_t num_residual_blocks() const { return num_residual_blocks_; }
  std::vector<Eigen::Isometry3d> Poses() const;
  // Empty without photometric blocks.
  std::vector<Photometric> PhotometricParameters() const;
  double* photometric_parameters(int frame) { return photometric_[frame].data(); }
  // Sets every pose from `frame_from_world` (tests).
  void SetPoses(const std::vector<Eigen::Isometry3d>& frame_from_world);
  // Orders intensities (group 0) before poses (group 1) for Schur elimination.
  std::shared_ptr<ceres::ParameterBlockOrdering> MakeOrdering();

 private:
  // Declared before problem_, which refers to it (Problem::Options::loss_function_ownership
  // is DO_NOT_TAKE_OWNERSHIP), so it outlives the problem.
  std::unique_ptr<ceres::LossFunction> loss_;
  std::unique_ptr<ceres::Problem> problem_;
  std::vector<std::array<double, kPoseAmbientSize>> poses_;
  std::vector<std::array<double, 2>> photometric_;  // [log_gain, offset] per frame
  // The per-voxel means of one phase's observations at `frame_from_world` (n of them).
  static void InitialIntensities(const std::vector<Frame>& frames,
                                 const CandidateSet& candidates,
                                 const std::vector<Eigen::Isometry3d>& frame_from_world,
                                 const std::vector<Photometric>& correction,
                                 double* intensities);
  // One per (voxel, phase), phase by phase: voxel v of phase p at p n + v.
  std::vector<double> intensities_;
  // Each phase's one-phase frames (the residuals point to them).
  std::unique_ptr<FramesByPhase> phase_frames_;
  int64_t num_residual_blocks_ = 0;
};

// Builds and solves. Fails (false, `error`) when the memory estimate exceeds the budget,
// naming the estimate and suggesting a coarser --panorama_spacing or --mode=dsr. A solve
// that runs but is not usable returns true with report->usable = false.
// With frames of T phases (Frame::num_phases), one intensity per (voxel, phase) and every
// phase's residuals on the view's one pose block (docs/design.md section 12); `intensities`
// then holds T x n values, phase by phase.
// report->frame_from_world and `intensities` (one per candidate voxel, at its centre) are
// in the world of `initial_frame_from_world` (frame 0's pose is its initial one unless
// options.gauge is kMean). With
// options.photometric, the photometric parameters start at options.initial_photometric (or
// 1 and 0) and are returned in report->photometric. With a robust loss, the reported costs
// are Ceres's, 1/2 sum rho(e_ij^2).
bool SolveDba(const std::vector<Frame>& frames,
              const CandidateSet& candidates,
              const std::vector<Eigen::Isometry3d>& initial_frame_from_world,
              const DbaOptions& options,
              SolveReport* report,
              std::vector<float>* intensities,
              std::string* error);

}  // namespace dsr

#endif  // DSR_DBA_DBA_PROBLEM_H_
