// Image and poses IO: exact geometry round trips, one-line errors naming the file.
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <unistd.h>

#include <gtest/gtest.h>

#include "core/atomic_file.h"
#include "core/io_image.h"
#include "core/io_poses.h"
#include "core/se3.h"

namespace dsr {
namespace {

std::string TempDir() {
  static const std::string dir = [] {
    const std::string d = ::testing::TempDir() + "/dsr_io_test_" + std::to_string(getpid());
    std::filesystem::create_directories(d);
    return d;
  }();
  return dir;
}

Image ObliqueImage() {
  ImageGeometry g;
  g.size = Eigen::Vector3i(7, 6, 5);
  g.spacing_mm = Eigen::Vector3d(0.7, 1.1, 2.3);
  g.origin_mm = Eigen::Vector3d(-12.5, 3.25, 40.0);
  g.direction = Eigen::AngleAxisd(0.5, Eigen::Vector3d(1, -2, 0.5).normalized()).toRotationMatrix();
  Image image(g);
  for (size_t v = 0; v < image.voxels.size(); ++v) image.voxels[v] = 0.25f * static_cast<float>(v) - 3.0f;
  return image;
}

void ExpectOneLineNaming(const std::string& error, const std::string& path) {
  EXPECT_EQ(error.find('\n'), std::string::npos) << error;
  EXPECT_NE(error.find(path), std::string::npos) << error;
}

TEST(ImageIo, RoundTripKeepsGeometryAndVoxels) {
  const Image image = ObliqueImage();
  for (const char* ext : {".nii", ".nii.gz", ".mha", ".nrrd"}) {
    const std::string path = TempDir() + "/round" + ext;
    std::string error;
    ASSERT_TRUE(WriteImage(image, path, &error)) << error;
    Image back;
    ASSERT_TRUE(ReadImage(path, &back, &error)) << error;
    EXPECT_EQ(back.geometry.size, image.geometry.size) << ext;
    // NIfTI stores the affine in float (sform/qform): 1e-5 mm; the others store text/double.
    EXPECT_LT((back.geometry.origin_mm - image.geometry.origin_mm).norm(), 1e-4) << ext;
    EXPECT_LT((back.geometry.spacing_mm - image.geometry.spacing_mm).norm(), 1e-5) << ext;
    EXPECT_LT((back.geometry.direction - image.geometry.direction).norm(), 1e-5) << ext;
    EXPECT_EQ(back.voxels, image.voxels) << ext;
  }
}

TEST(ImageIo, MaskRoundTripAndGridCheck) {
  const Image image = ObliqueImage();
  Mask mask(image.geometry, 0);
  mask.at(2, 2, 2) = 1;
  const std::string path = TempDir() + "/mask.nii.gz";
  std::string error;
  ASSERT_TRUE(WriteMask(mask, path, &error)) << error;
  Mask back;
  ASSERT_TRUE(ReadMask(path, image.geometry, &back, &error)) << error;
  EXPECT_EQ(back.voxels, mask.voxels);
  ImageGeometry other = image.geometry;
  other.size[0] = 9;
  EXPECT_FALSE(ReadMask(path, other, &back, &error));
  ExpectOneLineNaming(error, path);
  EXPECT_NE(error.find("does not match"), std::string::npos);
  const std::string empty_path = TempDir() + "/empty_mask.nii.gz";
  ASSERT_TRUE(WriteMask(Mask(image.geometry, 0), empty_path, &error)) << error;
  EXPECT_FALSE(ReadMask(empty_path, image.geometry, &back, &error));
  EXPECT_NE(error.find("no voxel"), std::string::npos) << error;
}

TEST(ImageIo, BadInputsGiveOneLineErrors) {
  Image image;
  std::string error;
  const std::string missing = TempDir() + "/missing.nii.gz";
  EXPECT_FALSE(ReadImage(missing, &image, &error));
  ExpectOneLineNaming(error, missing);
  EXPECT_NE(error.find("no such file"), std::string::npos);

  const std::string corrupt = TempDir() + "/corrupt.nii";
  std::ofstream(corrupt) << "this is not a nifti header at all, just text";
  EXPECT_FALSE(ReadImage(corrupt, &image, &error));
  ExpectOneLineNaming(error, corrupt);

  Image nan_image = ObliqueImage();
  nan_image.voxels[3] = NAN;
  const std::string nan_path = TempDir() + "/nan.mha";
  ASSERT_TRUE(WriteImage(nan_image, nan_path, &error)) << error;
  EXPECT_FALSE(ReadImage(nan_path, &image, &error));
  ExpectOneLineNaming(error, nan_path);
  EXPECT_NE(error.find("NaN"), std::string::npos);

  EXPECT_FALSE(ReadImage(TempDir() + "/x.png", &image, &error));
  EXPECT_NE(error.find("unsupported extension"), std::string::npos);
  EXPECT_FALSE(WriteImage(ObliqueImage(), "/nonexistent_folder_dsr/x.nii", &error));
  EXPECT_NE(error.find("does not exist"), std::string::npos) << error;
}

TEST(PosesIo, RoundTripIsExact) {
  PosesFile poses;
  Vector6d d;
  d << 1.5, -2.25, 3.0, 0.1, -0.2, 0.3;
  poses.images = {"a.nii.gz", "b.nii.gz"};
  poses.frame_from_world = {Eigen::Isometry3d::Identity(), ExpSE3(d)};
  const std::string path = TempDir() + "/poses.json";
  std::string error;
  ASSERT_TRUE(WritePoses(poses, path, &error)) << error;
  PosesFile back;
  ASSERT_TRUE(ReadPoses(path, 2, &back, &error)) << error;
  EXPECT_EQ(back.images, poses.images);
  EXPECT_LT((back.frame_from_world[1].matrix() - poses.frame_from_world[1].matrix()).norm(), 1e-15);
  EXPECT_FALSE(ReadPoses(path, 3, &back, &error));
  EXPECT_NE(error.find("expected 3"), std::string::npos) << error;
}

TEST(PosesIo, MalformedFilesAreRejected) {
  const std::pair<const char*, const char*> cases[] = {
      {"{not json", "not valid JSON"},
      {"{\"poses\": []}", "\"frames\""},
      {"{\"frames\": [{\"T\": [[1,0,0],[0,1,0],[0,0,1]]}]}", "4x4"},
      {"{\"frames\": [{\"T\": [[2,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}]}", "not rigid"},
      {"{\"frames\": [{\"T\": [[1,0,0,\"x\"],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}]}", "numbers"},
  };
  int n = 0;
  for (const auto& [text, expected] : cases) {
    const std::string path = TempDir() + "/bad" + std::to_string(n++) + ".json";
    std::ofstream(path) << text;
    PosesFile poses;
    std::string error;
    EXPECT_FALSE(ReadPoses(path, -1, &poses, &error)) << text;
    ExpectOneLineNaming(error, path);
    EXPECT_NE(error.find(expected), std::string::npos) << error;
  }
}

TEST(AtomicFile, LeavesNoTemporaryFilesAndKeepsOldFileOnFailure) {
  const std::string dir = TempDir() + "/atomic";
  std::filesystem::create_directories(dir);
  std::string error;
  ASSERT_TRUE(WriteFileAtomically(dir + "/out.txt", "first", &error)) << error;
  ASSERT_TRUE(WriteFileAtomically(dir + "/out.txt", "second", &error)) << error;
  int files = 0;
  for (const auto& entry : std::filesystem::directory_iterator(dir)) (void)entry, ++files;
  EXPECT_EQ(files, 1);
  const bool ok = WriteViaTemporaryFile(
      dir + "/out.txt",
      [](const std::string& temp, std::string* why) {
        std::ofstream(temp) << "partial";
        *why = "simulated failure";
        return false;
      },
      &error);
  EXPECT_FALSE(ok);
  std::ifstream in(dir + "/out.txt");
  std::string contents;
  in >> contents;
  EXPECT_EQ(contents, "second");
  files = 0;
  for (const auto& entry : std::filesystem::directory_iterator(dir)) (void)entry, ++files;
  EXPECT_EQ(files, 1);
}

}  // namespace
}  // namespace dsr
