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

// A frame's pose folded into its index map (u = a p + b), with the raw sampler data, so
// that the hot loop samples without calls: one validity byte and one gather of 8 float4
// [I, gu, gv, gw] per observation. Same arithmetic as Frame::SampleAtIndex (the slow twin
// the reference cost uses) up to the order of additions.
struct PosedFrame {
  const float* data;       // interleaved float4 per voxel
  const uint8_t* valid;    // valid-cell map
  double max_cell[3];      // n - 2 per axis (last valid cell index)
  int64_t stride_y, stride_z;  // in voxels
  double a[9], b[3];       // u = a p + b (row-major a)
  double r[9], t[3];       // p_ij = r p + t
  double g[9];             // gradient_to_physical, row-major
};

std::vector<PosedFrame> PoseFrames(const std::vector<Frame>& frames,
                                   const std::vector<Eigen::Isometry3d>& frame_from_world) {
  std::vector<PosedFrame> out(frames.size());
  for (size_t i = 0; i < frames.size(); ++i) {
    const Frame& f = frames[i];
    PosedFrame& pf = out[i];
    const Eigen::Vector3i& n = f.geometry().size;
    pf.data = f.interleaved();
    pf.valid = f.valid_cells();
    for (int d = 0; d < 3; ++d) pf.max_cell[d] = n[d] - 2.0;
    pf.stride_y = n[0];
    pf.stride_z = int64_t{n[0]} * n[1];
    const Eigen::Matrix3d rotation = frame_from_world[i].linear();
    const Eigen::Vector3d translation = frame_from_world[i].translation();
    const Eigen::Matrix3d a = f.index_from_physical() * rotation;
    const Eigen::Vector3d b = f.index_from_physical() * (translation - f.geometry().origin_mm);
    for (int row = 0; row < 3; ++row) {
      for (int col = 0; col < 3; ++col) {
        pf.a[3 * row + col] = a(row, col);
        pf.r[3 * row + col] = rotation(row, col);
        pf.g[3 * row + col] = f.gradient_to_physical()(row, col);
      }
      pf.b[row] = b[row];
      pf.t[row] = translation[row];
    }
  }
  return out;
}

// Samples frame `f` at world point p: false when sigma = 0. kChannels is 1 (value) or 4
// (value and index-space gradient); out[0..kChannels) receives them.
template <int kChannels>
inline bool SampleAt(const PosedFrame& f, const double p[3], double* out) {
  double u[3];
  for (int d = 0; d < 3; ++d) {
    u[d] = f.a[3 * d] * p[0] + f.a[3 * d + 1] * p[1] + f.a[3 * d + 2] * p[2] + f.b[d];
  }
  const double fx = std::floor(u[0]), fy = std::floor(u[1]), fz = std::floor(u[2]);
  // As doubles first, so that huge or NaN coordinates never overflow an int.
  if (!(fx >= 0.0 && fy >= 0.0 && fz >= 0.0 && fx <= f.max_cell[0] && fy <= f.max_cell[1] &&
        fz <= f.max_cell[2])) {
    return false;
  }
  const int64_t cell = static_cast<int64_t>(fx) + f.stride_y * static_cast<int64_t>(fy) +
                       f.stride_z * static_cast<int64_t>(fz);
  if (f.valid[cell] == 0) return false;
  const double wx = u[0] - fx, wy = u[1] - fy, wz = u[2] - fz;
  const double w[8] = {(1 - wx) * (1 - wy) * (1 - wz), wx * (1 - wy) * (1 - wz),
                       (1 - wx) * wy * (1 - wz),       wx * wy * (1 - wz),
                       (1 - wx) * (1 - wy) * wz,       wx * (1 - wy) * wz,
                       (1 - wx) * wy * wz,             wx * wy * wz};
  const float* c = f.data + 4 * cell;
  const int64_t sy = 4 * f.stride_y, sz = 4 * f.stride_z;
  const float* corner[8] = {c, c + 4, c + sy, c + sy + 4, c + sz, c + sz + 4, c + sz + sy,
                            c + sz + sy + 4};
  double acc[kChannels] = {};
  for (int k = 0; k < 8; ++k) {
    for (int q = 0; q < kChannels; ++q) acc[q] += w[k] * corner[k][q];
  }
  for (int q = 0; q < kChannels; ++q) out[q] = acc[q];
  return true;
}

// Per-block accumulator: H (row-major, n x n, upper block triangle), g, f.
struct Accumulator {
  int n = 0;
  std::vector<double> hessian, gradient;
  double cost = 0.0;
  int64_t observations = 0;
};

