// Where each format keeps the phases of a 4D image, for the one-pass reader of
// io_phase_stream.h (ReadPhases, io_itk_phases.cc), Eigen-free (see io_itk.h): NIfTI-1 in
// one file, MetaImage binary data and NRRD of raw or gzip encoding, each with its storage
// type, byte order, data files and offsets.
#include "dsr/io/io_itk_internal.h"

#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <limits>
#include <memory>
#include <string>
#include <system_error>
#include <vector>

#include <itkImageIOBase.h>
#include <itk_zlib.h>

#include "dsr/io/io_phase_stream.h"

namespace dsr {
namespace itk_io {
namespace internal {
namespace {

bool HostIsBigEndian() {
  const uint16_t one = 1;
  unsigned char first = 0;
  std::memcpy(&first, &one, 1);
  return first == 0;
}

// The storage of ITK's component type `type` of `bytes` bytes (a long has 4 or 8).
bool StorageOf(itk::IOComponentEnum type, size_t bytes, phase_stream::Storage* storage) {
  using C = itk::IOComponentEnum;
  using S = phase_stream::Storage;
  const bool wide = bytes == 8;
  switch (type) {
    case C::UCHAR:
      *storage = S::kUint8;
      break;
    case C::CHAR:
      *storage = S::kInt8;
      break;
    case C::USHORT:
      *storage = S::kUint16;
      break;
    case C::SHORT:
      *storage = S::kInt16;
      break;
    case C::UINT:
    case C::ULONG:
    case C::ULONGLONG:
      *storage = wide ? S::kUint64 : S::kUint32;
      break;
    case C::INT:
    case C::LONG:
    case C::LONGLONG:
      *storage = wide ? S::kInt64 : S::kInt32;
      break;
    case C::FLOAT:
      *storage = S::kFloat32;
      break;
    case C::DOUBLE:
      *storage = S::kFloat64;
      break;
    default:
      return false;
  }
  return static_cast<size_t>(phase_stream::StorageBytes(*storage)) == bytes;
}

// The storage of the NIfTI datatypes ITK reads as scalars (nifti1.h codes).
bool NiftiStorage(int datatype, phase_stream::Storage* storage) {
  using S = phase_stream::Storage;
  struct Code {
    int datatype;
    S storage;
  };
  static constexpr Code kCodes[] = {
      {2, S::kUint8},  {4, S::kInt16},    {8, S::kInt32},    {16, S::kFloat32}, {64, S::kFloat64},
      {256, S::kInt8}, {512, S::kUint16}, {768, S::kUint32}, {1024, S::kInt64}, {1280, S::kUint64}};
  for (const Code& code : kCodes) {
    if (code.datatype != datatype) continue;
    *storage = code.storage;
    return true;
  }
  return false;
}

// NIfTI-1 in one file (.nii, .nii.gz: gzip over the whole file): `values` voxels from
// vox_offset, phase after phase, with niftilib's byte order and ITK's rescaling.
bool NiftiSource(const std::string& path, uint64_t values, phase_stream::Source* source) {
  gzFile file = gzopen(path.c_str(), "rb");
  if (file == nullptr) return false;
  std::unique_ptr<gzFile_s, int (*)(gzFile)> closer(file, gzclose_r);
  NiftiLayout layout;
  if (!ReadNiftiLayout(file, &layout) || layout.header_size != 348 || !layout.single_file ||
      layout.voxels != values || !NiftiStorage(layout.datatype, &source->storage)) {
    return false;
  }
  source->compressed = gzdirect(file) == 0;  // known after the header's read
  source->swap = layout.swap;
  // As ITK 5.2's NiftiImageIO: a slope of 0 counts as 1, and values are rescaled unless
  // the slope is 1 and the intercept 0 (MustRescale).
  const double eps = std::numeric_limits<double>::epsilon();
  source->slope = std::abs(layout.slope) < eps ? 1.0 : layout.slope;
  source->intercept = layout.intercept;
  source->rescale = std::abs(source->slope - 1.0) > eps || std::abs(source->intercept) > eps;
  const uint64_t bytes = values * phase_stream::StorageBytes(source->storage);
  if (source->compressed) {
    source->parts = {{path, 0, 0}};
    source->skip = layout.data_start;
  } else {
    source->parts = {{path, layout.data_start, bytes}};
  }
  return true;
}

// Where `file` keeps `share` bytes of uncompressed data after `skip` (-1: at its end).
bool PlainPart(const std::string& file, int64_t skip, uint64_t share, phase_stream::Part* part) {
  uint64_t offset = skip > 0 ? static_cast<uint64_t>(skip) : 0;
  if (skip < 0) {
    std::error_code ec;
    const uint64_t size = std::filesystem::file_size(file, ec);
    if (ec || size < share) return false;
    offset = size - share;
  }
  *part = {file, offset, share};
  return true;
}

// MetaImage: binary data after the header (LOCAL), in one data file or in LIST slice
// files, zlib-compressed or not, phase after phase.
bool MetaImageSource(const std::string& path,
                     const itk::ImageIOBase& io,
                     uint64_t values,
                     phase_stream::Source* source) {
  MetaImageLayout layout;
  bool found_data_file = false;
  std::string reason;
  if (!ParseMetaImageLayout(path, &layout, &found_data_file, &reason) || !layout.binary ||
      !StorageOf(io.GetComponentType(), io.GetComponentSize(), &source->storage)) {
    return false;
  }
  source->swap = layout.msb != HostIsBigEndian();
  source->compressed = layout.compressed;
  const uint64_t bytes = values * phase_stream::StorageBytes(source->storage);
  if (layout.kind == MetaImageLayout::Kind::kLocal) {
    if (layout.header_size != 0) return false;
    source->parts = {{path, layout.local_offset, bytes}};
    return true;
  }
  if (layout.files.empty() || bytes % layout.files.size() != 0 ||
      (layout.compressed &&
       (layout.kind == MetaImageLayout::Kind::kList || layout.header_size < 0))) {
    return false;
  }
  for (const std::string& file : layout.files) {
    phase_stream::Part part;
    if (!PlainPart(file, layout.header_size, bytes / layout.files.size(), &part)) return false;
    source->parts.push_back(part);
  }
  return true;
}

}  // namespace

// A NRRD field's non-negative integer, false for anything else.
bool NrrdCount(const std::string& text, uint64_t* value) {
  if (text.empty() || text.size() > 18 ||
      text.find_first_not_of("0123456789") != std::string::npos) {
    return false;
  }
  *value = std::stoull(text);
  return true;
}

// Which NRRD axis holds the phases: the 4th of a scalar 4D image, else the one axis of a
// kind that is not spatial (as NrrdRangeKind tells them), which ITK reads as components.
// The other axes must be ITK's three, in order. -1 when the header is not so.
int NrrdPhaseAxis(const itk::ImageIOBase& io,
                  const NrrdLayout& layout,
                  const std::vector<uint64_t>& sizes) {
  int axis = -1;
  if (io.GetPixelType() == itk::IOPixelEnum::SCALAR) {
    axis = sizes.size() == 4 ? 3 : -1;
  } else if (layout.kinds.size() == sizes.size()) {
    for (size_t a = 0; a < sizes.size(); ++a) {
      const std::string& kind = layout.kinds[a];
      if (kind == "domain" || kind == "space" || kind == "time" || kind == "???" ||
          kind == "none") {
        continue;
      }
      if (axis >= 0) return -1;
      axis = static_cast<int>(a);
    }
  }
  if (axis < 0 || sizes.size() != 4) return -1;
  for (unsigned a = 0, d = 0; a < 4; ++a) {
    if (static_cast<int>(a) != axis && sizes[a] != io.GetDimensions(d++)) return -1;
  }
  return axis;
}

namespace {

// NRRD, raw or gzip encoding, attached or in data files (line skip 0; byte skip for raw
// data), its phases on any one axis.
bool NrrdSource(const std::string& path,
                const itk::ImageIOBase& io,
                int phases,
                phase_stream::Source* source) {
  NrrdLayout layout;
  std::string reason;
  if (!ParseNrrdLayout(path, &layout, &reason) ||
      !StorageOf(io.GetComponentType(), io.GetComponentSize(), &source->storage)) {
    return false;
  }
  source->compressed = layout.encoding == "gzip" || layout.encoding == "gz";
  uint64_t line_skip = 0;
  int64_t byte_skip = 0;
  if ((!layout.line_skip.empty() && (!NrrdCount(layout.line_skip, &line_skip) || line_skip)) ||
      (!source->compressed && layout.encoding != "raw")) {
    return false;
  }
  if (layout.byte_skip == "-1") {
    byte_skip = -1;  // raw data at the end of its file
  } else if (!layout.byte_skip.empty()) {
    uint64_t skip = 0;
    if (!NrrdCount(layout.byte_skip, &skip)) return false;
    byte_skip = static_cast<int64_t>(skip);
  }
  const int size = phase_stream::StorageBytes(source->storage);
  if ((source->compressed && byte_skip != 0) ||
      (size > 1 && layout.endian != "little" && layout.endian != "big")) {
    return false;
  }
  source->swap = size > 1 && (layout.endian == "big") != HostIsBigEndian();
  std::vector<uint64_t> sizes(layout.sizes.size());
  for (size_t a = 0; a < sizes.size(); ++a) {
    if (!NrrdCount(layout.sizes[a], &sizes[a])) return false;
  }
  const int axis = NrrdPhaseAxis(io, layout, sizes);
  if (axis < 0 || sizes[axis] != static_cast<uint64_t>(phases)) return false;
  source->block = 1;
  for (int a = 0; a < axis; ++a) source->block *= sizes[a];
  const uint64_t bytes = source->voxels * static_cast<uint64_t>(phases) * size;
  if (layout.files.empty()) {
    if (byte_skip < 0) return PlainPart(path, -1, bytes, &source->parts.emplace_back());
    source->parts = {{path, layout.data_offset + static_cast<uint64_t>(byte_skip), bytes}};
    return true;
  }
  if (bytes % layout.files.size() != 0) return false;
  for (const std::string& file : layout.files) {
    phase_stream::Part part;
    if (!PlainPart(file, byte_skip, bytes / layout.files.size(), &part)) return false;
    source->parts.push_back(part);
  }
  return true;
}

}  // namespace

// Where the phases of the 4D image `io` read are kept, for phase_stream::ReadPhases; false
// when the file keeps them in a way that reader does not follow (ReadPhases then reads the
// file whole).
bool PhaseSource(const std::string& path,
                 const itk::ImageIOBase& io,
                 const PhasesHeader& header,
                 phase_stream::Source* source) {
  const std::string name = io.GetNameOfClass();
  source->phases = header.phases;
  source->voxels =
      static_cast<uint64_t>(header.grid.size[0]) * header.grid.size[1] * header.grid.size[2];
  source->block = source->voxels;
  // Sizes whose products could overflow are left to the whole-file read (and its limits).
  constexpr uint64_t kMostValues = uint64_t{1} << 40;
  if (source->voxels > kMostValues / static_cast<uint64_t>(header.phases)) return false;
  const uint64_t values = source->voxels * static_cast<uint64_t>(header.phases);
  if (name == "NiftiImageIO") return NiftiSource(path, values, source);
  if (name == "MetaImageIO") return MetaImageSource(path, io, values, source);
  if (name == "NrrdImageIO") return NrrdSource(path, io, header.phases, source);
  return false;
}

}  // namespace internal
}  // namespace itk_io
}  // namespace dsr
