// The data-block checks around ITK's readers (io_itk.cc), Eigen-free like it (see io_itk.h):
// which checks run, by format, before ITK parses a header (CheckHeaderBeforeItk) and before
// it reads the voxels (CheckDataBlock, CheckVoxelBytesFit), and the checks of plain and
// compressed data that the formats share. Each format's own checks are in io_itk_nifti.cc
// (NIfTI) and io_itk_headers.cc (MetaImage and NRRD).
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
#include "dsr/io/io_itk_internal.h"

#include <cerrno>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>
#include <system_error>
#include <vector>

#include <itkImageIOBase.h>
#include <itk_zlib.h>

#include "dsr/util/text.h"

namespace dsr {
namespace itk_io {
namespace internal {

// `what` names the data block: "data" (in the image file) or "data file <name>".
std::string DataEndsEarly(const std::string& what, uint64_t found, uint64_t expected) {
  return what + " ends after " + std::to_string(found) + " of " + std::to_string(expected) +
         " bytes; the file is truncated";
}

// zlib's gzerror() message starts with the file name, which the caller already gives.
std::string Corrupt(const std::string& what, const std::string& zlib_message) {
  return (what == "data" ? "compressed data" : what) + " is corrupt (zlib: " + zlib_message + ")";
}

// Whether a file of `file_bytes` could hold `data_bytes` of voxels, even at zlib's largest
// compression ratio (1032:1), with room for a header: a header promising more (found by
// fuzzing: a 421-byte file asked for 12.7 GB) is refused before anything is allocated.
bool FileCanHold(uint64_t data_bytes, uint64_t file_bytes) {
  return data_bytes <= 1100 * file_bytes + 4096;
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
        *reason = Corrupt(what, stream.msg != nullptr ? std::string(stream.msg)
                                                      : "error " + std::to_string(status));
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
    *reason =
        what + " holds " + std::to_string(available) + " bytes, expected " + std::to_string(bytes);
    return false;
  }
  return true;
}

// Checks the data block of the formats whose ITK readers do not (see the file comment);
// with `exact`, of a file just written, for every format. `checked`: see CheckNiftiData.
DataProblem CheckDataBlock(const itk::ImageIOBase& io,
                           const std::string& path,
                           bool exact,
                           std::string* reason,
                           const std::vector<bool>* checked,
                           DirectVoxels* direct) {
  const std::string name = io.GetNameOfClass();
  const uint64_t bytes = static_cast<uint64_t>(io.GetImageSizeInBytes());
  bool ok = true;
  if (name == "NiftiImageIO") return CheckNiftiData(path, exact, reason, checked, direct);
  if (name == "MetaImageIO") ok = CheckMetaImageData(path, bytes, exact, reason);
  if (name == "NrrdImageIO" && exact) ok = CheckWrittenNrrdData(path, bytes, reason);
  return ok ? DataProblem::kNone : DataProblem::kData;
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
      holder = std::string(layout.files.size() > 1 ? "its data files" : "its data file") + " (" +
               std::to_string(file_bytes) + " bytes)";
    }
  }
  if (bounded && !FileCanHold(bytes, file_bytes)) {
    *error = path + ": cannot read the voxels (the header promises " + std::to_string(bytes) +
             " bytes of voxels, more than " + holder + " can hold)";
    return false;
  }
  return true;
}

}  // namespace internal
}  // namespace itk_io
}  // namespace dsr
