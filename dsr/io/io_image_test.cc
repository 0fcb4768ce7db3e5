// Image and mask IO (io/io_image.h): exact round trips in every supported format,
// integer pixels read as float, and one-line errors naming the file for every bad input.
#include "dsr/io/io_image.h"

#include <sys/stat.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <cstring>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <zlib.h>

#include "dsr/io/io_image_test_itk.h"
#include "dsr/tests/support/scoped_temp_dir.h"

namespace dsr {
namespace {

using ::testing::ElementsAre;
using ::testing::HasSubstr;
using ::testing::Not;

// Geometry must survive a round trip to 1e-6 (mm and direction entries). NIfTI stores the
// affine as float32, whose rounding (6e-8 relative) stays below this for coordinates
// under ~8 mm, as used here; MetaImage and NRRD store decimal doubles.
constexpr double kGeometryTolerance = 1e-6;

ImageGeometry ObliqueGeometry() {
  ImageGeometry g;
  g.size = Eigen::Vector3i(7, 6, 5);
  g.spacing_mm = Eigen::Vector3d(0.7, 1.1, 2.3);
  g.origin_mm = Eigen::Vector3d(-3.7, 2.9, 5.3);
  g.direction = Eigen::AngleAxisd(0.5, Eigen::Vector3d(1, -2, 0.5).normalized()).toRotationMatrix();
  return g;
}

// Voxel values that are not integers and not in order (so a transposed read would show).
Image ObliqueImage() {
  Image image(ObliqueGeometry());
  for (size_t v = 0; v < image.voxels.size(); ++v) {
    image.voxels[v] = 0.25f * static_cast<float>((v * 37) % 211) - 3.1f;
  }
  return image;
}

test_itk::Grid ToGrid(const ImageGeometry& g) {
  test_itk::Grid grid;
  grid.size = {g.size[0], g.size[1], g.size[2]};
  for (int a = 0; a < 3; ++a) {
    grid.origin[a] = g.origin_mm[a];
    grid.spacing[a] = g.spacing_mm[a];
    for (int b = 0; b < 3; ++b) grid.direction[3 * a + b] = g.direction(a, b);
  }
  return grid;
}

void ExpectSameGeometry(const ImageGeometry& actual, const ImageGeometry& expected) {
  EXPECT_EQ(actual.size, expected.size);
  EXPECT_LT((actual.origin_mm - expected.origin_mm).cwiseAbs().maxCoeff(), kGeometryTolerance)
      << actual.origin_mm.transpose();
  EXPECT_LT((actual.spacing_mm - expected.spacing_mm).cwiseAbs().maxCoeff(), kGeometryTolerance)
      << actual.spacing_mm.transpose();
  EXPECT_LT((actual.direction - expected.direction).cwiseAbs().maxCoeff(), kGeometryTolerance)
      << actual.direction;
}

// Every user-input error is one line that names the file.
void ExpectOneLineNaming(const std::string& error, const std::string& path) {
  EXPECT_EQ(error.find('\n'), std::string::npos) << error;
  EXPECT_THAT(error, HasSubstr(path));
}

// Reads `path` expecting failure; returns the error.
std::string ReadError(const std::string& path) {
  Image image;
  std::string error;
  EXPECT_FALSE(ReadImage(path, &image, &error)) << path;
  ExpectOneLineNaming(error, path);
  return error;
}

TEST(ImageIo, RoundTripKeepsGeometryAndVoxelsInEveryFormat) {
  const Image image = ObliqueImage();
  for (const std::string ext : {".nii", ".nii.gz", ".mha", ".mhd", ".nrrd", ".nhdr"}) {
    SCOPED_TRACE(ext);
    ScopedTempDir dir;
    const std::string path = dir.File("round" + ext);
    std::string error;
    ASSERT_TRUE(WriteImage(image, path, &error)) << error;
    Image back;
    ASSERT_TRUE(ReadImage(path, &back, &error)) << error;
    ExpectSameGeometry(back.geometry, image.geometry);
    EXPECT_EQ(back.voxels, image.voxels);
    // Overwriting works and leaves no temporary file or folder behind.
    ASSERT_TRUE(WriteImage(image, path, &error)) << error;
    for (const std::string& name : dir.Entries()) {
      EXPECT_EQ(name.rfind("round", 0), 0u) << "left behind: " << name;
    }
  }
}

TEST(ImageIo, DetachedHeaderKeepsItsDataFileName) {
  ScopedTempDir dir;
  std::string error;
  ASSERT_TRUE(WriteImage(ObliqueImage(), dir.File("frame.mhd"), &error)) << error;
  EXPECT_THAT(dir.Entries(), ElementsAre("frame.mhd", "frame.raw"));
  std::ifstream header(dir.File("frame.mhd"));
  const std::string text((std::istreambuf_iterator<char>(header)),
                         std::istreambuf_iterator<char>());
  EXPECT_THAT(text, HasSubstr("ElementDataFile = frame.raw"));
}

TEST(ImageIo, IntegerPixelTypesAreReadAsFloat) {
  ScopedTempDir dir;
  const ImageGeometry g = ObliqueGeometry();
  std::vector<double> bytes(g.NumVoxels()), shorts(g.NumVoxels());
  for (size_t v = 0; v < bytes.size(); ++v) {
    bytes[v] = static_cast<double>((v * 7) % 256);
    shorts[v] = static_cast<double>(static_cast<int>(v * 997 % 60000) - 30000);
  }
  for (const std::string name : {"u8.nii.gz", "u8.nrrd"}) {
    const std::string path = dir.File(name);
    ASSERT_EQ(test_itk::WriteScalarImage(path, ToGrid(g), test_itk::Pixel::kUint8, bytes), "");
    Image image;
    std::string error;
    ASSERT_TRUE(ReadImage(path, &image, &error)) << error;
    ExpectSameGeometry(image.geometry, g);
    EXPECT_EQ(std::vector<double>(image.voxels.begin(), image.voxels.end()), bytes) << name;
  }
  for (const std::string name : {"s16.nii", "s16.mha"}) {
    const std::string path = dir.File(name);
    ASSERT_EQ(test_itk::WriteScalarImage(path, ToGrid(g), test_itk::Pixel::kInt16, shorts), "");
    Image image;
    std::string error;
    ASSERT_TRUE(ReadImage(path, &image, &error)) << error;
    ExpectSameGeometry(image.geometry, g);
    EXPECT_EQ(std::vector<double>(image.voxels.begin(), image.voxels.end()), shorts) << name;
  }
}

// Writes `data` to `path` gzip-compressed: one member, or two split at `split` (what gzip
// writes for concatenated files) when `split` lies inside the data.
void GzipInMembers(const std::string& path, const std::string& data, size_t split) {
  for (int member = 0; member < (split < data.size() ? 2 : 1); ++member) {
    gzFile out = gzopen(path.c_str(), member == 0 ? "wb" : "ab");
    ASSERT_NE(out, nullptr);
    const size_t from = member == 0 ? 0 : split, to = member == 0 ? split : data.size();
    ASSERT_EQ(gzwrite(out, data.data() + from, static_cast<unsigned>(to - from)),
              static_cast<int>(to - from));
    ASSERT_EQ(gzclose(out), Z_OK);
  }
}

// Reads `path` with ReadImage into `image` and expects geometry `g` and ITK's own reader's
// voxels, bit for bit.
void ReadAsItkReadsIt(const std::string& path, const ImageGeometry& g, Image* image) {
  std::string error;
  ASSERT_TRUE(ReadImage(path, image, &error)) << error;
  ExpectSameGeometry(image->geometry, g);
  std::vector<std::vector<float>> itk;
  ASSERT_EQ(test_itk::ReadPhasesWithItk(path, &itk), "") << path;
  ASSERT_EQ(itk.size(), 1u);
  EXPECT_EQ(image->voxels, itk[0]) << path;
}

// A float NIfTI file is decompressed once: the data check copies the voxels out as it
// scans them (io_itk_nifti.cc; a .nii.gz of one gzip member inflated in one call by libdeflate,
// others by zlib's stream). The voxels and geometry read that way are ITK's own reader's,
// bit for bit, compressed or not, in 3D and as a 4D file of one volume, and as a file of two
// gzip members (what gzip writes for concatenated files); a header with scl_slope 2 and
// scl_inter 1 (which the copy must not skip) is read scaled, as ITK reads it.
TEST(ImageIo, FloatNiftiReadInTheCheckPassIsItksReadBitForBit) {
  ScopedTempDir dir;
  const ImageGeometry g = ObliqueGeometry();
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> value(-1e3, 1e3);
  std::vector<double> values(g.NumVoxels());
  for (double& v : values) v = value(rng);
  test_itk::Grid four = ToGrid(g);
  four.size.push_back(1);
  const auto compare = [&](const std::string& path, double slope, double intercept) {
    Image image;
    ASSERT_NO_FATAL_FAILURE(ReadAsItkReadsIt(path, g, &image));
    for (size_t v = 0; v < values.size(); v += 41) {
      EXPECT_EQ(image.voxels[v], static_cast<float>(slope * static_cast<float>(values[v]) +
                                                    intercept))
          << path << " voxel " << v;
    }
  };
  for (const std::string name : {"f.nii.gz", "f.nii", "f4.nii.gz"}) {
    const std::string path = dir.File(name);
    ASSERT_EQ(test_itk::WriteScalarImage(path, name == "f4.nii.gz" ? four : ToGrid(g),
                                         test_itk::Pixel::kFloat, values),
              "");
    compare(path, 1.0, 0.0);
  }
  {
    // f.nii as two gzip members, split in the middle of its voxels.
    std::ifstream plain(dir.File("f.nii"), std::ios::binary);
    const std::string bytes((std::istreambuf_iterator<char>(plain)),
                            std::istreambuf_iterator<char>());
    const std::string two = dir.File("two_members.nii.gz");
    ASSERT_NO_FATAL_FAILURE(GzipInMembers(two, bytes, bytes.size() / 2));
    compare(two, 1.0, 0.0);
  }
  // The uncompressed file with scl_slope = 2, scl_inter = 1 (bytes 112 and 116).
  const std::string scaled = dir.File("scaled.nii");
  std::filesystem::copy_file(dir.File("f.nii"), scaled);
  {
    std::fstream file(scaled, std::ios::in | std::ios::out | std::ios::binary);
    const float slope = 2.0f, intercept = 1.0f;
    file.seekp(112);
    file.write(reinterpret_cast<const char*>(&slope), 4);
    file.write(reinterpret_cast<const char*>(&intercept), 4);
  }
  compare(scaled, 2.0, 1.0);
}

// A uint8 NIfTI file (masks, 8-bit echo) is read in the data check's pass as well: one
// gzip member inflated whole and converted to float there, two members through ITK's read;
// both are ITK's own reader's voxels bit for bit, every byte value included, and a
// compressed header with scl_slope 2 and scl_inter 1 is read scaled, as ITK reads it.
TEST(ImageIo, Uint8NiftiReadInTheCheckPassIsItksReadBitForBit) {
  ScopedTempDir dir;
  const ImageGeometry g = ObliqueGeometry();
  std::vector<double> values(g.NumVoxels());
  for (size_t v = 0; v < values.size(); ++v) values[v] = static_cast<double>((v * 7 + 3) % 256);
  const auto compare = [&](const std::string& path, double slope, double intercept) {
    Image image;
    ASSERT_NO_FATAL_FAILURE(ReadAsItkReadsIt(path, g, &image));
    for (size_t v = 0; v < values.size(); ++v) {
      ASSERT_EQ(image.voxels[v], static_cast<float>(slope * values[v] + intercept)) << v;
    }
  };
  const std::string plain = dir.File("u8.nii");
  ASSERT_EQ(test_itk::WriteScalarImage(plain, ToGrid(g), test_itk::Pixel::kUint8, values), "");
  std::ifstream in(plain, std::ios::binary);
  std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  ASSERT_NO_FATAL_FAILURE(GzipInMembers(dir.File("one.nii.gz"), bytes, bytes.size()));
  compare(dir.File("one.nii.gz"), 1.0, 0.0);
  ASSERT_NO_FATAL_FAILURE(GzipInMembers(dir.File("two.nii.gz"), bytes, bytes.size() / 2));
  compare(dir.File("two.nii.gz"), 1.0, 0.0);
  const float slope = 2.0f, intercept = 1.0f;  // bytes 112 and 116
  std::memcpy(&bytes[112], &slope, 4);
  std::memcpy(&bytes[116], &intercept, 4);
  ASSERT_NO_FATAL_FAILURE(GzipInMembers(dir.File("scaled.nii.gz"), bytes, bytes.size()));
  compare(dir.File("scaled.nii.gz"), 2.0, 1.0);
}

TEST(ImageIo, FourDimensionalImageWithOneVolumeIsRead) {
  ScopedTempDir dir;
  const ImageGeometry g = ObliqueGeometry();
  test_itk::Grid grid = ToGrid(g);
  grid.size.push_back(1);
  std::vector<double> values(g.NumVoxels());
  for (size_t v = 0; v < values.size(); ++v) values[v] = static_cast<double>(v);
  const std::string path = dir.File("one_volume.nii.gz");
  ASSERT_EQ(test_itk::WriteScalarImage(path, grid, test_itk::Pixel::kFloat, values), "");
  Image image;
  std::string error;
  ASSERT_TRUE(ReadImage(path, &image, &error)) << error;
  ExpectSameGeometry(image.geometry, g);
  EXPECT_EQ(std::vector<double>(image.voxels.begin(), image.voxels.end()), values);
}

TEST(ImageIo, MissingFileIsAnError) {
  ScopedTempDir dir;
  EXPECT_EQ(ReadError(dir.File("missing.nii.gz")), dir.File("missing.nii.gz") + ": no such file");
}

TEST(ImageIo, UnsupportedExtensionListsTheSupportedOnes) {
  ScopedTempDir dir;
  const std::string path = dir.File("frame.png");
  std::ofstream(path) << "png";
  EXPECT_THAT(ReadError(path), HasSubstr("unsupported extension (supported: .nii, .nii.gz, .mha"));
  EXPECT_TRUE(HasSupportedImageExtension("a/B.NII.GZ"));
  EXPECT_TRUE(HasSupportedImageExtension("b.nhdr"));
  EXPECT_FALSE(HasSupportedImageExtension("c.gz"));
  EXPECT_FALSE(HasSupportedImageExtension("nii"));
}

TEST(ImageIo, TwoDimensionalImageIsRejected) {
  ScopedTempDir dir;
  const std::string path = dir.File("slice.nii");
  test_itk::Grid grid;
  grid.size = {4, 3};
  ASSERT_EQ(
      test_itk::WriteScalarImage(path, grid, test_itk::Pixel::kFloat, std::vector<double>(12, 1.0)),
      "");
  EXPECT_EQ(ReadError(path), path + ": 2D image; expected a 3D image");
}

TEST(ImageIo, FourDimensionalImageWithSeveralVolumesIsRejected) {
  ScopedTempDir dir;
  const std::string path = dir.File("series.nii.gz");
  test_itk::Grid grid;
  grid.size = {5, 4, 3, 4};
  ASSERT_EQ(test_itk::WriteScalarImage(
                path, grid, test_itk::Pixel::kFloat, std::vector<double>(240, 1.0)),
            "");
  EXPECT_EQ(
      ReadError(path),
      path + ": 4D image of size 5x4x3x4; expected a 3D image (4D only with a 4th size of 1)");
}

TEST(ImageIo, VectorPixelsAreRejected) {
  for (const std::string ext : {".nii.gz", ".mha", ".nrrd"}) {
    ScopedTempDir dir;
    const std::string path = dir.File("vectors" + ext);
    test_itk::Grid grid;
    grid.size = {4, 3, 2};
    ASSERT_EQ(test_itk::WriteVectorImage(path, grid), "");
    EXPECT_THAT(ReadError(path),
                HasSubstr(": vector pixels (3 components); expected a scalar image"));
  }
}

TEST(ImageIo, CorruptHeaderIsRejected) {
  ScopedTempDir dir;
  const std::string path = dir.File("garbage.nii");
  std::ofstream out(path, std::ios::binary);
  std::mt19937 rng(7);
  for (int i = 0; i < 2048; ++i) out.put(static_cast<char>(rng() & 0xff));
  out.close();
  EXPECT_THAT(ReadError(path), HasSubstr("cannot read the header"));

  const std::string text = dir.File("text.mha");
  std::ofstream(text) << "this is not a MetaImage header\n";
  EXPECT_THAT(ReadError(text), HasSubstr("cannot read the header"));
}

// Found by tests/fuzz/fuzz_image: a NIfTI header whose orientation fields are NaN, infinite
// or huge made ITK's reader abort the process (vnl_svd's assert_finite); now it is a
// one-line error naming the field.
TEST(ImageIo, NonFiniteNiftiOrientationIsAnErrorNotAnAbort) {
  ScopedTempDir dir;
  const std::string good = dir.File("good.nii");
  std::string error;
  ASSERT_TRUE(WriteImage(ObliqueImage(), good, &error)) << error;
  std::ifstream in(good, std::ios::binary);
  const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  ASSERT_GT(bytes.size(), 348u);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const float huge = 3e38f;
  const int16_t one = 1;
  struct Patch {
    const char* name;
    int offset;
    float value;
    int code_offset;  // qform_code (252) or sform_code (254) set to 1; -1 for pixdim
    const char* field;
  };
  for (const Patch& patch : {Patch{"srow_nan.nii", 280, nan, 254, "srow"},
                             Patch{"srow_huge.nii", 300, huge, 254, "srow"},
                             Patch{"quatern_nan.nii", 256, nan, 252, "quatern"},
                             Patch{"pixdim_inf.nii", 80, std::numeric_limits<float>::infinity(),
                                   -1, "pixdim"},
                             Patch{"bad_sizeof_hdr.nii", 104, nan, -1, "pixdim"}}) {
    std::string damaged = bytes;
    std::memcpy(&damaged[patch.offset], &patch.value, sizeof(float));
    if (std::string(patch.name) == "bad_sizeof_hdr.nii") {
      // niftilib reads a header whose sizeof_hdr is garbage (it trusts dim[0])
      const int32_t garbage = -553647780;
      std::memcpy(&damaged[0], &garbage, sizeof(garbage));
    }
    if (patch.code_offset > 0) std::memcpy(&damaged[patch.code_offset], &one, sizeof(one));
    const std::string path = dir.File(patch.name);
    std::ofstream(path, std::ios::binary).write(damaged.data(), damaged.size());
    EXPECT_THAT(ReadError(path), HasSubstr(patch.field)) << patch.name;
  }
}

// Found by tests/fuzz/fuzz_image: a tiny file whose header promises gigabytes of voxels
// (here a NIfTI header with a garbage sizeof_hdr, which niftilib accepts) made the reader
// allocate them before looking at the data; now refused up front.
TEST(ImageIo, HeaderPromisingMoreThanTheFileHoldsIsRefusedBeforeAllocating) {
  ScopedTempDir dir;
  const std::string good = dir.File("small.nii");
  std::string error;
  ASSERT_TRUE(WriteImage(ObliqueImage(), good, &error)) << error;
  std::ifstream in(good, std::ios::binary);
  std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const int32_t garbage = -553647780;
  const int16_t dims[4] = {3, 2000, 2000, 2000};  // 32 GB of float voxels
  std::memcpy(&bytes[0], &garbage, sizeof(garbage));
  std::memcpy(&bytes[40], dims, sizeof(dims));
  const std::string path = dir.File("promises_too_much.nii");
  std::ofstream(path, std::ios::binary).write(bytes.data(), bytes.size());
  EXPECT_THAT(ReadError(path), HasSubstr("more than a"));
}

// Found by tests/fuzz/fuzz_image: a MetaImage header key longer than 255 characters
// overflowed a strcpy buffer inside ITK's MetaIO (the process aborted); now an error.
TEST(ImageIo, OverlongMetaImageHeaderKeyIsAnErrorNotAnAbort) {
  ScopedTempDir dir;
  for (const std::string& line : {std::string(300, 'K'), std::string(300, 'K') + " = 1"}) {
    const std::string path = dir.File("long_key.mha");
    std::ofstream(path, std::ios::binary)
        << line << "\nObjectType = Image\nNDims = 3\nDimSize = 2 2 2\n"
        << "ElementType = MET_FLOAT\nElementDataFile = LOCAL\n" << std::string(32, '\0');
    EXPECT_THAT(ReadError(path), HasSubstr("key of 300 characters"));
  }
  // Also found by fuzzing: control characters in ElementDataFile made MetaIO read past a
  // buffer (AddressSanitizer, heap-buffer-overflow in MetaImage::ReadStream).
  const std::string path = dir.File("control.mha");
  std::ofstream(path, std::ios::binary)
      << "ObjectType = Image\nNDims = 3\nDimSize = 2 2 2\nElementType = MET_FLOAT\n"
      << "ElementDataFile =gggg\x12\x12\x12gggg\n" << std::string(32, '\0');
  EXPECT_THAT(ReadError(path), HasSubstr("line 5 contains control characters"));
  // And a printf pattern in ElementDataFile, which MetaIO hands to snprintf as the format.
  const std::string pattern = dir.File("pattern.mha");
  std::ofstream(pattern, std::ios::binary)
      << "ObjectType = Image\nNDims = 3\nDimSize = 2 2 2\nElementType = MET_FLOAT\n"
      << "ElementDataFile = %space: left-posage\n" << std::string(32, '\0');
  EXPECT_THAT(ReadError(pattern), HasSubstr("patterns"));
  // And a key without '=': MetaIO took the following lines as its value, then a "%" in
  // them as a file pattern with step 0 (SIGFPE, integer division by zero).
  const std::string no_equals = dir.File("no_equals.mha");
  std::ofstream(no_equals, std::ios::binary)
      << "ObjectType = Image\nNDims = 3\nDimSize = 4 3 2\nElementType = MET_FLOAT\n"
      << "ElementDataFile \nLB 4 =inaryD.ta 6%-pe = MET_FLOAT\n" << std::string(96, '\0');
  EXPECT_THAT(ReadError(no_equals), HasSubstr("line 5 is not a 'key = value' line"));
  // And a huge NDims: MetaIO read that many numbers per array field, for hours.
  const std::string huge = dir.File("huge_ndims.mha");
  std::ofstream(huge, std::ios::binary)
      << "ObjectType = Image\nNDims = 1111111111111111111111113\nDimSize = 3 3 2\n"
      << "ElementType = MET_FLOAT\nElementDataFile = LOCAL\n" << std::string(72, '\0');
  EXPECT_THAT(ReadError(huge), HasSubstr("NDims = '1111111111111111111"));
}

// ITK 5.2 itself returns zeros or garbage for a truncated NIfTI or MetaImage data block.
TEST(ImageIo, TruncatedOrCorruptDataIsRejected) {
  ImageGeometry g;
  g.size = Eigen::Vector3i(16, 16, 16);
  Image image(g);
  std::mt19937 rng(11);  // random voxels so that compression cannot shrink them away
  std::uniform_real_distribution<float> value(-100.0f, 100.0f);
  for (float& v : image.voxels) v = value(rng);
  struct Case {
    std::string written;  // the image file
    std::string damaged;  // the file that is cut or overwritten (the data file for .mhd)
    bool truncate;        // else 64 bytes in the middle are overwritten
    std::string expected;
  };
  const Case cases[] = {
      {"cut.nii.gz", "cut.nii.gz", true, "cannot read the voxels (data ends after "},
      {"cut.nii", "cut.nii", true, "cannot read the voxels (data ends after 8016 of 16384 bytes"},
      {"cut.mha", "cut.mha", true, "cannot read the voxels (data ends after "},
      {"cut.mhd", "cut.raw", true, "cannot read the voxels (data file cut.raw ends after 8192 of"},
      {"cut.nrrd", "cut.nrrd", true, "cannot read the voxels (_nrrdEncodingGzip_read: expected"},
      {"bad.nii.gz", "bad.nii.gz", false, "cannot read the voxels (compressed data is corrupt"},
      {"bad.mha", "bad.mha", false, "cannot read the voxels (compressed data is corrupt"},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.written);
    ScopedTempDir dir;
    std::string error;
    ASSERT_TRUE(WriteImage(image, dir.File(c.written), &error)) << error;
    const std::string damaged = dir.File(c.damaged);
    const auto size = std::filesystem::file_size(damaged);
    if (c.truncate) {
      std::filesystem::resize_file(damaged, size / 2);
    } else {
      std::fstream file(damaged, std::ios::in | std::ios::out | std::ios::binary);
      file.seekp(static_cast<std::streamoff>(size / 2));
      for (int i = 0; i < 64; ++i) file.put(static_cast<char>(rng() & 0xff));
    }
    EXPECT_THAT(ReadError(dir.File(c.written)), HasSubstr(c.expected));
  }
}

TEST(ImageIo, NonFiniteVoxelsAreRejectedWithTheirIndex) {
  ScopedTempDir dir;
  Image image = ObliqueImage();
  image.at(3, 2, 1) = std::numeric_limits<float>::quiet_NaN();
  const std::string nan_path = dir.File("nan.mha");
  std::string error;
  ASSERT_TRUE(WriteImage(image, nan_path, &error)) << error;
  EXPECT_EQ(ReadError(nan_path), nan_path + ": voxel (3,2,1) is NaN");

  image = ObliqueImage();
  image.at(6, 0, 4) = -std::numeric_limits<float>::infinity();
  const std::string inf_path = dir.File("inf.nrrd");
  ASSERT_TRUE(WriteImage(image, inf_path, &error)) << error;
  EXPECT_EQ(ReadError(inf_path), inf_path + ": voxel (6,0,4) is Inf");
}

// A MetaImage file written by hand, so that its header can hold any geometry.
std::string WriteMetaImage(const ScopedTempDir& dir,
                           const std::string& name,
                           const std::string& spacing,
                           const std::string& matrix,
                           const std::string& dim_size = "2 2 2") {
  const std::string path = dir.File(name);
  std::ofstream out(path, std::ios::binary);
  out << "ObjectType = Image\nNDims = 3\nBinaryData = True\nBinaryDataByteOrderMSB = False\n"
      << "CompressedData = False\nTransformMatrix = " << matrix << "\nOffset = 0 0 0\n"
      << "ElementSpacing = " << spacing << "\nDimSize = " << dim_size
      << "\nElementType = MET_FLOAT\n"
      << "ElementDataFile = LOCAL\n";
  const float voxels[8] = {1, 2, 3, 4, 5, 6, 7, 8};
  out.write(reinterpret_cast<const char*>(voxels), sizeof(voxels));
  return path;
}

TEST(ImageIo, InvalidGeometryIsRejected) {
  ScopedTempDir dir;
  const std::string identity = "1 0 0 0 1 0 0 0 1";
  Image image;
  std::string error;
  ASSERT_TRUE(ReadImage(WriteMetaImage(dir, "fine.mha", "1 2 3", identity), &image, &error))
      << error;
  EXPECT_EQ(image.geometry.spacing_mm, Eigen::Vector3d(1, 2, 3));
  EXPECT_EQ(image.voxels[7], 8.0f);

  EXPECT_THAT(ReadError(WriteMetaImage(dir, "zero.mha", "1 0 1", identity)), HasSubstr("spacing"));
  EXPECT_THAT(ReadError(WriteMetaImage(dir, "negative.mha", "1 -2 1", identity)),
              HasSubstr("spacing"));
  EXPECT_THAT(ReadError(WriteMetaImage(dir, "singular.mha", "1 1 1", "1 0 0 0 1 0 0 0 0")),
              HasSubstr("direction"));
  EXPECT_THAT(ReadError(WriteMetaImage(dir, "sheared.mha", "1 1 1", "1 0.5 0 0 1 0 0 0 1")),
              HasSubstr("direction"));
}

TEST(ImageIo, HeaderThatDoesNotParseOrPromisesTooMuchIsRejected) {
  ScopedTempDir dir;
  const std::string identity = "1 0 0 0 1 0 0 0 1";
  EXPECT_EQ(ReadError(WriteMetaImage(dir, "nan.mha", "1 nan 1", identity)),
            dir.File("nan.mha") +
                ": cannot read the header (File cannot be read: " + dir.File("nan.mha") + ")");
  EXPECT_THAT(ReadError(WriteMetaImage(dir, "empty.mha", "1 1 1", identity, "2 0 2")),
              HasSubstr("every dimension must be >= 1"));
  // 4e15 bytes promised, 32 present: refused before anything is allocated.
  EXPECT_THAT(ReadError(WriteMetaImage(dir, "huge.mha", "1 1 1", identity, "100000 100000 100000")),
              HasSubstr("cannot read the voxels (data ends after 32 of 4000000000000000 bytes"));
}

TEST(ImageIo, MissingDataFileIsRejected) {
  ScopedTempDir dir;
  const std::string path = dir.File("frame.mhd");
  std::string error;
  ASSERT_TRUE(WriteImage(ObliqueImage(), path, &error)) << error;
  std::filesystem::remove(dir.File("frame.raw"));
  EXPECT_THAT(ReadError(path), HasSubstr("cannot read the voxels"));
}

TEST(ImageIo, FolderIsNotAnImage) {
  ScopedTempDir dir;
  std::filesystem::create_directory(dir.File("sub.nii"));
  EXPECT_THAT(ReadError(dir.File("sub.nii")), HasSubstr("is a folder"));
}

TEST(ImageIo, WriteErrorsNameTheOutput) {
  ScopedTempDir dir;
  const Image image = ObliqueImage();
  std::string error;

  std::filesystem::create_directory(dir.File("folder.nii"));
  EXPECT_FALSE(WriteImage(image, dir.File("folder.nii"), &error));
  EXPECT_EQ(error, dir.File("folder.nii") + ": is a folder, expected a file name");

  const std::string missing = dir.File("no/such/folder/out.nii.gz");
  EXPECT_FALSE(WriteImage(image, missing, &error));
  EXPECT_EQ(error, missing + ": folder " + dir.File("no/such/folder") + " does not exist");

  EXPECT_FALSE(WriteImage(image, dir.File("out.tiff"), &error));
  EXPECT_THAT(error, HasSubstr("unsupported extension"));

  Image flat = image;
  flat.geometry.spacing_mm[1] = 0.0;
  EXPECT_FALSE(WriteImage(flat, dir.File("flat.nii"), &error));
  ExpectOneLineNaming(error, dir.File("flat.nii"));
  EXPECT_THAT(error, HasSubstr("spacing"));
  EXPECT_THAT(dir.Entries(), ElementsAre("folder.nii"));
}

TEST(ImageIo, FailedWriteKeepsTheOldFile) {
  if (geteuid() == 0) GTEST_SKIP() << "root ignores folder permissions";
  ScopedTempDir dir;
  const std::string path = dir.File("keep.nii.gz");
  std::string error;
  ASSERT_TRUE(WriteImage(ObliqueImage(), path, &error)) << error;
  ASSERT_EQ(::chmod(dir.path().c_str(), 0555), 0);
  Image other = ObliqueImage();
  other.voxels.assign(other.voxels.size(), 42.0f);
  EXPECT_FALSE(WriteImage(other, path, &error));
  EXPECT_EQ(error, path + ": folder " + dir.path() + " is not writable");
  ::chmod(dir.path().c_str(), 0755);
  Image back;
  ASSERT_TRUE(ReadImage(path, &back, &error)) << error;
  EXPECT_EQ(back.voxels, ObliqueImage().voxels);
}

TEST(MaskIo, RoundTripAndNonZeroIsInside) {
  ScopedTempDir dir;
  const ImageGeometry g = ObliqueGeometry();
  Mask mask(g, 0);
  mask.at(1, 2, 3) = 1;
  mask.at(6, 5, 4) = 200;  // any non-zero value is inside, written as 1
  std::string error;
  for (const std::string ext : {".nii.gz", ".mha", ".nrrd"}) {
    const std::string path = dir.File("mask" + ext);
    ASSERT_TRUE(WriteMask(mask, path, &error)) << error;
    Mask back;
    ASSERT_TRUE(ReadMask(path, g, &back, &error)) << error;
    EXPECT_EQ(back.geometry.size, g.size);
    EXPECT_EQ(CountInside(back), 2);
    EXPECT_EQ(back.at(1, 2, 3), 1);
    EXPECT_EQ(back.at(6, 5, 4), 1);
  }
  // A float mask with arbitrary non-zero values.
  std::vector<double> values(g.NumVoxels(), 0.0);
  values[5] = -0.5;
  values[9] = 3.0;
  const std::string path = dir.File("float_mask.nii");
  ASSERT_EQ(test_itk::WriteScalarImage(path, ToGrid(g), test_itk::Pixel::kDouble, values), "");
  Mask back;
  ASSERT_TRUE(ReadMask(path, g, &back, &error)) << error;
  EXPECT_EQ(CountInside(back), 2);
  EXPECT_EQ(back.voxels[5], 1);
  EXPECT_EQ(back.voxels[9], 1);
}

TEST(MaskIo, MaskOfAnotherSizeIsRejected) {
  ScopedTempDir dir;
  const ImageGeometry g = ObliqueGeometry();
  ImageGeometry bigger = g;
  bigger.size = Eigen::Vector3i(32, 32, 32);
  const std::string path = dir.File("mask.nii.gz");
  std::string error;
  ASSERT_TRUE(WriteMask(Mask(bigger, 1), path, &error)) << error;
  Mask mask;
  EXPECT_FALSE(ReadMask(path, g, &mask, &error));
  ExpectOneLineNaming(error, path);
  EXPECT_THAT(error, HasSubstr(": mask grid 32x32x32 voxels"));
  EXPECT_THAT(error, HasSubstr("does not match the image grid 7x6x5 voxels"));
}

TEST(MaskIo, MaskOnAShiftedGridIsRejected) {
  ScopedTempDir dir;
  const ImageGeometry g = ObliqueGeometry();
  ImageGeometry shifted = g;
  shifted.origin_mm[0] += 0.5;
  const std::string path = dir.File("shifted.mha");
  std::string error;
  ASSERT_TRUE(WriteMask(Mask(shifted, 1), path, &error)) << error;
  Mask mask;
  EXPECT_FALSE(ReadMask(path, g, &mask, &error));
  ExpectOneLineNaming(error, path);
  EXPECT_THAT(error, HasSubstr("mask grid does not match the image grid (origin -3.2,2.9,5.3 mm"));

  ImageGeometry scaled = g;
  scaled.spacing_mm[2] = 2.0;
  ASSERT_TRUE(WriteMask(Mask(scaled, 1), path, &error)) << error;
  EXPECT_FALSE(ReadMask(path, g, &mask, &error));
  EXPECT_THAT(error, HasSubstr("(spacing 0.7,1.1,2 mm vs 0.7,1.1,2.3 mm)"));

  ImageGeometry turned = g;
  turned.direction = Eigen::Matrix3d::Identity();
  ASSERT_TRUE(WriteMask(Mask(turned, 1), path, &error)) << error;
  EXPECT_FALSE(ReadMask(path, g, &mask, &error));
  EXPECT_THAT(error, HasSubstr("(direction differs by up to"));
}

TEST(MaskIo, EmptyMaskIsRejected) {
  ScopedTempDir dir;
  const ImageGeometry g = ObliqueGeometry();
  const std::string path = dir.File("empty.nii.gz");
  std::string error;
  ASSERT_TRUE(WriteMask(Mask(g, 0), path, &error)) << error;
  Mask mask;
  EXPECT_FALSE(ReadMask(path, g, &mask, &error));
  EXPECT_EQ(error, path + ": mask has no voxel inside (every voxel is 0)");
}

TEST(MaskIo, ImageErrorsApplyToMasks) {
  ScopedTempDir dir;
  Mask mask;
  std::string error;
  EXPECT_FALSE(ReadMask(dir.File("none.nii"), ObliqueGeometry(), &mask, &error));
  EXPECT_EQ(error, dir.File("none.nii") + ": no such file");
  EXPECT_THAT(error, Not(HasSubstr("\n")));
}

}  // namespace
}  // namespace dsr
