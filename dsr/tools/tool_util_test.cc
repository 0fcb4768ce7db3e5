// Helpers shared by the tools (tools/tool_util.h).
#include "dsr/tools/tool_util.h"

#include <gtest/gtest.h>

#include "dsr/io/io_poses.h"

namespace dsr {
namespace {

// Before InitTool, every option of the table counts as a flag of the tool.
TEST(FieldPathsAsFlags, NamesTheFlagOfEachField) {
  // The path joined with '_', its last part, its first part.
  EXPECT_EQ(FieldPathsAsFlags("search.rotations=0: must be in [1, 100000]"),
            "--search_rotations=0: must be in [1, 100000]");
  EXPECT_EQ(FieldPathsAsFlags("solve.max_iterations=0: must be >= 1"),
            "--max_iterations=0: must be >= 1");
  EXPECT_EQ(FieldPathsAsFlags("loss.scale=0: must be finite and > 0 for loss.kind=huber"),
            "--loss_scale=0: must be finite and > 0 for --loss=huber");
  EXPECT_EQ(FieldPathsAsFlags("a frame is off (solve.progress)"), "a frame is off (--progress)");
  // Fields no option sets keep their names; flags and prose stay.
  EXPECT_EQ(FieldPathsAsFlags("search.num_screened=-1: must be >= 0"),
            "search.num_screened=-1: must be >= 0");
  EXPECT_EQ(FieldPathsAsFlags("--loss=tukey: must be squared"), "--loss=tukey: must be squared");
  EXPECT_EQ(FieldPathsAsFlags("the loss is squared"), "the loss is squared");
}

Eigen::Isometry3d Shift(double x) {
  Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
  t.translation().x() = x;
  return t;
}

TEST(MatchPosesToImages, ReordersPosesAndRegaugesGainsAndOffsets) {
  PosesFile poses;
  poses.images = {"a.nii.gz", "b.nii.gz", "c.nii.gz"};
  poses.frame_from_world = {Shift(0), Shift(1), Shift(2)};
  // On a's scale: corrected = gain * I + offset.
  poses.gain = {1.0, 2.0, 0.5};
  poses.offset = {0.0, 10.0, -4.0};
  std::string error;
  ASSERT_TRUE(MatchPosesToImages("init", "p.json", {"/x/b.nii.gz", "/x/c.nii.gz", "/x/a.nii.gz"},
                                 &poses, &error))
      << error;
  ASSERT_EQ(poses.images, std::vector<std::string>({"b.nii.gz", "c.nii.gz", "a.nii.gz"}));
  EXPECT_EQ(poses.frame_from_world[0].translation().x(), 1.0);
  EXPECT_EQ(poses.frame_from_world[2].translation().x(), 0.0);
  ASSERT_EQ(poses.gain.size(), 3u);
  ASSERT_EQ(poses.offset.size(), 3u);
  // Now on b's scale: I_b = (2 I_b + 10 - 10) / 2; c: (0.5 I_c - 4 - 10) / 2; a: (I_a - 10) / 2.
  EXPECT_DOUBLE_EQ(poses.gain[0], 1.0);
  EXPECT_DOUBLE_EQ(poses.offset[0], 0.0);
  EXPECT_DOUBLE_EQ(poses.gain[1], 0.25);
  EXPECT_DOUBLE_EQ(poses.offset[1], -7.0);
  EXPECT_DOUBLE_EQ(poses.gain[2], 0.5);
  EXPECT_DOUBLE_EQ(poses.offset[2], -5.0);
  // The same intensity on the old scale is the same on the new one, up to b's map.
  const double i_c = 37.0;
  EXPECT_DOUBLE_EQ(poses.gain[1] * i_c + poses.offset[1], ((0.5 * i_c - 4.0) - 10.0) / 2.0);
}

// A file with gains and no offsets (each field may come alone): the offsets that the new
// gauge needs appear only where they are not 0.
TEST(MatchPosesToImages, GainsWithoutOffsets) {
  PosesFile poses;
  poses.images = {"a", "b"};
  poses.frame_from_world = {Shift(0), Shift(1)};
  poses.gain = {1.0, 4.0};
  std::string error;
  ASSERT_TRUE(MatchPosesToImages("init", "p.json", {"b.nii", "a.nii"}, &poses, &error)) << error;
  EXPECT_EQ(poses.gain, std::vector<double>({1.0, 0.25}));
  EXPECT_TRUE(poses.offset.empty());
}

TEST(MatchPosesToImages, FilesWithoutGainsStayWithout) {
  PosesFile poses;
  poses.images = {"a", "b"};
  poses.frame_from_world = {Shift(0), Shift(1)};
  std::string error;
  ASSERT_TRUE(MatchPosesToImages("init", "p.json", {"b.nii", "a.nii"}, &poses, &error)) << error;
  EXPECT_TRUE(poses.gain.empty());
  EXPECT_TRUE(poses.offset.empty());
  EXPECT_EQ(poses.frame_from_world[0].translation().x(), 1.0);
}

// A view given as its phases' files joined by ';' is named in a poses file by its first file
// (what dsr_register writes for it), with or without the folder and the extension; its
// other files name nothing.
TEST(MatchPosesToImages, ViewsOfJoinedPhaseFilesGoByTheirFirstFile) {
  PosesFile poses;
  poses.images = {"v0_p0.nii.gz", "v1_p0"};
  poses.frame_from_world = {Shift(0), Shift(1)};
  std::string error;
  const std::vector<std::string> views = {"/x/v1_p0.nii.gz;/x/v1_p1.nii.gz",
                                          "/x/v0_p0.nii.gz; /x/v0_p1.nii.gz"};
  ASSERT_TRUE(MatchPosesToImages("init", "p.json", views, &poses, &error))
      << error;
  EXPECT_EQ(poses.images, std::vector<std::string>({"v1_p0", "v0_p0.nii.gz"}));
  EXPECT_EQ(poses.frame_from_world[0].translation().x(), 1.0);
  PosesFile later;
  later.images = {"v0_p1.nii.gz", "v1_p1.nii.gz"};
  later.frame_from_world = {Shift(0), Shift(1)};
  EXPECT_FALSE(MatchPosesToImages("init", "p.json", views, &later, &error));
  EXPECT_NE(error.find("no entry names the image /x/v1_p0.nii.gz;/x/v1_p1.nii.gz"),
            std::string::npos)
      << error;
}

}  // namespace
}  // namespace dsr
