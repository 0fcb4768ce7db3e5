// Views recorded over the heart cycle through the tools (docs/design.md section 12): a
// beating sequence written by dsr_simulate (one 4D NIfTI per view), registered by
// dsr_register with every phase (one pose per view, the 4D panorama as NIfTI and as 3D
// Slicer's sequence, the report of a chosen phase), the same views as one 3D file per phase
// joined by ';', --phases' selection, dsr_fuse's 4D panorama, and bad phase sets refused
// with one line naming the file or flag.
#include <algorithm>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "dsr/io/io_image.h"
#include "dsr/io/io_phases.h"
#include "dsr/io/io_poses.h"
#include "dsr/tests/support/cli_run.h"
#include "dsr/tests/support/scoped_temp_dir.h"

namespace dsr {
namespace {

namespace fs = std::filesystem;
using testing_cli::ReadText;
using testing_cli::RunTool;
using testing_cli::ToolRun;

class PhasesCli : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    temp_ = new ScopedTempDir("dsr_phases_cli_test");
    const ToolRun sim = RunTool(DSR_SIMULATE_BIN,
                                "--out_dir=" + Seq("") +
                                    " --phantom_size=64 --frame_size=32,32,28 --num_frames=3 "
                                    "--max_rotation_deg=6 --max_translation_voxels=3 "
                                    "--min_depth_voxels=2 --sigma=10 --num_phases=3 "
                                    "--beat_amplitude_mm=1.5 --beat_radius_mm=7",
                                Dir());
    ASSERT_EQ(sim.exit_code, 0) << sim.err;
    // Each view's phases also as 3D files.
    for (int f = 0; f < 3; ++f) {
      std::vector<Image> phases;
      std::string error;
      ASSERT_TRUE(ReadPhases(Frame(f), &phases, &error)) << error;
      ASSERT_EQ(phases.size(), 3u);
      for (int p = 0; p < 3; ++p) {
        ASSERT_TRUE(WriteImage(phases[p], Phase3D(f, p), &error)) << error;
      }
    }
  }
  static void TearDownTestSuite() {
    delete temp_;
    temp_ = nullptr;
  }
  static fs::path Dir() { return temp_->dir(); }
  static std::string Seq(const std::string& name) { return (Dir() / "seq" / name).string(); }
  static std::string Frame(int f) { return Seq("frame_0" + std::to_string(f) + ".nii.gz"); }
  static std::string Phase3D(int f, int p) {
    return Seq("view_" + std::to_string(f) + "_phase_" + std::to_string(p) + ".nii.gz");
  }
  static std::string Images() { return Frame(0) + "," + Frame(1) + "," + Frame(2); }
  static std::string Masks() {
    return Seq("mask_00.nii.gz") + "," + Seq("mask_01.nii.gz") + "," + Seq("mask_02.nii.gz");
  }
  static std::string Out(const std::string& name) { return (Dir() / name).string(); }
  ToolRun Register(const std::string& args) {
    return RunTool(DSR_REGISTER_BIN,
                   "--pyramid_levels=2 --pyramid_min_size=8 --progress=false --masks=" + Masks() +
                       " " + args,
                   Dir());
  }
  static ScopedTempDir* temp_;
};

ScopedTempDir* PhasesCli::temp_ = nullptr;

