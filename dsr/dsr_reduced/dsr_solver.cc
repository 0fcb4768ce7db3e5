// DSR solve in Ceres: LM or dogleg with a dense solver over the pose parameters.
#include "dsr/dsr_reduced/dsr_solver.h"

#include <algorithm>
#include <cmath>

#include <glog/logging.h>

#include "dsr/solve/convergence.h"
#include "dsr/util/option_fields.h"

#include "dsr/dsr_reduced/reduced_cost.h"

namespace dsr {

bool DsrOptions::Validate(std::string* error) const {
  if (!solve.Validate(error)) {
    *error = PrefixFieldPaths("solve", *error);
    return false;
  }
  if (!ValidatePoseOnlyLinearSolver(solve, "DSR solves", error)) return false;
  if (!ValidateInitialPhotometric(photometric, initial_photometric, error)) return false;
  if (!loss.Validate(error)) {
    *error = PrefixFieldPaths("loss", *error);
    return false;
  }
  if (num_chunks < 1) {
    *error = FieldError("num_chunks", num_chunks, "must be >= 1");
    return false;
  }
  if (backend != nullptr && reference_cost) {
    *error = FieldError("backend", backend->Name(),
                        "evaluates the fast path; the per-voxel reference cost (reference_cost) "
                        "has none");
    return false;
  }
  return true;
}

DsrProblem::DsrProblem(const std::vector<Frame>& frames,
                       const CandidateSet& candidates,
                       const std::vector<Eigen::Isometry3d>& frame_from_world,
                       const DsrOptions& options,
                       const ObservationWeights* weights) {
  const int m = static_cast<int>(frames.size());
  CHECK_GE(m, 2);
  CHECK_EQ(candidates.num_frames, m);
  // Each phase's one-phase frames (the theorem eliminates every (voxel, phase) intensity);
  // a 3D sequence's are the caller's frames.
  phase_frames_ = std::make_unique<FramesByPhase>(frames);
  const FramesByPhase& phase_frames = *phase_frames_;
  const int phases = phase_frames.size();
  for (int p = 0; weights != nullptr && p < phases; ++p) {
    CHECK(static_cast<int64_t>(weights[p].offset.size()) == candidates.num_voxels() + 1)
        << "weights built for another candidate set";
  }
  ceres::Problem::Options problem_options;
  problem_options.manifold_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  problem_ = std::make_unique<ceres::Problem>(problem_options);
  static PoseManifold* const kManifold = new PoseManifold();  // shared, never freed
  poses_.resize(m);
  for (int i = 0; i < m; ++i) PoseToParameters(frame_from_world[i], poses_[i].data());
  if (options.photometric) {
    photometric_.assign(m, {0.0, 0.0});
    if (!options.initial_photometric.empty()) {
      CHECK_EQ(static_cast<int>(options.initial_photometric.size()), m);
      for (int i = 0; i < m; ++i) {
        photometric_[i] = {options.initial_photometric[i].log_gain,
                           options.initial_photometric[i].offset};
      }
    }
  }

  const bool mean_gauge = options.gauge == Gauge::kMean;
  if (mean_gauge && options.reference_cost) {
    // The prior's stiffness, from the data's normal equations at the initial poses.
    gauge_stiffness_ = MeanGaugeStiffnessAt(frames, candidates, frame_from_world,
                                            PhotometricParameters(), weights,
                                            StreamContextFor(options.solve));
  }
  std::vector<double*> all_poses;
  std::vector<Eigen::Vector3d> centres;  // of the fields of view, for the mean gauge's prior
  for (int i = 0; i < m; ++i) {
    all_poses.push_back(poses_[i].data());
    centres.push_back(frames[i].ValidCentre());
  }

  if (options.reference_cost) {
    for (int i = 0; i < m; ++i) {
      problem_->AddParameterBlock(poses_[i].data(), kPoseAmbientSize, kManifold);
    }
    if (mean_gauge) {
      problem_->AddResidualBlock(new MeanPosePrior(frame_from_world, centres, gauge_stiffness_),
                                 nullptr, all_poses);
    } else {
      problem_->SetParameterBlockConstant(poses_[0].data());
    }
    if (options.photometric) {
      for (int i = 0; i < m; ++i) problem_->AddParameterBlock(photometric_[i].data(), 2);
      problem_->SetParameterBlockConstant(photometric_[0].data());
    }
    for (int p = 0; p < phases; ++p) {
      AddReferenceCosts(phase_frames[p], candidates, weights != nullptr ? weights + p : nullptr,
                        options.photometric);
    }
    return;
  }
  std::vector<double*> free_blocks;
  for (int i = mean_gauge ? 0 : 1; i < m; ++i) {
    problem_->AddParameterBlock(poses_[i].data(), kPoseAmbientSize, kManifold);
    free_blocks.push_back(poses_[i].data());
  }
  // Frame 0's photometric parameters are the chunk costs' constant gauge, not a block.
  if (options.photometric) {
    for (int i = 1; i < m; ++i) {
      problem_->AddParameterBlock(photometric_[i].data(), 2);
      free_blocks.push_back(photometric_[i].data());
    }
  }
  const int64_t n = candidates.num_voxels();
  const int64_t chunks = std::max<int64_t>(1, std::min<int64_t>(options.num_chunks, n));
  // Every phase's chunks, over the same pose (and photometric) blocks: Ceres sums them.
  for (int p = 0; p < phases; ++p) {
    for (int64_t c = 0; c < chunks; ++c) {
      const int64_t begin = n * c / chunks, end = n * (c + 1) / chunks;
      auto* chunk = new ReducedChunkCost(&phase_frames[p], &candidates, frame_from_world[0], begin,
                                         end, StreamContextFor(options.solve),
                                         options.photometric,
                                         weights != nullptr ? weights + p : nullptr,
                                         options.gauge, options.backend);
      chunks_.push_back(chunk);
      problem_->AddResidualBlock(chunk, nullptr, free_blocks);
    }
  }
  if (mean_gauge) {
    // The prior's stiffness, from the data's normal equations at the initial poses: the
    // chunks' passes there, which they keep for the solve's first evaluation (the reference
    // cost's MeanGaugeStiffnessAt to rounding: the chunks' poses are their blocks').
    Eigen::MatrixXd hessian;
    for (const ReducedChunkCost* chunk : chunks_) {
      const NormalEquations& pass = chunk->EvaluateWithJacobiansAt(free_blocks.data());
      hessian = hessian.size() == 0 ? pass.hessian : Eigen::MatrixXd(hessian + pass.hessian);
    }
    const int p = options.photometric ? kWideJacobianSize : kJacobianSize;
    gauge_stiffness_ = MeanGaugeStiffness(hessian, m, p);
    problem_->AddResidualBlock(new MeanPosePrior(frame_from_world, centres, gauge_stiffness_),
                               nullptr, all_poses);
  }
}

void DsrProblem::AddReferenceCosts(const std::vector<Frame>& frames,
                                   const CandidateSet& candidates,
                                   const ObservationWeights* weights,
                                   bool photometric) {
  const int m = static_cast<int>(frames.size());
  for (int64_t v = 0; v < candidates.num_voxels(); ++v) {
    std::vector<const Frame*> observers;
    std::vector<double*> blocks;
    for (int i = 0; i < m; ++i) {
      if (candidates.observers[v] >> i & 1u) {
        observers.push_back(&frames[i]);
        blocks.push_back(poses_[i].data());
      }
    }
    // The voxel's weights, in the observers' (increasing frame) order; none unweighted.
    std::vector<double> voxel_weights;
    if (weights != nullptr) {
      voxel_weights.assign(weights->weight.begin() + weights->offset[v],
                           weights->weight.begin() + weights->offset[v + 1]);
    }
    if (photometric) {
      for (int i = 0; i < m; ++i) {
        if (candidates.observers[v] >> i & 1u) blocks.push_back(photometric_[i].data());
      }
      problem_->AddResidualBlock(
          new VoxelReducedPhotometricCost(observers, candidates.VoxelCenter(v),
                                          std::move(voxel_weights)),
          nullptr, blocks);
    } else {
      problem_->AddResidualBlock(
          new VoxelReducedCost(observers, candidates.VoxelCenter(v), std::move(voxel_weights)),
          nullptr, blocks);
    }
  }
}

int64_t DsrProblem::LastObservations() const {
  if (chunks_.empty()) return -1;
  int64_t total = 0;
  for (const ReducedChunkCost* chunk : chunks_) total += chunk->last_observations();
  return total;
}

void DsrProblem::SetEvaluationPolicy(const StreamedEvaluationPolicy& policy) {
  for (ReducedChunkCost* chunk : chunks_) chunk->set_policy(policy);
}

std::vector<Photometric> DsrProblem::PhotometricParameters() const {
  std::vector<Photometric> out;
  for (const auto& x : photometric_) out.push_back({x[0], x[1]});
  return out;
}

std::vector<Eigen::Isometry3d> DsrProblem::Poses() const {
  std::vector<Eigen::Isometry3d> out;
  for (const auto& x : poses_) out.push_back(ParametersToPose(x.data()));
  return out;
}

namespace {

// Runs Ceres on `dsr` with options.solve's settings and fills the report's solver fields
// (FillReport). The fast path's chunk costs thread internally over fixed voxel blocks
// (deterministic), so Ceres itself evaluates the few chunks one after another. `stop` (may
// be null) is the pose step rule.
bool RunCeres(const DsrOptions& options,
              const std::string& label,
              PoseStepCallback* stop,
              DsrProblem* dsr,
              SolveReport* report,
              std::string* error) {
  ceres::Solver::Options solver_options;
  options.solve.ToCeres(options.reference_cost ? ceres::SPARSE_NORMAL_CHOLESKY : ceres::DENSE_QR,
                        &solver_options);
  if (!options.reference_cost) solver_options.num_threads = 1;
  ProgressCallback progress(options.solve.progress_prefix + label, options.solve.progress,
                            options.solve.on_iteration);
  solver_options.callbacks.push_back(&progress);
  if (stop != nullptr) stop->AddTo(&solver_options);
  std::string why;
  if (!solver_options.IsValid(&why)) {
    *error = "invalid solver options: " + why;
    return false;
  }
  ceres::Solver::Summary summary;
  ceres::Solve(solver_options, &dsr->problem(), &summary);
  FillReport(summary, progress, report);
  return true;
}

// One Ceres solve of f (weights null) or of f_w.
bool SolveOnce(const std::vector<Frame>& frames,
               const CandidateSet& candidates,
               const std::vector<Eigen::Isometry3d>& initial_frame_from_world,
               const DsrOptions& options,
               const ObservationWeights* weights,
               SolveReport* report,
               std::string* error) {
  DsrProblem dsr(frames, candidates, initial_frame_from_world, options, weights);
  // Reuse of passes relies on Ceres's trust-region loop and the pose step rule below, so
  // it is set for this solve only (stream/streamed_cost.h).
  dsr.SetEvaluationPolicy(EvaluationPolicyFor(frames, options.solve));
  const bool mean_gauge = options.gauge == Gauge::kMean;
  std::vector<const double*> pose_blocks(frames.size(), nullptr);
  for (size_t i = mean_gauge ? 0 : 1; i < frames.size(); ++i) {
    pose_blocks[i] = dsr.pose_parameters(i);
  }
  PoseStepCallback stop(&frames, pose_blocks, options.solve.step_tolerance,
                        options.solve.max_rejected_steps);
  if (!dsr.chunks().empty()) {
    stop.SetTrialEndsSolve([&dsr] { return EveryTrialEndsSolve(dsr.chunks()); });
  }
  if (!RunCeres(options, options.reference_cost ? "dsr-ref" : "dsr", &stop, &dsr, report,
                error)) {
    return false;
  }
  if (!stop.reason().empty()) report->termination = stop.reason();
  report->frame_from_world = dsr.Poses();
  report->photometric = dsr.PhotometricParameters();
  report->observations_per_iteration = dsr.LastObservations();
  std::vector<const double*> free_blocks, photometric_blocks;
  for (size_t i = 0; i < frames.size(); ++i) {
    if (pose_blocks[i] != nullptr) free_blocks.push_back(pose_blocks[i]);
    if (options.photometric && i > 0) {
      photometric_blocks.push_back(dsr.photometric_parameters(i));
    }
  }
  // The weighted per-frame costs are not the misfits' sums of squares: none with weights.
  bool final_pass = !dsr.chunks().empty() && weights == nullptr;
  for (const ReducedChunkCost* chunk : dsr.chunks()) {
    report->jacobian_passes += chunk->pass_counts().jacobian_passes;
    report->cost_passes += chunk->pass_counts().cost_passes;
    // A pass a backend failed to evaluate has no per-frame costs.
    const NormalEquations* pass = chunk->PassAt(free_blocks, photometric_blocks);
    final_pass = final_pass && pass != nullptr && pass->frame_cost.size() == frames.size();
  }
  if (final_pass) {
    report->final_frame_cost.assign(frames.size(), 0.0);
    report->final_frame_observations.assign(frames.size(), 0);
    for (const ReducedChunkCost* chunk : dsr.chunks()) {
      const NormalEquations* pass = chunk->PassAt(free_blocks, photometric_blocks);
      for (size_t i = 0; i < frames.size(); ++i) {
        report->final_frame_cost[i] += pass->frame_cost[i];
        report->final_frame_observations[i] += pass->frame_observations[i];
      }
    }
  }
  if (report->observations_per_iteration < 0) {  // reference cost: count once (small problems)
    report->observations_per_iteration = 0;
    for (int p = 0; p < NumPhases(frames); ++p) {
      ReducedSystem counts;
      AccumulateReducedSystem(PhaseFrames(frames, p), candidates, report->frame_from_world, 0,
                              candidates.num_voxels(), false, StreamContextFor(options.solve),
                              &counts);
      report->observations_per_iteration += counts.observations;
    }
  }
  return true;
}

// IRLS for a robust loss (SolveDsr's comment in dsr_solver.h).
bool SolveReweighted(const std::vector<Frame>& frames,
                     const CandidateSet& candidates,
                     const std::vector<Eigen::Isometry3d>& initial_frame_from_world,
                     const DsrOptions& options,
                     SolveReport* report,
                     std::string* error) {
  const int m = static_cast<int>(frames.size());
  const StreamContext context = StreamContextFor(options.solve);
  std::vector<Eigen::Isometry3d> poses = initial_frame_from_world;
  std::vector<Photometric> photometric;
  if (options.photometric) {
    photometric = options.initial_photometric.empty() ? std::vector<Photometric>(m)
                                                      : options.initial_photometric;
  }
  std::vector<ObservationWeights> weights(NumPhases(frames), ObservationWeights(candidates));
  ReweightStats stats;
  UpdateObservationWeightsByPhase(frames, candidates, poses, photometric, options.loss, context,
                                  &weights, &stats);
  *report = SolveReport();
  report->initial_cost = 0.5 * stats.robust_cost;
  report->usable = true;
  const double tolerance = options.solve.step_tolerance;
  DsrOptions solve_options = options;
  std::string why;
  int solves = 0;
  for (; solves < kMaxReweightings; ++solves) {
    if (options.photometric) solve_options.initial_photometric = photometric;
    SolveReport part;
    if (!SolveOnce(frames, candidates, poses, solve_options, weights.data(), &part, error)) {
      return false;
    }
    // Sum the solves: iteration records follow one another, renumbered.
    for (IterationRecord record : part.iterations) {
      record.iteration += report->num_iterations;
      record.seconds += report->seconds;
      report->iterations.push_back(record);
    }
    report->num_iterations += part.num_iterations;
    report->seconds += part.seconds;
    report->jacobian_passes += part.jacobian_passes;
    report->cost_passes += part.cost_passes;
    report->observations_per_iteration = part.observations_per_iteration;
    report->termination = part.termination;
    if (!part.usable) {  // the report keeps the last usable poses and their weights' cost
      report->usable = false;
      ++solves;
      why = "weighted solve " + std::to_string(solves) + " not usable";
      break;
    }
    const double motion = LargestMotionVoxels(frames, poses, part.frame_from_world);
    poses = part.frame_from_world;
    if (options.photometric) photometric = part.photometric;
    UpdateObservationWeightsByPhase(frames, candidates, poses, photometric, options.loss, context,
                                    &weights, &stats);
    if (tolerance > 0.0 ? motion < tolerance
                        : (stats.max_weight_change <= kWeightChangeTolerance || motion == 0.0)) {
      ++solves;
      why = "converged";
      break;
    }
  }
  if (why.empty()) why = "stopped at the limit of " + std::to_string(kMaxReweightings) + " solves";
  report->termination = options.loss.ToString() + " loss, " + std::to_string(solves) +
                        " reweighted solves (" + why + "); last solve: " + report->termination;
  report->frame_from_world = poses;
  report->photometric = photometric;
  report->final_cost = 0.5 * stats.robust_cost;
  report->usable = report->usable && std::isfinite(report->final_cost);
  report->seconds_per_iteration = report->seconds / std::max(1, report->num_iterations);
  return true;
}

// options.initial_photometric is empty or has one entry per frame; else false with `error`.
bool InitialPhotometricCountMatches(const DsrOptions& options, size_t num_frames,
                                    std::string* error) {
  if (options.initial_photometric.empty() || options.initial_photometric.size() == num_frames) {
    return true;
  }
  *error = "initial photometric parameters: " + std::to_string(options.initial_photometric.size()) +
           " for " + std::to_string(num_frames) + " frames";
  return false;
}

}  // namespace

bool SolveDsr(const std::vector<Frame>& frames,
              const CandidateSet& candidates,
              const std::vector<Eigen::Isometry3d>& initial_frame_from_world,
              const DsrOptions& options,
              SolveReport* report,
              std::string* error) {
  if (!InitialPhotometricCountMatches(options, frames.size(), error)) return false;
  if (!options.loss.Validate(error)) {
    *error = PrefixFieldPaths("loss", *error);
    return false;
  }
  if (options.loss.IsSquared()) {
    return SolveOnce(frames, candidates, initial_frame_from_world, options, nullptr, report,
                     error);
  }
  return SolveReweighted(frames, candidates, initial_frame_from_world, options, report, error);
}

bool SolvePhotometricAtPoses(const std::vector<Frame>& frames,
                             const CandidateSet& candidates,
                             const std::vector<Eigen::Isometry3d>& frame_from_world,
                             const DsrOptions& options,
                             SolveReport* report,
                             std::string* error) {
  DsrOptions photometric_options = options;
  photometric_options.photometric = true;
  photometric_options.loss = RobustLoss();
  photometric_options.gauge = Gauge::kFrame0;  // the poses are constant
  if (!photometric_options.Validate(error)) return false;
  if (!InitialPhotometricCountMatches(options, frames.size(), error)) return false;
  DsrProblem dsr(frames, candidates, frame_from_world, photometric_options);
  for (size_t i = 1; i < frames.size(); ++i) {
    dsr.problem().SetParameterBlockConstant(dsr.pose_parameters(i));
  }
  if (!RunCeres(options, "dsr-photometric", nullptr, &dsr, report, error)) return false;
  report->frame_from_world = frame_from_world;
  report->photometric = dsr.PhotometricParameters();
  report->observations_per_iteration = dsr.LastObservations();
  return true;
}

}  // namespace dsr
