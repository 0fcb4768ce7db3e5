// The output plan (app/output_plan.h) run through the real tools: every collision of an
// output with an input, or of two outputs, found through the names the tools derive
// themselves (per-frame transforms, resampled frames, report files, dsr_compare's poses
// files) and through the data files of detached image headers, is refused before any work:
// exit 2, one error line naming both flags, the input byte-identical and nothing written
// (no folder created either). Plus the order of dsr_register's writes (the poses file
// last) and dsr_compare's up-front checks of its sequence folders and methods.
#include <filesystem>
#include <fstream>
#include <map>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "dsr/tests/support/cli_run.h"
#include "dsr/io/io_image.h"
#include "dsr/io/io_poses.h"
#include "dsr/tests/support/scoped_temp_dir.h"

namespace dsr {
namespace {

namespace fs = std::filesystem;
using testing_cli::ReadText;
using testing_cli::RunTool;
using testing_cli::ToolRun;

// Every file (with its bytes) and folder under `root`, to show that a refused run changed
// nothing.
std::map<std::string, std::string> Snapshot(const fs::path& root) {
  std::map<std::string, std::string> entries;
  for (const auto& entry : fs::recursive_directory_iterator(root)) {
    const std::string name = fs::relative(entry.path(), root).string();
    entries[name] = entry.is_directory() ? std::string("<folder>") : ReadText(entry.path());
  }
  return entries;
}

void CopyFile(const fs::path& from, const fs::path& to) {
  fs::create_directories(to.parent_path());
  fs::copy_file(from, to, fs::copy_options::overwrite_existing);
}

class OutputPlanTest : public ::testing::Test {
 protected:
  // One small simulated sequence for every test (3 frames of 20x20x16 voxels).
  static void SetUpTestSuite() {
    temp_ = new ScopedTempDir("dsr_output_plan_test");
    const ToolRun sim = RunTool(DSR_SIMULATE_BIN,
                                "--out_dir=" + Seq("") +
                                    " --phantom_size=48 --frame_size=20,20,16 --num_frames=3 "
                                    "--max_rotation_deg=4 --max_translation_voxels=1 "
                                    "--min_depth_voxels=2 --sigma=5",
                                Root());
    ASSERT_EQ(sim.exit_code, 0) << sim.err;
    PosesFile identity;
    identity.images = {"frame_00.nii.gz", "frame_01.nii.gz", "frame_02.nii.gz"};
    identity.frame_from_world.assign(3, Eigen::Isometry3d::Identity());
    std::string error;
    ASSERT_TRUE(WritePoses(identity, (Root() / "identity.json").string(), &error)) << error;
  }
  static void TearDownTestSuite() {
    delete temp_;
    temp_ = nullptr;
  }

  void SetUp() override {
    work_ = Root() / ::testing::UnitTest::GetInstance()->current_test_info()->name();
    fs::create_directories(work_);
  }

  static std::string Seq(const std::string& name) { return (Root() / "seq" / name).string(); }
  static std::string Frames() {
    return Seq("frame_00.nii.gz") + "," + Seq("frame_01.nii.gz") + "," + Seq("frame_02.nii.gz");
  }
  static std::string Masks() {
    return Seq("mask_00.nii.gz") + "," + Seq("mask_01.nii.gz") + "," + Seq("mask_02.nii.gz");
  }
  std::string W(const std::string& name) const { return (work_ / name).string(); }
  static std::string RegisterArgs() {
    return "--images=" + Frames() + " --masks=" + Masks() + " --pyramid_levels=1 --progress=false ";
  }

  // Runs `binary args` and expects it refused before any work: exit 2, one error line that
  // names each of `must_name`, and the work folder (inputs included) exactly as before.
  void ExpectRefused(const std::string& binary,
                     const std::string& args,
                     const std::vector<std::string>& must_name) {
    SCOPED_TRACE(args);
    const std::map<std::string, std::string> before = Snapshot(work_);
    const ToolRun run = RunTool(binary, args, Root());
    EXPECT_EQ(run.exit_code, 2) << run.err;
    ASSERT_EQ(run.error_lines.size(), 1u) << run.err;
    for (const std::string& name : must_name) {
      EXPECT_NE(run.error_lines[0].find(name), std::string::npos)
          << "the error line should name '" << name << "': " << run.error_lines[0];
    }
    const std::map<std::string, std::string> after = Snapshot(work_);
    EXPECT_EQ(after.size(), before.size()) << "a file or folder was created";
    EXPECT_TRUE(after == before) << "a file was changed";
  }

  // The suite's folder: its inputs, and the work of each test.
  static fs::path Root() { return temp_->dir(); }

