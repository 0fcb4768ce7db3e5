// AVX2 + FMA kernels (see stream/kernels/kernels_avx2.h): the same formulas as the portable sampler
// (stream/voxel_stream.cc) and group kernel (stream/hessian_batch.cc), four lanes at a time.
//
// Sampling one observation: u = A p + b as one 4-lane vector (x, y, z, 0); the 8 corners
// of the trilinear cell are 4 rows of two corners. Each row's two [I, gu, gv, gw] come
// from the values x-1..x+2 of that row and of its neighbouring rows along y and z (12
// rows of 4 floats in all): the central differences in float, as CornerSample (image/
// frame.h) forms them, one 4 x 4 transpose, then converted to double and blended with the
// x weights, then the rows with the y and z weights: the value and the index-space
// gradient come out together in one register.
// The Jacobian: grad = G gu and p_ij = R p + t as 4-lane vectors, p_ij x grad by lane
// permutes.
#include "dsr/stream/kernels/kernels_avx2.h"

#include "dsr/stream/voxel_stream.h"

#ifdef DSR_HAVE_AVX2_KERNELS
#include <immintrin.h>

#define DSR_TARGET_AVX2 __attribute__((target("avx2,fma")))

namespace dsr {
namespace internal {

namespace {

struct Point {
  __m256d x, y, z;  // p_j, each coordinate broadcast
};

DSR_TARGET_AVX2 inline Point MakePoint(const double p[3]) {
  return {_mm256_set1_pd(p[0]), _mm256_set1_pd(p[1]), _mm256_set1_pd(p[2])};
}

// A frame's constants as registers (stream/kernels/voxel_sampler_loop.inc: made once per run).
struct FrameView {
  __m256d a[4];      // columns of A, then b
  __m256d max_cell;  // last valid cell index per axis
  __m256d ahead;     // the prefetch hint's step
  __m256d strides;   // 1, n_x, n_x n_y, 0
  __m256d g[3];      // columns of (D S)^-T
  __m256d r[4];      // columns of R, then t
  const float* values;
  const uint8_t* valid_bits;
  int64_t stride_y, stride_z;  // in voxels
};

DSR_TARGET_AVX2 inline FrameView MakeFrameView(const PosedFrame& f, const double ahead[4]) {
  FrameView view;
  for (int c = 0; c < 4; ++c) {
    view.a[c] = _mm256_loadu_pd(f.a[c]);
    view.r[c] = _mm256_loadu_pd(f.r[c]);
  }
  for (int c = 0; c < 3; ++c) view.g[c] = _mm256_loadu_pd(f.g[c]);
  view.max_cell = _mm256_loadu_pd(f.max_cell);
  view.ahead = _mm256_loadu_pd(ahead);
  view.strides = _mm256_loadu_pd(f.strides);
  view.values = f.values;
  view.valid_bits = f.valid_bits;
  view.stride_y = f.stride_y;
  view.stride_z = f.stride_z;
  return view;
}

// cols[0] p.x + cols[1] p.y + cols[2] p.z + cols[3] (lane 3 stays 0).
DSR_TARGET_AVX2 inline __m256d Affine(const __m256d cols[4], const Point& p) {
  return _mm256_fmadd_pd(cols[0], p.x,
                         _mm256_fmadd_pd(cols[1], p.y, _mm256_fmadd_pd(cols[2], p.z, cols[3])));
}

// One row of the cell: its values at x-1..x+2 (`row`) and those of the rows before and
// after it along y and z (lanes 1 and 2 read). Its two corners' value and differences
// (CornerSample without the factor 1/2, which the caller applies once: exact) as doubles,
// [I_x, I_x+1, du_x, du_x+1] in `a` and [dv_x, dv_x+1, dw_x, dw_x+1] in `b`. The
// differences are formed in float, as CornerSample forms them.
struct RowCorners {
  __m256d a, b;
};
DSR_TARGET_AVX2 inline RowCorners CellRow(__m128 row, __m128 y_before, __m128 y_after,
                                          __m128 z_before, __m128 z_after) {
  // Lanes 0 and 1: x+1 - (x-1) and x+2 - x.
  const __m128 du = _mm_sub_ps(_mm_movehl_ps(row, row), row);
  const __m128 dv = _mm_sub_ps(y_after, y_before);
  const __m128 dw = _mm_sub_ps(z_after, z_before);
  return {_mm256_cvtps_pd(_mm_shuffle_ps(row, du, _MM_SHUFFLE(1, 0, 2, 1))),
          _mm256_cvtps_pd(_mm_shuffle_ps(dv, dw, _MM_SHUFFLE(2, 1, 2, 1)))};
}

// The linear indices of the cells whose lowest corners are `a` and `b` (integer-valued,
// inside the grid): one dot product with (1, n_x, n_x n_y, 0) each, summed across lanes
// together. Exact: the products and sums are integers far below 2^53.
DSR_TARGET_AVX2 inline void TwoCells(
    const FrameView& f, __m256d a, __m256d b, int64_t* ca, int64_t* cb) {
  // [a0 + a1, b0 + b1, a2 + a3, b2 + b3], then the two halves added.
  const __m256d pairs = _mm256_hadd_pd(_mm256_mul_pd(a, f.strides), _mm256_mul_pd(b, f.strides));
  const __m128d sums = _mm_add_pd(_mm256_castpd256_pd128(pairs), _mm256_extractf128_pd(pairs, 1));
  *ca = _mm_cvttsd_si64(sums);
  *cb = _mm_cvttsd_si64(_mm_unpackhi_pd(sums, sums));
}

// Whether every point between `first` and `last` has its cell inside the grid: both
// ends' u at least kMargin inside [0, max_cell + 1) on each axis. u is affine in the
// point, and each computed u is within about 1e-12 of the exact one (|u| < 2^11), so the
// points in between are inside by nearly kMargin too. NaN: false.
DSR_TARGET_AVX2 inline bool RunInside(const FrameView& f, const Point& first, const Point& last) {
  constexpr double kMargin = 1e-6;
  const __m256d u0 = Affine(f.a, first), u1 = Affine(f.a, last);
  const __m256d lo = _mm256_min_pd(u0, u1), hi = _mm256_max_pd(u0, u1);
  const __m256d ok = _mm256_and_pd(
      _mm256_cmp_pd(lo, _mm256_set1_pd(kMargin), _CMP_GE_OQ),
      _mm256_cmp_pd(hi, _mm256_add_pd(f.max_cell, _mm256_set1_pd(1.0 - kMargin)), _CMP_LE_OQ));
  return (_mm256_movemask_pd(ok) & 0x7) == 0x7;  // lanes x, y, z
}

template <bool kInside, bool kGradient>
DSR_TARGET_AVX2 inline bool SampleOne(const FrameView& f, const Point& p, double sample[4]) {
  const __m256d u = Affine(f.a, p);
  const __m256d max_cell = f.max_cell;
  // The hint's cell: the cell of u + ahead, clamped into the grid (max first: a NaN lane
  // becomes 0).
  const __m256d later = _mm256_min_pd(
      _mm256_max_pd(_mm256_floor_pd(_mm256_add_pd(u, f.ahead)), _mm256_setzero_pd()), max_cell);
  const __m256d fl = _mm256_floor_pd(u);
  int64_t hint, cell;
  if (kInside) {
    TwoCells(f, later, fl, &hint, &cell);
  } else {
    // The sample's cell clamped like the hint's, so that the shared index computation
    // stays finite either way; the bounds test follows the prefetch.
    TwoCells(f, later, _mm256_min_pd(_mm256_max_pd(fl, _mm256_setzero_pd()), max_cell), &hint,
             &cell);
  }
  {
    const char* c = reinterpret_cast<const char*>(f.values + hint);
    const int64_t sy = 4 * f.stride_y, sz = 4 * f.stride_z;  // bytes
    _mm_prefetch(c, _MM_HINT_T0);
    _mm_prefetch(c + sy, _MM_HINT_T0);
    _mm_prefetch(c + sz, _MM_HINT_T0);
    _mm_prefetch(c + sy + sz, _MM_HINT_T0);
    if (kGradient) {  // the outer rows the differences read
      _mm_prefetch(c - sy, _MM_HINT_T0);
      _mm_prefetch(c + 2 * sy, _MM_HINT_T0);
      _mm_prefetch(c - sy + sz, _MM_HINT_T0);
      _mm_prefetch(c + 2 * sy + sz, _MM_HINT_T0);
      _mm_prefetch(c - sz, _MM_HINT_T0);
      _mm_prefetch(c + 2 * sz, _MM_HINT_T0);
      _mm_prefetch(c + sy - sz, _MM_HINT_T0);
      _mm_prefetch(c + sy + 2 * sz, _MM_HINT_T0);
    }
    _mm_prefetch(reinterpret_cast<const char*>(f.valid_bits + (hint >> 3)), _MM_HINT_T0);
  }
  if (!kInside) {
    // fl inside the grid (ordered comparisons: false for NaN).
    const __m256d inside = _mm256_and_pd(_mm256_cmp_pd(fl, _mm256_setzero_pd(), _CMP_GE_OQ),
                                         _mm256_cmp_pd(fl, max_cell, _CMP_LE_OQ));
    if (_mm256_movemask_pd(inside) != 0xF) return false;
  }
  if (((f.valid_bits[cell >> 3] >> (cell & 7)) & 1) == 0) return false;
  // The weights broadcast from memory (loads, not lane permutes): w1 = u - floor(u) per
  // axis, w0 = 1 - w1.
  alignas(32) double w[4];
  _mm256_store_pd(w, _mm256_sub_pd(u, fl));
  const __m256d one = _mm256_set1_pd(1.0);
  const __m256d wy1 = _mm256_broadcast_sd(w + 1), wz1 = _mm256_broadcast_sd(w + 2);
  const __m256d wy0 = _mm256_sub_pd(one, wy1), wz0 = _mm256_sub_pd(one, wz1);
  // [wx0, wx1, wx0, wx1] (wx0 = 1 - wx1 rounded once, as a subtraction rounds it).
  const __m256d wx = _mm256_fmadd_pd(_mm256_set_pd(1.0, -1.0, 1.0, -1.0), _mm256_broadcast_sd(w),
                                     _mm256_set_pd(0.0, 1.0, 0.0, 1.0));
  if (!kGradient) {
    // The value alone: the cell's 4 rows of 2 values, with the ops (and so the rounding)
    // of lanes 0 and 1 of the gradient path below.
    const float* c = f.values + cell;
    const int64_t sy = f.stride_y, sz = f.stride_z;
    const auto pair = [](const float* r) {
      return _mm_cvtps_pd(_mm_castsi128_ps(_mm_loadu_si64(r)));  // 2 floats, unaligned
    };
    const __m128d y0 = _mm256_castpd256_pd128(wy0), y1 = _mm256_castpd256_pd128(wy1);
    const __m128d z0 = _mm256_castpd256_pd128(wz0), z1 = _mm256_castpd256_pd128(wz1);
    const __m128d a = _mm_fmadd_pd(
        _mm_fmadd_pd(pair(c + sy + sz), y1, _mm_mul_pd(pair(c + sz), y0)), z1,
        _mm_mul_pd(_mm_fmadd_pd(pair(c + sy), y1, _mm_mul_pd(pair(c), y0)), z0));
    const __m128d x = _mm_mul_pd(a, _mm256_castpd256_pd128(wx));
    sample[0] = _mm_cvtsd_f64(_mm_hadd_pd(x, x));
    return true;
  }
  // The 12 rows (x-1..x+2) around the cell: its 4 rows (y, z in {0, 1}) and their outer
  // neighbours along y (y = -1, 2) and z (z = -1, 2). All inside the grid: a valid cell's
  // corners are stencil voxels, one voxel inside it on every side.
  const float* c = f.values + cell - 1;
  const int64_t sy = f.stride_y, sz = f.stride_z;
  const __m128 r00 = _mm_loadu_ps(c), r10 = _mm_loadu_ps(c + sy);
  const __m128 r01 = _mm_loadu_ps(c + sz), r11 = _mm_loadu_ps(c + sy + sz);
  const RowCorners t00 = CellRow(r00, _mm_loadu_ps(c - sy), r10, _mm_loadu_ps(c - sz), r01);
  const RowCorners t10 =
      CellRow(r10, r00, _mm_loadu_ps(c + 2 * sy), _mm_loadu_ps(c + sy - sz), r11);
  const RowCorners t01 =
      CellRow(r01, _mm_loadu_ps(c - sy + sz), r11, r00, _mm_loadu_ps(c + 2 * sz));
  const RowCorners t11 =
      CellRow(r11, r01, _mm_loadu_ps(c + 2 * sy + sz), r10, _mm_loadu_ps(c + sy + 2 * sz));
  // The y and z weights first (every lane is a corner quantity), then x across lanes.
  const __m256d a = _mm256_fmadd_pd(
      _mm256_fmadd_pd(t11.a, wy1, _mm256_mul_pd(t01.a, wy0)), wz1,
      _mm256_mul_pd(_mm256_fmadd_pd(t10.a, wy1, _mm256_mul_pd(t00.a, wy0)), wz0));
  const __m256d b = _mm256_fmadd_pd(
      _mm256_fmadd_pd(t11.b, wy1, _mm256_mul_pd(t01.b, wy0)), wz1,
      _mm256_mul_pd(_mm256_fmadd_pd(t10.b, wy1, _mm256_mul_pd(t00.b, wy0)), wz0));
  // The differences' factor 1/2 on the gradient lanes.
  const __m256d wa = _mm256_mul_pd(wx, _mm256_set_pd(0.5, 0.5, 1.0, 1.0));
  const __m256d wb = _mm256_mul_pd(wx, _mm256_set1_pd(0.5));
  // hadd: [I, gv, gu, gw], the order JacobianOne reads.
  _mm256_storeu_pd(sample, _mm256_hadd_pd(_mm256_mul_pd(a, wa), _mm256_mul_pd(b, wb)));
  return true;
}

DSR_TARGET_AVX2 inline void JacobianOne(const FrameView& f,
                                        const Point& p,
                                        const double sample[4],
                                        double jac[6]) {
  // The sample as SampleOne stores it: [I, gv, gu, gw].
  const __m256d gu = _mm256_broadcast_sd(sample + 2), gv = _mm256_broadcast_sd(sample + 1),
                gw = _mm256_broadcast_sd(sample + 3);
  const __m256d grad =
      _mm256_fmadd_pd(f.g[0], gu, _mm256_fmadd_pd(f.g[1], gv, _mm256_mul_pd(f.g[2], gw)));
  const __m256d q = Affine(f.r, p);  // p_ij
  // p_ij x grad = q.yzx * grad.zxy - q.zxy * grad.yzx (lane 3: 0 - 0).
  const __m256d cross = _mm256_fmsub_pd(
      _mm256_permute4x64_pd(q, 0xC9), _mm256_permute4x64_pd(grad, 0xD2),
      _mm256_mul_pd(_mm256_permute4x64_pd(q, 0xD2), _mm256_permute4x64_pd(grad, 0xC9)));
  // jac[0..5] = [grad; cross] as [g0 g1 g2 c0] and [c1 c2]: nothing past jac[5] is
  // written (the next slot may already hold another observation's Jacobian).
  const __m256d shifted = _mm256_permute4x64_pd(cross, 0x39);  // [c1 c2 0 c0]
  _mm256_storeu_pd(jac, _mm256_blend_pd(grad, shifted, 0x8));
  _mm_storeu_pd(jac + 4, _mm256_castpd256_pd128(shifted));
}

#define DSR_KERNEL_ATTR DSR_TARGET_AVX2
#include "dsr/stream/kernels/voxel_sampler_loop.inc"
#undef DSR_KERNEL_ATTR

}  // namespace

int64_t SampleVoxelBatchAvx2(const std::vector<PosedFrame>& posed,
                             const CandidateSet& candidates,
                             int64_t v,
                             int64_t end,
                             bool with_jacobian,
                             VoxelBatch* batch) {
  return SampleVoxelBatchLoop(posed, candidates, v, end, with_jacobian, batch);
}

namespace {

// h[0..3] += s * x.
DSR_TARGET_AVX2 inline void AddScaled4(double* h, __m256d s, __m256d x) {
  _mm256_storeu_pd(h, _mm256_fmadd_pd(s, x, _mm256_loadu_pd(h)));
}
// h[0..1] += s * x.
DSR_TARGET_AVX2 inline void AddScaled2(double* h, __m128d s, __m128d x) {
  _mm_storeu_pd(h, _mm_fmadd_pd(s, x, _mm_loadu_pd(h)));
}

// Width 8 (stream/hessian_batch.h): every block row is two 4-lane registers. For every
// block row a, half of it (4 rows of the 8) at a time, and every block b >= a: 8
// accumulators, each row r adding S_r[i] * S_r[8 columns of b] for its 4 rows i (4
// broadcasts, 2 loads, 8 FMAs), then the 4 x 8 tile scaled and added to H.
DSR_TARGET_AVX2 void AddGroupHessianWideAvx2(const HessianGroup& group,
                                             const HessianWeights& weights,
                                             double* h,
                                             int n) {
  constexpr int W = kWideJacobianSize;
  const double* const* rows = group.rows;
  const int num_rows = group.num_rows, k = group.k;
  const int* frame = group.frame;
  for (int a = 0; a < k; ++a) {
    for (int i0 = W * a; i0 < W * a + W; i0 += 4) {
      double* h_row = h + static_cast<int64_t>(W * frame[a] + i0 - W * a) * n;
      for (int b = a; b < k; ++b) {
        const int c = W * b;
        __m256d acc[4][2];
        for (int i = 0; i < 4; ++i) acc[i][0] = acc[i][1] = _mm256_setzero_pd();
        for (int r = 0; r < num_rows; ++r) {
          const double* s = rows[r];
          const __m256d c0 = _mm256_loadu_pd(s + c), c1 = _mm256_loadu_pd(s + c + 4);
          for (int i = 0; i < 4; ++i) {
            const __m256d x = _mm256_broadcast_sd(s + i0 + i);
            acc[i][0] = _mm256_fmadd_pd(x, c0, acc[i][0]);
            acc[i][1] = _mm256_fmadd_pd(x, c1, acc[i][1]);
          }
        }
        const __m256d scale = _mm256_set1_pd(BlockScale(group, weights, a, b));
        for (int i = 0; i < 4; ++i) {
          double* hb = h_row + static_cast<int64_t>(i) * n + W * frame[b];
          AddScaled4(hb, scale, acc[i][0]);
          AddScaled4(hb + 4, scale, acc[i][1]);
        }
      }
    }
  }
}

// Width 8: the 8 entries as two 4-lane registers, rows in pairs as below.
DSR_TARGET_AVX2 void AddGroupGradientWideAvx2(const HessianGroup& group,
                                              const double* const* residuals,
                                              double* g) {
  constexpr int W = kWideJacobianSize;
  const double* const* rows = group.rows;
  const int num_rows = group.num_rows;
  for (int a = 0; a < group.k; ++a) {
    __m256d lo0 = _mm256_setzero_pd(), lo1 = _mm256_setzero_pd();
    __m256d hi0 = _mm256_setzero_pd(), hi1 = _mm256_setzero_pd();
    int r = 0;
    for (; r + 1 < num_rows; r += 2) {
      const double* j0 = rows[r] + W * a;
      const double* j1 = rows[r + 1] + W * a;
      const __m256d w0 = _mm256_broadcast_sd(residuals[r] + a);
      const __m256d w1 = _mm256_broadcast_sd(residuals[r + 1] + a);
      lo0 = _mm256_fmadd_pd(w0, _mm256_loadu_pd(j0), lo0);
      hi0 = _mm256_fmadd_pd(w0, _mm256_loadu_pd(j0 + 4), hi0);
      lo1 = _mm256_fmadd_pd(w1, _mm256_loadu_pd(j1), lo1);
      hi1 = _mm256_fmadd_pd(w1, _mm256_loadu_pd(j1 + 4), hi1);
    }
    if (r < num_rows) {
      const double* j0 = rows[r] + W * a;
      const __m256d w0 = _mm256_broadcast_sd(residuals[r] + a);
      lo0 = _mm256_fmadd_pd(w0, _mm256_loadu_pd(j0), lo0);
      hi0 = _mm256_fmadd_pd(w0, _mm256_loadu_pd(j0 + 4), hi0);
    }
    double* ga = g + W * group.frame[a];
    _mm256_storeu_pd(ga, _mm256_add_pd(_mm256_loadu_pd(ga), _mm256_add_pd(lo0, lo1)));
    _mm256_storeu_pd(ga + 4, _mm256_add_pd(_mm256_loadu_pd(ga + 4), _mm256_add_pd(hi0, hi1)));
  }
}

}  // namespace


// The group's rows S_r = [J_0 ... J_{k-1}] are 6k consecutive doubles each. For every
// block row a and half of it (3 rows of the 6), the kernel walks the columns of blocks
// b >= a two blocks (12 columns, 3 registers) at a time: 9 accumulators, each row r adds
// S_r[i] * S_r[12 columns] for its 3 rows i (3 broadcasts, 3 loads, 9 FMAs: no padding
// lane), then the tile is scaled per block and added to H. An odd last block is a 3 x 6
// tile (a 4-lane and a 2-lane register per row).
DSR_TARGET_AVX2 void AddGroupHessianAvx2(const HessianGroup& group,
                         const HessianWeights& weights,
                         double* h,
                         int n) {
  if (group.width == kWideJacobianSize) {
    AddGroupHessianWideAvx2(group, weights, h, n);
    return;
  }
  const double* const* rows = group.rows;
  const int num_rows = group.num_rows, k = group.k;
  const int* frame = group.frame;
  for (int a = 0; a < k; ++a) {
    for (int i0 = 6 * a; i0 < 6 * a + 6; i0 += 3) {
      double* h_row = h + static_cast<int64_t>(6 * frame[a] + i0 - 6 * a) * n;
      for (int b = a; b < k; b += 2) {
        const int c = 6 * b;
        const double wb = BlockScale(group, weights, a, b);
        if (b + 1 < k) {
          __m256d acc[3][3];
          for (int i = 0; i < 3; ++i) acc[i][0] = acc[i][1] = acc[i][2] = _mm256_setzero_pd();
          for (int r = 0; r < num_rows; ++r) {
            const double* s = rows[r];
            const __m256d c0 = _mm256_loadu_pd(s + c), c1 = _mm256_loadu_pd(s + c + 4),
                          c2 = _mm256_loadu_pd(s + c + 8);
            for (int i = 0; i < 3; ++i) {
              const __m256d x = _mm256_broadcast_sd(s + i0 + i);
              acc[i][0] = _mm256_fmadd_pd(x, c0, acc[i][0]);
              acc[i][1] = _mm256_fmadd_pd(x, c1, acc[i][1]);
              acc[i][2] = _mm256_fmadd_pd(x, c2, acc[i][2]);
            }
          }
          // Columns 0..5 belong to block b (weight wb), 6..11 to block b + 1 (b + 1 > a).
          const __m256d s0 = _mm256_set1_pd(wb),
                        s2 = _mm256_set1_pd(BlockScale(group, weights, a, b + 1));
          for (int i = 0; i < 3; ++i) {
            double* hb = h_row + static_cast<int64_t>(i) * n + 6 * frame[b];
            double* hb1 = h_row + static_cast<int64_t>(i) * n + 6 * frame[b + 1];
            AddScaled4(hb, s0, acc[i][0]);
            AddScaled2(hb + 4, _mm256_castpd256_pd128(s0), _mm256_castpd256_pd128(acc[i][1]));
            AddScaled2(hb1, _mm256_castpd256_pd128(s2), _mm256_extractf128_pd(acc[i][1], 1));
            AddScaled4(hb1 + 2, s2, acc[i][2]);
          }
        } else {
          __m256d acc4[3];
          __m128d acc2[3];
          for (int i = 0; i < 3; ++i) {
            acc4[i] = _mm256_setzero_pd();
            acc2[i] = _mm_setzero_pd();
          }
          for (int r = 0; r < num_rows; ++r) {
            const double* s = rows[r];
            const __m256d c0 = _mm256_loadu_pd(s + c);
            const __m128d c1 = _mm_loadu_pd(s + c + 4);
            for (int i = 0; i < 3; ++i) {
              const __m256d x = _mm256_broadcast_sd(s + i0 + i);
              acc4[i] = _mm256_fmadd_pd(x, c0, acc4[i]);
              acc2[i] = _mm_fmadd_pd(_mm256_castpd256_pd128(x), c1, acc2[i]);
            }
          }
          const __m256d s0 = _mm256_set1_pd(wb);
          for (int i = 0; i < 3; ++i) {
            double* hb = h_row + static_cast<int64_t>(i) * n + 6 * frame[b];
            AddScaled4(hb, s0, acc4[i]);
            AddScaled2(hb + 4, _mm256_castpd256_pd128(s0), acc2[i]);
          }
        }
      }
    }
  }
}

// For each a: the 6 entries as a 4-lane and a 2-lane register; rows in pairs with two
// sets of accumulators, so that consecutive rows' FMAs do not wait on each other.
DSR_TARGET_AVX2 void AddGroupGradientAvx2(const HessianGroup& group,
                                          const double* const* residuals,
                                          double* g) {
  if (group.width == kWideJacobianSize) {
    AddGroupGradientWideAvx2(group, residuals, g);
    return;
  }
  const double* const* rows = group.rows;
  const int num_rows = group.num_rows;
  for (int a = 0; a < group.k; ++a) {
    __m256d lo0 = _mm256_setzero_pd(), lo1 = _mm256_setzero_pd();
    __m128d hi0 = _mm_setzero_pd(), hi1 = _mm_setzero_pd();
    int r = 0;
    for (; r + 1 < num_rows; r += 2) {
      const double* j0 = rows[r] + 6 * a;
      const double* j1 = rows[r + 1] + 6 * a;
      const __m256d w0 = _mm256_broadcast_sd(residuals[r] + a);
      const __m256d w1 = _mm256_broadcast_sd(residuals[r + 1] + a);
      lo0 = _mm256_fmadd_pd(w0, _mm256_loadu_pd(j0), lo0);
      hi0 = _mm_fmadd_pd(_mm256_castpd256_pd128(w0), _mm_loadu_pd(j0 + 4), hi0);
      lo1 = _mm256_fmadd_pd(w1, _mm256_loadu_pd(j1), lo1);
      hi1 = _mm_fmadd_pd(_mm256_castpd256_pd128(w1), _mm_loadu_pd(j1 + 4), hi1);
    }
    if (r < num_rows) {
      const double* j0 = rows[r] + 6 * a;
      const __m256d w0 = _mm256_broadcast_sd(residuals[r] + a);
      lo0 = _mm256_fmadd_pd(w0, _mm256_loadu_pd(j0), lo0);
      hi0 = _mm_fmadd_pd(_mm256_castpd256_pd128(w0), _mm_loadu_pd(j0 + 4), hi0);
    }
    double* ga = g + 6 * group.frame[a];
    _mm256_storeu_pd(ga, _mm256_add_pd(_mm256_loadu_pd(ga), _mm256_add_pd(lo0, lo1)));
    _mm_storeu_pd(ga + 4, _mm_add_pd(_mm_loadu_pd(ga + 4), _mm_add_pd(hi0, hi1)));
  }
}

}  // namespace internal
}  // namespace dsr

#endif  // DSR_HAVE_AVX2_KERNELS
