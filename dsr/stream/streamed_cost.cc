#include "dsr/stream/streamed_cost.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

#include <Eigen/Eigenvalues>
#include <glog/logging.h>

#include "dsr/geometry/se3.h"
#include "dsr/solve/convergence.h"

namespace dsr {
namespace {

// Eigenvalues of H below this fraction of the largest are treated as zero (rounding).
constexpr double kRelativeEigenvalueFloor = 1e-14;

}  // namespace

void CompressNormalEquations(const Eigen::MatrixXd& hessian,
                             const Eigen::VectorXd& gradient,
                             double cost,
                             Eigen::VectorXd* residual,
                             Eigen::MatrixXd* jacobian) {
  const int n = static_cast<int>(hessian.rows());
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eigen(hessian);
  const Eigen::VectorXd& lambda = eigen.eigenvalues();
  const Eigen::MatrixXd& v = eigen.eigenvectors();
  const double floor = kRelativeEigenvalueFloor * std::max(0.0, lambda.maxCoeff());
  residual->setZero(n + 1);
  jacobian->setZero(n + 1, n);
  double explained = 0.0;
  for (int e = 0; e < n; ++e) {
    if (!(lambda[e] > floor) || lambda[e] <= 0.0) continue;
    const double s = std::sqrt(lambda[e]);
    jacobian->row(e) = s * v.col(e).transpose();
    (*residual)[e] = v.col(e).dot(gradient) / s;
    explained += (*residual)[e] * (*residual)[e];
  }
  // |r|^2 = f: the part of the cost the linear model cannot change.
  (*residual)[n] = std::sqrt(std::max(0.0, cost - explained));
}

namespace {

// Tangent parameters per frame.
int FrameParameters(bool photometric) { return photometric ? kWideJacobianSize : kJacobianSize; }

}  // namespace

StreamedPoseCost::StreamedPoseCost(int num_frames,
                                   const Eigen::Isometry3d& frame0_from_world,
                                   bool photometric,
                                   Gauge gauge)
    : num_frames_(num_frames),
      frame0_from_world_(frame0_from_world),
      photometric_(photometric),
      first_pose_block_frame_(gauge == Gauge::kMean ? 0 : 1),
      num_pose_blocks_(num_frames - first_pose_block_frame_) {
  const int free = num_frames - 1;
  CHECK_GE(free, 1);
  const int p = FrameParameters(photometric_);
  if (gauge == Gauge::kMean) {
    for (int k = 0; k < kPoseTangentSize; ++k) kept_parameters_.push_back(k);
  }
  for (int k = p; k < p * num_frames_; ++k) kept_parameters_.push_back(k);
  set_num_residuals(static_cast<int>(kept_parameters_.size()) + 1);
  for (int i = 0; i < num_pose_blocks_; ++i) {
    mutable_parameter_block_sizes()->push_back(kPoseAmbientSize);
  }
  if (photometric) {
    for (int i = 0; i < free; ++i) mutable_parameter_block_sizes()->push_back(2);
  }
}

StreamedEvaluationPolicy EvaluationPolicyFor(const std::vector<Frame>& frames,
                                             const SolveOptions& solve) {
  StreamedEvaluationPolicy policy;
  policy.frames = &frames;
  policy.step_tolerance_voxels = solve.step_tolerance;
  policy.speculate = policy.lazy_final = solve.reuse_evaluations;
  return policy;
}

bool StreamedPoseCost::Evaluate(double const* const* parameters,
                                double* residuals,
                                double** jacobians) const {
  const int m = num_frames_;
  const int free = m - 1;
  const int blocks = num_pose_blocks_;
  const int first = first_pose_block_frame_;
  const int n = num_residuals() - 1;
  // The point: every free parameter, poses first (what a pass is cached by).
  std::vector<double> flat(static_cast<size_t>(blocks) * kPoseAmbientSize +
                           (photometric_ ? 2 * free : 0));
  for (int b = 0; b < blocks; ++b) {
    std::copy(parameters[b], parameters[b] + kPoseAmbientSize, flat.begin() + b * kPoseAmbientSize);
  }
  std::vector<Eigen::Isometry3d> poses(m);
  poses[0] = frame0_from_world_;
  for (int i = first; i < m; ++i) poses[i] = ParametersToPose(parameters[i - first]);
  std::vector<Photometric> photometric;
  if (photometric_) {
    photometric.resize(m);  // frame 0: the gauge
    for (int i = 1; i < m; ++i) {
      const double* x = parameters[blocks + i - 1];
      photometric[i] = {x[0], x[1]};
      flat[blocks * kPoseAmbientSize + 2 * (i - 1)] = x[0];
      flat[blocks * kPoseAmbientSize + 2 * (i - 1) + 1] = x[1];
    }
  }
  const bool with_jacobian = jacobians != nullptr;
  const bool same_point = !pass_parameters_.empty() && flat == pass_parameters_;

  if (!with_jacobian) {  // a trial point
    if (last_was_cost_only_) speculate_next_ = false;  // the previous trial was rejected
    last_was_cost_only_ = true;
    if (!same_point) {
      // Would this step end the solve if accepted (solve/convergence.h's rule)?
      bool final_step = false;
      pass_motion_ = 0.0;
      if (policy_.frames != nullptr && policy_.step_tolerance_voxels > 0.0 &&
          static_cast<int>(accepted_poses_.size()) == m) {
        pass_motion_ = LargestMotionVoxels(*policy_.frames, accepted_poses_, poses);
        final_step = RemainingMotionVoxels(pass_motion_, accepted_motion_) <
                     policy_.step_tolerance_voxels;
      }
      const bool speculate = policy_.speculate && speculate_next_ && !final_step;
      Accumulate(poses, photometric, speculate, &pass_);
      ++(speculate ? counts_.jacobian_passes : counts_.cost_passes);
      pass_parameters_ = flat;
      pass_has_jacobian_ = speculate;
      pass_is_final_ = final_step && policy_.lazy_final;
      trial_ends_solve_ = final_step;
    }
    last_observations_ = pass_.observations;
    if (!std::isfinite(pass_.cost)) return false;
    std::fill(residuals, residuals + n, 0.0);
    residuals[n] = std::sqrt(pass_.cost);
    return true;
  }

  // The current point (iteration 0, or a step Ceres accepted).
  const bool accepted_trial = last_was_cost_only_ && same_point;
  last_was_cost_only_ = false;
  if (accepted_trial) {
    speculate_next_ = true;
    accepted_motion_ = pass_motion_;
  }
  if (same_point && pass_has_jacobian_) {
    accepted_ = pass_;
  } else if (same_point && pass_is_final_ && static_cast<int>(accepted_poses_.size()) == m) {
    // The solve ends here: the previous point's Gauss-Newton model, this point's cost.
    accepted_.cost = pass_.cost;
    accepted_.observations = pass_.observations;
    accepted_poses_ = poses;
    last_observations_ = accepted_.observations;
    if (!std::isfinite(accepted_.cost)) return false;
    return WriteJacobianEvaluation(accepted_, /*exact_cost=*/true, parameters, residuals,
                                   jacobians);
  } else {
    Accumulate(poses, photometric, true, &accepted_);
    ++counts_.jacobian_passes;
    pass_ = accepted_;
    pass_parameters_ = flat;
    pass_has_jacobian_ = true;
    pass_is_final_ = false;
  }
  accepted_poses_ = poses;
  last_observations_ = accepted_.observations;
  if (!std::isfinite(accepted_.cost)) return false;
  return WriteJacobianEvaluation(accepted_, /*exact_cost=*/false, parameters, residuals, jacobians);
}

const NormalEquations& StreamedPoseCost::EvaluateWithJacobiansAt(
    double const* const* parameters) const {
  std::vector<double> residuals(num_residuals());
  std::vector<std::vector<double>> jacobian_storage;
  std::vector<double*> jacobians;
  for (int32_t size : parameter_block_sizes()) {
    jacobian_storage.emplace_back(static_cast<size_t>(num_residuals()) * size);
    jacobians.push_back(jacobian_storage.back().data());
  }
  if (!Evaluate(parameters, residuals.data(), jacobians.data())) {
    accepted_.cost = std::numeric_limits<double>::quiet_NaN();
  }
  return accepted_;
}

const NormalEquations* StreamedPoseCost::PassAt(
    const std::vector<const double*>& free_blocks,
    const std::vector<const double*>& photometric_blocks) const {
  const size_t free = num_frames_ - 1;
  const size_t blocks = num_pose_blocks_;
  if (pass_parameters_.empty() || free_blocks.size() != blocks ||
      photometric_blocks.size() != (photometric_ ? free : 0)) {
    return nullptr;
  }
  for (size_t i = 0; i < blocks; ++i) {
    if (!std::equal(free_blocks[i], free_blocks[i] + kPoseAmbientSize,
                    pass_parameters_.begin() + i * kPoseAmbientSize)) {
      return nullptr;
    }
  }
  for (size_t i = 0; i < photometric_blocks.size(); ++i) {
    if (!std::equal(photometric_blocks[i], photometric_blocks[i] + 2,
                    pass_parameters_.begin() + blocks * kPoseAmbientSize + 2 * i)) {
      return nullptr;
    }
  }
  return &pass_;
}

bool StreamedPoseCost::WriteJacobianEvaluation(const NormalEquations& system,
                                               bool exact_cost,
                                               double const* const* parameters,
                                               double* residuals,
                                               double** jacobians) const {
  const int m = num_frames_;
  const int p = FrameParameters(photometric_);
  const int n = num_residuals() - 1;
  Eigen::VectorXd r;
  Eigen::MatrixXd jac;
  if (first_pose_block_frame_ == 1) {  // the kept parameters are the trailing n
    CompressNormalEquations(system.hessian.bottomRightCorner(n, n), system.gradient.tail(n),
                            system.cost, &r, &jac);
  } else {
    CompressNormalEquations(system.hessian(kept_parameters_, kept_parameters_),
                            system.gradient(kept_parameters_), system.cost, &r, &jac);
  }
  if (exact_cost) {
    // A model taken from another point may explain more than this point's cost: shrink
    // it so that |r'|^2 is the cost (the step it implies is never taken).
    const double explained = r.head(n).squaredNorm();
    if (explained > system.cost) {
      r.head(n) *= std::sqrt(system.cost / explained);
      r[n] = 0.0;
    }
  }
  if (!r.allFinite() || !jac.allFinite()) return false;
  Eigen::Map<Eigen::VectorXd>(residuals, n + 1) = r;
  const int first = first_pose_block_frame_;
  // Frame i's first column in the kept parameters (frame 0 keeps only its pose).
  const int shift = first == 0 ? kPoseTangentSize : 0;
  for (int i = first; i < m; ++i) {
    const int column = i == 0 ? 0 : shift + p * (i - 1);
    if (jacobians[i - first] != nullptr) {
      Eigen::Map<Eigen::Matrix<double, Eigen::Dynamic, kPoseAmbientSize, Eigen::RowMajor>> out(
          jacobians[i - first], n + 1, kPoseAmbientSize);
      out.noalias() = jac.middleCols<6>(column) * TangentToAmbientJacobian(parameters[i - first]);
    }
    // [log_gain, offset] are their own tangent coordinates.
    const int photometric_block = num_pose_blocks_ + i - 1;
    if (photometric_ && i > 0 && jacobians[photometric_block] != nullptr) {
      Eigen::Map<Eigen::Matrix<double, Eigen::Dynamic, 2, Eigen::RowMajor>>(
          jacobians[photometric_block], n + 1, 2) = jac.middleCols<2>(column + 6);
    }
  }
  return true;
}

bool SolveStreamedPoses(const std::vector<Frame>& frames,
                        const std::vector<Eigen::Isometry3d>& initial_frame_from_world,
                        int64_t num_voxels,
                        int num_blocks,
                        const StreamedBlockFactory& make_block,
                        const SolveOptions& solve,
                        const std::string& label,
                        SolveReport* report,
                        std::string* error) {
  const int m = static_cast<int>(frames.size());
  CHECK_GE(m, 2);
  CHECK_EQ(static_cast<int>(initial_frame_from_world.size()), m);
  static PoseManifold* const kManifold = new PoseManifold();  // shared, never freed
  ceres::Problem::Options problem_options;
  problem_options.manifold_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  ceres::Problem problem(problem_options);
  std::vector<std::array<double, kPoseAmbientSize>> poses(m);
  std::vector<double*> free_blocks;
  std::vector<const double*> pose_blocks(m, nullptr);
  for (int i = 0; i < m; ++i) PoseToParameters(initial_frame_from_world[i], poses[i].data());
  for (int i = 1; i < m; ++i) {
    problem.AddParameterBlock(poses[i].data(), kPoseAmbientSize, kManifold);
    free_blocks.push_back(poses[i].data());
    pose_blocks[i] = poses[i].data();
  }
  const int64_t blocks = std::max<int64_t>(1, std::min<int64_t>(num_blocks, num_voxels));
  std::vector<const StreamedPoseCost*> costs;
  for (int64_t c = 0; c < blocks; ++c) {
    StreamedPoseCost* cost = make_block(num_voxels * c / blocks, num_voxels * (c + 1) / blocks);
    cost->set_policy(EvaluationPolicyFor(frames, solve));
    costs.push_back(cost);
    problem.AddResidualBlock(cost, nullptr, free_blocks);
  }
  ceres::Solver::Options options;
  solve.ToCeres(ceres::DENSE_QR, &options);
  // The streamed blocks thread internally over fixed voxel blocks (deterministic); Ceres
  // evaluates the few blocks one after another.
  options.num_threads = 1;
  ProgressCallback progress(solve.progress_prefix + label, solve.progress, solve.on_iteration);
  options.callbacks.push_back(&progress);
  PoseStepCallback stop(&frames, pose_blocks, solve.step_tolerance,
                        solve.max_rejected_steps);
  stop.SetTrialEndsSolve([&costs] { return EveryTrialEndsSolve(costs); });
  stop.AddTo(&options);
  std::string why;
  if (!options.IsValid(&why)) {
    *error = "invalid solver options: " + why;
    return false;
  }
  ceres::Solver::Summary summary;
  ceres::Solve(options, &problem, &summary);
  FillReport(summary, progress, report);
  if (!stop.reason().empty()) report->termination = stop.reason();
  report->frame_from_world.clear();
  for (const auto& x : poses) report->frame_from_world.push_back(ParametersToPose(x.data()));
  report->observations_per_iteration = 0;
  for (const StreamedPoseCost* cost : costs) {
    report->observations_per_iteration += cost->last_observations();
    report->jacobian_passes += cost->pass_counts().jacobian_passes;
    report->cost_passes += cost->pass_counts().cost_passes;
  }
  return true;
}

}  // namespace dsr
