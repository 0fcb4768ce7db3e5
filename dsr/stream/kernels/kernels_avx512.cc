// AVX-512 group kernel of the batched Gauss-Newton matrix (stream/hessian_batch.h): the
// same sums as AddGroupHessianPortable and AddGroupHessianAvx2, eight lanes at a time.
//
// A group's rows S_r = [J_0 ... J_{k-1}] are 6k consecutive doubles each (stream/voxel_stream.h).
// For every block row a, the kernel walks the columns of blocks b >= a four blocks (24
// columns, 3 registers) at a time, all 6 rows of block a at once: 18 accumulators (of
// the 32 registers), each row r adding S_r[i] * S_r[24 columns] for i = 0..5 (6
// broadcasts, 3 loads, 18 FMAs). A last chunk of 1-3 blocks loads only the registers it
// needs (its last one masked: nothing past the row). The 6 x 24 tile is then scaled per
// block and added to H, 6 masked lanes per block row. Width 8 (photometric parameters):
// one whole register per block row, 8 rows x 3 blocks per tile (AddGroupHessianWideAvx512).
#include "dsr/stream/kernels/kernels_avx512.h"

#include "dsr/stream/hessian_batch.h"
#include "dsr/stream/voxel_stream.h"

#ifdef DSR_HAVE_AVX512_KERNELS
#include <immintrin.h>

#define DSR_TARGET_AVX512 __attribute__((target("avx512f,fma")))

