// The bad-input catalogue: every entry runs a tool on one bad input and expects
// exit code 2, exactly one error line that names the file or flag, and no output file left
// in the output folder. Files are crafted here: MetaImage headers by hand (spacing,
// direction, NaN/Inf, 2D/4D, vector pixels) and NIfTI files written by the tools
// themselves and then damaged (truncated, corrupt header).
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
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
using testing_cli::RunTool;
using testing_cli::ToolRun;

struct MhaOptions {
  std::string ndims = "3";
  std::string size = "16 16 16";
  std::string spacing = "1 1 1";
  std::string matrix = "1 0 0 0 1 0 0 0 1";
  std::string offset = "0 0 0";
  std::string channels;  // ElementNumberOfChannels, empty = not written
  int count = 16 * 16 * 16;
  float special = 0.0f;   // written into voxel special_voxel when use_special (NaN, Inf)
  bool use_special = false;
  int special_voxel = 100;
};

// A MetaImage with inline float data: a textured cube (values 1..), so it is a valid frame
// apart from what `o` breaks.
void WriteMha(const fs::path& path, const MhaOptions& o) {
  std::ofstream out(path, std::ios::binary);
  out << "ObjectType = Image\nNDims = " << o.ndims
      << "\nBinaryData = True\nBinaryDataByteOrderMSB = False\nCompressedData = False\n"
      << "TransformMatrix = " << o.matrix << "\nOffset = " << o.offset
      << "\nElementSpacing = " << o.spacing << "\nDimSize = " << o.size << "\n";
  if (!o.channels.empty()) out << "ElementNumberOfChannels = " << o.channels << "\n";
  out << "ElementType = MET_FLOAT\nElementDataFile = LOCAL\n";
  const int channels = o.channels.empty() ? 1 : std::stoi(o.channels);
  std::vector<float> data(static_cast<size_t>(o.count) * channels);
  for (size_t v = 0; v < data.size(); ++v) data[v] = 1.0f + static_cast<float>((v * 37) % 101);
  if (o.use_special) data[o.special_voxel] = o.special;
  out.write(reinterpret_cast<const char*>(data.data()), data.size() * sizeof(float));
}

