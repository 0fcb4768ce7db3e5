#include "dsr/geometry/volume.h"

#include <algorithm>
#include <vector>
#include <cmath>
#include <limits>
#include <sstream>

namespace dsr {

Eigen::Isometry3d ImageGeometry::PhysicalFromIndexRigidPart() const {
  Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
  t.linear() = direction;
  t.translation() = origin_mm;
  return t;
}

bool ImageGeometry::SameGrid(const ImageGeometry& other, double tolerance_mm) const {
  return size == other.size &&
         (origin_mm - other.origin_mm).cwiseAbs().maxCoeff() <= tolerance_mm &&
         (spacing_mm - other.spacing_mm).cwiseAbs().maxCoeff() <= tolerance_mm &&
         (direction - other.direction).cwiseAbs().maxCoeff() <= 1e-6;
}

std::string VoxelName(int64_t linear, int64_t nx, int64_t ny) {
  const int64_t nxy = nx * ny;
  return "voxel (" + std::to_string(linear % nx) + "," + std::to_string((linear % nxy) / nx) + "," +
         std::to_string(linear / nxy) + ")";
}

namespace {

std::string NotFinite(const Image& image, size_t v, const std::string& what) {
  return what + ": " + VoxelName(static_cast<int64_t>(v), image.geometry.size[0],
                                 image.geometry.size[1]) +
         " is " + (std::isnan(image.voxels[v]) ? "NaN" : "Inf");
}

}  // namespace

bool CheckFiniteVoxels(const Image& image,
                       const std::string& what,
                       std::string* error,
                       bool* constant) {
  // Chunks of branch-free integer reductions, which the compiler vectorises: at -O3 this
  // pass took less time than a std::find_if for the first non-finite voxel.
  constexpr size_t kChunk = 4096;
  const float* x = image.voxels.data();
  const size_t n = image.voxels.size();
  const float first = n > 0 ? x[0] : 0.0f;
  int differs = 0;
  for (size_t begin = 0; begin < n; begin += kChunk) {
    const size_t end = std::min(n, begin + kChunk);
    int bad = 0;
    for (size_t v = begin; v < end; ++v) {
      bad |= std::fabs(x[v]) <= std::numeric_limits<float>::max() ? 0 : 1;  // NaN: 1
      differs |= x[v] != first ? 1 : 0;
    }
    if (bad != 0) {
      size_t v = begin;
      while (std::isfinite(x[v])) ++v;
      *error = NotFinite(image, v, what);
      return false;
    }
  }
  if (constant != nullptr) *constant = n > 0 && differs == 0;
  return true;
}

bool ImageGeometry::Validate(const std::string& what, std::string* error) const {
  auto fail = [&](const std::string& message) {
    if (error) *error = what + ": " + message;
    return false;
  };
  for (int a = 0; a < 3; ++a) {
    if (size[a] < 1) return fail("size " + DebugString() + ": every dimension must be >= 1");
    if (!std::isfinite(spacing_mm[a]) || spacing_mm[a] <= 0.0) {
      std::ostringstream s;
      s << "spacing " << spacing_mm.transpose() << ": must be finite and > 0";
      return fail(s.str());
    }
    if (!std::isfinite(origin_mm[a])) return fail("origin is not finite");
  }
  if (!direction.allFinite()) return fail("direction is not finite");
  const double orthonormality =
      (direction.transpose() * direction - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff();
  if (orthonormality > 1e-4 || std::abs(std::abs(direction.determinant()) - 1.0) > 1e-4) {
    return fail("direction matrix is singular or not orthonormal (|D^T D - I| = " +
                std::to_string(orthonormality) + ")");
  }
  return true;
}

std::string ImageGeometry::DebugString() const {
  std::ostringstream s;
  s << size[0] << "x" << size[1] << "x" << size[2] << " voxels, spacing "
    << spacing_mm[0] << "," << spacing_mm[1] << "," << spacing_mm[2] << " mm, origin "
    << origin_mm[0] << "," << origin_mm[1] << "," << origin_mm[2] << " mm";
  return s.str();
}

namespace {

// One pass of a 1D erosion of half-width r along axis `axis` (voxels within r of an
// outside voxel or the border become outside).
void ErodeAlongAxis(int axis, int r, Mask* mask) {
  const Eigen::Vector3i n = mask->geometry.size;
  const int len = n[axis];
  std::vector<uint8_t> line(len), out(len);
  std::vector<int> last_outside(len);
  Eigen::Vector3i idx;
  const int a1 = (axis + 1) % 3, a2 = (axis + 2) % 3;
  for (int p = 0; p < n[a1]; ++p) {
    for (int q = 0; q < n[a2]; ++q) {
      idx[a1] = p;
      idx[a2] = q;
      for (int t = 0; t < len; ++t) {
        idx[axis] = t;
        line[t] = mask->at(idx[0], idx[1], idx[2]);
      }
      // A voxel survives when every voxel within [t - r, t + r] is inside the volume
      // and inside the mask: check via distance to the nearest outside voxel.
      int prev_outside = -1;  // the border: a virtual outside voxel at -1
      for (int t = 0; t < len; ++t) {
        if (!line[t]) prev_outside = t;
        last_outside[t] = prev_outside;
      }
      int next_outside = len;
      for (int t = len - 1; t >= 0; --t) {
        if (!line[t]) next_outside = t;
        out[t] = (t - last_outside[t] > r && next_outside - t > r) ? 1 : 0;
      }
      for (int t = 0; t < len; ++t) {
        idx[axis] = t;
        mask->at(idx[0], idx[1], idx[2]) = out[t];
      }
    }
  }
}

}  // namespace

Mask MaskFromNonZero(const Image& image, int erosion_voxels) {
  // Outside: the zero voxels connected to the grid border through zero voxels (6-neighbour
  // flood fill); every other voxel is inside, so zeros enclosed by data (noise clamped at
  // 0, dark anatomy) do not punch holes that the erosion would widen 27-fold.
  const ImageGeometry& g = image.geometry;
  Mask mask(g, 1);
  std::vector<int64_t> stack;
  const auto visit = [&](int i, int j, int k) {
    const int64_t l = g.LinearIndex(i, j, k);
    if (mask.voxels[l] == 0 || image.voxels[l] != 0.0f) return;
    mask.voxels[l] = 0;
    stack.push_back(l);
  };
  for (int k = 0; k < g.size[2]; ++k) {
    for (int j = 0; j < g.size[1]; ++j) {
      for (int i = 0; i < g.size[0]; ++i) {
        const bool border = i == 0 || j == 0 || k == 0 || i == g.size[0] - 1 ||
                            j == g.size[1] - 1 || k == g.size[2] - 1;
        if (border) visit(i, j, k);
      }
    }
  }
  while (!stack.empty()) {
    const int64_t l = stack.back();
    stack.pop_back();
    const int i = static_cast<int>(l % g.size[0]);
    const int j = static_cast<int>((l / g.size[0]) % g.size[1]);
    const int k = static_cast<int>(l / (int64_t{g.size[0]} * g.size[1]));
    if (i > 0) visit(i - 1, j, k);
    if (i + 1 < g.size[0]) visit(i + 1, j, k);
    if (j > 0) visit(i, j - 1, k);
    if (j + 1 < g.size[1]) visit(i, j + 1, k);
    if (k > 0) visit(i, j, k - 1);
    if (k + 1 < g.size[2]) visit(i, j, k + 1);
  }
  ErodeMask(erosion_voxels, &mask);
  return mask;
}

void ErodeMask(int erosion_voxels, Mask* mask) {
  if (erosion_voxels <= 0) return;
  for (int axis = 0; axis < 3; ++axis) ErodeAlongAxis(axis, erosion_voxels, mask);
}

int64_t CountInside(const Mask& mask) {
  return std::count_if(mask.voxels.begin(), mask.voxels.end(), [](uint8_t m) { return m != 0; });
}

}  // namespace dsr
