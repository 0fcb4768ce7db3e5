// SsdToMeanTerm: DSR's per-voxel term (stream/voxel_term.h), the sum of squared
// differences of a voxel's observations to their mean, the panorama intensity eliminated
// in closed form (docs/design.md sections 4.1-4.2). The term every plain DSR evaluation
// streams (AccumulateReducedSystem, stream/reduced_system.h); its photometric and weighted
// variants are in stream/reduced_system.cc.
#ifndef DSR_STREAM_SSD_TO_MEAN_TERM_H_
#define DSR_STREAM_SSD_TO_MEAN_TERM_H_

#include "dsr/model/observation.h"
#include "dsr/stream/hessian_batch.h"
#include "dsr/stream/voxel_term.h"

namespace dsr {

// The DSR term of one voxel observed by k >= 2 frames: r_a = I_a - mu,
//   cost += sum_a r_a^2,  g_a += J_a^T r_a,  H_ab += (delta_ab - 1/k) J_a^T J_b,
// and frame a's share r_a^2 of the cost (for the per-frame misfits). H and g are added in
// batches by the stream from the Jacobians and the residuals the term writes (fast path),
// or here voxel by voxel (the twin tests compare with).
struct SsdToMeanTerm {
  static constexpr int kFrameParameters = 6;
  bool batched_hessian = true;
  bool batched_gradient = true;
  HessianWeights Weights(int k) const { return {1.0, -1.0 / k}; }

  // The voxel's numbers are read through restrict pointers and summed in locals: the
  // accumulator's doubles could otherwise alias them, and every store to the gradient
  // would reload the observations (callgrind: 76 instructions per observation, now 53
  // with the per-voxel loop).
  void operator()(const VoxelObservations& obs, bool with_jacobian, VoxelAccumulator* acc) const {
    const int k = obs.k;
    const int* __restrict frame = obs.frame;
    const double* __restrict value = obs.value;
    double mean = 0.0;
    for (int a = 0; a < k; ++a) mean += value[a];
    mean /= k;
    // With a batched gradient the residuals go straight to the batch for the stream.
    double local[kMaxFrames];
    double* __restrict residual = obs.residual != nullptr ? obs.residual : local;
    double cost = 0.0;
    for (int a = 0; a < k; ++a) {
      const double r = value[a] - mean;
      residual[a] = r;
      cost += r * r;
      acc->frame_cost[frame[a]] += r * r;
      ++acc->frame_observations[frame[a]];
    }
    acc->cost += cost;
    acc->observations += k;
    if (!with_jacobian || obs.residual != nullptr) return;
    double* __restrict g = acc->gradient.data();
    for (int a = 0; a < k; ++a) AddGradient(g, frame[a], obs.jac[a], residual[a]);
    if (batched_hessian) return;
    const double inv_k = 1.0 / k;
    double* h = acc->hessian.data();
    const int n = acc->n;
    for (int a = 0; a < k; ++a) {
      AddOuter(h, n, frame[a], frame[a], obs.jac[a], obs.jac[a], 1.0 - inv_k);
      for (int b = a + 1; b < k; ++b) {
        AddOuter(h, n, frame[a], frame[b], obs.jac[a], obs.jac[b], -inv_k);
      }
    }
  }
};

}  // namespace dsr

#endif  // DSR_STREAM_SSD_TO_MEAN_TERM_H_
