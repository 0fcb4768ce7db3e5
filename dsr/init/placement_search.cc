#include "dsr/init/placement_search.h"

#include <algorithm>
#include <cmath>
#include <mutex>
#include <sstream>

#include <glog/logging.h>

#include "dsr/baselines/baselines.h"
#include "dsr/image/pyramid.h"
#include "dsr/init/masked_ncc.h"
#include "dsr/init/rotation_grid.h"
#include "dsr/util/option_fields.h"
#include "dsr/util/parallel.h"

namespace dsr {
namespace {

constexpr double kDegree = M_PI / 180.0;
// Fewest valid cells of a half-resolution volume for the coarse screen of the rotations
// (below, the full-resolution search scores every rotation).
constexpr int64_t kMinScreenCells = 64;

// The volume's values and valid-cell map on the box of its valid cells (`lo` its first
// voxel): the rest of the grid is outside the field of view and would only enlarge the
// FFTs.
void ValuesAndValidCells(const Frame& frame, Eigen::Vector3i* lo, Image* values, Mask* valid) {
  const ImageGeometry& g = frame.geometry();
  const Eigen::AlignedBox3d& box = frame.ValidIndexBox();  // [min cell, max cell + 1]
  *lo = box.min().cast<int>();
  ImageGeometry cropped = g;
  cropped.size = (box.max() - box.min()).cast<int>().cwiseMax(1);
  *values = Image(cropped, 0.0f);
  *valid = Mask(cropped, 0);
  const float* data = frame.values();
  for (int k = 0; k < cropped.size[2]; ++k) {
    for (int j = 0; j < cropped.size[1]; ++j) {
      for (int i = 0; i < cropped.size[0]; ++i) {
        const int64_t l = g.LinearIndex(i + (*lo)[0], j + (*lo)[1], k + (*lo)[2]);
        if (!frame.IsValidCell(l)) continue;
        const int64_t c = cropped.LinearIndex(i, j, k);
        values->voxels[c] = data[l];
        valid->voxels[c] = 1;
      }
    }
  }
}

// The voxels that are a corner of some valid cell of `frame` (every point a valid sample
// can come from lies in a cell spanned by them).
Mask ValidCellCorners(const Frame& frame) {
  const ImageGeometry& g = frame.geometry();
  Mask corners(g, 0);
  for (int k = 0; k + 1 < g.size[2]; ++k) {
    for (int j = 0; j + 1 < g.size[1]; ++j) {
      for (int i = 0; i + 1 < g.size[0]; ++i) {
        if (!frame.IsValidCell(g.LinearIndex(i, j, k))) continue;
        for (int c = 0; c < 8; ++c) {
          corners.voxels[g.LinearIndex(i + (c & 1), j + ((c >> 1) & 1), k + (c >> 2))] = 1;
        }
      }
    }
  }
  return corners;
}

// Physical points whose convex hull holds every point a valid sample of `frame` can come
// from: the valid cells' corners that are not surrounded by other such corners.
std::vector<Eigen::Vector3d> ValidHullCandidates(const Frame& frame) {
  const ImageGeometry& g = frame.geometry();
  const Eigen::Vector3i& n = g.size;
  const Mask corners = ValidCellCorners(frame);
  const auto corner = [&](int i, int j, int k) {
    return corners.voxels[g.LinearIndex(i, j, k)] != 0;
  };
  std::vector<Eigen::Vector3d> points;
  for (int k = 0; k < n[2]; ++k) {
    for (int j = 0; j < n[1]; ++j) {
      for (int i = 0; i < n[0]; ++i) {
        if (!corner(i, j, k)) continue;
        const bool interior = i > 0 && j > 0 && k > 0 && i + 1 < n[0] && j + 1 < n[1] &&
                              k + 1 < n[2] && corner(i - 1, j, k) && corner(i + 1, j, k) &&
                              corner(i, j - 1, k) && corner(i, j + 1, k) &&
                              corner(i, j, k - 1) && corner(i, j, k + 1);
        if (!interior) points.push_back(g.IndexToPhysical(Eigen::Vector3d(i, j, k)));
      }
    }
  }
  return points;
}

// Pearson correlation from sums over n pairs (a, b) shifted by reference values.
struct Correlation {
  double sa = 0, sb = 0, saa = 0, sbb = 0, sab = 0;
  int64_t n = 0;
  void Add(double a, double b) {
    sa += a;
    sb += b;
    saa += a * a;
    sbb += b * b;
    sab += a * b;
    ++n;
  }
  double Value() const {
    if (n < 2) return -std::numeric_limits<double>::infinity();
    const double var_a = saa - sa * sa / n, var_b = sbb - sb * sb / n;
    // A flat side (relative to its own scale) has no correlation.
    constexpr double kFlat = 1e-12;
    if (!(var_a > kFlat * saa) || !(var_b > kFlat * sbb)) {
      return -std::numeric_limits<double>::infinity();
    }
    return std::clamp((sab - sa * sb / n) / std::sqrt(var_a * var_b), -1.0, 1.0);
  }
};

// The moving field of view rotated onto the fixed grid's axes (see SearchPeaks).
struct RotatedGrid {
  Eigen::Vector3i size;
  Eigen::Vector3d half_extent;  // in fixed voxels: W index q sits at y = D S (q - half)
};

}  // namespace

bool PlacementSearchOptions::Validate(std::string* error) const {
  if (!(rotation_deg > 0.0 && rotation_deg <= 180.0)) {
    return RefuseField(error, "rotation_deg", rotation_deg, "must be in (0, 180]");
  }
  if (rotations < 1 || rotations > 100000) {
    return RefuseField(error, "rotations", rotations, "must be in [1, 100000]");
  }
  if (pair_rotations < 1 || pair_rotations > 100000) {
    return RefuseField(error, "pair_rotations", pair_rotations, "must be in [1, 100000]");
  }
  if (num_screened < 0 || num_screened > 100000) {
    return RefuseField(error, "num_screened", num_screened, "must be in [0, 100000]");
  }
  if (num_refined < 1 || num_refined > 100) {
    return RefuseField(error, "num_refined", num_refined, "must be in [1, 100]");
  }
  if (!(distinct_rotation_deg >= 0.0 && distinct_rotation_deg <= 180.0)) {
    return RefuseField(error, "distinct_rotation_deg", distinct_rotation_deg,
                       "must be in [0, 180]");
  }
  if (!(min_overlap_fraction > 0.0 && min_overlap_fraction <= 1.0)) {
    return RefuseField(error, "min_overlap_fraction", min_overlap_fraction, "must be in (0, 1]");
  }
  if (!refine.Validate(error)) {
    *error = PrefixFieldPaths("refine", *error);
    return false;
  }
  return true;
}

double ScoreMinOverlap(const PlacementSearchOptions& options) {
  return 0.5 * options.min_overlap_fraction;
}

Placement ScorePlacement(const Frame& fixed,
                         const Frame& moving,
                         const Eigen::Isometry3d& moving_from_fixed,
                         double min_overlap_fraction) {
  const ImageGeometry& g = moving.geometry();
  const Eigen::Isometry3d fixed_from_moving = moving_from_fixed.inverse();
  const float* data = moving.values();
  Correlation c;
  int64_t valid = 0;
  for (int k = 0; k < g.size[2]; ++k) {
    for (int j = 0; j < g.size[1]; ++j) {
      for (int i = 0; i < g.size[0]; ++i) {
        const int64_t l = g.LinearIndex(i, j, k);
        if (!moving.IsValidCell(l)) continue;
        ++valid;
        double value = 0.0;
        const Eigen::Vector3d x = fixed_from_moving * g.IndexToPhysical(Eigen::Vector3d(i, j, k));
        if (fixed.Sample(x, &value, nullptr)) c.Add(value, data[l]);
      }
    }
  }
  Placement p;
  p.moving_from_fixed = moving_from_fixed;
  p.overlap = c.n;
  p.overlap_fraction = valid > 0 ? static_cast<double>(c.n) / valid : 0.0;
  if (p.overlap_fraction >= min_overlap_fraction) p.ncc = c.Value();
  return p;
}

namespace {

// The best translation of `moving` in `fixed` for each of `rotations` (the rotation parts
// of moving_from_fixed), in their order; ncc -inf where no translation qualifies.
std::vector<Placement> BestTranslations(const Frame& fixed,
                                        const Frame& moving,
                                        const std::vector<Eigen::Matrix3d>& rotations,
                                        const PlacementSearchOptions& options) {
  const ImageGeometry& fg = fixed.geometry();
  const Eigen::Matrix3d fixed_index_from_physical = fg.PhysicalToIndexMatrix();
  const Eigen::Matrix3d fixed_physical_from_index = fg.IndexToPhysicalMatrix();
  std::vector<Placement> peaks(rotations.size());
  if (fixed.num_valid_cells() == 0 || moving.num_valid_cells() == 0) return peaks;
  const Eigen::Vector3d c_m = moving.ValidCentre();

  // One grid W for every rotation (MaskedNcc prepares the fixed side for one moving size):
  // large enough for the moving field of view under any sampled rotation (the hull of its
  // valid cells, tighter than their box). W index q stands for the point
  // y = D_f S_f (q - half) of the rotated moving frame, whose moving point is x = R y + c_m
  // (R = the rotation of moving_from_fixed).
  const std::vector<Eigen::Vector3d> hull = ValidHullCandidates(moving);
  Eigen::Vector3d half = Eigen::Vector3d::Zero();
  for (const Eigen::Matrix3d& r : rotations) {
    const Eigen::Matrix3d to_w = fixed_index_from_physical * r.transpose();
    for (const Eigen::Vector3d& x : hull) half = half.cwiseMax((to_w * (x - c_m)).cwiseAbs());
  }
  half = half.array().ceil();
  const Eigen::Vector3i w_size = (2.0 * half).cast<int>() + Eigen::Vector3i::Ones();
  ImageGeometry w_grid = fg;
  w_grid.size = w_size;

  // The fixed side on the box of its valid cells: map shift s puts W voxel q on fixed
  // voxel q + s + fixed_lo.
  Eigen::Vector3i fixed_lo;
  Image fixed_values;
  Mask fixed_valid;
  ValuesAndValidCells(fixed, &fixed_lo, &fixed_values, &fixed_valid);
  const MaskedNcc ncc(fixed_values, fixed_valid, w_size);
  // Moving valid cells in fixed voxels (the NCC counts fixed-grid voxels).
  const double moving_fov_in_fixed_voxels = static_cast<double>(moving.num_valid_cells()) *
                                            moving.geometry().spacing_mm.prod() /
                                            fg.spacing_mm.prod();
  const int64_t min_overlap = std::max<int64_t>(
      8, std::llround(options.min_overlap_fraction * moving_fov_in_fixed_voxels));

  // Rotations in blocks, each block with its own resampling buffers (allocating them per
  // rotation cost a tenth of the search).
  const int64_t num_rotations = static_cast<int64_t>(rotations.size());
  const int64_t block =
      std::max<int64_t>(1, num_rotations / (4 * ResolveThreads(options.num_threads)));
  ParallelFor(0, (num_rotations + block - 1) / block, options.num_threads, [&](int64_t b) {
    Image w(w_grid, 0.0f);
    Mask w_mask(w_grid, 0);
    for (int64_t r = b * block; r < std::min(num_rotations, (b + 1) * block); ++r) {
      const Eigen::Matrix3d& rotation = rotations[r];
      // Moving index of W voxel q: A q + b.
      const Eigen::Matrix3d a =
          moving.index_from_physical() * rotation * fixed_physical_from_index;
      const Eigen::Vector3d offset =
          moving.ToIndex(c_m - rotation * fixed_physical_from_index * half);
      for (int k = 0; k < w_size[2]; ++k) {
        for (int j = 0; j < w_size[1]; ++j) {
          for (int i = 0; i < w_size[0]; ++i) {
            const int64_t l = w_grid.LinearIndex(i, j, k);
            double value = 0.0;
            const bool valid =
                moving.SampleAtIndex(a * Eigen::Vector3d(i, j, k) + offset, &value, nullptr);
            w.voxels[l] = valid ? static_cast<float>(value) : 0.0f;
            w_mask.voxels[l] = valid ? 1 : 0;
          }
        }
      }
      const NccPeak peak = ncc.Best(w, w_mask, min_overlap);
      // Fixed voxel q + s + lo holds W voxel q: p = o_f + D_f S_f (q + s + lo) = t + y with
      // t = o_f + D_f S_f (s + lo + half), so fixed_from_moving = Translate(t) R^T
      // Translate(-c_m).
      const Eigen::Vector3d t =
          fg.origin_mm +
          fixed_physical_from_index * ((peak.shift + fixed_lo).cast<double>() + half);
      Eigen::Isometry3d fixed_from_moving = Eigen::Isometry3d::Identity();
      fixed_from_moving.linear() = rotation.transpose();
      fixed_from_moving.translation() = t - rotation.transpose() * c_m;
      Placement& p = peaks[r];
      p.moving_from_fixed = fixed_from_moving.inverse();
      p.ncc = peak.ncc;
      p.overlap = peak.overlap;
      p.overlap_fraction = moving_fov_in_fixed_voxels > 0.0
                               ? std::min(1.0, peak.overlap / moving_fov_in_fixed_voxels)
                               : 0.0;
    }
  });
  return peaks;
}

// `frame` downsampled once (the pyramid's rule: smoothing of sigma 1 voxel, then every
// other voxel), its mask the corners of its valid cells. False when too little of the
// field of view survives for an NCC to rank anything.
bool HalfResolution(const Frame& frame, Frame* half) {
  const ImageGeometry& g = frame.geometry();
  if (g.size.minCoeff() < 8) return false;
  const Mask mask = ValidCellCorners(frame);
  Image values(g, 0.0f);
  const float* data = frame.values();
  for (int64_t l = 0; l < g.NumVoxels(); ++l) {
    if (mask.voxels[l]) values.voxels[l] = data[l];
  }
  ImageLevel level = Downsample(values, mask, 1.0, 1);
  // A Frame's valid cells lie one voxel inside its mask (their gradients' stencil), which
  // at half resolution would take two fine voxels off every side of the field of view:
  // the mask is grown by one coarse voxel first (the smoothed values reach that far).
  const ImageGeometry& hg = level.mask.geometry;
  Mask grown(hg, 0);
  for (int k = 0; k < hg.size[2]; ++k) {
    for (int j = 0; j < hg.size[1]; ++j) {
      for (int i = 0; i < hg.size[0]; ++i) {
        if (!level.mask.at(i, j, k)) continue;
        for (int dk = std::max(0, k - 1); dk <= std::min(hg.size[2] - 1, k + 1); ++dk) {
          for (int dj = std::max(0, j - 1); dj <= std::min(hg.size[1] - 1, j + 1); ++dj) {
            for (int di = std::max(0, i - 1); di <= std::min(hg.size[0] - 1, i + 1); ++di) {
              grown.at(di, dj, dk) = 1;
            }
          }
        }
      }
    }
  }
  *half = Frame(level.image, grown);
  return half->num_valid_cells() >= kMinScreenCells;
}

}  // namespace

std::vector<Placement> SearchPeaks(const Frame& fixed,
                                   const Frame& moving,
                                   const Eigen::Matrix3d& centre,
                                   const PlacementSearchOptions& options) {
  std::vector<Eigen::Matrix3d> rotations =
      RotationsInBall(centre, options.rotation_deg * kDegree, options.rotations);
  // The coarse screen: every rotation on both volumes at half resolution (an eighth of the
  // voxels, FFTs to match), then only the best num_screened rotations at this level.
  Frame coarse_fixed, coarse_moving;
  if (options.num_screened > 0 && options.num_screened < static_cast<int>(rotations.size()) &&
      HalfResolution(fixed, &coarse_fixed) && HalfResolution(moving, &coarse_moving)) {
    const std::vector<Placement> coarse =
        BestTranslations(coarse_fixed, coarse_moving, rotations, options);
    std::vector<int> order(rotations.size());
    for (size_t r = 0; r < order.size(); ++r) order[r] = static_cast<int>(r);
    std::stable_sort(order.begin(), order.end(),
                     [&](int a, int b) { return coarse[a].ncc > coarse[b].ncc; });
    order.resize(options.num_screened);
    std::sort(order.begin(), order.end());  // the kept rotations in their grid order
    std::vector<Eigen::Matrix3d> kept;
    for (int r : order) kept.push_back(rotations[r]);
    rotations = std::move(kept);
  }
  std::vector<Placement> peaks = BestTranslations(fixed, moving, rotations, options);
  // Best first; ties keep the rotation order (deterministic).
  std::stable_sort(peaks.begin(), peaks.end(),
                   [](const Placement& a, const Placement& b) { return a.ncc > b.ncc; });
  while (!peaks.empty() && !std::isfinite(peaks.back().ncc)) peaks.pop_back();
  return peaks;
}

std::vector<Placement> SearchPlacement(const Frame& fixed,
                                       const Frame& moving,
                                       const Eigen::Matrix3d& centre,
                                       const std::vector<Eigen::Isometry3d>& extra_starts,
                                       const PlacementSearchOptions& options) {
  const std::vector<Placement> peaks = SearchPeaks(fixed, moving, centre, options);
  // The best distinct peaks: a peak close to a chosen one (rotation and moving centre in
  // the fixed volume) is the same basin.
  const Eigen::Vector3d c_m = moving.ValidCentre();
  const double same_translation_mm = 3.0 * fixed.geometry().spacing_mm.maxCoeff();
  std::vector<Placement> starts;
  for (const Placement& p : peaks) {
    if (static_cast<int>(starts.size()) >= options.num_refined) break;
    const Eigen::Vector3d centre_p = p.moving_from_fixed.inverse() * c_m;
    bool distinct = true;
    for (const Placement& q : starts) {
      if (RotationAngleBetween(p.moving_from_fixed.linear(), q.moving_from_fixed.linear()) <
              options.distinct_rotation_deg * kDegree &&
          (centre_p - q.moving_from_fixed.inverse() * c_m).norm() < same_translation_mm) {
        distinct = false;
        break;
      }
    }
    if (distinct) starts.push_back(p);
  }
  for (size_t e = 0; e < extra_starts.size(); ++e) {
    Placement p;
    p.moving_from_fixed = extra_starts[e];
    p.extra_start = static_cast<int>(e);
    starts.push_back(p);
  }
  BaselineOptions pair;
  pair.solve = options.refine;
  pair.solve.num_threads = options.num_threads;
  pair.panorama_spacing = 1.0;
  std::vector<Placement> refined;
  for (const Placement& start : starts) {
    Eigen::Isometry3d pose = start.moving_from_fixed;
    SolveReport report;
    std::string why;
    // RegisterPair writes the pose only after a usable solve: a start whose overlap is too
    // small to solve on is scored as it is.
    RegisterPair(fixed, Eigen::Isometry3d::Identity(), moving, pair, &pose, &report, &why);
    Placement scored = ScorePlacement(fixed, moving, pose, ScoreMinOverlap(options));
    scored.extra_start = start.extra_start;
    VLOG(1) << "placement candidate: search NCC " << start.ncc << " -> refined NCC "
            << scored.ncc << " (overlap " << scored.overlap_fraction << ")";
    if (std::isfinite(scored.ncc)) refined.push_back(scored);
  }
  std::stable_sort(refined.begin(), refined.end(),
                   [](const Placement& a, const Placement& b) { return a.ncc > b.ncc; });
  return refined;
}

}  // namespace dsr
