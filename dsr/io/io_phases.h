// 4D images as phases: one 3D volume per heart phase (an ECG-gated sequence), all on the
// same 3D grid. Read and written through ITK like io_image.h, with its rules (finite
// voxels, valid geometry, one-line errors that start with the file's path, atomic writes
// verified by reading them back).
//
// Files (docs/usage.md, "4D images: phases"):
// - NIfTI (.nii, .nii.gz): a 4D image whose 4th axis (time) indexes the phases. Written
//   with phase spacing 1 and origin 0 on that axis, its unit unknown (xyzt_units: mm, no
//   time unit): the 4th index is a phase number, not a time.
// - NRRD (.nrrd, .nhdr): a 4D scalar image (as ITK writes it: four domain axes), or three
//   spatial axes and one non-spatial axis of kind "list" (3D Slicer) or "vector" (ITK's
//   vector images). Written as dimension 4 with the phases on axis 0, kind "list", space
//   direction "none", label "phase"; .nrrd compressed, .nhdr with an uncompressed
//   "<stem>.raw".
// - 3D Slicer's volume sequences (.seq.nrrd, .seq.nhdr): that NRRD plus the keys 3D
//   Slicer's Sequences module reads, so that it loads the file as a sequence of scalar
//   volumes (vtkMRMLScalarVolumeNode) indexed 0..T-1: "DataNodeClassName:=
//   vtkMRMLScalarVolumeNode", "axis 0 index type:=numeric", "axis 0 index values:=0 1 ...".
// - MetaImage (.mha, .mhd): a 4D image (NDims = 4).
// A 3D file is one phase, read exactly as ReadImage reads it; one phase is written exactly
// as WriteImage writes it.
#ifndef DSR_IO_IO_PHASES_H_
#define DSR_IO_IO_PHASES_H_

#include <string>
#include <vector>

#include "dsr/geometry/volume.h"

namespace dsr {

// Reads the phases `which` of a 3D or 4D image (indices in the file, each at most once, in
// the order given; empty: every phase) as float: each Image has the file's 3D grid (the
// origin, spacing and direction of its three spatial axes). A 3D image (or a 4D one with
// one phase on a 4th axis) is phase 0 and gives what ReadImage gives. Refuses 2D and 5D+
// images, pixels other than scalars (or a NRRD list/vector axis of phases), a 4th axis
// mixed with space, invalid geometry, a phase the file does not have ("<path>: no phase 5
// (the file has 4 phases, 0 to 3)") and non-finite voxels in a phase read ("<path>: phase
// 2: voxel (i,j,k) is NaN", the phase's index in the file); phases not read are not
// looked at. Memory: the phases read plus a few MiB, decoded phase by phase (NIfTI-1,
// binary MetaImage, raw or gzip NRRD; files in other layouts are held whole while
// reading, see itk_io::ReadPhases). Compressed data is decompressed up to the last phase
// read.
bool ReadPhases(const std::string& path,
                const std::vector<int>& which,
                std::vector<Image>* phases,
                std::string* error);
// Every phase.
bool ReadPhases(const std::string& path, std::vector<Image>* phases, std::string* error);

// Writes the phases (T >= 1; the format follows the extension, see above). Every phase
// must lie on phase 0's grid (ImageGeometry::SameGrid) with a matching voxel count; phase
// 0's grid is written. One phase is written as WriteImage writes it. Atomic (temp file +
// rename, or a temporary folder for .nhdr/.mhd), verified by reading the header and the
// data size back. Memory: one extra copy of the voxels while writing.
bool WritePhases(const std::vector<Image>& phases, const std::string& path, std::string* error);
// The same for voxels held elsewhere (the Python module's arrays): phase t's
// grid.NumVoxels() voxels, x fastest, start at voxels[t]. No copy beyond the writer's.
bool WritePhases(const ImageGeometry& grid,
                 const std::vector<const float*>& voxels,
                 const std::string& path,
                 std::string* error);

// The files of one view given as `spec`: the file itself when one has that name, else the
// 3D files of its phases joined by ';' ("v0_p0.nii.gz;v0_p1.nii.gz"), in phase order
// (items trimmed of spaces, empty items dropped).
std::vector<std::string> ViewFiles(const std::string& spec);

// ReadView's refusal of a phase of one value in every voxel, "<what> has the same value (0)
// in every voxel: ..." (also the Python module's, for arrays); `what` names the phase.
std::string ConstantPhaseError(const std::string& what, const Image& phase);

// A view's phases `which` (as ReadPhases; empty: all) (docs/design.md section 12): ReadPhases
// of its one file (3D: one phase), or for files joined by ';' (ViewFiles) the 3D images of
// the files `which` names, only those read, each on the grid of the first one read
// ("<file>: phase 2 lies on another grid than phase 0 (<first>)"). A phase of a view of
// several phases that holds one value in every voxel (a blank phase) is refused ("<file>:
// phase 2 has the same value (0) in every voxel: ..."), found by the finite-voxel check's
// own pass; a 3D view is read as ReadImage reads it (the registration refuses a frame of one
// value in its field of view).
bool ReadView(const std::string& spec,
              const std::vector<int>& which,
              std::vector<Image>* phases,
              std::string* error);
// Every phase.
bool ReadView(const std::string& spec, std::vector<Image>* phases, std::string* error);

// The number of phases of a view from headers alone: NumPhasesInFile of its one file, or
// the number of files joined by ';' (1 for a 3D file).
bool NumPhasesInView(const std::string& spec, int* phases, std::string* error);

// Reads a mask as ReadMask does (any scalar type, non-zero = inside, on `expected`'s grid,
// at least one voxel inside). A 3D file behaves exactly as with ReadMask; a 4D mask is
// accepted only when every phase has the same inside as phase 0 (then it is that 3D mask),
// otherwise "<path>: mask phase t differs from phase 0 at voxel (i,j,k) ...".
bool ReadMaskPhases(const std::string& path,
                    const ImageGeometry& expected,
                    Mask* mask,
                    std::string* error);

// The number of phases of an image file, from its header alone (1 for a 3D image), with
// ReadPhases's header checks.
bool NumPhasesInFile(const std::string& path, int* phases, std::string* error);

}  // namespace dsr

#endif  // DSR_IO_IO_PHASES_H_
