// ITK image reading and writing with plain arrays (see io_itk.h for why no Eigen here): the
// ITK wrapper behind io_itk.h's Read, Write, VerifyWritten and DataFiles, and the steps of
// its read pipeline that the other io_itk*.cc files share (io_itk_internal.h).
//
// Reading goes through itk::ImageIOBase directly rather than itk::ImageFileReader: the
// header is inspected (pixel type, dimension, geometry) before any voxel is allocated, the
// geometry is copied exactly as stored (the reader would silently flip negative spacings
// and replace the direction of 4D files by a default), and the voxels of any scalar
// component type are converted to float here. Before ITK parses the header and before it
// reads the voxels, the checks of io_itk_checks.cc run: ITK 5.2's NIfTI and MetaImage
// readers do not fail on a truncated or corrupt data block.
//
// Writing: the NIfTI and MetaImage writers report success when the disk is full or a
// file-size limit is hit, so every written file is read back (VerifyWritten) with the same
// checks, demanding the exact size.
//
// 4D images (phases) are read and written by io_itk_phases.cc, ITK transform files by
// io_itk_transform.cc.
#include "dsr/io/io_itk.h"

#include <algorithm>
#include <cctype>
#include <climits>
#include <cstdint>
#include <exception>
#include <filesystem>
#include <memory>
#include <mutex>
#include <new>
#include <regex>
#include <string>
#include <system_error>
#include <utility>
#include <vector>

#include <itkImage.h>
#include <itkImageFileWriter.h>
#include <itkImageIOBase.h>
#include <itkImageIOFactory.h>
#include <itkImageIORegion.h>
#include <itkMetaImageIOFactory.h>
#include <itkNiftiImageIOFactory.h>
#include <itkNrrdImageIOFactory.h>

#include "dsr/io/io_itk_internal.h"
#include "dsr/util/text.h"

