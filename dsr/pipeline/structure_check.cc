#include "dsr/pipeline/structure_check.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <memory>
#include <sstream>

#include <Eigen/Eigenvalues>
#include <glog/logging.h>

#include "dsr/util/parallel.h"

namespace dsr {

namespace {

// Sums of one block (fixed, so that the result does not depend on the thread count).
struct StructureSums {
  std::array<int64_t, kMaxFrames> pairs{};
  std::array<double, kMaxFrames> rr{}, r1{}, r2{}, rsq{}, cc{}, c1{}, c2{}, c1c1{};
  // The brightness regressors z = mu [1, x, y, z] at the same pairs (mu the panorama's mean,
  // x, y, z the sample's place in the frame): their lag products with the residual and with
  // themselves, and their sums on either side.
  std::array<Eigen::Vector4d, kMaxFrames> rz, z1, z2;
  std::array<Eigen::Matrix4d, kMaxFrames> zz;
  StructureSums() {
    for (int f = 0; f < kMaxFrames; ++f) {
      rz[f].setZero();
      z1[f].setZero();
      z2[f].setZero();
      zz[f].setZero();
    }
  }
};

// The voxels of the last L + 1 columns of the current panorama row, for the lag pairs.
struct LagSlot {
  int64_t linear = -1;  // the voxel's linear index in the grid; -1: empty
  uint32_t observers = 0;
  std::array<double, kMaxFrames> residual;
  std::array<double, kMaxFrames> corrected;
  std::array<Eigen::Vector4d, kMaxFrames> brightness;  // z: mu_j [1, x, y, z] in frame f
};

// Fixed blocks of candidate voxels (a multiple of any thread count used here).
constexpr int64_t kBlocks = 64;

// Adds the pair of `slot` and `before`, the voxel the lag before it on its row, to the sums
// of every frame that observes both.
void AddLagPair(const LagSlot& slot, const LagSlot& before, StructureSums* sums) {
  uint32_t both = slot.observers & before.observers;
  while (both != 0) {
    const int f = __builtin_ctz(both);
    both &= both - 1;
    ++sums->pairs[f];
    sums->rr[f] += slot.residual[f] * before.residual[f];
    sums->r1[f] += before.residual[f];
    sums->r2[f] += slot.residual[f];
    sums->rsq[f] += 0.5 * (slot.residual[f] * slot.residual[f] +
                           before.residual[f] * before.residual[f]);
    sums->cc[f] += slot.corrected[f] * before.corrected[f];
    sums->c1[f] += before.corrected[f];
    sums->c2[f] += slot.corrected[f];
    sums->c1c1[f] += 0.5 * (before.corrected[f] * before.corrected[f] +
                            slot.corrected[f] * slot.corrected[f]);
    sums->rz[f] += 0.5 * (before.residual[f] * slot.brightness[f] +
                          slot.residual[f] * before.brightness[f]);
    sums->zz[f] += before.brightness[f] * slot.brightness[f].transpose();
    sums->z1[f] += before.brightness[f];
    sums->z2[f] += slot.brightness[f];
  }
}

// Adds the first m frames' sums of a block to *total.
void AddSums(const StructureSums& block, int m, StructureSums* total) {
  for (int f = 0; f < m; ++f) {
    total->pairs[f] += block.pairs[f];
    total->rr[f] += block.rr[f];
    total->r1[f] += block.r1[f];
    total->r2[f] += block.r2[f];
    total->rsq[f] += block.rsq[f];
    total->cc[f] += block.cc[f];
    total->c1[f] += block.c1[f];
    total->c2[f] += block.c2[f];
    total->c1c1[f] += block.c1c1[f];
    total->rz[f] += block.rz[f];
    total->zz[f] += block.zz[f];
    total->z1[f] += block.z1[f];
    total->z2[f] += block.z2[f];
  }
}

// Frame f's structure statistics from the sums of its lag pairs.
FrameStructure StructureFromSums(const StructureSums& total, int f) {
  FrameStructure s;
  s.pairs = total.pairs[f];
  if (s.pairs < 2) return s;
  const double n_pairs = static_cast<double>(s.pairs);
  // Centred: a frame's mean residual is a brightness offset, not anatomy out of line.
  const double r_mean1 = total.r1[f] / n_pairs, r_mean2 = total.r2[f] / n_pairs;
  s.residual_lag = total.rr[f] / n_pairs - r_mean1 * r_mean2;
  // Less the part a brightness field explains: a gain of frame i against the others that
  // varies smoothly over it (a gain, or attenuation with depth that the others see at
  // other depths) leaves r = (g(x) - 1) mu + noise, structure that is brightness, not
  // anatomy out of line. With g linear in the sample's place, that is r = z^T beta for the
  // regressors z = mu [1, x, y, z]; the regression at the lag, beta = C_zz'^-1 c_rz' (where
  // the noise of z and r, which share frame i's, does not bias it), accounts for
  // c_rz'^T C_zz'^-1 c_rz' of the residual's lag covariance.
  const Eigen::Vector4d z_mean1 = total.z1[f] / n_pairs, z_mean2 = total.z2[f] / n_pairs;
  const Eigen::Vector4d c_rz =
      total.rz[f] / n_pairs - 0.5 * (r_mean1 * z_mean2 + r_mean2 * z_mean1);
  Eigen::Matrix4d c_zz = total.zz[f] / n_pairs - z_mean1 * z_mean2.transpose();
  c_zz = (0.5 * (c_zz + c_zz.transpose())).eval();
  // Its positive part only (a lag covariance need not be positive definite): directions
  // of z without structure at the lag explain nothing.
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix4d> eigen(c_zz);
  const double largest = eigen.eigenvalues().maxCoeff();
  for (int e = 0; e < 4; ++e) {
    const double lambda = eigen.eigenvalues()[e];
    if (lambda > 1e-9 * largest) {
      const double along = eigen.eigenvectors().col(e).dot(c_rz);
      s.residual_lag -= along * along / lambda;
    }
  }
  s.residual_variance = total.rsq[f] / n_pairs - 0.25 * (r_mean1 + r_mean2) * (r_mean1 + r_mean2);
  const double mean1 = total.c1[f] / n_pairs, mean2 = total.c2[f] / n_pairs;
  const double mean = 0.5 * (mean1 + mean2);
  s.signal_lag = total.cc[f] / n_pairs - mean1 * mean2;
  s.signal_variance = total.c1c1[f] / n_pairs - mean * mean;
  const double root_n = std::sqrt(n_pairs);
  if (s.residual_variance > 0.0) s.significance = s.residual_lag / (s.residual_variance / root_n);
  s.judged = s.signal_lag > kStructureSignificance * s.signal_variance / root_n;
  if (s.judged) s.fraction = s.residual_lag / s.signal_lag;
  return s;
}

}  // namespace

int StructureLagVoxels(const std::vector<Frame>& frames, const ImageGeometry& grid) {
  double largest = 0.0;
  for (const Frame& f : frames) largest = std::max(largest, f.geometry().spacing_mm.maxCoeff());
  const int lag = static_cast<int>(std::ceil(2.0 * std::sqrt(3.0) * largest / grid.spacing_mm[0] -
                                             1e-9));
  return std::max(2, lag);
}

namespace {

// FrameStructures over every row of `candidates`.
std::vector<FrameStructure> FrameStructuresOfRows(
    const std::vector<Frame>& frames,
    const CandidateSet& candidates,
    const std::vector<Eigen::Isometry3d>& frame_from_world,
    const StreamContext& context,
    const std::vector<Photometric>& photometric) {
  const int m = static_cast<int>(frames.size());
  const int lag = StructureLagVoxels(frames, candidates.grid);
  const int64_t nx = candidates.grid.size[0];
  const std::vector<PosedFrame> posed = PoseFrames(frames, frame_from_world);
  const KernelPath path = StreamKernelPath(context);
  std::vector<double> gain(m, 1.0), offset(m, 0.0);
  for (int i = 0; i < m && !photometric.empty(); ++i) {
    gain[i] = photometric[i].gain();
    offset[i] = photometric[i].offset;
  }
  // Each frame's place of a sample, in units of its half-size about its grid's centre, for
  // the brightness regressors (O(1), so that they are conditioned alike).
  std::vector<Eigen::Vector3d> middle(m);
  std::vector<double> scale(m);
  for (int i = 0; i < m; ++i) {
    const ImageGeometry& g = frames[i].geometry();
    middle[i] = g.IndexToPhysical(0.5 * (g.size.cast<double>() - Eigen::Vector3d::Ones()));
    scale[i] = 2.0 / std::max(1e-9, g.size.cast<double>().cwiseProduct(g.spacing_mm).maxCoeff());
  }
  const int64_t n = candidates.num_voxels();
  std::vector<StructureSums> blocks(kBlocks);
  ParallelFor(0, kBlocks, context.num_threads, [&](int64_t b) {
    StructureSums& sums = blocks[b];
    std::vector<LagSlot> ring(lag + 1);
    VoxelBatch* const batch = ThreadVoxelBatch();
    const int64_t end = n * (b + 1) / kBlocks;
    for (int64_t v = n * b / kBlocks; v < end;) {
      v = SampleVoxelBatch(path, posed, candidates, v, end, /*with_jacobian=*/false, batch);
      for (int t = 0; t < batch->num_voxels; ++t) {
        const int64_t linear = candidates.voxel[batch->voxel[t]];
        const int64_t x = linear % nx;
        LagSlot& slot = ring[x % (lag + 1)];
        // The voxel L before this one on its row sits in the slot of x - L: that slot is
        // written at column x - L and next at x + 1.
        const LagSlot& before = ring[(x + 1) % (lag + 1)];
        const int k = batch->begin[t + 1] - batch->begin[t];
        slot.linear = linear;
        slot.observers = batch->observers[t];
        double mean = 0.0;
        for (int a = batch->begin[t]; a < batch->begin[t + 1]; ++a) {
          const int f = batch->frame[a];
          slot.corrected[f] = gain[f] * batch->value[a] + offset[f];
          mean += slot.corrected[f];
        }
        mean /= k;
        const Eigen::Vector3d centre = candidates.VoxelCenter(batch->voxel[t]);
        for (int a = batch->begin[t]; a < batch->begin[t + 1]; ++a) {
          const int f = batch->frame[a];
          slot.residual[f] = slot.corrected[f] - mean;
          const Eigen::Vector3d place = scale[f] * (frame_from_world[f] * centre - middle[f]);
          slot.brightness[f] << mean, mean * place;
        }
        if (x < lag || before.linear != linear - lag) continue;
        AddLagPair(slot, before, &sums);
      }
    }
  });
  StructureSums total;
  for (const StructureSums& block : blocks) AddSums(block, m, &total);
  std::vector<FrameStructure> out(m);
  for (int f = 0; f < m; ++f) out[f] = StructureFromSums(total, f);
  return out;
}

}  // namespace

std::vector<FrameStructure> FrameStructures(const std::vector<Frame>& frames,
                                            const CandidateSet& candidates,
                                            const std::vector<Eigen::Isometry3d>& frame_from_world,
                                            const StreamContext& context,
                                            const std::vector<Photometric>& photometric,
                                            double pairs_per_frame) {
  const int m = static_cast<int>(frames.size());
  CHECK_EQ(static_cast<int>(frame_from_world.size()), m);
  CHECK(photometric.empty() || static_cast<int>(photometric.size()) == m);
  CHECK_LE(m, kMaxFrames);
  // Every frame's pairs are about its observations: beyond pairs_per_frame of them, rows
  // spread evenly suffice (whole rows: the lag pairs lie along them).
  const double keep_rows =
      pairs_per_frame > 0.0
          ? static_cast<double>(candidates.NumObservations()) / m / pairs_per_frame
          : 0.0;
  if (keep_rows >= 2.0) {
    return FrameStructuresOfRows(frames,
                                 CandidatesInRows(candidates, static_cast<int>(keep_rows)),
                                 frame_from_world, context, photometric);
  }
  return FrameStructuresOfRows(frames, candidates, frame_from_world, context, photometric);
}

std::vector<int> StructureOutliers(const std::vector<FrameStructure>& structure,
                                   double max_fraction,
                                   const std::vector<bool>* exempt) {
  std::vector<int> outliers;
  if (!(max_fraction > 0.0)) return outliers;
  for (size_t i = 0; i < structure.size(); ++i) {
    if (exempt != nullptr && (*exempt)[i]) continue;
    const FrameStructure& s = structure[i];
    if (s.judged && s.fraction > max_fraction && s.significance > kStructureSignificance) {
      outliers.push_back(static_cast<int>(i));
    }
  }
  std::stable_sort(outliers.begin(), outliers.end(), [&](int a, int b) {
    return structure[a].fraction > structure[b].fraction;
  });
  return outliers;
}

bool StructureOutlier(const std::vector<FrameStructure>& structure,
                      double max_fraction,
                      std::string* why,
                      const std::vector<bool>* exempt) {
  const std::vector<int> outliers = StructureOutliers(structure, max_fraction, exempt);
  if (outliers.empty()) return false;
  const int worst = outliers.front();
  const FrameStructure& s = structure[worst];
  std::ostringstream text;
  text.precision(3);
  text << "frame " << worst << " does not line up with the others at the poses reached: "
       << 100.0 * s.fraction << "% of its own structure remains in its differences to the "
       << "panorama (" << s.significance << " standard errors of noise alone; "
       << "max_structure_fraction=" << max_fraction << ")";
  if (outliers.size() > 1) text << "; " << outliers.size() << " frames are above it";
  text << ": a wrong local minimum; give better initial poses (init)";
  *why = text.str();
  return true;
}

std::string StructureSummary(const std::vector<FrameStructure>& structure) {
  int worst = -1, flat = 0;
  for (size_t i = 0; i < structure.size(); ++i) {
    if (!structure[i].judged) {
      ++flat;
    } else if (worst < 0 || structure[i].fraction > structure[worst].fraction) {
      worst = static_cast<int>(i);
    }
  }
  if (worst < 0 && flat == 0) return "";
  std::ostringstream text;
  text.precision(2);
  text << "structure check (docs/design.md 8.4): ";
  if (worst >= 0) {
    text << "at most " << 100.0 * structure[worst].fraction << "% of a frame's own structure "
         << "remains in its differences to the panorama (frame " << worst << ", "
         << structure[worst].significance << " standard errors of noise alone)";
  }
  if (flat > 0) {
    text << (worst >= 0 ? "; " : "") << flat << (flat == 1 ? " frame" : " frames")
         << " too flat to judge";
  }
  return text.str();
}

}  // namespace dsr
