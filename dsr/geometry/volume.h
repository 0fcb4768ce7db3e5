// A 3D scalar volume on a physical grid (docs/design.md section 1).
//
// Geometry: size (voxels along index axes i, j, k = ITK index[0..2]), origin o (mm),
// spacing S (mm, diagonal) and direction D (3x3, columns = index axes in physical space).
// The physical point of continuous index u is x = o + D S u (ITK/LPS convention).
// Voxels are stored x-fastest: linear = i + size[0] * (j + size[1] * k).
#ifndef DSR_GEOMETRY_VOLUME_H_
#define DSR_GEOMETRY_VOLUME_H_

#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "dsr/util/huge_pages.h"

namespace dsr {

struct ImageGeometry {
  Eigen::Vector3i size = Eigen::Vector3i::Zero();
  Eigen::Vector3d origin_mm = Eigen::Vector3d::Zero();
  Eigen::Vector3d spacing_mm = Eigen::Vector3d::Ones();
  Eigen::Matrix3d direction = Eigen::Matrix3d::Identity();

  int64_t NumVoxels() const {
    return int64_t{size[0]} * int64_t{size[1]} * int64_t{size[2]};
  }
  int64_t LinearIndex(int i, int j, int k) const {
    return i + int64_t{size[0]} * (j + int64_t{size[1]} * k);
  }
  // D S: maps an index offset to a physical offset.
  Eigen::Matrix3d IndexToPhysicalMatrix() const {
    return direction * spacing_mm.asDiagonal();
  }
  // S^-1 D^-1 (D^-1 = D^T only for orthonormal directions; the inverse is used).
  Eigen::Matrix3d PhysicalToIndexMatrix() const {
    return IndexToPhysicalMatrix().inverse();
  }
  Eigen::Vector3d IndexToPhysical(const Eigen::Vector3d& ijk) const {
    return origin_mm + IndexToPhysicalMatrix() * ijk;
  }
  Eigen::Vector3d PhysicalToIndex(const Eigen::Vector3d& xyz_mm) const {
    return PhysicalToIndexMatrix() * (xyz_mm - origin_mm);
  }
  // The affine map index -> physical as a 4x4 (for IO and resampling).
  Eigen::Isometry3d PhysicalFromIndexRigidPart() const;

  // True when both describe the same voxel grid, up to `tolerance_mm` in origin and
  // spacing and 1e-6 in direction.
  bool SameGrid(const ImageGeometry& other, double tolerance_mm = 1e-4) const;

  // Checks that the grid is usable: every size >= 1, finite positive spacing, finite
  // origin, direction orthonormal within 1e-4 (ITK's own tolerance is similar). On
  // failure `error` names the broken rule; `what` prefixes it (e.g. the file name).
  bool Validate(const std::string& what, std::string* error) const;

  std::string DebugString() const;
};

template <typename T>
struct Volume {
  ImageGeometry geometry;
  std::vector<T> voxels;

  Volume() = default;
  explicit Volume(const ImageGeometry& g, T fill = T{}) : geometry(g) {
    AssignWithHugePages(&voxels, static_cast<size_t>(g.NumVoxels()), fill);
  }

  T& at(int i, int j, int k) { return voxels[geometry.LinearIndex(i, j, k)]; }
  const T& at(int i, int j, int k) const {
    return voxels[geometry.LinearIndex(i, j, k)];
  }
  bool empty() const { return voxels.empty(); }
};

using Image = Volume<float>;   // intensities
using Mask = Volume<uint8_t>;  // field of view: 1 inside, 0 outside

// "voxel (i,j,k)" for the voxel at `linear` (x-fastest) of a grid nx voxels wide and ny
// high, as error messages name voxels.
std::string VoxelName(int64_t linear, int64_t nx, int64_t ny);

// Checks that every voxel is finite (the registration's sums take no NaN or Inf). On
// failure `error` names the first bad voxel by index, "<what>: voxel (i,j,k) is NaN". The
// front ends check what they read or are given (io_image's ReadImage, the Python module).
// With `constant` (may be null), also tells in the same pass whether every voxel holds one
// value (0 for a blank image; false for no voxel), set when the check passes.
bool CheckFiniteVoxels(const Image& image,
                       const std::string& what,
                       std::string* error,
                       bool* constant = nullptr);

// A field-of-view mask from an image that is zero outside its field of view: 1 except at
// the zero voxels connected to the grid border through zero voxels (so zeros enclosed by
// non-zero data, e.g. noise clamped at 0, stay inside), then eroded by `erosion_voxels` voxels
// (6-connected structuring element applied `erosion_voxels` times along each axis, i.e.
// a box of half-width `erosion_voxels`). Voxels on the image border count as outside.
Mask MaskFromNonZero(const Image& image, int erosion_voxels);

// Erodes `mask` by a box of half-width `erosion_voxels` (MaskFromNonZero's erosion; voxels
// within `erosion_voxels` of the grid border become outside). 0 leaves it as it is.
void ErodeMask(int erosion_voxels, Mask* mask);

// Number of voxels with mask != 0.
int64_t CountInside(const Mask& mask);

}  // namespace dsr

#endif  // DSR_GEOMETRY_VOLUME_H_
