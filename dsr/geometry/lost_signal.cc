// Beams without signal (dsr/geometry/lost_signal.h).
#include "dsr/geometry/lost_signal.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <vector>

#include "dsr/util/parallel.h"

namespace dsr {
namespace {

// Weighted least-squares line y = a + b t; false when the t's do not vary.
bool FitLine(const std::vector<double>& t, const std::vector<double>& y,
             const std::vector<double>& w, double* a, double* b) {
  double sw = 0.0, st = 0.0, sy = 0.0, stt = 0.0, sty = 0.0;
  for (size_t s = 0; s < t.size(); ++s) {
    sw += w[s];
    st += w[s] * t[s];
    sy += w[s] * y[s];
    stt += w[s] * t[s] * t[s];
    sty += w[s] * t[s] * y[s];
  }
  const double det = sw * stt - st * st;
  if (sw <= 0.0 || !(det > 1e-12 * sw * sw)) return false;
  *b = (sw * sty - st * sy) / det;
  *a = (sy - *b * st) / sw;
  return true;
}

// Per slice along `axis`: the voxel count and the sums of the other two index coordinates.
struct SliceSums {
  std::vector<double> count, sum_b, sum_c;
};

// The slice sums along every axis at once, over every `stride`-th voxel along each axis
// (the slices not visited stay empty).
std::array<SliceSums, 3> SumSlices(const Mask& fov, int stride) {
  const Eigen::Vector3i& n = fov.geometry.size;
  std::array<SliceSums, 3> s;
  for (int a = 0; a < 3; ++a) {
    s[a].count.assign(n[a], 0.0);
    s[a].sum_b.assign(n[a], 0.0);
    s[a].sum_c.assign(n[a], 0.0);
  }
  for (int k = 0; k < n[2]; k += stride) {
    for (int j = 0; j < n[1]; j += stride) {
      const int64_t row = fov.geometry.LinearIndex(0, j, k);
      double count = 0.0, sum_i = 0.0;
      for (int i = 0; i < n[0]; i += stride) {
        if (!fov.voxels[row + i]) continue;
        count += 1.0;
        sum_i += i;
        s[0].count[i] += 1.0;
        s[0].sum_b[i] += j;
        s[0].sum_c[i] += k;
      }
      if (count == 0.0) continue;
      s[1].count[j] += count, s[1].sum_b[j] += k * count, s[1].sum_c[j] += sum_i;
      s[2].count[k] += count, s[2].sum_b[k] += sum_i, s[2].sum_c[k] += j * count;
    }
  }
  return s;
}

// The sector along one axis and direction (found false when it does not widen enough).
Sector SectorAlong(const SliceSums& s, int axis, int direction) {
  Sector sector;
  std::vector<double> t, width, weight, cb, cc;
  for (size_t q = 0; q < s.count.size(); ++q) {
    if (s.count[q] <= 0.0) continue;
    t.push_back(static_cast<double>(q));
    width.push_back(std::sqrt(s.count[q]));
    weight.push_back(1.0);
    cb.push_back(s.sum_b[q] / s.count[q]);
    cc.push_back(s.sum_c[q] / s.count[q]);
  }
  if (static_cast<int>(t.size()) < kMinLostSignalSlabs) return sector;
  double a = 0.0, b = 0.0;
  if (!FitLine(t, width, weight, &a, &b)) return sector;
  const double near = direction > 0 ? t.front() : t.back();
  const double far = direction > 0 ? t.back() : t.front();
  const double near_width = a + b * near, far_width = a + b * far;
  if (!(far_width > 0.0) || direction * b <= 0.0) return sector;
  sector.widening = near_width > 0.0 ? far_width / near_width : HUGE_VAL;
  if (sector.widening < kMinSectorWidening) return sector;
  const double apex_t = -a / b;
  // The centroids weighted by the slices' counts: the wide slices fix the beam axis best.
  double ab = 0.0, bb = 0.0, ac = 0.0, bc = 0.0;
  std::vector<double> counts;
  for (double q : t) counts.push_back(s.count[static_cast<size_t>(q)]);
  if (!FitLine(t, cb, counts, &ab, &bb) || !FitLine(t, cc, counts, &ac, &bc)) return sector;
  sector.found = true;
  sector.depth_axis = axis;
  sector.direction = direction;
  sector.apex[axis] = apex_t;
  sector.apex[(axis + 1) % 3] = ab + bb * apex_t;
  sector.apex[(axis + 2) % 3] = ac + bc * apex_t;
  return sector;
}

// The beam bins of a sector: a voxel's beam is its offset from the apex (mm) over its depth
// along the depth axis, two tangents binned `width` apart from (u0, v0); its slab is its
// depth in units of slab_mm.
struct BeamGrid {
  Sector sector;
  Eigen::Vector3d spacing = Eigen::Vector3d::Ones();
  double u0 = 0.0, v0 = 0.0, width = 1.0, slab_mm = 1.0;
  int nu = 0, nv = 0, slabs = 0;