TEST_F(PhasesCli, EveryPhaseRegistersWithOnePosePerViewAndA4DPanorama) {
  const ToolRun run = Register("--images=" + Images() + " --out_poses=" + Out("all.json") +
                               " --out_panorama=" + Out("panorama.nii.gz") + " --gt_poses=" +
                               Seq("gt_poses.json") + " --report_dir=" + Out("report") +
                               " --report_phase=2");
  ASSERT_EQ(run.exit_code, 0) << run.err;
  EXPECT_NE(run.out.find("3 frames x 3 phases"), std::string::npos) << run.out;
  std::string error;
  PosesFile poses;
  ASSERT_TRUE(ReadPoses(Out("all.json"), 3, &poses, &error)) << error;
  EXPECT_EQ(poses.images[1], "frame_01.nii.gz");
  std::vector<Image> panorama;
  ASSERT_TRUE(ReadPhases(Out("panorama.nii.gz"), &panorama, &error)) << error;
  ASSERT_EQ(panorama.size(), 3u);
  EXPECT_NE(panorama[0].voxels, panorama[2].voxels);  // the beat and each phase's noise
  EXPECT_TRUE(fs::exists(Out("report/index.md")));
  // The same views as one 3D file per phase joined by ';': the same data, the same poses.
  std::string joined;
  for (int f = 0; f < 3; ++f) {
    joined += std::string(f ? "," : "") + Phase3D(f, 0) + ";" + Phase3D(f, 1) + ";" +
              Phase3D(f, 2);
  }
  // (Quoted: the tools run through the shell, where ';' ends a command.)
  const ToolRun files = Register("'--images=" + joined + "' --out_poses=" + Out("joined.json") +
                                 " --out_panorama=" + Out("panorama.seq.nrrd"));
  ASSERT_EQ(files.exit_code, 0) << files.err;
  PosesFile from_files;
  ASSERT_TRUE(ReadPoses(Out("joined.json"), 3, &from_files, &error)) << error;
  for (int f = 0; f < 3; ++f) {
    EXPECT_TRUE(from_files.frame_from_world[f].isApprox(poses.frame_from_world[f], 1e-12)) << f;
  }
  EXPECT_EQ(from_files.images[1], "view_1_phase_0.nii.gz");
  // 3D Slicer's sequence file: its list axis of 3 phases (io/io_phases.h has the format).
  const std::string header = ReadText(Out("panorama.seq.nrrd")).substr(0, 600);
  EXPECT_NE(header.find("kinds: list domain domain domain"), std::string::npos) << header;
  EXPECT_NE(header.find("axis 0 index values:=0 1 2"), std::string::npos) << header;
  // One phase alone: a 3D panorama and other poses (one phase's noise).
  const ToolRun one = Register("--images=" + Images() + " --phases=1 --out_poses=" +
                               Out("one.json") + " --out_panorama=" + Out("one.nii.gz"));
  ASSERT_EQ(one.exit_code, 0) << one.err;
  EXPECT_EQ(one.out.find("x 3 phases"), std::string::npos) << one.out;
  Image single;
  ASSERT_TRUE(ReadImage(Out("one.nii.gz"), &single, &error)) << error;
  EXPECT_NE(ReadText(Out("one.json")), ReadText(Out("all.json")));
}

TEST_F(PhasesCli, FuseWritesEveryPhase) {
  const ToolRun reg = Register("--images=" + Images() + " --out_poses=" + Out("fuse.json"));
  ASSERT_EQ(reg.exit_code, 0) << reg.err;
  const ToolRun fuse = RunTool(DSR_FUSE_BIN, "--images=" + Images() + " --masks=" + Masks() +
                                                 " --poses=" + Out("fuse.json") + " --out=" +
                                                 Out("fused.nii.gz") + " --phases=2,0",
                               Dir());
  ASSERT_EQ(fuse.exit_code, 0) << fuse.err;
  EXPECT_NE(fuse.out.find("3 frames x 2 phases"), std::string::npos) << fuse.out;
  std::vector<Image> fused;
  std::string error;
  ASSERT_TRUE(ReadPhases(Out("fused.nii.gz"), &fused, &error)) << error;
  ASSERT_EQ(fused.size(), 2u);
  // Phase 0 of the file (--phases=2,0) is the sequence's phase 2: its 3D fusion.
  const ToolRun alone = RunTool(DSR_FUSE_BIN, "--images=" + Images() + " --masks=" + Masks() +
                                                  " --poses=" + Out("fuse.json") + " --out=" +
                                                  Out("fused2.nii.gz") + " --phases=2",
                                Dir());
  ASSERT_EQ(alone.exit_code, 0) << alone.err;
  Image phase2;
  ASSERT_TRUE(ReadImage(Out("fused2.nii.gz"), &phase2, &error)) << error;
  EXPECT_EQ(fused[0].voxels, phase2.voxels);
}

