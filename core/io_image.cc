// Image IO (see io_image.h): validation and conversion around the ITK adapter (io_itk).
#include "core/io_image.h"

#include <algorithm>
#include <cmath>

#include "core/atomic_file.h"
#include "core/io_itk.h"

namespace dsr {
namespace {

bool EndsWith(const std::string& s, const std::string& suffix) {
  return s.size() >= suffix.size() && s.compare(s.size() - suffix.size(), suffix.size(), suffix) == 0;
}

constexpr char kExtensions[] = "use .nii, .nii.gz, .mha, .mhd, .nrrd or .nhdr";

template <typename T>
bool WriteVolume(const Volume<T>& volume, const std::string& path, bool as_bytes, std::string* error) {
  if (!HasSupportedImageExtension(path)) {
    *error = path + ": unsupported extension (" + kExtensions + ")";
    return false;
  }
  if (EndsWith(path, ".mhd") || EndsWith(path, ".nhdr")) {
    // The header names its data file, so renaming a temporary header would break it.
    *error = path + ": detached-header formats (.mhd, .nhdr) are read-only here; write .mha or .nrrd";
    return false;
  }
  itk_io::RawVolume raw;
  for (int a = 0; a < 3; ++a) {
    raw.size[a] = volume.geometry.size[a];
    raw.origin[a] = volume.geometry.origin_mm[a];
    raw.spacing[a] = volume.geometry.spacing_mm[a];
    for (int b = 0; b < 3; ++b) raw.direction[3 * a + b] = volume.geometry.direction(a, b);
  }
  raw.voxels.assign(volume.voxels.begin(), volume.voxels.end());
  return WriteViaTemporaryFile(
      path,
      [&](const std::string& temp, std::string* why) {
        if (itk_io::Write(raw, temp, as_bytes, why)) return true;
        *why = path + why->substr(temp.size());  // name the real output, not the temp file
        return false;
      },
      error);
}

}  // namespace

bool HasSupportedImageExtension(const std::string& path) {
  std::string lower = path;
  std::transform(lower.begin(), lower.end(), lower.begin(), ::tolower);
  for (const char* ext : {".nii", ".nii.gz", ".mha", ".mhd", ".nrrd", ".nhdr"}) {
    if (EndsWith(lower, ext)) return true;
  }
  return false;
}

bool ReadImage(const std::string& path, Image* image, std::string* error) {
  if (!HasSupportedImageExtension(path)) {
    *error = path + ": unsupported extension (" + kExtensions + ")";
    return false;
  }
  itk_io::RawVolume raw;
  if (!itk_io::Read(path, &raw, error)) return false;
  Image out;
  for (int a = 0; a < 3; ++a) {
    out.geometry.size[a] = raw.size[a];
    out.geometry.origin_mm[a] = raw.origin[a];
    out.geometry.spacing_mm[a] = raw.spacing[a];
    for (int b = 0; b < 3; ++b) out.geometry.direction(a, b) = raw.direction[3 * a + b];
  }
  if (!out.geometry.Validate(path, error)) return false;
  out.voxels = std::move(raw.voxels);
  const int64_t nx = out.geometry.size[0], nxy = nx * out.geometry.size[1];
  for (int64_t v = 0; v < static_cast<int64_t>(out.voxels.size()); ++v) {
    if (!std::isfinite(out.voxels[v])) {
      *error = path + ": voxel (" + std::to_string(v % nx) + "," + std::to_string((v % nxy) / nx) +
               "," + std::to_string(v / nxy) + ") is " + (std::isnan(out.voxels[v]) ? "NaN" : "Inf");
      return false;
    }
  }
  *image = std::move(out);
  return true;
}

bool ReadMask(const std::string& path,
              const ImageGeometry& expected,
              Mask* mask,
              std::string* error) {
  Image image;
  if (!ReadImage(path, &image, error)) return false;
  if (image.geometry.size != expected.size) {
    *error = path + ": mask grid " + image.geometry.DebugString() +
             " does not match the image grid " + expected.DebugString();
    return false;
  }
  if (!image.geometry.SameGrid(expected)) {
    *error = path + ": mask origin/spacing/direction differ from the image's (" +
             image.geometry.DebugString() + " vs " + expected.DebugString() + ")";
    return false;
  }
  Mask out(expected, 0);
  int64_t inside = 0;
  for (size_t v = 0; v < image.voxels.size(); ++v) {
    out.voxels[v] = image.voxels[v] != 0.0f;
    inside += out.voxels[v];
  }
  if (inside == 0) {
    *error = path + ": mask has no voxel inside the field of view";
    return false;
  }
  *mask = std::move(out);
  return true;
}

bool WriteImage(const Image& image, const std::string& path, std::string* error) {
  return WriteVolume(image, path, false, error);
}

bool WriteMask(const Mask& mask, const std::string& path, std::string* error) {
  return WriteVolume(mask, path, true, error);
}

}  // namespace dsr
