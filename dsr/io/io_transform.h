// Per-frame transforms for other tools (3D Slicer, ITK/SimpleITK, ANTs, elastix).
//
// ITK resamples a moving image onto a fixed grid by mapping each fixed (output) physical
// point through the transform to the moving image: the file holds fixed -> moving. For
// frame i resampled onto the panorama (world = frame 0's physical space, LPS, mm) that is
// world -> frame i, i.e. T_i = frame_from_world itself (docs/design.md section 1). Written as
// AffineTransform_double_3_3 (a rigid matrix, centre 0), which every ITK-based tool reads.
#ifndef DSR_IO_IO_TRANSFORM_H_
#define DSR_IO_IO_TRANSFORM_H_

#include <string>

#include <Eigen/Geometry>

namespace dsr {

// Writes atomically (temporary file + rename). `path` ends in .tfm or .txt.
bool WriteItkTransform(const Eigen::Isometry3d& frame_from_world,
                       const std::string& path,
                       std::string* error);
// Reads a matrix-offset transform (affine, Euler, versor rigid) as an affine map.
bool ReadItkTransform(const std::string& path, Eigen::Affine3d* transform, std::string* error);

}  // namespace dsr

#endif  // DSR_IO_IO_TRANSFORM_H_
