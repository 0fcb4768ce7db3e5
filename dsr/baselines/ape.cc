// APE: accumulated pairwise estimates (docs/design.md section 5), streamed like DSR.
#include <cmath>
#include <cstring>

#include <glog/logging.h>

#include "dsr/baselines/baselines.h"

namespace dsr {
namespace {

// The APE term of one voxel observed by k >= 2 frames: for each pair a < b,
// e = a_a - a_b, cost += e^2, g_a += J_a^T e, g_b -= J_b^T e,
// H_aa += J_a^T J_a, H_bb += J_b^T J_b, H_ab -= J_a^T J_b. O(k^2) per voxel, as APE
// evaluates it (no use of the per-voxel identity with DSR).
struct ApeVoxelTerm {
  // Pair by pair, as APE evaluates it; in the batched form its H would be
  // H_ab = (k delta_ab - 1) J_a^T J_b.
  bool batched_hessian = false;
  bool batched_gradient = false;  // its gradient is added pair by pair
  HessianWeights Weights(int k) const { return {static_cast<double>(k), -1.0}; }

  void operator()(const VoxelObservations& obs, bool with_jacobian, VoxelAccumulator* acc) const {
    const int k = obs.k;
    acc->observations += int64_t{k} * (k - 1) / 2;
    double* h = acc->hessian.data();
    double* g = acc->gradient.data();
    const int n = acc->n;
    for (int a = 0; a < k; ++a) {
      for (int b = a + 1; b < k; ++b) {
        const double e = obs.value[a] - obs.value[b];
        acc->cost += e * e;
        if (!with_jacobian) continue;
        const int fa = obs.frame[a], fb = obs.frame[b];
        const double* ja = obs.jac[a];
        const double* jb = obs.jac[b];
        for (int i = 0; i < 6; ++i) {
          g[6 * fa + i] += ja[i] * e;
          g[6 * fb + i] -= jb[i] * e;
        }
        if (batched_hessian) continue;
        AddOuter(h, n, fa, fa, ja, ja, 1.0);
        AddOuter(h, n, fb, fb, jb, jb, 1.0);
        AddOuter(h, n, fa, fb, ja, jb, -1.0);
      }
    }
  }
};

}  // namespace

void AccumulateApeSystem(const std::vector<Frame>& frames,
                         const CandidateSet& candidates,
                         const std::vector<Eigen::Isometry3d>& frame_from_world,
                         int64_t begin,
                         int64_t end,
                         bool with_jacobian,
                         const StreamContext& context,
                         NormalEquations* out,
                         bool batched_hessian) {
  ApeVoxelTerm term;
  term.batched_hessian = batched_hessian;
  StreamNormalEquations(frames, candidates, frame_from_world, begin, end, with_jacobian,
                        context, term, out);
}

ApeChunkCost::ApeChunkCost(const std::vector<Frame>* frames,
                           const CandidateSet* candidates,
                           const Eigen::Isometry3d& frame0_from_world,
                           int64_t begin,
                           int64_t end,
                           const StreamContext& context)
    : StreamedPoseCost(static_cast<int>(frames->size()), frame0_from_world),
      frames_(frames),
      candidates_(candidates),
      begin_(begin),
      end_(end),
      context_(context) {}

void ApeChunkCost::Accumulate(const std::vector<Eigen::Isometry3d>& frame_from_world,
                              const std::vector<Photometric>& /*photometric: none*/,
                              bool with_jacobian,
                              NormalEquations* out) const {
  AccumulateApeSystem(*frames_, *candidates_, frame_from_world, begin_, end_, with_jacobian,
                      context_, out);
}

VoxelApeCost::VoxelApeCost(std::vector<const Frame*> observers,
                           const Eigen::Vector3d& voxel_center_in_world)
    : observers_(std::move(observers)), voxel_center_in_world_(voxel_center_in_world) {
  const int n = static_cast<int>(observers_.size());
  set_num_residuals(std::max(1, n * (n - 1) / 2));
  for (int i = 0; i < n; ++i) mutable_parameter_block_sizes()->push_back(kPoseAmbientSize);
}

bool VoxelApeCost::Evaluate(double const* const* parameters,
                            double* residuals,
                            double** jacobians) const {
  const int n = static_cast<int>(observers_.size());
  const int rows = num_residuals();
  std::vector<double> value(n, 0.0);
  std::vector<RowVector6d> jac(n, RowVector6d::Zero());
  std::vector<bool> sigma(n, false);
  for (int i = 0; i < n; ++i) {
    sigma[i] = ObserveSample(*observers_[i], ParametersToPose(parameters[i]),
                             voxel_center_in_world_, &value[i], &jac[i]);
  }
  std::fill(residuals, residuals + rows, 0.0);
  if (jacobians != nullptr) {
    for (int a = 0; a < n; ++a) {
      if (jacobians[a] != nullptr)
        std::memset(jacobians[a], 0, sizeof(double) * rows * kPoseAmbientSize);
    }
  }
  int row = 0;
  for (int a = 0; a < n; ++a) {
    for (int b = a + 1; b < n; ++b, ++row) {
      if (!sigma[a] || !sigma[b]) continue;  // the pair does not both observe the voxel
      residuals[row] = value[a] - value[b];
      if (jacobians == nullptr) continue;
      const std::pair<int, double> sides[2] = {{a, 1.0}, {b, -1.0}};
      for (const auto& [frame, sign] : sides) {
        if (jacobians[frame] == nullptr) continue;
        Eigen::Map<Eigen::Matrix<double, 1, kPoseAmbientSize>> out(
            jacobians[frame] + row * kPoseAmbientSize);
        out = sign * jac[frame] * TangentToAmbientJacobian(parameters[frame]);
      }
    }
  }
  return true;
}

bool SolveApe(const std::vector<Frame>& frames,
              const CandidateSet& candidates,
              const std::vector<Eigen::Isometry3d>& initial_frame_from_world,
              const BaselineOptions& options,
              SolveReport* report,
              std::string* error) {
  const StreamContext context = StreamContextFor(options.solve);
  const Eigen::Isometry3d frame0 = initial_frame_from_world[0];
  return SolveStreamedPoses(
      frames, initial_frame_from_world, candidates.num_voxels(), options.num_chunks,
      [&](int64_t begin, int64_t end) {
        return new ApeChunkCost(&frames, &candidates, frame0, begin, end, context);
      },
      options.solve, "ape", report, error);
}

}  // namespace dsr
