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
// compressed data. The expected size comes from the datatype and the sizes only (a NIfTI
// bitpix that disagrees is refused), and covers every file a MetaImage names (a data
// file, or each LIST slice file). niftilib also replaces NaN/Inf float voxels by 0, so
// NIfTI float data is scanned for them on the way. That costs one extra decompression of
// .nii.gz and compressed .mha files and one extra read of float .nii files; NRRD (teem)
// already reports such errors itself.
//
// Writing: the NIfTI and MetaImage writers report success when the disk is full or a
// file-size limit is hit, so every written file is read back (VerifyWritten) with the same
// checks, demanding the exact size.
//
// Phases (4D images, io_phases.h): the header through the same ImageIOBase path (a scalar
// 4D image, or a NRRD whose one non-spatial axis is a list or vector, which ITK reads as
// vector pixels) and the same data-block checks; the voxels of the phases asked for are
// then decoded by io_phase_stream.h in one pass over the data block, from where each
// format keeps them (ITK 5.2 can read a region of NIfTI and MetaImage files, but reopens
// and re-inflates a compressed file from its start for each region, and reads NRRD
// whole); layouts that reader does not follow are read whole by ITK. Written by ITK's
// writer as a scalar 4D image, or for NRRD by ITK's teem (NrrdIO) directly, since ITK's
// writer gives a non-spatial axis the kind "vector" and no keys of its own, while 3D
// Slicer's .seq.nrrd wants kind "list" and its sequence keys.
#include "dsr/io/io_itk.h"

#include <algorithm>
#include <cmath>
#include <cctype>
#include <cerrno>
#include <climits>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <limits>
#include <memory>
#include <mutex>
#include <new>
#include <regex>
#include <sstream>
#include <streambuf>
#include <vector>

#include <libdeflate.h>

#include <itkImage.h>
#include <itkImageFileWriter.h>
#include <itkImageIOBase.h>
#include <itkImageIOFactory.h>
#include <itkImageIORegion.h>
#include <itkMetaDataObject.h>
#include <itkMetaImageIOFactory.h>
#include <itkNiftiImageIOFactory.h>
#include <itkNrrdImageIOFactory.h>
#include <NrrdIO.h>
#include <itk_zlib.h>

#include "dsr/io/io_phase_stream.h"
#include "dsr/util/text.h"

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

// ---- NIfTI ----

// NIfTI datatype codes with their names and sizes (nifti1.h). The data size of a file
// follows from the datatype, as niftilib reads it: bitpix is redundant, so a bitpix that
// disagrees marks a damaged or hand-edited header whose size cannot be trusted.
struct NiftiType {
  int code;
  const char* name;
  int bits;
};
constexpr NiftiType kNiftiTypes[] = {
    {2, "uint8", 8},         {4, "int16", 16},        {8, "int32", 32},      {16, "float32", 32},
    {32, "complex64", 64},   {64, "float64", 64},     {128, "rgb24", 24},    {256, "int8", 8},
    {512, "uint16", 16},     {768, "uint32", 32},     {1024, "int64", 64},   {1280, "uint64", 64},
    {1536, "float128", 128}, {1792, "complex128", 128}, {2048, "complex256", 256},
    {2304, "rgba32", 32}};

const NiftiType* FindNiftiType(int code) {
  for (const NiftiType& type : kNiftiTypes) {
    if (type.code == code) return &type;
  }
  return nullptr;
}

// Where the voxels of a NIfTI-1 (348-byte header) or NIfTI-2 (540-byte header) file are.
struct NiftiLayout {
  int32_t header_size = 0;
  bool swap = false;
  int datatype = 0;
  int bitpix = 0;
  int64_t size[3] = {1, 1, 1};  // dim[1..3], for voxel indices in messages
  int64_t dim[8] = {0};         // dim[0..7] as stored
  uint64_t voxels = 1;          // product of dim[1..dim[0]]
  uint64_t data_start = 0;      // vox_offset
  // NIfTI-1 only: a single file ("n+1" magic) and scl_slope/scl_inter as niftilib keeps
  // them (a non-finite field becomes 0).
  bool single_file = false;
  double slope = 0.0;
  double intercept = 0.0;
};

// Reads the header at the start of `file` (gzopen'ed, so compressed or not). False when it
// is not a header this file knows (ITK accepted it, so ITK is left to read it).
bool ReadNiftiLayout(gzFile file, NiftiLayout* layout) {
  unsigned char header[540];
  if (gzread(file, header, 348) != 348) return false;
  const int32_t sizeof_hdr = LoadAt<int32_t>(header, 0, false);
  layout->swap = sizeof_hdr != 348 && sizeof_hdr != 540;
  layout->header_size = layout->swap ? LoadAt<int32_t>(header, 0, true) : sizeof_hdr;
  const bool swap = layout->swap;
  if (layout->header_size == 348) {
    for (int d = 0; d < 8; ++d) layout->dim[d] = LoadAt<int16_t>(header, 40 + 2 * d, swap);
    const int ndim = std::clamp<int>(LoadAt<int16_t>(header, 40, swap), 1, 7);
    for (int d = 1; d <= ndim; ++d) {
      const int64_t n = std::max<int16_t>(LoadAt<int16_t>(header, 40 + 2 * d, swap), 1);
      if (d <= 3) layout->size[d - 1] = n;
      layout->voxels *= static_cast<uint64_t>(n);
    }
    layout->datatype = LoadAt<int16_t>(header, 70, swap);
    layout->bitpix = LoadAt<int16_t>(header, 72, swap);
    const float vox_offset = LoadAt<float>(header, 108, swap);  // NaN or huge: ITK's problem
    layout->data_start =
        vox_offset > 348.0f && vox_offset < 1e15f ? static_cast<uint64_t>(vox_offset) : 348;
    // niftilib tells the byte order by dim[0], this header by sizeof_hdr: both must agree.
    const int16_t dim0 = LoadAt<int16_t>(header, 40, swap);
    layout->single_file = std::memcmp(header + 344, "n+1", 4) == 0 && dim0 >= 1 && dim0 <= 7;
    const auto fixed = [](float v) { return std::isfinite(v) ? static_cast<double>(v) : 0.0; };
    layout->slope = fixed(LoadAt<float>(header, 112, swap));
    layout->intercept = fixed(LoadAt<float>(header, 116, swap));
    return true;
  }
  if (layout->header_size == 540) {
    if (gzread(file, header + 348, 540 - 348) != 540 - 348) return false;
    for (int d = 0; d < 8; ++d) layout->dim[d] = LoadAt<int64_t>(header, 16 + 8 * d, swap);
    const int ndim = static_cast<int>(std::clamp<int64_t>(LoadAt<int64_t>(header, 16, swap), 1, 7));
    for (int d = 1; d <= ndim; ++d) {
      // Clamped so that the product cannot overflow; ITK refuses such sizes anyway.
      const int64_t n = std::clamp<int64_t>(LoadAt<int64_t>(header, 16 + 8 * d, swap), 1, 1 << 30);
      if (d <= 3) layout->size[d - 1] = n;
      layout->voxels *= static_cast<uint64_t>(n);
    }
    layout->datatype = LoadAt<int16_t>(header, 12, swap);
    layout->bitpix = LoadAt<int16_t>(header, 14, swap);
    layout->data_start =
        static_cast<uint64_t>(std::max<int64_t>(LoadAt<int64_t>(header, 168, swap), 540));
    return true;
  }
  return false;
}

