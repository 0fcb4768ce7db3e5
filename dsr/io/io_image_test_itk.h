// Test-only writers that call ITK directly, to make files dsr never writes itself
// (integer pixels, 2D, 4D, vector pixels). Kept free of Eigen, like io/io_itk.h: ITK 5.2
// bundles its own Eigen, which cannot share a translation unit with the system one.
#ifndef DSR_IO_IO_IMAGE_TEST_ITK_H_
#define DSR_IO_IO_IMAGE_TEST_ITK_H_

#include <string>
#include <vector>

namespace dsr {
namespace test_itk {

enum class Pixel { kUint8, kInt16, kFloat, kDouble };

// Geometry of the first three axes; extra axes (4D) get spacing 1, origin 0, identity.
struct Grid {
  std::vector<int> size;  // 2, 3 or 4 entries
  double origin[3] = {0, 0, 0};
  double spacing[3] = {1, 1, 1};
  double direction[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};  // row-major, columns = index axes
};

// Writes a scalar image whose voxel v (x fastest) is values[v], cast to `pixel`. The
// format follows the extension. Returns "" on success, else ITK's message.
std::string WriteScalarImage(const std::string& path,
                             const Grid& grid,
                             Pixel pixel,
                             const std::vector<double>& values);

// Writes a 3D image of itk::Vector<float, 3> pixels (all equal to (1, 2, 3)).
std::string WriteVectorImage(const std::string& path, const Grid& grid);

// Reads every phase of a 4D image through ITK's own reader (itk::ImageFileReader, float
// pixels), independently of dsr's reader: a scalar 4D image volume by volume along its 4th
// axis, a 3D image of vector pixels (a NRRD list axis) component by component. Voxels x
// fastest. Returns "" on success, else ITK's message.
std::string ReadPhasesWithItk(const std::string& path, std::vector<std::vector<float>>* phases);

// Resamples the 3D image in `image_path` onto `grid` (3 sizes) with the transform in
// `transform_path` (read by itk::TransformFileReader, fixed -> moving), linear
// interpolation, 0 outside: what Slicer/ANTs/SimpleITK do with that pair. Voxels x fastest.
// Returns "" on success, else ITK's message.
std::string ResampleWithTransformFile(const std::string& image_path,
                                      const std::string& transform_path,
                                      const Grid& grid,
                                      std::vector<float>* voxels);

}  // namespace test_itk
}  // namespace dsr

#endif  // DSR_IO_IO_IMAGE_TEST_ITK_H_
