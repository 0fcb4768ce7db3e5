// The pose uncertainty's sums in one pass (uncertainty.h): SumForUncertainty, which samples
// every observation once with the slopes of its interpolants (cubes and their jackknife
// groups, runs of the same observers, one slab of cubes per task), the UncertaintySums
// methods, and GradientJacobian, its slow twin by forward differences.
#include "dsr/pipeline/uncertainty.h"

#include <algorithm>
#include <cstdint>
#include <utility>
#include <vector>

#include <glog/logging.h>

#include "dsr/pipeline/uncertainty_internal.h"
#include "dsr/util/parallel.h"

namespace dsr {
namespace {

using uncertainty_internal::kClusterVoxels;

// The observers of candidate voxel v that sample it at their poses: k of them, frame[a]
// with value[a] and Jacobian jacobian[a] (arrays of at least kMaxFrames), and their mean.
int ObserveVoxel(const std::vector<Frame>& frames,
                 const CandidateSet& candidates,
                 const std::vector<Eigen::Isometry3d>& frame_from_world,
                 int64_t v,
                 double* value,
                 RowVector6d* jacobian,
                 int* frame,
                 double* mean) {
  const Eigen::Vector3d centre = candidates.VoxelCenter(v);
  int k = 0;
  double sum = 0.0;
  for (uint32_t bits = candidates.observers[v]; bits != 0; bits &= bits - 1) {
    const int f = __builtin_ctz(bits);
    if (ObserveSample(frames[f], frame_from_world[f], centre, &value[k], &jacobian[k])) {
      frame[k] = f;
      sum += value[k];
      ++k;
    }
  }
  *mean = k > 0 ? sum / k : 0.0;
  return k;
}

// The cube of kClusterVoxels voxels on a side that panorama voxel l lies in, as (cube index
// in its slab of kClusterVoxels planes, slab), and the jackknife group of a cube: a fixed
// hash of its three indices, so that the groups interleave over the whole overlap.
int CubeGroup(int64_t cx, int64_t cy, int64_t cz) {
  const uint64_t h = static_cast<uint64_t>(cx) * 73856093u ^ static_cast<uint64_t>(cy) * 19349663u ^
                     static_cast<uint64_t>(cz) * 83492791u;
  return static_cast<int>(h % kUncertaintyGroups);
}

// Whether a cube is in the subset of 1 in keep_one_in cubes (SumForUncertainty): chosen by
// another fixed hash of its indices than its group's, so that the subset spreads evenly
// over the overlap and over the groups.
bool CubeKept(int64_t cx, int64_t cy, int64_t cz, int keep_one_in) {
  uint64_t h = static_cast<uint64_t>(cx) * 0x9E3779B97F4A7C15ull ^
               static_cast<uint64_t>(cy) * 0xC2B2AE3D27D4EB4Full ^
               static_cast<uint64_t>(cz) * 0x165667B19E3779F9ull;
  h ^= h >> 29;
  return h % static_cast<uint64_t>(keep_one_in) == 0;
}

// One observation with what the curvature needs: its value, Jacobian J (1x6, as
// ObserveSample), the derivative of its value dv (1x6, the slope of the trilinear value) and
// of its Jacobian dJ (6x6, column c = d J^T / d delta_c), under a left perturbation of its
// frame's pose (p_ij -> p_ij + rho + phi x p_ij).
struct SlopedSample {
  int frame = 0;
  double value = 0.0;
  RowVector6d jacobian;
  RowVector6d value_slope;
  Matrix6d jacobian_slope;
};

bool ObserveWithSlopes(const Frame& frame,
                       const Eigen::Isometry3d& frame_from_world,
                       const Eigen::Vector3d& centre,
                       SlopedSample* out) {
  const Eigen::Vector3d p = frame_from_world * centre;
  Eigen::Vector3d gradient_ijk, value_slope_ijk;
  Eigen::Matrix3d gradient_slope_ijk;
  if (!frame.SampleSlopesAtIndex(frame.ToIndex(p), &out->value, &gradient_ijk, &value_slope_ijk,
                                 &gradient_slope_ijk)) {
    return false;
  }
  // As Frame::Sample and ObserveSample: g = (D S)^-T grad_u, J = [g; p x g].
  const Eigen::Matrix3d& to_physical = frame.gradient_to_physical();
  const Eigen::Vector3d g = to_physical * gradient_ijk;
  out->jacobian.head<3>() = g.transpose();
  out->jacobian.tail<3>() = p.cross(g).transpose();
  const Eigen::Vector3d gv = to_physical * value_slope_ijk;
  out->value_slope.head<3>() = gv.transpose();
  out->value_slope.tail<3>() = p.cross(gv).transpose();
  // d g / d p (physical), and for each tangent axis c the motion of p: e_c (translation) or
  // e_{c-3} x p (rotation).
  const Eigen::Matrix3d dg_dp = to_physical * gradient_slope_ijk * frame.index_from_physical();
  for (int c = 0; c < 6; ++c) {
    const Eigen::Vector3d dp =
        c < 3 ? Eigen::Vector3d::Unit(c) : Eigen::Vector3d::Unit(c - 3).cross(p);
    const Eigen::Vector3d dg = dg_dp * dp;
    out->jacobian_slope.col(c).head<3>() = dg;
    out->jacobian_slope.col(c).tail<3>() = dp.cross(g) + p.cross(dg);
  }
  return true;
}

// The sample of the corrected frame gain * I + offset: its value, and every derivative by
// the gain (the interpolants are linear in the voxels, whose weights sum to 1).
void CorrectSample(const Photometric& photometric, SlopedSample* sample) {
  const double gain = photometric.gain();
  sample->value = gain * sample->value + photometric.offset;
  sample->jacobian *= gain;
  sample->value_slope *= gain;
  sample->jacobian_slope *= gain;
}

// One slab's sums (SumForUncertainty): its cubes' gradient shares [6m x cubes of the slab]
// and A per group.
struct SlabSums {
  int64_t observations = 0, voxels = 0;
  double cost = 0.0;
  std::vector<Eigen::MatrixXd> curvature;
  std::vector<int64_t> group_voxels;
  Eigen::MatrixXd shares;
};

// Consecutive (voxel, phase) pairs with the same valid observers in one group of cubes: the
// terms J_a^T dv_b of A (every pair of observers a, b, scaled by delta_ab - 1/k) are summed
// over such a run in registers and added to A once per run, not once per voxel.
struct ObserverRun {
  static constexpr int kMaxRows = 32;
  uint32_t observers = 0;  // bit f: frame f, in increasing frame order as the rows hold them
  int group = -1;
  int k = 0;
  int rows = 0;
  int frame[kMaxFrames];
  double jacobian[kMaxRows][kMaxFrames][6];
  double value_slope[kMaxRows][kMaxFrames][6];
};

// Adds the run's (delta_ab - 1/k) sum_r J_ra^T dv_rb to block (frame a, frame b) of `a`
// (column-major, 6m square) and empties it.
void FlushRun(ObserverRun* run, std::vector<Eigen::MatrixXd>* curvature) {
  if (run->rows == 0) return;
  Eigen::MatrixXd& a_group = (*curvature)[run->group];
  const int n = static_cast<int>(a_group.rows());
  const int k = run->k;
  for (int a = 0; a < k; ++a) {
    for (int b = 0; b < k; ++b) {
      // sum[j][i] = sum_r J_ra[i] dv_rb[j]: column j of the block, contiguous in A.
      double sum[6][6] = {};
      for (int r = 0; r < run->rows; ++r) {
        const double* ja = run->jacobian[r][a];
        const double* vb = run->value_slope[r][b];
        for (int j = 0; j < 6; ++j) {
          for (int i = 0; i < 6; ++i) sum[j][i] += ja[i] * vb[j];
        }
      }
      const double scale = (a == b ? 1.0 : 0.0) - 1.0 / k;
      double* block =
          a_group.data() + static_cast<int64_t>(6 * run->frame[b]) * n + 6 * run->frame[a];
      for (int j = 0; j < 6; ++j) {
        for (int i = 0; i < 6; ++i) block[static_cast<int64_t>(j) * n + i] += scale * sum[j][i];
      }
    }
  }
  run->rows = 0;
}

// Adds one (voxel, phase)'s k >= 2 valid observations to a slab's sums: cost, its cube's
// gradient share, A's own residual term at once and its J^T dv terms through its run.
void AddVoxel(const SlopedSample* sample,
              int k,
              uint32_t observed,
              int group,
              int64_t cube,
              ObserverRun* run,
              SlabSums* out) {
  double mean = 0.0;
  for (int a = 0; a < k; ++a) mean += sample[a].value;
  mean /= k;
  ++out->voxels;
  ++out->group_voxels[group];
  out->observations += k;
  if (run->observers != observed || run->group != group || run->rows == ObserverRun::kMaxRows) {
    FlushRun(run, &out->curvature);
    run->observers = observed;
    run->group = group;
    run->k = k;
    for (int a = 0; a < k; ++a) run->frame[a] = sample[a].frame;
  }
  Eigen::MatrixXd& a_group = out->curvature[group];
  for (int a = 0; a < k; ++a) {
    const SlopedSample& x = sample[a];
    const int f = x.frame;
    const double r = x.value - mean;
    out->cost += r * r;
    out->shares.block<6, 1>(6 * f, cube) += x.jacobian.transpose() * r;
    a_group.block<6, 6>(6 * f, 6 * f) += x.jacobian_slope * r;
    for (int e = 0; e < 6; ++e) {
      run->jacobian[run->rows][a][e] = x.jacobian[e];
      run->value_slope[run->rows][a][e] = x.value_slope[e];
    }
  }
  ++run->rows;
}

// Adds a slab's sums to the whole's, its cubes' gradient shares as g_B g_B^T to their
// groups' covariances.
void AddSlab(const SlabSums& slab, int64_t slab_index, int64_t cubes_x, UncertaintySums* sums) {
  if (slab.curvature.empty()) return;
  sums->observations += slab.observations;
  sums->voxels += slab.voxels;
  sums->cost += slab.cost;
  for (int g = 0; g < kUncertaintyGroups; ++g) {
    sums->curvature[g] += slab.curvature[g];
    sums->group_voxels[g] += slab.group_voxels[g];
  }
  for (int64_t c = 0; c < slab.shares.cols(); ++c) {
    if (slab.shares.col(c).isZero(0.0)) continue;
    ++sums->clusters;
    const int group = CubeGroup(c % cubes_x, c / cubes_x, slab_index);
    sums->gradient_covariance[group].noalias() +=
        slab.shares.col(c) * slab.shares.col(c).transpose();
  }
}

}  // namespace

Eigen::MatrixXd UncertaintySums::Curvature(int left_out) const {
  Eigen::MatrixXd sum = Eigen::MatrixXd::Zero(curvature[0].rows(), curvature[0].cols());
  for (int g = 0; g < static_cast<int>(curvature.size()); ++g) {
    if (g != left_out) sum += curvature[g];
  }
  return sum;
}

Eigen::MatrixXd UncertaintySums::GradientCovariance(int left_out) const {
  Eigen::MatrixXd sum =
      Eigen::MatrixXd::Zero(gradient_covariance[0].rows(), gradient_covariance[0].cols());
  for (int g = 0; g < static_cast<int>(gradient_covariance.size()); ++g) {
    if (g != left_out) sum += gradient_covariance[g];
  }
  return sum;
}

// Cov(g) of the DSR gradient g = sum_j sum_a J_aj^T r_aj (6m, all frames) is estimated from
// the residuals themselves, cluster by cluster: the panorama is cut into cubes of
// kClusterVoxels voxels, g_B is the gradient's share of cube B, and Cov(g) ~ sum_B g_B g_B^T.
// This holds when residuals in different cubes are independent, whatever their
// correlation inside one cube (trilinear resampling spreads one frame voxel's noise over
// the 8 panorama voxels around it) and whatever their variance (which resampling lowers
// below the frames' own noise, so that s^2 from the cost would be too small). Frames of T
// phases: a cube's share sums its phases' (the tied cost's gradient; docs/design.md 12).
// A = dg / d delta from each observation's slopes (GradientJacobian's formula, header):
//   own block  (f, f) += dJ_f^T r_f + J_f^T dv_f,  every block (f, b) -= J_f^T dv_b / k.
UncertaintySums SumForUncertainty(const std::vector<Frame>& frames,
                                  const CandidateSet& candidates,
                                  const std::vector<Eigen::Isometry3d>& frame_from_world,
                                  int num_threads,
                                  int keep_one_in,
                                  const std::vector<Photometric>* photometric) {
  const int m = static_cast<int>(frames.size());
  const int n = 6 * m;
  const ImageGeometry& grid = candidates.grid;
  const int64_t nx = grid.size[0], nxy = nx * grid.size[1];
  const int64_t cx = (grid.size[0] + kClusterVoxels - 1) / kClusterVoxels;
  const int64_t cy = (grid.size[1] + kClusterVoxels - 1) / kClusterVoxels;
  const int64_t slabs = (grid.size[2] + kClusterVoxels - 1) / kClusterVoxels;
  // Candidates are sorted by linear index, so each slab of cubes (kClusterVoxels planes)
  // is a contiguous range: slabs run in parallel, each summing its own cubes.
  std::vector<int64_t> slab_begin(slabs + 1, candidates.num_voxels());
  for (int64_t v = candidates.num_voxels() - 1; v >= 0; --v) {
    slab_begin[candidates.voxel[v] / nxy / kClusterVoxels] = v;
  }
  for (int64_t s = slabs - 1; s >= 0; --s)
    slab_begin[s] = std::min(slab_begin[s], slab_begin[s + 1]);
  UncertaintySums sums;
  sums.curvature.assign(kUncertaintyGroups, Eigen::MatrixXd::Zero(n, n));
  sums.gradient_covariance.assign(kUncertaintyGroups, Eigen::MatrixXd::Zero(n, n));
  sums.group_voxels.assign(kUncertaintyGroups, 0);
  const FramesByPhase phases(frames);
  std::vector<SlabSums> slab_sums(slabs);
  ParallelFor(0, slabs, num_threads, [&](int64_t s) {
    if (slab_begin[s] == slab_begin[s + 1]) return;
    SlabSums& out = slab_sums[s];
    out.curvature.assign(kUncertaintyGroups, Eigen::MatrixXd::Zero(n, n));
    out.group_voxels.assign(kUncertaintyGroups, 0);
    out.shares = Eigen::MatrixXd::Zero(n, cx * cy);
    SlopedSample sample[kMaxFrames];
    // One run per group (the cubes along a row change group every kClusterVoxels voxels);
    // the slab's voxels are walked once per phase, so the runs do not grow with the phases.
    std::vector<ObserverRun> runs(kUncertaintyGroups);
    for (int p = 0; p < phases.size(); ++p) {
      for (int64_t v = slab_begin[s]; v < slab_begin[s + 1]; ++v) {
        const int64_t l = candidates.voxel[v];
        const int64_t j = (l % nxy) / nx, i = l % nx;
        const int64_t cube = (j / kClusterVoxels) * cx + i / kClusterVoxels;
        if (keep_one_in > 1 && !CubeKept(i / kClusterVoxels, j / kClusterVoxels, s, keep_one_in)) {
          // On to the next cube along the row.
          const int64_t cube_end = std::min(l - i + nx, l - i % kClusterVoxels + kClusterVoxels);
          while (v + 1 < slab_begin[s + 1] && candidates.voxel[v + 1] < cube_end) ++v;
          continue;
        }
        const int group = CubeGroup(i / kClusterVoxels, j / kClusterVoxels, s);
        const Eigen::Vector3d centre = candidates.VoxelCenter(v);
        int k = 0;
        uint32_t observed = 0;
        for (uint32_t bits = candidates.observers[v]; bits != 0; bits &= bits - 1) {
          const int f = __builtin_ctz(bits);
          if (ObserveWithSlopes(phases[p][f], frame_from_world[f], centre, &sample[k])) {
            if (photometric != nullptr) CorrectSample((*photometric)[f], &sample[k]);
            sample[k].frame = f;
            observed |= 1u << f;
            ++k;
          }
        }
        if (k >= 2) AddVoxel(sample, k, observed, group, cube, &runs[group], &out);
      }
    }
    for (ObserverRun& run : runs) FlushRun(&run, &out.curvature);
  });
  for (int64_t s = 0; s < slabs; ++s) AddSlab(slab_sums[s], s, cx, &sums);  // fixed order
  return sums;
}

namespace {

// Fixed number of voxel blocks of GradientJacobian's pass: results do not depend on threads.
constexpr int64_t kCurvatureBlocks = 64;

}  // namespace

namespace {

// GradientJacobian of one phase's frames.
Eigen::MatrixXd OnePhaseGradientJacobian(const std::vector<Frame>& frames,
                                         const CandidateSet& candidates,
                                         const std::vector<Eigen::Isometry3d>& frame_from_world,
                                         const std::vector<double>& step_mm,
                                         const std::vector<double>& step_rad,
                                         int num_threads) {
  const int m = static_cast<int>(frames.size());
  const int n = 6 * m;
  CHECK_EQ(static_cast<int>(frame_from_world.size()), m);
  CHECK_EQ(static_cast<int>(step_mm.size()), m);
  CHECK_EQ(static_cast<int>(step_rad.size()), m);
  // perturbed[6 f + c]: frame f's pose moved by its step along tangent axis c.
  std::vector<Eigen::Isometry3d> perturbed(6 * m);
  std::vector<double> step(6 * m);
  for (int f = 0; f < m; ++f) {
    for (int c = 0; c < 6; ++c) {
      step[6 * f + c] = c < 3 ? step_mm[f] : step_rad[f];
      Vector6d delta = Vector6d::Zero();
      delta[c] = step[6 * f + c];
      perturbed[6 * f + c] = ExpSE3(delta) * frame_from_world[f];
    }
  }
  const int64_t count = candidates.num_voxels();
  const int64_t num_blocks = std::max<int64_t>(1, std::min(kCurvatureBlocks, count));
  const int64_t block_size = (count + num_blocks - 1) / num_blocks;
  std::vector<Eigen::MatrixXd> block_jacobians(num_blocks);
  ParallelFor(0, num_blocks, num_threads, [&](int64_t b) {
    Eigen::MatrixXd a_block = Eigen::MatrixXd::Zero(n, n);
    double value[kMaxFrames];
    int frame[kMaxFrames];
    RowVector6d jacobian[kMaxFrames];
    RowVector6d value_derivative[kMaxFrames];  // d value / d delta, by differences
    for (int64_t v = b * block_size; v < std::min(count, (b + 1) * block_size); ++v) {
      const Eigen::Vector3d centre = candidates.VoxelCenter(v);
      double mean = 0.0;
      const int k =
          ObserveVoxel(frames, candidates, frame_from_world, v, value, jacobian, frame, &mean);
      if (k < 2) continue;
      for (int a = 0; a < k; ++a) {
        const int f = frame[a];
        const Vector6d at = jacobian[a].transpose() * (value[a] - mean);
        for (int c = 0; c < 6; ++c) {
          double moved = 0.0;
          RowVector6d moved_jacobian;
          value_derivative[a][c] = 0.0;
          // A sample that leaves the field of view at the step is left out, so that the
          // difference measures the slope, not the observation count.
          if (!ObserveSample(frames[f], perturbed[6 * f + c], centre, &moved, &moved_jacobian)) {
            continue;
          }
          const double h = step[6 * f + c];
          value_derivative[a][c] = (moved - value[a]) / h;
          // Own block: frame f's gradient share with its sample moved and the mean following.
          const double moved_mean = mean + (moved - value[a]) / k;
          a_block.block<6, 1>(6 * f, 6 * f + c) +=
              (moved_jacobian.transpose() * (moved - moved_mean) - at) / h;
        }
      }
      // Other frames' blocks: moving frame fb's sample moves the mean by its change / k.
      for (int a = 0; a < k; ++a) {
        for (int c = 0; c < k; ++c) {
          if (c == a) continue;
          a_block.block<6, 6>(6 * frame[a], 6 * frame[c]).noalias() -=
              jacobian[a].transpose() * (value_derivative[c] / k);
        }
      }
    }
    block_jacobians[b] = std::move(a_block);
  });
  Eigen::MatrixXd jacobian = Eigen::MatrixXd::Zero(n, n);
  for (const Eigen::MatrixXd& block : block_jacobians) jacobian += block;  // fixed order
  return jacobian;
}

}  // namespace

Eigen::MatrixXd GradientJacobian(const std::vector<Frame>& frames,
                                 const CandidateSet& candidates,
                                 const std::vector<Eigen::Isometry3d>& frame_from_world,
                                 const std::vector<double>& step_mm,
                                 const std::vector<double>& step_rad,
                                 int num_threads) {
  // Frames of T phases: the tied cost's gradient is the sum of the phases' (design.md 12).
  const FramesByPhase phases(frames);
  Eigen::MatrixXd jacobian = OnePhaseGradientJacobian(phases[0], candidates, frame_from_world,
                                                      step_mm, step_rad, num_threads);
  for (int p = 1; p < phases.size(); ++p) {
    jacobian += OnePhaseGradientJacobian(phases[p], candidates, frame_from_world, step_mm, step_rad,
                                         num_threads);
  }
  return jacobian;
}

}  // namespace dsr