// Views given as their phases' files joined by ';': the poses file dsr_register writes for
// them (each view named by its first file) is read back by dsr_fuse --poses and by
// dsr_register's --init and --gt_poses, which once refused it ("no entry names the image").
TEST_F(PhasesCli, PosesOfJoinedPhaseFilesAreReadBackByEveryTool) {
  std::string joined;
  for (int f = 0; f < 3; ++f) {
    joined += std::string(f ? "," : "") + Phase3D(f, 0) + ";" + Phase3D(f, 1) + ";" +
              Phase3D(f, 2);
  }
  const std::string images = "'--images=" + joined + "'";  // the shell ends a command at ';'
  const ToolRun reg = Register(images + " --out_poses=" + Out("own.json"));
  ASSERT_EQ(reg.exit_code, 0) << reg.err;
  const ToolRun fuse = RunTool(DSR_FUSE_BIN, images + " --masks=" + Masks() + " --poses=" +
                                                 Out("own.json") + " --out=" +
                                                 Out("own_fused.nii.gz"),
                               Dir());
  EXPECT_EQ(fuse.exit_code, 0) << fuse.err;
  const ToolRun init = Register(images + " --init=" + Out("own.json") + " --out_poses=" +
                                Out("own_again.json"));
  EXPECT_EQ(init.exit_code, 0) << init.err;
  const ToolRun gt = Register(images + " --gt_poses=" + Out("own.json") + " --out_poses=" +
                              Out("own_gt.json"));
  ASSERT_EQ(gt.exit_code, 0) << gt.err;
  EXPECT_NE(gt.out.find("TRE mean 0.0000 mm"), std::string::npos) << gt.out;
}

TEST_F(PhasesCli, OnePhaseOfFourDimensionalFilesIsRegisteredAndFusedAsItsThreeDimensionalFiles) {
  // --phases=1 reads phase 1 alone from each 4D file: the same poses and the same fusion as
  // the files holding phase 1 only (read as 3D images, as before).
  const std::string phase1 = Phase3D(0, 1) + "," + Phase3D(1, 1) + "," + Phase3D(2, 1);
  const ToolRun four = Register("--images=" + Images() + " --phases=1 --out_poses=" +
                                Out("p1_4d.json"));
  ASSERT_EQ(four.exit_code, 0) << four.err;
  const ToolRun three = Register("--images=" + phase1 + " --out_poses=" + Out("p1_3d.json"));
  ASSERT_EQ(three.exit_code, 0) << three.err;
  std::string error;
  PosesFile from_4d, from_3d;
  ASSERT_TRUE(ReadPoses(Out("p1_4d.json"), 3, &from_4d, &error)) << error;
  ASSERT_TRUE(ReadPoses(Out("p1_3d.json"), 3, &from_3d, &error)) << error;
  for (int f = 0; f < 3; ++f) {
    EXPECT_TRUE(from_4d.frame_from_world[f].isApprox(from_3d.frame_from_world[f], 1e-12)) << f;
  }
  // Each fusion with its own run's poses (matched to its images by name).
  const auto fuse = [&](const std::string& images, const std::string& name) {
    return RunTool(DSR_FUSE_BIN, "--images=" + images + " --masks=" + Masks() + " --poses=" +
                                     Out(name + ".json") + " --out=" + Out(name + ".nii.gz") +
                                     (images == Images() ? " --phases=1" : ""),
                   Dir());
  };
  const ToolRun fused_4d = fuse(Images(), "p1_4d");
  ASSERT_EQ(fused_4d.exit_code, 0) << fused_4d.err;
  const ToolRun fused_3d = fuse(phase1, "p1_3d");
  ASSERT_EQ(fused_3d.exit_code, 0) << fused_3d.err;
  Image image_4d, image_3d;
  ASSERT_TRUE(ReadImage(Out("p1_4d.nii.gz"), &image_4d, &error)) << error;
  ASSERT_TRUE(ReadImage(Out("p1_3d.nii.gz"), &image_3d, &error)) << error;
  EXPECT_EQ(image_4d.voxels, image_3d.voxels);
}

TEST_F(PhasesCli, BadPhaseSetsGiveOneLineNamingTheFileOrFlag) {
  const auto expect_bad = [&](const std::string& args, const std::string& needle) {
    const ToolRun run = Register(args + " --out_poses=" + Out("bad.json"));
    EXPECT_EQ(run.exit_code, 2) << args << "\n" << run.err;
    EXPECT_NE(run.err.find(needle), std::string::npos) << args << "\n" << run.err;
    EXPECT_FALSE(fs::exists(Out("bad.json")));
  };
  // A 3D view among 4D ones.
  expect_bad("--images=" + Frame(0) + "," + Phase3D(1, 0) + "," + Frame(2),
             Phase3D(1, 0) + ": 1 phase, but " + Frame(0) + " has 3");
  expect_bad("--images=" + Images() + " --phases=0,3", Frame(0) + " has 3 phases (0 to 2), no "
                                                       "phase 3");
  expect_bad("--images=" + Images() + " --phases=1,1", "--phases=1,1: must be all or");
  // One grammar: digits separated by single commas, no space, sign or empty item.
  for (const std::string phases : {" 1", "1 ", "+1", "0,1,", ",0", "0,,1"}) {
    expect_bad("--images=" + Images() + " '--phases=" + phases + "'",
               "--phases=" + phases + ": must be all or");
  }
  expect_bad("--images=" + Images() + " --phases=0 --report_phase=1 --report_dir=" + Out("r"),
             "--report_phase=1: only 1 phase is registered");
  expect_bad("--images=" + Images() + " --mode=ape", "mode=ape registers 3D frames");
  expect_bad("'--images=" + Phase3D(0, 0) + ";" + Seq("missing.nii.gz") + "," + Frame(1) + "," +
                 Frame(2) + "'",
             "missing.nii.gz: no such file");
}

