// Reading a registration's frames (io/io_frames.h).
#include "dsr/io/io_frames.h"

#include "dsr/io/io_image.h"
#include "dsr/util/parallel.h"

namespace dsr {

bool MaskFromImage(const Image& image,
                   int mask_erosion,
                   const std::string& name,
                   Mask* mask,
                   std::string* error) {
  *mask = MaskFromNonZero(image, mask_erosion);
  if (CountInside(*mask) > 0) return true;
  *error = name + ": no voxel left in the field of view (non-zero voxels eroded by "
           "mask_erosion=" + std::to_string(mask_erosion) + ")";
  return false;
}

bool ReadFrames(const std::vector<std::string>& image_paths,
                const std::vector<std::string>& mask_paths,
                int mask_erosion,
                int num_threads,
                std::vector<Image>* images,
                std::vector<Mask>* masks,
                std::string* error) {
  const int m = static_cast<int>(image_paths.size());
  images->assign(m, Image());
  masks->assign(m, Mask());
  std::vector<std::string> read_errors(m);
  ParallelFor(0, m, num_threads, [&](int64_t i) {
    std::string& e = read_errors[i];
    if (!ReadImage(image_paths[i], &(*images)[i], &e)) return;
    if (!mask_paths.empty()) {
      ReadMask(mask_paths[i], (*images)[i].geometry, &(*masks)[i], &e);
      return;
    }
    MaskFromImage((*images)[i], mask_erosion, image_paths[i], &(*masks)[i], &e);
  });
  for (const std::string& e : read_errors) {
    if (!e.empty()) {
      *error = e;
      return false;
    }
  }
  return true;
}

}  // namespace dsr
