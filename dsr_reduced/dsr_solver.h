// DSR solve: Ceres over the 6(m-1) free pose parameters (and, with photometric parameters,
// 2(m-1) more) only (docs/design.md sections 4 and 2.8).
#ifndef DSR_DSR_REDUCED_DSR_SOLVER_H_
#define DSR_DSR_REDUCED_DSR_SOLVER_H_

#include <array>
#include <memory>
#include <string>
#include <vector>

#include <ceres/ceres.h>

#include "core/frame.h"
#include "core/observation.h"
#include "core/solve_options.h"
#include "dsr_reduced/reduced_cost.h"

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
  bool Validate(std::string* error) const;
};

// The reduced Ceres problem over free poses (frame 0 constant, not a parameter block of
// the fast cost; a constant block of the reference cost).
class DsrProblem {
 public:
  DsrProblem(const std::vector<Frame>& frames,
             const CandidateSet& candidates,
             const std::vector<Eigen::Isometry3d>& frame_from_world,
             const DsrOptions& options);
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
  // How the fast path's blocks reuse their passes (core/streamed_cost.h); none by
  // default, so that evaluations outside a solve are plain ones.
  void SetEvaluationPolicy(const StreamedEvaluationPolicy& policy);

 private:
  std::unique_ptr<ceres::Problem> problem_;
  std::vector<std::array<double, kPoseAmbientSize>> poses_;
  std::vector<std::array<double, 2>> photometric_;  // [log_gain, offset] per frame
  std::vector<ReducedChunkCost*> chunks_;  // owned by problem_
};

// Solves. A solve that runs but is not usable returns true with report->usable = false.
bool SolveDsr(const std::vector<Frame>& frames,
              const CandidateSet& candidates,
              const std::vector<Eigen::Isometry3d>& initial_frame_from_world,
              const DsrOptions& options,
              SolveReport* report,
              std::string* error);

}  // namespace dsr

#endif  // DSR_DSR_REDUCED_DSR_SOLVER_H_
