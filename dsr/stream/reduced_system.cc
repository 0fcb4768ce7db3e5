// The reduced normal equations (docs/design.md section 4): the per-voxel terms of the
// stream, and the reweighting pass of a robust loss.
#include "dsr/stream/reduced_system.h"

#include <algorithm>
#include <cfloat>
#include <cmath>
#include <memory>

#include <glog/logging.h>

#include "dsr/solve/gauge.h"
#include "dsr/stream/ssd_to_mean_term.h"

namespace dsr {
namespace {

// The DSR term with photometric parameters (docs/design.md section 2.8), residuals in each
// frame's own grey levels. With the corrected observations c_a = g_a I_a + b_a (g = gain,
// b = offset of the observing frame) and u_a = 1 / g_a,
//   mu = sum_a u_a^2 c_a / S,  S = sum_a u_a^2,   r_a = u_a (c_a - mu),
// and the rows R_a = [J_a, u_a (mu - b_a), u_a] (pose tangent, log gain, offset): the
// Jacobian of r with the intensity eliminated (DBA's Schur complement at M = mu) is
//   d r_a / d x_b = (delta_ab - u_a u_b / S) R_b,
//   cost += sum_a r_a^2,  g_b += R_b^T r_b,  H_ab += (delta_ab - u_a u_b / S) R_a^T R_b,
// batched by the stream with the projection factors u (stream/hessian_batch.h).
struct DsrPhotometricVoxelTerm {
  static constexpr int kFrameParameters = kWideJacobianSize;
  bool batched_hessian = true;
  bool batched_gradient = true;
  double gain[kMaxFrames];
  double offset[kMaxFrames];
  double unit[kMaxFrames];              // 1 / gain
  const double* projection_factors = unit;
  HessianWeights Weights(int) const { return {}; }  // not read: projection_factors

  DsrPhotometricVoxelTerm() = default;
  // `unit` is an array member: a copy must point at its own.
  DsrPhotometricVoxelTerm(const DsrPhotometricVoxelTerm&) = delete;
  DsrPhotometricVoxelTerm& operator=(const DsrPhotometricVoxelTerm&) = delete;

