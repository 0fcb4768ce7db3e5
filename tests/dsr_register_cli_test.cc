// dsr_register's command line (tools/dsr_register.cc) on a tiny simulated sequence written
// by dsr_simulate: the happy path (poses, panorama, per-frame errors) and bad inputs (one
// error line naming the file or flag, exit code 2, no output written).
#include <unistd.h>

#include <filesystem>
#include <string>

#include <gtest/gtest.h>

#include "cli_run.h"
#include "core/io_image.h"
#include "core/io_poses.h"

namespace dsr {
namespace {

namespace fs = std::filesystem;
using testing_cli::RunTool;
using testing_cli::ToolRun;

class DsrRegisterCli : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new fs::path(fs::temp_directory_path() /
                        ("dsr_register_cli_test_" + std::to_string(getpid())));
    fs::remove_all(*dir_);
    fs::create_directories(*dir_);
    const ToolRun sim = RunTool(DSR_SIMULATE_BIN,
                                "--out_dir=" + (*dir_ / "seq").string() +
                                    " --phantom_size=64 --frame_size=32,32,28 --num_frames=3 "
                                    "--max_rotation_deg=6 --max_translation_voxels=3 "
                                    "--min_depth_voxels=2 --sigma=10",
                                *dir_);
    ASSERT_EQ(sim.exit_code, 0) << sim.err;
  }
  static void TearDownTestSuite() {
    fs::remove_all(*dir_);
    delete dir_;
  }
  static std::string Seq(const std::string& name) { return (*dir_ / "seq" / name).string(); }
  static std::string Images() {
    return Seq("frame_00.nii.gz") + "," + Seq("frame_01.nii.gz") + "," + Seq("frame_02.nii.gz");
  }
  static std::string Masks() {
    return Seq("mask_00.nii.gz") + "," + Seq("mask_01.nii.gz") + "," + Seq("mask_02.nii.gz");
  }
  static std::string Out(const std::string& name) { return (*dir_ / name).string(); }
  ToolRun Register(const std::string& args) {
    return RunTool(DSR_REGISTER_BIN, "--pyramid_levels=2 --pyramid_min_size=8 " + args, *dir_);
  }
  // A bad input: exit 2, exactly one error line containing `needle`, no poses written.
  void ExpectBadInput(const std::string& args, const std::string& needle) {
    const std::string out = Out("bad_poses.json");
    fs::remove(out);
    const ToolRun run = Register(args + " --out_poses=" + out);
    EXPECT_EQ(run.exit_code, 2) << args << "\n" << run.err;
    ASSERT_EQ(run.error_lines.size(), 1u) << args << "\n" << run.err;
    EXPECT_NE(run.error_lines[0].find(needle), std::string::npos) << run.error_lines[0];
    EXPECT_FALSE(fs::exists(out)) << args;
  }

  static fs::path* dir_;
};

fs::path* DsrRegisterCli::dir_ = nullptr;

TEST_F(DsrRegisterCli, RegistersWritesPosesPanoramaAndPrintsErrors) {
  const std::string poses_path = Out("poses.json"), panorama_path = Out("panorama.nii.gz");
  const ToolRun run = Register("--images=" + Images() + " --masks=" + Masks() +
                               " --out_poses=" + poses_path + " --out_panorama=" +
                               panorama_path + " --gt_poses=" + Seq("gt_poses.json"));
  ASSERT_EQ(run.exit_code, 0) << run.err;
  EXPECT_NE(run.out.find("MAE: translation"), std::string::npos) << run.out;
  EXPECT_NE(run.err.find("dsr iter"), std::string::npos) << "progress lines on stderr";
  EXPECT_NE(run.out.find("peak memory"), std::string::npos) << run.out;
  PosesFile poses;
  std::string error;
  ASSERT_TRUE(ReadPoses(poses_path, 3, &poses, &error)) << error;
  EXPECT_TRUE(poses.frame_from_world[0].isApprox(Eigen::Isometry3d::Identity(), 1e-15));
  EXPECT_EQ(poses.images[1], "frame_01.nii.gz");
  Image panorama;
  ASSERT_TRUE(ReadImage(panorama_path, &panorama, &error)) << error;
  // Larger than one frame's field of view (the bounding box of its mask, in voxels of the
  // same spacing): the panorama spans the frames' valid cells, which lie inside the masks.
  Image frame;
  ASSERT_TRUE(ReadImage(Seq("frame_00.nii.gz"), &frame, &error)) << error;
  Mask mask;
  ASSERT_TRUE(ReadMask(Seq("mask_00.nii.gz"), frame.geometry, &mask, &error)) << error;
  Eigen::AlignedBox3i box;
  for (int k = 0; k < mask.geometry.size[2]; ++k)
    for (int j = 0; j < mask.geometry.size[1]; ++j)
      for (int i = 0; i < mask.geometry.size[0]; ++i)
        if (mask.at(i, j, k) != 0) box.extend(Eigen::Vector3i(i, j, k));
  ASSERT_FALSE(box.isEmpty());
  const Eigen::Vector3i extent = box.sizes() + Eigen::Vector3i::Ones();
  EXPECT_GT(panorama.geometry.NumVoxels(), int64_t{extent[0]} * extent[1] * extent[2]);
}

TEST_F(DsrRegisterCli, DbaModeAndMasksFromImages) {
  const ToolRun run = Register("--images=" + Images() + " --mode=dba --mask_erosion=2" +
                               " --out_poses=" + Out("dba.json") + " --progress=false");
  ASSERT_EQ(run.exit_code, 0) << run.err;
  EXPECT_EQ(run.err.find("iter"), std::string::npos) << "--progress=false";
  EXPECT_TRUE(fs::exists(Out("dba.json")));
}

