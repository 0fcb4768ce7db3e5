// Streaming normal equations over panorama voxels: the hot loop every image-based solver
// shares (DSR in dsr_reduced/, APE and the pair registrations in baselines/).
//
// For each candidate voxel j (core/observation.h) the stream samples every candidate
// observer i at p_ij = T_i p_j with the observation model of core/observation.h (value
// and gradient in one trilinear gather of the interleaved frame data), keeps those with
// sigma_ij = 1, and, when at least two frames observe the voxel, builds their Jacobians
// J_ij and hands them to a per-voxel term that adds its cost, gradient and Gauss-Newton
// matrix to an accumulator. Nothing per observation is stored.
//
// Determinism: a voxel range is split into a fixed number of blocks (independent of the
// thread count), each block accumulated on its own and the blocks summed in order, so the
// result is bit-identical for any number of threads.
//
// The slow, obviously-correct twin of the sampling is ObserveSample (core/observation.h);
// tests compare the two through the per-voxel reference costs.
#ifndef DSR_CORE_VOXEL_STREAM_H_
#define DSR_CORE_VOXEL_STREAM_H_

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <glog/logging.h>

#include "core/frame.h"
#include "core/hessian_batch.h"
#include "core/observation.h"
#include "core/parallel.h"

namespace dsr {

// Normal equations of a sum of squares over all m frames (6m x 6m, frame 0's rows
// included): H = J^T J (full square), g = J^T r, cost = sum r^2.
struct NormalEquations {
  Eigen::MatrixXd hessian;
  Eigen::VectorXd gradient;
  double cost = 0.0;
  // Intensity differences the objective evaluated (e.g. sum of k_j for DSR, sum of
  // k_j (k_j - 1) / 2 for APE), over voxels with k_j >= 2.
  int64_t observations = 0;
  // Per frame (m entries), for terms that split their cost by frame (DSR: frame i's sum
  // of squared residuals and its number of residuals); zero otherwise.
  std::vector<double> frame_cost;
  std::vector<int64_t> frame_observations;
};

// A frame's pose folded into its index map (u = a p + b), with the raw sampler data, so
// that the hot loop samples without calls: one validity byte and one gather of 8 float4
// [I, gu, gv, gw] per observation. Same arithmetic as Frame::SampleAtIndex up to the
// order of additions.
struct PosedFrame {
  const float* data;           // interleaved float4 per voxel
  const uint8_t* valid;        // valid-cell map
  double max_cell[3];          // n - 2 per axis (last valid cell index)
  int64_t stride_y, stride_z;  // in voxels
  double a[9], b[3];           // u = a p + b (row-major a)
  double r[9], t[3];           // p_ij = r p + t
  double g[9];                 // gradient_to_physical, row-major
};

std::vector<PosedFrame> PoseFrames(const std::vector<Frame>& frames,
                                   const std::vector<Eigen::Isometry3d>& frame_from_world);

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

// J_ij = grad I_i(p_ij)^T [I_3, -[p_ij]x] from an index-space gradient `gu` at world p.
inline void ObservationJacobian(const PosedFrame& pf, const double p[3], const double gu[3], double jac[6]) {
  double gm[3], q[3];
  for (int d = 0; d < 3; ++d) {
    gm[d] = pf.g[3 * d] * gu[0] + pf.g[3 * d + 1] * gu[1] + pf.g[3 * d + 2] * gu[2];
    q[d] = pf.r[3 * d] * p[0] + pf.r[3 * d + 1] * p[1] + pf.r[3 * d + 2] * p[2] + pf.t[d];
  }
  // J = [grad; p_ij x grad]  (grad^T (-[p_ij]x) = (p_ij x grad)^T)
  jac[0] = gm[0];
  jac[1] = gm[1];
  jac[2] = gm[2];
  jac[3] = q[1] * gm[2] - q[2] * gm[1];
  jac[4] = q[2] * gm[0] - q[0] * gm[2];
  jac[5] = q[0] * gm[1] - q[1] * gm[0];
}

// Per-block accumulator: H (row-major, n x n; terms fill at least the upper block
// triangle, see StreamNormalEquations), g, cost.
struct VoxelAccumulator {
  int n = 0;
  std::vector<double> hessian, gradient;
  double cost = 0.0;
  int64_t observations = 0;
  double frame_cost[kMaxFrames] = {};
  int64_t frame_observations[kMaxFrames] = {};
};

// The observers of one voxel, as the stream hands them to a term: k >= 2 frames
// `frame[a]` with value `value[a]` and, when Jacobians are wanted, J in `jac[a]`.
struct VoxelObservations {
  int k = 0;
  int frame[kMaxFrames];
  double value[kMaxFrames];
  double jac[kMaxFrames][6];
};

// Adds J_a^T s J_b to the (frame fa, frame fb) block of a row-major n x n matrix; only the
// upper triangle of the block when fa == fb.
inline void AddOuter(double* h, int n, int fa, int fb, const double* ja, const double* jb, double s) {
  if (fa == fb) {
    for (int i = 0; i < 6; ++i) {
      const double si = s * ja[i];
      double* row = h + (6 * fa + i) * n + 6 * fa;
      for (int j = i; j < 6; ++j) row[j] += si * jb[j];
    }
    return;
  }
  for (int i = 0; i < 6; ++i) {
    const double si = s * ja[i];
    double* row = h + (6 * fa + i) * n + 6 * fb;
    for (int j = 0; j < 6; ++j) row[j] += si * jb[j];
  }
}

namespace internal {

// Fixed number of accumulation blocks per voxel range: results do not depend on threads.
constexpr int64_t kStreamBlocks = 64;

template <class Term>
void StreamBlock(const std::vector<PosedFrame>& posed,
                 const CandidateSet& candidates,
                 int64_t b0,
                 int64_t b1,
                 bool with_jacobian,
                 const Term& term,
                 VoxelAccumulator* acc) {
  const ImageGeometry& grid = candidates.grid;
  const int64_t nx = grid.size[0], nxy = nx * grid.size[1];
  double m[9];
  const Eigen::Matrix3d to_world = grid.IndexToPhysicalMatrix();
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) m[3 * r + c] = to_world(r, c);
  const double o[3] = {grid.origin_mm[0], grid.origin_mm[1], grid.origin_mm[2]};
  VoxelObservations obs;
  double sample[kMaxFrames][4];
  const bool batched = with_jacobian && term.batched_hessian;
  HessianBatcher batcher(batched ? acc->hessian.data() : nullptr, acc->n);
  for (int64_t v = b0; v < b1; ++v) {
    const int64_t l = candidates.voxel[v];
    const double ijk[3] = {static_cast<double>(l % nx), static_cast<double>((l % nxy) / nx),
                           static_cast<double>(l / nxy)};
    double p[3];
    for (int r = 0; r < 3; ++r) {
      p[r] = o[r] + m[3 * r] * ijk[0] + m[3 * r + 1] * ijk[1] + m[3 * r + 2] * ijk[2];
    }
    // Sample every candidate (value and gradient in one gather); Jacobians only when at
    // least two observe the voxel.
    int k = 0;
    for (uint32_t bits = candidates.observers[v]; bits != 0; bits &= bits - 1) {
      const int f = __builtin_ctz(bits);
      const bool observed = with_jacobian ? SampleAt<4>(posed[f], p, sample[k])
                                          : SampleAt<1>(posed[f], p, sample[k]);
      if (observed) obs.frame[k++] = f;
    }
    if (k < 2) continue;
    obs.k = k;
    for (int a = 0; a < k; ++a) obs.value[a] = sample[a][0];
    if (with_jacobian) {
      for (int a = 0; a < k; ++a) {
        ObservationJacobian(posed[obs.frame[a]], p, &sample[a][1], obs.jac[a]);
      }
    }
    term(obs, with_jacobian, acc);
    if (batched) batcher.Add(k, obs.frame, obs.jac, term.Weights(k));
  }
  if (batched) batcher.Flush();
}

}  // namespace internal