class BadInputCatalogue : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    temp_ = new ScopedTempDir("dsr_catalogue_test");
    fs::create_directories(Root() / "in");
    const ToolRun sim = RunTool(DSR_SIMULATE_BIN,
                                "--out_dir=" + In("") +
                                    " --phantom_size=48 --frame_size=20,20,16 --num_frames=3 "
                                    "--max_rotation_deg=4 --max_translation_voxels=1 "
                                    "--min_depth_voxels=2 --sigma=5",
                                Root());
    ASSERT_EQ(sim.exit_code, 0) << sim.err;
    // Damaged copies of frame_01.
    const std::string bytes = testing_cli::ReadText(In("frame_01.nii.gz"));
    std::ofstream(In("truncated.nii.gz"), std::ios::binary).write(bytes.data(), bytes.size() / 2);
    std::string corrupt = bytes;
    for (size_t i = 0; i < 64 && i < corrupt.size(); ++i) corrupt[i] = static_cast<char>(0x5a);
    std::ofstream(In("corrupt.nii.gz"), std::ios::binary).write(corrupt.data(), corrupt.size());
    std::ofstream(In("empty.nii")).close();
    MhaOptions o;
    WriteMha(In("good.mha"), o);
    o = MhaOptions();
    o.ndims = "2";
    o.size = "64 64";
    o.spacing = "1 1";
    o.matrix = "1 0 0 1";
    o.offset = "0 0";
    WriteMha(In("flat2d.mha"), o);
    o = MhaOptions();
    o.ndims = "4";
    o.size = "16 16 16 3";
    o.spacing = "1 1 1 1";
    o.matrix = "1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1";
    o.offset = "0 0 0 0";
    o.count = 16 * 16 * 16 * 3;
    WriteMha(In("time4d.mha"), o);
    o = MhaOptions();
    o.channels = "3";
    WriteMha(In("vector.mha"), o);
    o = MhaOptions();
    o.spacing = "0 1 1";
    WriteMha(In("zero_spacing.mha"), o);
    o = MhaOptions();
    o.spacing = "1 -2 1";
    WriteMha(In("negative_spacing.mha"), o);
    o = MhaOptions();
    o.matrix = "1 0 0 1 0 0 0 0 1";
    WriteMha(In("singular_direction.mha"), o);
    // A header in nanometres and one in kilometres (frames share frame 0's millimetres).
    o = MhaOptions();
    o.spacing = "1e-9 1e-9 1e-9";
    WriteMha(In("nanometre_spacing.mha"), o);
    o.spacing = "1e9 1e9 1e9";
    WriteMha(In("huge_spacing.mha"), o);
    o = MhaOptions();
    o.use_special = true;
    o.special = std::numeric_limits<float>::quiet_NaN();
    WriteMha(In("nan.mha"), o);
    o.special = std::numeric_limits<float>::infinity();
    WriteMha(In("inf.mha"), o);
    o.special = -5.0f;  // a negative intensity inside, refused by --intensity_transform=sqrt
    o.special_voxel = 8 + 16 * (8 + 16 * 8);
    WriteMha(In("negative.mha"), o);
    // A mask of another size, and a mask with no inside voxel on frame_00's grid.
    o = MhaOptions();
    WriteMha(In("mask_other_size.mha"), o);
    Image frame0;
    std::string error;
    ASSERT_TRUE(ReadImage(In("frame_00.nii.gz"), &frame0, &error)) << error;
    Image zero(frame0.geometry, 0.0f);
    ASSERT_TRUE(WriteImage(zero, In("all_zero.nii.gz"), &error)) << error;
    ASSERT_TRUE(WriteImage(zero, In("mask_empty.nii.gz"), &error)) << error;
    // Poses files.
    std::ofstream(In("not_json.json")) << "{\"frames\": [ this is not json";
    std::ofstream(In("wrong_shape.json"))
        << R"({"frames":[{"image":"a","T":[[1,0,0],[0,1,0],[0,0,1]]}]})";
    std::ofstream(In("non_rigid.json"))
        << R"({"frames":[{"image":"a","T":[[2,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]},)"
        << R"({"image":"b","T":[[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]},)"
        << R"({"image":"c","T":[[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}]})";
    PosesFile two;
    two.images = {"a", "b"};
    two.frame_from_world.assign(2, Eigen::Isometry3d::Identity());
    ASSERT_TRUE(WritePoses(two, In("two_frames.json"), &error)) << error;
    PosesFile apart;  // without image names: taken in --images order
    apart.frame_from_world.assign(3, Eigen::Isometry3d::Identity());
    apart.frame_from_world[2].translation() = Eigen::Vector3d(300.0, 0.0, 0.0);
    ASSERT_TRUE(WritePoses(apart, In("apart.json"), &error)) << error;
    apart.frame_from_world[2].translation() = Eigen::Vector3d(1e300, 0.0, 0.0);
    ASSERT_TRUE(WritePoses(apart, In("astronomical.json"), &error)) << error;
    PosesFile strangers;  // names that are none of the frames
    strangers.images = {"x.nii.gz", "y.nii.gz", "z.nii.gz"};
    strangers.frame_from_world.assign(3, Eigen::Isometry3d::Identity());
    ASSERT_TRUE(WritePoses(strangers, In("strangers.json"), &error)) << error;
    // Two frames whose content is a linear ramp: their overlap cannot fix 6 degrees of freedom.
    Image ramp(frame0.geometry);
    for (int k = 0; k < ramp.geometry.size[2]; ++k)
      for (int j = 0; j < ramp.geometry.size[1]; ++j)
        for (int i = 0; i < ramp.geometry.size[0]; ++i) ramp.at(i, j, k) = 10.0f + 3.0f * i;
    ASSERT_TRUE(WriteImage(ramp, In("ramp_a.nii.gz"), &error)) << error;
    ASSERT_TRUE(WriteImage(ramp, In("ramp_b.nii.gz"), &error)) << error;
  }
  static void TearDownTestSuite() {
    delete temp_;
    temp_ = nullptr;
  }
  static std::string In(const std::string& name) { return (Root() / "in" / name).string(); }
  static std::string Frames() {
    return In("frame_00.nii.gz") + "," + In("frame_01.nii.gz") + "," + In("frame_02.nii.gz");
  }
  static std::string Masks() {
    return In("mask_00.nii.gz") + "," + In("mask_01.nii.gz") + "," + In("mask_02.nii.gz");
  }
  // Runs one catalogue entry in a fresh, empty output folder.
  void Expect(const std::string& binary, const std::string& args_with_out,
              const std::string& must_name) {
    const fs::path out = Root() / ("out_" + std::to_string(++entry_));
    fs::create_directories(out);
    std::string args = args_with_out;
    for (size_t at; (at = args.find("@OUT")) != std::string::npos;)
      args.replace(at, 4, out.string());
    const ToolRun run = RunTool(binary, args, Root());
    SCOPED_TRACE(binary + " " + args);
    if (getenv("DSR_TEST_LOG") != nullptr) {
      std::printf("%s\n", run.error_lines.empty() ? "(no error line)" : run.error_lines[0].c_str());
    }
    EXPECT_EQ(run.exit_code, 2) << run.err;
    ASSERT_EQ(run.error_lines.size(), 1u) << run.err;
    EXPECT_NE(run.error_lines[0].find(must_name), std::string::npos)
        << "the error line should name '" << must_name << "': " << run.error_lines[0];
    EXPECT_TRUE(fs::is_empty(out)) << "output left behind";
  }
  void Register(const std::string& args, const std::string& must_name) {
    Expect(DSR_REGISTER_BIN,
           "--out_poses=@OUT/poses.json --out_panorama=@OUT/panorama.nii.gz "
           "--pyramid_levels=1 --progress=false " + args,
           must_name);
  }

  // The suite's folder: its inputs, and the work of each test.
  static fs::path Root() { return temp_->dir(); }

  static ScopedTempDir* temp_;
  static int entry_;
};

