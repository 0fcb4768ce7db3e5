// 4D images as phases (io/io_phases.h): exact round trips in NIfTI, NRRD and 3D Slicer's
// .seq.nrrd, the written headers field by field, 4D files other tools write, 4D masks, and
// one-line errors naming the file for every bad input.
#include "dsr/io/io_phases.h"

#include <malloc.h>
#include <zlib.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <iostream>
#include <iterator>
#include <limits>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "dsr/io/io_image.h"
#include "dsr/io/io_image_test_itk.h"
#include "dsr/tests/support/scoped_temp_dir.h"

namespace dsr {
namespace {

using ::testing::HasSubstr;
using ::testing::Not;

// As in io_image_test: NIfTI stores the affine as float32, fine to 1e-6 for these sizes.
constexpr double kGeometryTolerance = 1e-6;
constexpr int kPhases = 3;

// Anisotropic spacing, a rotated direction and an origin away from 0.
ImageGeometry ObliqueGeometry() {
  ImageGeometry g;
  g.size = Eigen::Vector3i(7, 6, 5);
  g.spacing_mm = Eigen::Vector3d(0.7, 1.1, 2.3);
  g.origin_mm = Eigen::Vector3d(-3.7, 2.9, 5.3);
  g.direction = Eigen::AngleAxisd(0.5, Eigen::Vector3d(1, -2, 0.5).normalized()).toRotationMatrix();
  return g;
}

// Phases whose voxels differ from phase to phase and are not in order.
std::vector<Image> ObliquePhases(int count = kPhases) {
  std::vector<Image> phases;
  for (int t = 0; t < count; ++t) {
    Image image(ObliqueGeometry());
    for (size_t v = 0; v < image.voxels.size(); ++v) {
      image.voxels[v] = 0.25f * static_cast<float>((v * 37 + 11 * t) % 211) - 3.1f + 100.0f * t;
    }
    phases.push_back(image);
  }
  return phases;
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

void ExpectSamePhases(const std::vector<Image>& actual, const std::vector<Image>& expected) {
  ASSERT_EQ(actual.size(), expected.size());
  for (size_t t = 0; t < actual.size(); ++t) {
    SCOPED_TRACE("phase " + std::to_string(t));
    ExpectSameGeometry(actual[t].geometry, expected[t].geometry);
    EXPECT_EQ(actual[t].voxels, expected[t].voxels);
  }
}

void ExpectOneLineNaming(const std::string& error, const std::string& path) {
  EXPECT_EQ(error.find('\n'), std::string::npos) << error;
  EXPECT_THAT(error, HasSubstr(path));
}

std::string ReadPhasesError(const std::string& path) {
  std::vector<Image> phases;
  std::string error;
  EXPECT_FALSE(ReadPhases(path, &phases, &error)) << path;
  ExpectOneLineNaming(error, path);
  return error;
}

void WriteText(const std::string& path, const std::string& text) {
  std::ofstream out(path, std::ios::binary);
  out << text;
}

std::string ReadBytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

// The header lines of a NRRD file (up to its first empty line): "field: value" lines by
// field, "key:=value" lines by key, each with the rest of its line.
struct NrrdHeader {
  std::string magic;
  std::map<std::string, std::string> fields;
  std::map<std::string, std::string> keys;
};

NrrdHeader ReadNrrdHeader(const std::string& path) {
  NrrdHeader header;
  std::ifstream in(path, std::ios::binary);
  std::getline(in, header.magic);
  for (std::string line; std::getline(in, line) && !line.empty();) {
    if (line[0] == '#') continue;
    const size_t key = line.find(":=");
    if (key != std::string::npos) {
      header.keys[line.substr(0, key)] = line.substr(key + 2);
      continue;
    }
    const size_t colon = line.find(": ");
    if (colon != std::string::npos) header.fields[line.substr(0, colon)] = line.substr(colon + 2);
  }
  return header;
}

// "(a,b,c)" -> {a, b, c}.
std::vector<double> ParseVector(const std::string& text) {
  std::vector<double> values;
  std::string inner = text.substr(1, text.size() - 2);
  std::istringstream in(inner);
  for (std::string item; std::getline(in, item, ',');) values.push_back(std::stod(item));
  return values;
}

std::vector<std::string> Words(const std::string& text) {
  std::vector<std::string> words;
  std::istringstream in(text);
  for (std::string word; in >> word;) words.push_back(word);
  return words;
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

TEST(PhasesIo, RoundTripKeepsGeometryAndVoxelsInEveryFormat) {
  const std::vector<Image> phases = ObliquePhases();
  for (const std::string ext :
       {".nii.gz", ".nii", ".seq.nrrd", ".nrrd", ".nhdr", ".seq.nhdr", ".mha", ".mhd"}) {
    SCOPED_TRACE(ext);
    ScopedTempDir dir;
    const std::string path = dir.File("phases" + ext);
    std::string error;
    ASSERT_TRUE(WritePhases(phases, path, &error)) << error;
    int count = 0;
    ASSERT_TRUE(NumPhasesInFile(path, &count, &error)) << error;
    EXPECT_EQ(count, kPhases);
    std::vector<Image> back;
    ASSERT_TRUE(ReadPhases(path, &back, &error)) << error;
    ExpectSamePhases(back, phases);
    // Overwriting works and leaves no temporary file or folder behind.
    ASSERT_TRUE(WritePhases(phases, path, &error)) << error;
    for (const std::string& name : dir.Entries()) {
      EXPECT_EQ(name.rfind("phases", 0), 0u) << "left behind: " << name;
    }
    // A 4D image is no 3D image: ReadImage still refuses it.
    Image image;
    EXPECT_FALSE(ReadImage(path, &image, &error));
  }
}

TEST(PhasesIo, DetachedNrrdKeepsItsDataFileName) {
  ScopedTempDir dir;
  std::string error;
  ASSERT_TRUE(WritePhases(ObliquePhases(), dir.File("p.nhdr"), &error)) << error;
  EXPECT_THAT(dir.Entries(), ::testing::UnorderedElementsAre("p.nhdr", "p.raw"));
  EXPECT_EQ(ReadNrrdHeader(dir.File("p.nhdr")).fields["data file"], "p.raw");
}

TEST(PhasesIo, ThreeDimensionalFileIsOnePhaseAsReadImageReadsIt) {
  ScopedTempDir dir;
  const Image image = ObliquePhases(1)[0];
  for (const std::string ext : {".nii.gz", ".nrrd", ".mha"}) {
    SCOPED_TRACE(ext);
    const std::string path = dir.File("three_d" + ext);
    std::string error;
    ASSERT_TRUE(WriteImage(image, path, &error)) << error;
    Image expected;
    ASSERT_TRUE(ReadImage(path, &expected, &error)) << error;
    std::vector<Image> phases;
    ASSERT_TRUE(ReadPhases(path, &phases, &error)) << error;
    ASSERT_EQ(phases.size(), 1u);
    EXPECT_EQ(phases[0].geometry.size, expected.geometry.size);
    EXPECT_EQ(phases[0].geometry.origin_mm, expected.geometry.origin_mm);
    EXPECT_EQ(phases[0].geometry.spacing_mm, expected.geometry.spacing_mm);
    EXPECT_EQ(phases[0].geometry.direction, expected.geometry.direction);
    EXPECT_EQ(phases[0].voxels, expected.voxels);
    int count = 0;
    ASSERT_TRUE(NumPhasesInFile(path, &count, &error)) << error;
    EXPECT_EQ(count, 1);
  }
}

TEST(PhasesIo, OnePhaseIsWrittenAsWriteImageWritesIt) {
  ScopedTempDir dir;
  const std::vector<Image> one = ObliquePhases(1);
  for (const std::string ext : {".nii", ".nrrd", ".seq.nrrd"}) {
    SCOPED_TRACE(ext);
    std::string error;
    ASSERT_TRUE(WriteImage(one[0], dir.File("image" + ext), &error)) << error;
    ASSERT_TRUE(WritePhases(one, dir.File("phases" + ext), &error)) << error;
    const std::string written = ReadBytes(dir.File("phases" + ext));
    EXPECT_FALSE(written.empty());
    EXPECT_EQ(written, ReadBytes(dir.File("image" + ext)));
  }
}

TEST(PhasesIo, SlicerSequenceHeaderFollowsTheFormat) {
  ScopedTempDir dir;
  const std::vector<Image> phases = ObliquePhases();
  const std::string path = dir.File("cine.seq.nrrd");
  std::string error;
  ASSERT_TRUE(WritePhases(phases, path, &error)) << error;
  NrrdHeader header = ReadNrrdHeader(path);
  EXPECT_EQ(header.magic.rfind("NRRD000", 0), 0u) << header.magic;
  EXPECT_EQ(header.fields["type"], "float");
  EXPECT_EQ(header.fields["dimension"], "4");
  EXPECT_EQ(header.fields["space"], "left-posterior-superior");
  EXPECT_EQ(header.fields["sizes"], "3 7 6 5");  // the list axis first, then I, J, K
  EXPECT_EQ(header.fields["kinds"], "list domain domain domain");
  EXPECT_EQ(header.fields["labels"], "\"phase\" \"\" \"\" \"\"");
  EXPECT_EQ(header.fields["encoding"], "gzip");
  // The list axis has no space direction; the others are the columns of D S.
  const std::vector<std::string> directions = Words(header.fields["space directions"]);
  ASSERT_EQ(directions.size(), 4u) << header.fields["space directions"];
  EXPECT_EQ(directions[0], "none");
  const ImageGeometry g = ObliqueGeometry();
  const Eigen::Matrix3d ds = g.IndexToPhysicalMatrix();
  for (int a = 0; a < 3; ++a) {
    const std::vector<double> column = ParseVector(directions[a + 1]);
    ASSERT_EQ(column.size(), 3u) << directions[a + 1];
    for (int r = 0; r < 3; ++r) EXPECT_NEAR(column[r], ds(r, a), 1e-12) << a << "," << r;
  }
  const std::vector<double> origin = ParseVector(header.fields["space origin"]);
  ASSERT_EQ(origin.size(), 3u);
  for (int r = 0; r < 3; ++r) EXPECT_NEAR(origin[r], g.origin_mm[r], 1e-12);
  // 3D Slicer's sequence keys: scalar volumes indexed 0..T-1.
  EXPECT_EQ(header.keys["DataNodeClassName"], "vtkMRMLScalarVolumeNode");
  EXPECT_EQ(header.keys["axis 0 index type"], "numeric");
  EXPECT_EQ(header.keys["axis 0 index values"], "0 1 2");
  EXPECT_EQ(header.keys.size(), 3u);
  // A plain .nrrd has the same list axis and none of the sequence keys.
  const std::string plain = dir.File("cine.nrrd");
  ASSERT_TRUE(WritePhases(phases, plain, &error)) << error;
  header = ReadNrrdHeader(plain);
  EXPECT_EQ(header.fields["kinds"], "list domain domain domain");
  EXPECT_EQ(header.fields["sizes"], "3 7 6 5");
  EXPECT_TRUE(header.keys.empty());
}

// NIfTI-1 header fields of a written .nii (uncompressed, little-endian on this machine).
template <typename T>
T NiftiField(const std::string& bytes, size_t offset) {
  T value;
  std::memcpy(&value, bytes.data() + offset, sizeof(T));
  return value;
}

TEST(PhasesIo, NiftiHasATimeAxisOfSpacingOne) {
  ScopedTempDir dir;
  const std::string path = dir.File("cine.nii");
  std::string error;
  ASSERT_TRUE(WritePhases(ObliquePhases(), path, &error)) << error;
  const std::string bytes = ReadBytes(path);
  ASSERT_GE(bytes.size(), 348u);
  EXPECT_EQ(NiftiField<int16_t>(bytes, 40), 4);            // dim[0]
  EXPECT_EQ(NiftiField<int16_t>(bytes, 40 + 2 * 4), kPhases);  // dim[4]
  EXPECT_EQ(NiftiField<float>(bytes, 76 + 4 * 4), 1.0f);   // pixdim[4]
  const int units = NiftiField<uint8_t>(bytes, 123);        // xyzt_units
  EXPECT_EQ(units & 0x07, 2);  // NIFTI_UNITS_MM
  EXPECT_EQ(units & 0x38, 0);  // the time unit is unknown: the 4th index is a phase
  EXPECT_EQ(NiftiField<int16_t>(bytes, 70), 16);  // datatype float32
}

TEST(PhasesIo, FourDimensionalFilesOfOtherToolsAreRead) {
  // ITK's own 4D writer (what SimpleITK writes for a 4D image): four domain axes.
  const ImageGeometry g = ObliqueGeometry();
  test_itk::Grid grid = ToGrid(g);
  grid.size.push_back(kPhases);
  std::vector<double> values(static_cast<size_t>(g.NumVoxels()) * kPhases);
  for (size_t v = 0; v < values.size(); ++v) values[v] = static_cast<double>((v * 7) % 101);
  for (const std::string ext : {".nii.gz", ".nrrd", ".mha"}) {
    SCOPED_TRACE(ext);
    ScopedTempDir dir;
    const std::string path = dir.File("itk4d" + ext);
    ASSERT_EQ(test_itk::WriteScalarImage(path, grid, test_itk::Pixel::kInt16, values), "");
    std::vector<Image> phases;
    std::string error;
    ASSERT_TRUE(ReadPhases(path, &phases, &error)) << error;
    ASSERT_EQ(phases.size(), static_cast<size_t>(kPhases));
    for (int t = 0; t < kPhases; ++t) {
      ExpectSameGeometry(phases[t].geometry, g);
      const size_t n = static_cast<size_t>(g.NumVoxels());
      EXPECT_EQ(std::vector<double>(phases[t].voxels.begin(), phases[t].voxels.end()),
                std::vector<double>(values.begin() + t * n, values.begin() + (t + 1) * n));
    }
  }
}

// A 2x2x2 NRRD of `phases` phases with voxel value 10 * phase + voxel (ascii), the phase
// axis of kind `kind` at position `list_axis` (0 or 3), with `extra` header lines.
std::string SmallNrrd(int phases,
                      const std::string& kind,
                      int list_axis,
                      const std::string& extra) {
  std::ostringstream text;
  const std::string sizes = list_axis == 0 ? std::to_string(phases) + " 2 2 2"
                                           : "2 2 2 " + std::to_string(phases);
  const std::string kinds = list_axis == 0 ? kind + " domain domain domain"
                                           : "domain domain domain " + kind;
  const std::string directions = list_axis == 0 ? "none (2,0,0) (0,3,0) (0,0,4)"
                                                : "(2,0,0) (0,3,0) (0,0,4) none";
  text << "NRRD0005\ntype: float\ndimension: 4\nspace: left-posterior-superior\nsizes: " << sizes
       << "\nspace directions: " << directions << "\nkinds: " << kinds
       << "\nencoding: ascii\nspace origin: (1,-2,3)\n" << extra << "\n";
  for (int k = 0; k < 8 * phases; ++k) {
    const int voxel = list_axis == 0 ? k / phases : k % 8;
    const int phase = list_axis == 0 ? k % phases : k / 8;
    text << 10 * phase + voxel << "\n";
  }
  return text.str();
}

TEST(PhasesIo, NrrdListAxisIsReadFirstOrLast) {
  // 3D Slicer wrote the list axis first (axis 0) and now writes it last (axis 3); ITK
  // writes vector images with a "vector" axis first.
  struct Case {
    std::string kind;
    int list_axis;
    std::string keys;
  };
  for (const Case& c : {Case{"list", 0, "axis 0 index values:=0 1 2\n"},
                        Case{"list", 3, "axis 3 index values:=0 1 2\n"},
                        Case{"vector", 0, ""}}) {
    SCOPED_TRACE(c.kind + " axis " + std::to_string(c.list_axis));
    ScopedTempDir dir;
    const std::string path = dir.File("slicer.seq.nrrd");
    WriteText(path, SmallNrrd(3, c.kind, c.list_axis, c.keys));
    std::vector<Image> phases;
    std::string error;
    ASSERT_TRUE(ReadPhases(path, &phases, &error)) << error;
    ASSERT_EQ(phases.size(), 3u);
    for (int t = 0; t < 3; ++t) {
      EXPECT_EQ(phases[t].geometry.size, Eigen::Vector3i(2, 2, 2));
      EXPECT_EQ(phases[t].geometry.spacing_mm, Eigen::Vector3d(2, 3, 4));
      EXPECT_EQ(phases[t].geometry.origin_mm, Eigen::Vector3d(1, -2, 3));
      for (int v = 0; v < 8; ++v) EXPECT_EQ(phases[t].voxels[v], 10.0f * t + v) << t << "," << v;
    }
  }
}

TEST(PhasesIo, OtherNonSpatialAxesAreRefused) {
  ScopedTempDir dir;
  const std::string rgb = dir.File("rgb.nrrd");
  WriteText(rgb, SmallNrrd(3, "RGB-color", 0, ""));
  EXPECT_THAT(ReadPhasesError(rgb), HasSubstr("rgb pixels"));
  const std::string vector3 = dir.File("vector3.nrrd");
  WriteText(vector3, SmallNrrd(3, "3-vector", 0, ""));
  EXPECT_THAT(ReadPhasesError(vector3), HasSubstr("'3-vector'"));
  const std::string vector_pixels = dir.File("vector.nii.gz");  // NIfTI vector pixels
  test_itk::Grid grid;
  grid.size = {4, 3, 2};
  ASSERT_EQ(test_itk::WriteVectorImage(vector_pixels, grid), "");
  EXPECT_THAT(ReadPhasesError(vector_pixels), HasSubstr("components"));
}

TEST(PhasesIo, BadInputsAreOneLineErrors) {
  ScopedTempDir dir;
  // Five dimensions.
  const std::string five = dir.File("five.nrrd");
  std::string text = "NRRD0004\ntype: float\ndimension: 5\nsizes: 2 2 2 2 2\nencoding: ascii\n\n";
  for (int v = 0; v < 32; ++v) text += std::to_string(v) + "\n";
  WriteText(five, text);
  EXPECT_THAT(ReadPhasesError(five), HasSubstr("5D image of size 2x2x2x2x2"));
  // Empty files.
  for (const std::string name : {"empty.nii.gz", "empty.nrrd", "empty.seq.nrrd"}) {
    WriteText(dir.File(name), "");
    ReadPhasesError(dir.File(name));
    int count = 0;
    std::string error;
    EXPECT_FALSE(NumPhasesInFile(dir.File(name), &count, &error));
    ExpectOneLineNaming(error, dir.File(name));
  }
  // A 4th axis mixed with space.
  const std::string mixed = dir.File("mixed.nrrd");
  text = "NRRD0004\ntype: float\ndimension: 4\nspace dimension: 4\nsizes: 2 2 2 2\n"
         "space directions: (1,0,0,0) (0,1,0,0) (0,0,1,0.5) (0,0,0,1)\nencoding: ascii\n\n";
  for (int v = 0; v < 16; ++v) text += std::to_string(v) + "\n";
  WriteText(mixed, text);
  EXPECT_THAT(ReadPhasesError(mixed), HasSubstr("4th axis"));
  // A time axis beside a 3D space (ITK reads no such file).
  const std::string time = dir.File("time.nrrd");
  WriteText(time, SmallNrrd(3, "time", 3, ""));
  ReadPhasesError(time);
  // Missing file, unsupported extension, 2D image.
  EXPECT_THAT(ReadPhasesError(dir.File("none.nii.gz")), HasSubstr("no such file"));
  EXPECT_THAT(ReadPhasesError(dir.File("x.png")), HasSubstr("unsupported extension"));
  test_itk::Grid flat;
  flat.size = {4, 3};
  ASSERT_EQ(test_itk::WriteScalarImage(dir.File("flat.nrrd"), flat, test_itk::Pixel::kFloat,
                                       std::vector<double>(12, 1.0)), "");
  EXPECT_THAT(ReadPhasesError(dir.File("flat.nrrd")), HasSubstr("2D image"));
}

TEST(PhasesIo, NonFiniteVoxelsNameThePhase) {
  std::vector<Image> phases = ObliquePhases();
  phases[2].at(1, 2, 3) = std::numeric_limits<float>::quiet_NaN();
  for (const std::string ext : {".nii.gz", ".nrrd", ".mha"}) {
    SCOPED_TRACE(ext);
    ScopedTempDir dir;
    const std::string path = dir.File("nan" + ext);
    std::string error;
    ASSERT_TRUE(WritePhases(phases, path, &error)) << error;
    const std::string read_error = ReadPhasesError(path);
    EXPECT_EQ(read_error, path + ": phase 2: voxel (1,2,3) is NaN");
  }
}

TEST(PhasesIo, WriteRefusesPhasesOnDifferentGridsAndWritesNothing) {
  ScopedTempDir dir;
  std::vector<Image> phases = ObliquePhases();
  phases[1].geometry.origin_mm[0] += 0.5;
  const std::string path = dir.File("bad.nii.gz");
  std::string error;
  EXPECT_FALSE(WritePhases(phases, path, &error));
  ExpectOneLineNaming(error, path);
  EXPECT_THAT(error, HasSubstr("phase 1"));
  phases = ObliquePhases();
  phases[2].voxels.pop_back();
  EXPECT_FALSE(WritePhases(phases, path, &error));
  ExpectOneLineNaming(error, path);
  EXPECT_THAT(error, HasSubstr("phase 2"));
  EXPECT_FALSE(WritePhases({}, path, &error));
  ExpectOneLineNaming(error, path);
  phases = ObliquePhases();
  for (Image& phase : phases) phase.geometry.spacing_mm[2] = 0.0;
  EXPECT_FALSE(WritePhases(phases, path, &error));
  ExpectOneLineNaming(error, path);
  EXPECT_THAT(error, HasSubstr("invalid grid"));
  EXPECT_FALSE(WritePhases(ObliquePhases(), dir.File("x.png"), &error));
  EXPECT_FALSE(WritePhases(ObliquePhases(), dir.File("missing/x.nrrd"), &error));
  ExpectOneLineNaming(error, dir.File("missing/x.nrrd"));
  EXPECT_TRUE(dir.Entries().empty());
}

// A mask as phases: 1 in the box x < 4, z >= 1 of every phase (phase 1 stores 2 there, so
// only the inside, not the value, is the same).
std::vector<Image> MaskPhases() {
  std::vector<Image> phases;
  for (int t = 0; t < kPhases; ++t) {
    Image image(ObliqueGeometry(), 0.0f);
    for (int k = 1; k < 5; ++k) {
      for (int j = 0; j < 6; ++j) {
        for (int i = 0; i < 4; ++i) image.at(i, j, k) = t == 1 ? 2.0f : 1.0f;
      }
    }
    phases.push_back(image);
  }
  return phases;
}

TEST(PhasesIo, FourDimensionalMaskWithEqualPhasesIsItsThreeDimensionalMask) {
  ScopedTempDir dir;
  const std::vector<Image> phases = MaskPhases();
  std::string error;
  ASSERT_TRUE(WriteImage(phases[0], dir.File("mask3d.nrrd"), &error)) << error;
  Mask expected;
  ASSERT_TRUE(ReadMask(dir.File("mask3d.nrrd"), ObliqueGeometry(), &expected, &error)) << error;
  for (const std::string ext : {".nii.gz", ".seq.nrrd"}) {
    SCOPED_TRACE(ext);
    const std::string path = dir.File("mask4d" + ext);
    ASSERT_TRUE(WritePhases(phases, path, &error)) << error;
    Mask mask;
    ASSERT_TRUE(ReadMaskPhases(path, ObliqueGeometry(), &mask, &error)) << error;
    ExpectSameGeometry(mask.geometry, expected.geometry);
    EXPECT_EQ(mask.voxels, expected.voxels);
  }
  // A 3D mask file: exactly ReadMask, errors included.
  Mask mask;
  ASSERT_TRUE(ReadMaskPhases(dir.File("mask3d.nrrd"), ObliqueGeometry(), &mask, &error));
  EXPECT_EQ(mask.voxels, expected.voxels);
  ImageGeometry other = ObliqueGeometry();
  other.origin_mm[1] += 1.0;
  std::string mask_error;
  EXPECT_FALSE(ReadMask(dir.File("mask3d.nrrd"), other, &mask, &mask_error));
  EXPECT_FALSE(ReadMaskPhases(dir.File("mask3d.nrrd"), other, &mask, &error));
  EXPECT_EQ(error, mask_error);
}

TEST(PhasesIo, FourDimensionalMaskWithDifferentPhasesIsRefused) {
  ScopedTempDir dir;
  std::vector<Image> phases = MaskPhases();
  phases[2].at(5, 4, 3) = 1.0f;
  const std::string path = dir.File("moving_mask.nii.gz");
  std::string error;
  ASSERT_TRUE(WritePhases(phases, path, &error)) << error;
  Mask mask;
  EXPECT_FALSE(ReadMaskPhases(path, ObliqueGeometry(), &mask, &error));
  ExpectOneLineNaming(error, path);
  EXPECT_THAT(error, HasSubstr("mask phase 2 differs from phase 0 at voxel (5,4,3)"));
  // The grid and inside rules of ReadMask still apply to a 4D mask.
  ImageGeometry other = ObliqueGeometry();
  other.size[0] = 8;
  EXPECT_FALSE(ReadMaskPhases(path, other, &mask, &error));
  EXPECT_THAT(error, HasSubstr("does not match the image grid"));
}


// ---- Reading chosen phases: only those decoded and held (io_phase_stream.h) ----

// Every 4D format dsr writes (phase-major NIfTI and MetaImage, NRRD's list axis with the
// phases side by side), compressed or not, attached or with a data file.
const char* const kPhaseFormats[] = {".nii", ".nii.gz", ".nrrd", ".seq.nrrd", ".nhdr", ".mha",
                                     ".mhd"};

std::vector<Image> ReadChosen(const std::string& path, const std::vector<int>& which) {
  std::vector<Image> phases;
  std::string error;
  EXPECT_TRUE(ReadPhases(path, which, &phases, &error)) << error;
  return phases;
}

std::string ReadChosenError(const std::string& path, const std::vector<int>& which) {
  std::vector<Image> phases;
  std::string error;
  EXPECT_FALSE(ReadPhases(path, which, &phases, &error)) << path;
  ExpectOneLineNaming(error, path);
  return error;
}

// Phases `which` of `path` are exactly those of a full read, which is exactly what ITK's
// own reader reads.
void ExpectChosenAsFullRead(const std::string& path, const std::vector<int>& which) {
  const std::vector<Image> full = ReadChosen(path, {});
  std::vector<std::vector<float>> itk;
  ASSERT_EQ(test_itk::ReadPhasesWithItk(path, &itk), "");
  ASSERT_EQ(full.size(), itk.size());
  for (size_t t = 0; t < full.size(); ++t) EXPECT_EQ(full[t].voxels, itk[t]) << "phase " << t;
  const std::vector<Image> chosen = ReadChosen(path, which);
  ASSERT_EQ(chosen.size(), which.size());
  for (size_t k = 0; k < which.size(); ++k) {
    SCOPED_TRACE("phase " + std::to_string(which[k]));
    ExpectSameGeometry(chosen[k].geometry, full[which[k]].geometry);
    EXPECT_EQ(chosen[k].voxels, full[which[k]].voxels);
  }
}

TEST(PhasesIo, ChosenPhasesAreThoseOfAFullReadBitForBit) {
  const std::vector<Image> written = ObliquePhases(4);
  for (const std::string ext : kPhaseFormats) {
    SCOPED_TRACE(ext);
    ScopedTempDir dir;
    const std::string path = dir.File("phases" + ext);
    std::string error;
    ASSERT_TRUE(WritePhases(written, path, &error)) << error;
    ExpectChosenAsFullRead(path, {2, 0});
    ExpectChosenAsFullRead(path, {3});
    ExpectSamePhases(ReadChosen(path, {1, 3}), {written[1], written[3]});
  }
}

TEST(PhasesIo, ChosenPhasesOfOtherToolsFilesAreThoseOfAFullRead) {
  // ITK's own writer: int16, four domain axes, uncompressed NRRD and MetaImage.
  const ImageGeometry g = ObliqueGeometry();
  test_itk::Grid grid = ToGrid(g);
  grid.size.push_back(4);
  std::vector<double> values(static_cast<size_t>(g.NumVoxels()) * 4);
  for (size_t v = 0; v < values.size(); ++v) values[v] = static_cast<double>((v * 7) % 101) - 50;
  for (const std::string ext : {".nii.gz", ".nii", ".nrrd", ".mha", ".mhd"}) {
    SCOPED_TRACE(ext);
    ScopedTempDir dir;
    const std::string path = dir.File("itk4d" + ext);
    ASSERT_EQ(test_itk::WriteScalarImage(path, grid, test_itk::Pixel::kInt16, values), "");
    ExpectChosenAsFullRead(path, {2, 0});
  }
}

// Writes `value` at `offset` of `bytes` in big- or little-endian order.
template <typename T>
void Put(std::string* bytes, size_t offset, T value, bool big_endian) {
  unsigned char raw[sizeof(T)];
  std::memcpy(raw, &value, sizeof(T));
  if (big_endian) std::reverse(raw, raw + sizeof(T));
  bytes->replace(offset, sizeof(T), reinterpret_cast<const char*>(raw), sizeof(T));
}

// A NIfTI-1 file of 4x3x2 int16 voxels and 3 phases with scl_slope 0.37 and scl_inter
// -12.5, written field by field in either byte order.
std::string ScaledNifti(bool big_endian) {
  std::string bytes(352, '\0');
  Put<int32_t>(&bytes, 0, 348, big_endian);
  const int16_t dims[8] = {4, 4, 3, 2, 3, 1, 1, 1};
  for (int d = 0; d < 8; ++d) Put<int16_t>(&bytes, 40 + 2 * d, dims[d], big_endian);
  Put<int16_t>(&bytes, 70, 4, big_endian);   // datatype int16
  Put<int16_t>(&bytes, 72, 16, big_endian);  // bitpix
  const float pixdim[8] = {1, 0.5f, 0.75f, 2, 1, 1, 1, 1};
  for (int d = 0; d < 8; ++d) Put<float>(&bytes, 76 + 4 * d, pixdim[d], big_endian);
  Put<float>(&bytes, 108, 352.0f, big_endian);  // vox_offset
  Put<float>(&bytes, 112, 0.37f, big_endian);   // scl_slope
  Put<float>(&bytes, 116, -12.5f, big_endian);  // scl_inter
  bytes[123] = 2;                               // xyzt_units: mm
  bytes.replace(344, 4, std::string("n+1\0", 4));
  for (int v = 0; v < 4 * 3 * 2 * 3; ++v) {
    bytes.append(2, '\0');
    Put<int16_t>(&bytes, bytes.size() - 2, static_cast<int16_t>(v * 311 - 9000), big_endian);
  }
  return bytes;
}

void WriteGzip(const std::string& path, const std::string& bytes) {
  gzFile file = gzopen(path.c_str(), "wb");
  ASSERT_NE(file, nullptr);
  ASSERT_EQ(gzwrite(file, bytes.data(), static_cast<unsigned>(bytes.size())),
            static_cast<int>(bytes.size()));
  gzclose(file);
}

TEST(PhasesIo, ChosenPhasesOfScaledNiftiAreRescaledAsItkRescales) {
  for (const bool big_endian : {false, true}) {
    SCOPED_TRACE(big_endian ? "big-endian" : "little-endian");
    ScopedTempDir dir;
    WriteText(dir.File("scaled.nii"), ScaledNifti(big_endian));
    WriteGzip(dir.File("scaled.nii.gz"), ScaledNifti(big_endian));
    for (const std::string name : {"scaled.nii", "scaled.nii.gz"}) {
      SCOPED_TRACE(name);
      ExpectChosenAsFullRead(dir.File(name), {2, 0});
      const std::vector<Image> phase = ReadChosen(dir.File(name), {1});
      ASSERT_EQ(phase.size(), 1u);
      const float raw = static_cast<float>(24 * 311 - 9000);  // phase 1's first voxel
      EXPECT_EQ(phase[0].voxels[0], static_cast<float>(static_cast<double>(raw) * 0.37f - 12.5));
    }
  }
}

// A 2x2x2 NRRD of 3 phases of int16 voxels 10 * phase + voxel, raw and big-endian, the
// list axis at `list_axis` (0 or 3), with `extra` header lines and `before` bytes between
// the header and the data.
std::string BinaryNrrd(int list_axis, const std::string& extra, const std::string& before) {
  std::string text = std::string("NRRD0004\ntype: short\ndimension: 4\n") +
                     (list_axis == 0 ? "sizes: 3 2 2 2\nkinds: list domain domain domain\n"
                                     : "sizes: 2 2 2 3\nkinds: domain domain domain list\n") +
                     "endian: big\nencoding: raw\n" + extra + "\n" + before;
  for (int k = 0; k < 24; ++k) {
    const int voxel = list_axis == 0 ? k / 3 : k % 8;
    const int phase = list_axis == 0 ? k % 3 : k / 8;
    text.append(2, '\0');
    Put<int16_t>(&text, text.size() - 2, static_cast<int16_t>(10 * phase + voxel), true);
  }
  return text;
}

TEST(PhasesIo, ChosenPhasesOfBinaryNrrdOnEitherAxis) {
  for (const int list_axis : {0, 3}) {
    for (const bool at_end : {false, true}) {
      SCOPED_TRACE("list axis " + std::to_string(list_axis) + (at_end ? ", byte skip -1" : ""));
      ScopedTempDir dir;
      const std::string path = dir.File("binary.nrrd");
      WriteText(path, at_end ? BinaryNrrd(list_axis, "byte skip: -1\n", "junk")
                             : BinaryNrrd(list_axis, "", ""));
      const std::vector<Image> phases = ReadChosen(path, {2, 0});
      ASSERT_EQ(phases.size(), 2u);
      for (int v = 0; v < 8; ++v) {
        EXPECT_EQ(phases[0].voxels[v], 20.0f + v) << v;
        EXPECT_EQ(phases[1].voxels[v], 0.0f + v) << v;
      }
    }
  }
}

TEST(PhasesIo, NonFiniteVoxelsCountOnlyInThePhasesRead) {
  std::vector<Image> phases = ObliquePhases(4);
  phases[1].at(1, 2, 3) = std::numeric_limits<float>::quiet_NaN();
  phases[3].at(4, 0, 2) = std::numeric_limits<float>::infinity();
  for (const std::string ext : kPhaseFormats) {
    SCOPED_TRACE(ext);
    ScopedTempDir dir;
    const std::string path = dir.File("nan" + ext);
    std::string error;
    ASSERT_TRUE(WritePhases(phases, path, &error)) << error;
    ExpectSamePhases(ReadChosen(path, {2, 0}), {phases[2], phases[0]});
    // Named by the phase's index in the file, not its place among those read.
    EXPECT_EQ(ReadChosenError(path, {2, 1}), path + ": phase 1: voxel (1,2,3) is NaN");
    EXPECT_EQ(ReadChosenError(path, {3}), path + ": phase 3: voxel (4,0,2) is Inf");
  }
}

TEST(PhasesIo, PhasesAFileLacksOrAskedTwiceAreRefused) {
  ScopedTempDir dir;
  const std::string path = dir.File("four.nii.gz");
  std::string error;
  ASSERT_TRUE(WritePhases(ObliquePhases(4), path, &error)) << error;
  EXPECT_EQ(ReadChosenError(path, {0, 4}), path + ": no phase 4 (the file has 4 phases, 0 to 3)");
  EXPECT_EQ(ReadChosenError(path, {1, 1}), path + ": phase 1 is asked for twice");
  const std::string three_d = dir.File("three_d.nrrd");
  ASSERT_TRUE(WriteImage(ObliquePhases(1)[0], three_d, &error)) << error;
  EXPECT_EQ(ReadChosenError(three_d, {1}), three_d + ": no phase 1 (the file has only phase 0)");
  ExpectSamePhases(ReadChosen(three_d, {0}), ObliquePhases(1));
}

TEST(PhasesIo, TruncatedDataIsRefusedWhicheverPhasesAreRead) {
  for (const std::string ext : kPhaseFormats) {
    SCOPED_TRACE(ext);
    ScopedTempDir dir;
    const std::string path = dir.File("cut" + ext);
    std::string error;
    ASSERT_TRUE(WritePhases(ObliquePhases(4), path, &error)) << error;
    // The file holding the voxels loses its last quarter: phase 0 is still whole.
    const std::string data = ext == ".nhdr" || ext == ".mhd" ? dir.File("cut.raw") : path;
    const std::string bytes = ReadBytes(data);
    WriteText(data, bytes.substr(0, bytes.size() * 3 / 4));
    EXPECT_THAT(ReadChosenError(path, {0}), HasSubstr("cannot read the voxels"));
  }
}

TEST(PhasesIo, ViewOfJoinedFilesReadsOnlyTheChosenFiles) {
  ScopedTempDir dir;
  const std::vector<Image> phases = ObliquePhases(3);
  std::string error;
  ASSERT_TRUE(WriteImage(phases[0], dir.File("p0.nii.gz"), &error)) << error;
  WriteText(dir.File("p1.nii.gz"), "not an image");
  ASSERT_TRUE(WriteImage(phases[2], dir.File("p2.nii.gz"), &error)) << error;
  const std::string spec = dir.File("p0.nii.gz") + ";" + dir.File("p1.nii.gz") + ";" +
                           dir.File("p2.nii.gz");
  int count = 0;
  ASSERT_TRUE(NumPhasesInView(spec, &count, &error)) << error;
  EXPECT_EQ(count, 3);
  std::vector<Image> view;
  ASSERT_TRUE(ReadView(spec, {2, 0}, &view, &error)) << error;
  ExpectSamePhases(view, {phases[2], phases[0]});
  EXPECT_FALSE(ReadView(spec, {0, 1}, &view, &error));
  ExpectOneLineNaming(error, dir.File("p1.nii.gz"));
  EXPECT_FALSE(ReadView(spec, {3}, &view, &error));
  EXPECT_EQ(error, spec + ": no phase 3 (the view has 3 phases, 0 to 2)");
  // The grids are compared with the first file read.
  Image moved = phases[0];
  moved.geometry.origin_mm[0] += 1.0;
  ASSERT_TRUE(WriteImage(moved, dir.File("p0.nii.gz"), &error)) << error;
  EXPECT_FALSE(ReadView(spec, {2, 0}, &view, &error));
  EXPECT_EQ(error, dir.File("p0.nii.gz") + ": phase 0 lies on another grid than phase 2 (" +
                       dir.File("p2.nii.gz") + ")");
}

TEST(PhasesIo, NiftiSizeBelowOneOnAUsedAxisIsRefused) {
  // The standard requires dim[i] >= 1 for i = 1..dim[0]; the readers would take a dim[4] of
  // 0 or -3 as 1 and read one phase of a file that holds three.
  ScopedTempDir dir;
  const std::string path = dir.File("cine.nii");
  std::string error;
  ASSERT_TRUE(WritePhases(ObliquePhases(), path, &error)) << error;
  const std::string bytes = ReadBytes(path);
  for (const int16_t dim4 : {0, -3}) {
    SCOPED_TRACE(dim4);
    std::string edited = bytes;
    std::memcpy(&edited[40 + 2 * 4], &dim4, sizeof(dim4));
    WriteText(path, edited);
    EXPECT_EQ(ReadPhasesError(path), path + ": NIfTI header field dim[4] is " +
                                         std::to_string(dim4) + "; the standard requires dim[1] "
                                         "to dim[4] (dim[0] = 4) to be >= 1");
    int count = 0;
    EXPECT_FALSE(NumPhasesInFile(path, &count, &error));
    ExpectOneLineNaming(error, path);
    std::vector<Image> view;
    EXPECT_FALSE(ReadView(path, &view, &error));
    EXPECT_THAT(error, HasSubstr("dim[4] is"));
  }
  // A 3D file with no slice is no image either; sizes beyond dim[0] are not looked at.
  ASSERT_TRUE(WriteImage(ObliquePhases(1)[0], path, &error)) << error;
  std::string flat = ReadBytes(path);
  const int16_t zero = 0;
  std::memcpy(&flat[40 + 2 * 5], &zero, sizeof(zero));  // dim[5], dim[0] = 3
  WriteText(path, flat);
  std::vector<Image> phases;
  EXPECT_TRUE(ReadPhases(path, &phases, &error)) << error;
  std::memcpy(&flat[40 + 2 * 3], &zero, sizeof(zero));  // dim[3]
  WriteText(path, flat);
  Image image;
  EXPECT_FALSE(ReadImage(path, &image, &error));
  EXPECT_THAT(error, HasSubstr(path + ": NIfTI header field dim[3] is 0"));
}

TEST(PhasesIo, SlicerSequenceKeysThatDisagreeWithTheDataAreRefused) {
  ScopedTempDir dir;
  const std::string path = dir.File("cine.seq.nrrd");
  const auto error_of = [&](int list_axis, const std::string& keys) {
    WriteText(path, SmallNrrd(3, "list", list_axis, keys));
    return ReadPhasesError(path);
  };
  EXPECT_EQ(error_of(0, "axis 0 index values:=0 1\n"),
            path + ": key 'axis 0 index values' has 2 values for 3 phases (one index value per "
                   "phase)");
  EXPECT_EQ(error_of(3, "axis 3 index type:=numeric\naxis 3 index values:=0 1 2 3\n"),
            path + ": key 'axis 3 index values' has 4 values for 3 phases (one index value per "
                   "phase)");
  EXPECT_EQ(error_of(0, "axis 0 index type:=numeric\naxis 0 index values:=a b c\n"),
            path + ": key 'axis 0 index values': value 0 'a' is not a number (the index type is "
                   "numeric)");
  // Without a type the index is numeric (3D Slicer's default).
  EXPECT_THAT(error_of(0, "axis 0 index values:=0 1 nan\n"),
              HasSubstr("value 2 'nan' is not a number"));
  EXPECT_EQ(error_of(0, "axis 3 index values:=0 1 2\n"),
            path + ": key 'axis 3 index values' is about axis 3, but the phases are on axis 0 "
                   "(3D Slicer's sequence keys name the list axis)");
  EXPECT_THAT(error_of(3, "axis 0 index type:=numeric\n"),
              HasSubstr("key 'axis 0 index type' is about axis 0, but the phases are on axis 3"));
  EXPECT_EQ(error_of(0, "axis 0 index type:=date\n"),
            path + ": key 'axis 0 index type' is 'date'; 3D Slicer's index types are numeric and "
                   "text");
  // The same keys in a plain .nrrd.
  const std::string plain = dir.File("cine.nrrd");
  WriteText(plain, SmallNrrd(3, "list", 0, "axis 0 index values:=0 1\n"));
  EXPECT_THAT(ReadPhasesError(plain), HasSubstr("key 'axis 0 index values' has 2 values"));
  // What 3D Slicer writes (the list axis last; times, URL-encoded text) is read.
  for (const std::string keys :
       {"DataNodeClassName:=vtkMRMLScalarVolumeNode\naxis 3 index type:=numeric\n"
        "axis 3 index values:=0 0.0333 1.5e2\naxis 3 item 0 Window:=400\n",
        "axis 3 index type:=text\naxis 3 index values:=diastole mid%20systole systole\n"}) {
    SCOPED_TRACE(keys);
    WriteText(path, SmallNrrd(3, "list", 3, keys));
    std::vector<Image> phases;
    std::string error;
    EXPECT_TRUE(ReadPhases(path, &phases, &error)) << error;
    EXPECT_EQ(phases.size(), 3u);
  }
}

// A view of 3D float .nii.gz files, whose voxels the reader compares with the first while
// it moves them out of the inflated file: a constant phase is refused, and one voxel that
// differs, the last, makes it a phase to register.
TEST(PhasesIo, ConstantPhaseOfCompressedNiftiFilesIsFoundInTheReadersOwnPass) {
  ScopedTempDir dir;
  std::vector<Image> phases = ObliquePhases();
  std::fill(phases[1].voxels.begin(), phases[1].voxels.end(), -3.25f);
  std::string error;
  std::string spec;
  for (int t = 0; t < kPhases; ++t) {
    const std::string file = dir.File("p" + std::to_string(t) + ".nii.gz");
    ASSERT_TRUE(WriteImage(phases[t], file, &error)) << error;
    spec += (t ? ";" : "") + file;
  }
  std::vector<Image> view;
  EXPECT_FALSE(ReadView(spec, &view, &error));
  EXPECT_EQ(error, dir.File("p1.nii.gz") + ": phase 1 has the same value (-3.25) in every "
                                           "voxel: a blank or constant phase has nothing to "
                                           "register");
  phases[1].voxels.back() = 0.5f;
  ASSERT_TRUE(WriteImage(phases[1], dir.File("p1.nii.gz"), &error)) << error;
  ASSERT_TRUE(ReadView(spec, &view, &error)) << error;
  ExpectSamePhases(view, phases);
}

TEST(PhasesIo, ConstantPhaseOfAViewIsRefusedNamingThePhase) {
  ScopedTempDir dir;
  std::vector<Image> phases = ObliquePhases();
  std::fill(phases[1].voxels.begin(), phases[1].voxels.end(), 0.0f);  // a blank phase
  std::string error;
  for (const std::string ext : {".nii.gz", ".seq.nrrd"}) {
    SCOPED_TRACE(ext);
    const std::string path = dir.File("blank" + ext);
    ASSERT_TRUE(WritePhases(phases, path, &error)) << error;
    std::vector<Image> view;
    EXPECT_FALSE(ReadView(path, &view, &error));
    EXPECT_EQ(error, path + ": phase 1 has the same value (0) in every voxel: a blank or "
                            "constant phase has nothing to register");
    // Only the phases read are looked at; ReadPhases, a reader of any 4D image, takes it.
    ASSERT_TRUE(ReadView(path, {2, 0}, &view, &error)) << error;
    EXPECT_EQ(view.size(), 2u);
    ASSERT_TRUE(ReadPhases(path, &view, &error)) << error;
    ExpectSamePhases(view, phases);
  }
  // A view of 3D files: the file and its phase are named.
  std::fill(phases[2].voxels.begin(), phases[2].voxels.end(), 7.5f);
  std::string spec;
  for (int t = 0; t < kPhases; ++t) {
    const std::string file = dir.File("p" + std::to_string(t) + ".nrrd");
    ASSERT_TRUE(WriteImage(phases[t], file, &error)) << error;
    spec += (t ? ";" : "") + file;
  }
  std::vector<Image> view;
  EXPECT_FALSE(ReadView(spec, {0, 2}, &view, &error));
  EXPECT_EQ(error, dir.File("p2.nrrd") + ": phase 2 has the same value (7.5) in every voxel: a "
                                         "blank or constant phase has nothing to register");
  // A 3D view is read as ReadImage reads it (the registration judges its field of view), and
  // a 4D mask may be all inside.
  ASSERT_TRUE(ReadView(dir.File("p2.nrrd"), &view, &error)) << error;
  Image full(ObliqueGeometry(), 1.0f);
  ASSERT_TRUE(WritePhases({full, full, full}, dir.File("mask.nii.gz"), &error)) << error;
  Mask mask;
  ASSERT_TRUE(ReadMaskPhases(dir.File("mask.nii.gz"), ObliqueGeometry(), &mask, &error)) << error;
}

TEST(PhasesIo, HeaderOfManyMorePhasesThanTheDataIsRefused) {
  // 100000 phases declared, the voxels of one present: refused before anything is allocated.
  ScopedTempDir dir;
  std::string text =
      "NRRD0004\ntype: float\ndimension: 4\nspace: left-posterior-superior\n"
      "sizes: 100000 32 32 32\nspace directions: none (1,0,0) (0,1,0) (0,0,1)\n"
      "kinds: list domain domain domain\nendian: little\nencoding: raw\n"
      "space origin: (0,0,0)\n\n";
  text += std::string(4 * 32 * 32 * 32, '\0');
  for (const std::string name : {"many.seq.nrrd", "many.nrrd"}) {
    const std::string path = dir.File(name);
    WriteText(path, text);
    EXPECT_THAT(ReadPhasesError(path), HasSubstr("cannot read the voxels"));
    std::vector<Image> view;
    std::string error;
    EXPECT_FALSE(ReadView(path, {0}, &view, &error));
    ExpectOneLineNaming(error, path);
  }
  // A detached header is held to its data file's size (teem would check it only after the
  // 13 GB are allocated).
  const std::string detached = dir.File("many.seq.nhdr");
  const size_t blank_line = text.find("\n\n");
  WriteText(detached, text.substr(0, blank_line + 1) + "data file: many.raw\n\n");
  WriteText(dir.File("many.raw"), std::string(4 * 32 * 32 * 32, '\0'));
  EXPECT_THAT(ReadPhasesError(detached),
              HasSubstr("cannot read the voxels (the header promises 13107200000 bytes of voxels, "
                        "more than its data file (131072 bytes) can hold)"));
}

// The process's resident memory and its peak (VmRSS, VmHWM of /proc/self/status), bytes.
struct Resident {
  double now = 0.0;
  double peak = 0.0;
};

Resident ReadResident() {
  std::ifstream in("/proc/self/status");
  Resident r;
  for (std::string line; std::getline(in, line);) {
    std::istringstream fields(line);
    std::string key;
    double kib = 0.0;
    fields >> key >> kib;
    if (key == "VmRSS:") r.now = kib * 1024.0;
    if (key == "VmHWM:") r.peak = kib * 1024.0;
  }
  return r;
}

// How much the peak resident memory grows while `read` runs: freed heap memory is first
// given back (so that reusing it counts) and the peak brought down to the current size
// (writing 5 to /proc/self/clear_refs); -1 where it cannot be.
template <typename Read>
double PeakGrowth(const Read& read) {
  malloc_trim(0);
  {
    std::ofstream clear("/proc/self/clear_refs");
    if (!(clear << "5" << std::flush)) return -1.0;
  }
  const Resident before = ReadResident();
  if (before.now <= 0.0 || before.peak > before.now * 1.01 + (1 << 20)) return -1.0;
  read();
  return ReadResident().peak - before.now;
}

TEST(PhasesIo, ReadingOnePhaseHoldsOnlyThatPhase) {
  // 8 phases of 112 x 112 x 80 float voxels (4 MiB a phase, 32 MiB in all).
  ImageGeometry g;
  g.size = Eigen::Vector3i(112, 112, 80);
  const double phase_bytes = 4.0 * g.NumVoxels();
  for (const std::string ext : {".nii.gz", ".seq.nrrd", ".nii"}) {
    SCOPED_TRACE(ext);
    ScopedTempDir dir;
    const std::string path = dir.File("large" + ext);
    {
      std::vector<Image> phases;
      for (int t = 0; t < 8; ++t) {
        Image image(g);
        for (size_t v = 0; v < image.voxels.size(); ++v) {
          image.voxels[v] = static_cast<float>((v * 13 + 7 * t) % 97);
        }
        phases.push_back(std::move(image));
      }
      std::string error;
      ASSERT_TRUE(WritePhases(phases, path, &error)) << error;
    }
    std::vector<Image> read;
    const double one = PeakGrowth([&] { read = ReadChosen(path, {5}); });
    if (one < 0.0) GTEST_SKIP() << "the peak resident memory cannot be reset here";
    ASSERT_EQ(read.size(), 1u);
    read.clear();
    read.shrink_to_fit();
    const double all = PeakGrowth([&] { read = ReadChosen(path, {}); });
    ASSERT_EQ(read.size(), 8u);
    std::cout << ext << ": peak resident memory grows by " << one / (1 << 20)
              << " MiB reading 1 phase, " << all / (1 << 20) << " MiB reading all 8 (a phase: "
              << phase_bytes / (1 << 20) << " MiB)\n";
    // One phase and a few MiB of buffers, against all eight phases.
    EXPECT_LT(one, phase_bytes + 8.0 * (1 << 20));
    EXPECT_GT(all, 7.0 * phase_bytes);
    EXPECT_LT(one, 0.4 * all);
  }
}

}  // namespace
}  // namespace dsr
