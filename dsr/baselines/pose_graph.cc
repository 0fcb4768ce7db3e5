// Lie normalisation's pose graph: min sum ||Log(Z_ki^-1 T_k T_i^-1)||^2 on SE(3).
#include <array>

#include <ceres/ceres.h>
#include <ceres/rotation.h>
#include <glog/logging.h>

#include "dsr/baselines/baselines.h"
#include "dsr/baselines/lie_log.h"
#include "dsr/geometry/se3.h"

namespace dsr {
namespace {

// Residual Log(Z^-1 T_k T_i^-1) for pose blocks [qx qy qz qw tx ty tz] (geometry/se3.h).
struct RelativePoseResidual {
  RelativePoseResidual(const Eigen::Isometry3d& k_from_i, const Vector6d& sqrt_information)
      : sqrt_information_(sqrt_information) {
    // Store Z^-1 = (i_from_k) as quaternion (w, x, y, z for ceres/rotation.h) and t.
    const Eigen::Isometry3d inv = k_from_i.inverse();
    const Eigen::Quaterniond q(inv.linear());
    z_inv_q_ = {q.w(), q.x(), q.y(), q.z()};
    z_inv_t_ = {inv.translation().x(), inv.translation().y(), inv.translation().z()};
  }

  template <typename T>
  bool operator()(const T* pose_i, const T* pose_k, T* residual) const {
    // Quaternions in ceres/rotation.h order (w, x, y, z).
    const T qi[4] = {pose_i[3], pose_i[0], pose_i[1], pose_i[2]};
    const T qk[4] = {pose_k[3], pose_k[0], pose_k[1], pose_k[2]};
    // T_i^-1: (qi*, -(qi* t_i)).
    const T qi_inv[4] = {qi[0], -qi[1], -qi[2], -qi[3]};
    T ti_inv[3];
    ceres::UnitQuaternionRotatePoint(qi_inv, pose_i + 4, ti_inv);
    for (int d = 0; d < 3; ++d) ti_inv[d] = -ti_inv[d];
    // A = T_k T_i^-1: (qk qi*, qk ti_inv + t_k).
    T qa[4], ta[3];
    ceres::QuaternionProduct(qk, qi_inv, qa);
    ceres::UnitQuaternionRotatePoint(qk, ti_inv, ta);
    for (int d = 0; d < 3; ++d) ta[d] += pose_k[4 + d];
    // E = Z^-1 A.
    const T qz[4] = {T(z_inv_q_[0]), T(z_inv_q_[1]), T(z_inv_q_[2]), T(z_inv_q_[3])};
    T qe[4], te[3];
    ceres::QuaternionProduct(qz, qa, qe);
    ceres::UnitQuaternionRotatePoint(qz, ta, te);
    for (int d = 0; d < 3; ++d) te[d] += T(z_inv_t_[d]);
    const T qe_xyzw[4] = {qe[1], qe[2], qe[3], qe[0]};
    LogSE3Quaternion(qe_xyzw, te, residual);
    for (int d = 0; d < 6; ++d) residual[d] *= T(sqrt_information_[d]);
    return true;
  }

  static ceres::CostFunction* Create(const RelativePose& z) {
    return new ceres::AutoDiffCostFunction<RelativePoseResidual, 6, kPoseAmbientSize,
                                           kPoseAmbientSize>(
        new RelativePoseResidual(z.k_from_i, z.sqrt_information));
  }

  Vector6d sqrt_information_;
  std::array<double, 4> z_inv_q_;
  std::array<double, 3> z_inv_t_;
};

}  // namespace

bool SolvePoseGraph(const std::vector<RelativePose>& measurements,
                    const std::vector<Eigen::Isometry3d>& initial,
                    const SolveOptions& solve,
                    std::vector<Eigen::Isometry3d>* frame_from_world,
                    SolveReport* report,
                    std::string* error,
                    double cauchy_scale) {
  const int m = static_cast<int>(initial.size());
  static PoseManifold* const kManifold = new PoseManifold();  // shared, never freed
  ceres::Problem::Options problem_options;
  problem_options.manifold_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  ceres::Problem problem(problem_options);
  std::vector<std::array<double, kPoseAmbientSize>> poses(m);
  for (int i = 0; i < m; ++i) {
    PoseToParameters(initial[i], poses[i].data());
    problem.AddParameterBlock(poses[i].data(), kPoseAmbientSize, kManifold);
  }
  problem.SetParameterBlockConstant(poses[0].data());
  for (const RelativePose& z : measurements) {
    CHECK(0 <= z.i && z.i < z.k && z.k < m);
    ceres::LossFunction* loss =
        cauchy_scale > 0.0 ? new ceres::CauchyLoss(cauchy_scale) : nullptr;  // owned by problem
    problem.AddResidualBlock(RelativePoseResidual::Create(z), loss, poses[z.i].data(),
                             poses[z.k].data());
  }
  ceres::Solver::Options options;
  SolveOptions graph = solve;
  graph.linear_solver.reset();  // a few poses: dense is right whatever the image solver was
  graph.ToCeres(ceres::DENSE_QR, &options);
  // The graph is cheap and smooth: converge tightly, independent of the image tolerances.
  options.max_num_iterations = 200;
  options.function_tolerance = 1e-14;
  options.gradient_tolerance = 1e-14;
  options.parameter_tolerance = 1e-14;
  ProgressCallback progress(solve.progress_prefix + "pose-graph", false);
  options.callbacks.push_back(&progress);
  std::string why;
  if (!options.IsValid(&why)) {
    *error = "invalid solver options: " + why;
    return false;
  }
  ceres::Solver::Summary summary;
  ceres::Solve(options, &problem, &summary);
  FillReport(summary, progress, report);
  frame_from_world->clear();
  for (const auto& x : poses) frame_from_world->push_back(ParametersToPose(x.data()));
  report->frame_from_world = *frame_from_world;
  return true;
}

}  // namespace dsr