ScopedTempDir* BadInputCatalogue::temp_ = nullptr;
int BadInputCatalogue::entry_ = 0;

TEST_F(BadInputCatalogue, ImageFiles) {
  const std::string f0 = In("frame_00.nii.gz") + ",";
  Register("--images=" + f0 + In("missing.nii.gz"), "missing.nii.gz");
  Register("--images=" + f0 + (Root() / "in").string(), "in");  // a folder
  Register("--images=" + f0 + In("empty.nii"), "empty.nii");
  Register("--images=" + f0 + In("corrupt.nii.gz"), "corrupt.nii.gz");
  Register("--images=" + f0 + In("truncated.nii.gz"), "truncated.nii.gz");
  Register("--images=" + f0 + In("flat2d.mha"), "flat2d.mha");
  Register("--images=" + f0 + In("time4d.mha"), "time4d.mha");
  Register("--images=" + f0 + In("vector.mha"), "vector.mha");
  Register("--images=" + f0 + In("zero_spacing.mha"), "zero_spacing.mha");
  Register("--images=" + f0 + In("negative_spacing.mha"), "negative_spacing.mha");
  Register("--images=" + f0 + In("singular_direction.mha"), "singular_direction.mha");
  Register("--images=" + f0 + In("nan.mha"), "nan.mha");
  Register("--images=" + f0 + In("inf.mha"), "inf.mha");
  Register("--images=" + f0 + In("all_zero.nii.gz"), "all_zero.nii.gz");
  Register("--images=" + f0 + In("all_zero.nii.gz") + " --masks=" + In("mask_00.nii.gz") + "," +
               In("mask_01.nii.gz"),
           "frame 1");
  Register("--images=" + Frames() + " --masks=" + In("mask_00.nii.gz") + "," +
               In("mask_other_size.mha") + "," + In("mask_02.nii.gz"),
           "mask_other_size.mha");
  Register("--images=" + Frames() + " --masks=" + In("mask_empty.nii.gz") + "," +
               In("mask_01.nii.gz") + "," + In("mask_02.nii.gz"),
           "mask_empty.nii.gz");
  Register("--images=" + Frames() + " --masks=" + In("mask_00.nii.gz"), "--masks");
}

TEST_F(BadInputCatalogue, FrameSets) {
  Register("--images=" + In("frame_00.nii.gz"), "--images");
  Register("--images=" + In("frame_00.nii.gz") + "," + In("frame_00.nii.gz"), "frame_00.nii.gz");
  Register("--images=" + Frames() + " --masks=" + Masks() + " --init=" + In("apart.json"),
           "frame 2 does not overlap");
  Register("--images=" + In("ramp_a.nii.gz") + "," + In("ramp_b.nii.gz") + " --mask_erosion=1",
           "6 degrees of freedom of frame 1");
  // Errors that name what is wrong rather than what fails later (the frame's file, --init).
  Register("--images=" + In("good.mha") + "," + In("nanometre_spacing.mha"),
           "nanometre_spacing.mha: frame 1 has a voxel spacing");
  Register("--images=" + In("good.mha") + "," + In("huge_spacing.mha"),
           "huge_spacing.mha: frame 1 has a voxel spacing");
  Register("--images=" + Frames() + " --masks=" + Masks() + " --init=" + In("astronomical.json"),
           "(--init) place frame 2");
}

