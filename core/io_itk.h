// The ITK side of image IO, kept free of Eigen: ITK 5.2 bundles its own Eigen 3.3, which
// cannot share a translation unit with the system Eigen 3.4 the rest of dsr uses. Only
// io_itk.cc includes ITK; io_image.cc converts RawVolume to and from dsr::Volume.
#ifndef DSR_CORE_IO_ITK_H_
#define DSR_CORE_IO_ITK_H_

#include <string>
#include <vector>

namespace dsr {
namespace itk_io {

struct RawVolume {
  int size[3] = {0, 0, 0};
  double origin[3] = {0, 0, 0};
  double spacing[3] = {1, 1, 1};
  double direction[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};  // row-major, columns = index axes
  std::vector<float> voxels;                           // x fastest
};

// Reads a scalar 3D image (or 4D with one volume) as float. Errors are one line naming
// `path`: no such file, unsupported extension, unreadable header, non-scalar pixels, 2D,
// 4D with several volumes.
bool Read(const std::string& path, RawVolume* volume, std::string* error);

// Writes `volume` to `path` as float (as_bytes = false) or unsigned char (true). Not
// atomic by itself (callers write to a temporary path).
bool Write(const RawVolume& volume, const std::string& path, bool as_bytes, std::string* error);

}  // namespace itk_io
}  // namespace dsr

#endif  // DSR_CORE_IO_ITK_H_
