// ITK image reading and writing with plain arrays (see io_itk.h for why no Eigen here).
//
// Reading goes through itk::ImageIOBase directly rather than itk::ImageFileReader: the
// header is inspected (pixel type, dimension, geometry) before any voxel is allocated, the
// geometry is copied exactly as stored (the reader would silently flip negative spacings
// and replace the direction of 4D files by a default), and the voxels of any scalar
// component type are converted to float here.
//
// ITK 5.2's NIfTI and MetaImage readers do not fail on a truncated or corrupt data block:
// they return zeros or garbage for the missing part (MetaImage only prints to std::cerr).
// So before ITK reads the voxels, the data block of those formats is checked here: its
// size for uncompressed data, a full decompression (zlib checks its CRC/Adler-32) for
// compressed data. That costs one extra decompression of .nii.gz and compressed .mha
// files; NRRD (teem) already reports such errors itself.
#include "core/io_itk.h"

#include <algorithm>
#include <cmath>
#include <cctype>
#include <cerrno>
#include <climits>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <memory>
#include <mutex>
#include <new>
#include <regex>
#include <streambuf>

#include <itkImage.h>
#include <itkImageFileWriter.h>
#include <itkImageIOBase.h>
#include <itkImageIOFactory.h>
#include <itkImageIORegion.h>
#include <itkMetaImageIOFactory.h>
#include <itkNiftiImageIOFactory.h>
#include <itkNrrdImageIOFactory.h>
#include <itk_zlib.h>

namespace dsr {
namespace itk_io {
namespace {

// MetaIO (and ITK's default OutputWindow) print diagnostics to std::cerr, several lines
// each, on top of the exception or status that is turned into the one-line error. While
// any ITK call of this file runs, std::cerr writes into a stateless sink. The count makes
// overlapping calls from several threads restore the real buffer only once, at the end.
class ScopedQuietStdErr {
 public:
  ScopedQuietStdErr() {
    std::lock_guard<std::mutex> lock(Mutex());
    if (Depth()++ == 0) Saved() = std::cerr.rdbuf(&Sink());
  }
  ~ScopedQuietStdErr() {
    std::lock_guard<std::mutex> lock(Mutex());
    if (--Depth() == 0) std::cerr.rdbuf(Saved());
  }
  ScopedQuietStdErr(const ScopedQuietStdErr&) = delete;
  ScopedQuietStdErr& operator=(const ScopedQuietStdErr&) = delete;

