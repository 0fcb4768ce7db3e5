// The ITK side of image IO, kept free of Eigen: ITK 5.2 bundles its own Eigen 3.3, which
// cannot share a translation unit with the system Eigen 3.4 the rest of dsr uses. Only
// the io_itk*.cc files include ITK; io_image.cc converts RawVolume to and from dsr::Volume
// and owns the rules that need Eigen (geometry validation, masks, atomic writes).
#ifndef DSR_IO_IO_ITK_H_
#define DSR_IO_IO_ITK_H_

#include <functional>
#include <string>
#include <vector>

namespace dsr {
namespace itk_io {

// A 3D scalar volume in plain arrays. Geometry follows ITK: x = origin + D S index, with
// index[0] = i varying fastest in `voxels`.
struct RawVolume {
  int size[3] = {0, 0, 0};
  double origin[3] = {0, 0, 0};
  double spacing[3] = {1, 1, 1};
  double direction[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};  // row-major D, columns = index axes
  std::vector<float> voxels;                          // x fastest
  // Set by Read when its own pass over the voxels found every one finite (a float or
  // uint8 NIfTI file read directly); `constant` then says whether every voxel holds one
  // value. When false, a caller that needs either reads the voxels itself.
  bool checked_finite = false;
  bool constant = false;
};

// Called with the header (voxels still empty) before any voxel is read; returns false with
// an error to stop the read.
using HeaderCheck = std::function<bool(const RawVolume& header, std::string* error)>;

// Reads a scalar 3D image (or a 4D one whose 4th size is 1) and converts its voxels to
// float. The header is inspected first: a missing file, an unreadable or corrupt header,
// non-scalar pixels, a dimension other than 3 (or 4 with one volume) and a failing
// `check_header` are reported before the voxels are read. Errors are one line naming `path`.
bool Read(const std::string& path,
          const HeaderCheck& check_header,
          RawVolume* volume,
          std::string* error);

enum class PixelType { kFloat, kUint8 };

// Writes `volume` to `path` (format from the extension) with voxels cast to `pixel_type`,
// then checks the result with VerifyWritten. Not atomic by itself: callers write to a
// temporary path and publish it only on success. Errors are one line naming `path`.
bool Write(const RawVolume& volume,
           const std::string& path,
           PixelType pixel_type,
           bool compress,
           std::string* error);

// Reads back what Write put at `path` and checks that it is complete: the header parses and
// describes `volume` (size, `pixel_type`), and the voxel data has exactly the size it must
// have: header + voxels x bytes per voxel for uncompressed data (in the data file for
// .mhd/.nhdr), a full decompression that ends cleanly with exactly that many bytes for
// compressed data. Failed writes (disk full, file-size limit) show up here even where the
// ITK writer reports success. The error names `path` and says "write failed".
bool VerifyWritten(const RawVolume& volume,
                   const std::string& path,
                   PixelType pixel_type,
                   std::string* error);

// ---- Phases: a 4D image read or written as T 3D volumes on one grid (io_phases.h) ----

// What a header says about an image's phases: its 3D grid (voxels empty), the number of
// phases and whether Read reads the file as it is (`single_volume`: a scalar 3D image, or
// 4D with a 4th size of 1) or only ReadPhases does.
struct PhasesHeader {
  RawVolume grid;
  int phases = 1;
  bool single_volume = true;
};

// Reads the header only and classifies the file: a scalar 3D image (1 phase); a scalar 4D
// image, one phase per index of the 4th axis (NIfTI's time axis, ITK's 4D NRRD/MetaImage);
// a NRRD of 3 spatial axes and one non-spatial axis of kind "list" or "vector" (3D
// Slicer's .seq.nrrd and ITK's vector images), one phase per item. Anything else (2D, 5D+,
// other pixel kinds, a 4th axis mixed with space) is refused with one line naming `path`.
bool ReadPhasesHeader(const std::string& path, PhasesHeader* header, std::string* error);

// Reads the phases `which` (distinct indices in [0, phases), in that order; empty: every
// phase) as float: the header checks of ReadPhasesHeader, then `check_header` on the 3D
// grid, then the data-block checks of Read (a NIfTI's non-finite voxels only in the phases
// read). `phases` gets one x-fastest vector per phase of `which`. The voxel data is decoded
// in one pass, chunk by chunk, keeping only those phases (io_phase_stream.h): peak memory
// is theirs plus a few MiB, whatever the file's number of phases. NIfTI-1 files, MetaImage
// binary data and NRRD of raw or gzip encoding are read so; other layouts (NRRD text
// encodings, NIfTI-2, ...) are read whole and the phases copied out (peak: the file's
// voxels once plus the phases).
bool ReadPhases(const std::string& path,
                const HeaderCheck& check_header,
                const std::vector<int>& which,
                RawVolume* grid,
                std::vector<std::vector<float>>* phases,
                std::string* error);

// How WritePhases lays the phases out:
// kScalar4d: a scalar 4D image (x, y, z, phase), phase spacing 1, origin 0 (NIfTI's time
//   axis, ITK's 4D MetaImage).
// kNrrdList: NRRD of dimension 4 with the phases on axis 0 of kind "list" (space direction
//   "none", label "phase") followed by the three spatial axes (space left-posterior-superior).
// kSlicerSequence: kNrrdList plus 3D Slicer's sequence keys (DataNodeClassName
//   vtkMRMLScalarVolumeNode, "axis 0 index type" numeric, "axis 0 index values" 0..T-1).
enum class PhasesLayout { kScalar4d, kNrrdList, kSlicerSequence };

// Writes float phases (each grid.size[0] * size[1] * size[2] voxels, x fastest; grid's
// voxels unused) to `path` and verifies the result as Write does. Holds one copy of the
// voxels (the 4D buffer) while writing. Not atomic by itself. Errors name `path`.
bool WritePhases(const RawVolume& grid,
                 const std::vector<const float*>& phases,
                 const std::string& path,
                 PhasesLayout layout,
                 bool compress,
                 std::string* error);

// `path` followed by the data files its header names (see io_image.h, ImageDataFiles).
bool DataFiles(const std::string& path, std::vector<std::string>* files, std::string* error);

// ITK transform files (.tfm, .txt; .h5 where ITK has HDF5): a 3D affine transform
// x_moving = A x_fixed + b, `matrix` = row-major [A | b] (12 numbers), written as ITK's
// AffineTransform_double_3_3 with centre 0. Not atomic by itself. Errors name `path`.
bool WriteAffineTransform(const std::string& path, const double matrix[12], std::string* error);
// Reads the first transform of a file: an AffineTransform, Euler3DTransform,
// VersorRigid3DTransform or any other matrix-offset transform of dimension 3.
bool ReadAffineTransform(const std::string& path, double matrix[12], std::string* error);

}  // namespace itk_io
}  // namespace dsr

#endif  // DSR_IO_IO_ITK_H_
