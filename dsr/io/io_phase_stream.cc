// One pass over a 4D image's data block, keeping the chosen phases (io_phase_stream.h).
#include "dsr/io/io_phase_stream.h"

#include <zlib.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <memory>
#include <type_traits>

namespace dsr {
namespace phase_stream {
namespace {

// Bytes read, inflated or converted at a time.
constexpr size_t kChunkBytes = size_t{1} << 20;

// Worded as the data checks of io_itk_checks.cc word it.
std::string EndsEarly(uint64_t found, uint64_t expected) {
  return "data ends after " + std::to_string(found) + " of " + std::to_string(expected) +
         " bytes; the file is truncated";
}

// The data block's bytes in order, from the parts one after the other.
class ByteStream {
 public:
  ByteStream(const Source& source, uint64_t expected) : source_(source), expected_(expected) {}
  ByteStream(const ByteStream&) = delete;
  ByteStream& operator=(const ByteStream&) = delete;
  ~ByteStream() {
    if (inflating_) inflateEnd(&zlib_);
  }

  // The next `count` bytes into `out`, or passed over when `out` is null.
  bool Next(unsigned char* out, uint64_t count, std::string* reason) {
    while (count > 0) {
      if (!open_ && !OpenPart(reason)) return false;
      uint64_t got = 0;
      const bool ok = source_.compressed ? Inflate(out, count, &got, reason)
                                         : Plain(out, count, &got, reason);
      if (!ok) return false;
      delivered_ += got;
      count -= got;
      if (out != nullptr) out += got;
    }
    return true;
  }

 private:
  bool OpenPart(std::string* reason) {
    if (part_ >= source_.parts.size()) {
      *reason = EndsEarly(delivered_, expected_);
      return false;
    }
    const Part& part = source_.parts[part_];
    in_ = std::ifstream(part.file, std::ios::binary);
    if (!in_) {
      *reason = part.file + " cannot be opened (" + std::strerror(errno) + ")";
      return false;
    }
    std::error_code ec;
    const uint64_t size = std::filesystem::file_size(part.file, ec);
    in_.seekg(static_cast<std::streamoff>(part.offset));
    left_ = ec || size < part.offset ? 0 : std::min(part.bytes, size - part.offset);
    short_ = left_ < part.bytes;
    if (source_.compressed) {
      if (inflating_) inflateEnd(&zlib_);
      zlib_ = z_stream{};
      if (inflateInit2(&zlib_, 15 + 32) != Z_OK) {  // 15 + 32: a zlib or gzip header
        *reason = "cannot start zlib";
        return false;
      }
      inflating_ = true;
      eof_ = false;
      if (input_ == nullptr) input_.reset(new unsigned char[kChunkBytes]);
    }
    open_ = true;
    return true;
  }

  void EndPart() {
    open_ = false;
    ++part_;
  }

  bool Plain(unsigned char* out, uint64_t count, uint64_t* got, std::string* reason) {
    if (left_ == 0) {
      if (short_) {
        *reason = EndsEarly(delivered_, expected_);
        return false;
      }
      EndPart();
      return true;
    }
    const uint64_t take = std::min(count, left_);
    if (out == nullptr) {
      in_.seekg(static_cast<std::streamoff>(take), std::ios::cur);
      *got = take;
    } else {
      in_.read(reinterpret_cast<char*>(out), static_cast<std::streamsize>(take));
      *got = static_cast<uint64_t>(in_.gcount());
    }
    if (!in_) {
      *reason = EndsEarly(delivered_ + *got, expected_);
      return false;
    }
    left_ -= *got;
    return true;
  }

  // More compressed input (none at the part's end of file).
  void Fill() {
    in_.read(reinterpret_cast<char*>(input_.get()), static_cast<std::streamsize>(kChunkBytes));
    const std::streamsize read = std::max<std::streamsize>(in_.gcount(), 0);
    zlib_.next_in = input_.get();
    zlib_.avail_in = static_cast<uInt>(read);
    eof_ = read == 0;
  }

  // After a stream's end: whether another gzip member follows (gzread, and so niftilib,
  // reads them one after the other); if so, zlib is ready for it.
  bool AnotherMember() {
    if (zlib_.avail_in < 2) {
      const uInt kept = zlib_.avail_in;
      if (kept == 1) input_[0] = zlib_.next_in[0];
      in_.read(reinterpret_cast<char*>(input_.get() + kept),
               static_cast<std::streamsize>(kChunkBytes - kept));
      zlib_.next_in = input_.get();
      zlib_.avail_in = kept + static_cast<uInt>(std::max<std::streamsize>(in_.gcount(), 0));
    }
    if (zlib_.avail_in < 2 || zlib_.next_in[0] != 0x1f || zlib_.next_in[1] != 0x8b) return false;
    return inflateReset(&zlib_) == Z_OK;
  }

