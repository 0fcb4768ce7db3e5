// Field-of-view masks from images (geometry/field_of_view.h, docs/design.md section 2.1).
#include "dsr/geometry/field_of_view.h"

#include <algorithm>
#include <cmath>
#include <numeric>
#include <vector>

#include "dsr/geometry/convex_hull.h"

namespace dsr {
namespace {

// A voxel centre counts as inside a facet's half-space up to this distance (voxels), so that
// the hull's own vertices, which qhull places on its facets up to rounding (~1e-13 here),
// are inside. A lattice point off a facet's plane lies at least 1/|N| away, N the integer
// normal of three of its lattice vertices (|N| < 2 sqrt(3) L^2 on an L^3 grid): 1e-6 voxel
// admits no such point on grids up to about 500 voxels a side.
constexpr double kHullSlackVoxels = 1e-6;

// A maximal run [i0, i1] of inside voxels along i in one row (j, k).
struct Run {
  int i0;
  int i1;
};

// Disjoint sets of runs (the components), with path halving and union by index.
class Components {
 public:
  explicit Components(size_t n) : parent_(n) { std::iota(parent_.begin(), parent_.end(), 0); }
  int Find(int a) {
    while (parent_[a] != a) {
      parent_[a] = parent_[parent_[a]];
      a = parent_[a];
    }
    return a;
  }
  void Join(int a, int b) {
    a = Find(a);
    b = Find(b);
    if (a != b) parent_[std::max(a, b)] = std::min(a, b);
  }

