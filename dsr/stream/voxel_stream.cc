// Posed frames and the portable batch sampler (stream/voxel_stream.h).
#include "dsr/stream/voxel_stream.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <memory>

#include "dsr/stream/kernels/kernels_avx2.h"
#include "dsr/stream/kernels/kernels_avx512.h"

namespace dsr {
namespace {

// The portable sampler: the same formulas as the AVX2 one (stream/kernels/kernels_avx2.cc), one
// double at a time, plugged into the shared loop.
struct Point {
  double p[3];
};

inline Point MakePoint(const double p[3]) { return {{p[0], p[1], p[2]}}; }

struct FrameView {
  const PosedFrame* f;
  const double* ahead;
};

inline FrameView MakeFrameView(const PosedFrame& f, const double ahead[4]) { return {&f, ahead}; }

// J_ij = grad I_i(p_ij)^T [I_3, -[p_ij]x] from an index-space gradient `gu` at world p,
// portable.
void ObservationJacobian(const PosedFrame& f,
                         const double p[3],
                         const double gu[3],
                         double jac[6]) {
  double grad[3], q[3];
  for (int d = 0; d < 3; ++d) {
    grad[d] = f.g[0][d] * gu[0] + f.g[1][d] * gu[1] + f.g[2][d] * gu[2];
    q[d] = f.r[0][d] * p[0] + f.r[1][d] * p[1] + f.r[2][d] * p[2] + f.r[3][d];
  }
  // J = [grad; p_ij x grad]  (grad^T (-[p_ij]x) = (p_ij x grad)^T).
  jac[0] = grad[0];
  jac[1] = grad[1];
  jac[2] = grad[2];
  jac[3] = q[1] * grad[2] - q[2] * grad[1];
  jac[4] = q[2] * grad[0] - q[0] * grad[2];
  jac[5] = q[0] * grad[1] - q[1] * grad[0];
}

inline void JacobianOne(const FrameView& view,
                        const Point& p,
                        const double sample[4],
                        double jac[6]) {
  ObservationJacobian(*view.f, p.p, sample + 1, jac);
}

// Continuous index of p in f and its cell; false outside the grid or for non-finite u.
inline bool CellOf(
    const PosedFrame& f, const double p[3], double u[3], double fl[3], int64_t* cell) {
  for (int d = 0; d < 3; ++d) {
    u[d] = f.a[0][d] * p[0] + f.a[1][d] * p[1] + f.a[2][d] * p[2] + f.a[3][d];
    fl[d] = std::floor(u[d]);
  }
  // As doubles first, so that huge or NaN coordinates never overflow an int.
  if (!(fl[0] >= 0.0 && fl[1] >= 0.0 && fl[2] >= 0.0 && fl[0] <= f.max_cell[0] &&
        fl[1] <= f.max_cell[1] && fl[2] <= f.max_cell[2])) {
    return false;
  }
  *cell = static_cast<int64_t>(fl[0]) + f.stride_y * static_cast<int64_t>(fl[1]) +
          f.stride_z * static_cast<int64_t>(fl[2]);
  return true;
}

// The portable sampler always tests the bounds (the twin stays the plain formula).
inline bool RunInside(const FrameView&, const Point&, const Point&) { return false; }

template <bool kInside, bool kGradient>
inline bool SampleOne(const FrameView& view, const Point& p, double sample[4]) {
  const PosedFrame& f = *view.f;
  const double* ahead = view.ahead;
  double later[3];
  for (int d = 0; d < 3; ++d) {
    const double u =
        f.a[0][d] * p.p[0] + f.a[1][d] * p.p[1] + f.a[2][d] * p.p[2] + f.a[3][d] + ahead[d];
    later[d] = std::min(std::max(0.0, std::floor(u)), f.max_cell[d]);  // NaN -> 0
  }
  const int64_t cell = static_cast<int64_t>(later[0]) +
                       f.stride_y * static_cast<int64_t>(later[1]) +
                       f.stride_z * static_cast<int64_t>(later[2]);
  const float* c = f.values + cell;
  __builtin_prefetch(c);
  __builtin_prefetch(c + f.stride_y);
  __builtin_prefetch(c + f.stride_z);
  __builtin_prefetch(c + f.stride_y + f.stride_z);
  __builtin_prefetch(f.valid_bits + (cell >> 3));
  return kGradient ? SampleAt(f, p.p, sample) : SampleValueAt(f, p.p, sample);
}

#define DSR_KERNEL_ATTR
#include "dsr/stream/kernels/voxel_sampler_loop.inc"
#undef DSR_KERNEL_ATTR

}  // namespace

std::vector<PosedFrame> PoseFrames(const std::vector<Frame>& frames,
                                   const std::vector<Eigen::Isometry3d>& frame_from_world) {
  std::vector<PosedFrame> out(frames.size());
  for (size_t i = 0; i < frames.size(); ++i) {
    const Frame& f = frames[i];
    PosedFrame& pf = out[i];
    std::memset(&pf, 0, sizeof(pf));
    const Eigen::Vector3i& n = f.geometry().size;
    pf.values = f.values();
    pf.valid_bits = f.valid_bits();
    for (int d = 0; d < 3; ++d) pf.max_cell[d] = n[d] - 2.0;
    pf.stride_y = n[0];
    pf.stride_z = int64_t{n[0]} * n[1];
    pf.strides[0] = 1.0;
    pf.strides[1] = static_cast<double>(pf.stride_y);
    pf.strides[2] = static_cast<double>(pf.stride_z);
    const Eigen::Matrix3d rotation = frame_from_world[i].linear();
    const Eigen::Vector3d translation = frame_from_world[i].translation();
    const Eigen::Matrix3d a = f.index_from_physical() * rotation;
    const Eigen::Vector3d b = f.index_from_physical() * (translation - f.geometry().origin_mm);
    for (int row = 0; row < 3; ++row) {
      for (int col = 0; col < 3; ++col) {
        pf.a[col][row] = a(row, col);
        pf.r[col][row] = rotation(row, col);
        pf.g[col][row] = f.gradient_to_physical()(row, col);
      }
      pf.a[3][row] = b[row];
      pf.r[3][row] = translation[row];
    }
  }
  return out;
}

namespace {

// The valid cell of p in f (sigma = 1) and its trilinear weights; false otherwise.
struct CellWeights {
  int64_t cell;
  double wx0, wx1, wy0, wy1, wz0, wz1;
};
inline bool ValidCellWeights(const PosedFrame& f, const double p[3], CellWeights* c) {
  double u[3], fl[3];
  if (!CellOf(f, p, u, fl, &c->cell)) return false;
  if (((f.valid_bits[c->cell >> 3] >> (c->cell & 7)) & 1) == 0) return false;
  c->wx1 = u[0] - fl[0];
  c->wy1 = u[1] - fl[1];
  c->wz1 = u[2] - fl[2];
  c->wx0 = 1.0 - c->wx1;
  c->wy0 = 1.0 - c->wy1;
  c->wz0 = 1.0 - c->wz1;
  return true;
}

// One quantity given at the cell's 8 corners as 4 rows (y, z) of two (x, then x + 1 `dx`
// floats further on), blended along x, then y, then z.
inline double Blend(const CellWeights& c, const float* r00, const float* r10, const float* r01,
                    const float* r11, int dx) {
  const double t00 = r00[0] * c.wx0 + r00[dx] * c.wx1, t10 = r10[0] * c.wx0 + r10[dx] * c.wx1;
  const double t01 = r01[0] * c.wx0 + r01[dx] * c.wx1, t11 = r11[0] * c.wx0 + r11[dx] * c.wx1;
  const double ty0 = t00 * c.wy0 + t10 * c.wy1, ty1 = t01 * c.wy0 + t11 * c.wy1;
  return ty0 * c.wz0 + ty1 * c.wz1;
}

}  // namespace

bool SampleAt(const PosedFrame& f, const double p[3], double out[4]) {
  CellWeights w;
  if (!ValidCellWeights(f, p, &w)) return false;
  const float* c = f.values + w.cell;
  const int64_t sy = f.stride_y, sz = f.stride_z;
  // The 8 corners' [I, gu, gv, gw] (image/frame.h: CornerSample), as 4 rows of two.
  float r00[8], r10[8], r01[8], r11[8];
  for (int dx = 0; dx < 2; ++dx) {
    CornerSample(c + dx, sy, sz, r00 + 4 * dx);
    CornerSample(c + dx + sy, sy, sz, r10 + 4 * dx);
    CornerSample(c + dx + sz, sy, sz, r01 + 4 * dx);
    CornerSample(c + dx + sy + sz, sy, sz, r11 + 4 * dx);
  }
  for (int q = 0; q < 4; ++q) out[q] = Blend(w, r00 + q, r10 + q, r01 + q, r11 + q, 4);
  return true;
}

bool SampleValueAt(const PosedFrame& f, const double p[3], double* value) {
  CellWeights w;
  if (!ValidCellWeights(f, p, &w)) return false;
  // SampleAt's value (its q = 0), from the corners' values alone.
  const float* r00 = f.values + w.cell;
  const float* r10 = r00 + f.stride_y;
  *value = Blend(w, r00, r10, r00 + f.stride_z, r10 + f.stride_z, 1);
  return true;
}

int64_t SampleVoxelBatch(KernelPath path,
                         const std::vector<PosedFrame>& posed,
                         const CandidateSet& candidates,
                         int64_t v,
                         int64_t end,
                         bool with_jacobian,
                         VoxelBatch* batch) {
#ifdef DSR_HAVE_AVX2_KERNELS
  if (ResolveKernelPath(path) != KernelPath::kPortable) {  // kAvx512 samples with AVX2 too
    return internal::SampleVoxelBatchAvx2(posed, candidates, v, end, with_jacobian, batch);
  }
#endif
  return SampleVoxelBatchLoop(posed, candidates, v, end, with_jacobian, batch);
}

VoxelBatch* ThreadVoxelBatch() {
  thread_local const std::unique_ptr<VoxelBatch> batch(new VoxelBatch);
  return batch.get();
}

}  // namespace dsr