  bool Inflate(unsigned char* out, uint64_t count, uint64_t* got, std::string* reason) {
    if (out == nullptr && scratch_ == nullptr) scratch_.reset(new unsigned char[kChunkBytes]);
    const uInt want = static_cast<uInt>(std::min<uint64_t>(count, kChunkBytes));
    zlib_.next_out = out != nullptr ? out : scratch_.get();
    zlib_.avail_out = want;
    bool ended = false;
    while (zlib_.avail_out > 0 && !ended) {
      if (zlib_.avail_in == 0) Fill();
      const int status = inflate(&zlib_, Z_NO_FLUSH);
      if (status == Z_STREAM_END) {
        ended = !AnotherMember();
      } else if (status == Z_BUF_ERROR && zlib_.avail_in == 0 && eof_) {
        break;  // the file ends inside the stream
      } else if (status != Z_OK && status != Z_BUF_ERROR) {
        *reason = "compressed data is corrupt (zlib: " +
                  (zlib_.msg != nullptr ? std::string(zlib_.msg) : std::to_string(status)) + ")";
        return false;
      }
    }
    *got = want - zlib_.avail_out;
    if (ended) {
      EndPart();
    } else if (*got == 0) {
      *reason = EndsEarly(delivered_, expected_);
      return false;
    }
    return true;
  }