// A header whose bitpix disagrees with its datatype is refused: which of the two is wrong
// cannot be known, and a file cut to the bitpix size would otherwise pass the size check
// while niftilib, reading by datatype, zero-fills the rest. So is a size below 1 on a used
// axis (the standard requires dim[i] >= 1 for i = 1..dim[0]): the readers take a dim[4] of 0
// or -3 as 1, one phase of a file that may hold more. A dim[0] outside 1..7 is ITK's to
// refuse (niftilib tells the byte order by it).
bool CheckNiftiFields(const std::string& path, std::string* reason) {
  gzFile file = gzopen(path.c_str(), "rb");
  if (file == nullptr) return true;  // the data check reports unreadable files
  std::unique_ptr<gzFile_s, int (*)(gzFile)> closer(file, gzclose_r);
  NiftiLayout layout;
  if (!ReadNiftiLayout(file, &layout)) return true;
  const int64_t ndim = layout.dim[0];
  for (int64_t d = 1; ndim <= 7 && d <= ndim; ++d) {
    if (layout.dim[d] >= 1) continue;
    *reason = "NIfTI header field dim[" + std::to_string(d) + "] is " +
              std::to_string(layout.dim[d]) + "; the standard requires dim[1] to dim[" +
              std::to_string(ndim) + "] (dim[0] = " + std::to_string(ndim) + ") to be >= 1";
    return false;
  }
  const NiftiType* type = FindNiftiType(layout.datatype);
  if (type == nullptr || type->bits == layout.bitpix) return true;
  *reason = "bitpix " + std::to_string(layout.bitpix) + " disagrees with datatype " + type->name +
            " (" + std::to_string(type->bits) + " bits)";
  return false;
}

// Finds the first non-finite value in a stream of float32 or float64 voxels that arrives
// in chunks of any size (and alignment) at increasing offsets.
class NonFiniteScan {
 public:
  // `element_bytes` 4 or 8; 0 scans nothing (integer voxels cannot be NaN). With `checked`
  // (one entry per phase of `phase_voxels` voxels), only the phases it marks count.
  NonFiniteScan(uint64_t data_start,
                uint64_t data_bytes,
                int element_bytes,
                bool swap,
                const std::vector<bool>* checked = nullptr,
                uint64_t phase_voxels = 1)
      : begin_(data_start),
        end_(data_start + data_bytes),
        element_(element_bytes),
        swap_(swap),
        checked_(checked),
        phase_voxels_(std::max<uint64_t>(phase_voxels, 1)) {}

  bool active() const { return element_ != 0; }
  bool found() const { return first_ >= 0; }
  int64_t first_index() const { return first_; }
  bool first_is_nan() const { return first_is_nan_; }

  // `bytes` are the stream's bytes [offset, offset + count).
  void Feed(const unsigned char* bytes, size_t count, uint64_t offset) {
    if (!active() || found()) return;
    const uint64_t from = std::max(offset, begin_);
    const uint64_t to = std::min<uint64_t>(offset + count, end_);
    for (uint64_t at = from; at < to && !found();) {
      const unsigned char* p = bytes + (at - offset);
      if (pending_ == 0 && !swap_ && to - at >= kBlock * static_cast<uint64_t>(element_) &&
          SkipsBlock(p)) {
        at += kBlock * static_cast<uint64_t>(element_);
        index_ += static_cast<int64_t>(kBlock);
        continue;
      }
      if (pending_ == 0 && to - at >= static_cast<uint64_t>(element_)) {
        Check(p);  // a whole element in this chunk
        at += static_cast<uint64_t>(element_);
      } else {  // an element split across chunks
        carry_[pending_++] = *p;
        ++at;
        if (pending_ == element_) {
          Check(carry_);
          pending_ = 0;
        }
      }
    }
  }

 private:
  static constexpr uint64_t kBlock = 1024;  // elements

  // Whether none of the kBlock elements of type `Bits` (uint32_t: float, uint64_t: double)
  // at `p` (this machine's byte order) has its exponent's bits all set (NaN or Inf).
  template <typename Bits>
  static bool AllFinite(const unsigned char* p) {
    constexpr Bits kExponent =
        static_cast<Bits>(sizeof(Bits) == 4 ? 0x7f800000ull : 0x7ff0000000000000ull);
    Bits bad = 0;
    for (uint64_t e = 0; e < kBlock; ++e) {
      Bits bits;
      std::memcpy(&bits, p + e * sizeof(Bits), sizeof(Bits));
      bad |= (bits & kExponent) == kExponent ? 1 : 0;
    }
    return bad == 0;
  }

