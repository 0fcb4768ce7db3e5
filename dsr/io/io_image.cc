// Image and mask IO (see io_image.h): the rules around the ITK adapter (io_itk.h), which
// cannot see Eigen. Geometry is validated with ImageGeometry::Validate from the header,
// before any voxel is read; voxels must be finite; masks must lie on the image's grid and
// contain at least one inside voxel; writes are verified by reading them back (io_itk.h,
// VerifyWritten) and atomic (atomic_file.h), so a failed write never replaces a file.
// The rules io_phases.cc shares are in io_internal (io_image_internal.h).
#include "dsr/io/io_image.h"

#include <zlib.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <sstream>

#include <glog/logging.h>

#include "dsr/io/io_image_internal.h"
#include "dsr/io/io_itk.h"
#include "dsr/util/atomic_file.h"
#include "dsr/util/text.h"

namespace dsr {
namespace {

constexpr const char* kSupportedExtensions[] = {
    ".nii", ".nii.gz", ".mha", ".mhd", ".nrrd", ".nhdr"};

}  // namespace

namespace io_internal {

std::string UnsupportedExtension(const std::string& path) {
  std::string list;
  for (const char* ext : kSupportedExtensions) {
    list += (list.empty() ? "" : ", ") + std::string(ext);
  }
  return path + ": unsupported extension (supported: " + list + ")";
}

ImageGeometry ToGeometry(const itk_io::RawVolume& raw) {
  ImageGeometry geometry;
  for (int a = 0; a < 3; ++a) {
    geometry.size[a] = raw.size[a];
    geometry.origin_mm[a] = raw.origin[a];
    geometry.spacing_mm[a] = raw.spacing[a];
    for (int b = 0; b < 3; ++b) geometry.direction(a, b) = raw.direction[3 * a + b];
  }
  return geometry;
}

itk_io::RawVolume ToRaw(const ImageGeometry& geometry) {
  itk_io::RawVolume raw;
  for (int a = 0; a < 3; ++a) {
    raw.size[a] = geometry.size[a];
    raw.origin[a] = geometry.origin_mm[a];
    raw.spacing[a] = geometry.spacing_mm[a];
    for (int b = 0; b < 3; ++b) raw.direction[3 * a + b] = geometry.direction(a, b);
  }
  return raw;
}

}  // namespace io_internal

namespace {

using io_internal::IsNifti;
using io_internal::ToGeometry;
using io_internal::ToRaw;
using io_internal::UnsupportedExtension;

std::string Triple(const Eigen::Vector3d& v) {
  std::ostringstream s;
  s << v[0] << "," << v[1] << "," << v[2];
  return s.str();
}

// Why `mask` is not on `image` (same size assumed): the first of origin, spacing and
// direction that is beyond ImageGeometry::SameGrid's tolerance.
std::string GridDifference(const ImageGeometry& mask, const ImageGeometry& image) {
  ImageGeometry moved = mask;
  moved.origin_mm = image.origin_mm;
  if (!mask.SameGrid(moved)) {
    return "origin " + Triple(mask.origin_mm) + " mm vs " + Triple(image.origin_mm) + " mm";
  }
  ImageGeometry scaled = mask;
  scaled.spacing_mm = image.spacing_mm;
  if (!mask.SameGrid(scaled)) {
    return "spacing " + Triple(mask.spacing_mm) + " mm vs " + Triple(image.spacing_mm) + " mm";
  }
  std::ostringstream s;
  s << "direction differs by up to " << (mask.direction - image.direction).cwiseAbs().maxCoeff();
  return s.str();
}

template <typename T>
bool WriteVolume(const Volume<T>& volume,
                 const std::string& path,
                 itk_io::PixelType pixel_type,
                 std::string* error) {
  CHECK_EQ(static_cast<int64_t>(volume.voxels.size()), volume.geometry.NumVoxels())
      << "volume written to " << path << " has a voxel count that does not match its grid";
  if (!HasSupportedImageExtension(path)) {
    *error = UnsupportedExtension(path);
    return false;
  }
  std::string why;
  if (!volume.geometry.Validate("grid", &why)) {
    *error = path + ": cannot write an image with an invalid " + why;
    return false;
  }
  itk_io::RawVolume raw = ToRaw(volume.geometry);
  raw.voxels.resize(volume.voxels.size());
  if (pixel_type == itk_io::PixelType::kUint8) {  // masks: non-zero is inside, stored as 1
    std::transform(volume.voxels.begin(), volume.voxels.end(), raw.voxels.begin(), [](T v) {
      return v != T{0} ? 1.0f : 0.0f;
    });
  } else {
    std::copy(volume.voxels.begin(), volume.voxels.end(), raw.voxels.begin());
  }
  const std::string ext = Lower(path);
  // .nii is never compressed (NIfTI takes it from the name); .mhd/.nhdr keep raw data
  // files, which other tools often map directly.
  const bool compress = EndsWith(ext, ".nii.gz") || EndsWith(ext, ".mha") || EndsWith(ext, ".nrrd");
  const auto write = [&](const std::string& temp, std::string* write_error) {
    return itk_io::Write(raw, temp, pixel_type, compress, write_error);
  };
  // A detached header names its data file after itself, so it cannot be written under a
  // temporary name and renamed: it is written with its final name in a temporary folder.
  if (EndsWith(ext, ".mhd") || EndsWith(ext, ".nhdr")) {
    return WriteFilesViaTemporaryFolder(path, write, error);
  }
  return WriteViaTemporaryFile(path, write, error);
}

}  // namespace

bool HasSupportedImageExtension(const std::string& path) {
  const std::string lower = Lower(path);
  return std::any_of(std::begin(kSupportedExtensions),
                     std::end(kSupportedExtensions),
                     [&](const char* ext) { return EndsWith(lower, ext); });
}

namespace io_internal {

// A NIfTI header's pixdim[1..3] of 0, which ITK reads as a spacing of 1 mm (a negative one
// it refuses): "" when the file is no NIfTI-1/2 file or its spacings are not 0. The header
// is read through zlib, which reads .nii and .nii.gz alike.
bool IsNifti(const std::string& path) {
  const std::string lower = Lower(path);
  return EndsWith(lower, ".nii") || EndsWith(lower, ".nii.gz");
}

// A NIfTI header stores the origin in float32: far from 0 its precision (half the gap to
// the next float) exceeds half a voxel, and the file no longer places the frame where it
// was (frames of one sequence move against each other). Refused, naming the magnitude.
bool CheckNiftiOriginPrecision(const std::string& path, const ImageGeometry& g,
                               std::string* error) {
  const double half_voxel = 0.5 * g.spacing_mm.minCoeff();
  for (int d = 0; d < 3; ++d) {
    const float stored = static_cast<float>(g.origin_mm[d]);
    const double precision =
        0.5 * (std::nextafter(std::abs(stored), std::numeric_limits<float>::infinity()) -
               std::abs(stored));
    if (precision <= half_voxel) continue;
    std::ostringstream text;
    text << path << ": origin " << g.origin_mm[d] << " mm (axis " << d << ") is so far from 0 "
         << "that a NIfTI header, which stores it in float32, holds it only to +/-" << precision
         << " mm, more than half a voxel (" << half_voxel << " mm): the file cannot place the "
         << "frame; move the origin nearer 0, or store the frames as .nrrd or .mha";
    *error = text.str();
    return false;
  }
  return true;
}

std::string ZeroNiftiSpacing(const std::string& path) {
  if (!IsNifti(path)) return "";
  gzFile file = gzopen(path.c_str(), "rb");
  if (file == nullptr) return "";
  unsigned char header[540];
  const int got = gzread(file, header, sizeof(header));
  gzclose(file);
  if (got < 348) return "";
  int32_t size;
  std::memcpy(&size, header, 4);
  const bool swapped = size != 348 && size != 540;
  if (swapped) size = static_cast<int32_t>(__builtin_bswap32(static_cast<uint32_t>(size)));
  if ((size != 348 && size != 540) || got < size) return "";
  for (int d = 1; d <= 3; ++d) {
    double pixdim = 0.0;
    if (size == 348) {  // NIfTI-1: float32 pixdim[8] at byte 76
      uint32_t bits;
      std::memcpy(&bits, header + 76 + 4 * d, 4);
      if (swapped) bits = __builtin_bswap32(bits);
      float value;
      std::memcpy(&value, &bits, 4);
      pixdim = value;
    } else {  // NIfTI-2: double pixdim[8] at byte 104
      uint64_t bits;
      std::memcpy(&bits, header + 104 + 8 * d, 8);
      if (swapped) bits = __builtin_bswap64(bits);
      std::memcpy(&pixdim, &bits, 8);
    }
    if (pixdim == 0.0) {
      return "pixdim[" + std::to_string(d) + "] is 0 in the NIfTI header: the voxel spacing "
             "must be finite and > 0 (a reader would take 1 mm)";
    }
  }
  return "";
}

bool MaskFromImage(const std::string& path,
                   const Image& image,
                   const ImageGeometry& expected,
                   Mask* mask,
                   std::string* error) {
  if (image.geometry.size != expected.size) {
    *error = path + ": mask grid " + image.geometry.DebugString() +
             " does not match the image grid " + expected.DebugString();
    return false;
  }
  if (!image.geometry.SameGrid(expected)) {
    *error = path + ": mask grid does not match the image grid (" +
             GridDifference(image.geometry, expected) + ")";
    return false;
  }
  Mask out(expected, 0);
  int64_t inside = 0;
  for (size_t v = 0; v < image.voxels.size(); ++v) {
    out.voxels[v] = image.voxels[v] != 0.0f ? 1 : 0;
    inside += out.voxels[v];
  }
  if (inside == 0) {
    *error = path + ": mask has no voxel inside (every voxel is 0)";
    return false;
  }
  *mask = std::move(out);
  return true;
}

bool ReadImage(const std::string& path, Image* image, std::string* error, bool* constant) {
  if (!HasSupportedImageExtension(path)) {
    *error = UnsupportedExtension(path);
    return false;
  }
  const std::string zero_spacing = io_internal::ZeroNiftiSpacing(path);
  if (!zero_spacing.empty()) {
    *error = path + ": " + zero_spacing;
    return false;
  }
  const bool nifti = IsNifti(path);
  itk_io::RawVolume raw;
  const auto check_header = [&](const itk_io::RawVolume& header, std::string* header_error) {
    return ToGeometry(header).Validate(path, header_error);
  };
  if (!itk_io::Read(path, check_header, &raw, error)) return false;
  Image out;
  out.geometry = ToGeometry(raw);
  if (nifti && !io_internal::CheckNiftiOriginPrecision(path, out.geometry, error)) return false;
  out.voxels = std::move(raw.voxels);
  if (raw.checked_finite) {
    if (constant != nullptr) *constant = raw.constant;
  } else if (!CheckFiniteVoxels(out, path, error, constant)) {
    return false;
  }
  *image = std::move(out);
  return true;
}

}  // namespace io_internal

bool ReadImage(const std::string& path, Image* image, std::string* error) {
  return io_internal::ReadImage(path, image, error, nullptr);
}

bool ReadMask(const std::string& path,
              const ImageGeometry& expected,
              Mask* mask,
              std::string* error) {
  Image image;
  if (!ReadImage(path, &image, error)) return false;
  return io_internal::MaskFromImage(path, image, expected, mask, error);
}

bool ImageDataFiles(const std::string& path, std::vector<std::string>* files, std::string* error) {
  return itk_io::DataFiles(path, files, error);
}

std::vector<std::string> WrittenImageFiles(const std::string& path) {
  // MetaIO replaces the header's suffix by "raw" (".zraw" if compressed, which .mhd never
  // is here); teem drops ".nhdr" and appends ".raw". Both match the suffix
  // case-sensitively, so "X.NHDR" is one attached file (and "X.MHD" is refused).
  for (const char* detached : {".mhd", ".nhdr"}) {
    if (EndsWith(path, detached)) {
      return {path, path.substr(0, path.size() - std::strlen(detached)) + ".raw"};
    }
  }
  return {path};
}

bool WriteImage(const Image& image, const std::string& path, std::string* error) {
  return WriteVolume(image, path, itk_io::PixelType::kFloat, error);
}

bool WriteMask(const Mask& mask, const std::string& path, std::string* error) {
  return WriteVolume(mask, path, itk_io::PixelType::kUint8, error);
}

}  // namespace dsr
