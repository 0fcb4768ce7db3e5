// io/'s own helpers shared by io_image.cc and io_phases.cc (defined in io_image.cc): the
// rules ReadImage and ReadMask apply, so that phases are read by the same ones. Not for use
// outside dsr/io.
#ifndef DSR_IO_IO_IMAGE_INTERNAL_H_
#define DSR_IO_IO_IMAGE_INTERNAL_H_

#include <string>

#include "dsr/geometry/volume.h"
#include "dsr/io/io_itk.h"

namespace dsr {
namespace io_internal {

// "<path>: unsupported extension (supported: ...)".
std::string UnsupportedExtension(const std::string& path);

ImageGeometry ToGeometry(const itk_io::RawVolume& raw);
itk_io::RawVolume ToRaw(const ImageGeometry& geometry);  // voxels empty

// .nii or .nii.gz (any case).
bool IsNifti(const std::string& path);
// Why a NIfTI header's pixdim[1..3] cannot be used ("" when it can or `path` is no NIfTI).
std::string ZeroNiftiSpacing(const std::string& path);
// Refuses a NIfTI grid whose float32 origin cannot place it to half a voxel.
bool CheckNiftiOriginPrecision(const std::string& path, const ImageGeometry& g,
                               std::string* error);

// ReadImage, with `constant` (when not null) telling whether every voxel holds one value,
// found by the finite-voxel check's own pass.
bool ReadImage(const std::string& path, Image* image, std::string* error, bool* constant);

// ReadMask's rules for an image read from `path`: on `expected`'s grid (same size, then
// ImageGeometry::SameGrid), non-zero = inside, at least one voxel inside.
bool MaskFromImage(const std::string& path,
                   const Image& image,
                   const ImageGeometry& expected,
                   Mask* mask,
                   std::string* error);

}  // namespace io_internal
}  // namespace dsr

#endif  // DSR_IO_IO_IMAGE_INTERNAL_H_