namespace dsr {
namespace itk_io {
namespace internal {

// Registered explicitly (not through ITK_USE_FILE's generated manager) and once.
void RegisterFactories() {
  static std::once_flag once;
  std::call_once(once, [] {
    itk::NiftiImageIOFactory::RegisterOneFactory();
    itk::MetaImageIOFactory::RegisterOneFactory();
    itk::NrrdImageIOFactory::RegisterOneFactory();
  });
}

// ITK descriptions span several lines and start with "ITK ERROR: Class(0x...): ". Keep the
// text on one line without the object address.
// NRRD (teem) errors are a chain "[nrrd] outer: trouble [nrrd] ... [nrrd] inner: cause";
// only the innermost link says what is wrong.
std::string OneLine(const std::string& message) {
  static const std::regex kItkPrefix(R"(ITK ERROR: \w+\(0x[0-9a-fA-F]+\): )");
  std::string text = std::regex_replace(message, kItkPrefix, "");
  const size_t innermost = text.rfind("[nrrd] ");
  if (innermost != std::string::npos) text = text.substr(innermost + 7);
  for (char& c : text) {
    if (c == '\n' || c == '\r' || c == '\t') c = ' ';
  }
  text.erase(
      std::unique(text.begin(), text.end(), [](char a, char b) { return a == ' ' && b == ' '; }),
      text.end());
  while (!text.empty() && (text.back() == ' ' || text.back() == '.')) text.pop_back();
  while (!text.empty() && text.front() == ' ') text.erase(text.begin());
  return text.empty() ? "no details" : text;
}

std::string Describe(const itk::ExceptionObject& e) { return OneLine(e.GetDescription()); }

namespace {

template <typename Component>
void ConvertToFloat(const void* buffer, size_t count, float* out) {
  const Component* in = static_cast<const Component*>(buffer);
  std::transform(in, in + count, out, [](Component v) { return static_cast<float>(v); });
}

}  // namespace

// Converts `count` components of type `type` to float; false for an unknown type.
bool ConvertBuffer(itk::IOComponentEnum type, const void* buffer, size_t count, float* out) {
  using C = itk::IOComponentEnum;
  switch (type) {
    case C::UCHAR:
      ConvertToFloat<unsigned char>(buffer, count, out);
      return true;
    case C::CHAR:
      ConvertToFloat<signed char>(buffer, count, out);
      return true;
    case C::USHORT:
      ConvertToFloat<unsigned short>(buffer, count, out);
      return true;
    case C::SHORT:
      ConvertToFloat<short>(buffer, count, out);
      return true;
    case C::UINT:
      ConvertToFloat<unsigned int>(buffer, count, out);
      return true;
    case C::INT:
      ConvertToFloat<int>(buffer, count, out);
      return true;
    case C::ULONG:
      ConvertToFloat<unsigned long>(buffer, count, out);
      return true;
    case C::LONG:
      ConvertToFloat<long>(buffer, count, out);
      return true;
    case C::ULONGLONG:
      ConvertToFloat<unsigned long long>(buffer, count, out);
      return true;
    case C::LONGLONG:
      ConvertToFloat<long long>(buffer, count, out);
      return true;
    case C::FLOAT:
      ConvertToFloat<float>(buffer, count, out);
      return true;
    case C::DOUBLE:
      ConvertToFloat<double>(buffer, count, out);
      return true;
    default:
      return false;
  }
}

// The 3D grid of the first three axes of `io` (sizes that fit an int) into `header`.
bool FillGrid(const std::string& path,
              const itk::ImageIOBase& io,
              RawVolume* header,
              std::string* error) {
  for (int a = 0; a < 3; ++a) {
    const uint64_t n = io.GetDimensions(a);
    if (n > static_cast<uint64_t>(INT_MAX)) {
      *error = path + ": size " + std::to_string(n) + " along axis " + std::to_string(a) +
               " is too large";
      return false;
    }
    header->size[a] = static_cast<int>(n);
    header->origin[a] = io.GetOrigin(a);
    header->spacing[a] = io.GetSpacing(a);
    // GetDirection(a) is the direction of index axis a, i.e. column a of D.
    const std::vector<double> axis = io.GetDirection(a);
    for (int r = 0; r < 3; ++r) {
      header->direction[3 * r + a] = r < static_cast<int>(axis.size()) ? axis[r] : 0.0;
    }
  }
  return true;
}

namespace {

// Header checks that need only ITK: scalar pixels, a known component type, 3D (or 4D
// with one volume), sizes that fit an int. Fills the geometry of `header`.
bool InspectHeader(const std::string& path,
                   const itk::ImageIOBase& io,
                   RawVolume* header,
                   std::string* error) {
  const unsigned components = io.GetNumberOfComponents();
  const itk::IOPixelEnum pixel = io.GetPixelType();
  if (pixel != itk::IOPixelEnum::SCALAR || components != 1) {
    *error = path + ": " + itk::ImageIOBase::GetPixelTypeAsString(pixel) + " pixels (" +
             std::to_string(components) + " components); expected a scalar image";
    return false;
  }
  const itk::IOComponentEnum component = io.GetComponentType();
  if (!ConvertBuffer(component, nullptr, 0, nullptr)) {  // a known type converts nothing
    *error =
        path + ": unsupported voxel type " + itk::ImageIOBase::GetComponentTypeAsString(component);
    return false;
  }
  const unsigned dims = io.GetNumberOfDimensions();
  if (dims < 3) {
    *error = path + ": " + std::to_string(dims) + "D image; expected a 3D image";
    return false;
  }
  if (dims > 3) {
    uint64_t volumes = 1;
    for (unsigned d = 3; d < dims; ++d) volumes *= io.GetDimensions(d);
    if (dims > 4 || volumes != 1) {
      std::string extent;
      for (unsigned d = 0; d < dims; ++d) {
        extent += (d ? "x" : "") + std::to_string(io.GetDimensions(d));
      }
      *error = path + ": " + std::to_string(dims) + "D image of size " + extent +
               "; expected a 3D image (4D only with a 4th size of 1)";
      return false;
    }
  }
  return FillGrid(path, io, header, error);
}

template <typename Pixel>
void WriteAs(const RawVolume& volume, const std::string& path, bool compress) {
  using ItkImage = itk::Image<Pixel, 3>;
  auto image = ItkImage::New();
  typename ItkImage::RegionType region;
  typename ItkImage::SpacingType spacing;
  typename ItkImage::PointType origin;
  typename ItkImage::DirectionType direction;
  for (int a = 0; a < 3; ++a) {
    region.SetSize(a, static_cast<itk::SizeValueType>(volume.size[a]));
    spacing[a] = volume.spacing[a];
    origin[a] = volume.origin[a];
    for (int b = 0; b < 3; ++b) direction[a][b] = volume.direction[3 * a + b];
  }
  image->SetRegions(region);
  image->SetSpacing(spacing);
  image->SetOrigin(origin);
  image->SetDirection(direction);
  image->Allocate();
  std::transform(
      volume.voxels.begin(), volume.voxels.end(), image->GetBufferPointer(), [](float v) {
        return static_cast<Pixel>(v);
      });
  auto writer = itk::ImageFileWriter<ItkImage>::New();
  writer->SetFileName(path);
  writer->SetInput(image);
  writer->SetUseCompression(compress);
  writer->Update();
}

}  // namespace

// The checks Read makes before ITK sees `path`: it exists and is a regular file.
bool CheckInputFile(const std::string& path, std::string* error) {
  namespace fs = std::filesystem;
  std::error_code ec;
  const fs::file_status status = fs::status(path, ec);
  if (!fs::exists(status)) {
    *error = path + ": no such file";
    return false;
  }
  if (fs::is_directory(status)) {
    *error = path + ": is a folder, expected an image file";
    return false;
  }
  if (!fs::is_regular_file(status)) {
    *error = path + ": not a regular file";
    return false;
  }
  return true;
}

// ITK's ImageIO for `path` with the header read, after the checks that must run before ITK
// parses it; nullptr with `error` when no ImageIO takes the file or a check fails. Throws
// what ITK throws.
itk::ImageIOBase::Pointer OpenHeader(const std::string& path, std::string* error) {
  itk::ImageIOBase::Pointer io =
      itk::ImageIOFactory::CreateImageIO(path.c_str(), itk::IOFileModeEnum::ReadMode);
  if (!io) {
    *error = path + ": cannot read the header (not a valid NIfTI, MetaImage or NRRD file)";
    return nullptr;
  }
  io->SetFileName(path);
  std::string reason;
  if (!CheckHeaderBeforeItk(io->GetNameOfClass(), path, &reason)) {
    *error = path + ": " + reason;
    return nullptr;
  }
  io->ReadImageInformation();
  return io;
}

// The checks before any voxel of `io` (header read and checked) is read: the data-block
// checks (`checked`: see CheckNiftiData), then CheckVoxelBytesFit.
bool CheckBeforeReading(const itk::ImageIOBase& io,
                        const std::string& path,
                        const std::vector<bool>* checked,
                        std::string* error,
                        DirectVoxels* direct) {
  std::string reason;
  const DataProblem problem = CheckDataBlock(io, path, /*exact=*/false, &reason, checked, direct);
  if (problem != DataProblem::kNone) {
    *error = problem == DataProblem::kVoxel ? path + ": " + reason
                                            : path + ": cannot read the voxels (" + reason + ")";
    return false;
  }
  return CheckVoxelBytesFit(io, path, error);
}

// Reads every voxel component of `io` (header read and checked, CheckBeforeReading passed)
// as float, x fastest (components fastest of all), in one read (in place for float files).
void ReadWholeAsFloat(itk::ImageIOBase& io, std::vector<float>* voxels) {
  const unsigned dims = io.GetNumberOfDimensions();
  itk::ImageIORegion region(dims);
  size_t count = io.GetNumberOfComponents();
  for (unsigned d = 0; d < dims; ++d) {
    region.SetIndex(d, 0);
    region.SetSize(d, io.GetDimensions(d));
    count *= static_cast<size_t>(io.GetDimensions(d));
  }
  io.SetIORegion(region);
  const size_t bytes = static_cast<size_t>(io.GetImageSizeInBytes());
  if (io.GetComponentType() == itk::IOComponentEnum::FLOAT && bytes == count * sizeof(float)) {
    // Already the voxels' type: read in place (no second copy of a large volume).
    voxels->resize(count);
    io.Read(voxels->data());
  } else {
    // 8-byte aligned storage for any component type.
    std::unique_ptr<uint64_t[]> buffer(new uint64_t[bytes / sizeof(uint64_t) + 1]);
    io.Read(buffer.get());
    voxels->resize(count);
    ConvertBuffer(io.GetComponentType(), buffer.get(), count, voxels->data());
  }
}

namespace {

// CheckBeforeReading, then ReadWholeAsFloat, unless the check's pass already holds the
// voxels (DirectVoxels: a float or uint8 NIfTI file is decompressed once, not twice), into
// `volume`'s voxels; its `checked_finite` and `constant` as that pass found them.
bool ReadAllAsFloat(itk::ImageIOBase& io,
                    const std::string& path,
                    RawVolume* volume,
                    std::string* error) {
  std::vector<float>* voxels = &volume->voxels;
  DirectVoxels direct;
  const itk::IOComponentEnum component = io.GetComponentType();
  const bool one_direct = (component == itk::IOComponentEnum::FLOAT ||
                          component == itk::IOComponentEnum::UCHAR) &&
                         io.GetNumberOfComponents() == 1 &&
                         io.GetPixelType() == itk::IOPixelEnum::SCALAR;
  if (one_direct) {
    direct.datatype = component == itk::IOComponentEnum::FLOAT ? 16 : 2;
    direct.count = 1;
    for (unsigned d = 0; d < io.GetNumberOfDimensions(); ++d) direct.count *= io.GetDimensions(d);
    direct.voxels = voxels;
  }
  if (!CheckBeforeReading(io, path, nullptr, error, one_direct ? &direct : nullptr)) return false;
  if (!direct.filled) ReadWholeAsFloat(io, voxels);
  volume->checked_finite = direct.filled && direct.checked;
  volume->constant = volume->checked_finite && direct.constant;
  return true;
}

}  // namespace

// The one-line error for the exception being handled, thrown while a read was at `stage`.
// Call only inside a catch block.
std::string ReadFailure(const std::string& path, const char* stage) {
  try {
    throw;
  } catch (const itk::ExceptionObject& e) {
    std::string what = Describe(e);
    // MetaImageIO appends strerror(errno) to any header it cannot parse, even though the
    // file was opened: "Reason: No such file or directory" would mislead.
    const size_t reason = what.find(" for reading. Reason: ");
    if (reason != std::string::npos) what.erase(reason);
    return path + ": " + stage + " (" + what + ")";
  } catch (const std::bad_alloc&) {
    return path + ": " + stage + " (out of memory; is the header's size right?)";
  } catch (const std::exception& e) {
    return path + ": " + stage + " (" + OneLine(e.what()) + ")";
  }
}

// VerifyWritten for any shape: the written header has at least sizes.size() dimensions of
// these sizes (any further ones of size 1), `components` components of `component`, and
// the data block is complete (exact size).
bool VerifyWrittenShape(const std::vector<uint64_t>& sizes,
                        unsigned components,
                        itk::IOComponentEnum component,
                        const std::string& path,
                        std::string* error) {
  RegisterFactories();
  const ScopedQuietStdErr quiet;
  const auto fail = [&](const std::string& reason) {
    *error = path + ": write failed (disk full or file-size limit?): " + reason;
    return false;
  };
  try {
    itk::ImageIOBase::Pointer io =
        itk::ImageIOFactory::CreateImageIO(path.c_str(), itk::IOFileModeEnum::ReadMode);
    if (!io) return fail("the written header cannot be read back");
    io->SetFileName(path);
    std::string reason;
    if (!CheckHeaderBeforeItk(io->GetNameOfClass(), path, &reason)) return fail(reason);
    io->ReadImageInformation();
    bool same = io->GetNumberOfDimensions() >= sizes.size() &&
                io->GetNumberOfComponents() == components && io->GetComponentType() == component;
    for (unsigned d = 0; same && d < io->GetNumberOfDimensions(); ++d) {
      same = io->GetDimensions(d) == (d < sizes.size() ? sizes[d] : 1);
    }
    if (!same) return fail("the written header does not describe the image");
    if (CheckDataBlock(*io, path, /*exact=*/true, &reason) != DataProblem::kNone) {
      return fail(reason);
    }
    return true;
  } catch (const itk::ExceptionObject& e) {
    return fail("the written header cannot be read back (" + Describe(e) + ")");
  } catch (const std::bad_alloc&) {
    return fail("out of memory while reading it back");
  } catch (const std::exception& e) {
    return fail(OneLine(e.what()));
  }
}

}  // namespace internal

// The helpers the functions of io_itk.h below call.
using internal::CheckInputFile;
using internal::Describe;
using internal::InspectHeader;
using internal::IsRegularFile;
using internal::MetaImageLayout;
using internal::NrrdLayout;
using internal::OneLine;
using internal::OpenHeader;
using internal::ParseMetaImageLayout;
using internal::ParseNrrdLayout;
using internal::ReadAllAsFloat;
using internal::ReadFailure;
using internal::RegisterFactories;
using internal::ScopedQuietStdErr;
using internal::VerifyWrittenShape;
using internal::WriteAs;

bool Read(const std::string& path,
          const HeaderCheck& check_header,
          RawVolume* volume,
          std::string* error) {
  if (!CheckInputFile(path, error)) return false;
  RegisterFactories();
  const ScopedQuietStdErr quiet;
  const char* stage = "cannot read the header";
  try {
    itk::ImageIOBase::Pointer io = OpenHeader(path, error);
    if (!io) return false;
    RawVolume out;
    if (!InspectHeader(path, *io, &out, error)) return false;
    if (check_header && !check_header(out, error)) return false;
    stage = "cannot read the voxels";
    if (!ReadAllAsFloat(*io, path, &out, error)) return false;
    *volume = std::move(out);
    return true;
  } catch (...) {
    *error = ReadFailure(path, stage);
  }
  return false;
}

bool Write(const RawVolume& volume,
           const std::string& path,
           PixelType pixel_type,
           bool compress,
           std::string* error) {
  RegisterFactories();
  const ScopedQuietStdErr quiet;
  try {
    if (pixel_type == PixelType::kUint8) {
      WriteAs<unsigned char>(volume, path, compress);
    } else {
      WriteAs<float>(volume, path, compress);
    }
    // ITK 5.2's NIfTI and MetaImage writers ignore failed writes (niftilib only prints
    // "NWAD: wrote only 0 of N bytes"), so success is decided by reading the result back.
    return VerifyWritten(volume, path, pixel_type, error);
  } catch (const itk::ExceptionObject& e) {
    *error = path + ": cannot write (" + Describe(e) + ")";
  } catch (const std::bad_alloc&) {
    *error = path + ": cannot write (out of memory)";
  } catch (const std::exception& e) {
    *error = path + ": cannot write (" + OneLine(e.what()) + ")";
  }
  return false;
}

bool VerifyWritten(const RawVolume& volume,
                   const std::string& path,
                   PixelType pixel_type,
                   std::string* error) {
  const itk::IOComponentEnum component =
      pixel_type == PixelType::kUint8 ? itk::IOComponentEnum::UCHAR : itk::IOComponentEnum::FLOAT;
  const std::vector<uint64_t> sizes = {static_cast<uint64_t>(volume.size[0]),
                                       static_cast<uint64_t>(volume.size[1]),
                                       static_cast<uint64_t>(volume.size[2])};
  return VerifyWrittenShape(sizes, 1, component, path, error);
}

bool DataFiles(const std::string& path, std::vector<std::string>* files, std::string* error) {
  std::error_code ec;
  const std::filesystem::file_status status = std::filesystem::status(path, ec);
  if (!std::filesystem::exists(status)) {
    *error = path + ": no such file";
    return false;
  }
  if (!std::filesystem::is_regular_file(status)) {
    *error = path + ": not a regular file";
    return false;
  }
  std::string lower = path;
  std::transform(lower.begin(), lower.end(), lower.begin(), [](unsigned char c) {
    return static_cast<char>(std::tolower(c));
  });
  std::vector<std::string> out = {path};
  std::string reason;
  if (EndsWith(lower, ".mha") || EndsWith(lower, ".mhd")) {
    MetaImageLayout layout;
    bool found_data_file = false;
    if (!ParseMetaImageLayout(path, &layout, &found_data_file, &reason)) {
      *error = path + ": cannot read the header (" + reason + ")";
      return false;
    }
    out.insert(out.end(), layout.files.begin(), layout.files.end());
  } else if (EndsWith(lower, ".nrrd") || EndsWith(lower, ".nhdr")) {
    NrrdLayout layout;
    if (!ParseNrrdLayout(path, &layout, &reason)) {
      *error = path + ": cannot read the header (" + reason + ")";
      return false;
    }
    out.insert(out.end(), layout.files.begin(), layout.files.end());
  } else if (EndsWith(lower, ".hdr") || EndsWith(lower, ".hdr.gz")) {
    // Analyze / NIfTI pair: niftilib opens "<stem>.img", else "<stem>.img.gz" (matching the
    // header's case).
    const size_t dot = lower.rfind(".hdr");
    const bool upper = path.compare(dot, 4, ".HDR") == 0;
    const std::string stem = path.substr(0, dot) + (upper ? ".IMG" : ".img");
    const std::string gz = stem + (upper ? ".GZ" : ".gz");
    out.push_back(!IsRegularFile(stem) && IsRegularFile(gz) ? gz : stem);
  }
  // A header may name itself as its data file (HeaderSize skips the text).
  std::vector<std::string> unique;
  for (const std::string& file : out) {
    if (std::find(unique.begin(), unique.end(), file) == unique.end()) unique.push_back(file);
  }
  *files = std::move(unique);
  return true;
}

}  // namespace itk_io
}  // namespace dsr