TEST_F(DsrRegisterCli, AFailedRegistrationExitsOneAndLeavesThePosesFileAlone) {
  // A guard so strict that the frames' ordinary motion from identity counts as sliding out
  // of the overlap: the run solves, then fails with the reason, and the poses file a
  // previous run wrote stays as it was. No recovery: whether a recovered run would then
  // pass the strict guard depends on a percent of overlap either way.
  const std::string poses_path = Out("previous_poses.json");
  PosesFile previous;
  previous.images = {"a", "b", "c"};
  previous.frame_from_world.assign(3, Eigen::Isometry3d::Identity());
  std::string error;
  ASSERT_TRUE(WritePoses(previous, poses_path, &error)) << error;
  const std::string before = testing_cli::ReadText(poses_path);
  const ToolRun run = Register("--images=" + Images() + " --masks=" + Masks() +
                               " --min_kept_overlap=0.99 --max_recoveries=0 --progress=false"
                               " --out_poses=" +
                               poses_path);
  EXPECT_EQ(run.exit_code, 1) << run.err;
  ASSERT_EQ(run.error_lines.size(), 1u) << run.err;
  EXPECT_NE(run.error_lines[0].find("diverged: frame"), std::string::npos) << run.error_lines[0];
  EXPECT_NE(run.error_lines[0].find("--min_kept_overlap=0.99"), std::string::npos);
  EXPECT_EQ(testing_cli::ReadText(poses_path), before);
  // The same through the misfit check: a ratio just above 1 singles out the frame that
  // matches the others least.
  const ToolRun misfit = Register("--images=" + Images() + " --masks=" + Masks() +
                                  " --max_misfit_ratio=1.0001 --max_recoveries=0 --progress=false"
                                  " --out_poses=" +
                                  poses_path);
  EXPECT_EQ(misfit.exit_code, 1) << misfit.err;
  ASSERT_EQ(misfit.error_lines.size(), 1u) << misfit.err;
  EXPECT_NE(misfit.error_lines[0].find("does not match the others"), std::string::npos)
      << misfit.error_lines[0];
  EXPECT_EQ(testing_cli::ReadText(poses_path), before);
}

TEST_F(DsrRegisterCli, BadInputsGiveOneErrorLineAndExitCode2) {
  const std::string images = " --images=" + Images();
  ExpectBadInput("--images=" + Seq("frame_00.nii.gz") + "," + Seq("missing.nii.gz"),
                 "missing.nii.gz");
  ExpectBadInput("--images=" + Seq("frame_00.nii.gz"), "at least 2");
  ExpectBadInput("--images=" + Seq("frame_00.nii.gz") + "," + Seq("frame_00.nii.gz"),
                 "given twice");
  ExpectBadInput(images + " --masks=" + Seq("mask_00.nii.gz"), "--masks");
  ExpectBadInput(images + " --mode=bundle", "--mode=bundle");
  ExpectBadInput(images + " --panorama_spacing=-1", "--panorama_spacing");
  ExpectBadInput(images + " --max_iterations=0", "--max_iterations");
  ExpectBadInput(images + " --linear_solver=CHOLMOD", "--linear_solver");
  ExpectBadInput(images + " --trust_region=NEWTON", "--trust_region");
  ExpectBadInput(images + " --mode=dsr --linear_solver=DENSE_SCHUR", "--linear_solver");
  ExpectBadInput(images + " --init=" + Seq("missing.json"), "missing.json");
  ExpectBadInput(images + " --init=" + Seq("frame_00.nii.gz"), "--init");
  ExpectBadInput(images + " --mode=dba --memory_budget_mb=0.001", "--mode=dsr");
  ExpectBadInput(images + " --out_panorama=" + Seq("frame_01.nii.gz"), "inputs");
  ExpectBadInput(images + " --out_panorama=" + Out("panorama.png"), "--out_panorama");
  ExpectBadInput(images + " --pyramid_levels=0", "--pyramid_levels");
  ExpectBadInput(images + " --min_kept_overlap=1.5", "--min_kept_overlap");
  ExpectBadInput(images + " --max_misfit_ratio=0.5", "--max_misfit_ratio");
  ExpectBadInput(images + " --unknown_flag=3", "unknown_flag");
  // Output equal to an input.
  const ToolRun same = Register(images + " --out_poses=" + Seq("frame_02.nii.gz"));
  EXPECT_EQ(same.exit_code, 2) << same.err;
  EXPECT_TRUE(fs::exists(Seq("frame_02.nii.gz")));
  // No overlap at the initial poses: frame 2 far away; the message names the frame.
  // (Without image names the entries are taken in --images order; names of other images
  // are refused, naming --init.)
  PosesFile apart;
  apart.frame_from_world.assign(3, Eigen::Isometry3d::Identity());
  apart.frame_from_world[2].translation() = Eigen::Vector3d(400.0, 0.0, 0.0);
  std::string error;
  ASSERT_TRUE(WritePoses(apart, Out("apart.json"), &error)) << error;
  ExpectBadInput(images + " --init=" + Out("apart.json"), "frame 2 does not overlap");
  apart.images = {"a", "b", "c"};
  ASSERT_TRUE(WritePoses(apart, Out("strangers.json"), &error)) << error;
  ExpectBadInput(images + " --init=" + Out("strangers.json"), "no entry names the image");
  // Wrong frame count in --init.
  apart.images.pop_back();
  apart.frame_from_world.pop_back();
  ASSERT_TRUE(WritePoses(apart, Out("two.json"), &error)) << error;
  ExpectBadInput(images + " --init=" + Out("two.json"), "--init");
}

}  // namespace
}  // namespace dsr
