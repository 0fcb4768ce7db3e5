// Direct bundle adjustment in Ceres (docs/design.md section 3).
#include "dsr/dba/dba_problem.h"

#include <cmath>
#include <cstring>
#include <sstream>

#include <glog/logging.h>

#include "dsr/solve/convergence.h"
#include "dsr/stream/reduced_system.h"
#include "dsr/stream/streamed_cost.h"
#include "dsr/util/option_fields.h"
#include "dsr/util/parallel.h"

namespace dsr {

namespace {

// Both residuals. Without photometric parameters (`photometric` null) e = M - I exactly.
// With them, in the frame's own grey levels (docs/design.md 2.8): with u = 1 / gain,
//   e = u (M - offset) - I,
//   d e / d delta = -J,  d e / d M = u,  d e / d [log_gain, offset] = [-u (M - offset), -u],
// so frames whose gain differs count their noise alike. Jacobian pointers may be null.
void EvaluateObservation(const Frame& frame,
                         const Eigen::Vector3d& voxel_center_in_world,
                         const double* pose,
                         double panorama_intensity,
                         const double* photometric,
                         double* residual,
                         double* pose_jacobian,
                         double* intensity_jacobian,
                         double* photometric_jacobian) {
  double intensity;
  RowVector6d jacobian_tangent;
  const bool observed =
      ObserveSample(frame, ParametersToPose(pose), voxel_center_in_world, &intensity,
                    pose_jacobian != nullptr ? &jacobian_tangent : nullptr);
  if (!observed) {  // sigma_ij = 0: zero residual, zero Jacobian.
    *residual = 0.0;
    if (pose_jacobian != nullptr) {
      std::memset(pose_jacobian, 0, sizeof(double) * kPoseAmbientSize);
    }
    if (intensity_jacobian != nullptr) *intensity_jacobian = 0.0;
    if (photometric_jacobian != nullptr) photometric_jacobian[0] = photometric_jacobian[1] = 0.0;
    return;
  }
  if (photometric == nullptr) {
    *residual = panorama_intensity - intensity;
    if (intensity_jacobian != nullptr) *intensity_jacobian = 1.0;
  } else {
    const double unit = Photometric{photometric[0], photometric[1]}.unit();
    const double panorama_in_frame = unit * (panorama_intensity - photometric[1]);
    *residual = panorama_in_frame - intensity;
    if (intensity_jacobian != nullptr) *intensity_jacobian = unit;
    if (photometric_jacobian != nullptr) {
      photometric_jacobian[0] = -panorama_in_frame;  // d e / d log_gain
      photometric_jacobian[1] = -unit;               // d e / d offset
    }
  }
  if (pose_jacobian != nullptr) {
    // d e / d delta = -J_ij, placed in the ambient block via the MinusJacobian (se3.h).
    Eigen::Map<Eigen::Matrix<double, 1, kPoseAmbientSize>> ambient(pose_jacobian);
    ambient = -jacobian_tangent * TangentToAmbientJacobian(pose);
  }
}

double* Block(double** jacobians, int i) { return jacobians != nullptr ? jacobians[i] : nullptr; }

// The mean gauge's stiffness at the start, DSR's (DbaProblem's comment). The weights of a
// robust loss live only for this pass, before the problem's own storage is built.
Vector6d GaugeStiffness(const std::vector<Frame>& frames,
                        const CandidateSet& candidates,
                        const std::vector<Eigen::Isometry3d>& frame_from_world,
                        const std::vector<Photometric>& photometric,
                        const RobustLoss& loss,
                        const StreamContext& context) {
  if (loss.IsSquared()) {
    return MeanGaugeStiffnessAt(frames, candidates, frame_from_world, photometric, nullptr,
                                context);
  }
  // One set of weights per phase (each phase's observations have their own voxel locations).
  std::vector<ObservationWeights> weights(NumPhases(frames), ObservationWeights(candidates));
  ReweightStats stats;
  UpdateObservationWeightsByPhase(frames, candidates, frame_from_world, photometric, loss,
                                  context, &weights, &stats);
  return MeanGaugeStiffnessAt(frames, candidates, frame_from_world, photometric, weights.data(),
                              context);
}

}  // namespace

bool DbaResidual::Evaluate(double const* const* parameters,
                           double* residuals,
                           double** jacobians) const {
  EvaluateObservation(*frame_, voxel_center_in_world_, parameters[0], parameters[1][0], nullptr,
                      residuals, Block(jacobians, 0), Block(jacobians, 1), nullptr);
  return true;
}

bool DbaPhotometricResidual::Evaluate(double const* const* parameters,
                                      double* residuals,
                                      double** jacobians) const {
  EvaluateObservation(*frame_, voxel_center_in_world_, parameters[0], parameters[1][0],
                      parameters[2], residuals, Block(jacobians, 0), Block(jacobians, 1),
                      Block(jacobians, 2));
  return true;
}

bool DbaOptions::Validate(std::string* error) const {
  if (!solve.Validate(error)) {
    *error = PrefixFieldPaths("solve", *error);
    return false;
  }
  if (!std::isfinite(memory_budget_mb)) {
    *error = FieldError("memory_budget_mb", memory_budget_mb, "must be finite");
    return false;
  }
  if (!loss.Validate(error)) {
    *error = PrefixFieldPaths("loss", *error);
    return false;
  }
  return ValidateInitialPhotometric(photometric, initial_photometric, error);
}

std::string DbaMemoryEstimate::ToString() const {
  std::ostringstream s;
  s.precision(3);
  s << bytes / 1048576.0 << " MiB (" << residual_blocks << " residual blocks, "
    << intensity_blocks << " intensity blocks)";
  return s.str();
}

DbaMemoryEstimate EstimateDbaMemory(const CandidateSet& candidates,
                                    int num_frames,
                                    ceres::LinearSolverType linear_solver,
                                    bool photometric,
                                    int num_phases) {
  // Per-item costs in bytes for Ceres 2.1: a residual block (ResidualBlock, the DbaResidual
  // object, parameter pointers, its Jacobian row (8 doubles) and row-block structure in the
  // BlockSparseMatrix, residual, program copies) and an intensity block (ParameterBlock, map
  // entry, E^T E block, state copies). Checked against peak RSS of dsr_register --mode=dba
  // minus --mode=dsr on the same 6-frame sequences (DENSE_SCHUR, one level): 76k, 194k,
  // 559k and 929k residual blocks (6 per intensity block) cost 526-534 bytes per residual
  // block all-inclusive; this estimate gives about 690, i.e. it errs 30% on the safe side.
  constexpr double kBytesPerResidualBlock = 560.0;
  constexpr double kBytesPerIntensityBlock = 420.0;
  // A photometric residual block has a third parameter block: one more parameter pointer
  // (in the block and in its program copy) and 2 more Jacobian entries (in the
  // BlockSparseMatrix, the evaluator's scratch and the Schur F block), about 6 doubles.
  // The per-frame [log_gain, offset] blocks themselves are negligible; the reduced
  // system has 8 parameters per frame instead of 6.
  constexpr double kBytesPerPhotometricResidualBlock = 48.0;
  DbaMemoryEstimate e;
  e.residual_blocks = candidates.NumObservations() * num_phases;
  e.intensity_blocks = candidates.num_voxels() * num_phases;
  double bytes = kBytesPerResidualBlock * e.residual_blocks +
                 kBytesPerIntensityBlock * e.intensity_blocks;
  if (photometric) bytes += kBytesPerPhotometricResidualBlock * e.residual_blocks;
  const double pose_params = (photometric ? 8.0 : 6.0) * (num_frames - 1);
  const double params = pose_params + e.intensity_blocks;
  // Non-zeros of one residual's Jacobian row in tangent coordinates: pose, intensity and
  // with photometric parameters [log_gain, offset].
  const double row = photometric ? 9.0 : 7.0;
  if (linear_solver == ceres::DENSE_QR || linear_solver == ceres::DENSE_NORMAL_CHOLESKY) {
    // Dense Jacobian (rows x columns) or normal matrix, plus a factorisation copy.
    const double rows = linear_solver == ceres::DENSE_QR ? e.residual_blocks : params;
    bytes += 2.0 * 8.0 * rows * params;
  } else if (linear_solver == ceres::SPARSE_NORMAL_CHOLESKY) {
    // J^T J and its Cholesky factor: the pose rows fill in against every intensity.
    bytes += 2.0 * 12.0 * (row * e.residual_blocks + pose_params * params);
  } else {
    // Schur solvers: reduced camera matrix and per-voxel E^T E / F^T E workspaces.
    bytes += 8.0 * (pose_params * pose_params * 3.0 + (row + 1.0) * e.residual_blocks);
  }
  e.bytes = static_cast<int64_t>(bytes);
  return e;
}

DbaProblem::DbaProblem(const std::vector<Frame>& frames,
                       const CandidateSet& candidates,
                       const std::vector<Eigen::Isometry3d>& frame_from_world,
                       const std::vector<Photometric>& photometric,
                       const RobustLoss& loss,
                       Gauge gauge,
                       const StreamContext& context)
    : loss_(loss.CeresLoss()) {
  const int m = static_cast<int>(frames.size());
  CHECK_EQ(candidates.num_frames, m);
  CHECK_EQ(static_cast<int>(frame_from_world.size()), m);
  CHECK(photometric.empty() || static_cast<int>(photometric.size()) == m);
  // The correction each frame's observations get (identity without photometric blocks).
  std::vector<Photometric> correction(m);
  if (!photometric.empty()) correction = photometric;
  ceres::Problem::Options problem_options;
  problem_options.manifold_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  problem_options.cost_function_ownership = ceres::TAKE_OWNERSHIP;
  problem_options.loss_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;  // loss_, shared
  problem_ = std::make_unique<ceres::Problem>(problem_options);
  static PoseManifold* const kManifold = new PoseManifold();  // shared, never freed

  poses_.resize(m);
  std::vector<double*> all_poses;
  for (int i = 0; i < m; ++i) {
    PoseToParameters(frame_from_world[i], poses_[i].data());
    problem_->AddParameterBlock(poses_[i].data(), kPoseAmbientSize, kManifold);
    all_poses.push_back(poses_[i].data());
  }
  if (gauge == Gauge::kMean) {
    std::vector<Eigen::Vector3d> centres;
    for (const Frame& frame : frames) centres.push_back(frame.ValidCentre());
    const Vector6d stiffness =
        GaugeStiffness(frames, candidates, frame_from_world, photometric, loss, context);
    problem_->AddResidualBlock(new MeanPosePrior(frame_from_world, std::move(centres), stiffness),
                               nullptr, all_poses);
  } else {
    problem_->SetParameterBlockConstant(poses_[0].data());
  }
  if (!photometric.empty()) {
    photometric_.resize(m);
    for (int i = 0; i < m; ++i) {
      photometric_[i] = {photometric[i].log_gain, photometric[i].offset};
      problem_->AddParameterBlock(photometric_[i].data(), 2);
    }
    problem_->SetParameterBlockConstant(photometric_[0].data());
  }

  // Each phase's one-phase frames (a 3D sequence's are the caller's frames): one intensity
  // block per (voxel, phase), every phase's residuals on the view's one pose block.
  phase_frames_ = std::make_unique<FramesByPhase>(frames);
  const FramesByPhase& phase_frames = *phase_frames_;
  const int phases = phase_frames.size();
  const int64_t n = candidates.num_voxels();
  intensities_.assign(n * phases, 0.0);
  for (int p = 0; p < phases; ++p) {
    InitialIntensities(phase_frames[p], candidates, frame_from_world, correction,
                       &intensities_[p * n]);
  }
  for (int64_t v = 0; v < n; ++v) {
    const Eigen::Vector3d centre = candidates.VoxelCenter(v);
    for (int p = 0; p < phases; ++p) {
      for (int i = 0; i < m; ++i) {
        if (!(candidates.observers[v] >> i & 1u)) continue;
        const Frame* frame = &phase_frames[p][i];
        if (photometric_.empty()) {
          problem_->AddResidualBlock(new DbaResidual(frame, centre), loss_.get(),
                                     poses_[i].data(), &intensities_[p * n + v]);
        } else {
          problem_->AddResidualBlock(new DbaPhotometricResidual(frame, centre), loss_.get(),
                                     poses_[i].data(), &intensities_[p * n + v],
                                     photometric_[i].data());
        }
        ++num_residual_blocks_;
      }
    }
  }
}

void DbaProblem::InitialIntensities(const std::vector<Frame>& frames,
                                    const CandidateSet& candidates,
                                    const std::vector<Eigen::Isometry3d>& frame_from_world,
                                    const std::vector<Photometric>& correction,
                                    double* intensities) {
  // Initial intensities: the minimiser over M of the squared residuals, the per-voxel mean
  // of the observations (paper eq. 10); with photometric blocks the mean of the corrected
  // observations weighted by u_i^2 = 1 / gain_i^2 (docs/design.md 2.8), which is the plain
  // mean at the gauge.
  const int m = static_cast<int>(frames.size());
  const int64_t n = candidates.num_voxels();
  ParallelFor(0, n, 0, [&](int64_t v) {
    const Eigen::Vector3d p = candidates.VoxelCenter(v);
    double sum = 0.0, total = 0.0;
    for (int i = 0; i < m; ++i) {
      double value;
      if ((candidates.observers[v] >> i & 1u) &&
          ObserveSample(frames[i], frame_from_world[i], p, &value, nullptr)) {
        const double w = correction[i].unit() * correction[i].unit();
        sum += w * correction[i].Correct(value);
        total += w;
      }
    }
    if (total == 0.0) {
      // Nobody observes the voxel yet (a margin candidate). Start from the frames' values
      // ignoring the mask, so a sample that enters the field of view during the solve
      // meets a plausible intensity instead of 0 (which would make the cost jump).
      for (int i = 0; i < m; ++i) {
        if (!(candidates.observers[v] >> i & 1u)) continue;
        const double w = correction[i].unit() * correction[i].unit();
        sum += w * correction[i].Correct(
                       frames[i].InterpolateValue(frames[i].ToIndex(frame_from_world[i] * p)));
        total += w;
      }
    }
    intensities[v] = total > 0.0 ? sum / total : 0.0;
  });
}

std::vector<Eigen::Isometry3d> DbaProblem::Poses() const {
  std::vector<Eigen::Isometry3d> out;
  for (const auto& x : poses_) out.push_back(ParametersToPose(x.data()));
  return out;
}

std::vector<Photometric> DbaProblem::PhotometricParameters() const {
  std::vector<Photometric> out;
  for (const auto& x : photometric_) out.push_back({x[0], x[1]});
  return out;
}

void DbaProblem::SetPoses(const std::vector<Eigen::Isometry3d>& frame_from_world) {
  CHECK_EQ(frame_from_world.size(), poses_.size());
  for (size_t i = 0; i < poses_.size(); ++i)
    PoseToParameters(frame_from_world[i], poses_[i].data());
}

std::shared_ptr<ceres::ParameterBlockOrdering> DbaProblem::MakeOrdering() {
  auto ordering = std::make_shared<ceres::ParameterBlockOrdering>();
  for (double& value : intensities_) ordering->AddElementToGroup(&value, 0);
  for (auto& x : poses_) ordering->AddElementToGroup(x.data(), 1);
  for (auto& x : photometric_) ordering->AddElementToGroup(x.data(), 1);
  return ordering;
}

bool SolveDba(const std::vector<Frame>& frames,
              const CandidateSet& candidates,
              const std::vector<Eigen::Isometry3d>& initial_frame_from_world,
              const DbaOptions& options,
              SolveReport* report,
              std::vector<float>* intensities,
              std::string* error) {
  const ceres::LinearSolverType linear_solver = options.solve.LinearSolverOr(ceres::DENSE_SCHUR);
  const DbaMemoryEstimate estimate =
      EstimateDbaMemory(candidates, static_cast<int>(frames.size()), linear_solver,
                        options.photometric, NumPhases(frames));
  const double budget = options.memory_budget_mb > 0.0
                            ? options.memory_budget_mb * 1048576.0
                            : 0.5 * static_cast<double>(PhysicalMemoryBytes());
  if (budget > 0.0 && estimate.bytes > budget) {
    std::ostringstream s;
    s.precision(4);
    s << "DBA problem needs an estimated " << estimate.ToString() << " with "
      << ceres::LinearSolverTypeToString(linear_solver)
      << ", over the memory budget of " << budget / 1048576.0 << " MiB (memory_budget_mb="
      << options.memory_budget_mb << "); use mode=dsr, which needs no per-observation "
         "storage, or a coarser panorama (panorama_spacing)";
    *error = s.str();
    return false;
  }

  if (!options.initial_photometric.empty() &&
      options.initial_photometric.size() != frames.size()) {
    *error = "initial photometric parameters: " +
             std::to_string(options.initial_photometric.size()) + " for " +
             std::to_string(frames.size()) + " frames";
    return false;
  }
  std::vector<Photometric> start;
  if (options.photometric) {
    start = options.initial_photometric.empty() ? std::vector<Photometric>(frames.size())
                                                : options.initial_photometric;
  }
  if (!options.loss.Validate(error)) {
    *error = PrefixFieldPaths("loss", *error);
    return false;
  }
  DbaProblem dba(frames, candidates, initial_frame_from_world, start, options.loss, options.gauge,
                 StreamContextFor(options.solve));
  ceres::Solver::Options solver_options;
  options.solve.ToCeres(ceres::DENSE_SCHUR, &solver_options);
  if (ceres::IsSchurType(solver_options.linear_solver_type)) {
    solver_options.linear_solver_ordering = dba.MakeOrdering();
  }
  ProgressCallback progress(options.solve.progress_prefix + "dba", options.solve.progress,
                            options.solve.on_iteration);
  solver_options.callbacks.push_back(&progress);
  // Frame 0's block too when it is free (the rule measures motion against frame 0's).
  std::vector<const double*> pose_blocks(frames.size(), nullptr);
  for (size_t i = options.gauge == Gauge::kMean ? 0 : 1; i < frames.size(); ++i) {
    pose_blocks[i] = dba.pose_parameters(i);
  }
  PoseStepCallback stop(&frames, pose_blocks, options.solve.step_tolerance,
                        options.solve.max_rejected_steps);
  stop.AddTo(&solver_options);
  std::string why;
  if (!solver_options.IsValid(&why)) {
    *error = "invalid solver options: " + why;
    return false;
  }
  ceres::Solver::Summary summary;
  ceres::Solve(solver_options, &dba.problem(), &summary);
  FillReport(summary, progress, report);
  if (!stop.reason().empty()) report->termination = stop.reason();
  report->frame_from_world = dba.Poses();
  report->photometric = dba.PhotometricParameters();
  report->observations_per_iteration = dba.num_residual_blocks();
  if (intensities != nullptr) {
    intensities->resize(dba.num_intensities());
    for (int64_t v = 0; v < dba.num_intensities(); ++v) {
      (*intensities)[v] = static_cast<float>(*dba.intensity(v));
    }
  }
  return true;
}

}  // namespace dsr