  const Source& source_;
  const uint64_t expected_;
  uint64_t delivered_ = 0;
  size_t part_ = 0;
  bool open_ = false;
  std::ifstream in_;
  uint64_t left_ = 0;   // uncompressed: bytes of the open part still to read
  bool short_ = false;  // uncompressed: the open part's file holds less than its share
  z_stream zlib_{};
  bool inflating_ = false;
  bool eof_ = false;
  std::unique_ptr<unsigned char[]> input_;
  std::unique_ptr<unsigned char[]> scratch_;
};

template <typename C>
C Load(const unsigned char* bytes, bool swap) {
  unsigned char raw[sizeof(C)];
  std::memcpy(raw, bytes, sizeof(C));
  if (swap) std::reverse(raw, raw + sizeof(C));
  C value;
  std::memcpy(&value, raw, sizeof(C));
  return value;
}

// `count` stored values to float, as ITK's readers and io_itk.cc's ConvertBuffer give them.
template <typename C>
void ConvertAs(const unsigned char* in, size_t count, const Source& source, float* out) {
  for (size_t i = 0; i < count; ++i) {
    const C value = Load<C>(in + i * sizeof(C), source.swap);
    if (!source.rescale) {
      out[i] = static_cast<float>(value);
      continue;
    }
    // ITK: non-double voxels are cast to float first; two steps as in its RescaleFunction.
    double scaled =
        std::is_same<C, double>::value ? value : static_cast<double>(static_cast<float>(value));
    scaled *= source.slope;
    scaled += source.intercept;
    out[i] = static_cast<float>(scaled);
  }
}

void Convert(const unsigned char* in, size_t count, const Source& source, float* out) {
  switch (source.storage) {
    case Storage::kUint8:
      return ConvertAs<uint8_t>(in, count, source, out);
    case Storage::kInt8:
      return ConvertAs<int8_t>(in, count, source, out);
    case Storage::kUint16:
      return ConvertAs<uint16_t>(in, count, source, out);
    case Storage::kInt16:
      return ConvertAs<int16_t>(in, count, source, out);
    case Storage::kUint32:
      return ConvertAs<uint32_t>(in, count, source, out);
    case Storage::kInt32:
      return ConvertAs<int32_t>(in, count, source, out);
    case Storage::kUint64:
      return ConvertAs<uint64_t>(in, count, source, out);
    case Storage::kInt64:
      return ConvertAs<int64_t>(in, count, source, out);
    case Storage::kFloat32:
      return ConvertAs<float>(in, count, source, out);
    case Storage::kFloat64:
      return ConvertAs<double>(in, count, source, out);
  }
}

// Runs of at least a chunk: each run of a chosen phase read and converted, each other
// run passed over (a seek in uncompressed data).
bool ReadByRuns(const Source& source,
                const std::vector<float*>& dest,
                uint64_t end,
                ByteStream* stream,
                std::string* reason) {
  const size_t size = static_cast<size_t>(StorageBytes(source.storage));
  const uint64_t chunk = kChunkBytes / size;
  std::unique_ptr<unsigned char[]> buffer(new unsigned char[chunk * size]);
  for (uint64_t run = 0; run * source.block < end; ++run) {
    float* phase = dest[run % static_cast<uint64_t>(source.phases)];
    if (phase == nullptr) {
      if (!stream->Next(nullptr, source.block * size, reason)) return false;
      continue;
    }
    float* at = phase + run / static_cast<uint64_t>(source.phases) * source.block;
    for (uint64_t done = 0; done < source.block;) {
      const uint64_t n = std::min(chunk, source.block - done);
      if (!stream->Next(buffer.get(), n * size, reason)) return false;
      Convert(buffer.get(), static_cast<size_t>(n), source, at + done);
      done += n;
    }
  }
  return true;
}

// Shorter runs: chunk after chunk, each chunk's runs sent to their phases.
bool ReadByChunks(const Source& source,
                  const std::vector<float*>& dest,
                  uint64_t end,
                  ByteStream* stream,
                  std::string* reason) {
  const size_t size = static_cast<size_t>(StorageBytes(source.storage));
  const uint64_t chunk = kChunkBytes / size;
  const uint64_t phases = static_cast<uint64_t>(source.phases);
  std::unique_ptr<unsigned char[]> buffer(new unsigned char[chunk * size]);
  for (uint64_t first = 0; first < end;) {
    const uint64_t n = std::min(chunk, end - first);
    if (!stream->Next(buffer.get(), n * size, reason)) return false;
    for (uint64_t k = 0; k < n;) {
      const uint64_t e = first + k;
      const uint64_t run = e / source.block;
      const uint64_t within = e % source.block;
      const uint64_t length = std::min(source.block - within, n - k);
      float* phase = dest[run % phases];
      if (phase != nullptr) {
        Convert(buffer.get() + k * size, static_cast<size_t>(length), source,
                phase + run / phases * source.block + within);
      }
      k += length;
    }
    first += n;
  }
  return true;
}

}  // namespace

int StorageBytes(Storage storage) {
  switch (storage) {
    case Storage::kUint8:
    case Storage::kInt8:
      return 1;
    case Storage::kUint16:
    case Storage::kInt16:
      return 2;
    case Storage::kUint32:
    case Storage::kInt32:
    case Storage::kFloat32:
      return 4;
    case Storage::kUint64:
    case Storage::kInt64:
    case Storage::kFloat64:
      return 8;
  }
  return 1;
}

bool ReadPhases(const Source& source,
                const std::vector<int>& which,
                std::vector<std::vector<float>>* out,
                std::string* reason) {
  if (source.phases < 1 || source.voxels == 0 || source.block == 0 ||
      source.voxels % source.block != 0) {
    *reason = "the voxel layout is not one of phases (internal error)";
    return false;
  }
  const uint64_t phases = static_cast<uint64_t>(source.phases);
  std::vector<float*> dest(phases, nullptr);
  std::vector<std::vector<float>> read(which.size());
  uint64_t end = 0;  // one past the last value of a chosen phase, in stream order
  for (size_t k = 0; k < which.size(); ++k) {
    const uint64_t t = static_cast<uint64_t>(which[k]);
    if (which[k] < 0 || t >= phases || dest[t] != nullptr) {
      *reason = "phase " + std::to_string(which[k]) + " cannot be read (internal error)";
      return false;
    }
    read[k].resize(static_cast<size_t>(source.voxels));
    dest[t] = read[k].data();
    const uint64_t last_run = (source.voxels / source.block - 1) * phases + t;
    end = std::max(end, (last_run + 1) * source.block);
  }
  const uint64_t size = static_cast<uint64_t>(StorageBytes(source.storage));
  ByteStream stream(source, source.skip + phases * source.voxels * size);
  if (source.skip > 0 && !stream.Next(nullptr, source.skip, reason)) return false;
  const bool long_runs = source.block * size >= kChunkBytes;
  if (!(long_runs ? ReadByRuns(source, dest, end, &stream, reason)
                  : ReadByChunks(source, dest, end, &stream, reason))) {
    return false;
  }
  // The rest is passed over too, so that a truncated or corrupt data block is refused
  // whichever phases are read.
  if (!stream.Next(nullptr, (phases * source.voxels - end) * size, reason)) return false;
  *out = std::move(read);
  return true;
}

}  // namespace phase_stream
}  // namespace dsr