  // Whether the kBlock whole elements at `p` (this machine's byte order), from index_, lie
  // in one phase that does not count or are all finite: tested without a branch
  // (vectorised); a block that holds a non-finite value is then looked at element by element.
  bool SkipsBlock(const unsigned char* p) const {
    const uint64_t phase = static_cast<uint64_t>(index_) / phase_voxels_;
    if ((static_cast<uint64_t>(index_) + kBlock - 1) / phase_voxels_ != phase) return false;
    return !Counts(phase) || (element_ == 4 ? AllFinite<uint32_t>(p) : AllFinite<uint64_t>(p));
  }

  void Check(const unsigned char* p) {
    bool bad = false;
    bool nan = false;
    if (element_ == 4) {
      const uint32_t bits = LoadAt<uint32_t>(p, 0, swap_);
      bad = (bits & 0x7f800000u) == 0x7f800000u;
      nan = (bits & 0x007fffffu) != 0;
    } else {
      const uint64_t bits = LoadAt<uint64_t>(p, 0, swap_);
      bad = (bits & 0x7ff0000000000000ull) == 0x7ff0000000000000ull;
      nan = (bits & 0x000fffffffffffffull) != 0;
    }
    if (bad && Counts(static_cast<uint64_t>(index_) / phase_voxels_)) {
      first_ = index_;
      first_is_nan_ = nan;
    }
    ++index_;
  }

  bool Counts(uint64_t phase) const {
    return checked_ == nullptr || (phase < checked_->size() && (*checked_)[phase]);
  }

  uint64_t begin_;
  uint64_t end_;
  int element_;
  bool swap_;
  const std::vector<bool>* checked_;
  uint64_t phase_voxels_;
  unsigned char carry_[8] = {};
  int pending_ = 0;
  int64_t index_ = 0;
  int64_t first_ = -1;
  bool first_is_nan_ = false;
};

// Whether a file of `file_bytes` could hold `data_bytes` of voxels, even at zlib's largest
// compression ratio (1032:1), with room for a header: a header promising more (found by
// fuzzing: a 421-byte file asked for 12.7 GB) is refused before anything is allocated.
bool FileCanHold(uint64_t data_bytes, uint64_t file_bytes) {
  return data_bytes <= 1100 * file_bytes + 4096;
}

// How a data check failed: the block is incomplete or corrupt ("cannot read the voxels"),
// or a voxel is not finite (said the way io_image.cc says it for the other formats).
enum class DataProblem { kNone, kData, kVoxel };

// A read that may take its voxels from the data check's own pass (CheckNiftiData): `count`
// voxels expected (ITK's header: one float or uint8 component), stored as float in `voxels`
// when the check could copy them, which `filled` then says. `checked` says that the copy's
// own pass found every voxel finite and set `constant` (whether every voxel holds one
// value), so that the reader need not read them again.
struct DirectVoxels {
  int datatype = 16;  // the NIfTI datatype read directly: 16 (float32) or 2 (uint8)
  uint64_t count = 0;
  std::vector<float>* voxels = nullptr;
  bool filled = false;
  bool checked = false;
  bool constant = false;
};

// CheckNiftiData's direct copy, fast: a single-member gzip file whose trailer gives the
// size it inflates to, read and inflated in one call by libdeflate (clinical frames of 25 MB:
// 44 against zlib's 75 ms), a float32 file into `voxels`' own storage (no second buffer of
// the file's size), a uint8 file into a buffer of its own. Then one pass in chunks that stay
// in cache feeds the scan, puts each chunk's voxels (`element_bytes` each, `data_start` to
// `expected`) in their place as float and compares them with voxel 0, so that the reader need
// not read them again. Sets *total (the inflated bytes) and *constant (whether every voxel
// equals the first) and returns true when it did; false (`voxels` emptied) for anything else:
// the zlib loop then reads the file as before, with its messages for short, long or corrupt
// data.
bool InflateWhole(const std::string& path,
                  uint64_t data_start,
                  uint64_t expected,
                  int element_bytes,
                  NonFiniteScan* scan,
                  std::vector<float>* voxels,
                  uint64_t* total,
                  bool* constant) {
  std::ifstream in(path, std::ios::binary | std::ios::ate);
  if (!in) return false;
  const std::streamoff size = in.tellg();
  if (size < 18) return false;
  const std::unique_ptr<unsigned char[]> compressed(new unsigned char[static_cast<size_t>(size)]);
  in.seekg(0);
  if (!in.read(reinterpret_cast<char*>(compressed.get()), size)) return false;
  if (compressed[0] != 0x1f || compressed[1] != 0x8b) return false;
  const unsigned char* isize = compressed.get() + size - 4;  // the size modulo 2^32
  const uint64_t inflated = uint64_t{isize[0]} | uint64_t{isize[1]} << 8 |
                            uint64_t{isize[2]} << 16 | uint64_t{isize[3]} << 24;
  if (inflated < expected || inflated > expected + (uint64_t{1} << 20)) return false;
  std::unique_ptr<libdeflate_decompressor, void (*)(libdeflate_decompressor*)> decompressor(
      libdeflate_alloc_decompressor(), libdeflate_free_decompressor);
  if (decompressor == nullptr) return false;
  const bool floats = element_bytes == sizeof(float);
  const size_t count = static_cast<size_t>((expected - data_start) / element_bytes);
  std::unique_ptr<unsigned char[]> bytes;  // a uint8 file, inflated
  voxels->resize(floats ? static_cast<size_t>((inflated + sizeof(float) - 1) / sizeof(float))
                        : count);
  if (!floats) bytes.reset(new unsigned char[static_cast<size_t>(inflated)]);
  unsigned char* out = floats ? reinterpret_cast<unsigned char*>(voxels->data()) : bytes.get();
  size_t in_used = 0, out_got = 0;
  if (libdeflate_gzip_decompress_ex(decompressor.get(), compressed.get(),
                                    static_cast<size_t>(size), out, static_cast<size_t>(inflated),
                                    &in_used, &out_got) != LIBDEFLATE_SUCCESS ||
      in_used != static_cast<size_t>(size) || out_got != inflated) {
    voxels->clear();
    return false;
  }
  constexpr uint64_t kPassChunk = uint64_t{1} << 18;  // bytes of the file, a multiple of 4
  const float first = floats ? LoadAt<float>(out, data_start, false) : out[data_start];
  int differs = 0;
  for (uint64_t at = data_start; at < expected; at += kPassChunk) {
    const uint64_t chunk = std::min<uint64_t>(kPassChunk, expected - at);
    scan->Feed(out + at, static_cast<size_t>(chunk), at);
    float* to = voxels->data() + (at - data_start) / element_bytes;
    const size_t n = static_cast<size_t>(chunk / element_bytes);
    if (floats) {
      std::memmove(to, out + at, static_cast<size_t>(chunk));
    } else {
      for (size_t v = 0; v < n; ++v) to[v] = out[at + v];
    }
    for (size_t v = 0; v < n; ++v) differs |= to[v] != first ? 1 : 0;
  }
  voxels->resize(count);
  *total = inflated;
  *constant = differs == 0;
  return true;
}