 private:
  std::vector<int> parent_;
};

// Whether integer points span 3 dimensions, exactly (coordinates of a few thousand at most:
// the products below fit in 64 bits).
bool SpanThreeDimensions(const std::vector<Eigen::Vector3i>& points) {
  if (points.size() < 4) return false;
  using Vector3l = Eigen::Matrix<int64_t, 3, 1>;
  const Vector3l p0 = points[0].cast<int64_t>();
  size_t a = 1;
  while (a < points.size() && points[a] == points[0]) ++a;
  if (a == points.size()) return false;
  const Vector3l u = points[a].cast<int64_t>() - p0;
  size_t b = a + 1;
  Vector3l normal = Vector3l::Zero();
  for (; b < points.size() && normal.isZero(); ++b) {
    normal = u.cross(points[b].cast<int64_t>() - p0);
  }
  if (normal.isZero()) return false;  // collinear
  for (size_t c = b; c < points.size(); ++c) {
    if (normal.dot(points[c].cast<int64_t>() - p0) != 0) return true;
  }
  return false;  // coplanar
}

}  // namespace

bool StringToMaskRule(const std::string& name, MaskRule* rule) {
  for (MaskRule r : {MaskRule::kHull, MaskRule::kNonZero}) {
    if (name == MaskRuleToString(r)) {
      *rule = r;
      return true;
    }
  }
  return false;
}

bool MaskFromConvexHull(const Image& image, int erosion_voxels, Mask* mask, std::string* why) {
  const ImageGeometry& g = image.geometry;
  const int nx = g.size[0], ny = g.size[1], nz = g.size[2];
  const int64_t num_rows = int64_t{ny} * nz;
  const Mask inside = MaskFromNonZero(image, 0);
  // The inside voxels as runs along i, row by row in storage order (row r = j + ny k).
  std::vector<Run> runs;
  std::vector<int64_t> row_begin(num_rows + 1);
  for (int64_t r = 0; r < num_rows; ++r) {
    row_begin[r] = static_cast<int64_t>(runs.size());
    const uint8_t* row = inside.voxels.data() + r * nx;
    for (int i = 0; i < nx; ++i) {
      if (!row[i]) continue;
      const int i0 = i;
      while (i + 1 < nx && row[i + 1]) ++i;
      runs.push_back({i0, i});
    }
  }
  row_begin[num_rows] = static_cast<int64_t>(runs.size());
  // 26-connected components: a run touches the runs of the 8 neighbouring rows that come
  // within one voxel of it along i. Joining each row with its 4 neighbours that precede it
  // in storage order visits every such pair once; in one pair of rows, a sweep by end
  // point finds the touching runs (runs of a row are at least 2 apart).
  Components components(runs.size());
  constexpr int kEarlierRows[4][2] = {{-1, 0}, {-1, -1}, {0, -1}, {1, -1}};  // (dj, dk)
  for (int k = 0; k < nz; ++k) {
    for (int j = 0; j < ny; ++j) {
      const int64_t r = j + int64_t{ny} * k;
      for (const auto& [dj, dk] : kEarlierRows) {
        const int jj = j + dj, kk = k + dk;
        if (jj < 0 || jj >= ny || kk < 0) continue;
        const int64_t rr = jj + int64_t{ny} * kk;
        int64_t a = row_begin[r], b = row_begin[rr];
        while (a < row_begin[r + 1] && b < row_begin[rr + 1]) {
          if (runs[a].i0 <= runs[b].i1 + 1 && runs[b].i0 <= runs[a].i1 + 1) {
            components.Join(static_cast<int>(a), static_cast<int>(b));
          }
          if (runs[a].i1 < runs[b].i1) {
            ++a;
          } else {
            ++b;
          }
        }
      }
    }
  }
  std::vector<int64_t> component_voxels(runs.size(), 0);
  for (size_t a = 0; a < runs.size(); ++a) {
    component_voxels[components.Find(static_cast<int>(a))] += runs[a].i1 - runs[a].i0 + 1;
  }
  const int64_t largest =
      runs.empty() ? 0 : *std::max_element(component_voxels.begin(), component_voxels.end());
  // Each row's kept extremes: every kept voxel lies between them, so their centres span
  // the hull of all kept voxels' centres.
  std::vector<int> row_min(num_rows, -1), row_max(num_rows, -1);
  std::vector<Eigen::Vector3i> extremes;
  for (int k = 0; k < nz; ++k) {
    for (int j = 0; j < ny; ++j) {
      const int64_t r = j + int64_t{ny} * k;
      for (int64_t a = row_begin[r]; a < row_begin[r + 1]; ++a) {
        const int64_t voxels = component_voxels[components.Find(static_cast<int>(a))];
        if (static_cast<double>(voxels) < kMinHullComponentFraction * largest) continue;
        if (row_min[r] < 0) row_min[r] = runs[a].i0;
        row_max[r] = runs[a].i1;
      }
      if (row_min[r] < 0) continue;
      extremes.emplace_back(row_min[r], j, k);
      if (row_max[r] != row_min[r]) extremes.emplace_back(row_max[r], j, k);
    }
  }
  if (!SpanThreeDimensions(extremes)) {
    if (why) {
      *why = extremes.empty() ? "no voxel is non-zero"
                              : "the non-zero voxels lie on one plane or line";
    }
    return false;
  }
  std::vector<double> xyz;
  xyz.reserve(3 * extremes.size());
  for (const Eigen::Vector3i& p : extremes) {
    xyz.insert(xyz.end(), {1.0 * p[0], 1.0 * p[1], 1.0 * p[2]});
  }
  std::vector<HalfSpace> half_spaces;
  std::string error;
  if (!ConvexHullHalfSpaces(xyz, &half_spaces, &error)) {
    if (why) *why = error;
    return false;
  }
  // Each row (j, k) meets the hull in one interval of i: the intersection over the facets
  // of {i : n_i i + (n_j j + n_k k + offset) <= slack}.
  Mask out(g, 0);
  for (int k = 0; k < nz; ++k) {
    for (int j = 0; j < ny; ++j) {
      double lo = 0.0, hi = nx - 1.0;
      for (const HalfSpace& h : half_spaces) {
        const double rest = kHullSlackVoxels - (h[1] * j + h[2] * k + h[3]);
        if (h[0] > 0.0) {
          hi = std::min(hi, rest / h[0]);
        } else if (h[0] < 0.0) {
          lo = std::max(lo, rest / h[0]);
        } else if (rest < 0.0) {
          hi = -1.0;
        }
        if (lo > hi) break;
      }
      int i0 = 0, i1 = -1;
      if (lo <= hi) {  // then both lie in [0, nx - 1]
        i0 = static_cast<int>(std::ceil(lo));
        i1 = static_cast<int>(std::floor(hi));
      }
      // The kept voxels are inside whatever the facets' rounding.
      const int64_t r = j + int64_t{ny} * k;
      if (row_min[r] >= 0) {
        if (i0 > i1) {
          i0 = row_min[r];
          i1 = row_max[r];
        } else {
          i0 = std::min(i0, row_min[r]);
          i1 = std::max(i1, row_max[r]);
        }
      }
      if (i0 > i1) continue;
      std::fill(out.voxels.begin() + r * nx + i0, out.voxels.begin() + r * nx + i1 + 1, 1);
    }
  }
  ErodeMask(erosion_voxels, &out);
  *mask = std::move(out);
  return true;
}

Mask FieldOfViewFromImage(const Image& image, const FieldOfViewOptions& options, MaskRule* used) {
  Mask mask;
  if (options.mask_rule == MaskRule::kHull &&
      MaskFromConvexHull(image, options.mask_erosion, &mask, nullptr)) {
    if (used) *used = MaskRule::kHull;
    return mask;
  }
  if (used) *used = MaskRule::kNonZero;
  return MaskFromNonZero(image, options.mask_erosion);
}

}  // namespace dsr
