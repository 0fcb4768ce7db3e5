#include "dsr/dsr_reduced/photometric_at_poses.h"

#include <algorithm>
#include <cmath>
#include <memory>

#include <Eigen/Cholesky>
#include <glog/logging.h>

#include "dsr/util/parallel.h"

namespace dsr {
namespace {

// Fixed blocks of the samples (a multiple of any thread count used here): the sums do not
// depend on the thread count.
constexpr int64_t kBlocks = 64;
// Edge of the cubes the sandwich's gradient shares are clustered in (panorama voxels).
constexpr int kClusterVoxels = 8;
// Gauss-Newton stops when no step moves a frame's mapping alpha x + beta by more than this
// many of its grey levels over its samples' range, or after kMaxIterations.
constexpr double kStepTolerance = 1e-6;
constexpr int kMaxIterations = 25;

// The samples of a set of (voxel, phase) pairs with at least two observers, in memory,
// 5 bytes per observation and about 1.5 per pair: the observations of pair p follow
// those of pair p - 1 (count[p] of them), and the pairs come in runs of one cube (the
// cluster of the sandwich's gradient shares).
struct Samples {
  std::vector<uint8_t> count;  // pair p's observations (2..kMaxFrames)
  struct Run {
    int64_t cube;
    int64_t end;  // the run's pairs end before this pair
  };
  std::vector<Run> runs;
  std::vector<uint8_t> frame;
  // The sample rounded to float, the frames' own precision (4 bytes less per observation
  // and phase; the minimiser moves by about 1e-7 of a gain).
  std::vector<float> value;
  int64_t size() const { return static_cast<int64_t>(count.size()); }
};

// Every phase's samples of the candidates, in candidate order, phase by phase within a block.
std::vector<Samples> TakeSamples(const std::vector<Frame>& frames,
                                 const CandidateSet& candidates,
                                 const std::vector<Eigen::Isometry3d>& frame_from_world,
                                 const StreamContext& context) {
  const KernelPath path = StreamKernelPath(context);
  const FramesByPhase phases(frames);
  std::vector<std::vector<PosedFrame>> posed;
  for (int p = 0; p < phases.size(); ++p) posed.push_back(PoseFrames(phases[p], frame_from_world));
  const ImageGeometry& grid = candidates.grid;
  const int64_t nx = grid.size[0], nxy = nx * grid.size[1];
  const int64_t cx = (grid.size[0] + kClusterVoxels - 1) / kClusterVoxels;
  const int64_t cy = (grid.size[1] + kClusterVoxels - 1) / kClusterVoxels;
  const int64_t n = candidates.num_voxels();
  std::vector<Samples> blocks(kBlocks);
  ParallelFor(0, kBlocks, context.num_threads, [&](int64_t b) {
    Samples& out = blocks[b];
    VoxelBatch* const batch = ThreadVoxelBatch();
    const int64_t begin = n * b / kBlocks, end = n * (b + 1) / kBlocks;
    // At most the candidates' observers: reserved once, trimmed at the end.
    int64_t bound = 0;
    for (int64_t v = begin; v < end; ++v) bound += __builtin_popcount(candidates.observers[v]);
    out.frame.reserve(bound * phases.size());
    out.value.reserve(bound * phases.size());
    out.count.reserve((end - begin) * phases.size());
    for (int p = 0; p < phases.size(); ++p) {
      for (int64_t v = begin; v < end;) {
        v = SampleVoxelBatch(path, posed[p], candidates, v, end, /*with_jacobian=*/false,
                             batch);
        for (int t = 0; t < batch->num_voxels; ++t) {
          const int64_t l = candidates.voxel[batch->voxel[t]];
          const int64_t i = l % nx, j = (l % nxy) / nx, k = l / nxy;
          const int64_t cube =
              ((k / kClusterVoxels) * cy + j / kClusterVoxels) * cx + i / kClusterVoxels;
          if (out.runs.empty() || out.runs.back().cube != cube) out.runs.push_back({cube, 0});
          for (int a = batch->begin[t]; a < batch->begin[t + 1]; ++a) {
            out.frame.push_back(static_cast<uint8_t>(batch->frame[a]));
            out.value.push_back(static_cast<float>(batch->value[a]));
          }
          out.count.push_back(static_cast<uint8_t>(batch->begin[t + 1] - batch->begin[t]));
          out.runs.back().end = out.size();
        }
      }
    }
    out.frame.shrink_to_fit();
    out.value.shrink_to_fit();
    out.count.shrink_to_fit();
    out.runs.shrink_to_fit();
  });
  return blocks;
}

// One pass over a block's samples at (alpha, beta): the cost and, with `system`, the
// projected Gauss-Newton matrix (2m square, all frames) and gradient (2m).
struct Pass {
  double cost = 0.0;
  Eigen::MatrixXd hessian;
  Eigen::VectorXd gradient;
};

void AddPass(const Samples& s,
             const std::vector<double>& alpha,
             const std::vector<double>& beta,
             bool system,
             Pass* out) {
  const int m = static_cast<int>(alpha.size());
  // Per frame the sums of z z^T (P^2, P, 1), per pair of frames those over S, per frame -r z.
  std::vector<double> own(3 * m, 0.0), pair(3 * m * m, 0.0);
  out->gradient = Eigen::VectorXd::Zero(2 * m);
  // In locals: the compiler cannot keep `out`'s members in registers across the stores.
  double cost = 0.0;
  double* const gradient = out->gradient.data();
  // The pairs' sums are the same for every voxel of a run with the same observers (voxels
  // along a row share them but at fields of view's borders): summed per run, then added to
  // each of the run's pairs (a, b), a <= b, once.
  uint32_t run_observers = 0;
  double run[3] = {0.0, 0.0, 0.0};
  const auto flush = [&] {
    for (uint32_t left = run_observers; left != 0; left &= left - 1) {
      const int a = __builtin_ctz(left);
      for (uint32_t right = left; right != 0; right &= right - 1) {
        double* sums = &pair[3 * (a * m + __builtin_ctz(right))];
        sums[0] += run[0];
        sums[1] += run[1];
        sums[2] += run[2];
      }
    }
    run[0] = run[1] = run[2] = 0.0;
  };
  int64_t last = 0;
  for (int64_t p = 0; p < s.size(); ++p) {
    const int64_t first = last;
    last += s.count[p];
    double weight = 0.0, sum = 0.0;
    uint32_t observers = 0;
    for (int64_t o = first; o < last; ++o) {
      const int f = s.frame[o];
      weight += alpha[f] * alpha[f];
      sum += alpha[f] * (s.value[o] - beta[f]);
      observers |= uint32_t{1} << f;
    }
    const double panorama = sum / weight;
    for (int64_t o = first; o < last; ++o) {
      const int f = s.frame[o];
      const double r = s.value[o] - alpha[f] * panorama - beta[f];
      cost += r * r;
      if (!system) continue;
      gradient[2 * f] -= r * panorama;
      gradient[2 * f + 1] -= r;
      own[3 * f] += panorama * panorama;
      own[3 * f + 1] += panorama;
      own[3 * f + 2] += 1.0;
    }
    if (!system) continue;
    if (observers != run_observers) {
      flush();
      run_observers = observers;
    }
    run[0] += panorama * panorama / weight;
    run[1] += panorama / weight;
    run[2] += 1.0 / weight;
  }
  out->cost += cost;
  if (!system) return;
  flush();
  out->hessian = Eigen::MatrixXd::Zero(2 * m, 2 * m);
  for (int a = 0; a < m; ++a) {
    for (int b = 0; b < m; ++b) {
      // The frames come in increasing order within a voxel: the pair (a, b) is summed
      // under min, max.
      const double* sums = &pair[3 * (std::min(a, b) * m + std::max(a, b))];
      const double scale = alpha[a] * alpha[b];
      Eigen::Matrix2d block;
      block << -scale * sums[0], -scale * sums[1], -scale * sums[1], -scale * sums[2];
      if (a == b) block += (Eigen::Matrix2d() << own[3 * a], own[3 * a + 1], own[3 * a + 1],
                            own[3 * a + 2]).finished();
      out->hessian.block<2, 2>(2 * a, 2 * b) = block;
    }
  }
}

// The pass over every block (in fixed order: deterministic).
Pass FullPass(const std::vector<Samples>& blocks,
              const std::vector<double>& alpha,
              const std::vector<double>& beta,
              bool system,
              int num_threads) {
  std::vector<Pass> parts(blocks.size());
  ParallelFor(0, static_cast<int64_t>(blocks.size()), num_threads,
              [&](int64_t b) { AddPass(blocks[b], alpha, beta, system, &parts[b]); });
  Pass total = parts[0];
  for (size_t b = 1; b < parts.size(); ++b) {
    total.cost += parts[b].cost;
    if (system) {
      total.hessian += parts[b].hessian;
      total.gradient += parts[b].gradient;
    }
  }
  return total;
}

// The sandwich's middle: sum over cubes of g_B g_B^T (2m square, all frames). A cube's
// (voxel, phase) pairs are not contiguous (its rows are interleaved with other cubes', and
// every phase comes back to it): its runs' shares are summed in their order, cube by cube,
// in one column per cube of the grid.
Eigen::MatrixXd ClusteredGradientCovariance(const std::vector<Samples>& blocks,
                                            const std::vector<double>& alpha,
                                            const std::vector<double>& beta) {
  const int m = static_cast<int>(alpha.size());
  int64_t num_cubes = 0;
  for (const Samples& s : blocks) {
    for (const Samples::Run& run : s.runs) num_cubes = std::max(num_cubes, run.cube + 1);
  }
  Eigen::MatrixXd cube_share = Eigen::MatrixXd::Zero(2 * m, num_cubes);
  std::vector<uint8_t> seen(num_cubes, 0);
  Eigen::VectorXd share(2 * m);
  for (const Samples& s : blocks) {
    int64_t p = 0, last = 0;
    for (const Samples::Run& run : s.runs) {
      share.setZero();
      for (; p < run.end; ++p) {
        const int64_t first = last;
        last += s.count[p];
        double weight = 0.0, sum = 0.0;
        for (int64_t o = first; o < last; ++o) {
          weight += alpha[s.frame[o]] * alpha[s.frame[o]];
          sum += alpha[s.frame[o]] * (s.value[o] - beta[s.frame[o]]);
        }
        const double panorama = sum / weight;
        for (int64_t o = first; o < last; ++o) {
          const int f = s.frame[o];
          const double r = s.value[o] - alpha[f] * panorama - beta[f];
          share[2 * f] -= r * panorama;
          share[2 * f + 1] -= r;
        }
      }
      cube_share.col(run.cube) += share;
      seen[run.cube] = 1;
    }
  }
  Eigen::MatrixXd covariance = Eigen::MatrixXd::Zero(2 * m, 2 * m);
  for (int64_t c = 0; c < num_cubes; ++c) {
    if (seen[c]) covariance.noalias() += cube_share.col(c) * cube_share.col(c).transpose();
  }
  return covariance;
}

}  // namespace

double PhotometricEstimate::Change(int frame, double x) const {
  return photometric[frame].Correct(x) - x;
}

double PhotometricEstimate::ChangeStandardError(int frame, double x) const {
  if (frame == 0 || covariance.size() == 0) return 0.0;
  // gain x + offset = (x - beta) / alpha: d/d alpha = -(x - beta) / alpha^2, d/d beta =
  // -1 / alpha.
  const double alpha = photometric[frame].unit();
  const double beta = -alpha * photometric[frame].offset;
  const Eigen::Vector2d d(-(x - beta) / (alpha * alpha), -1.0 / alpha);
  const int at = 2 * (frame - 1);
  return std::sqrt(std::max(0.0, d.dot(covariance.block<2, 2>(at, at) * d)));
}

bool EstimatePhotometricAtPoses(const std::vector<Frame>& frames,
                                const CandidateSet& candidates,
                                const std::vector<Eigen::Isometry3d>& frame_from_world,
                                const StreamContext& context,
                                PhotometricEstimate* estimate,
                                std::string* error,
                                const std::vector<Photometric>* start) {
  const int m = static_cast<int>(frames.size());
  const int n = 2 * (m - 1);
  CHECK_GE(m, 2);
  CHECK_LE(m, kMaxFrames);  // a voxel's observers as the bits of a uint32_t (AddPass)
  const std::vector<Samples> blocks = TakeSamples(frames, candidates, frame_from_world, context);
  *estimate = PhotometricEstimate();
  // Each frame's observations and the range of its samples (for the step rule).
  std::vector<int64_t> count(m, 0);
  std::vector<double> low(m, 1e300), high(m, -1e300);
  for (const Samples& s : blocks) {
    estimate->voxels += s.size();
    estimate->observations += static_cast<int64_t>(s.value.size());
    for (size_t o = 0; o < s.value.size(); ++o) {
      ++count[s.frame[o]];
      low[s.frame[o]] = std::min<double>(low[s.frame[o]], s.value[o]);
      high[s.frame[o]] = std::max<double>(high[s.frame[o]], s.value[o]);
    }
  }
  for (int f = 0; f < m; ++f) {
    if (count[f] < 3) {
      *error = "frame " + std::to_string(f) + " has " + std::to_string(count[f]) +
               " samples where others see it too: too few for a gain and an offset";
      return false;
    }
  }
  std::vector<double> alpha(m, 1.0), beta(m, 0.0);
  CHECK(start == nullptr || static_cast<int>(start->size()) == m);
  for (int f = 1; f < m && start != nullptr; ++f) {
    alpha[f] = (*start)[f].unit();
    beta[f] = -alpha[f] * (*start)[f].offset;
  }
  Pass pass = FullPass(blocks, alpha, beta, true, context.num_threads);
  Eigen::LDLT<Eigen::MatrixXd> ldlt;
  for (int it = 0; it < kMaxIterations; ++it) {
    ldlt.compute(pass.hessian.bottomRightCorner(n, n));
    if (ldlt.info() != Eigen::Success || !(ldlt.vectorD().minCoeff() > 0.0)) {
      *error = "the samples do not determine the gains and offsets (singular system)";
      return false;
    }
    const Eigen::VectorXd step = ldlt.solve(-pass.gradient.tail(n));
    // How far `scale` times the step moves a frame's mapping, at most, in its grey levels.
    const auto moved_by = [&](double scale) {
      double moved = 0.0;
      for (int f = 1; f < m; ++f) {
        const double range = std::max(std::abs(high[f]), std::abs(low[f]));
        moved = std::max(moved, std::abs(scale * step[2 * (f - 1)]) * range +
                                    std::abs(scale * step[2 * (f - 1) + 1]));
      }
      return moved;
    };
    ++estimate->iterations;
    // Where the whole step stays within the tolerance, the estimate is at the minimiser to
    // that tolerance already: no pass is made to take it (at the minimiser the cost's
    // rounding can make every such step look uphill, and the backtracking below would halve
    // it a dozen times, one pass over the samples each).
    if (moved_by(1.0) < kStepTolerance) {
      estimate->converged = true;
      break;
    }
    // Backtrack while the cost rises (the projected problem is not quadratic).
    double scale = 1.0;
    Pass next;
    std::vector<double> next_alpha = alpha, next_beta = beta;
    for (int halving = 0; halving < 30; ++halving, scale *= 0.5) {
      for (int f = 1; f < m; ++f) {
        next_alpha[f] = alpha[f] + scale * step[2 * (f - 1)];
        next_beta[f] = beta[f] + scale * step[2 * (f - 1) + 1];
      }
      next = FullPass(blocks, next_alpha, next_beta, true, context.num_threads);
      if (next.cost <= pass.cost) break;
    }
    if (!(next.cost <= pass.cost)) break;  // no descent left: at the minimiser
    alpha = next_alpha;
    beta = next_beta;
    pass = std::move(next);
    if (moved_by(scale) < kStepTolerance) {
      estimate->converged = true;
      break;
    }
  }
  for (int f = 1; f < m; ++f) {
    if (!(alpha[f] > 0.0)) {
      *error = "frame " + std::to_string(f) + "'s estimated gain is not positive";
      return false;
    }
  }
  estimate->cost = pass.cost;
  estimate->photometric.assign(m, Photometric());
  for (int f = 1; f < m; ++f) {
    estimate->photometric[f].log_gain = -std::log(alpha[f]);
    estimate->photometric[f].offset = -beta[f] / alpha[f];
  }
  ldlt.compute(pass.hessian.bottomRightCorner(n, n));
  const Eigen::MatrixXd inverse = ldlt.solve(Eigen::MatrixXd::Identity(n, n));
  estimate->covariance =
      inverse * ClusteredGradientCovariance(blocks, alpha, beta).bottomRightCorner(n, n) * inverse;
  return true;
}

}  // namespace dsr