// Accumulates one voxel. Samples every candidate (value and gradient in one gather), and
// builds Jacobians and normal-equation terms only when at least two observe it.
inline void AccumulateVoxel(const std::vector<PosedFrame>& posed,
                            const double p[3],
                            uint32_t candidates,
                            bool with_jacobian,
                            Accumulator* acc) {
  int frame_of[kMaxFrames];
  double sample[kMaxFrames][4];
  int k = 0;
  for (uint32_t bits = candidates; bits != 0; bits &= bits - 1) {
    const int f = __builtin_ctz(bits);
    const bool observed = with_jacobian ? SampleAt<4>(posed[f], p, sample[k])
                                        : SampleAt<1>(posed[f], p, sample[k]);
    if (observed) frame_of[k++] = f;
  }
  if (k < 2) return;
  acc->observations += k;
  double mean = 0.0;
  for (int a = 0; a < k; ++a) mean += sample[a][0];
  mean /= k;
  if (!with_jacobian) {
    for (int a = 0; a < k; ++a) {
      const double r = sample[a][0] - mean;
      acc->cost += r * r;
    }
    return;
  }
  double jac[kMaxFrames][6];
  for (int a = 0; a < k; ++a) {
    const PosedFrame& pf = posed[frame_of[a]];
    const double* gu = &sample[a][1];
    double gm[3], q[3];
    for (int d = 0; d < 3; ++d) {
      gm[d] = pf.g[3 * d] * gu[0] + pf.g[3 * d + 1] * gu[1] + pf.g[3 * d + 2] * gu[2];
      q[d] = pf.r[3 * d] * p[0] + pf.r[3 * d + 1] * p[1] + pf.r[3 * d + 2] * p[2] + pf.t[d];
    }
    // J = [grad; p_ij x grad]  (grad^T (-[p_ij]x) = (p_ij x grad)^T)
    jac[a][0] = gm[0];
    jac[a][1] = gm[1];
    jac[a][2] = gm[2];
    jac[a][3] = q[1] * gm[2] - q[2] * gm[1];
    jac[a][4] = q[2] * gm[0] - q[0] * gm[2];
    jac[a][5] = q[0] * gm[1] - q[1] * gm[0];
  }
  const double inv_k = 1.0 / k;
  const int n = acc->n;
  double* h = acc->hessian.data();
  double* g = acc->gradient.data();
  for (int a = 0; a < k; ++a) {
    const double r = sample[a][0] - mean;
    acc->cost += r * r;
    const int fa = 6 * frame_of[a];
    const double* ja = jac[a];
    for (int i = 0; i < 6; ++i) g[fa + i] += ja[i] * r;
    // H_ab += (delta_ab - 1/k) J_a^T J_b for b >= a (upper block triangle); the diagonal
    // blocks only on and above their diagonal.
    const double diag = 1.0 - inv_k;
    for (int i = 0; i < 6; ++i) {
      const double s = diag * ja[i];
      double* row = h + (fa + i) * n + fa;
      for (int j = i; j < 6; ++j) row[j] += s * ja[j];
    }
    for (int b = a + 1; b < k; ++b) {
      const double* jb = jac[b];
      const int fb = 6 * frame_of[b];
      for (int i = 0; i < 6; ++i) {
        const double s = -inv_k * ja[i];
        double* row = h + (fa + i) * n + fb;
        for (int j = 0; j < 6; ++j) row[j] += s * jb[j];
      }
    }
  }
}

// Accumulates candidate voxels [b0, b1) into `acc`.
void AccumulateBlock(
    const std::vector<PosedFrame>& posed,
    const CandidateSet& candidates,
    int64_t b0,
    int64_t b1,
    bool with_jacobian,
    Accumulator* acc) {
  const ImageGeometry& grid = candidates.grid;
  const int64_t nx = grid.size[0], nxy = nx * grid.size[1];
  double m[9];
  const Eigen::Matrix3d to_world = grid.IndexToPhysicalMatrix();
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) m[3 * r + c] = to_world(r, c);
  const double o[3] = {grid.origin_mm[0], grid.origin_mm[1], grid.origin_mm[2]};
  for (int64_t v = b0; v < b1; ++v) {
    const int64_t l = candidates.voxel[v];
    const double ijk[3] = {static_cast<double>(l % nx), static_cast<double>((l % nxy) / nx),
                           static_cast<double>(l / nxy)};
    double p[3];
    for (int r = 0; r < 3; ++r) {
      p[r] = o[r] + m[3 * r] * ijk[0] + m[3 * r + 1] * ijk[1] + m[3 * r + 2] * ijk[2];
    }
    AccumulateVoxel(posed, p, candidates.observers[v], with_jacobian, acc);
  }
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
  const int n = 6 * m;
  std::vector<Accumulator> partial(num_blocks);
  ParallelFor(0, num_blocks, num_threads, [&](int64_t block) {
    Accumulator& acc = partial[block];
    acc.n = n;
    if (with_jacobian) {
      acc.hessian.assign(static_cast<size_t>(n) * n, 0.0);
      acc.gradient.assign(n, 0.0);
    }
    const int64_t b0 = begin + block * block_size, b1 = std::min(end, b0 + block_size);
    AccumulateBlock(posed, candidates, b0, b1, with_jacobian, &acc);
  });
  *out = ReducedSystem();
  if (with_jacobian) {
    out->hessian.setZero(n, n);
    out->gradient.setZero(n);
  }
  for (const Accumulator& acc : partial) {  // fixed order: deterministic
    out->cost += acc.cost;
    out->observations += acc.observations;
    if (with_jacobian) {
      // Row-major accumulator into the column-major matrix: transpose while adding.
      out->hessian += Eigen::Map<const Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic,
                                                     Eigen::RowMajor>>(acc.hessian.data(), n, n);
      out->gradient += Eigen::Map<const Eigen::VectorXd>(acc.gradient.data(), n);
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
  last_observations_ = system.observations;
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
