// Reading chosen phases of a 4D image in one pass over its voxel data, without ITK: the
// data block is decoded chunk by chunk (read, or inflated for zlib/gzip data) and only the
// chosen phases are kept, so memory holds those phases and one chunk, never the file's
// other phases. The ITK adapter (io_itk_phase_source.cc) describes where a file keeps its
// voxels (from the header ITK read) and leaves the data block to this reader. Not for use
// outside dsr/io.
#ifndef DSR_IO_IO_PHASE_STREAM_H_
#define DSR_IO_IO_PHASE_STREAM_H_

#include <cstdint>
#include <string>
#include <vector>

namespace dsr {
namespace phase_stream {

// How one voxel is stored.
enum class Storage { kUint8, kInt8, kUint16, kInt16, kUint32, kInt32, kUint64, kInt64,
                     kFloat32, kFloat64 };
int StorageBytes(Storage storage);

// A piece of the data block: `file` from byte `offset` on. Uncompressed, it holds `bytes`
// bytes of the block; compressed, a zlib or gzip stream (gzip members may follow each
// other) that runs to its end.
struct Part {
  std::string file;
  uint64_t offset = 0;
  uint64_t bytes = 0;
};

// A 4D image's data block: the parts one after the other, once decompressed, are `skip`
// bytes to pass over and then phases x voxels values of `storage` (byte-swapped when
// `swap`). The phases are interleaved in runs of `block` voxels: run g holds voxels
// (g / phases) * block ... + block - 1 of phase g % phases (block = voxels: phase after
// phase; block = 1: every voxel's phases side by side).
struct Source {
  std::vector<Part> parts;
  bool compressed = false;
  uint64_t skip = 0;
  Storage storage = Storage::kFloat32;
  bool swap = false;
  // NIfTI's scl_slope/scl_inter as ITK 5.2 applies them (NiftiImageIO::Read): through
  // float (double voxels: through double), then value * slope + intercept in double.
  bool rescale = false;
  double slope = 1.0;
  double intercept = 0.0;
  uint64_t voxels = 0;
  int phases = 0;
  uint64_t block = 0;
};

// Reads the phases `which` (distinct indices in [0, phases)) as float: (*out)[k] is phase
// which[k]. Uncompressed data of the other phases is skipped over (a seek), compressed data
// passed through the decompressor only; the whole block is gone through, so that a
// truncated or corrupt one is refused whichever phases are read. False with `reason` (no
// path) when the data ends early, is corrupt, or a file cannot be read.
bool ReadPhases(const Source& source,
                const std::vector<int>& which,
                std::vector<std::vector<float>>* out,
                std::string* reason);

}  // namespace phase_stream
}  // namespace dsr

#endif  // DSR_IO_IO_PHASE_STREAM_H_
