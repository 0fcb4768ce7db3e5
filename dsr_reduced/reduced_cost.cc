// Reduced DSR cost: per-voxel reference and streaming chunk cost (DESIGN.md section 4).
#include "dsr_reduced/reduced_cost.h"

#include <algorithm>
#include <cmath>
#include <cstring>

#include <Eigen/Eigenvalues>
#include <glog/logging.h>

#include "core/parallel.h"

namespace dsr {
namespace {

// Fixed number of accumulation blocks per voxel range: results do not depend on threads.
constexpr int64_t kMaxBlocks = 64;
// Eigenvalues of H_c below this fraction of the largest are treated as zero.
constexpr double kRelativeEigenvalueFloor = 1e-14;

// A frame's pose folded into its index map: u = a p + b, p_ij = rotation p + translation.
struct PosedFrame {
  const Frame* frame;
  Eigen::Matrix3d a;
  Eigen::Vector3d b;
  Eigen::Matrix3d rotation;
  Eigen::Vector3d translation;
};

std::vector<PosedFrame> PoseFrames(const std::vector<Frame>& frames,
                                   const std::vector<Eigen::Isometry3d>& frame_from_world) {
  std::vector<PosedFrame> out(frames.size());
  for (size_t i = 0; i < frames.size(); ++i) {
    const Eigen::Matrix3d& to_index = frames[i].index_from_physical();
    out[i].frame = &frames[i];
    out[i].rotation = frame_from_world[i].linear();
    out[i].translation = frame_from_world[i].translation();
    out[i].a = to_index * out[i].rotation;
    out[i].b = to_index * (out[i].translation - frames[i].geometry().origin_mm);
  }
  return out;
}

// Accumulates one voxel into (H upper triangle, g, f). Returns the number of observations.
int AccumulateVoxel(const std::vector<PosedFrame>& posed,
                    const Eigen::Vector3d& p,
                    uint32_t candidates,
                    bool with_jacobian,
                    Eigen::MatrixXd* hessian,
                    Eigen::VectorXd* gradient,
                    double* cost) {
  int frame_of[kMaxFrames];
  double value[kMaxFrames];
  Eigen::Matrix<double, 6, 1> jac[kMaxFrames];
  int k = 0;
  for (uint32_t bits = candidates; bits != 0; bits &= bits - 1) {
    const int f = __builtin_ctz(bits);
    const PosedFrame& pf = posed[f];
    const Eigen::Vector3d u = pf.a * p + pf.b;
    Eigen::Vector3d grad_u;
    if (!pf.frame->SampleAtIndex(u, &value[k], with_jacobian ? &grad_u : nullptr)) continue;
    if (with_jacobian) {
      const Eigen::Vector3d grad_mm = pf.frame->gradient_to_physical() * grad_u;
      const Eigen::Vector3d sample_in_frame = pf.rotation * p + pf.translation;
      jac[k].head<3>() = grad_mm;
      jac[k].tail<3>() = sample_in_frame.cross(grad_mm);  // grad^T (-[p]x)
    }
    frame_of[k++] = f;
  }
  if (k < 2) return 0;
  double mean = 0.0;
  for (int a = 0; a < k; ++a) mean += value[a];
  mean /= k;
  const double inv_k = 1.0 / k;
  for (int a = 0; a < k; ++a) {
    const double r = value[a] - mean;
    *cost += r * r;
    if (!with_jacobian) continue;
    const int fa = 6 * frame_of[a];
    gradient->segment<6>(fa) += jac[a] * r;
    // H_ab += (delta_ab - 1/k) J_a^T J_b for b >= a (upper block triangle).
    hessian->block<6, 6>(fa, fa).noalias() += (1.0 - inv_k) * jac[a] * jac[a].transpose();
    for (int b = a + 1; b < k; ++b) {
      hessian->block<6, 6>(fa, 6 * frame_of[b]).noalias() -= inv_k * jac[a] * jac[b].transpose();
    }
  }
  return k;
}

}  // namespace

VoxelReducedCost::VoxelReducedCost(std::vector<const Frame*> observers,
                                   const Eigen::Vector3d& voxel_center_in_world)
    : observers_(std::move(observers)), voxel_center_in_world_(voxel_center_in_world) {
  set_num_residuals(static_cast<int>(observers_.size()));
  for (size_t i = 0; i < observers_.size(); ++i) {
    mutable_parameter_block_sizes()->push_back(kPoseAmbientSize);
  }
}

bool VoxelReducedCost::Evaluate(double const* const* parameters,
                                double* residuals,
                                double** jacobians) const {
  const int n = static_cast<int>(observers_.size());
  std::vector<double> value(n, 0.0);
  std::vector<RowVector6d> jac(n, RowVector6d::Zero());
  std::vector<int> sigma(n, 0);
  int k = 0;
  double sum = 0.0;
  for (int i = 0; i < n; ++i) {
    if (ObserveSample(*observers_[i], ParametersToPose(parameters[i]), voxel_center_in_world_,
                      &value[i], &jac[i])) {
      sigma[i] = 1;
      ++k;
      sum += value[i];
    }
  }
  if (jacobians != nullptr) {
    for (int a = 0; a < n; ++a) {
      if (jacobians[a] != nullptr) std::memset(jacobians[a], 0, sizeof(double) * n * kPoseAmbientSize);
    }
  }
  if (k < 2) {  // mu_j = the lone observation (or none): no residual, no Jacobian.
    std::fill(residuals, residuals + n, 0.0);
    return true;
  }
  const double mean = sum / k;
  for (int i = 0; i < n; ++i) residuals[i] = sigma[i] ? value[i] - mean : 0.0;
  if (jacobians == nullptr) return true;
  for (int a = 0; a < n; ++a) {
    if (jacobians[a] == nullptr || !sigma[a]) continue;
    // d r_i / d delta_a = sigma_i sigma_a (delta_ia - 1/k) J_a, then to the ambient block.
    const Eigen::Matrix<double, 1, kPoseAmbientSize> ambient =
        jac[a] * TangentToAmbientJacobian(parameters[a]);
    Eigen::Map<Eigen::Matrix<double, Eigen::Dynamic, kPoseAmbientSize, Eigen::RowMajor>> out(
        jacobians[a], n, kPoseAmbientSize);
    for (int i = 0; i < n; ++i) {
      if (sigma[i]) out.row(i) = ((i == a ? 1.0 : 0.0) - 1.0 / k) * ambient;
    }
  }
  return true;
}

void AccumulateReducedSystem(const std::vector<Frame>& frames,
                             const CandidateSet& candidates,
                             const std::vector<Eigen::Isometry3d>& frame_from_world,
                             int64_t begin,
                             int64_t end,
                             bool with_jacobian,
                             int num_threads,
                             ReducedSystem* out) {
  const int m = static_cast<int>(frames.size());
  CHECK_EQ(static_cast<int>(frame_from_world.size()), m);
  CHECK_LE(0, begin);
  CHECK_LE(end, candidates.num_voxels());
  const std::vector<PosedFrame> posed = PoseFrames(frames, frame_from_world);
  const int64_t count = std::max<int64_t>(0, end - begin);
  const int64_t num_blocks = std::max<int64_t>(1, std::min(kMaxBlocks, count));
  const int64_t block_size = (count + num_blocks - 1) / num_blocks;
  std::vector<ReducedSystem> partial(num_blocks);
  ParallelFor(0, num_blocks, num_threads, [&](int64_t block) {
    ReducedSystem& s = partial[block];
    if (with_jacobian) {
      s.hessian.setZero(6 * m, 6 * m);
      s.gradient.setZero(6 * m);
    }
    const int64_t b0 = begin + block * block_size, b1 = std::min(end, b0 + block_size);
    for (int64_t v = b0; v < b1; ++v) {
      s.observations += AccumulateVoxel(posed, candidates.VoxelCenter(v), candidates.observers[v],
                                        with_jacobian, &s.hessian, &s.gradient, &s.cost);
    }
  });
  *out = ReducedSystem();
  if (with_jacobian) {
    out->hessian.setZero(6 * m, 6 * m);
    out->gradient.setZero(6 * m);
  }
  for (const ReducedSystem& s : partial) {  // fixed order: deterministic
    out->cost += s.cost;
    out->observations += s.observations;
    if (with_jacobian) {
      out->hessian += s.hessian;
      out->gradient += s.gradient;
    }
  }
  if (with_jacobian) {
    out->hessian.triangularView<Eigen::StrictlyLower>() = out->hessian.transpose();
  }
}

ReducedChunkCost::ReducedChunkCost(const std::vector<Frame>* frames,
                                   const CandidateSet* candidates,
                                   const Eigen::Isometry3d& frame0_from_world,
                                   int64_t begin,
                                   int64_t end,
                                   int num_threads)
    : frames_(frames),
      candidates_(candidates),
      frame0_from_world_(frame0_from_world),
      begin_(begin),
      end_(end),
      num_threads_(num_threads) {
  const int free = static_cast<int>(frames->size()) - 1;
  CHECK_GE(free, 1);
  set_num_residuals(6 * free + 1);
  for (int i = 0; i < free; ++i) mutable_parameter_block_sizes()->push_back(kPoseAmbientSize);
}

void ReducedChunkCost::Compress(const Eigen::MatrixXd& hessian_free,
                                const Eigen::VectorXd& gradient_free,
                                double cost,
                                Eigen::VectorXd* residual,
                                Eigen::MatrixXd* jacobian) {
  const int n = static_cast<int>(hessian_free.rows());
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eigen(hessian_free);
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
    (*residual)[e] = v.col(e).dot(gradient_free) / s;
    explained += (*residual)[e] * (*residual)[e];
  }
  // |r|^2 = f_c: the part of the cost the linear model cannot change.
  (*residual)[n] = std::sqrt(std::max(0.0, cost - explained));
}

