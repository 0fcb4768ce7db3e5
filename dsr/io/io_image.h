// Image and mask IO through ITK: NIfTI (.nii, .nii.gz), MetaImage (.mha, .mhd) and NRRD
// (.nrrd, .nhdr). Geometry (size, origin, spacing, direction) is copied as stored: exactly
// for MetaImage, to double rounding for NRRD (it stores D S, not D), to float32 precision
// for NIfTI (its header is float32). Any scalar pixel type is converted to float on read.
// Only io/ includes ITK.
//
// Every function returns false with a one-line `error` that names the file and the broken
// rule (missing file, not 3D, non-scalar pixels, corrupt header, truncated or corrupt data,
// NaN/Inf voxels, invalid geometry, mask on another grid, ...). Writes go to a temporary
// file in the target folder, are read back and checked to be complete (header and exact
// data size; compressed data fully decompressed), and only then renamed into place: a
// failed write (disk full, file-size limit) or an interrupted run never replaces a previous
// file with a truncated one. .nii.gz, .mha and .nrrd are written compressed; .nii, .mhd and
// .nhdr uncompressed (.mhd/.nhdr write a "<name>.raw" data file next to the header).
// 4D images (one 3D volume per heart phase) are read and written by io_phases.h.
#ifndef DSR_IO_IO_IMAGE_H_
#define DSR_IO_IO_IMAGE_H_

#include <string>
#include <vector>

#include "dsr/geometry/volume.h"

namespace dsr {

// Reads a 3D scalar image (any integer or float pixel type) as float. Rejects 2D and 4D+
// images (a 4D image with a last dimension of size 1 is accepted as 3D), vector/complex
// pixels, invalid geometry and non-finite voxel values.
bool ReadImage(const std::string& path, Image* image, std::string* error);

// Reads a mask (any scalar pixel type, non-zero = inside) and checks that it lies on
// `expected` (the image's grid): size must match exactly, origin/spacing/direction within
// ImageGeometry::SameGrid's tolerance. Rejects a mask with no inside voxel.
bool ReadMask(const std::string& path,
              const ImageGeometry& expected,
              Mask* mask,
              std::string* error);

// Writes float voxels (the format follows the extension). Atomic (temp file + rename).
bool WriteImage(const Image& image, const std::string& path, std::string* error);
// Writes a mask as unsigned char 0/1. Atomic.
bool WriteMask(const Mask& mask, const std::string& path, std::string* error);

// True for the extensions ITK can read/write here: .nii .nii.gz .mha .mhd .nrrd .nhdr.
bool HasSupportedImageExtension(const std::string& path);

// Every file an image at `path` consists of: `path` itself plus, for detached-header
// formats, the data file(s) its header names (.mhd ElementDataFile, including each LIST
// slice file; .nhdr data file(s); .hdr -> .img). Paths as given (not canonicalised), for
// existing inputs. Returns false with `error` naming the file when the header cannot be read.
bool ImageDataFiles(const std::string& path, std::vector<std::string>* files, std::string* error);
// Every file WriteImage/WriteMask(…, path) creates or replaces: `path` plus its data file
// for detached formats, as ITK 5.2 names it: "<stem>.mhd" -> "<stem>.raw" and
// "<stem>.nhdr" -> "<stem>.raw" (both written uncompressed, so never ".zraw"/".raw.gz").
// The suffixes are matched case-sensitively, as ITK does: "X.NHDR" is written as one
// attached NRRD file. Pure name arithmetic: nothing is read.
std::vector<std::string> WrittenImageFiles(const std::string& path);

}  // namespace dsr

#endif  // DSR_IO_IO_IMAGE_H_