// NIfTI-1 or NIfTI-2, plain or gzip-compressed: once decompressed the file must hold
// vox_offset + product(dim) * (datatype size) bytes, exactly if `exact` (files just
// written) else at least. Float voxels are scanned for NaN/Inf because niftilib's
// nifti_read_buffer silently replaces them by 0 ("fixes bad floats"), so ITK never shows
// them. The scan rides along the decompression for .nii.gz and costs one read of the file
// for .nii. With `checked` (one entry per phase of a 4D file), only the phases it marks are
// scanned: the others are not read.
//
// With `direct`, a file of its datatype (float32 in this machine's byte order, or uint8)
// without scaling (what nifti_read_buffer would hand ITK unchanged, bad floats aside, which
// the scan refuses) also has its voxels copied out as float as the check decompresses them:
// ITK's read would decompress the whole file a second time for the same bytes. The zlib loop
// (a file libdeflate does not take whole) copies float32 files only.
DataProblem CheckNiftiData(const std::string& path,
                           bool exact,
                           std::string* reason,
                           const std::vector<bool>* checked = nullptr,
                           DirectVoxels* direct = nullptr) {
  gzFile file = gzopen(path.c_str(), "rb");  // also reads uncompressed files
  if (file == nullptr) {
    *reason = std::strerror(errno);
    return DataProblem::kData;
  }
  std::unique_ptr<gzFile_s, int (*)(gzFile)> closer(file, gzclose_r);
  NiftiLayout layout;
  if (!ReadNiftiLayout(file, &layout)) {
    if (!exact) return DataProblem::kNone;  // not a header this check knows; ITK read it
    *reason = "header ends early";
    return DataProblem::kData;
  }
  const NiftiType* type = FindNiftiType(layout.datatype);
  if (type == nullptr) return DataProblem::kNone;  // ITK refuses or reads what it knows
  const uint64_t data_bytes = layout.voxels * static_cast<uint64_t>(type->bits / 8);
  const uint64_t expected = layout.data_start + data_bytes;
  const int float_bytes = layout.datatype == 16 ? 4 : layout.datatype == 64 ? 8 : 0;
  const uint64_t phase_voxels = static_cast<uint64_t>(layout.size[0] * layout.size[1] *
                                                      layout.size[2]);
  NonFiniteScan scan(layout.data_start, data_bytes, exact ? 0 : float_bytes, layout.swap, checked,
                     phase_voxels);
  const auto ends_early = [&](uint64_t total) {
    *reason = DataEndsEarly("data",
                            total > layout.data_start ? total - layout.data_start : 0,
                            data_bytes);
    return DataProblem::kData;
  };
  const auto too_long = [&](uint64_t total) {
    *reason = "data holds " + std::to_string(total - layout.data_start) + " bytes, expected " +
              std::to_string(data_bytes);
    return DataProblem::kData;
  };
  if (gzdirect(file) && !scan.active()) {  // uncompressed, nothing to scan: the size decides
    std::error_code ec;
    const uint64_t size = std::filesystem::file_size(path, ec);
    if (ec) {
      *reason = ec.message();
      return DataProblem::kData;
    }
    if (size < expected) return ends_early(size);
    if (exact && size != expected) return too_long(size);
    return DataProblem::kNone;
  }
  // The direct copy: only for a file that could hold the voxels at zlib's largest ratio
  // (a fuzzed header asking for gigabytes gets the check's own message, not an allocation).
  bool copy = false;
  if (direct != nullptr && !exact && checked == nullptr && layout.header_size == 348 &&
      layout.datatype == direct->datatype && !layout.swap && layout.single_file &&
      layout.intercept == 0.0 &&
      (layout.slope == 0.0 || layout.slope == 1.0) && layout.voxels == direct->count) {
    std::error_code ec;
    const uint64_t file_bytes = std::filesystem::file_size(path, ec);
    copy = !ec && FileCanHold(data_bytes, file_bytes);
  }
  uint64_t total = static_cast<uint64_t>(layout.header_size);
  const bool inflated = copy && !gzdirect(file) &&
                        InflateWhole(path, layout.data_start, expected, type->bits / 8, &scan,
                                     direct->voxels, &total, &direct->constant);
  unsigned char* copy_to = nullptr;
  if (copy && !inflated && layout.datatype == 16) {  // the zlib loop copies floats only
    direct->voxels->resize(static_cast<size_t>(layout.voxels));
    copy_to = reinterpret_cast<unsigned char*>(direct->voxels->data());
  }
  std::unique_ptr<unsigned char[]> chunk(new unsigned char[kChunkBytes]);
  for (; !inflated;) {
    const int got = gzread(file, chunk.get(), static_cast<unsigned>(kChunkBytes));
    if (got <= 0) break;
    scan.Feed(chunk.get(), static_cast<size_t>(got), total);
    if (copy_to != nullptr) {
      const uint64_t from = std::max(total, layout.data_start);
      const uint64_t to = std::min(total + static_cast<uint64_t>(got), expected);
      if (from < to) {
        std::memcpy(copy_to + (from - layout.data_start), chunk.get() + (from - total), to - from);
      }
    }
    total += static_cast<uint64_t>(got);
  }
  int status = Z_OK;
  const char* message = gzerror(file, &status);
  if (status != Z_OK) {
    if (status == Z_BUF_ERROR) return ends_early(total);
    *reason = Corrupt("data", GzipMessage(path, message));
    return DataProblem::kData;
  }
  if (total < expected) return ends_early(total);
  if (exact && total != expected) return too_long(total);
  if (scan.found()) {
    const int64_t first = scan.first_index();
    const int64_t nx = layout.size[0];
    const int64_t nxy = nx * layout.size[1];
    const int64_t nxyz = nxy * layout.size[2];
    const int64_t v = first % nxyz;  // within its 3D volume (a 4D file's phase)
    const std::string phase = static_cast<int64_t>(layout.voxels) > nxyz
                                  ? "phase " + std::to_string(first / nxyz) + ": "
                                  : "";
    *reason = phase + "voxel (" + std::to_string(v % nx) + "," + std::to_string((v % nxy) / nx) +
              "," + std::to_string(v / nxy) + ") is " + (scan.first_is_nan() ? "NaN" : "Inf");
    return DataProblem::kVoxel;
  }
  if (inflated || copy_to != nullptr) direct->filled = true;
  if (inflated) direct->checked = true;
  return DataProblem::kNone;
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
  const bool nifti2 =
      std::memcmp(header + 4, "n+2", 4) == 0 || std::memcmp(header + 4, "ni2", 4) == 0;
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
// cleanly and produce at least `expected` bytes (exactly `expected` if `exact`).
bool CheckCompressedStream(const std::string& path,
                           uint64_t offset,
                           uint64_t expected,
                           bool exact,
                           const std::string& what,
                           std::string* reason) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    *reason = what + " cannot be opened (" + std::strerror(errno) + ")";
    return false;
  }
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
  if (exact && total != expected) {
    *reason = what + " decompresses to " + std::to_string(total) + " bytes, expected " +
              std::to_string(expected);
    return false;
  }
  return true;
}