  void operator()(const VoxelObservations& obs, bool with_jacobian, VoxelAccumulator* acc) const {
    const int k = obs.k;
    const int* __restrict frame = obs.frame;
    const double* __restrict value = obs.value;
    double u[kMaxFrames];
    double weighted = 0.0, total = 0.0;
    for (int a = 0; a < k; ++a) {
      const int f = frame[a];
      u[a] = unit[f];
      const double w = u[a] * u[a];
      weighted += w * (gain[f] * value[a] + offset[f]);
      total += w;
    }
    const double mean = weighted / total;
    double local[kMaxFrames];
    double* __restrict residual = obs.residual != nullptr ? obs.residual : local;
    double cost = 0.0;
    for (int a = 0; a < k; ++a) {
      // u (c - mu) = I - u (mu - b): in the frame's grey levels.
      const double in_frame = u[a] * (mean - offset[frame[a]]);
      const double r = value[a] - in_frame;
      residual[a] = r;
      cost += r * r;
      acc->frame_cost[frame[a]] += r * r;
      ++acc->frame_observations[frame[a]];
    }
    acc->cost += cost;
    acc->observations += k;
    if (!with_jacobian) return;
    double (*__restrict wide)[kWideJacobianSize] = obs.wide_jac;
    for (int a = 0; a < k; ++a) {
      for (int e = 0; e < kJacobianSize; ++e) wide[a][e] = obs.jac[a][e];
      wide[a][6] = value[a] - residual[a];  // u (mu - b)
      wide[a][7] = u[a];
    }
    if (obs.residual != nullptr) return;  // the stream adds g and H
    constexpr int W = kWideJacobianSize;
    double* __restrict grad = acc->gradient.data();
    for (int a = 0; a < k; ++a) {
      for (int e = 0; e < W; ++e) grad[W * frame[a] + e] += residual[a] * wide[a][e];
    }
    if (batched_hessian) return;
    // The slow twin: every pair's 8 x 8 block (the diagonal ones whole, above their
    // diagonal is what the stream reads).
    double* h = acc->hessian.data();
    const int n = acc->n;
    for (int a = 0; a < k; ++a) {
      for (int b = a; b < k; ++b) {
        const double w = (a == b ? 1.0 : 0.0) - u[a] * u[b] / total;
        for (int i = 0; i < W; ++i) {
          double* row = h + static_cast<int64_t>(W * frame[a] + i) * n + W * frame[b];
          for (int j = 0; j < W; ++j) row[j] += w * wide[a][i] * wide[b][j];
        }
      }
    }
  }
};

// The weighted DSR term (robust loss, IRLS; the header's f_w): with observation weights
// w_a (> 0) of the voxel's valid observations, the corrected observations c_a (= I_a, or
// g_a I_a + b_a with photometric parameters), their units u_a (1, or 1 / g_a) and rows R_a
// (J_a, or [J_a, u_a (mu - b_a), u_a]), V = sum_a w_a u_a^2,
//   mu = sum_a w_a u_a^2 c_a / V,  r_a = u_a (c_a - mu),  cost += sum_a w_a r_a^2,
//   g_a += w_a r_a R_a,            H_ab += (delta_ab w_a - w_a u_a w_b u_b / V) R_a^T R_b,
// added voxel by voxel (the weights differ per observation, so H has no batched form
// here). The voxel's weights are found by its candidate index (VoxelObservations::voxel).
template <int kWidth>
struct DsrWeightedVoxelTerm {
  static_assert(kWidth == kJacobianSize || kWidth == kWideJacobianSize, "6 or 8 per frame");
  static constexpr int kFrameParameters = kWidth;
  bool batched_hessian = false;
  bool batched_gradient = false;
  HessianWeights Weights(int) const { return {}; }  // not batched
  const uint32_t* observers = nullptr;              // CandidateSet::observers
  const ObservationWeights* weights = nullptr;
  double gain[kMaxFrames];    // kWidth 8 only
  double offset[kMaxFrames];  // kWidth 8 only
  double unit[kMaxFrames];    // kWidth 8 only: 1 / gain

