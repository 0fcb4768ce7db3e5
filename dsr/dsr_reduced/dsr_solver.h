// DSR solve: Ceres over the 6(m-1) free pose parameters (and, with photometric parameters,
// 2(m-1) more) only (docs/design.md sections 4 and 2.8). With a robust loss, iteratively
// reweighted solves (docs/design.md section 4.7).
#ifndef DSR_DSR_REDUCED_DSR_SOLVER_H_
#define DSR_DSR_REDUCED_DSR_SOLVER_H_

#include <array>
#include <memory>
#include <string>
#include <vector>

#include <ceres/ceres.h>

#include "dsr/dsr_reduced/reduced_cost.h"
#include "dsr/image/frame.h"
#include "dsr/model/observation.h"
#include "dsr/solve/gauge.h"
#include "dsr/solve/solve_options.h"

namespace dsr {

struct DsrOptions {
  SolveOptions solve;  // linear solver default: DENSE_QR
  // Fast path: the candidate voxels split into this many residual blocks (each streams
  // its voxels with num_threads threads). Results do not depend on it beyond rounding.
  int num_chunks = 1;
  // Use the per-voxel reference cost instead (stores Jacobians: small problems only).
  bool reference_cost = false;
  // Estimate a gain and an offset per frame with the poses (docs/design.md section 2.8;
  // frame 0's fixed at 1 and 0), with either cost.
  bool photometric = false;
  // With photometric: the start, one per frame (frame 0's must be the gauge, 0 and 0);
  // empty: every gain 1 and offset 0.
  std::vector<Photometric> initial_photometric;
  // The loss (model/robust_loss.h). Squared: one solve of f. Huber or Cauchy: iteratively
  // reweighted solves of the weighted cost f_w (dsr_reduced/reduced_cost.h), with either cost.
  RobustLoss loss;
  // The pose gauge (solve/gauge.h). kMean: every pose is free, with a prior on their mean
  // displacement whose stiffness comes from the data's normal equations at the initial
  // poses (one extra pass, MeanGaugeStiffness); frame 0 moves too, and SolveDsr returns
  // every pose in the world of the initial poses (the candidates' world; RelativeToFrame0
  // gives the outputs' convention). Frame 0's photometric parameters stay the photometric
  // gauge in both.
  Gauge gauge = Gauge::kFrame0;
  // Where the fast path's passes are evaluated (dsr_reduced/reduced_cost_backend.h): null,
  // the CPU stream (DefaultReducedCostBackend); another backend (a GPU one) evaluates every
  // chunk's passes instead. Not with reference_cost. Copies of the options share it. The
  // mean gauge's prior stiffness and IRLS's reweighting passes stay on the CPU stream.
  std::shared_ptr<const ReducedCostBackend> backend;
  bool Validate(std::string* error) const;
};

// Most weighted solves of one robust SolveDsr (IRLS); it usually stops after 3 to 6, when
// a solve moves no field of view by solve.step_tolerance (docs/design.md 4.7).
constexpr int kMaxReweightings = 30;
// With solve.step_tolerance = 0 (solves run to their fixed point), IRLS stops when
// no weight changes by more than this (about 2 ulp of a float weight near 1) or the poses
// stop moving at all.
constexpr double kWeightChangeTolerance = 2.5e-7;

// The reduced Ceres problem over free poses (in the frame-0 gauge frame 0 is constant: not a
// parameter block of the fast cost, a constant block of the reference cost; in the mean
// gauge it is free in both, and a MeanPosePrior block holds the frames' common motion).
class DsrProblem {
 public:
  // With `weights` (built for `candidates`; not owned, must outlive the problem and not
  // change while it is solved), the weighted cost f_w; null: the plain cost f. With frames
  // of T phases (Frame::num_phases), `weights` points to T of them, phase by phase, and
  // the cost is the sum over the phases of each phase's cost, every phase's chunks over the
  // same pose blocks (docs/design.md section 12).
  // options.loss is not used here (SolveDsr computes the weights from it).
  DsrProblem(const std::vector<Frame>& frames,
             const CandidateSet& candidates,
             const std::vector<Eigen::Isometry3d>& frame_from_world,
             const DsrOptions& options,
             const ObservationWeights* weights = nullptr);
  ceres::Problem& problem() { return *problem_; }
  std::vector<Eigen::Isometry3d> Poses() const;
  double* pose_parameters(int frame) { return poses_[frame].data(); }
  // Empty without photometric parameters.
  std::vector<Photometric> PhotometricParameters() const;
  // Frame i's [log_gain, offset] (with photometric parameters; frame 0's is the gauge).
  double* photometric_parameters(int frame) { return photometric_[frame].data(); }
  // Observations counted by the fast path's latest evaluation (sum over chunks); -1 for
  // the reference cost, which does not count them.
  int64_t LastObservations() const;
  // The fast path's blocks (empty for the reference cost).
  const std::vector<ReducedChunkCost*>& chunks() const { return chunks_; }
  // The mean gauge's prior stiffness (MeanGaugeStiffness of the data's normal equations at
  // the initial poses; zero in the frame-0 gauge).
  const Vector6d& gauge_stiffness() const { return gauge_stiffness_; }
  // How the fast path's blocks reuse their passes (stream/streamed_cost.h); none by
  // default, so that evaluations outside a solve are plain ones.
  void SetEvaluationPolicy(const StreamedEvaluationPolicy& policy);