// The size of `file` from `offset` on must be at least `bytes` (exactly `bytes` if `exact`).
bool CheckPlainData(const std::string& file,
                    uint64_t offset,
                    uint64_t bytes,
                    bool exact,
                    const std::string& what,
                    std::string* reason) {
  std::error_code ec;
  const uint64_t size = std::filesystem::file_size(file, ec);
  if (ec) {
    *reason = what + " cannot be read (" + ec.message() + ")";
    return false;
  }
  const uint64_t available = size > offset ? size - offset : 0;
  if (available < bytes) {
    *reason = DataEndsEarly(what, available, bytes);
    return false;
  }
  if (exact && available != bytes) {
    *reason = what + " holds " + std::to_string(available) + " bytes, expected " +
              std::to_string(bytes);
    return false;
  }
  return true;
}

bool IsTrue(const std::string& value) {
  return !value.empty() && (value[0] == 'T' || value[0] == 't' || value[0] == '1');
}

std::vector<std::string> Words(const std::string& text) {
  std::vector<std::string> words;
  std::istringstream in(text);
  for (std::string word; in >> word;) words.push_back(word);
  return words;
}

// A data file named in a detached header, as MetaIO and teem open it: an absolute name as
// is, a relative one after the header's folder, textually (the path stays as the user gave
// it: "d/in.mhd" names "d/in.raw").
std::string BesideHeader(const std::string& header, const std::string& name) {
  if (!name.empty() && name[0] == '/') return name;
  const size_t slash = header.rfind('/');
  return slash == std::string::npos ? name : header.substr(0, slash + 1) + name;
}

bool IsRegularFile(const std::string& path) {
  std::error_code ec;
  return std::filesystem::is_regular_file(path, ec);
}

// Most header bytes read before giving up on finding the end of a text header.
constexpr size_t kMaxHeaderBytes = size_t{1} << 20;
// Most data files a LIST or pattern may name (one per slice of a 3D image in practice).
constexpr uint64_t kMaxDataFiles = 100000;

// Where the voxels of a MetaImage (.mha/.mhd) are, parsed the way MetaIO 5.2 parses them
// (metaImage.cxx, ReadStream): "LOCAL" (also "Local", "local") after the header; "LIST
// [nD]" one file per n-D slice, named on the lines after the header; a name containing
// "%" a file pattern; anything else one data file, where MetaIO falls back to "<name>.gz"
// and "<name>.Z" (then compressed) when <name> does not exist.
struct MetaImageLayout {
  enum class Kind { kLocal, kFile, kList };
  Kind kind = Kind::kLocal;
  bool compressed = false;
  int64_t header_size = 0;      // HeaderSize: bytes skipped in each data file, -1 = data at the end
  bool msb = false;             // BinaryDataByteOrderMSB (or ElementByteOrderMSB): big-endian
  bool binary = false;          // BinaryData (MetaIO reads text voxels without it)
  std::vector<int64_t> dims;    // DimSize
  uint64_t local_offset = 0;    // kLocal: where the data starts in the header file
  std::vector<std::string> files;  // kFile: the data file; kList: one per slice, in order
};