namespace dsr {
namespace internal {

namespace {

// Sums S_r[i0 + i] * S_r[c .. c + 8 kVectors) over the rows for i = 0..5 into `tile`
// (6 rows x 24 columns, row-major); the columns from `width` on are not read and come out
// 0. Only the last register can reach past the row (kMaskLast): the others load whole,
// so the loop holds one mask register and no mask moves (they would take the port of
// half the FMAs).
template <int kVectors, bool kMaskLast>
DSR_TARGET_AVX512 void SumTile(const double* const* rows,
                               int num_rows,
                               int i0,
                               int c,
                               int width,
                               double tile[6][24]) {
  const int last_lanes = width - c - 8 * (kVectors - 1);
  const __mmask8 last_mask =
      last_lanes >= 8 ? 0xFF : static_cast<__mmask8>((1u << last_lanes) - 1u);
  __m512d acc[6][kVectors];
  for (int i = 0; i < 6; ++i) {
    for (int v = 0; v < kVectors; ++v) acc[i][v] = _mm512_setzero_pd();
  }
  for (int r = 0; r < num_rows; ++r) {
    const double* s = rows[r];
    __m512d col[kVectors];
    for (int v = 0; v < kVectors; ++v) {
      col[v] = kMaskLast && v == kVectors - 1 ? _mm512_maskz_loadu_pd(last_mask, s + c + 8 * v)
                                              : _mm512_loadu_pd(s + c + 8 * v);
    }
    for (int i = 0; i < 6; ++i) {
      const __m512d x = _mm512_set1_pd(s[i0 + i]);
      for (int v = 0; v < kVectors; ++v) acc[i][v] = _mm512_fmadd_pd(x, col[v], acc[i][v]);
    }
  }
  for (int i = 0; i < 6; ++i) {
    for (int v = 0; v < kVectors; ++v) _mm512_storeu_pd(tile[i] + 8 * v, acc[i][v]);
    for (int v = kVectors; v < 3; ++v) _mm512_storeu_pd(tile[i] + 8 * v, _mm512_setzero_pd());
  }
}

// The tile of `blocks` (1..4) blocks from column c.
DSR_TARGET_AVX512 inline void SumBlocks(const double* const* rows,
                                        int num_rows,
                                        int i0,
                                        int c,
                                        int width,
                                        int blocks,
                                        double tile[6][24]) {
  // 1 block: one register (6 lanes); 2: two (8 + 4); 3: three (8 + 8 + 2); 4: three whole.
  switch (blocks) {
    case 1:
      SumTile<1, true>(rows, num_rows, i0, c, width, tile);
      break;
    case 2:
      SumTile<2, true>(rows, num_rows, i0, c, width, tile);
      break;
    case 3:
      SumTile<3, true>(rows, num_rows, i0, c, width, tile);
      break;
    default:
      SumTile<3, false>(rows, num_rows, i0, c, width, tile);
  }
}

// Width 8 (stream/hessian_batch.h): one register per block row. The tile of `kBlocks`
// (1-3) blocks from column c, all 8 rows of block row a at once: up to 24 accumulators,
// each row r adding S_r[i0 + i] * S_r[8 kBlocks columns] for i = 0..7 (8 broadcasts,
// kBlocks loads, 8 kBlocks FMAs).
template <int kBlocks>
DSR_TARGET_AVX512 void SumWideTile(const double* const* rows,
                                   int num_rows,
                                   int i0,
                                   int c,
                                   double tile[8][24]) {
  __m512d acc[8][kBlocks];
  for (int i = 0; i < 8; ++i) {
    for (int v = 0; v < kBlocks; ++v) acc[i][v] = _mm512_setzero_pd();
  }
  for (int r = 0; r < num_rows; ++r) {
    const double* s = rows[r];
    __m512d col[kBlocks];
    for (int v = 0; v < kBlocks; ++v) col[v] = _mm512_loadu_pd(s + c + 8 * v);
    for (int i = 0; i < 8; ++i) {
      const __m512d x = _mm512_set1_pd(s[i0 + i]);
      for (int v = 0; v < kBlocks; ++v) acc[i][v] = _mm512_fmadd_pd(x, col[v], acc[i][v]);
    }
  }
  for (int i = 0; i < 8; ++i) {
    for (int v = 0; v < kBlocks; ++v) _mm512_storeu_pd(tile[i] + 8 * v, acc[i][v]);
  }
}

DSR_TARGET_AVX512 void AddGroupHessianWideAvx512(const HessianGroup& group,
                                                 const HessianWeights& weights,
                                                 double* h,
                                                 int n) {
  constexpr int W = kWideJacobianSize;
  const double* const* rows = group.rows;
  const int num_rows = group.num_rows, k = group.k;
  const int* frame = group.frame;
  alignas(64) double tile[8][24];
  for (int a = 0; a < k; ++a) {
    const int i0 = W * a;
    for (int b0 = a; b0 < k; b0 += 3) {
      const int blocks = k - b0 < 3 ? k - b0 : 3;
      const int c = W * b0;
      switch (blocks) {
        case 1:
          SumWideTile<1>(rows, num_rows, i0, c, tile);
          break;
        case 2:
          SumWideTile<2>(rows, num_rows, i0, c, tile);
          break;
        default:
          SumWideTile<3>(rows, num_rows, i0, c, tile);
      }
      for (int q = 0; q < blocks; ++q) {
        const int b = b0 + q;
        const __m512d scale = _mm512_set1_pd(BlockScale(group, weights, a, b));
        for (int i = 0; i < W; ++i) {
          double* row = h + static_cast<int64_t>(W * frame[a] + i) * n + W * frame[b];
          _mm512_storeu_pd(row, _mm512_fmadd_pd(scale, _mm512_loadu_pd(tile[i] + 8 * q),
                                                _mm512_loadu_pd(row)));
        }
      }
    }
  }
}

}  // namespace

DSR_TARGET_AVX512 void AddGroupHessianAvx512(const HessianGroup& group,
                         const HessianWeights& weights,
                         double* h,
                         int n) {
  if (group.width == kWideJacobianSize) {
    AddGroupHessianWideAvx512(group, weights, h, n);
    return;
  }
  const double* const* rows = group.rows;
  const int num_rows = group.num_rows, k = group.k;
  const int* frame = group.frame;
  const int width = 6 * k;
  constexpr __mmask8 kBlockRow = 0x3F;  // 6 lanes
  alignas(64) double tile[6][24];
  for (int a = 0; a < k; ++a) {
    const int i0 = 6 * a;
    for (int c = i0; c < width; c += 24) {
      const int blocks = (width - c) / 6 < 4 ? (width - c) / 6 : 4;
      SumBlocks(rows, num_rows, i0, c, width, blocks, tile);
      for (int q = 0; q < blocks; ++q) {
        const int b = c / 6 + q;
        const __m512d scale = _mm512_set1_pd(BlockScale(group, weights, a, b));
        for (int i = 0; i < 6; ++i) {
          double* row = h + static_cast<int64_t>(6 * frame[a] + i) * n + 6 * frame[b];
          const __m512d sum = _mm512_maskz_loadu_pd(kBlockRow, tile[i] + 6 * q);
          _mm512_mask_storeu_pd(
              row, kBlockRow, _mm512_fmadd_pd(scale, sum, _mm512_maskz_loadu_pd(kBlockRow, row)));
        }
      }
    }
  }
}

}  // namespace internal
}  // namespace dsr

#endif  // DSR_HAVE_AVX512_KERNELS
