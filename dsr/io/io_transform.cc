#include "dsr/io/io_transform.h"

#include "dsr/io/io_itk.h"
#include "dsr/util/atomic_file.h"

namespace dsr {

bool WriteItkTransform(const Eigen::Isometry3d& frame_from_world,
                       const std::string& path,
                       std::string* error) {
  const bool tfm = path.size() > 4 && (path.compare(path.size() - 4, 4, ".tfm") == 0 ||
                                       path.compare(path.size() - 4, 4, ".txt") == 0);
  if (!tfm) {
    *error = path + ": transform files end in .tfm or .txt";
    return false;
  }
  double matrix[12];
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 4; ++c) matrix[4 * r + c] = frame_from_world.matrix()(r, c);
  return WriteViaTemporaryFile(
      path,
      [&](const std::string& temp, std::string* e) {
        return itk_io::WriteAffineTransform(temp, matrix, e);
      },
      error);
}

bool ReadItkTransform(const std::string& path, Eigen::Affine3d* transform, std::string* error) {
  double matrix[12];
  if (!itk_io::ReadAffineTransform(path, matrix, error)) return false;
  transform->setIdentity();
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 4; ++c) transform->matrix()(r, c) = matrix[4 * r + c];
  return true;
}

}  // namespace dsr