 private:
  // The per-voxel reference's blocks of one phase's frames (the pose blocks shared).
  void AddReferenceCosts(const std::vector<Frame>& frames,
                         const CandidateSet& candidates,
                         const ObservationWeights* weights,
                         bool photometric);
  std::unique_ptr<ceres::Problem> problem_;
  std::vector<std::array<double, kPoseAmbientSize>> poses_;
  std::vector<std::array<double, 2>> photometric_;  // [log_gain, offset] per frame
  std::vector<ReducedChunkCost*> chunks_;  // owned by problem_ (phase by phase)
  // Each phase's one-phase frames (the chunks point to them).
  std::unique_ptr<FramesByPhase> phase_frames_;
  Vector6d gauge_stiffness_ = Vector6d::Zero();  // the mean gauge's prior
};

// Solves. A solve that runs but is not usable returns true with report->usable = false.
// report->frame_from_world are the final poses in the world of `initial_frame_from_world`
// (frame 0's is its initial pose unless options.gauge is kMean).
// With a robust loss (options.loss not squared), iteratively reweighted least squares:
// weights w_ij = rho'(r_ij^2) from the robust location of each voxel at the start
// (UpdateObservationWeights), then repeatedly one Ceres solve of f_w with the weights fixed
// and new weights at its poses, until a solve moves no field of view by
// solve.step_tolerance (solve/convergence.h) or, with that tolerance 0, until no
// weight changes by more than kWeightChangeTolerance or the poses stay put; at most
// kMaxReweightings solves. The report then sums iterations, times and passes over the
// solves (iteration records concatenated and renumbered; each record's cost is 1/2 f_w of
// its own solve's weights) and gives as initial_cost and final_cost the robust cost
// 1/2 sum rho(r_ij^2) at the start and at the final poses (r_ij from the final weights'
// location: at the fixed point, DBA's final cost with the same loss). final_frame_cost
// stays empty (the weighted per-frame costs are not the misfits' plain sums).
bool SolveDsr(const std::vector<Frame>& frames,
              const CandidateSet& candidates,
              const std::vector<Eigen::Isometry3d>& initial_frame_from_world,
              const DsrOptions& options,
              SolveReport* report,
              std::string* error);

// The gains and offsets that minimise DSR's cost f with photometric parameters at fixed
// poses (docs/design.md section 2.9): one Ceres solve over the photometric blocks only,
// the pose blocks constant, from options.initial_photometric (empty: gain 1, offset 0),
// with the squared loss and without the pose step rule (options.loss and
// solve.step_tolerance are not used; options.photometric need not be set). The pipeline
// uses it to state the photometric parameters on the input's grey levels when it
// registered transformed intensities (model/intensity_transform.h). A solve that ran but
// is not usable returns true with report->usable = false; report->photometric holds the
// estimate, report->frame_from_world the given poses.
bool SolvePhotometricAtPoses(const std::vector<Frame>& frames,
                             const CandidateSet& candidates,
                             const std::vector<Eigen::Isometry3d>& frame_from_world,
                             const DsrOptions& options,
                             SolveReport* report,
                             std::string* error);

}  // namespace dsr

#endif  // DSR_DSR_REDUCED_DSR_SOLVER_H_