bool ReducedChunkCost::Evaluate(double const* const* parameters,
                                double* residuals,
                                double** jacobians) const {
  const int m = static_cast<int>(frames_->size());
  const int free = m - 1;
  std::vector<Eigen::Isometry3d> poses(m);
  poses[0] = frame0_from_world_;
  for (int i = 1; i < m; ++i) poses[i] = ParametersToPose(parameters[i - 1]);
  const bool with_jacobian = jacobians != nullptr;
  ReducedSystem system;
  AccumulateReducedSystem(*frames_, *candidates_, poses, begin_, end_, with_jacobian,
                          num_threads_, &system);
  if (!std::isfinite(system.cost)) return false;
  const int n = 6 * free;
  if (!with_jacobian) {
    std::fill(residuals, residuals + n, 0.0);
    residuals[n] = std::sqrt(system.cost);
    return true;
  }
  Eigen::VectorXd r;
  Eigen::MatrixXd jac;
  Compress(system.hessian.bottomRightCorner(n, n), system.gradient.tail(n), system.cost, &r,
           &jac);
  if (!r.allFinite() || !jac.allFinite()) return false;
  Eigen::Map<Eigen::VectorXd>(residuals, n + 1) = r;
  for (int i = 1; i < m; ++i) {
    if (jacobians[i - 1] == nullptr) continue;
    Eigen::Map<Eigen::Matrix<double, Eigen::Dynamic, kPoseAmbientSize, Eigen::RowMajor>> out(
        jacobians[i - 1], n + 1, kPoseAmbientSize);
    out.noalias() = jac.middleCols<6>(6 * (i - 1)) * TangentToAmbientJacobian(parameters[i - 1]);
  }
  return true;
}

}  // namespace dsr
