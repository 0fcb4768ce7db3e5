// 4D images as phases (see io_phases.h): the rules of io_image.cc (io_image_internal.h)
// around the ITK adapter's phase reader and writers (io_itk.h). A file ITK reads as one 3D
// volume goes through ReadImage/WriteImage themselves, so 3D files behave exactly as there.
#include "dsr/io/io_phases.h"

#include <algorithm>
#include <cstdint>
#include <filesystem>
#include <sstream>
#include <utility>

#include "dsr/io/io_image.h"
#include "dsr/io/io_image_internal.h"
#include "dsr/io/io_itk.h"
#include "dsr/util/atomic_file.h"
#include "dsr/util/text.h"

namespace dsr {
namespace {

using io_internal::IsNifti;
using io_internal::ToGeometry;
using io_internal::ToRaw;
using io_internal::UnsupportedExtension;

// How `path` lays phases out: 3D Slicer's sequence for .seq.nrrd/.seq.nhdr, a NRRD list
// axis for other .nrrd/.nhdr, a scalar 4D image for NIfTI and MetaImage.
itk_io::PhasesLayout LayoutFor(const std::string& path) {
  const std::string lower = Lower(path);
  if (EndsWith(lower, ".seq.nrrd") || EndsWith(lower, ".seq.nhdr")) {
    return itk_io::PhasesLayout::kSlicerSequence;
  }
  if (EndsWith(lower, ".nrrd") || EndsWith(lower, ".nhdr")) return itk_io::PhasesLayout::kNrrdList;
  return itk_io::PhasesLayout::kScalar4d;
}

// Every phase must share phase 0's grid and hold its number of voxels.
bool CheckPhasesToWrite(const std::vector<Image>& phases,
                        const std::string& path,
                        std::string* error) {
  const ImageGeometry& grid = phases[0].geometry;
  for (size_t t = 0; t < phases.size(); ++t) {
    const ImageGeometry& g = phases[t].geometry;
    if (g.size != grid.size || !g.SameGrid(grid)) {
      *error = path + ": cannot write phases on different grids: phase " + std::to_string(t) +
               " is on " + g.DebugString() + ", phase 0 on " + grid.DebugString();
      return false;
    }
    if (static_cast<int64_t>(phases[t].voxels.size()) != grid.NumVoxels()) {
      *error = path + ": cannot write phase " + std::to_string(t) + ": it holds " +
               std::to_string(phases[t].voxels.size()) + " voxels, its grid " +
               std::to_string(grid.NumVoxels());
      return false;
    }
  }
  return true;
}

// The linear index of the first voxel whose inside (non-zero) differs between `a` and `b`
// (same size), -1 when none does.
int64_t FirstInsideDifference(const Image& a, const Image& b) {
  for (size_t v = 0; v < a.voxels.size(); ++v) {
    if ((a.voxels[v] != 0.0f) != (b.voxels[v] != 0.0f)) return static_cast<int64_t>(v);
  }
  return -1;
}

// A `which` of ReadPhases for `name` of `count` phases ("file" or "view"): each index a
// phase it has, none twice.
bool CheckWhich(const std::string& name,
                const std::vector<int>& which,
                int count,
                const std::string& what,
                std::string* error) {
  for (size_t k = 0; k < which.size(); ++k) {
    const int t = which[k];
    if (t < 0 || t >= count) {
      *error = name + ": no phase " + std::to_string(t) + " (the " + what +
               (count > 1 ? " has " + std::to_string(count) + " phases, 0 to " +
                                std::to_string(count - 1) + ")"
                          : " has only phase 0)");
      return false;
    }
    if (std::find(which.begin(), which.begin() + k, t) != which.begin() + k) {
      *error = name + ": phase " + std::to_string(t) + " is asked for twice";
      return false;
    }
  }
  return true;
}

}  // namespace

// A phase of one value in every voxel (a blank phase: 0) is refused as a frame of one value
// in its field of view is: nothing in it can be registered, and it would pull the view's
// one pose for every phase.
std::string ConstantPhaseError(const std::string& what, const Image& phase) {
  std::ostringstream value;
  value << (phase.voxels.empty() ? 0.0f : phase.voxels[0]);
  return what + " has the same value (" + value.str() + ") in every voxel: a blank or "
         "constant phase has nothing to register";
}

bool NumPhasesInFile(const std::string& path, int* phases, std::string* error) {
  if (!HasSupportedImageExtension(path)) {
    *error = UnsupportedExtension(path);
    return false;
  }
  itk_io::PhasesHeader header;
  if (!itk_io::ReadPhasesHeader(path, &header, error)) return false;
  *phases = header.phases;
  return true;
}

namespace {

// ReadPhases, and with `refuse_constant` (a view's phases, ReadView) a 4D file's phase of one
// value in every voxel refused (ConstantPhaseError), found by the finite-voxel check's pass.
bool ReadFilePhases(const std::string& path,
                    const std::vector<int>& which,
                    bool refuse_constant,
                    std::vector<Image>* phases,
                    std::string* error) {
  if (!HasSupportedImageExtension(path)) {
    *error = UnsupportedExtension(path);
    return false;
  }
  itk_io::PhasesHeader header;
  if (!itk_io::ReadPhasesHeader(path, &header, error) ||
      !CheckWhich(path, which, header.phases, "file", error)) {
    return false;
  }
  if (header.single_volume) {
    std::vector<Image> out(1);
    if (!ReadImage(path, &out[0], error)) return false;
    *phases = std::move(out);
    return true;
  }
  const std::string zero_spacing = io_internal::ZeroNiftiSpacing(path);
  if (!zero_spacing.empty()) {
    *error = path + ": " + zero_spacing;
    return false;
  }
  const auto check_header = [&](const itk_io::RawVolume& grid, std::string* header_error) {
    return ToGeometry(grid).Validate(path, header_error);
  };
  itk_io::RawVolume grid;
  std::vector<std::vector<float>> voxels;
  if (!itk_io::ReadPhases(path, check_header, which, &grid, &voxels, error)) return false;
  const ImageGeometry geometry = ToGeometry(grid);
  if (IsNifti(path) && !io_internal::CheckNiftiOriginPrecision(path, geometry, error)) {
    return false;
  }
  std::vector<Image> out(voxels.size());
  for (size_t k = 0; k < out.size(); ++k) {
    out[k].geometry = geometry;
    out[k].voxels = std::move(voxels[k]);
    // Named by its index in the file, whatever its place in `which`.
    const int t = which.empty() ? static_cast<int>(k) : which[k];
    const std::string phase = path + ": phase " + std::to_string(t);
    bool constant = false;
    if (!CheckFiniteVoxels(out[k], phase, error, refuse_constant ? &constant : nullptr)) {
      return false;
    }
    if (constant) {
      *error = ConstantPhaseError(phase, out[k]);
      return false;
    }
  }
  *phases = std::move(out);
  return true;
}

}  // namespace

bool ReadPhases(const std::string& path,
                const std::vector<int>& which,
                std::vector<Image>* phases,
                std::string* error) {
  return ReadFilePhases(path, which, /*refuse_constant=*/false, phases, error);
}

bool ReadPhases(const std::string& path, std::vector<Image>* phases, std::string* error) {
  return ReadPhases(path, {}, phases, error);
}

bool WritePhases(const ImageGeometry& grid,
                 const std::vector<const float*>& voxels,
                 const std::string& path,
                 std::string* error) {
  if (voxels.empty()) {
    *error = path + ": cannot write an image of no phases";
    return false;
  }
  if (voxels.size() == 1) {
    Image image(grid);
    std::copy(voxels[0], voxels[0] + image.voxels.size(), image.voxels.begin());
    return WriteImage(image, path, error);
  }
  if (!HasSupportedImageExtension(path)) {
    *error = UnsupportedExtension(path);
    return false;
  }
  std::string why;
  if (!grid.Validate("grid", &why)) {
    *error = path + ": cannot write an image with an invalid " + why;
    return false;
  }
  const itk_io::RawVolume raw = ToRaw(grid);
  const itk_io::PhasesLayout layout = LayoutFor(path);
  const std::string ext = Lower(path);
  // As WriteImage: .nii is never compressed, .mhd/.nhdr keep raw data files.
  const bool compress = EndsWith(ext, ".nii.gz") || EndsWith(ext, ".mha") || EndsWith(ext, ".nrrd");
  const auto write = [&](const std::string& temp, std::string* write_error) {
    return itk_io::WritePhases(raw, voxels, temp, layout, compress, write_error);
  };
  // A detached header names its data file after itself (see WriteImage).
  if (EndsWith(ext, ".mhd") || EndsWith(ext, ".nhdr")) {
    return WriteFilesViaTemporaryFolder(path, write, error);
  }
  return WriteViaTemporaryFile(path, write, error);
}

bool WritePhases(const std::vector<Image>& phases, const std::string& path, std::string* error) {
  if (phases.empty()) {
    *error = path + ": cannot write an image of no phases";
    return false;
  }
  if (phases.size() == 1) return WriteImage(phases[0], path, error);
  if (!CheckPhasesToWrite(phases, path, error)) return false;
  std::vector<const float*> voxels;
  for (const Image& phase : phases) voxels.push_back(phase.voxels.data());
  return WritePhases(phases[0].geometry, voxels, path, error);
}

bool ReadMaskPhases(const std::string& path,
                    const ImageGeometry& expected,
                    Mask* mask,
                    std::string* error) {
  std::vector<Image> phases;
  if (!ReadPhases(path, &phases, error)) return false;
  Mask out;
  if (!io_internal::MaskFromImage(path, phases[0], expected, &out, error)) return false;
  for (size_t t = 1; t < phases.size(); ++t) {
    const int64_t v = FirstInsideDifference(phases[0], phases[t]);
    if (v < 0) continue;
    *error = path + ": mask phase " + std::to_string(t) + " differs from phase 0 at " +
             VoxelName(v, expected.size[0], expected.size[1]) +
             " (a 4D mask is taken only when every phase has the same inside)";
    return false;
  }
  *mask = std::move(out);
  return true;
}

std::vector<std::string> ViewFiles(const std::string& spec) {
  std::error_code ec;
  if (spec.find(';') == std::string::npos || std::filesystem::exists(spec, ec)) return {spec};
  std::vector<std::string> files;
  std::stringstream items(spec);
  std::string item;
  while (std::getline(items, item, ';')) {
    const size_t first = item.find_first_not_of(" \t");
    if (first == std::string::npos) continue;
    files.push_back(item.substr(first, item.find_last_not_of(" \t") - first + 1));
  }
  return files;
}

bool ReadView(const std::string& spec,
              const std::vector<int>& which,
              std::vector<Image>* phases,
              std::string* error) {
  const std::vector<std::string> files = ViewFiles(spec);
  if (files.size() == 1) {
    return ReadFilePhases(files[0], which, /*refuse_constant=*/true, phases, error);
  }
  const int count = static_cast<int>(files.size());
  if (!CheckWhich(spec, which, count, "view", error)) return false;
  std::vector<int> order = which;
  if (order.empty()) {
    for (int p = 0; p < count; ++p) order.push_back(p);
  }
  std::vector<Image> out(order.size());
  for (size_t k = 0; k < order.size(); ++k) {
    const std::string& file = files[order[k]];
    bool constant = false;
    if (!io_internal::ReadImage(file, &out[k], error, &constant)) return false;
    if (constant) {
      *error = ConstantPhaseError(file + ": phase " + std::to_string(order[k]), out[k]);
      return false;
    }
    if (k > 0 && !out[k].geometry.SameGrid(out[0].geometry)) {
      *error = file + ": phase " + std::to_string(order[k]) + " lies on another grid than phase " +
               std::to_string(order[0]) + " (" + files[order[0]] + ")";
      return false;
    }
  }
  *phases = std::move(out);
  return true;
}

bool ReadView(const std::string& spec, std::vector<Image>* phases, std::string* error) {
  return ReadView(spec, {}, phases, error);
}

bool NumPhasesInView(const std::string& spec, int* phases, std::string* error) {
  const std::vector<std::string> files = ViewFiles(spec);
  if (files.size() == 1) return NumPhasesInFile(files[0], phases, error);
  *phases = static_cast<int>(files.size());
  return true;
}

}  // namespace dsr
