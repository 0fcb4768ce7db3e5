// Phases (4D images, io_phases.h) through ITK, Eigen-free like io_itk.cc (see io_itk.h):
// io_itk.h's ReadPhasesHeader, ReadPhases and WritePhases.
//
// The header is read through the same ImageIOBase path as Read (io_itk.cc): a scalar 4D
// image, or a NRRD whose one non-spatial axis is a list or vector, which ITK reads as
// vector pixels; then the same data-block checks. The voxels of the phases asked for are
// then decoded by io_phase_stream.h in one pass over the data block, from where each
// format keeps them (io_itk_phase_source.cc; ITK 5.2 can read a region of NIfTI and
// MetaImage files, but reopens and re-inflates a compressed file from its start for each
// region, and reads NRRD whole); layouts that reader does not follow are read whole by ITK.
// Written by ITK's writer as a scalar 4D image, or for NRRD by ITK's teem (NrrdIO)
// directly, since ITK's writer gives a non-spatial axis the kind "vector" and no keys of
// its own, while 3D Slicer's .seq.nrrd wants kind "list" and its sequence keys.
#include "dsr/io/io_itk.h"

#include <algorithm>
#include <climits>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <exception>
#include <fstream>
#include <limits>
#include <memory>
#include <new>
#include <regex>
#include <string>
#include <vector>

#include <NrrdIO.h>
#include <itkImage.h>
#include <itkImageFileWriter.h>
#include <itkImageIOBase.h>
#include <itkMetaDataObject.h>

#include "dsr/io/io_itk_internal.h"
#include "dsr/io/io_phase_stream.h"
#include "dsr/util/text.h"