  // The tangents and the depth of voxel (i, j, k); false behind the apex.
  bool Tangents(int i, int j, int k, double* u, double* v, double* depth) const {
    const Eigen::Vector3d d = (Eigen::Vector3d(i, j, k) - sector.apex).cwiseProduct(spacing);
    const int a = sector.depth_axis;
    *depth = sector.direction * d[a];
    if (!(*depth > 0.0)) return false;
    *u = d[(a + 1) % 3] / *depth;
    *v = d[(a + 2) % 3] / *depth;
    return true;
  }
  // The bin of voxel (i, j, k) (-1 behind the apex) and its slab.
  int Bin(int i, int j, int k, int* slab) const {
    double u = 0.0, v = 0.0, depth = 0.0;
    if (!Tangents(i, j, k, &u, &v, &depth)) return -1;
    const int bu = std::clamp(static_cast<int>((u - u0) / width), 0, nu - 1);
    const int bv = std::clamp(static_cast<int>((v - v0) / width), 0, nv - 1);
    *slab = std::min(slabs - 1, static_cast<int>(depth / slab_mm));
    return bu + nu * bv;
  }
};

// Calls fn(i, j, k, linear) for every `stride`-th voxel along each axis inside `fov`.
template <typename Fn>
void ForEachInside(const Mask& fov, int stride, const Fn& fn) {
  const Eigen::Vector3i& n = fov.geometry.size;
  for (int k = 0; k < n[2]; k += stride) {
    for (int j = 0; j < n[1]; j += stride) {
      const int64_t row = fov.geometry.LinearIndex(0, j, k);
      for (int i = 0; i < n[0]; i += stride) {
        if (fov.voxels[row + i]) fn(i, j, k, row + i);
      }
    }
  }
}

// The bins of `sector` over the voxels ForEachInside visits: kBeamBinVoxels sampled voxels
// wide at their mean depth, at most 256 per tangent; nu == 0 when none lies ahead of the apex.
BeamGrid MakeBeamGrid(const Mask& fov, const Sector& sector, int stride) {
  BeamGrid grid;
  grid.sector = sector;
  grid.spacing = fov.geometry.spacing_mm;
  double u0 = HUGE_VAL, u1 = -HUGE_VAL, v0 = HUGE_VAL, v1 = -HUGE_VAL, depth_sum = 0.0;
  double depth_max = 0.0;
  int64_t ahead = 0;
  ForEachInside(fov, stride, [&](int i, int j, int k, int64_t) {
    double u = 0.0, v = 0.0, depth = 0.0;
    if (!grid.Tangents(i, j, k, &u, &v, &depth)) return;
    u0 = std::min(u0, u), u1 = std::max(u1, u);
    v0 = std::min(v0, v), v1 = std::max(v1, v);
    depth_sum += depth;
    depth_max = std::max(depth_max, depth);
    ++ahead;
  });
  if (ahead == 0) return grid;
  const double step = stride * grid.spacing.minCoeff();
  grid.u0 = u0, grid.v0 = v0;
  grid.width = kBeamBinVoxels * step / (depth_sum / ahead);
  grid.nu = std::clamp(static_cast<int>(std::ceil((u1 - u0) / grid.width)), 1, 256);
  grid.nv = std::clamp(static_cast<int>(std::ceil((v1 - v0) / grid.width)), 1, 256);
  grid.slab_mm = stride * grid.spacing[sector.depth_axis];
  grid.slabs = static_cast<int>(depth_max / grid.slab_mm) + 1;
  return grid;
}

// A bin's depth profile: its lag correlation in standard errors of noise alone, its mean.
struct BinVerdict {
  bool seen = false;    // the bin holds voxels (mean is set)
  bool judged = false;  // enough slabs for z
  double z = 0.0, mean = 0.0;
};

BinVerdict JudgeProfile(const double* sum, const int* count, int slabs_total) {
  BinVerdict verdict;
  double total = 0.0, p_sum = 0.0;
  int64_t voxels = 0;
  int slabs = 0;
  for (int d = 0; d < slabs_total; ++d) {
    if (count[d] == 0) continue;
    total += sum[d];
    voxels += count[d];
    p_sum += sum[d] / count[d];
    ++slabs;
  }
  if (voxels == 0) return verdict;
  verdict.seen = true;
  verdict.mean = total / voxels;
  if (slabs < kMinLostSignalSlabs) return verdict;
  const double p_mean = p_sum / slabs;
  double var = 0.0, cov = 0.0;
  int pairs = 0;
  for (int d = 0; d < slabs_total; ++d) {
    if (count[d] == 0) continue;
    const double x = sum[d] / count[d] - p_mean;
    var += x * x;
    const int e = d + kLostSignalLagVoxels;
    if (e < slabs_total && count[e] > 0) {
      cov += x * (sum[e] / count[e] - p_mean);
      ++pairs;
    }
  }
  if (pairs < 2) return verdict;
  var /= slabs;
  cov /= pairs;
  verdict.judged = true;
  // A constant profile carries nothing either: noise alone at a level the clamp made flat.
  verdict.z = var > 0.0 ? cov / var * std::sqrt(static_cast<double>(pairs)) : 0.0;
  return verdict;
}

double Median(std::vector<double> values) {
  std::nth_element(values.begin(), values.begin() + values.size() / 2, values.end());
  return values[values.size() / 2];
}

// Whether a bin is a core: judged, without structure, and darker than `core_cut`.
bool IsCore(const BinVerdict& v, double core_cut) {
  return v.judged && v.z < kLostSignalZ && v.mean < core_cut;
}

// The lost bins of an nu x nv grid of beam bins (header comment): the cores (IsCore),
// grown through 8-neighbours whose mean is below the geometric mean of the cores' median
// level and `median` (closer to the lost level than to the view's, in decibels); a grown
// region of fewer than kMinDropoutShare of the `judged` bins is left in.
std::vector<uint8_t> LostBins(const std::vector<BinVerdict>& verdicts,
                              int nu,
                              int nv,
                              double median,
                              double core_cut,
                              int judged) {
  const int nbins = nu * nv;
  std::vector<uint8_t> core(nbins, 0), lost(nbins, 0), seen(nbins, 0);
  std::vector<double> core_means;
  for (int b = 0; b < nbins; ++b) {
    core[b] = IsCore(verdicts[b], core_cut);
    if (core[b]) core_means.push_back(verdicts[b].mean);
  }
  if (core_means.empty()) return lost;
  const double cut = std::sqrt(std::max(0.0, Median(core_means)) * median);
  for (int seed = 0; seed < nbins; ++seed) {
    if (!core[seed] || seen[seed]) continue;
    std::vector<int> region = {seed}, stack = {seed};
    seen[seed] = 1;
    while (!stack.empty()) {
      const int b = stack.back();
      stack.pop_back();
      for (int dv = -1; dv <= 1; ++dv) {
        for (int du = -1; du <= 1; ++du) {
          const int u = b % nu + du, v = b / nu + dv;
          if (u < 0 || u >= nu || v < 0 || v >= nv) continue;
          const int n = u + nu * v;
          if (seen[n] || !verdicts[n].seen || !(verdicts[n].mean < cut)) continue;
          seen[n] = 1;
          region.push_back(n);
          stack.push_back(n);
        }
      }
    }
    if (region.size() < kMinDropoutShare * judged) continue;
    for (int b : region) lost[b] = 1;
  }
  return lost;
}

// The statistics' stride (kLostSignalSampleVoxels).
int SampleStride(const ImageGeometry& g) {
  const double share = static_cast<double>(g.NumVoxels()) / kLostSignalSampleVoxels;
  return std::max(1, static_cast<int>(std::lround(std::cbrt(share))));
}

// A view's beam bins, judged (the statistics' pass).
struct ViewBeams {
  Sector sector;
  BeamGrid grid;
  std::vector<BinVerdict> verdicts;
  double median = 0.0;  // of the judged bins' means
  int judged = 0;
  int64_t fov_voxels = 0;
  // The view's lost bins by its own rule (cores below kDropoutCoreRatio of the median).
  std::vector<uint8_t> own_lost;
};

ViewBeams JudgeBeams(const Image& image, const Mask& fov) {
  ViewBeams view;
  view.fov_voxels = CountInside(fov);
  view.sector = FindSector(fov);
  if (!view.sector.found) return view;
  const int stride = SampleStride(fov.geometry);
  view.grid = MakeBeamGrid(fov, view.sector, stride);
  const BeamGrid& grid = view.grid;
  const int nbins = grid.nu * grid.nv;
  if (nbins == 0) return view;
  std::vector<double> sum(static_cast<size_t>(nbins) * grid.slabs, 0.0);
  std::vector<int> count(sum.size(), 0);
  ForEachInside(fov, stride, [&](int i, int j, int k, int64_t l) {
    int slab = 0;
    const int b = grid.Bin(i, j, k, &slab);
    if (b < 0) return;
    const size_t at = static_cast<size_t>(b) * grid.slabs + slab;
    sum[at] += image.voxels[l];
    ++count[at];
  });
  view.verdicts.resize(nbins);
  std::vector<double> means;
  for (int b = 0; b < nbins; ++b) {
    const size_t at = static_cast<size_t>(b) * grid.slabs;
    view.verdicts[b] = JudgeProfile(&sum[at], &count[at], grid.slabs);
    if (view.verdicts[b].judged) means.push_back(view.verdicts[b].mean);
  }
  view.judged = static_cast<int>(means.size());
  if (means.empty()) return view;
  view.median = Median(means);
  view.own_lost = LostBins(view.verdicts, grid.nu, grid.nv, view.median,
                           kDropoutCoreRatio * view.median, view.judged);
  return view;
}

// The level of noise alone the views share: the median of the core bins of the dropouts
// found in each view by its own rule (kDropoutCoreRatio of its median); 0 when no view has
// one. Isolated dark bins that form no dropout (dark tissue) do not count.
double SharedLevel(const std::vector<ViewBeams>& views) {
  std::vector<double> pooled;
  for (const ViewBeams& view : views) {
    const double core_cut = kDropoutCoreRatio * view.median;
    for (size_t b = 0; b < view.own_lost.size(); ++b) {
      if (view.own_lost[b] && IsCore(view.verdicts[b], core_cut)) {
        pooled.push_back(view.verdicts[b].mean);
      }
    }
  }
  return pooled.empty() ? 0.0 : Median(pooled);
}

// A view's lost beams from its judged bins, labelled voxel by voxel. `shared_level` > 0:
// the level of noise alone the views share; a core may then be as bright as the geometric
// mean of that level and the view's median, where that is above kDropoutCoreRatio of it.
LostSignal LabelLost(const ViewBeams& view, const Mask& fov, double shared_level) {
  LostSignal out;
  out.sector = view.sector;
  out.fov_voxels = view.fov_voxels;
  out.judged_bins = view.judged;
  if (view.judged == 0) return out;
  const double own_cut = kDropoutCoreRatio * view.median;
  const double core_cut =
      shared_level > 0.0 ? std::max(own_cut, std::sqrt(shared_level * view.median)) : own_cut;
  const BeamGrid& grid = view.grid;
  // The view's own verdict stands where the shared level does not widen its cores.
  const std::vector<uint8_t> lost_bin =
      core_cut == own_cut
          ? view.own_lost
          : LostBins(view.verdicts, grid.nu, grid.nv, view.median, core_cut, view.judged);
  out.lost_bins = static_cast<int>(std::count(lost_bin.begin(), lost_bin.end(), 1));
  if (out.lost_bins == 0) return out;
  out.lost = Mask(fov.geometry, 0);
  ForEachInside(fov, 1, [&](int i, int j, int k, int64_t l) {
    int slab = 0;
    const int b = grid.Bin(i, j, k, &slab);
    if (b >= 0 && lost_bin[b]) {
      out.lost.voxels[l] = 1;
      ++out.lost_voxels;
    }
  });
  return out;
}

}  // namespace

Sector FindSector(const Mask& fov) {
  Sector best;
  const std::array<SliceSums, 3> sums = SumSlices(fov, SampleStride(fov.geometry));
  for (int axis = 0; axis < 3; ++axis) {
    for (int direction : {1, -1}) {
      const Sector s = SectorAlong(sums[axis], axis, direction);
      if (s.found && (!best.found || s.widening > best.widening)) best = s;
    }
  }
  return best;
}

LostSignal FindLostSignal(const Image& image, const Mask& fov) {
  std::vector<ViewBeams> view(1, JudgeBeams(image, fov));
  return LabelLost(view[0], fov, SharedLevel(view));
}

std::vector<LostSignal> FindLostSignalInViews(const std::vector<Image>& images,
                                              const std::vector<Mask>& fovs,
                                              int num_threads) {
  const int m = static_cast<int>(images.size());
  std::vector<ViewBeams> views(m);
  ParallelFor(0, m, num_threads, [&](int64_t i) { views[i] = JudgeBeams(images[i], fovs[i]); });
  const double shared_level = SharedLevel(views);
  std::vector<LostSignal> out(m);
  ParallelFor(0, m, num_threads,
              [&](int64_t i) { out[i] = LabelLost(views[i], fovs[i], shared_level); });
  return out;
}

}  // namespace dsr
