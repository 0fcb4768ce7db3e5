// Streaming normal equations over panorama voxels: the hot loop every image-based solver
// shares (DSR in dsr_reduced/, APE and the pair registrations in baselines/).
//
// For each candidate voxel j (model/observation.h) the stream samples every candidate
// observer i at p_ij = T_i p_j with the observation model of model/observation.h (value
// and gradient in one trilinear pass over the frame's voxel values), keeps those with
// sigma_ij = 1, and, when at least two frames observe the voxel, builds their Jacobians
// J_ij and hands them to a per-voxel term (stream/voxel_term.h) that adds its cost,
// gradient and Gauss-Newton matrix to an accumulator. Nothing per observation is kept
// beyond a batch of up to 2048 voxels.
//
// Work is done in batches (VoxelBatch): the sampler fills one with the observations of
// consecutive candidate voxels, the term consumes them voxel by voxel, and for terms whose
// Gauss-Newton matrix has the per-voxel form (delta_ab d + s) J_a^T J_b the stream adds it
// for the whole batch at once, voxels with the same observers together
// (stream/hessian_batch.h), and likewise their gradient g_a += r_a J_a when the term hands
// over its residuals r_a. Larger batches make larger groups, up to what stays in the L2
// cache: 2048 voxels (8192 observations, about 0.6 MB). The sampler and those
// kernels have SIMD implementations (AVX2+FMA, and AVX-512 for the Gauss-Newton matrix)
// where the CPU has them, and portable ones (the twins tests compare with; KernelPath).
//
// Determinism: a voxel range is split into a fixed number of blocks (independent of the
// thread count), each block accumulated on its own and the blocks summed in order, so the
// result is bit-identical for any number of threads (for a given kernel path).
//
// The slow, obviously-correct twin of the sampling is ObserveSample (model/observation.h);
// tests compare the two through the per-voxel reference costs.
#ifndef DSR_STREAM_VOXEL_STREAM_H_
#define DSR_STREAM_VOXEL_STREAM_H_

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <type_traits>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <glog/logging.h>

#include "dsr/image/frame.h"
#include "dsr/model/observation.h"
#include "dsr/stream/hessian_batch.h"
#include "dsr/stream/voxel_term.h"
#include "dsr/util/cpu.h"
#include "dsr/util/parallel.h"