namespace dsr {
namespace itk_io {
namespace internal {
namespace {

// "AxBxC..." for the sizes of every axis of `io`.
std::string Extent(const itk::ImageIOBase& io) {
  std::string extent;
  for (unsigned d = 0; d < io.GetNumberOfDimensions(); ++d) {
    extent += (d ? "x" : "") + std::to_string(io.GetDimensions(d));
  }
  return extent;
}

// The kind of the first non-spatial axis in a NRRD header's "kinds:" field (a kind other
// than domain, space, time or unknown), "" when there is none.
std::string NrrdRangeKind(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::string line;
  size_t read = 0;
  while (read < kMaxHeaderBytes && std::getline(in, line)) {
    read += line.size() + 1;
    if (Trim(line).empty()) break;  // the header ends at its first empty line
    const size_t colon = line.find(':');
    if (line[0] == '#' || colon == std::string::npos || Trim(line.substr(0, colon)) != "kinds") {
      continue;
    }
    for (const std::string& kind : Words(line.substr(colon + 1))) {
      if (kind != "domain" && kind != "space" && kind != "time" && kind != "???" &&
          kind != "none") {
        return kind;
      }
    }
  }
  return "";
}

// A scalar 4D image's 4th axis must be apart from space: no spatial component in its
// direction, no 4th component in the directions of the first three.
bool FourthAxisApart(const itk::ImageIOBase& io) {
  for (unsigned a = 0; a < 4; ++a) {
    const std::vector<double> axis = io.GetDirection(a);
    for (size_t r = 0; r < axis.size(); ++r) {
      if ((a < 3) != (r < 3) && std::abs(axis[r]) > 1e-6) return false;
    }
  }
  return true;
}

// Whether `value` is a number as a numeric index value of 3D Slicer is: all of it a finite
// decimal (or scientific) floating-point number.
bool IsIndexNumber(const std::string& value) {
  if (value.empty() || value.find_first_not_of("0123456789+-.eE") != std::string::npos) {
    return false;
  }
  char* end = nullptr;
  const double number = std::strtod(value.c_str(), &end);
  return end == value.c_str() + value.size() && std::isfinite(number);
}

// 3D Slicer's sequence keys in a NRRD of `phases` phases (vtkMRMLVolumeSequenceStorageNode):
// "axis <A> index type:=numeric|text" and "axis <A> index values:=<v0> <v1> ...", A the
// list axis (3 as Slicer writes it now, 0 as it wrote it and dsr writes it), one value per
// phase (split at spaces), numbers unless the type is text (numeric is Slicer's default).
// dsr indexes phases by position, but keys that disagree with the data mean a file edited
// or assembled by hand: refused, naming the key.
bool CheckSequenceKeys(const std::string& path,
                       const itk::ImageIOBase& io,
                       int phases,
                       std::string* error) {
  static const std::regex kKey(R"(axis ([0-9]{1,9}) index (type|values))");
  NrrdLayout layout;
  std::string reason;
  std::vector<uint64_t> sizes;
  int axis = -1;
  if (ParseNrrdLayout(path, &layout, &reason)) {
    sizes.resize(layout.sizes.size());
    bool counts = true;
    for (size_t a = 0; a < sizes.size(); ++a) {
      counts = counts && NrrdCount(layout.sizes[a], &sizes[a]);
    }
    if (counts) axis = NrrdPhaseAxis(io, layout, sizes);
  }
  const itk::MetaDataDictionary& keys = io.GetMetaDataDictionary();
  std::string type = "numeric", values_key, values;
  for (const std::string& key : keys.GetKeys()) {
    std::smatch match;
    std::string value;
    if (!std::regex_match(key, match, kKey) || !itk::ExposeMetaData(keys, key, value)) continue;
    const std::string named = "key '" + key + "'";
    if (axis >= 0 && std::stoi(match[1].str()) != axis) {
      *error = path + ": " + named + " is about axis " + match[1].str() +
               ", but the phases are on axis " + std::to_string(axis) +
               " (3D Slicer's sequence keys name the list axis)";
      return false;
    }
    if (match[2] == "type") {
      type = Trim(value);
      if (type != "numeric" && type != "text") {
        *error = path + ": " + named + " is '" + type +
                 "'; 3D Slicer's index types are numeric "
                 "and text";
        return false;
      }
    } else {
      values_key = named;
      values = value;
    }
  }
  if (values_key.empty()) return true;
  const std::vector<std::string> items = Words(values);
  if (items.size() != static_cast<size_t>(phases)) {
    *error = path + ": " + values_key + " has " + std::to_string(items.size()) + " value" +
             (items.size() == 1 ? "" : "s") + " for " + std::to_string(phases) +
             " phases (one index value per phase)";
    return false;
  }
  for (size_t t = 0; t < items.size() && type == "numeric"; ++t) {
    if (IsIndexNumber(items[t])) continue;
    *error = path + ": " + values_key + ": value " + std::to_string(t) + " '" +
             items[t].substr(0, 40) + "' is not a number (the index type is numeric)";
    return false;
  }
  return true;
}

// ReadPhasesHeader's classification of the header `io` has read (see io_itk.h).
bool InspectPhasesHeader(const std::string& path,
                         const itk::ImageIOBase& io,
                         PhasesHeader* header,
                         std::string* error) {
  const itk::IOComponentEnum component = io.GetComponentType();
  if (!ConvertBuffer(component, nullptr, 0, nullptr)) {  // a known type converts nothing
    *error =
        path + ": unsupported voxel type " + itk::ImageIOBase::GetComponentTypeAsString(component);
    return false;
  }
  const unsigned dims = io.GetNumberOfDimensions();
  const unsigned components = io.GetNumberOfComponents();
  const itk::IOPixelEnum pixel = io.GetPixelType();
  uint64_t phases = 1;
  if (pixel == itk::IOPixelEnum::SCALAR && components == 1) {
    if (dims < 3 || dims > 4) {
      *error = path + ": " + std::to_string(dims) + "D image of size " + Extent(io) +
               "; expected a 3D image or a 4D image of phases (x, y, z, phase)";
      return false;
    }
    if (dims == 4 && io.GetDimensions(3) > 1 && !FourthAxisApart(io)) {  // 1: as Read takes it
      *error = path +
               ": the header's directions mix the 4th axis with space; expected three "
               "spatial axes and a separate 4th (phase) axis";
      return false;
    }
    phases = dims == 4 ? io.GetDimensions(3) : 1;
    header->single_volume = phases == 1;
  } else if (std::string(io.GetNameOfClass()) == "NrrdImageIO" &&
             pixel == itk::IOPixelEnum::VECTOR && dims == 3) {
    const std::string kind = NrrdRangeKind(path);
    if (kind != "list" && kind != "vector") {
      *error = path + ": NRRD non-spatial axis of kind '" + kind +
               "'; phases need an axis of kind list (3D Slicer's .seq.nrrd) or vector";
      return false;
    }
    phases = components;
    header->single_volume = false;
  } else {
    *error = path + ": " + itk::ImageIOBase::GetPixelTypeAsString(pixel) + " pixels (" +
             std::to_string(components) + " components) in a " + std::to_string(dims) +
             "D image; expected scalar voxels (phases on a 4th axis or a NRRD list axis)";
    return false;
  }
  if (phases < 1 || phases > static_cast<uint64_t>(INT_MAX)) {
    *error = path + ": " + std::to_string(phases) + " phases is not a usable number";
    return false;
  }
  if (!header->single_volume && std::string(io.GetNameOfClass()) == "NrrdImageIO" &&
      !CheckSequenceKeys(path, io, static_cast<int>(phases), error)) {
    return false;
  }
  header->phases = static_cast<int>(phases);
  return FillGrid(path, io, &header->grid, error);
}

// Phases `which` of `all` (the file's voxels as float: phase-major, or phase-fastest if
// `interleaved`; `phases` phases of `count` voxels each), in that order; `all` is released
// at the end.
void SplitPhases(std::vector<float>* all,
                 int phases,
                 size_t count,
                 bool interleaved,
                 const std::vector<int>& which,
                 std::vector<std::vector<float>>* out) {
  out->assign(which.size(), {});
  const size_t stride = static_cast<size_t>(phases);
  for (size_t k = 0; k < which.size(); ++k) {
    const size_t t = static_cast<size_t>(which[k]);
    std::vector<float>& phase = (*out)[k];
    phase.resize(count);
    if (interleaved) {
      for (size_t v = 0; v < count; ++v) phase[v] = (*all)[v * stride + t];
    } else {
      std::copy(all->begin() + t * count, all->begin() + (t + 1) * count, phase.begin());
    }
  }
  std::vector<float>().swap(*all);
}

size_t VoxelCount(const RawVolume& grid) {
  return static_cast<size_t>(grid.size[0]) * static_cast<size_t>(grid.size[1]) *
         static_cast<size_t>(grid.size[2]);
}

// A scalar 4D float image (x, y, z, phase) through ITK's writer: phase spacing 1, origin
// 0, the 4th axis apart from space. Throws what ITK throws.
void WriteScalar4d(const RawVolume& grid,
                   const std::vector<const float*>& phases,
                   const std::string& path,
                   bool compress) {
  using ItkImage = itk::Image<float, 4>;
  auto image = ItkImage::New();
  ItkImage::RegionType region;
  ItkImage::SpacingType spacing;
  ItkImage::PointType origin;
  ItkImage::DirectionType direction;
  direction.SetIdentity();
  for (int a = 0; a < 3; ++a) {
    region.SetSize(a, static_cast<itk::SizeValueType>(grid.size[a]));
    spacing[a] = grid.spacing[a];
    origin[a] = grid.origin[a];
    for (int b = 0; b < 3; ++b) direction[a][b] = grid.direction[3 * a + b];
  }
  region.SetSize(3, static_cast<itk::SizeValueType>(phases.size()));
  spacing[3] = 1.0;
  origin[3] = 0.0;
  image->SetRegions(region);
  image->SetSpacing(spacing);
  image->SetOrigin(origin);
  image->SetDirection(direction);
  image->Allocate();
  const size_t count = VoxelCount(grid);
  for (size_t t = 0; t < phases.size(); ++t) {
    std::copy(phases[t], phases[t] + count, image->GetBufferPointer() + t * count);
  }
  auto writer = itk::ImageFileWriter<ItkImage>::New();
  writer->SetFileName(path);
  writer->SetInput(image);
  writer->SetUseCompression(compress);
  writer->Update();
}

// The error teem (NrrdIO) left in its "nrrd" biff, on one line.
std::string TeemError() {
  char* text = biffGetDone(NRRD);
  const std::string message = text != nullptr ? OneLine(text) : "no details";
  std::free(text);
  return message;
}

// Sets the fields of a NRRD of 4 axes (phases on axis 0, kind list, label "phase"; then the
// three spatial axes in LPS space) around `data`, and 3D Slicer's sequence keys if
// `sequence`. False when teem refuses.
bool DescribeNrrdList(
    const RawVolume& grid, size_t phases, bool sequence, float* data, Nrrd* nrrd) {
  size_t size[4] = {phases, static_cast<size_t>(grid.size[0]), static_cast<size_t>(grid.size[1]),
                    static_cast<size_t>(grid.size[2])};
  if (nrrdWrap_nva(nrrd, data, nrrdTypeFloat, 4, size) != 0 ||
      nrrdSpaceSet(nrrd, nrrdSpaceLeftPosteriorSuperior) != 0 ||
      nrrdSpaceOriginSet(nrrd, grid.origin) != 0) {
    return false;
  }
  int kinds[NRRD_DIM_MAX] = {nrrdKindList, nrrdKindDomain, nrrdKindDomain, nrrdKindDomain};
  nrrdAxisInfoSet_nva(nrrd, nrrdAxisInfoKind, kinds);
  double directions[NRRD_DIM_MAX][NRRD_SPACE_DIM_MAX];
  for (int r = 0; r < 3; ++r) {
    directions[0][r] = std::numeric_limits<double>::quiet_NaN();  // "none"
    for (int a = 0; a < 3; ++a) directions[a + 1][r] = grid.spacing[a] * grid.direction[3 * r + a];
  }
  nrrdAxisInfoSet_nva(nrrd, nrrdAxisInfoSpaceDirection, directions);
  const char* labels[NRRD_DIM_MAX] = {"phase", "", "", ""};
  nrrdAxisInfoSet_nva(nrrd, nrrdAxisInfoLabel, labels);
  if (!sequence) return true;
  std::string values;
  for (size_t t = 0; t < phases; ++t) values += (t ? " " : "") + std::to_string(t);
  return nrrdKeyValueAdd(nrrd, "DataNodeClassName", "vtkMRMLScalarVolumeNode") == 0 &&
         nrrdKeyValueAdd(nrrd, "axis 0 index type", "numeric") == 0 &&
         nrrdKeyValueAdd(nrrd, "axis 0 index values", values.c_str()) == 0;
}

// A NRRD with the phases on a list axis (axis 0, phase-fastest voxels) through teem, which
// ITK's writer cannot make (it writes kind "vector" and no per-axis keys for that axis).
bool WriteNrrdList(const RawVolume& grid,
                   const std::vector<const float*>& phases,
                   const std::string& path,
                   bool sequence,
                   bool compress,
                   std::string* error) {
  const size_t count = VoxelCount(grid);
  const size_t stride = phases.size();
  std::vector<float> data(count * stride);  // the one copy: phase-fastest
  for (size_t t = 0; t < stride; ++t) {
    for (size_t v = 0; v < count; ++v) data[v * stride + t] = phases[t][v];
  }
  std::unique_ptr<Nrrd, Nrrd* (*)(Nrrd*)> nrrd(nrrdNew(), nrrdNix);  // nix: keeps `data`
  std::unique_ptr<NrrdIoState, NrrdIoState* (*)(NrrdIoState*)> io(nrrdIoStateNew(), nrrdIoStateNix);
  const NrrdEncoding* encoding =
      nrrdEncodingArray[compress ? nrrdEncodingTypeGzip : nrrdEncodingTypeRaw];
  if (!encoding->available()) {
    *error = path + ": cannot write (this build's NRRD library has no gzip encoding)";
    return false;
  }
  io->encoding = encoding;
  if (!DescribeNrrdList(grid, stride, sequence, data.data(), nrrd.get()) ||
      nrrdSave(path.c_str(), nrrd.get(), io.get()) != 0) {
    *error = path + ": cannot write (" + TeemError() + ")";
    return false;
  }
  return true;
}

}  // namespace
}  // namespace internal

// The helpers the functions of io_itk.h below call.
using internal::CheckBeforeReading;
using internal::CheckInputFile;
using internal::CheckVoxelBytesFit;
using internal::Describe;
using internal::InspectPhasesHeader;
using internal::OneLine;
using internal::OpenHeader;
using internal::PhaseSource;
using internal::ReadFailure;
using internal::ReadWholeAsFloat;
using internal::RegisterFactories;
using internal::ScopedQuietStdErr;
using internal::SplitPhases;
using internal::VerifyWrittenShape;
using internal::VoxelCount;
using internal::WriteNrrdList;
using internal::WriteScalar4d;

bool ReadPhasesHeader(const std::string& path, PhasesHeader* header, std::string* error) {
  if (!CheckInputFile(path, error)) return false;
  RegisterFactories();
  const ScopedQuietStdErr quiet;
  try {
    itk::ImageIOBase::Pointer io = OpenHeader(path, error);
    if (!io) return false;
    PhasesHeader out;
    if (!InspectPhasesHeader(path, *io, &out, error)) return false;
    *header = out;
    return true;
  } catch (...) {
    *error = ReadFailure(path, "cannot read the header");
  }
  return false;
}

bool ReadPhases(const std::string& path,
                const HeaderCheck& check_header,
                const std::vector<int>& which,
                RawVolume* grid,
                std::vector<std::vector<float>>* phases,
                std::string* error) {
  if (!CheckInputFile(path, error)) return false;
  RegisterFactories();
  const ScopedQuietStdErr quiet;
  const char* stage = "cannot read the header";
  try {
    itk::ImageIOBase::Pointer io = OpenHeader(path, error);
    if (!io) return false;
    PhasesHeader header;
    if (!InspectPhasesHeader(path, *io, &header, error)) return false;
    if (check_header && !check_header(header.grid, error)) return false;
    // Before the lists below, as long as the phases (a header may claim 2^31 of them).
    if (!CheckVoxelBytesFit(*io, path, error)) return false;
    std::vector<int> order = which;
    if (order.empty()) {
      for (int t = 0; t < header.phases; ++t) order.push_back(t);
    }
    std::vector<bool> chosen(static_cast<size_t>(header.phases), false);
    for (const int t : order) {
      if (t < 0 || t >= header.phases || chosen[t]) {
        *error = path + ": no phase " + std::to_string(t) + " to read (the file has " +
                 std::to_string(header.phases) + ", each read once)";
        return false;
      }
      chosen[t] = true;
    }
    stage = "cannot read the voxels";
    if (!CheckBeforeReading(*io, path, &chosen, error)) return false;
    phase_stream::Source source;
    if (PhaseSource(path, *io, header, &source)) {
      std::string reason;
      if (!phase_stream::ReadPhases(source, order, phases, &reason)) {
        *error = path + ": " + stage + " (" + reason + ")";
        return false;
      }
    } else {
      std::vector<float> all;
      ReadWholeAsFloat(*io, &all);
      const bool interleaved = io->GetPixelType() != itk::IOPixelEnum::SCALAR;
      SplitPhases(&all, header.phases, VoxelCount(header.grid), interleaved, order, phases);
    }
    *grid = header.grid;
    return true;
  } catch (...) {
    *error = ReadFailure(path, stage);
  }
  return false;
}

bool WritePhases(const RawVolume& grid,
                 const std::vector<const float*>& phases,
                 const std::string& path,
                 PhasesLayout layout,
                 bool compress,
                 std::string* error) {
  RegisterFactories();
  const ScopedQuietStdErr quiet;
  std::vector<uint64_t> sizes = {static_cast<uint64_t>(grid.size[0]),
                                 static_cast<uint64_t>(grid.size[1]),
                                 static_cast<uint64_t>(grid.size[2])};
  unsigned components = static_cast<unsigned>(phases.size());
  try {
    if (layout == PhasesLayout::kScalar4d) {
      WriteScalar4d(grid, phases, path, compress);
      sizes.push_back(phases.size());
      components = 1;
    } else if (!WriteNrrdList(grid, phases, path, layout == PhasesLayout::kSlicerSequence, compress,
                              error)) {
      return false;
    }
  } catch (const itk::ExceptionObject& e) {
    *error = path + ": cannot write (" + Describe(e) + ")";
    return false;
  } catch (const std::bad_alloc&) {
    *error = path + ": cannot write (out of memory)";
    return false;
  } catch (const std::exception& e) {
    *error = path + ": cannot write (" + OneLine(e.what()) + ")";
    return false;
  }
  return VerifyWrittenShape(sizes, components, itk::IOComponentEnum::FLOAT, path, error);
}

}  // namespace itk_io
}  // namespace dsr