TEST_F(BadInputCatalogue, PosesFiles) {
  const std::string base = "--images=" + Frames() + " --masks=" + Masks();
  Register(base + " --init=" + In("not_json.json"), "not_json.json");
  Register(base + " --init=" + In("wrong_shape.json"), "wrong_shape.json");
  Register(base + " --init=" + In("non_rigid.json"), "non_rigid.json");
  Register(base + " --init=" + In("two_frames.json"), "two_frames.json");
  Register(base + " --gt_poses=" + In("two_frames.json"), "--gt_poses");
  // Poses are matched to the images by name: names of other images are refused.
  Register(base + " --init=" + In("strangers.json"),
           "--init=" + In("strangers.json") + ": no entry names");
  Register(base + " --gt_poses=" + In("strangers.json"), "--gt_poses=");
}

TEST_F(BadInputCatalogue, FlagValues) {
  const std::string base = "--images=" + Frames() + " --masks=" + Masks();
  Register(base + " --panorama_spacing=-1", "--panorama_spacing");
  Register(base + " --max_iterations=0", "--max_iterations");
  Register(base + " --mode=bundle_adjust", "--mode");
  Register(base + " --linear_solver=MAGIC", "--linear_solver");
  Register(base + " --trust_region=ANNEALING", "--trust_region");
  Register(base + " --num_threads=-2", "--num_threads");
  Register(base + " --step_tolerance=-1", "--step_tolerance");
  Register(base + " --num_frames_typo=3", "--num_frames_typo=3: unknown flag");
  Register(base + " --max_iterations=many", "--max_iterations=many: not a valid int32");
  Register(base + " --mode=dba --memory_budget_mb=0.01", "--mode=dsr");
  Register(base + " --min_kept_overlap=-0.1", "--min_kept_overlap");
  Register(base + " --max_misfit_ratio=nan", "--max_misfit_ratio");
  Register(base + " --max_recoveries=11", "--max_recoveries");
  Register(base + " --max_misfit_ratio=0 --min_kept_overlap=0 --max_pair_mismatch_ratio=0 "
                  "--max_structure_fraction=0",
           "--max_recoveries");
  Register(base + " --max_structure_fraction=1", "--max_structure_fraction=1: must be in [0, 1)");
  Register(base + " --max_structure_fraction=nan", "--max_structure_fraction");
  Register(base + " --preset=heart", "--preset=heart: must be none or echo");
  Register(base + " --max_pose_error_voxels=-1", "--max_pose_error_voxels=-1: must be >= 0");
  Register(base + " --photometric=gamma", "--photometric=gamma: must be none, affine or auto");
  Register(base + " --max_pair_mismatch_ratio=1", "--max_pair_mismatch_ratio");
  Register(base + " --max_pair_mismatch_ratio=inf", "--max_pair_mismatch_ratio");
  Register(base + " --search_rotations=0", "--search_rotations=0:");
  Register(base + " --search_pair_rotations=-5", "--search_pair_rotations=-5:");
  Register(base + " --search_rotation_deg=200", "--search_rotation_deg=200:");
  Register(base + " --search_max_axis=4", "--search_max_axis");
  Register(base + " --init=no_such_start", "no_such_start");
  Register(base + " --smoothing=1e6", "--smoothing");
  Register(base + " --panorama_spacing=1e300", "--panorama_spacing");
  Register(base + " --intensity_transform=log", "--intensity_transform=log: must be none or sqrt");
  Register(base + " --panorama_sampling=dither",
           "--panorama_sampling=dither: must be half_voxel or all_phases");
  Register(base + " --gauge=frame1", "--gauge=frame1: must be frame0 or mean");
  Register(base + " --mask_rule=convex", "--mask_rule=convex: must be hull or nonzero");
  Register(base + " --mode=ape --gauge=mean",
           "--gauge=mean: needs --mode=dsr or dba (--mode=ape holds frame 0 constant)");
  Register("--images=" + In("good.mha") + "," + In("negative.mha") + " --intensity_transform=sqrt",
           "negative.mha: frame 1 has a negative intensity (-5) at voxel (8,8,8) inside its mask: "
           "--intensity_transform=sqrt needs intensities >= 0");
}

