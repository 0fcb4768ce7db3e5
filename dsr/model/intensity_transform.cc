#include "dsr/model/intensity_transform.h"

#include <algorithm>
#include <sstream>

#include "dsr/util/option_fields.h"

namespace dsr {

bool StringToIntensityTransform(const std::string& name, IntensityTransform* transform) {
  return FindNamed(name, {IntensityTransform::kNone, IntensityTransform::kSqrt},
                   IntensityTransformToString, transform);
}

double IntensityTransformScale(const std::vector<Image>& images, const std::vector<Mask>& masks) {
  double scale = 0.0;
  for (size_t i = 0; i < images.size(); ++i) {
    for (size_t l = 0; l < images[i].voxels.size(); ++l) {
      if (masks[i].voxels[l] != 0) scale = std::max(scale, double{images[i].voxels[l]});
    }
  }
  return scale;
}

std::vector<Photometric> PhotometricOnInputScale(const std::vector<Photometric>& on_transform,
                                                 const std::vector<Image>& images,
                                                 const std::vector<Mask>& masks, double scale) {
  std::vector<Photometric> start(on_transform.size());
  for (size_t i = 1; i < on_transform.size(); ++i) {
    double sum = 0.0;
    int64_t count = 0;
    for (size_t l = 0; l < images[i].voxels.size(); ++l) {
      if (masks[i].voxels[l] == 0) continue;
      sum += images[i].voxels[l];
      ++count;
    }
    const double mean = count > 0 ? sum / count : 0.0;
    if (!(mean > 0.0 && scale > 0.0)) continue;
    double gain = 1.0, offset = 0.0;
    GainAndOffsetOnInputScale(on_transform[i].gain(), on_transform[i].offset, mean, scale, &gain,
                              &offset);
    if (gain > 0.0 && std::isfinite(gain) && std::isfinite(offset)) {
      start[i] = {std::log(gain), offset};
    }
  }
  return start;
}

bool ApplyIntensityTransform(const std::vector<Image>& images,
                             const std::vector<Mask>& masks,
                             IntensityTransform transform,
                             double scale,
                             std::vector<Image>* transformed,
                             std::string* error) {
  *transformed = images;
  if (transform == IntensityTransform::kNone) return true;
  for (size_t i = 0; i < images.size(); ++i) {
    const Image& image = images[i];
    for (size_t l = 0; l < image.voxels.size(); ++l) {
      if (masks[i].voxels[l] == 0 || image.voxels[l] >= 0.0f) continue;
      std::ostringstream s;
      s << "frame " << i << " has a negative intensity (" << image.voxels[l] << ") at "
        << VoxelName(static_cast<int64_t>(l), image.geometry.size[0], image.geometry.size[1])
        << " inside its mask: intensity_transform=" << IntensityTransformToString(transform)
        << " needs intensities >= 0";
      *error = s.str();
      return false;
    }
  }
  for (Image& image : *transformed) {
    for (float& v : image.voxels) {
      v = static_cast<float>(ForwardIntensity(std::max(0.0, double{v}), scale));
    }
  }
  return true;
}

}  // namespace dsr