// Streams candidate voxels [begin, end) at the given poses through `term`, a callable
// `void(const VoxelObservations&, bool with_jacobian, VoxelAccumulator*)` that adds the
// voxel's cost and observation count and, when with_jacobian, its gradient and its
// Gauss-Newton terms to at least the upper block triangle (frame a <= frame b) of the
// row-major H, the diagonal blocks at least on and above their diagonal (AddOuter does
// this). The result's H is made symmetric from that upper triangle. Without Jacobians
// only cost and observations are filled.
// The term also has `bool batched_hessian` and `HessianWeights Weights(int k)`: when
// batched_hessian is true, the term adds no Gauss-Newton terms itself and the stream adds
// H_ab += (delta_ab * diagonal + shared) J_a^T J_b for it in batches (core/hessian_batch.h).
template <class Term>
void StreamNormalEquations(const std::vector<Frame>& frames,
                           const CandidateSet& candidates,
                           const std::vector<Eigen::Isometry3d>& frame_from_world,
                           int64_t begin,
                           int64_t end,
                           bool with_jacobian,
                           int num_threads,
                           const Term& term,
                           NormalEquations* out) {
  const int m = static_cast<int>(frames.size());
  CHECK_EQ(static_cast<int>(frame_from_world.size()), m);
  CHECK_LE(0, begin);
  CHECK_LE(end, candidates.num_voxels());
  const std::vector<PosedFrame> posed = PoseFrames(frames, frame_from_world);
  const int64_t count = std::max<int64_t>(0, end - begin);
  const int64_t num_blocks = std::max<int64_t>(1, std::min(internal::kStreamBlocks, count));
  const int64_t block_size = (count + num_blocks - 1) / num_blocks;
  const int n = 6 * m;
  std::vector<VoxelAccumulator> partial(num_blocks);
  ParallelFor(0, num_blocks, num_threads, [&](int64_t block) {
    VoxelAccumulator& acc = partial[block];
    acc.n = n;
    if (with_jacobian) {
      acc.hessian.assign(static_cast<size_t>(n) * n, 0.0);
      acc.gradient.assign(n, 0.0);
    }
    const int64_t b0 = begin + block * block_size, b1 = std::min(end, b0 + block_size);
    internal::StreamBlock(posed, candidates, b0, b1, with_jacobian, term, &acc);
  });
  *out = NormalEquations();
  if (with_jacobian) {
    out->hessian.setZero(n, n);
    out->gradient.setZero(n);
  }
  out->frame_cost.assign(m, 0.0);
  out->frame_observations.assign(m, 0);
  for (const VoxelAccumulator& acc : partial) {  // fixed order: deterministic
    out->cost += acc.cost;
    out->observations += acc.observations;
    for (int i = 0; i < m; ++i) {
      out->frame_cost[i] += acc.frame_cost[i];
      out->frame_observations[i] += acc.frame_observations[i];
    }
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

}  // namespace dsr

#endif  // DSR_CORE_VOXEL_STREAM_H_