  void operator()(const VoxelObservations& obs, bool with_jacobian, VoxelAccumulator* acc) const {
    constexpr bool kPhotometric = kWidth == kWideJacobianSize;
    const int k = obs.k;
    const int* __restrict frame = obs.frame;
    const double* __restrict value = obs.value;
    const uint32_t bits = observers[obs.voxel];
    const float* voxel_weights = weights->weight.data() + weights->offset[obs.voxel];
    // v[a] = w_a u_a^2, the weight of c_a in the mean (w_a without photometric parameters,
    // so that the plain numbers are those of the plain weighted mean).
    double w[kMaxFrames], v[kMaxFrames], c[kMaxFrames], r[kMaxFrames];
    double total = 0.0, sum = 0.0;
    for (int a = 0; a < k; ++a) {
      const int f = frame[a];
      w[a] = voxel_weights[__builtin_popcount(bits & ((1u << f) - 1u))];
      c[a] = kPhotometric ? gain[f] * value[a] + offset[f] : value[a];
      v[a] = kPhotometric ? w[a] * unit[f] * unit[f] : w[a];
      total += v[a];
      sum += v[a] * c[a];
    }
    const double mean = sum / total;
    double cost = 0.0;
    for (int a = 0; a < k; ++a) {
      r[a] = kPhotometric ? value[a] - unit[frame[a]] * (mean - offset[frame[a]]) : c[a] - mean;
      const double share = w[a] * r[a] * r[a];
      cost += share;
      acc->frame_cost[frame[a]] += share;
      ++acc->frame_observations[frame[a]];
    }
    acc->cost += cost;
    acc->observations += k;
    if (!with_jacobian) return;
    double row[kMaxFrames][kWidth];
    double wu[kMaxFrames];  // w_a u_a
    for (int a = 0; a < k; ++a) {
      for (int e = 0; e < kJacobianSize; ++e) row[a][e] = obs.jac[a][e];
      if (kPhotometric) {
        const double u = unit[frame[a]];
        row[a][kWidth - 2] = value[a] - r[a];  // u (mu - b)
        row[a][kWidth - 1] = u;
        wu[a] = w[a] * u;
      } else {
        wu[a] = w[a];
      }
    }
    double* __restrict grad = acc->gradient.data();
    for (int a = 0; a < k; ++a) {
      const double s = w[a] * r[a];
      for (int e = 0; e < kWidth; ++e) grad[kWidth * frame[a] + e] += s * row[a][e];
    }
    // Blocks (frame[a], frame[b]) for a <= b (frames increase with a), the diagonal ones on
    // and above their diagonal: what the stream reads.
    double* h = acc->hessian.data();
    const int n = acc->n;
    for (int a = 0; a < k; ++a) {
      for (int b = a; b < k; ++b) {
        const double coefficient = (a == b ? w[a] : 0.0) - wu[a] * wu[b] / total;
        for (int i = 0; i < kWidth; ++i) {
          const double si = coefficient * row[a][i];
          double* out = h + static_cast<int64_t>(kWidth * frame[a] + i) * n + kWidth * frame[b];
          for (int j = a == b ? i : 0; j < kWidth; ++j) out[j] += si * row[b][j];
        }
      }
    }
  }
};

}  // namespace

ObservationWeights::ObservationWeights(const CandidateSet& candidates) {
  const int64_t n = candidates.num_voxels();
  offset.resize(n + 1);
  offset[0] = 0;
  for (int64_t v = 0; v < n; ++v) {
    offset[v + 1] = offset[v] + __builtin_popcount(candidates.observers[v]);
  }
  weight.assign(offset[n], 1.0f);
}

namespace {

// sum += part (every field; both from the same kind of pass).
void AddNormalEquations(const NormalEquations& part, NormalEquations* sum) {
  if (part.hessian.size() != 0) sum->hessian += part.hessian;
  if (part.gradient.size() != 0) sum->gradient += part.gradient;
  sum->cost += part.cost;
  sum->observations += part.observations;
  sum->voxels += part.voxels;
  for (size_t i = 0; i < part.frame_cost.size() && i < sum->frame_cost.size(); ++i) {
    sum->frame_cost[i] += part.frame_cost[i];
    sum->frame_observations[i] += part.frame_observations[i];
  }
}

// `accumulate(frames_of_one_phase, out)` for every phase of `frames`, the results summed:
// the tied cost of views with T phases (docs/design.md section 12). One phase: the call.
template <class Accumulate>
void SumOverPhases(const std::vector<Frame>& frames, ReducedSystem* out, Accumulate accumulate) {
  const int phases = NumPhases(frames);
  if (phases == 1) {
    accumulate(frames, out);
    return;
  }
  accumulate(PhaseFrames(frames, 0), out);
  for (int p = 1; p < phases; ++p) {
    ReducedSystem part;
    accumulate(PhaseFrames(frames, p), &part);
    AddNormalEquations(part, out);
  }
}

}  // namespace

void AccumulateReducedSystem(const std::vector<Frame>& frames,
                             const CandidateSet& candidates,
                             const std::vector<Eigen::Isometry3d>& frame_from_world,
                             int64_t begin,
                             int64_t end,
                             bool with_jacobian,
                             const StreamContext& context,
                             ReducedSystem* out,
                             bool batched_hessian) {
  if (NumPhases(frames) > 1) {
    SumOverPhases(frames, out, [&](const std::vector<Frame>& phase, ReducedSystem* part) {
      AccumulateReducedSystem(phase, candidates, frame_from_world, begin, end, with_jacobian,
                              context, part, batched_hessian);
    });
    return;
  }
  SsdToMeanTerm term;
  term.batched_hessian = batched_hessian;
  term.batched_gradient = batched_hessian;
  StreamNormalEquations(frames, candidates, frame_from_world, begin, end, with_jacobian,
                        context, term, out);
}

void AccumulateReducedPhotometricSystem(const std::vector<Frame>& frames,
                                        const CandidateSet& candidates,
                                        const std::vector<Eigen::Isometry3d>& frame_from_world,
                                        const std::vector<Photometric>& photometric,
                                        int64_t begin,
                                        int64_t end,
                                        bool with_jacobian,
                                        const StreamContext& context,
                                        ReducedSystem* out,
                                        bool batched_hessian) {
  CHECK_EQ(photometric.size(), frames.size());
  if (NumPhases(frames) > 1) {
    SumOverPhases(frames, out, [&](const std::vector<Frame>& phase, ReducedSystem* part) {
      AccumulateReducedPhotometricSystem(phase, candidates, frame_from_world, photometric, begin,
                                         end, with_jacobian, context, part, batched_hessian);
    });
    return;
  }
  DsrPhotometricVoxelTerm term;
  term.batched_hessian = batched_hessian;
  term.batched_gradient = batched_hessian;
  for (size_t i = 0; i < photometric.size(); ++i) {
    term.gain[i] = photometric[i].gain();
    term.offset[i] = photometric[i].offset;
    term.unit[i] = photometric[i].unit();
  }
  StreamNormalEquations(frames, candidates, frame_from_world, begin, end, with_jacobian,
                        context, term, out);
}

void AccumulateWeightedReducedSystem(const std::vector<Frame>& frames,
                                     const CandidateSet& candidates,
                                     const std::vector<Eigen::Isometry3d>& frame_from_world,
                                     const std::vector<Photometric>& photometric,
                                     const ObservationWeights& weights,
                                     int64_t begin,
                                     int64_t end,
                                     bool with_jacobian,
                                     const StreamContext& context,
                                     ReducedSystem* out) {
  CHECK_EQ(static_cast<int64_t>(weights.offset.size()), candidates.num_voxels() + 1)
      << "weights built for another candidate set";
  CHECK_EQ(NumPhases(frames), 1) << "observation weights are one phase's: pass its frames";
  if (photometric.empty()) {
    DsrWeightedVoxelTerm<kJacobianSize> term;
    term.observers = candidates.observers.data();
    term.weights = &weights;
    StreamNormalEquations(frames, candidates, frame_from_world, begin, end, with_jacobian,
                          context, term, out);
    return;
  }
  CHECK_EQ(photometric.size(), frames.size());
  DsrWeightedVoxelTerm<kWideJacobianSize> term;
  term.observers = candidates.observers.data();
  term.weights = &weights;
  for (size_t i = 0; i < photometric.size(); ++i) {
    term.gain[i] = photometric[i].gain();
    term.offset[i] = photometric[i].offset;
    term.unit[i] = photometric[i].unit();
  }
  StreamNormalEquations(frames, candidates, frame_from_world, begin, end, with_jacobian,
                        context, term, out);
}

void UpdateObservationWeights(const std::vector<Frame>& frames,
                              const CandidateSet& candidates,
                              const std::vector<Eigen::Isometry3d>& frame_from_world,
                              const std::vector<Photometric>& photometric,
                              const RobustLoss& loss,
                              const StreamContext& context,
                              ObservationWeights* weights,
                              ReweightStats* stats) {
  const int m = static_cast<int>(frames.size());
  CHECK_EQ(static_cast<int>(frame_from_world.size()), m);
  CHECK(photometric.empty() || static_cast<int>(photometric.size()) == m);
  CHECK_EQ(static_cast<int64_t>(weights->offset.size()), candidates.num_voxels() + 1)
      << "weights built for another candidate set";
  CHECK_EQ(NumPhases(frames), 1) << "observation weights are one phase's: pass its frames";
  double gain[kMaxFrames], offset[kMaxFrames], unit[kMaxFrames];
  for (int i = 0; i < m; ++i) {
    gain[i] = photometric.empty() ? 1.0 : photometric[i].gain();
    offset[i] = photometric.empty() ? 0.0 : photometric[i].offset;
    unit[i] = photometric.empty() ? 1.0 : photometric[i].unit();
  }
  const KernelPath path = StreamKernelPath(context);
  const std::vector<PosedFrame> posed = PoseFrames(frames, frame_from_world);
  // Fixed blocks summed in order, as in StreamNormalEquations: identical for any thread
  // count. Each voxel's weights are written by its block only.
  const int64_t n = candidates.num_voxels();
  const int64_t num_blocks = std::max<int64_t>(1, std::min<int64_t>(64, n));
  const int64_t block_size = (n + num_blocks - 1) / num_blocks;
  std::vector<ReweightStats> partial(num_blocks);
  float* w_all = weights->weight.data();
  const int64_t* offsets = weights->offset.data();
  ParallelFor(0, num_blocks, context.num_threads, [&](int64_t block) {
    ReweightStats& out = partial[block];
    // Candidate observations the sampler does not hand over get weight 1.
    const auto reset = [&](int64_t v0, int64_t v1) {
      for (int64_t l = offsets[v0]; l < offsets[v1]; ++l) {
        out.max_weight_change = std::max(out.max_weight_change, std::abs(1.0 - w_all[l]));
        w_all[l] = 1.0f;
      }
    };
    VoxelBatch* const batch = ThreadVoxelBatch();
    const int64_t b0 = std::min(n, block * block_size), b1 = std::min(n, b0 + block_size);
    for (int64_t v = b0; v < b1;) {
      const int64_t next = SampleVoxelBatch(path, posed, candidates, v, b1, false, batch);
      int64_t done = v;
      for (int t = 0; t < batch->num_voxels; ++t) {
        const int64_t voxel = batch->voxel[t];
        reset(done, voxel);
        done = voxel + 1;
        const int first = batch->begin[t], k = batch->begin[t + 1] - first;
        const uint32_t bits = candidates.observers[voxel];
        float* slots = w_all + offsets[voxel];
        double c[kMaxFrames], w[kMaxFrames], old[kMaxFrames], u[kMaxFrames];
        int slot[kMaxFrames];
        for (int a = 0; a < k; ++a) {
          const int f = batch->frame[first + a];
          slot[a] = __builtin_popcount(bits & ((1u << f) - 1u));
          c[a] = gain[f] * batch->value[first + a] + offset[f];
          u[a] = unit[f];
          old[a] = w[a] = slots[slot[a]];
        }
        // Residuals in each frame's grey levels (docs/design.md 2.8): units u = 1 / gain.
        const double* units = photometric.empty() ? nullptr : u;
        RobustLocation(loss, c, k, w, kLocationIterations, units);
        // Candidate observers that do not observe the voxel now: weight 1.
        uint32_t valid_slots = 0;
        for (int a = 0; a < k; ++a) valid_slots |= 1u << slot[a];
        const int kc = static_cast<int>(offsets[voxel + 1] - offsets[voxel]);
        for (int e = 0; e < kc; ++e) {
          if (valid_slots >> e & 1u) continue;
          out.max_weight_change = std::max(out.max_weight_change, std::abs(1.0 - slots[e]));
          slots[e] = 1.0f;
        }
        double total = 0.0, sum = 0.0;
        for (int a = 0; a < k; ++a) {
          // The stored (float) weights define the next solve's mean; the cost below uses
          // them too.
          const float stored = std::max(FLT_MIN, static_cast<float>(w[a]));
          slots[slot[a]] = stored;
          out.max_weight_change = std::max(out.max_weight_change, std::abs(stored - old[a]));
          const double v = units != nullptr ? stored * u[a] * u[a] : stored;
          total += v;
          sum += v * c[a];
        }
        const double mean = sum / total;
        for (int a = 0; a < k; ++a) {
          const double r = units != nullptr ? u[a] * (c[a] - mean) : c[a] - mean;
          out.robust_cost += loss.Rho(r * r);
        }
        out.observations += k;
      }
      reset(done, next);
      v = next;
    }
  });
  *stats = ReweightStats();
  for (const ReweightStats& part : partial) {
    stats->robust_cost += part.robust_cost;
    stats->max_weight_change = std::max(stats->max_weight_change, part.max_weight_change);
    stats->observations += part.observations;
  }
}

void AccumulateDsrCostSystem(const std::vector<Frame>& frames,
                             const CandidateSet& candidates,
                             const std::vector<Eigen::Isometry3d>& frame_from_world,
                             const std::vector<Photometric>& photometric,
                             const ObservationWeights* weights,
                             int64_t begin,
                             int64_t end,
                             bool with_jacobian,
                             const StreamContext& context,
                             ReducedSystem* out) {
  if (weights != nullptr) {
    AccumulateWeightedReducedSystem(frames, candidates, frame_from_world, photometric, *weights,
                                    begin, end, with_jacobian, context, out);
  } else if (!photometric.empty()) {
    AccumulateReducedPhotometricSystem(frames, candidates, frame_from_world, photometric, begin,
                                       end, with_jacobian, context, out);
  } else {
    AccumulateReducedSystem(frames, candidates, frame_from_world, begin, end, with_jacobian,
                            context, out);
  }
}

void UpdateObservationWeightsByPhase(const std::vector<Frame>& frames,
                                     const CandidateSet& candidates,
                                     const std::vector<Eigen::Isometry3d>& frame_from_world,
                                     const std::vector<Photometric>& photometric,
                                     const RobustLoss& loss,
                                     const StreamContext& context,
                                     std::vector<ObservationWeights>* weights,
                                     ReweightStats* stats) {
  const int phases = NumPhases(frames);
  CHECK_EQ(static_cast<int>(weights->size()), phases);
  if (phases == 1) {
    UpdateObservationWeights(frames, candidates, frame_from_world, photometric, loss, context,
                             &weights->front(), stats);
    return;
  }
  *stats = ReweightStats();
  for (int p = 0; p < phases; ++p) {
    ReweightStats part;
    UpdateObservationWeights(PhaseFrames(frames, p), candidates, frame_from_world, photometric,
                             loss, context, &(*weights)[p], &part);
    stats->robust_cost += part.robust_cost;
    stats->max_weight_change = std::max(stats->max_weight_change, part.max_weight_change);
    stats->observations += part.observations;
  }
}

Vector6d MeanGaugeStiffnessAt(const std::vector<Frame>& frames,
                              const CandidateSet& candidates,
                              const std::vector<Eigen::Isometry3d>& frame_from_world,
                              const std::vector<Photometric>& photometric,
                              const ObservationWeights* weights,
                              const StreamContext& context) {
  ReducedSystem system;
  const int phases = NumPhases(frames);
  if (phases == 1 || weights == nullptr) {  // unweighted passes sum the phases themselves
    AccumulateDsrCostSystem(frames, candidates, frame_from_world, photometric, weights, 0,
                            candidates.num_voxels(), true, context, &system);
  } else {  // the sum of the phases' systems, each with its phase's weights
    for (int phase = 0; phase < phases; ++phase) {
      ReducedSystem part;
      AccumulateDsrCostSystem(PhaseFrames(frames, phase), candidates, frame_from_world,
                              photometric, weights != nullptr ? weights + phase : nullptr, 0,
                              candidates.num_voxels(), true, context, &part);
      system.hessian = phase == 0 ? part.hessian : Eigen::MatrixXd(system.hessian + part.hessian);
    }
  }
  const int p = photometric.empty() ? kJacobianSize : kWideJacobianSize;
  return MeanGaugeStiffness(system.hessian, static_cast<int>(frames.size()), p);
}

}  // namespace dsr