namespace dsr {

// Normal equations of a sum of squares over all m frames (p m x p m, frame 0's rows
// included; p = 6 pose parameters per frame, or 8 with photometric parameters: the pose
// tangent, then log gain and offset): H = J^T J (full square), g = J^T r, cost = sum r^2.
struct NormalEquations {
  Eigen::MatrixXd hessian;
  Eigen::VectorXd gradient;
  double cost = 0.0;
  // Intensity differences the objective evaluated (e.g. sum of k_j for DSR, sum of
  // k_j (k_j - 1) / 2 for APE), over voxels with k_j >= 2.
  int64_t observations = 0;
  // Voxels with k_j >= 2 (the panorama intensities DSR eliminates: one degree of freedom
  // each, for the noise estimate of pipeline/uncertainty.h).
  int64_t voxels = 0;
  // Per frame (m entries), for terms that split their cost by frame (DSR: frame i's sum
  // of squared residuals and its number of residuals); zero otherwise.
  std::vector<double> frame_cost;
  std::vector<int64_t> frame_observations;
};

// A frame's pose folded into its index map (u = A p + b), with the raw sampler data, so
// that the hot loop samples without calls: one validity bit and the 32 voxel values of a
// cell's corners and their neighbours (12 rows of 4) per observation. Vectors are stored
// as 4 lanes (x, y, z, 0) so that the AVX2 path loads them whole.
struct PosedFrame {
  const float* values;         // voxel values, x-fastest (image/frame.h)
  const uint8_t* valid_bits;   // valid-cell bit map (image/frame.h)
  int64_t stride_y, stride_z;  // in voxels
  double a[4][4];              // columns of A, then b: u = A p + b (index units)
  double max_cell[4];          // n - 2 per axis (last valid cell index), 0 in lane 3
  double r[4][4];              // columns of R, then t: p_ij = R p + t (frame mm)
  double g[3][4];              // columns of (D S)^-T: index gradient -> physical gradient
  double strides[4];           // 1, stride_y, stride_z, 0: a cell's linear index as a dot product
};

std::vector<PosedFrame> PoseFrames(const std::vector<Frame>& frames,
                                   const std::vector<Eigen::Isometry3d>& frame_from_world);

// How a stream runs: its threads and its kernel path (util/cpu.h). Results are
// bit-identical for any thread count; the kernel paths agree to rounding.
struct StreamContext {
  int num_threads = 0;  // <= 0: all hardware threads
  KernelPath kernels = KernelPath::kAuto;
};

// The kernel path a stream with `context` runs (kAuto resolved); CHECKs that the CPU runs
// it (SolveOptions::Validate refuses one it does not).
inline KernelPath StreamKernelPath(const StreamContext& context) {
  const KernelPath path = ResolveKernelPath(context.kernels);
  CHECK(KernelPathAvailable(path)) << KernelPathToString(path) << " kernels are not available here";
  return path;
}

// Samples frame `f` at world point p with the portable sampler: false when sigma = 0;
// else out = [I, dI/du, dI/dv, dI/dw] (value and index-space gradient).
bool SampleAt(const PosedFrame& f, const double p[3], double out[4]);
// The same sample's value alone (SampleAt's out[0], bit for bit), from the cell's 8 values:
// what an evaluation without Jacobians reads.
bool SampleValueAt(const PosedFrame& f, const double p[3], double* value);

// The observations of consecutive candidate voxels with at least two observers. Voxel t
// has k_t = begin[t + 1] - begin[t] observations, in increasing frame order.
struct VoxelBatch {
  static constexpr int kMaxObservations = 8192;
  static constexpr int kMaxVoxels = 2048;
  int num_voxels = 0;
  int num_observations = 0;
  int begin[kMaxVoxels + 1];
  uint32_t observers[kMaxVoxels];  // bit f: frame f observes voxel t (sigma = 1)
  int64_t voxel[kMaxVoxels];       // voxel t's index in the CandidateSet
  int frame[kMaxObservations];
  double value[kMaxObservations];
  // Only with Jacobians.
  alignas(64) double jac[kMaxObservations][kJacobianSize];
  // Only with Jacobians, for terms with a batched gradient: the observations' residuals
  // r, written by the term (g_{frame} += r J is added a batch at a time).
  double residual[kMaxObservations];
  // Only with Jacobians, for terms with 8 parameters per frame: their wide Jacobians,
  // written by the term from jac and value (the batched kernels read these instead).
  alignas(64) double wide_jac[kMaxObservations][kWideJacobianSize];
};

// This thread's batch, made once and reused (a new 1.1 MB batch per block would be zeroed
// and start cold in the caches every time). One user at a time per thread: a block's loop.
VoxelBatch* ThreadVoxelBatch();

// Fills `batch` (emptied first) with the candidate voxels from `v` on (stopping at `end`
// or when the batch is full) that at least two frames observe at `posed`; Jacobians only
// when `with_jacobian`. Returns the first voxel not consumed. `path`: the sampler to run
// (kAvx512 samples with AVX2; kAuto: the widest available).
int64_t SampleVoxelBatch(KernelPath path,
                         const std::vector<PosedFrame>& posed,
                         const CandidateSet& candidates,
                         int64_t v,
                         int64_t end,
                         bool with_jacobian,
                         VoxelBatch* batch);

namespace internal {

// Fixed number of accumulation blocks per voxel range: results do not depend on threads.
constexpr int64_t kStreamBlocks = 64;

template <class Term>
void StreamBlock(KernelPath path,
                 const std::vector<PosedFrame>& posed,
                 const CandidateSet& candidates,
                 int64_t b0,
                 int64_t b1,
                 bool with_jacobian,
                 const Term& term,
                 VoxelBatch* batch,
                 VoxelAccumulator* acc) {
  constexpr int kWidth = FrameParametersOf<Term>::value;
  static_assert(kWidth == kJacobianSize || kWidth == kWideJacobianSize, "6 or 8 per frame");
  const bool batched = with_jacobian && term.batched_hessian;
  const bool batched_gradient = batched && term.batched_gradient;
  HessianWeights weights[kMaxFrames + 1];
  if (batched) {
    for (int k = 2; k <= kMaxFrames; ++k) weights[k] = term.Weights(k);
  }
  for (int64_t v = b0; v < b1;) {
    v = SampleVoxelBatch(path, posed, candidates, v, b1, with_jacobian, batch);
    acc->voxels += batch->num_voxels;
    for (int t = 0; t < batch->num_voxels; ++t) {
      VoxelObservations obs;
      const int first = batch->begin[t];
      obs.k = batch->begin[t + 1] - first;
      obs.voxel = batch->voxel[t];
      obs.frame = batch->frame + first;
      obs.value = batch->value + first;
      obs.jac = batch->jac + first;
      if (batched_gradient) obs.residual = batch->residual + first;
      if (with_jacobian && kWidth == kWideJacobianSize) obs.wide_jac = batch->wide_jac + first;
      term(obs, with_jacobian, acc);
    }
    if (batched) {
      AddBatchHessian(path, *batch, weights, acc->hessian.data(), acc->n,
                      batched_gradient ? acc->gradient.data() : nullptr, kWidth,
                      ProjectionFactorsOf<Term>::Get(term));
    }
  }
}

}  // namespace internal

// Streams candidate voxels [begin, end) at the given poses through `term` with the threads
// and kernels of `context` (StreamKernelPath). `term` is a voxel term (stream/voxel_term.h:
// what it receives, what it adds, its batched form; checked at compile time). The result's
// H is made symmetric from the upper block triangle the term and the batched kernels fill.
// Without Jacobians only cost and observations are filled.
template <class Term>
void StreamNormalEquations(const std::vector<Frame>& frames,
                           const CandidateSet& candidates,
                           const std::vector<Eigen::Isometry3d>& frame_from_world,
                           int64_t begin,
                           int64_t end,
                           bool with_jacobian,
                           const StreamContext& context,
                           const Term& term,
                           NormalEquations* out) {
  CheckVoxelTerm<Term>();
  const int m = static_cast<int>(frames.size());
  CHECK_EQ(static_cast<int>(frame_from_world.size()), m);
  CHECK_LE(0, begin);
  CHECK_LE(end, candidates.num_voxels());
  const KernelPath path = StreamKernelPath(context);
  const std::vector<PosedFrame> posed = PoseFrames(frames, frame_from_world);
  const int64_t count = std::max<int64_t>(0, end - begin);
  const int64_t num_blocks = std::max<int64_t>(1, std::min(internal::kStreamBlocks, count));
  const int64_t block_size = (count + num_blocks - 1) / num_blocks;
  const int n = internal::FrameParametersOf<Term>::value * m;
  std::vector<VoxelAccumulator> partial(num_blocks);
  ParallelFor(0, num_blocks, context.num_threads, [&](int64_t block) {
    VoxelAccumulator& acc = partial[block];
    acc.n = n;
    if (with_jacobian) {
      acc.hessian.assign(static_cast<size_t>(n) * n, 0.0);
      acc.gradient.assign(n, 0.0);
    }
    const int64_t b0 = begin + block * block_size, b1 = std::min(end, b0 + block_size);
    internal::StreamBlock(path, posed, candidates, b0, b1, with_jacobian, term, ThreadVoxelBatch(),
                          &acc);
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
    out->voxels += acc.voxels;
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

#endif  // DSR_STREAM_VOXEL_STREAM_H_
