// Batched Gauss-Newton matrix of the voxel stream (core/voxel_stream.h).
//
// For DSR (and APE), one voxel observed by frames a = 0..k-1 with Jacobians J_a adds
//   H_ab += (delta_ab * diagonal + shared) J_a^T J_b        (DSR: 1 and -1/k)
// to every pair of its observers: k(k+1)/2 6x6 blocks. Added voxel by voxel, every one of
// those multiply-adds loads and stores an element of H, which made the block updates a
// third of an evaluation. Neighbouring voxels mostly have the same observers, so the
// batcher keeps a few open batches keyed by the observer set: a batch stacks its voxels'
// rows s_v = [J_0 ... J_{k-1}] (N x 6k, one row per voxel), and a flush adds
//   P = S^T S  (one symmetric rank-N update, register-blocked by Eigen),
//   H_ab += (delta_ab * diagonal + shared) P_ab
// once per N voxels. Same sums, added in another order.
//
// The slow twin is the per-voxel AddOuter path of the same term (tests compare them).
#ifndef DSR_CORE_HESSIAN_BATCH_H_
#define DSR_CORE_HESSIAN_BATCH_H_

#include <cstdint>
#include <vector>

#include <Eigen/Core>

#include "core/observation.h"

namespace dsr {

// The per-voxel form of a term's Gauss-Newton matrix, given the voxel's k observers.
struct HessianWeights {
  double diagonal = 0.0;  // added to the a == b blocks only
  double shared = 0.0;    // added to every block
};

class HessianBatcher {
 public:
  // Voxels per batch and open batches: one flush per kRows voxels; kSlots observer sets
  // are open at a time (replaced least recently used first).
  static constexpr int kRows = 64;
  static constexpr int kSlots = 8;

  // `h`: row-major n x n matrix the flushes add to (upper block triangle, and the diagonal
  // blocks on and above their diagonal, as AddOuter fills them).
  HessianBatcher(double* h, int n);

  // Adds one voxel: its k observers `frame[0..k)` (increasing), their Jacobians, and the
  // weights of its form. Voxels with the same observers must come with the same weights.
  void Add(int k, const int* frame, const double (*jac)[6], const HessianWeights& weights);

  // Adds every open batch to H (call before reading H).
  void Flush();

 private:
  struct Slot {
    uint32_t observers = 0;  // 0: free
    int k = 0;
    int rows = 0;
    int64_t last_use = 0;
    HessianWeights weights;
    int frame[kMaxFrames];
    Eigen::MatrixXd stacked;  // kRows x 6k, row r = voxel r's [J_0 ... J_{k-1}]
  };
  void FlushSlot(Slot* slot);

  double* h_;
  int n_;
  int64_t clock_ = 0;
  Slot slots_[kSlots];
  Eigen::MatrixXd product_;  // scratch for P = S^T S
};

}  // namespace dsr

#endif  // DSR_CORE_HESSIAN_BATCH_H_
