// What the io_itk*.cc files (the ITK side of image IO, io_itk.h) share: the quiet std::cerr,
// the one-line errors and the read pipeline around ITK's ImageIOBase (io_itk.cc), the
// data-block checks (io_itk_checks.cc), the NIfTI header and data (io_itk_nifti.cc), the
// MetaImage and NRRD header parsers (io_itk_headers.cc) and where a 4D image keeps its phases
// (io_itk_phase_source.cc); each function is described where it is defined. Includes ITK
// and its zlib, so only for the sources of the dsr_io_itk object library, which stay free of
// Eigen (see io_itk.h). Not for use outside dsr/io.
#ifndef DSR_IO_IO_ITK_INTERNAL_H_
#define DSR_IO_IO_ITK_INTERNAL_H_

#include <cstddef>
#include <cstdint>
#include <iostream>
#include <mutex>
#include <streambuf>
#include <string>
#include <vector>

#include <itkImageIOBase.h>
#include <itkMacro.h>
#include <itk_zlib.h>

#include "dsr/io/io_itk.h"
#include "dsr/io/io_phase_stream.h"

namespace dsr {
namespace itk_io {
namespace internal {

// ---- io_itk.cc: around ITK's calls ----

// MetaIO (and ITK's default OutputWindow) print diagnostics to std::cerr, several lines
// each, on top of the exception or status that is turned into the one-line error. While
// any ITK call of io_itk.cc or io_itk_phases.cc runs, std::cerr writes into a stateless
// sink. The count makes overlapping calls from several threads restore the real buffer only
// once, at the end.
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

// ITK's NIfTI, MetaImage and NRRD ImageIO factories, registered once.
void RegisterFactories();
// An ITK or teem error message on one line.
std::string OneLine(const std::string& message);
std::string Describe(const itk::ExceptionObject& e);
// Converts `count` components of type `type` to float; false for an unknown type.
bool ConvertBuffer(itk::IOComponentEnum type, const void* buffer, size_t count, float* out);
// The 3D grid of the first three axes of `io` into `header`.
bool FillGrid(const std::string& path,
              const itk::ImageIOBase& io,
              RawVolume* header,
              std::string* error);

// ---- What a data check found (io_itk_checks.cc, io_itk_nifti.cc) ----

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

// ---- io_itk.cc: the read pipeline ----

// `path` exists and is a regular file.
bool CheckInputFile(const std::string& path, std::string* error);
// ITK's ImageIO for `path` with the header read and checked; nullptr with `error` if not.
itk::ImageIOBase::Pointer OpenHeader(const std::string& path, std::string* error);
// The data-block checks and CheckVoxelBytesFit, before any voxel of `io` is read.
bool CheckBeforeReading(const itk::ImageIOBase& io,
                        const std::string& path,
                        const std::vector<bool>* checked,
                        std::string* error,
                        DirectVoxels* direct = nullptr);
// Every voxel component of `io` as float, x fastest, in one read.
void ReadWholeAsFloat(itk::ImageIOBase& io, std::vector<float>* voxels);
// The one-line error for the exception being handled; only inside a catch block.
std::string ReadFailure(const std::string& path, const char* stage);
// VerifyWritten for any number of dimensions and components.
bool VerifyWrittenShape(const std::vector<uint64_t>& sizes,
                        unsigned components,
                        itk::IOComponentEnum component,
                        const std::string& path,
                        std::string* error);

// ---- io_itk_checks.cc: the data-block checks ----

// Chunk size for streaming decompression checks.
constexpr size_t kChunkBytes = size_t{1} << 20;

// "<what> ends after <found> of <expected> bytes; the file is truncated".
std::string DataEndsEarly(const std::string& what, uint64_t found, uint64_t expected);
// "<what> is corrupt (zlib: <message>)".
std::string Corrupt(const std::string& what, const std::string& zlib_message);
// Whether a file of `file_bytes` could hold `data_bytes` of voxels at zlib's largest ratio.
bool FileCanHold(uint64_t data_bytes, uint64_t file_bytes);
// A zlib or gzip stream at `offset` of `path` inflates cleanly to (at least) `expected` bytes.
bool CheckCompressedStream(const std::string& path,
                           uint64_t offset,
                           uint64_t expected,
                           bool exact,
                           const std::string& what,
                           std::string* reason);
// `file` holds (at least) `bytes` from `offset` on.
bool CheckPlainData(const std::string& file,
                    uint64_t offset,
                    uint64_t bytes,
                    bool exact,
                    const std::string& what,
                    std::string* reason);
// The data block of `path` as its format demands (every format with `exact`).
DataProblem CheckDataBlock(const itk::ImageIOBase& io,
                           const std::string& path,
                           bool exact,
                           std::string* reason,
                           const std::vector<bool>* checked = nullptr,
                           DirectVoxels* direct = nullptr);
// The checks that must run before ITK's ImageIO `io_name` parses the header of `path`.
bool CheckHeaderBeforeItk(const std::string& io_name, const std::string& path, std::string* reason);
// The voxel bytes the header of `io` promises fit in the files that hold them.
bool CheckVoxelBytesFit(const itk::ImageIOBase& io, const std::string& path, std::string* error);

// ---- io_itk_nifti.cc: NIfTI ----

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

// The NIfTI-1 or NIfTI-2 header at the start of `file`; false when it is neither.
bool ReadNiftiLayout(gzFile file, NiftiLayout* layout);
// The header's dim and bitpix fields as the data check needs them.
bool CheckNiftiFields(const std::string& path, std::string* reason);
// The data block of a NIfTI file: size, decompression, NaN/Inf voxels.
DataProblem CheckNiftiData(const std::string& path,
                           bool exact,
                           std::string* reason,
                           const std::vector<bool>* checked = nullptr,
                           DirectVoxels* direct = nullptr);
// The header's orientation fields are finite numbers of sane size.
bool CheckNiftiOrientation(const std::string& path, std::string* reason);

// ---- io_itk_headers.cc: MetaImage and NRRD headers ----

// Most header bytes read before giving up on finding the end of a text header.
constexpr size_t kMaxHeaderBytes = size_t{1} << 20;

// The words of `text`, split at white space.
std::vector<std::string> Words(const std::string& text);
bool IsRegularFile(const std::string& path);

// Where the voxels of a MetaImage (.mha/.mhd) are, parsed the way MetaIO 5.2 parses them
// (metaImage.cxx, ReadStream): "LOCAL" (also "Local", "local") after the header; "LIST
// [nD]" one file per n-D slice, named on the lines after the header; a name containing
// "%" a file pattern; anything else one data file, where MetaIO falls back to "<name>.gz"
// and "<name>.Z" (then compressed) when <name> does not exist.
struct MetaImageLayout {
  enum class Kind { kLocal, kFile, kList };
  Kind kind = Kind::kLocal;
  bool compressed = false;
  int64_t header_size = 0;    // HeaderSize: bytes skipped in each data file, -1 = data at the end
  bool msb = false;           // BinaryDataByteOrderMSB (or ElementByteOrderMSB): big-endian
  bool binary = false;        // BinaryData (MetaIO reads text voxels without it)
  std::vector<int64_t> dims;  // DimSize
  uint64_t local_offset = 0;  // kLocal: where the data starts in the header file
  std::vector<std::string> files;  // kFile: the data file; kList: one per slice, in order
};

// Where the voxels of the MetaImage `path` are, as MetaIO reads them.
bool ParseMetaImageLayout(const std::string& path,
                          MetaImageLayout* layout,
                          bool* found_data_file,
                          std::string* reason);
// The data block of a MetaImage: `bytes` of voxels (exactly if `exact`).
bool CheckMetaImageData(const std::string& path, uint64_t bytes, bool exact, std::string* reason);
// The header lines that would make MetaIO abort or misread, before it parses them.
bool CheckMetaImageKeys(const std::string& path, std::string* reason);

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

// Where the voxels of the NRRD `path` are, as teem reads them.
bool ParseNrrdLayout(const std::string& path, NrrdLayout* layout, std::string* reason);
// The data block of a NRRD just written: exactly `bytes` of voxels.
bool CheckWrittenNrrdData(const std::string& path, uint64_t bytes, std::string* reason);

// ---- io_itk_phase_source.cc: where a 4D image keeps its phases ----

// A NRRD field's non-negative integer, false for anything else.
bool NrrdCount(const std::string& text, uint64_t* value);
// Which NRRD axis holds the phases; -1 when the header is not as ITK read it.
int NrrdPhaseAxis(const itk::ImageIOBase& io,
                  const NrrdLayout& layout,
                  const std::vector<uint64_t>& sizes);
// Where the phases of the 4D image `io` read are kept; false when the one-pass reader
// (io_phase_stream.h) does not follow the file's layout.
bool PhaseSource(const std::string& path,
                 const itk::ImageIOBase& io,
                 const PhasesHeader& header,
                 phase_stream::Source* source);

}  // namespace internal
}  // namespace itk_io
}  // namespace dsr

#endif  // DSR_IO_IO_ITK_INTERNAL_H_