// False with `reason` when the header names its data in a way that cannot be followed
// (or, with `found_data_file` false, has no ElementDataFile line at all).
bool ParseMetaImageLayout(const std::string& path,
                          MetaImageLayout* layout,
                          bool* found_data_file,
                          std::string* reason) {
  *found_data_file = false;
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    *reason = std::string("cannot open the header (") + std::strerror(errno) + ")";
    return false;
  }
  std::string line;
  std::string value;
  size_t read = 0;
  while (read < kMaxHeaderBytes && std::getline(in, line)) {
    read += line.size() + 1;
    const size_t equals = line.find('=');
    if (equals == std::string::npos) continue;
    const std::string key = Trim(line.substr(0, equals));
    const std::string text = Trim(line.substr(equals + 1));
    if (key == "CompressedData") layout->compressed = IsTrue(text);
    if (key == "HeaderSize") layout->header_size = std::atoll(text.c_str());
    if (key == "BinaryDataByteOrderMSB" || key == "ElementByteOrderMSB") layout->msb = IsTrue(text);
    if (key == "BinaryData") layout->binary = IsTrue(text);
    if (key == "DimSize") {
      layout->dims.clear();
      for (const std::string& word : Words(text)) layout->dims.push_back(std::atoll(word.c_str()));
    }
    if (key == "ElementDataFile") {
      value = text;
      *found_data_file = true;
      break;
    }
  }
  if (!*found_data_file) {
    *reason = "the MetaImage header has no ElementDataFile line";
    return false;
  }
  if (value == "LOCAL" || value == "Local" || value == "local") {
    layout->kind = MetaImageLayout::Kind::kLocal;
    layout->local_offset = static_cast<uint64_t>(in.tellg());
    return true;
  }
  if (value.compare(0, 4, "LIST") == 0) {
    layout->kind = MetaImageLayout::Kind::kList;
    const int ndims = static_cast<int>(layout->dims.size());
    const std::vector<std::string> words = Words(value);
    // MetaIO: "LIST 2D" -> 2; 0 (none given) or more than NDims -> NDims - 1.
    int file_dims = words.size() > 1 ? static_cast<int>(std::atof(words[1].c_str())) : 0;
    if (file_dims == 0 || file_dims > ndims) file_dims = ndims - 1;
    // MetaIO indexes its sizes with this number unchecked: a negative one or NDims itself
    // reads outside them, so only 1..NDims-1 is followed.
    if (file_dims < 1 || file_dims >= ndims) {
      *reason = "ElementDataFile = " + value + ": each LIST file must hold 1 to " +
                std::to_string(ndims - 1) + " dimensions";
      return false;
    }
    uint64_t count = 1;
    for (int d = file_dims; d < ndims; ++d) {
      count *= static_cast<uint64_t>(std::max<int64_t>(layout->dims[d], 1));
      if (count > kMaxDataFiles) {
        *reason = "ElementDataFile = " + value + " needs more than " +
                  std::to_string(kMaxDataFiles) + " slice files";
        return false;
      }
    }
    while (layout->files.size() < count && std::getline(in, line)) {
      // MetaIO skips a last name that is not followed by a line end (it stops at eof), so
      // that slice would be left unread.
      if (in.eof()) break;
      // MetaIO strips trailing blanks and unprintable characters but keeps the first one,
      // and an empty line makes it index before the start of the name.
      size_t end = line.size();
      while (end > 1 && (std::isspace(static_cast<unsigned char>(line[end - 1])) ||
                         !std::isprint(static_cast<unsigned char>(line[end - 1])))) {
        --end;
      }
      if (end == 0) {
        *reason = "ElementDataFile = LIST: slice file name " +
                  std::to_string(layout->files.size() + 1) + " is empty";
        return false;
      }
      layout->files.push_back(BesideHeader(path, line.substr(0, end)));
    }
    if (layout->files.size() < count) {
      *reason = "ElementDataFile = " + value + " names " + std::to_string(layout->files.size()) +
                " of the " + std::to_string(count) + " slice files (each on a line of its own)";
      return false;
    }
    return true;
  }
  if (value.find('%') != std::string::npos) {
    // A printf pattern that MetaIO passes to snprintf unchecked (found by fuzzing: "%s"
    // crashes). Frames are single volumes: LOCAL, one data file, or LIST.
    *reason = "MetaImage ElementDataFile patterns (with %) are not supported";
    return false;
  }
  layout->kind = MetaImageLayout::Kind::kFile;
  std::string file = BesideHeader(path, value);
  if (!IsRegularFile(file)) {
    for (const char* suffix : {".gz", ".Z"}) {
      if (IsRegularFile(file + suffix)) {
        file += suffix;
        layout->compressed = true;
        break;
      }
    }
  }
  layout->files.push_back(file);
  return true;
}

// MetaImage: `bytes` of voxel data must follow the header (LOCAL), be in the data file, or
// be spread over the LIST slice files, compressed or not; exactly so if `exact`.
bool CheckMetaImageData(const std::string& path, uint64_t bytes, bool exact, std::string* reason) {
  MetaImageLayout layout;
  bool found_data_file = false;
  if (!ParseMetaImageLayout(path, &layout, &found_data_file, reason)) {
    return !found_data_file && !exact;  // ITK parsed a header this check does not follow
  }
  if (layout.kind == MetaImageLayout::Kind::kLocal) {
    if (layout.compressed) {
      return CheckCompressedStream(path, layout.local_offset, bytes, exact, "data", reason);
    }
    return CheckPlainData(path, layout.local_offset, bytes, exact, "data", reason);
  }
  if (layout.kind == MetaImageLayout::Kind::kList && layout.compressed) {
    // MetaIO inflates each slice with the whole image's CompressedDataSize: not followed.
    *reason = "compressed LIST slice files are not supported";
    return false;
  }
  const uint64_t file_bytes = bytes / layout.files.size();
  for (const std::string& file : layout.files) {
    const std::string what =
        layout.kind == MetaImageLayout::Kind::kList
            ? "slice file " + file
            : "data file " + std::filesystem::path(file).filename().string();
    if (!IsRegularFile(file)) {
      *reason = (layout.kind == MetaImageLayout::Kind::kList ? "slice file " : "data file ") +
                file + " does not exist";
      return false;
    }
    if (layout.compressed) {
      if (!CheckCompressedStream(file, 0, file_bytes, exact, what, reason)) return false;
      continue;
    }
    // HeaderSize > 0 skips that many bytes; -1 means "the data is at the end".
    const uint64_t offset = layout.header_size > 0 ? static_cast<uint64_t>(layout.header_size) : 0;
    if (!CheckPlainData(file, offset, file_bytes, exact && layout.header_size >= 0, what, reason)) {
      return false;
    }
  }
  return true;
}