TEST_F(BadInputCatalogue, OutputPaths) {
  const std::string images =
      "--images=" + Frames() + " --masks=" + Masks() + " --progress=false --pyramid_levels=1";
  // Output equal to an input (the input stays as it was).
  const std::string before = testing_cli::ReadText(In("frame_02.nii.gz"));
  Expect(DSR_REGISTER_BIN, images + " --out_poses=" + In("frame_02.nii.gz"), "--out_poses");
  EXPECT_EQ(testing_cli::ReadText(In("frame_02.nii.gz")), before);
  Expect(DSR_REGISTER_BIN, images + " --out_poses=@OUT/missing_folder/poses.json", "--out_poses");
  Expect(DSR_REGISTER_BIN, images + " --out_poses=@OUT", "--out_poses");
  Expect(DSR_REGISTER_BIN,
         images + " --out_poses=@OUT/p.json --out_panorama=@OUT/panorama.jpg", "--out_panorama");
  Expect(DSR_REGISTER_BIN, images, "--out_poses");  // required flag missing
}

TEST_F(BadInputCatalogue, Simulator) {
  Expect(DSR_SIMULATE_BIN, "--out_dir=@OUT/s --num_frames=1", "--num_frames");
  Expect(DSR_SIMULATE_BIN, "--out_dir=@OUT/s --frame_size=96,96", "--frame_size");
  Expect(DSR_SIMULATE_BIN, "--out_dir=@OUT/s --sigma=-3", "--sigma");
  Expect(DSR_SIMULATE_BIN, "--out_dir=@OUT/s --intensity_mapping=doppler", "--intensity_mapping");
  Expect(DSR_SIMULATE_BIN, "--out_dir=@OUT/s --echo_reject=255", "--echo_reject");
  Expect(DSR_SIMULATE_BIN, "--out_dir=@OUT/s --echo_edge_sigma_mm=-1", "--echo_edge_sigma_mm");
  Expect(DSR_SIMULATE_BIN, "--out_dir=@OUT/s --echo_edge_weight=2", "--echo_edge_weight");
  Expect(DSR_SIMULATE_BIN, "--out_dir=@OUT/s --source=" + In("truncated.nii.gz"),
         "truncated.nii.gz");
  Expect(DSR_SIMULATE_BIN, "--out_dir=@OUT/s --source=" + In("missing.nii.gz"), "missing.nii.gz");
}

TEST_F(BadInputCatalogue, Fuse) {
  const std::string base = "--images=" + Frames() + " --masks=" + Masks();
  Expect(DSR_FUSE_BIN, base + " --poses=" + In("two_frames.json") + " --out=@OUT/p.nii.gz",
         "--poses");
  Expect(DSR_FUSE_BIN, base + " --poses=" + In("non_rigid.json") + " --out=@OUT/p.nii.gz",
         "non_rigid.json");
  Expect(DSR_FUSE_BIN, base + " --poses=" + In("missing.json") + " --out=@OUT/p.nii.gz",
         "missing.json");
  Expect(DSR_FUSE_BIN, base + " --poses=" + In("apart.json") + " --out=@OUT/p.nii.gz --blend=max",
         "--blend");
  Expect(DSR_FUSE_BIN, base + " --poses=" + In("apart.json") + " --out=" + In("frame_01.nii.gz"),
         "--out");
  Expect(DSR_FUSE_BIN, "--images=" + In("frame_00.nii.gz") + "," + In("nan.mha") + " --poses=" +
                           In("two_frames.json") + " --out=@OUT/p.nii.gz",
         "nan.mha");
}

TEST_F(BadInputCatalogue, Compare) {
  Expect(DSR_COMPARE_BIN, "--out_dir=@OUT/c --methods=dsr,magic", "--methods");
  Expect(DSR_COMPARE_BIN, "--out_dir=@OUT/c --init=random", "--init");
  Expect(DSR_COMPARE_BIN,
         "--out_dir=@OUT/c --init=global --max_misfit_ratio=0 --min_kept_overlap=0",
         "--max_recoveries");
  Expect(DSR_COMPARE_BIN, "--out_dir=@OUT/c --num_sequences=0", "--num_sequences");
  Expect(DSR_COMPARE_BIN, "--out_dir=@OUT/c --max_misfit_ratio=1", "--max_misfit_ratio");
  Expect(DSR_COMPARE_BIN, "--out_dir=@OUT/c --max_pair_mismatch_ratio=0.5",
         "--max_pair_mismatch_ratio");
  Expect(DSR_COMPARE_BIN, "--out_dir=@OUT/c --frame_size=8,8", "--frame_size");
  Expect(DSR_COMPARE_BIN, "--out_dir=@OUT/c --methods=dsr --sequences=" + In("no_such_folder"),
         "no_such_folder");
}

}  // namespace
}  // namespace dsr