  static ScopedTempDir* temp_;
  fs::path work_;
};

ScopedTempDir* OutputPlanTest::temp_ = nullptr;

// O03: one file spelled two ways (".", "..", a symlinked folder).
TEST_F(OutputPlanTest, TwoSpellingsOfOneOutputFile) {
  fs::create_directories(W("real/sub"));
  fs::create_directory_symlink(W("real"), W("link"));
  ExpectRefused(DSR_REGISTER_BIN,
                RegisterArgs() + "--out_poses=" + W("x.nii.gz") + " --out_panorama=" +
                    W("./x.nii.gz"),
                {"--out_poses=" + W("x.nii.gz"), "--out_panorama=" + W("./x.nii.gz")});
  ExpectRefused(DSR_REGISTER_BIN,
                RegisterArgs() + "--out_poses=" + W("real/p.nii.gz") + " --out_panorama=" +
                    W("link/sub/../p.nii.gz"),
                {"--out_poses", "--out_panorama"});
  // A folder that does not exist yet: "new/./x" and "new/x" are one file too.
  ExpectRefused(DSR_REGISTER_BIN,
                RegisterArgs() + "--out_poses=" + W("new/./sub/../frame_01.tfm") +
                    " --out_tfm_dir=" + W("new"),
                {"--out_poses", "--out_tfm_dir"});
}

// An input under another name: the @LIST file of --images, and a hard link of --gt_poses.
TEST_F(OutputPlanTest, OtherNamesOfAnInput) {
  std::ofstream(W("list.txt")) << Seq("frame_00.nii.gz") << "\n" << Seq("frame_01.nii.gz") << "\n";
  ExpectRefused(DSR_REGISTER_BIN,
                "--images=@" + W("list.txt") + " --out_poses=" + W("./list.txt"),
                {"--out_poses", "--images=@" + W("list.txt")});
  CopyFile(Seq("gt_poses.json"), W("gt.json"));
  fs::create_hard_link(W("gt.json"), W("hard.json"));
  ExpectRefused(DSR_REGISTER_BIN,
                RegisterArgs() + "--gt_poses=" + W("gt.json") + " --out_poses=" + W("hard.json"),
                {"--out_poses=" + W("hard.json"), "--gt_poses=" + W("gt.json")});
}

// O07: a name the tool derives (frame_00.tfm in --out_tfm_dir; the report's poses.json)
// is another output.
TEST_F(OutputPlanTest, DerivedNameIsAnotherOutput) {
  ExpectRefused(DSR_REGISTER_BIN,
                RegisterArgs() + "--out_poses=" + W("frame_00.tfm") + " --out_tfm_dir=" + W(""),
                {"--out_poses=" + W("frame_00.tfm"), "--out_tfm_dir"});
  // The report folder does not exist: it is not created either.
  ExpectRefused(DSR_REGISTER_BIN,
                RegisterArgs() + "--out_poses=" + W("report/poses.json") + " --report_dir=" +
                    W("report"),
                {"--out_poses", "--report_dir"});
  ExpectRefused(DSR_REGISTER_BIN,
                RegisterArgs() + "--out_poses=" + W("p.json") + " --report_dir=" + W("report") +
                    " --out_tfm_dir=" + W("report/transforms"),
                {"--report_dir", "--out_tfm_dir", "frame_00.tfm"});
}

// O05, O04: --gt_poses or --init inside --report_dir, where the report writes poses.json.
TEST_F(OutputPlanTest, PosesInputInsideReportDir) {
  CopyFile(Seq("gt_poses.json"), W("gt/poses.json"));
  CopyFile(Seq("gt_poses.json"), W("init/poses.json"));
  ExpectRefused(DSR_REGISTER_BIN,
                RegisterArgs() + "--gt_poses=" + W("gt/poses.json") + " --report_dir=" +
                    W("gt") + " --out_poses=" + W("o5.json"),
                {"--report_dir", "--gt_poses=" + W("gt/poses.json")});
  ExpectRefused(DSR_REGISTER_BIN,
                RegisterArgs() + "--init=" + W("init/./poses.json") + " --report_dir=" +
                    W("init/") + " --out_poses=" + W("o4.json"),
                {"--report_dir", "--init="});
}

// O06: an input named like a resampled frame inside --out_resampled_dir.
TEST_F(OutputPlanTest, InputNamedLikeResampledFrame) {
  CopyFile(Seq("frame_01.nii.gz"), W("res/frame_01_in_panorama.nii.gz"));
  ExpectRefused(DSR_REGISTER_BIN,
                "--images=" + Seq("frame_00.nii.gz") + "," + W("res/frame_01_in_panorama.nii.gz") +
                    "," + Seq("frame_02.nii.gz") + " --masks=" + Masks() +
                    " --pyramid_levels=1 --progress=false --out_resampled_dir=" + W("res") +
                    " --out_poses=" + W("o6.json"),
                {"--out_resampled_dir", "--images"});
}

// X03: the data file a .mhd output writes next to itself is an input's data file: an
// ElementDataFile named explicitly, and one slice of a LIST.
TEST_F(OutputPlanTest, DetachedHeaderDataFileIsAnInput) {
  Image frame1;
  std::string error;
  ASSERT_TRUE(ReadImage(Seq("frame_01.nii.gz"), &frame1, &error)) << error;
  fs::create_directories(W("mhd"));
  ASSERT_TRUE(WriteImage(frame1, W("mhd/pan.mhd"), &error)) << error;
  fs::rename(W("mhd/pan.mhd"), W("mhd/in.mhd"));  // in.mhd names pan.raw
  ASSERT_NE(ReadText(W("mhd/in.mhd")).find("pan.raw"), std::string::npos);
  const std::string images = "--images=" + Seq("frame_00.nii.gz") + "," + W("mhd/in.mhd") +
                             " --pyramid_levels=1 --progress=false --out_poses=" + W("x3.json");
  ExpectRefused(DSR_REGISTER_BIN,
                images + " --out_panorama=" + W("mhd/pan.mhd"),
                {"--out_panorama=" + W("mhd/pan.mhd"), "pan.raw", "--images"});
  // The data file itself as an output.
  ExpectRefused(DSR_REGISTER_BIN,
                "--images=" + Seq("frame_00.nii.gz") + "," + W("mhd/in.mhd") +
                    " --out_poses=" + W("mhd/pan.raw"),
                {"--out_poses", "pan.raw"});
  // LIST: one file per slice; an output whose data file is slice 3.
  const std::string raw = ReadText(W("mhd/pan.raw"));
  const size_t slice_bytes = raw.size() / frame1.geometry.size[2];
  std::string header = ReadText(W("mhd/in.mhd"));
  header = header.substr(0, header.find("ElementDataFile")) + "ElementDataFile = LIST 2D\n";
  fs::create_directories(W("list"));
  for (int z = 0; z < frame1.geometry.size[2]; ++z) {
    const std::string name = "sl_" + std::to_string(z) + ".raw";
    std::ofstream(W("list/" + name), std::ios::binary) << raw.substr(z * slice_bytes, slice_bytes);
    header += name + "\n";
  }
  std::ofstream(W("list/list.mhd")) << header;
  Image listed;
  ASSERT_TRUE(ReadImage(W("list/list.mhd"), &listed, &error)) << error;
  ExpectRefused(DSR_REGISTER_BIN,
                "--images=" + Seq("frame_00.nii.gz") + "," + W("list/list.mhd") +
                    " --out_poses=" + W("x.json") + " --out_panorama=" + W("list/sl_3.nhdr"),
                {"--out_panorama", "sl_3.raw", "--images"});
}

// U04: dsr_fuse --out and --out_count one file; and dsr_simulate's frames over its source.
TEST_F(OutputPlanTest, FuseAndSimulateOutputs) {
  const std::string fuse = "--images=" + Frames() + " --masks=" + Masks() + " --poses=" +
                           (Root() / "identity.json").string();
  ExpectRefused(DSR_FUSE_BIN,
                fuse + " --out=" + W("p.nii.gz") + " --out_count=" + W("./p.nii.gz"),
                {"--out=" + W("p.nii.gz"), "--out_count"});
  ExpectRefused(DSR_FUSE_BIN,
                fuse + " --out=" + W("p.mhd") + " --out_count=" + W("p.nhdr"),
                {"--out=" + W("p.mhd"), "--out_count=" + W("p.nhdr"), "p.raw"});
  CopyFile(Seq("frame_00.nii.gz"), W("sim/frame_00.nii.gz"));
  ExpectRefused(DSR_SIMULATE_BIN,
                "--source=" + W("sim/frame_00.nii.gz") + " --out_dir=" + W("sim") +
                    " --frame_size=8,8,8 --num_frames=2",
                {"--out_dir", "--source"});
}

// D05: when the panorama cannot be written (a file-size limit, i.e. a full disk), the run
// fails with exit 1 and the previous poses file is as it was: it is written last.
TEST_F(OutputPlanTest, PosesFileIsWrittenLast) {
  std::ofstream(W("p.json")) << "previous\n";
  // 8 KiB: enough for the poses (and stderr), not for the uncompressed panorama (12 KiB).
  const std::string limited = std::string("bash -c 'trap \"\" XFSZ; ulimit -f 8; exec ") +
                              DSR_REGISTER_BIN + " \"$@\"' bash";
  const ToolRun run = RunTool(limited,
                              RegisterArgs() + "--out_poses=" + W("p.json") +
                                  " --out_panorama=" + W("pan.nii") + " --out_tfm_dir=" + W("t"),
                              Root());
  EXPECT_EQ(run.exit_code, 1) << run.err;
  // The tool's own error line (the NIfTI library may print one of its own before it).
  ASSERT_FALSE(run.error_lines.empty()) << run.err;
  EXPECT_EQ(run.error_lines.back().rfind("dsr_register: error: " + W("pan.nii"), 0), 0u)
      << run.err;
  EXPECT_EQ(ReadText(W("p.json")), "previous\n");
  EXPECT_FALSE(fs::exists(W("pan.nii")));
  // Without the limit the same run replaces it.
  const ToolRun ok = RunTool(DSR_REGISTER_BIN,
                             RegisterArgs() + "--out_poses=" + W("p.json") + " --out_panorama=" +
                                 W("pan.nii") + " --out_tfm_dir=" + W("t"),
                             Root());
  ASSERT_EQ(ok.exit_code, 0) << ok.err;
  EXPECT_NE(ReadText(W("p.json")), "previous\n");
  EXPECT_TRUE(fs::exists(W("t/frame_02.tfm")));
}

// C02: every --sequences folder is checked before the first run.
TEST_F(OutputPlanTest, CompareChecksEverySequenceFirst) {
  for (const char* name : {"frame_00.nii.gz", "frame_01.nii.gz", "frame_02.nii.gz",
                           "mask_00.nii.gz", "mask_01.nii.gz", "mask_02.nii.gz"}) {
    CopyFile(Seq(name), W(std::string("nogt/") + name));
    CopyFile(Seq(name), W(std::string("corrupt/") + name));
    if (name[0] == 'f') CopyFile(Seq(name), W(std::string("nomasks/") + name));
  }
  CopyFile(Seq("gt_poses.json"), W("corrupt/gt_poses.json"));
  CopyFile(Seq("gt_poses.json"), W("nomasks/gt_poses.json"));
  std::ofstream(W("corrupt/frame_02.nii.gz"), std::ios::binary) << "not an image";
  const std::string compare = "--methods=dsr --pyramid_levels=1 --out_dir=" + W("c") +
                              " --sequences=" + Seq("") + ",";
  ExpectRefused(DSR_COMPARE_BIN, compare + W("nogt"), {"--sequences", "nogt", "gt_poses.json"});
  ExpectRefused(DSR_COMPARE_BIN, compare + W("corrupt"), {"frame_02.nii.gz"});
  ExpectRefused(DSR_COMPARE_BIN, compare + W("nomasks"), {"--sequences", "nomasks", "mask"});
  // Without --sequence_masks the masks are not needed: the comparison runs.
  const ToolRun run = RunTool(DSR_COMPARE_BIN, compare + W("nomasks") + " --sequence_masks=false",
                              Root());
  ASSERT_EQ(run.exit_code, 0) << run.err;
  EXPECT_TRUE(fs::exists(W("c/poses/seq_dsr.json")));
  EXPECT_TRUE(fs::exists(W("c/poses/nomasks_dsr.json")));
}

// C03: two sequence folders with one name would share rows and poses files; a method given
// twice would run twice into one poses file.
TEST_F(OutputPlanTest, CompareRefusesDuplicateSequencesAndMethods) {
  for (const char* name : {"frame_00.nii.gz", "frame_01.nii.gz", "frame_02.nii.gz",
                           "mask_00.nii.gz", "mask_01.nii.gz", "mask_02.nii.gz", "gt_poses.json"}) {
    CopyFile(Seq(name), W(std::string("x/seq/") + name));
    CopyFile(Seq(name), W(std::string("y/seq/") + name));
  }
  const std::string out = " --pyramid_levels=1 --out_dir=" + W("c");
  ExpectRefused(DSR_COMPARE_BIN,
                "--methods=dsr --sequences=" + W("x/seq") + "," + W("y/seq/") + out,
                {"--sequences", W("x/seq"), W("y/seq/"), "'seq'"});
  ExpectRefused(DSR_COMPARE_BIN,
                "--methods=dsr --sequences=" + W("x/seq") + "," + W("x/./seq") + out,
                {"--sequences", "twice"});
  ExpectRefused(DSR_COMPARE_BIN, "--methods=dsr,ape,dsr --sequences=" + W("x/seq") + out,
                {"--methods=dsr,ape,dsr", "'dsr'"});
}

}  // namespace
}  // namespace dsr