// Where the voxels of a NRRD (.nrrd/.nhdr) are, as teem reads them: after the header's
// first empty line, or in the file(s) named by "data file:" (one name, "LIST [subdim]"
// with the names on the remaining lines, or "<printf format> <min> <max> <step>
// [subdim]"), relative to the header's folder.
struct NrrdLayout {
  std::string encoding = "raw";
  uint64_t data_offset = 0;        // attached data: where it starts in the header file
  std::vector<std::string> files;  // detached data files, in order
  // The fields the phase reader follows (ReadPhases): as written, "" or empty when absent.
  std::vector<std::string> sizes;
  std::vector<std::string> kinds;
  std::string endian;
  std::string line_skip;
  std::string byte_skip;
};

// Expands a teem file pattern: `format` must hold exactly one integer conversion
// ("%d", "%03d", ...), anything else could make snprintf read arguments that are not there.
bool ExpandNrrdPattern(const std::string& header,
                       const std::vector<std::string>& words,
                       std::vector<std::string>* files,
                       std::string* reason) {
  static const std::regex kOneInteger(R"(([^%]|%%)*%[-+ 0#]?[0-9]{0,3}[diu]([^%]|%%)*)");
  static const std::regex kInteger(R"([-+]?[0-9]{1,9})");
  const std::string& format = words[0];
  if (!std::regex_match(format, kOneInteger) || !std::regex_match(words[1], kInteger) ||
      !std::regex_match(words[2], kInteger) || !std::regex_match(words[3], kInteger)) {
    *reason = "data file pattern '" + format + " " + words[1] + " " + words[2] + " " + words[3] +
              "' is not '<format with one %d> <min> <max> <step>'";
    return false;
  }
  const int64_t first = std::stoll(words[1]);
  const int64_t last = std::stoll(words[2]);
  const int64_t step = std::stoll(words[3]);
  if (step == 0 || (last - first) / step < 0 ||
      static_cast<uint64_t>((last - first) / step) >= kMaxDataFiles) {
    *reason = "data file pattern '" + format + "' has an unusable range " + words[1] + ".." +
              words[2] + " step " + words[3];
    return false;
  }
  for (int64_t i = first; step > 0 ? i <= last : i >= last; i += step) {
    char name[4096];
    std::snprintf(name, sizeof(name), format.c_str(), static_cast<int>(i));
    files->push_back(BesideHeader(header, name));
  }
  return true;
}

bool ParseNrrdLayout(const std::string& path, NrrdLayout* layout, std::string* reason) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    *reason = std::string("cannot open the header (") + std::strerror(errno) + ")";
    return false;
  }
  std::string line;
  if (!std::getline(in, line) || line.compare(0, 4, "NRRD") != 0) {
    *reason = "not a NRRD header (the first line is not NRRD000x)";
    return false;
  }
  size_t read = line.size() + 1;
  bool list = false;
  while (read < kMaxHeaderBytes && std::getline(in, line)) {
    read += line.size() + 1;
    if (list) {  // the rest of the header file names the data files
      const std::string name = Trim(line);
      if (!name.empty()) layout->files.push_back(BesideHeader(path, name));
      continue;
    }
    if (Trim(line).empty()) break;  // the header ends at its first empty line
    if (line[0] == '#' || line.find(":=") != std::string::npos) continue;  // comment, key/value
    const size_t colon = line.find(':');
    if (colon == std::string::npos) continue;
    const std::string field = Trim(line.substr(0, colon));
    const std::string value = Trim(line.substr(colon + 1));
    if (field == "encoding") layout->encoding = value;
    if (field == "sizes") layout->sizes = Words(value);
    if (field == "kinds") layout->kinds = Words(value);
    if (field == "endian") layout->endian = value;
    if (field == "line skip" || field == "lineskip") layout->line_skip = value;
    if (field == "byte skip" || field == "byteskip") layout->byte_skip = value;
    if (field == "data file" || field == "datafile") {
      const std::vector<std::string> words = Words(value);
      if (!words.empty() && words[0] == "LIST") {
        list = true;
      } else if ((words.size() == 4 || words.size() == 5) &&
                 words[0].find('%') != std::string::npos) {
        if (!ExpandNrrdPattern(path, words, &layout->files, reason)) return false;
      } else {
        layout->files.push_back(BesideHeader(path, value));
      }
    }
  }
  layout->data_offset = in ? static_cast<uint64_t>(in.tellg()) : 0;
  return true;
}

// NRRD just written (raw or gzip encoding): `bytes` of voxels, exactly, after the header
// or in its data file. Reading leaves this to teem, which checks sizes itself.
bool CheckWrittenNrrdData(const std::string& path, uint64_t bytes, std::string* reason) {
  NrrdLayout layout;
  if (!ParseNrrdLayout(path, &layout, reason)) return false;
  const bool gzip = layout.encoding == "gzip" || layout.encoding == "gz";
  if (!gzip && layout.encoding != "raw") {
    *reason = "unexpected NRRD encoding " + layout.encoding;
    return false;
  }
  if (layout.files.size() > 1) {
    *reason = "NRRD data split over " + std::to_string(layout.files.size()) + " files";
    return false;
  }
  const std::string file = layout.files.empty() ? path : layout.files[0];
  const uint64_t offset = layout.files.empty() ? layout.data_offset : 0;
  const std::string what = layout.files.empty()
                               ? "data"
                               : "data file " + std::filesystem::path(file).filename().string();
  if (gzip) return CheckCompressedStream(file, offset, bytes, true, what, reason);
  return CheckPlainData(file, offset, bytes, true, what, reason);
}

// Checks the data block of the formats whose ITK readers do not (see the file comment);
// with `exact`, of a file just written, for every format. `checked`: see CheckNiftiData.
DataProblem CheckDataBlock(const itk::ImageIOBase& io,
                           const std::string& path,
                           bool exact,
                           std::string* reason,
                           const std::vector<bool>* checked = nullptr,
                           DirectVoxels* direct = nullptr) {
  const std::string name = io.GetNameOfClass();
  const uint64_t bytes = static_cast<uint64_t>(io.GetImageSizeInBytes());
  bool ok = true;
  if (name == "NiftiImageIO") return CheckNiftiData(path, exact, reason, checked, direct);
  if (name == "MetaImageIO") ok = CheckMetaImageData(path, bytes, exact, reason);
  if (name == "NrrdImageIO" && exact) ok = CheckWrittenNrrdData(path, bytes, reason);
  return ok ? DataProblem::kNone : DataProblem::kData;
}

