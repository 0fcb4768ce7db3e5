// Tests that the IO layer loses no data and never accepts an incomplete file:
// failed writes (file-size limit, i.e. disk full) never replace a previous file, NIfTI
// sizes follow the datatype, NIfTI NaN/Inf are refused, MetaImage LIST and detached data
// files are checked (a detached NRRD header's promise too), and the files an image consists
// of or a write creates are listed.
#include <fcntl.h>
#include <signal.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iterator>
#include <limits>
#include <map>
#include <random>
#include <string>
#include <vector>

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <zlib.h>

#include "dsr/io/io_image.h"
#include "dsr/io/io_itk.h"
#include "dsr/io/io_phases.h"
#include "dsr/tests/support/scoped_temp_dir.h"
#include "dsr/util/atomic_file.h"

namespace dsr {
namespace {

namespace fs = std::filesystem;
using ::testing::ElementsAre;
using ::testing::ElementsAreArray;
using ::testing::HasSubstr;
using ::testing::StartsWith;

const char* const kExtensions[] = {".nii", ".nii.gz", ".mha", ".mhd", ".nrrd", ".nhdr"};

std::string ReadBytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

void WriteBytes(const std::string& path, const std::string& bytes) {
  std::ofstream(path, std::ios::binary | std::ios::trunc) << bytes;
}

// Writes the bytes of `from` gzip-compressed to `to`.
void GzipFile(const std::string& from, const std::string& to) {
  const std::string bytes = ReadBytes(from);
  gzFile out = gzopen(to.c_str(), "wb");
  ASSERT_NE(out, nullptr) << to;
  EXPECT_EQ(gzwrite(out, bytes.data(), static_cast<unsigned>(bytes.size())),
            static_cast<int>(bytes.size()));
  EXPECT_EQ(gzclose(out), Z_OK);
}

// Random voxels, so that compression cannot shrink the data below the file-size limit.
Image RandomImage(const Eigen::Vector3i& size, uint32_t seed) {
  ImageGeometry g;
  g.size = size;
  Image image(g);
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> value(-100.0f, 100.0f);
  for (float& v : image.voxels) v = value(rng);
  return image;
}

// Runs `write` in a forked child whose files may not grow beyond `limit_bytes`, with
// SIGXFSZ ignored so that writes past the limit fail with EFBIG (as on a full disk) instead
// of killing the process. Returns the child's result; `error` gets the error it reported.
bool WriteUnderFileSizeLimit(rlim_t limit_bytes,
                             const std::function<bool(std::string*)>& write,
                             std::string* error) {
  int fds[2];
  if (::pipe(fds) != 0) {
    ADD_FAILURE() << "pipe failed";
    return true;
  }
  const pid_t child = ::fork();
  if (child == 0) {
    ::close(fds[0]);
    ::alarm(60);  // a hang in the child fails the test instead of blocking it
    ::signal(SIGXFSZ, SIG_IGN);
    const rlimit limit = {limit_bytes, limit_bytes};
    if (::setrlimit(RLIMIT_FSIZE, &limit) != 0) ::_exit(3);
    std::string message;
    const bool ok = write(&message);
    size_t done = 0;
    while (done < message.size()) {
      const ssize_t n = ::write(fds[1], message.data() + done, message.size() - done);
      if (n <= 0) break;
      done += static_cast<size_t>(n);
    }
    ::close(fds[1]);
    ::_exit(ok ? 0 : 1);
  }
  ::close(fds[1]);
  error->clear();
  char buffer[4096];
  for (ssize_t n; (n = ::read(fds[0], buffer, sizeof(buffer))) > 0;) error->append(buffer, n);
  ::close(fds[0]);
  int status = 0;
  ::waitpid(child, &status, 0);
  EXPECT_TRUE(WIFEXITED(status)) << "the writing child died (signal " << WTERMSIG(status) << ")";
  EXPECT_NE(WEXITSTATUS(status), 3) << "setrlimit failed";
  return WIFEXITED(status) && WEXITSTATUS(status) == 0;
}

// ---- Writes verified before they replace anything ----

TEST(IoWriteVerification, FileSizeLimitFailsEveryFormatAndKeepsThePreviousFile) {
  const Image previous = RandomImage(Eigen::Vector3i(48, 48, 40), 1);
  const Image next = RandomImage(Eigen::Vector3i(48, 48, 40), 2);
  // 0: nothing can be written; 512: the header fits, the voxels do not; 64 KiB: as in the
  // original report (`ulimit -f 64`).
  for (const rlim_t limit : {rlim_t{0}, rlim_t{512}, rlim_t{64 * 1024}}) {
    for (const std::string ext : kExtensions) {
      SCOPED_TRACE(ext + " limit " + std::to_string(limit));
      ScopedTempDir dir;
      const std::string path = dir.File("pan" + ext);
      std::string error;
      ASSERT_TRUE(WriteImage(previous, path, &error)) << error;
      std::map<std::string, std::string> before;
      for (const std::string& file : WrittenImageFiles(path)) before[file] = ReadBytes(file);
      const std::vector<std::string> entries = dir.Entries();

      EXPECT_FALSE(WriteUnderFileSizeLimit(
          limit, [&](std::string* e) { return WriteImage(next, path, e); }, &error));
      EXPECT_THAT(error, StartsWith(path + ": "));
      EXPECT_EQ(error.find('\n'), std::string::npos) << error;
      for (const auto& [file, bytes] : before) {
        EXPECT_TRUE(ReadBytes(file) == bytes) << file << " changed";
      }
      EXPECT_EQ(dir.Entries(), entries) << "a temporary file or folder was left behind";
      Image back;
      ASSERT_TRUE(ReadImage(path, &back, &error)) << error;
      EXPECT_EQ(back.voxels, previous.voxels);
    }
  }
}

TEST(IoWriteVerification, TheReasonNamesAFailedWrite) {
  // NIfTI and MetaImage writers report success on a failed write; the read-back says why.
  const Image image = RandomImage(Eigen::Vector3i(48, 48, 40), 3);
  for (const std::string ext : {".nii", ".nii.gz", ".mha", ".mhd"}) {
    SCOPED_TRACE(ext);
    ScopedTempDir dir;
    const std::string path = dir.File("out" + ext);
    std::string error;
    EXPECT_FALSE(WriteUnderFileSizeLimit(
        64 * 1024, [&](std::string* e) { return WriteImage(image, path, e); }, &error));
    EXPECT_THAT(error, StartsWith(path + ": write failed (disk full or file-size limit?): "));
    EXPECT_TRUE(dir.Entries().empty()) << "left behind: " << dir.Entries()[0];
  }
}

TEST(IoWriteVerification, MasksAreVerifiedToo) {
  ImageGeometry g;
  g.size = Eigen::Vector3i(64, 64, 64);
  Mask mask(g, 0);
  std::mt19937 rng(4);
  for (uint8_t& v : mask.voxels) v = rng() & 1;
  for (const std::string ext : kExtensions) {
    SCOPED_TRACE(ext);
    ScopedTempDir dir;
    const std::string path = dir.File("mask" + ext);
    std::string error;
    EXPECT_FALSE(WriteUnderFileSizeLimit(
        16 * 1024, [&](std::string* e) { return WriteMask(mask, path, e); }, &error));
    EXPECT_THAT(error, StartsWith(path + ": "));
    EXPECT_TRUE(dir.Entries().empty());
  }
}

TEST(IoWriteVerification, AtomicTextWritesFailUnderTheLimitAndKeepThePreviousFile) {
  ScopedTempDir dir;
  const std::string path = dir.File("poses.json");
  std::string error;
  ASSERT_TRUE(WriteFileAtomically(path, "previous\n", &error)) << error;
  const std::string big(200 * 1024, 'x');
  EXPECT_FALSE(WriteUnderFileSizeLimit(
      64 * 1024, [&](std::string* e) { return WriteFileAtomically(path, big, e); }, &error));
  EXPECT_EQ(error, path + ": write failed (File too large)");
  EXPECT_EQ(ReadBytes(path), "previous\n");
  EXPECT_THAT(dir.Entries(), ElementsAre("poses.json"));
  // The same write without the limit succeeds (the limit, not the writer, failed it).
  EXPECT_TRUE(WriteUnderFileSizeLimit(
      RLIM_INFINITY, [&](std::string* e) { return WriteFileAtomically(path, big, e); }, &error))
      << error;
  EXPECT_EQ(ReadBytes(path), big);
}

// VerifyWritten demands the exact size: a file cut short or with extra bytes is refused,
// for every format (this is what catches writers that report success on a failed write).
TEST(IoWriteVerification, VerifyWrittenRefusesShortAndLongData) {
  const Image image = RandomImage(Eigen::Vector3i(16, 16, 16), 5);
  itk_io::RawVolume raw;
  for (int a = 0; a < 3; ++a) raw.size[a] = 16;
  for (const std::string ext : kExtensions) {
    SCOPED_TRACE(ext);
    ScopedTempDir dir;
    const std::string path = dir.File("v" + ext);
    std::string error;
    ASSERT_TRUE(WriteImage(image, path, &error)) << error;
    EXPECT_TRUE(itk_io::VerifyWritten(raw, path, itk_io::PixelType::kFloat, &error)) << error;
    itk_io::RawVolume other = raw;
    other.size[2] = 15;
    EXPECT_FALSE(itk_io::VerifyWritten(other, path, itk_io::PixelType::kFloat, &error));
    EXPECT_THAT(error, HasSubstr("the written header does not describe the image"));
    EXPECT_FALSE(itk_io::VerifyWritten(raw, path, itk_io::PixelType::kUint8, &error));

    const std::string data = WrittenImageFiles(path).back();  // the data file, or the image
    const std::string intact = ReadBytes(data);
    WriteBytes(data, intact.substr(0, intact.size() - 1));
    EXPECT_FALSE(itk_io::VerifyWritten(raw, path, itk_io::PixelType::kFloat, &error));
    EXPECT_THAT(error, StartsWith(path + ": write failed (disk full or file-size limit?): "));
    if (ext != ".nii.gz" && ext != ".mha" && ext != ".nrrd") {  // compressed: ends cleanly
      WriteBytes(data, intact + "x");
      EXPECT_FALSE(itk_io::VerifyWritten(raw, path, itk_io::PixelType::kFloat, &error));
      EXPECT_THAT(error, HasSubstr("bytes, expected"));
    }
  }
}

// ---- NIfTI: size from the datatype, bitpix must agree, NaN/Inf refused ----

// A hand-made single-file NIfTI-1 image: 352-byte header (identity geometry) + `data`.
std::string NiftiFile(int nx, int ny, int nz, int16_t datatype, int16_t bitpix, bool big_endian,
                      const std::string& data) {
  std::string header(352, '\0');
  const auto put = [&](size_t offset, const void* value, size_t size) {
    std::string bytes(static_cast<const char*>(value), size);
    if (big_endian) std::reverse(bytes.begin(), bytes.end());
    header.replace(offset, size, bytes);
  };
  const int32_t sizeof_hdr = 348;
  put(0, &sizeof_hdr, 4);
  const int16_t dim[8] = {3, static_cast<int16_t>(nx), static_cast<int16_t>(ny),
                          static_cast<int16_t>(nz), 1, 1, 1, 1};
  for (int d = 0; d < 8; ++d) put(40 + 2 * d, &dim[d], 2);
  put(70, &datatype, 2);
  put(72, &bitpix, 2);
  const float pixdim[8] = {1, 1, 1, 1, 1, 1, 1, 1};
  for (int d = 0; d < 8; ++d) put(76 + 4 * d, &pixdim[d], 4);
  const float vox_offset = 352;
  put(108, &vox_offset, 4);
  const float scl_slope = 1;
  put(112, &scl_slope, 4);
  header.replace(344, 4, std::string("n+1\0", 4));
  return header + data;
}

template <typename T>
std::string Bytes(const std::vector<T>& values, bool big_endian) {
  std::string out;
  for (const T& v : values) {
    std::string bytes(reinterpret_cast<const char*>(&v), sizeof(T));
    if (big_endian) std::reverse(bytes.begin(), bytes.end());
    out += bytes;
  }
  return out;
}

std::string ReadError(const std::string& path) {
  Image image;
  std::string error;
  EXPECT_FALSE(ReadImage(path, &image, &error)) << path;
  EXPECT_EQ(error.find('\n'), std::string::npos) << error;
  EXPECT_THAT(error, StartsWith(path + ": "));
  return error;
}

TEST(NiftiIo, BitpixThatDisagreesWithTheDatatypeIsRefused) {
  ScopedTempDir dir;
  std::vector<float> voxels(8 * 8 * 8, 1.5f);
  // The reported case: float32 with bitpix 8 and a quarter of the data (as bitpix says).
  const std::string quarter = Bytes(voxels, false).substr(0, voxels.size());
  const std::string path = dir.File("bitpix.nii");
  WriteBytes(path, NiftiFile(8, 8, 8, 16, 8, false, quarter));
  EXPECT_EQ(ReadError(path), path + ": bitpix 8 disagrees with datatype float32 (32 bits)");
  // Big-endian, complete data, bitpix too large: refused all the same.
  const std::string be = dir.File("bitpix_be.nii");
  WriteBytes(be, NiftiFile(8, 8, 8, 16, 64, true, Bytes(voxels, true)));
  EXPECT_EQ(ReadError(be), be + ": bitpix 64 disagrees with datatype float32 (32 bits)");
  // The agreeing header reads.
  const std::string good = dir.File("good_be.nii");
  WriteBytes(good, NiftiFile(8, 8, 8, 16, 32, true, Bytes(voxels, true)));
  Image image;
  std::string error;
  ASSERT_TRUE(ReadImage(good, &image, &error)) << error;
  EXPECT_EQ(image.voxels, voxels);
}

TEST(NiftiIo, DataSizeFollowsTheDatatype) {
  ScopedTempDir dir;
  // int16 voxels: 2 bytes each; the file holds only half of them.
  const std::vector<int16_t> voxels(8 * 8 * 8, 7);
  const std::string half = Bytes(voxels, false).substr(0, voxels.size());
  const std::string path = dir.File("half.nii");
  WriteBytes(path, NiftiFile(8, 8, 8, 4, 16, false, half));
  EXPECT_EQ(ReadError(path),
            path + ": cannot read the voxels (data ends after 512 of 1024 bytes; the file is "
                   "truncated)");
  // The same, compressed: checked after decompression.
  const std::string gz = dir.File("half.nii.gz");
  Image image = RandomImage(Eigen::Vector3i(8, 8, 8), 6);
  std::string error;
  ASSERT_TRUE(WriteImage(image, dir.File("whole.nii"), &error)) << error;
  std::string whole = ReadBytes(dir.File("whole.nii"));
  WriteBytes(dir.File("cut.nii"), whole.substr(0, 352 + 1000));
  GzipFile(dir.File("cut.nii"), gz);
  EXPECT_THAT(ReadError(gz), HasSubstr("cannot read the voxels (data ends after 1000 of 2048"));
}

// The float NIfTI read that inflates, scans and moves the voxels in one pass tests them in
// blocks of 1024: a non-finite voxel is named wherever it lies, at a block's first or last
// element, in the last partial block, or as the very first or last voxel; the same file
// once fixed reads back exactly.
TEST(NiftiIo, NonFiniteVoxelsAreNamedWhereverTheyLieInTheBlocks) {
  ScopedTempDir dir;
  const Image image = RandomImage(Eigen::Vector3i(67, 61, 59), 8);  // 241133: a partial block
  const int64_t last = static_cast<int64_t>(image.voxels.size()) - 1;
  for (const int64_t at : {int64_t{0}, int64_t{1023}, int64_t{1024}, int64_t{65536 + 7},
                           int64_t{235 * 1024 - 1}, last - 1, last}) {
    SCOPED_TRACE(at);
    ASSERT_LE(at, last);
    Image bad = image;
    bad.voxels[static_cast<size_t>(at)] = at % 2 ? std::numeric_limits<float>::infinity()
                                                 : std::numeric_limits<float>::quiet_NaN();
    const std::string path = dir.File("bad.nii.gz");
    std::string error;
    ASSERT_TRUE(WriteImage(bad, path, &error)) << error;
    const int64_t nx = 67, nxy = 67 * 61;
    EXPECT_EQ(ReadError(path), path + ": voxel (" + std::to_string(at % nx) + "," +
                                   std::to_string(at % nxy / nx) + "," +
                                   std::to_string(at / nxy) + ") is " +
                                   (at % 2 ? "Inf" : "NaN"));
  }
  const std::string path = dir.File("good.nii.gz");
  std::string error;
  ASSERT_TRUE(WriteImage(image, path, &error)) << error;
  Image back;
  ASSERT_TRUE(ReadImage(path, &back, &error)) << error;
  EXPECT_EQ(back.voxels, image.voxels);
}

TEST(NiftiIo, NonFiniteVoxelsAreRefusedLikeInOtherFormats) {
  ScopedTempDir dir;
  // float32, little-endian, written by dsr itself (.nii and .nii.gz); the NaN lies beyond
  // the first 1 MiB so that it is found across decompression chunks.
  Image image = RandomImage(Eigen::Vector3i(80, 80, 80), 7);
  image.at(71, 3, 60) = std::numeric_limits<float>::quiet_NaN();
  for (const std::string ext : {".nii", ".nii.gz"}) {
    const std::string path = dir.File("nan" + ext);
    std::string error;
    ASSERT_TRUE(WriteImage(image, path, &error)) << error;
    EXPECT_EQ(ReadError(path), path + ": voxel (71,3,60) is NaN");
  }
  // float64, big-endian, -Inf at (3,4,5) of 8x8x8: index 3 + 8 * (4 + 8 * 5).
  std::vector<double> voxels(8 * 8 * 8, 2.0);
  voxels[3 + 8 * (4 + 8 * 5)] = -std::numeric_limits<double>::infinity();
  const std::string be = dir.File("inf_be.nii");
  WriteBytes(be, NiftiFile(8, 8, 8, 64, 64, true, Bytes(voxels, true)));
  EXPECT_EQ(ReadError(be), be + ": voxel (3,4,5) is Inf");
  // Integer voxels cannot be NaN: an int16 file whose bytes would spell a NaN as float reads.
  const std::vector<int16_t> ints(8 * 8 * 8, static_cast<int16_t>(0x7fc0));
  const std::string int_path = dir.File("ints.nii");
  WriteBytes(int_path, NiftiFile(8, 8, 8, 4, 16, false, Bytes(ints, false)));
  Image back;
  std::string error;
  EXPECT_TRUE(ReadImage(int_path, &back, &error)) << error;
}

// ---- MetaImage: LIST slice files and detached data files ----

// A MetaImage header for float voxels of size nx x ny x nz; `data_file` is the
// ElementDataFile value and `tail` what follows the header (LIST names).
std::string MetaHeader(int nx, int ny, int nz, const std::string& data_file,
                       const std::string& tail = "", bool compressed = false) {
  return "ObjectType = Image\nNDims = 3\nBinaryData = True\nBinaryDataByteOrderMSB = False\n"
         "CompressedData = " +
         std::string(compressed ? "True" : "False") +
         "\nTransformMatrix = 1 0 0 0 1 0 0 0 1\nOffset = 0 0 0\nElementSpacing = 1 1 1\n"
         "DimSize = " +
         std::to_string(nx) + " " + std::to_string(ny) + " " + std::to_string(nz) +
         "\nElementType = MET_FLOAT\nElementDataFile = " + data_file + "\n" + tail;
}

// Writes `image` as a LIST .mhd with one slice file "sl_<z>.raw" per z; returns the names.
std::vector<std::string> WriteListImage(const ScopedTempDir& dir,
                                        const std::string& header_name,
                                        const Image& image) {
  const Eigen::Vector3i n = image.geometry.size;
  std::vector<std::string> names;
  std::string list;
  for (int z = 0; z < n[2]; ++z) {
    const std::string name = "sl_" + std::to_string(z) + ".raw";
    const char* slice = reinterpret_cast<const char*>(image.voxels.data() + z * n[0] * n[1]);
    WriteBytes(dir.File(name), std::string(slice, sizeof(float) * n[0] * n[1]));
    names.push_back(name);
    list += name + "\n";
  }
  WriteBytes(dir.File(header_name), MetaHeader(n[0], n[1], n[2], "LIST 2D", list));
  return names;
}

TEST(MetaImageIo, ListOfSliceFilesIsReadWhenComplete) {
  ScopedTempDir dir;
  const Image image = RandomImage(Eigen::Vector3i(5, 4, 3), 8);
  WriteListImage(dir, "list.mhd", image);
  Image back;
  std::string error;
  ASSERT_TRUE(ReadImage(dir.File("list.mhd"), &back, &error)) << error;
  EXPECT_EQ(back.voxels, image.voxels);
}

TEST(MetaImageIo, IncompleteListIsRefusedNamingTheSliceFile) {
  const Image image = RandomImage(Eigen::Vector3i(5, 4, 3), 9);
  {
    ScopedTempDir dir;
    WriteListImage(dir, "list.mhd", image);
    fs::resize_file(dir.File("sl_1.raw"), 30);
    const std::string path = dir.File("list.mhd");
    EXPECT_EQ(ReadError(path), path + ": cannot read the voxels (slice file " +
                                   dir.File("sl_1.raw") +
                                   " ends after 30 of 80 bytes; the file is truncated)");
  }
  {
    ScopedTempDir dir;
    WriteListImage(dir, "list.mhd", image);
    fs::remove(dir.File("sl_2.raw"));
    const std::string path = dir.File("list.mhd");
    EXPECT_EQ(ReadError(path), path + ": cannot read the voxels (slice file " +
                                   dir.File("sl_2.raw") + " does not exist)");
  }
  ScopedTempDir dir;
  WriteListImage(dir, "list.mhd", image);
  const std::string names = "sl_0.raw\nsl_1.raw\nsl_2.raw\n";
  struct Case {
    std::string name, header, expected;
  };
  const Case cases[] = {
      // MetaIO skips a last name without a line end: that slice would stay unread.
      {"no_newline.mhd", MetaHeader(5, 4, 3, "LIST 2D", "sl_0.raw\nsl_1.raw\nsl_2.raw"),
       "names 2 of the 3 slice files"},
      {"too_few.mhd", MetaHeader(5, 4, 3, "LIST", "sl_0.raw\nsl_1.raw\n"),
       "names 2 of the 3 slice files"},
      // An empty name made MetaIO index before the start of its string.
      {"empty_name.mhd", MetaHeader(5, 4, 3, "LIST 2D", "sl_0.raw\n\nsl_2.raw\n"),
       "slice file name 2 is empty"},
      // One file holding all three dimensions: MetaIO reads it with an unset slice size.
      {"whole_volume.mhd", MetaHeader(5, 4, 3, "LIST 3D", names), "must hold 1 to 2 dimensions"},
      {"negative.mhd", MetaHeader(5, 4, 3, "LIST -1D", names), "must hold 1 to 2 dimensions"},
      {"compressed.mhd", MetaHeader(5, 4, 3, "LIST 2D", names, true),
       "compressed LIST slice files are not supported"},
      {"pattern.mhd", MetaHeader(5, 4, 3, "sl_%d.raw 0 2 1"), "patterns (with %) are not"},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    WriteBytes(dir.File(c.name), c.header);
    EXPECT_THAT(ReadError(dir.File(c.name)), HasSubstr(c.expected));
  }
}

TEST(MetaImageIo, DetachedDataFileMissingOrShortIsRefusedNamingIt) {
  ScopedTempDir dir;
  const Image image = RandomImage(Eigen::Vector3i(5, 4, 3), 10);
  const std::string path = dir.File("frame.mhd");
  std::string error;
  ASSERT_TRUE(WriteImage(image, path, &error)) << error;
  fs::resize_file(dir.File("frame.raw"), 100);
  EXPECT_EQ(ReadError(path),
            path + ": cannot read the voxels (data file frame.raw ends after 100 of 240 bytes; "
                   "the file is truncated)");
  fs::remove(dir.File("frame.raw"));
  EXPECT_EQ(ReadError(path),
            path + ": cannot read the voxels (data file " + dir.File("frame.raw") +
                " does not exist)");
  // MetaIO falls back to "<name>.gz" (compressed) when <name> is missing; so does the check.
  const std::string raw(reinterpret_cast<const char*>(image.voxels.data()), 240);
  WriteBytes(dir.File("frame.raw"), raw);
  GzipFile(dir.File("frame.raw"), dir.File("frame.raw.gz"));
  fs::remove(dir.File("frame.raw"));
  Image back;
  ASSERT_TRUE(ReadImage(path, &back, &error)) << error;
  EXPECT_EQ(back.voxels, image.voxels);
  std::vector<std::string> files;
  ASSERT_TRUE(ImageDataFiles(path, &files, &error)) << error;
  EXPECT_THAT(files, ElementsAre(path, dir.File("frame.raw.gz")));
}

TEST(NrrdIo, DetachedDataFileMissingOrShortIsRefused) {
  ScopedTempDir dir;
  const std::string path = dir.File("frame.nhdr");
  std::string error;
  ASSERT_TRUE(WriteImage(RandomImage(Eigen::Vector3i(5, 4, 3), 11), path, &error)) << error;
  // teem checks NRRD data itself (and names the data file when it is missing).
  fs::resize_file(dir.File("frame.raw"), 100);
  EXPECT_THAT(ReadError(path), HasSubstr("cannot read the voxels"));
  fs::remove(dir.File("frame.raw"));
  EXPECT_THAT(ReadError(path), HasSubstr("couldn't open \"" + dir.File("frame.raw") + "\""));
}

// Found by fuzzing (tests/fuzz/fuzz_phases): a .nhdr whose sizes promise far more voxels
// than it or its data file holds had them allocated before teem (or the phase reader) read
// a byte: 1.6 TB for a 2.5 KB file, and 2^31 phases listed one by one. Refused first, as
// attached headers are (a missing data file is teem's error, above).
TEST(NrrdIo, DetachedHeaderPromisingMoreThanItsDataHoldsIsRefusedBeforeAllocating) {
  ScopedTempDir dir;
  const std::string head =
      "NRRD0004\ntype: short\ndimension: 4\nspace: left-posterior-superior\n"
      "space directions: none (1,0,0) (0,1,0) (0,0,1)\nkinds: list domain domain domain\n"
      "endian: little\nencoding: raw\n";
  const std::string data(3 * 2 * 2 * 2 * 2, '\1');
  const auto read_error = [](const std::string& path) {
    std::vector<Image> phases;
    std::string error;
    EXPECT_FALSE(ReadPhases(path, &phases, &error)) << path;
    return error;
  };
  WriteBytes(dir.File("huge.nhdr"), head + "sizes: 3 2 2147483647 2\n\n" + data);
  const std::string size = std::to_string(fs::file_size(dir.File("huge.nhdr")));
  EXPECT_THAT(read_error(dir.File("huge.nhdr")),
              HasSubstr("cannot read the voxels (the header promises 51539607528 bytes of "
                        "voxels, more than a " + size + "-byte file can hold)"));
  // Only the header is read to count the phases.
  WriteBytes(dir.File("phases.seq.nhdr"), head + "sizes: 2147483647 2 2 2\n\n" + data);
  int count = 0;
  std::string error;
  ASSERT_TRUE(NumPhasesInFile(dir.File("phases.seq.nhdr"), &count, &error)) << error;
  EXPECT_EQ(count, 2147483647);
  EXPECT_THAT(read_error(dir.File("phases.seq.nhdr")), HasSubstr("can hold)"));
  // Data files: their sizes bound the data.
  WriteBytes(dir.File("d.raw"), data);
  WriteBytes(dir.File("detached.nhdr"), head + "sizes: 3 2 2 100000000\ndata file: d.raw\n");
  EXPECT_THAT(read_error(dir.File("detached.nhdr")),
              HasSubstr("more than its data file (48 bytes) can hold)"));
  // A 3D image reads the same way.
  const std::string slab = "NRRD0004\ntype: float\ndimension: 3\nsizes: 100000 100000 100\n"
                           "endian: little\nencoding: raw\n";
  WriteBytes(dir.File("slab.nhdr"), slab + "data file: d.raw\n");
  Image image;
  EXPECT_FALSE(ReadImage(dir.File("slab.nhdr"), &image, &error));
  EXPECT_THAT(error, HasSubstr("more than its data file (48 bytes) can hold)"));
  // Not a regular file: 0 bytes (teem would read its terabytes from the device).
  WriteBytes(dir.File("zeros.nhdr"), slab + "data file: /dev/zero\n");
  EXPECT_FALSE(ReadImage(dir.File("zeros.nhdr"), &image, &error));
  EXPECT_THAT(error, HasSubstr("more than its data file (0 bytes) can hold)"));
}

// ---- Files an image consists of, files a write creates ----

TEST(ImageIoDataFiles, ListsTheHeaderAndEveryDataFileAsGiven) {
  ScopedTempDir dir;
  const Image image = RandomImage(Eigen::Vector3i(5, 4, 3), 12);
  std::string error;
  std::vector<std::string> files;
  for (const std::string ext : {".nii", ".nii.gz", ".mha", ".nrrd"}) {
    const std::string path = dir.File("single" + ext);
    ASSERT_TRUE(WriteImage(image, path, &error)) << error;
    ASSERT_TRUE(ImageDataFiles(path, &files, &error)) << error;
    EXPECT_THAT(files, ElementsAre(path)) << ext;
  }
  for (const std::string ext : {".mhd", ".nhdr"}) {
    const std::string path = dir.File("detached" + ext);
    ASSERT_TRUE(WriteImage(image, path, &error)) << error;
    ASSERT_TRUE(ImageDataFiles(path, &files, &error)) << error;
    EXPECT_THAT(files, ElementsAre(path, dir.File("detached.raw"))) << ext;
  }
  // A LIST: every slice file, in order, relative to the header's folder and not
  // canonicalised ("/./" stays).
  const std::vector<std::string> names = WriteListImage(dir, "list.mhd", image);
  const std::string as_given = dir.path() + "/./list.mhd";
  ASSERT_TRUE(ImageDataFiles(as_given, &files, &error)) << error;
  std::vector<std::string> expected = {as_given};
  for (const std::string& name : names) expected.push_back(dir.path() + "/./" + name);
  EXPECT_THAT(files, ElementsAreArray(expected));
  // Analyze / NIfTI pair.
  WriteBytes(dir.File("pair.hdr"), "");
  ASSERT_TRUE(ImageDataFiles(dir.File("pair.hdr"), &files, &error)) << error;
  EXPECT_THAT(files, ElementsAre(dir.File("pair.hdr"), dir.File("pair.img")));
}

TEST(ImageIoDataFiles, NrrdListAndPatternDataFiles) {
  ScopedTempDir dir;
  const std::string head =
      "NRRD0004\ntype: float\ndimension: 3\nsizes: 2 2 3\nencoding: raw\nendian: little\n";
  WriteBytes(dir.File("list.nhdr"), head + "data file: LIST 2\ns0.raw\ns1.raw\nsub/s2.raw\n");
  std::vector<std::string> files;
  std::string error;
  ASSERT_TRUE(ImageDataFiles(dir.File("list.nhdr"), &files, &error)) << error;
  EXPECT_THAT(files, ElementsAre(dir.File("list.nhdr"), dir.File("s0.raw"), dir.File("s1.raw"),
                                 dir.File("sub/s2.raw")));
  WriteBytes(dir.File("pattern.nhdr"), head + "data file: s%02d.raw 1 5 2 2\n");
  ASSERT_TRUE(ImageDataFiles(dir.File("pattern.nhdr"), &files, &error)) << error;
  EXPECT_THAT(files, ElementsAre(dir.File("pattern.nhdr"), dir.File("s01.raw"),
                                 dir.File("s03.raw"), dir.File("s05.raw")));
  // A format that is not one integer conversion is refused, not passed to snprintf.
  WriteBytes(dir.File("bad.nhdr"), head + "data file: s%s.raw 1 5 2 2\n");
  EXPECT_FALSE(ImageDataFiles(dir.File("bad.nhdr"), &files, &error));
  EXPECT_THAT(error, StartsWith(dir.File("bad.nhdr") + ": cannot read the header (data file "));
  WriteBytes(dir.File("abs.nhdr"), head + "data file: /elsewhere/d.raw\n");
  ASSERT_TRUE(ImageDataFiles(dir.File("abs.nhdr"), &files, &error)) << error;
  EXPECT_THAT(files, ElementsAre(dir.File("abs.nhdr"), "/elsewhere/d.raw"));
}

TEST(ImageIoDataFiles, UnreadableHeadersAndMissingFilesAreErrorsNamingTheFile) {
  ScopedTempDir dir;
  std::vector<std::string> files;
  std::string error;
  EXPECT_FALSE(ImageDataFiles(dir.File("none.mhd"), &files, &error));
  EXPECT_EQ(error, dir.File("none.mhd") + ": no such file");
  WriteBytes(dir.File("no_data.mhd"), "ObjectType = Image\nNDims = 3\n");
  EXPECT_FALSE(ImageDataFiles(dir.File("no_data.mhd"), &files, &error));
  EXPECT_EQ(error, dir.File("no_data.mhd") +
                       ": cannot read the header (the MetaImage header has no ElementDataFile "
                       "line)");
  WriteBytes(dir.File("short.mhd"), MetaHeader(2, 2, 3, "LIST", "a.raw\n"));
  EXPECT_FALSE(ImageDataFiles(dir.File("short.mhd"), &files, &error));
  EXPECT_THAT(error, HasSubstr("names 1 of the 3 slice files"));
  WriteBytes(dir.File("garbage.nrrd"), "PNG\n");
  EXPECT_FALSE(ImageDataFiles(dir.File("garbage.nrrd"), &files, &error));
  EXPECT_THAT(error, StartsWith(dir.File("garbage.nrrd") + ": cannot read the header (not a NRRD"));
}

TEST(ImageIoWrittenFiles, MatchesWhatWriteImageCreates) {
  const Image image = RandomImage(Eigen::Vector3i(5, 4, 3), 13);
  for (const std::string name : {"a.nii", "a.nii.gz", "a.mha", "a.mhd", "a.nrrd", "a.nhdr",
                                 "a.b.mhd", "x.raw.mhd", "a.b.nhdr", "B.NHDR", "c.NRRD"}) {
    SCOPED_TRACE(name);
    ScopedTempDir dir;
    std::string error;
    ASSERT_TRUE(WriteImage(image, dir.File(name), &error)) << error;
    std::vector<std::string> expected;
    for (const std::string& file : WrittenImageFiles(dir.File(name))) {
      EXPECT_EQ(fs::path(file).parent_path(), fs::path(dir.path()));
      expected.push_back(fs::path(file).filename().string());
    }
    std::sort(expected.begin(), expected.end());
    EXPECT_EQ(dir.Entries(), expected);
  }
  EXPECT_THAT(WrittenImageFiles("d/pan.mhd"), ElementsAre("d/pan.mhd", "d/pan.raw"));
  EXPECT_THAT(WrittenImageFiles("pan.nii.gz"), ElementsAre("pan.nii.gz"));
}

}  // namespace
}  // namespace dsr
