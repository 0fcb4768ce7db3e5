// NIfTI-1 and NIfTI-2 files read byte by byte next to ITK's reader, Eigen-free (see io_itk.h;
// why these checks, see io_itk_checks.cc): the header's layout, the fields to check before
// ITK's NIfTI reader parses them (it would abort, or misread the data's size) and the data
// check (size, decompression, NaN/Inf voxels), whose pass may also copy the voxels out for
// the reader (a whole .nii.gz inflated at once by libdeflate).
#include "dsr/io/io_itk_internal.h"

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>
#include <system_error>
#include <vector>

#include <libdeflate.h>

#include <itk_zlib.h>

namespace dsr {
namespace itk_io {
namespace internal {
namespace {

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

// NIfTI datatype codes with their names and sizes (nifti1.h). The data size of a file
// follows from the datatype, as niftilib reads it: bitpix is redundant, so a bitpix that
// disagrees marks a damaged or hand-edited header whose size cannot be trusted.
struct NiftiType {
  int code;
  const char* name;
  int bits;
};
constexpr NiftiType kNiftiTypes[] = {
    {2, "uint8", 8},         {4, "int16", 16},          {8, "int32", 32},
    {16, "float32", 32},     {32, "complex64", 64},     {64, "float64", 64},
    {128, "rgb24", 24},      {256, "int8", 8},          {512, "uint16", 16},
    {768, "uint32", 32},     {1024, "int64", 64},       {1280, "uint64", 64},
    {1536, "float128", 128}, {1792, "complex128", 128}, {2048, "complex256", 256},
    {2304, "rgba32", 32}};

const NiftiType* FindNiftiType(int code) {
  for (const NiftiType& type : kNiftiTypes) {
    if (type.code == code) return &type;
  }
  return nullptr;
}

}  // namespace

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

namespace {

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
  if (libdeflate_gzip_decompress_ex(decompressor.get(), compressed.get(), static_cast<size_t>(size),
                                    out, static_cast<size_t>(inflated), &in_used,
                                    &out_got) != LIBDEFLATE_SUCCESS ||
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

}  // namespace

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
                           const std::vector<bool>* checked,
                           DirectVoxels* direct) {
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
  const uint64_t phase_voxels =
      static_cast<uint64_t>(layout.size[0] * layout.size[1] * layout.size[2]);
  NonFiniteScan scan(layout.data_start, data_bytes, exact ? 0 : float_bytes, layout.swap, checked,
                     phase_voxels);
  const auto ends_early = [&](uint64_t total) {
    *reason = DataEndsEarly("data", total > layout.data_start ? total - layout.data_start : 0,
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
      layout.intercept == 0.0 && (layout.slope == 0.0 || layout.slope == 1.0) &&
      layout.voxels == direct->count) {
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

}  // namespace internal
}  // namespace itk_io
}  // namespace dsr