// ITK's MetaIO copies each header key into a fixed 255-byte buffer with strcpy: a longer
// key (a line without "=" counts whole) overflows it and the process aborts; control
// characters in a value make it read past a buffer (both found by fuzzing). Checks the
// header lines, up to ElementDataFile, first.
bool CheckMetaImageKeys(const std::string& path, std::string* reason) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return true;  // later stages report unreadable files
  constexpr size_t kMaxKey = 250;
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

// Checks that must run before ITK parses a header: ITK would abort on it (see the
// functions) or read it by rules that disagree with the file's size.
bool CheckHeaderBeforeItk(const std::string& io_name,
                          const std::string& path,
                          std::string* reason) {
  if (io_name == "NiftiImageIO") {
    return CheckNiftiOrientation(path, reason) && CheckNiftiFields(path, reason);
  }
  if (io_name == "MetaImageIO") return CheckMetaImageKeys(path, reason);
  return true;
}

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

// A header that promises more voxel bytes than its file could hold, even at zlib's largest
// compression ratio (1032:1), is refused before anything is allocated (found by fuzzing: a
// 421-byte file asked for 12.7 GB). A .mhd's data files are measured by the data check
// (CheckDataBlock); a .nhdr's data is bounded here by the files that hold it, itself or
// its data files (one that is not a regular file, /dev/zero, counts 0 bytes), since the
// phase reader and ITK allocate the voxels before teem reads them (found by fuzzing: a
// 2.5 KB .nhdr asked for 1.6 TB).
bool CheckVoxelBytesFit(const itk::ImageIOBase& io, const std::string& path, std::string* error) {
  namespace fs = std::filesystem;
  const size_t bytes = static_cast<size_t>(io.GetImageSizeInBytes());
  const bool attached = EndsWith(path, ".nii") || EndsWith(path, ".nii.gz") ||
                        EndsWith(path, ".mha") || EndsWith(path, ".nrrd");
  std::error_code ec;
  uint64_t file_bytes = fs::file_size(path, ec);
  bool bounded = attached && !ec;
  std::string holder = "a " + std::to_string(file_bytes) + "-byte file";
  NrrdLayout layout;
  std::string reason;
  if (!attached && !ec && std::string(io.GetNameOfClass()) == "NrrdImageIO" &&
      ParseNrrdLayout(path, &layout, &reason)) {
    bounded = true;
    if (!layout.files.empty()) {
      file_bytes = 0;
      for (const std::string& file : layout.files) {
        const uint64_t size = fs::is_regular_file(file, ec) ? fs::file_size(file, ec) : 0;
        file_bytes += ec ? 0 : size;
      }
      holder = std::string(layout.files.size() > 1 ? "its data files" : "its data file") +
               " (" + std::to_string(file_bytes) + " bytes)";
    }
  }
  if (bounded && !FileCanHold(bytes, file_bytes)) {
    *error = path + ": cannot read the voxels (the header promises " + std::to_string(bytes) +
             " bytes of voxels, more than " + holder + " can hold)";
    return false;
  }
  return true;
}

// The checks before any voxel of `io` (header read and checked) is read: the data-block
// checks (`checked`: see CheckNiftiData), then CheckVoxelBytesFit.
bool CheckBeforeReading(const itk::ImageIOBase& io,
                        const std::string& path,
                        const std::vector<bool>* checked,
                        std::string* error,
                        DirectVoxels* direct = nullptr) {
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

// ---- Phases (io_phases.h) ----

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

bool NrrdCount(const std::string& text, uint64_t* value);
int NrrdPhaseAxis(const itk::ImageIOBase& io,
                  const NrrdLayout& layout,
                  const std::vector<uint64_t>& sizes);

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
        *error = path + ": " + named + " is '" + type + "'; 3D Slicer's index types are numeric "
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
      *error = path + ": the header's directions mix the 4th axis with space; expected three "
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

// ---- Phase by phase (io_phase_stream.h): where each format keeps its voxels ----

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
  static constexpr Code kCodes[] = {{2, S::kUint8},    {4, S::kInt16},   {8, S::kInt32},
                                    {16, S::kFloat32}, {64, S::kFloat64}, {256, S::kInt8},
                                    {512, S::kUint16}, {768, S::kUint32}, {1024, S::kInt64},
                                    {1280, S::kUint64}};
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
      (layout.compressed && (layout.kind == MetaImageLayout::Kind::kList ||
                             layout.header_size < 0))) {
    return false;
  }
  for (const std::string& file : layout.files) {
    phase_stream::Part part;
    if (!PlainPart(file, layout.header_size, bytes / layout.files.size(), &part)) return false;
    source->parts.push_back(part);
  }
  return true;
}

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

// Where the phases of the 4D image `io` read are kept, for phase_stream::ReadPhases; false
// when the file keeps them in a way that reader does not follow (ReadPhases then reads the
// file whole).
bool PhaseSource(const std::string& path,
                 const itk::ImageIOBase& io,
                 const PhasesHeader& header,
                 phase_stream::Source* source) {
  const std::string name = io.GetNameOfClass();
  source->phases = header.phases;
  source->voxels = static_cast<uint64_t>(header.grid.size[0]) * header.grid.size[1] *
                   header.grid.size[2];
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
bool DescribeNrrdList(const RawVolume& grid,
                      size_t phases,
                      bool sequence,
                      float* data,
                      Nrrd* nrrd) {
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
  std::unique_ptr<NrrdIoState, NrrdIoState* (*)(NrrdIoState*)> io(nrrdIoStateNew(),
                                                                   nrrdIoStateNix);
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
    } else if (!WriteNrrdList(grid, phases, path, layout == PhasesLayout::kSlicerSequence,
                              compress, error)) {
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