 private:
  class NullBuffer : public std::streambuf {
   protected:
    int_type overflow(int_type c) override { return traits_type::not_eof(c); }
    std::streamsize xsputn(const char*, std::streamsize n) override { return n; }
  };
  static std::mutex& Mutex() {
    static std::mutex mutex;
    return mutex;
  }
  static int& Depth() {
    static int depth = 0;
    return depth;
  }
  static std::streambuf*& Saved() {
    static std::streambuf* saved = nullptr;
    return saved;
  }
  static NullBuffer& Sink() {
    static NullBuffer* sink = new NullBuffer();  // never destroyed: std::cerr may outlive statics
    return *sink;
  }
};

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
bool EndsWith(const std::string& text, const std::string& suffix) {
  return text.size() >= suffix.size() &&
         text.compare(text.size() - suffix.size(), suffix.size(), suffix) == 0;
}

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

template <typename Component>
void ConvertToFloat(const void* buffer, size_t count, float* out) {
  const Component* in = static_cast<const Component*>(buffer);
  std::transform(in, in + count, out, [](Component v) { return static_cast<float>(v); });
}

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

// ---- Data-block checks (see the file comment) ----

// Chunk size for streaming decompression checks.
constexpr size_t kChunkBytes = size_t{1} << 20;

// `what` names the data block: "data" (in the image file) or "data file <name>".
std::string DataEndsEarly(const std::string& what, uint64_t found, uint64_t expected) {
  return what + " ends after " + std::to_string(found) + " of " + std::to_string(expected) +
         " bytes; the file is truncated";
}

// zlib's gzerror() message starts with the file name, which the caller already gives.
std::string Corrupt(const std::string& what, const std::string& zlib_message) {
  return (what == "data" ? "compressed data" : what) + " is corrupt (zlib: " + zlib_message + ")";
}

std::string GzipMessage(const std::string& path, const char* message) {
  const std::string text = message != nullptr ? message : "unknown error";
  const std::string prefix = path + ": ";
  return text.rfind(prefix, 0) == 0 ? text.substr(prefix.size()) : text;
}

template <typename T>
T LoadAt(const unsigned char* bytes, size_t offset, bool swap) {
  unsigned char raw[sizeof(T)];
  std::memcpy(raw, bytes + offset, sizeof(T));
  if (swap) std::reverse(raw, raw + sizeof(T));
  T value;
  std::memcpy(&value, raw, sizeof(T));
  return value;
}

// NIfTI-1 (348-byte header) or NIfTI-2 (540-byte header), plain or gzip-compressed: the
// file must hold vox_offset + product(dim) * bitpix / 8 bytes once decompressed.
bool CheckNiftiData(const std::string& path, std::string* reason) {
  gzFile file = gzopen(path.c_str(), "rb");  // also reads uncompressed files
  if (file == nullptr) {
    *reason = std::strerror(errno);
    return false;
  }
  std::unique_ptr<gzFile_s, int (*)(gzFile)> closer(file, gzclose_r);
  unsigned char header[540];
  if (gzread(file, header, 348) != 348) {
    *reason = "header ends early";
    return false;
  }
  const int32_t sizeof_hdr = LoadAt<int32_t>(header, 0, false);
  const int32_t swapped_sizeof_hdr = LoadAt<int32_t>(header, 0, true);
  const bool swap = sizeof_hdr != 348 && sizeof_hdr != 540;
  const int32_t header_size = swap ? swapped_sizeof_hdr : sizeof_hdr;
  uint64_t voxels = 1;
  int bitpix = 0;
  uint64_t data_start = 0;
  if (header_size == 348) {
    const int ndim = std::clamp<int>(LoadAt<int16_t>(header, 40, swap), 1, 7);
    for (int d = 1; d <= ndim; ++d) {
      voxels *=
          static_cast<uint64_t>(std::max<int16_t>(LoadAt<int16_t>(header, 40 + 2 * d, swap), 1));
    }
    bitpix = LoadAt<int16_t>(header, 72, swap);
    const float vox_offset = LoadAt<float>(header, 108, swap);  // NaN or huge: ITK's problem
    data_start =
        vox_offset > 348.0f && vox_offset < 1e15f ? static_cast<uint64_t>(vox_offset) : 348;
  } else if (header_size == 540) {
    if (gzread(file, header + 348, 540 - 348) != 540 - 348) {
      *reason = "header ends early";
      return false;
    }
    const int ndim = static_cast<int>(std::clamp<int64_t>(LoadAt<int64_t>(header, 16, swap), 1, 7));
    for (int d = 1; d <= ndim; ++d) {
      voxels *=
          static_cast<uint64_t>(std::max<int64_t>(LoadAt<int64_t>(header, 16 + 8 * d, swap), 1));
    }
    bitpix = LoadAt<int16_t>(header, 14, swap);
    data_start = static_cast<uint64_t>(std::max<int64_t>(LoadAt<int64_t>(header, 168, swap), 540));
  } else {
    return true;  // not a NIfTI header this check knows; ITK accepted it, so let ITK read it
  }
  const uint64_t expected = data_start + voxels * static_cast<uint64_t>(std::max(bitpix, 0) / 8);
  if (gzdirect(file)) {  // uncompressed: the file size decides
    std::error_code ec;
    const uint64_t size = std::filesystem::file_size(path, ec);
    if (!ec && size < expected) {
      *reason =
          DataEndsEarly("data", size > data_start ? size - data_start : 0, expected - data_start);
      return false;
    }
    return true;
  }
  uint64_t total = static_cast<uint64_t>(header_size);
  std::unique_ptr<unsigned char[]> chunk(new unsigned char[kChunkBytes]);
  for (;;) {
    const int got = gzread(file, chunk.get(), static_cast<unsigned>(kChunkBytes));
    if (got <= 0) break;
    total += static_cast<uint64_t>(got);
  }
  int status = Z_OK;
  const char* message = gzerror(file, &status);
  if (status != Z_OK) {
    *reason = status == Z_BUF_ERROR
                  ? DataEndsEarly(
                        "data", total > data_start ? total - data_start : 0, expected - data_start)
                  : Corrupt("data", GzipMessage(path, message));
    return false;
  }
  if (total < expected) {
    *reason =
        DataEndsEarly("data", total > data_start ? total - data_start : 0, expected - data_start);
    return false;
  }
  return true;
}

// ITK's NIfTI reader turns the header's orientation into a matrix and runs an SVD that
// aborts the process (vnl assert_finite) when a used field is NaN, infinite or so large
// that the product overflows. Checks those fields first: pixdim always, the quaternion
// fields when qform_code > 0, the srow rows when sform_code > 0 (found by fuzzing).
bool CheckNiftiOrientation(const std::string& path, std::string* reason) {
  gzFile file = gzopen(path.c_str(), "rb");
  if (file == nullptr) return true;  // the data check reports unreadable files
  std::unique_ptr<gzFile_s, int (*)(gzFile)> closer(file, gzclose_r);
  unsigned char header[540];
  if (gzread(file, header, 348) != 348) return true;
  // Like niftilib (which does not insist on sizeof_hdr): NIfTI-2 by its magic, else
  // NIfTI-1; the byte order from dim[0], which must be 1..7.
  const bool nifti2 = std::memcmp(header + 4, "n+2", 4) == 0 || std::memcmp(header + 4, "ni2", 4) == 0;
  bool swap = false;
  if (nifti2) {
    const int32_t sizeof_hdr = LoadAt<int32_t>(header, 0, false);
    swap = sizeof_hdr != 540;
  } else {
    const int16_t dim0 = LoadAt<int16_t>(header, 40, false);
    swap = dim0 < 1 || dim0 > 7;
  }
  const int32_t header_size = nifti2 ? 540 : 348;
  constexpr double kLimit = 1e12;  // mm; far beyond any scanner, far below overflow
  auto bad = [](double v) { return !std::isfinite(v) || std::abs(v) > kLimit; };
  auto fail = [&](const char* field) {
    *reason = std::string("NIfTI header field ") + field + " is not a finite number of sane size";
    return false;
  };
  if (header_size == 348) {
    for (int d = 0; d < 8; ++d) {
      if (bad(LoadAt<float>(header, 76 + 4 * d, swap))) return fail("pixdim");
    }
    if (LoadAt<int16_t>(header, 252, swap) > 0) {
      for (int q = 0; q < 6; ++q) {
        if (bad(LoadAt<float>(header, 256 + 4 * q, swap))) return fail("quatern/qoffset");
      }
    }
    if (LoadAt<int16_t>(header, 254, swap) > 0) {
      for (int q = 0; q < 12; ++q) {
        if (bad(LoadAt<float>(header, 280 + 4 * q, swap))) return fail("srow");
      }
    }
  } else if (header_size == 540) {
    if (gzread(file, header + 348, 540 - 348) != 540 - 348) return true;
    for (int d = 0; d < 8; ++d) {
      if (bad(LoadAt<double>(header, 104 + 8 * d, swap))) return fail("pixdim");
    }
    if (LoadAt<int32_t>(header, 344, swap) > 0) {
      for (int q = 0; q < 6; ++q) {
        if (bad(LoadAt<double>(header, 352 + 8 * q, swap))) return fail("quatern/qoffset");
      }
    }
    if (LoadAt<int32_t>(header, 348, swap) > 0) {
      for (int q = 0; q < 12; ++q) {
        if (bad(LoadAt<double>(header, 400 + 8 * q, swap))) return fail("srow");
      }
    }
  }
  return true;
}

// Inflates the zlib (or gzip) stream that starts at `offset` of `path`; it must end
// cleanly and produce at least `expected` bytes.
bool CheckCompressedStream(const std::string& path,
                           uint64_t offset,
                           uint64_t expected,
                           const std::string& what,
                           std::string* reason) {
  std::ifstream in(path, std::ios::binary);
  in.seekg(static_cast<std::streamoff>(offset));
  z_stream stream{};
  if (inflateInit2(&stream, 15 + 32) != Z_OK) {  // 15 + 32: zlib or gzip header
    *reason = "cannot start zlib";
    return false;
  }
  std::unique_ptr<z_stream, int (*)(z_stream*)> ender(&stream, inflateEnd);
  std::unique_ptr<unsigned char[]> input(new unsigned char[kChunkBytes]);
  std::unique_ptr<unsigned char[]> output(new unsigned char[kChunkBytes]);
  uint64_t total = 0;
  int status = Z_OK;
  while (status != Z_STREAM_END) {
    in.read(reinterpret_cast<char*>(input.get()), static_cast<std::streamsize>(kChunkBytes));
    const std::streamsize got = in.gcount();
    if (got <= 0) {
      *reason = DataEndsEarly(what, total, expected);
      return false;
    }
    stream.next_in = input.get();
    stream.avail_in = static_cast<uInt>(got);
    while (stream.avail_in > 0 && status != Z_STREAM_END) {
      stream.next_out = output.get();
      stream.avail_out = static_cast<uInt>(kChunkBytes);
      status = inflate(&stream, Z_NO_FLUSH);
      if (status != Z_OK && status != Z_STREAM_END && status != Z_BUF_ERROR) {
        *reason = Corrupt(
            what,
            stream.msg != nullptr ? std::string(stream.msg) : "error " + std::to_string(status));
        return false;
      }
      total += kChunkBytes - stream.avail_out;
    }
  }
  if (total < expected) {
    *reason = DataEndsEarly(what, total, expected);
    return false;
  }
  return true;
}

bool IsTrue(const std::string& value) {
  return !value.empty() && (value[0] == 'T' || value[0] == 't' || value[0] == '1');
}

std::string Trim(const std::string& text) {
  const size_t begin = text.find_first_not_of(" \t\r");
  if (begin == std::string::npos) return "";
  return text.substr(begin, text.find_last_not_of(" \t\r") - begin + 1);
}

// ITK's MetaIO copies each header key into a fixed 255-byte buffer with strcpy: a longer
// key (a line without "=" counts whole) overflows it and the process aborts; control
// characters in a value make it read past a buffer (both found by fuzzing). Checks the
// header lines, up to ElementDataFile, first.
bool CheckMetaImageKeys(const std::string& path, std::string* reason) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return true;  // later stages report unreadable files
  constexpr size_t kMaxKey = 250;
  constexpr size_t kMaxHeaderBytes = 1 << 20;
  std::string line;
  size_t read = 0;
  for (int number = 1; std::getline(in, line) && read < kMaxHeaderBytes; ++number) {
    read += line.size() + 1;
    const size_t equals = line.find('=');
    const std::string key = Trim(equals == std::string::npos ? line : line.substr(0, equals));
    // MetaIO splits some values into words without bounds checks; control characters in a
    // header line (found by fuzzing in ElementDataFile) make it read past its buffer.
    for (const char c : line) {
      const unsigned char u = static_cast<unsigned char>(c);
      if (u < 0x20 && c != '\t' && c != '\r') {
        *reason = "MetaImage header line " + std::to_string(number) +
                  " contains control characters (not a text header)";
        return false;
      }
    }
    if (key.size() > kMaxKey) {
      *reason = "MetaImage header line " + std::to_string(number) + " has a key of " +
                std::to_string(key.size()) + " characters (at most " + std::to_string(kMaxKey) +
                ")";
      return false;
    }
    if (equals == std::string::npos && !key.empty()) {
      // MetaIO reads a key up to the next '=', across line ends: "ElementDataFile" alone on
      // a line took the next lines as its value, and a "%" there as a file pattern whose
      // step parsed as 0 (found by fuzzing: integer division by zero in ReadStream).
      *reason = "MetaImage header line " + std::to_string(number) +
                " is not a 'key = value' line";
      return false;
    }
    if (key == "NDims") {
      // MetaIO reads NDims numbers for every array field; a huge NDims (found by fuzzing:
      // 1111...113) made it loop for hours over an exhausted stream.
      const std::string value = Trim(line.substr(equals + 1));
      if (value.empty() || value.size() > 2 ||
          value.find_first_not_of("0123456789") != std::string::npos || std::stoi(value) < 1 ||
          std::stoi(value) > 16) {
        *reason = "MetaImage header line " + std::to_string(number) + ": NDims = '" +
                  value.substr(0, 20) + "' is not a dimension in [1, 16]";
        return false;
      }
    }
    if (key == "ElementDataFile") {
      // A "%" makes MetaIO treat the value as a printf pattern for a file series and pass
      // it to snprintf as the format (found by fuzzing: "%s" crashes). Frames are single
      // volumes: LOCAL, one data file, or LIST.
      if (equals != std::string::npos && line.find('%', equals) != std::string::npos) {
        *reason = "MetaImage ElementDataFile patterns (with %) are not supported";
        return false;
      }
      break;
    }
  }
  return true;
}

// MetaImage (.mha with LOCAL data, .mhd with a data file): `bytes` of voxel data must
// follow the header (LOCAL) or be in the data file, compressed or not. Multi-file data
// (LIST, file patterns) is left to ITK.
bool CheckMetaImageData(const std::string& path, uint64_t bytes, std::string* reason) {
  std::ifstream in(path, std::ios::binary);
  std::string line;
  std::string data_file;
  bool compressed = false;
  int64_t header_size = 0;
  while (data_file.empty() && std::getline(in, line)) {
    const size_t equals = line.find('=');
    if (equals == std::string::npos) continue;
    const std::string key = Trim(line.substr(0, equals));
    const std::string value = Trim(line.substr(equals + 1));
    if (key == "CompressedData") compressed = IsTrue(value);
    if (key == "HeaderSize") header_size = std::atoll(value.c_str());
    if (key == "ElementDataFile") data_file = value;
  }
  if (data_file.empty()) return true;  // ITK parsed a header this check does not follow
  std::string lower = data_file;
  std::transform(
      lower.begin(), lower.end(), lower.begin(), [](unsigned char c) { return std::tolower(c); });
  std::string file = path;
  uint64_t offset = 0;
  if (lower == "local") {
    offset = static_cast<uint64_t>(in.tellg());
  } else if (lower.rfind("list", 0) == 0 || data_file.find('%') != std::string::npos) {
    return true;
  } else {
    const std::filesystem::path data_path(data_file);
    file = (data_path.is_absolute() ? data_path
                                    : std::filesystem::path(path).parent_path() / data_path)
               .string();
    if (!std::filesystem::exists(file)) {
      *reason = "data file " + file + " does not exist";
      return false;
    }
    offset = header_size > 0 ? static_cast<uint64_t>(header_size) : 0;
  }
  const std::string what =
      file == path ? "data" : "data file " + std::filesystem::path(file).filename().string();
  if (compressed) return CheckCompressedStream(file, offset, bytes, what, reason);
  std::error_code ec;
  const uint64_t size = std::filesystem::file_size(file, ec);
  const uint64_t available = !ec && size > offset ? size - offset : 0;
  if (available < bytes) {
    *reason = DataEndsEarly(what, available, bytes);
    return false;
  }
  return true;
}

// Checks the data block of the formats whose ITK readers do not (see the file comment).
bool CheckDataBlock(const itk::ImageIOBase& io, const std::string& path, std::string* reason) {
  const std::string name = io.GetNameOfClass();
  if (name == "NiftiImageIO") return CheckNiftiData(path, reason);
  if (name == "MetaImageIO") {
    return CheckMetaImageData(path, static_cast<uint64_t>(io.GetImageSizeInBytes()), reason);
  }
  return true;
}

}  // namespace

bool Read(const std::string& path,
          const HeaderCheck& check_header,
          RawVolume* volume,
          std::string* error) {
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
  RegisterFactories();
  const ScopedQuietStdErr quiet;
  const char* stage = "cannot read the header";
  try {
    itk::ImageIOBase::Pointer io =
        itk::ImageIOFactory::CreateImageIO(path.c_str(), itk::IOFileModeEnum::ReadMode);
    if (!io) {
      *error = path + ": cannot read the header (not a valid NIfTI, MetaImage or NRRD file)";
      return false;
    }
    io->SetFileName(path);
    {
      const std::string io_name = io->GetNameOfClass();
      std::string reason;
      if ((io_name == "NiftiImageIO" && !CheckNiftiOrientation(path, &reason)) ||
          (io_name == "MetaImageIO" && !CheckMetaImageKeys(path, &reason))) {
        *error = path + ": " + reason;
        return false;
      }
    }
    io->ReadImageInformation();
    RawVolume out;
    if (!InspectHeader(path, *io, &out, error)) return false;
    if (check_header && !check_header(out, error)) return false;

    stage = "cannot read the voxels";
    std::string reason;
    if (!CheckDataBlock(*io, path, &reason)) {
      *error = path + ": " + stage + " (" + reason + ")";
      return false;
    }
    const unsigned dims = io->GetNumberOfDimensions();
    itk::ImageIORegion region(dims);
    for (unsigned d = 0; d < dims; ++d) {
      region.SetIndex(d, 0);
      region.SetSize(d, io->GetDimensions(d));
    }
    io->SetIORegion(region);
    const size_t count = static_cast<size_t>(out.size[0]) * static_cast<size_t>(out.size[1]) *
                         static_cast<size_t>(out.size[2]);
    const size_t bytes = static_cast<size_t>(io->GetImageSizeInBytes());
    // A header that promises more voxel bytes than its file could hold, even at zlib's
    // largest compression ratio (1032:1), is refused before anything is allocated (found by
    // fuzzing: a 421-byte file asked for 12.7 GB). Detached headers (.mhd, .nhdr) point to
    // another file and are left to the data check above.
    const bool attached = EndsWith(path, ".nii") || EndsWith(path, ".nii.gz") ||
                          EndsWith(path, ".mha") || EndsWith(path, ".nrrd");
    const uint64_t file_bytes = fs::file_size(path, ec);
    if (attached && !ec && bytes > 1100 * file_bytes + 4096) {
      *error = path + ": " + stage + " (the header promises " + std::to_string(bytes) +
               " bytes of voxels, more than a " + std::to_string(file_bytes) +
               "-byte file can hold)";
      return false;
    }
    if (io->GetComponentType() == itk::IOComponentEnum::FLOAT && bytes == count * sizeof(float)) {
      // Already the voxels' type: read in place (no second copy of a large volume).
      out.voxels.resize(count);
      io->Read(out.voxels.data());
    } else {
      // 8-byte aligned storage for any component type.
      std::unique_ptr<uint64_t[]> buffer(new uint64_t[bytes / sizeof(uint64_t) + 1]);
      io->Read(buffer.get());
      out.voxels.resize(count);
      ConvertBuffer(io->GetComponentType(), buffer.get(), count, out.voxels.data());
    }
    *volume = std::move(out);
    return true;
  } catch (const itk::ExceptionObject& e) {
    std::string what = Describe(e);
    // MetaImageIO appends strerror(errno) to any header it cannot parse, even though the
    // file was opened: "Reason: No such file or directory" would mislead.
    const size_t reason = what.find(" for reading. Reason: ");
    if (reason != std::string::npos) what.erase(reason);
    *error = path + ": " + stage + " (" + what + ")";
  } catch (const std::bad_alloc&) {
    *error = path + ": " + stage + " (out of memory; is the header's size right?)";
  } catch (const std::exception& e) {
    *error = path + ": " + stage + " (" + OneLine(e.what()) + ")";
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
    return true;
  } catch (const itk::ExceptionObject& e) {
    *error = path + ": cannot write (" + Describe(e) + ")";
  } catch (const std::bad_alloc&) {
    *error = path + ": cannot write (out of memory)";
  } catch (const std::exception& e) {
    *error = path + ": cannot write (" + OneLine(e.what()) + ")";
  }
  return false;
}

}  // namespace itk_io
}  // namespace dsr