// Views whose files contradict themselves or each other: refused before any work with one
// line naming the file, exit status 2, nothing written.
TEST_F(PhasesCli, ContradictoryViewsGiveOneLineNamingTheFile) {
  const auto expect_bad = [&](const std::string& images, const std::string& needle) {
    const ToolRun run = Register("'--images=" + images + "' --out_poses=" + Out("bad.json"));
    EXPECT_EQ(run.exit_code, 2) << images << "\n" << run.err;
    ASSERT_EQ(run.err_lines.size(), 1u) << images << "\n" << run.err;
    EXPECT_NE(run.err_lines[0].find(needle), std::string::npos) << images << "\n" << run.err;
    EXPECT_FALSE(fs::exists(Out("bad.json")));
  };
  const auto joined = [](int f) {
    return Phase3D(f, 0) + ";" + Phase3D(f, 1) + ";" + Phase3D(f, 2);
  };
  // One file as two phases of a view, and one phase file in two views (under another name).
  expect_bad(Phase3D(0, 0) + ";" + Phase3D(0, 0) + ";" + Phase3D(0, 2) + "," + Frame(1) + "," +
                 Frame(2),
             "--images: " + Phase3D(0, 0) + " is given twice (phase 0 of image 0 and phase 1 of "
             "image 0");
  const std::string renamed = Seq("./view_0_phase_0.nii.gz");
  expect_bad(joined(0) + "," + renamed + ";" + Phase3D(1, 1) + ";" + Phase3D(1, 2) + "," +
                 joined(2),
             "--images: " + renamed + " is given twice (phase 0 of image 0 and phase 0 of image 1");
  std::vector<Image> phases;
  std::string error;
  ASSERT_TRUE(ReadPhases(Frame(0), &phases, &error)) << error;
  const std::string others = "," + Frame(1) + "," + Frame(2);
  // A NIfTI time axis of size 0.
  const std::string nifti = Out("dim0.nii");
  ASSERT_TRUE(WritePhases(phases, nifti, &error)) << error;
  std::string bytes = ReadText(nifti);
  bytes[40 + 2 * 4] = bytes[40 + 2 * 4 + 1] = 0;
  std::ofstream(nifti, std::ios::binary) << bytes;
  expect_bad(nifti + others, nifti + ": NIfTI header field dim[4] is 0");
  // 3D Slicer's index values, one short.
  const std::string sequence = Out("keys.seq.nrrd");
  ASSERT_TRUE(WritePhases(phases, sequence, &error)) << error;
  bytes = ReadText(sequence);
  const size_t values = bytes.find("axis 0 index values:=0 1 2\n");
  ASSERT_NE(values, std::string::npos);
  bytes.replace(values, 27, "axis 0 index values:=0 1\n");
  std::ofstream(sequence, std::ios::binary) << bytes;
  expect_bad(sequence + others,
             sequence + ": key 'axis 0 index values' has 2 values for 3 phases");
  // A blank phase.
  const std::string blank = Out("blank.nii.gz");
  std::fill(phases[1].voxels.begin(), phases[1].voxels.end(), 0.0f);
  ASSERT_TRUE(WritePhases(phases, blank, &error)) << error;
  expect_bad(blank + others, blank + ": phase 1 has the same value (0) in every voxel");
  // 100000 phases declared, one phase of data.
  const std::string many = Out("many.seq.nrrd");
  std::ofstream(many, std::ios::binary)
      << "NRRD0004\ntype: float\ndimension: 4\nspace: left-posterior-superior\n"
         "sizes: 100000 32 32 28\nspace directions: none (1,0,0) (0,1,0) (0,0,1)\n"
         "kinds: list domain domain domain\nendian: little\nencoding: raw\n\n"
      << std::string(4 * 32 * 32 * 28, '\0');
  expect_bad(many + others, many + ": cannot read the voxels");
}

}  // namespace
}  // namespace dsr
