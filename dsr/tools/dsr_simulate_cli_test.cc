// dsr_simulate's command line (tools/dsr_simulate.cc): runs the built binary
// (DSR_SIMULATE_BIN, set by CMake) and checks its files, exit codes and error lines.
#include <sys/wait.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "dsr/tests/support/cli_run.h"
#include "dsr/io/io_image.h"
#include "dsr/io/io_phases.h"
#include "dsr/io/io_poses.h"
#include "dsr/sim/simulate.h"
#include "dsr/tests/support/scoped_temp_dir.h"

namespace dsr {
namespace {

namespace fs = std::filesystem;

using testing_cli::ReadText;
using testing_cli::RunTool;
using testing_cli::ToolRun;

class DsrSimulateCli : public ::testing::Test {
 protected:
  // Runs the binary with `args` (each a single shell word, no quoting needed here).
  ToolRun Simulate(const std::string& args) { return RunTool(DSR_SIMULATE_BIN, args, dir_); }

  // A tiny, fast configuration that fits a 48^3 phantom.
  static std::string Tiny() {
    return "--phantom_size=48 --frame_size=20,20,16 --num_frames=3 --max_rotation_deg=5 "
           "--max_translation_voxels=2 --min_depth_voxels=2";
  }
  // Tiny()'s sequence options for the library (the phantom aside), noise-free.
  static SimulationOptions TinyOptions() {
    SimulationOptions o;
    o.frame_size = Eigen::Vector3i(20, 20, 16);
    o.num_frames = 3;
    o.max_rotation_deg = 5.0;
    o.max_translation_voxels = 2.0;
    o.min_depth_voxels = 2.0;
    o.sigma = 0.0;
    return o;
  }

  // A folder per test (the fixture is made anew for each).
  const ScopedTempDir temp_{"dsr_simulate_cli_test"};
  const fs::path dir_ = temp_.dir();
};

TEST_F(DsrSimulateCli, TinyRunWritesFramesMasksAndPoses) {
  const fs::path out = dir_ / "new" / "run";  // created, two levels
  const ToolRun run =
      Simulate("--out_dir=" + out.string() + " " + Tiny() + " --write_source --seed=7 --v=1");
  ASSERT_EQ(run.exit_code, 0) << run.err;
  EXPECT_NE(run.out.find("wrote 3 frames of 20x20x16"), std::string::npos) << run.out;
  EXPECT_NE(run.err.find("flags:"), std::string::npos) << "flags are logged at --v=1";
  EXPECT_NE(run.err.find("--num_frames=3"), std::string::npos);

  PosesFile poses;
  std::string error;
  ASSERT_TRUE(ReadPoses((out / "gt_poses.json").string(), 3, &poses, &error)) << error;
  EXPECT_TRUE(poses.gain.empty()) << "no gain or offset without --gain_range/--offset_range";
  EXPECT_TRUE(poses.offset.empty());
  for (int f = 0; f < 3; ++f) {
    const std::string frame_name = "frame_0" + std::to_string(f) + ".nii.gz";
    EXPECT_EQ(poses.images[f], frame_name);
    Image frame;
    ASSERT_TRUE(ReadImage((out / frame_name).string(), &frame, &error)) << error;
    EXPECT_EQ(frame.geometry.size, Eigen::Vector3i(20, 20, 16));
    EXPECT_TRUE(frame.geometry.spacing_mm.isApprox(Eigen::Vector3d::Ones()));
    Mask mask;
    ASSERT_TRUE(ReadMask(
        (out / ("mask_0" + std::to_string(f) + ".nii.gz")).string(), frame.geometry, &mask, &error))
        << error;
    // Mask voxels lie in the field of view, where intensities are non-zero except where
    // noise was clamped at 0 (dark blood pools).
    int64_t inside = 0, zero_inside = 0;
    for (size_t v = 0; v < mask.voxels.size(); ++v) {
      if (!mask.voxels[v]) continue;
      ++inside;
      zero_inside += frame.voxels[v] == 0.0f;
    }
    EXPECT_GT(inside, 500);
    EXPECT_LT(zero_inside, inside / 5);
  }
  Image source;
  ASSERT_TRUE(ReadImage((out / "source.nii.gz").string(), &source, &error)) << error;
  EXPECT_EQ(source.geometry.size, Eigen::Vector3i(48, 48, 48));

  // Same flags, same sequence.
  const fs::path again = dir_ / "again";
  ASSERT_EQ(Simulate("--out_dir=" + again.string() + " " + Tiny() + " --seed=7").exit_code, 0);
  EXPECT_EQ(ReadText(out / "gt_poses.json"), ReadText(again / "gt_poses.json"));
  Image a, b;
  ASSERT_TRUE(ReadImage((out / "frame_02.nii.gz").string(), &a, &error));
  ASSERT_TRUE(ReadImage((again / "frame_02.nii.gz").string(), &b, &error));
  EXPECT_EQ(a.voxels, b.voxels);
}

TEST_F(DsrSimulateCli, WalkAndMaskErosionReachTheSimulator) {
  const fs::path random = dir_ / "random", walk = dir_ / "walk";
  ASSERT_EQ(Simulate("--out_dir=" + random.string() + " " + Tiny() + " --seed=5").exit_code, 0);
  const ToolRun run = Simulate("--out_dir=" + walk.string() + " " + Tiny() +
                               " --seed=5 --pose_model=walk --step_rotation_deg=3 "
                               "--step_translation_voxels=1 --mask_erosion=0");
  ASSERT_EQ(run.exit_code, 0) << run.err;
  PosesFile random_poses, walk_poses;
  std::string error;
  ASSERT_TRUE(ReadPoses((random / "gt_poses.json").string(), 3, &random_poses, &error)) << error;
  ASSERT_TRUE(ReadPoses((walk / "gt_poses.json").string(), 3, &walk_poses, &error)) << error;
  // Frame 0 is drawn alike; then each frame is within one step of the previous (the frame
  // centre in the world moves <= 1 voxel of 1 mm, the rotation <= 3 degrees). The JSON
  // round trip keeps the 17 significant digits.
  EXPECT_TRUE(walk_poses.frame_from_world[0].isApprox(random_poses.frame_from_world[0], 1e-12));
  const Eigen::Vector3d center(9.5, 9.5, 7.5);  // of the 20x20x16 frame at 1 mm, origin 0
  for (int f = 1; f < 3; ++f) {
    const Eigen::Isometry3d& previous = walk_poses.frame_from_world[f - 1];
    const Eigen::Isometry3d& next = walk_poses.frame_from_world[f];
    EXPECT_LE((next.inverse() * center - previous.inverse() * center).norm(), 1.0 + 1e-9);
    EXPECT_LE(Eigen::AngleAxisd(next.linear().transpose() * previous.linear()).angle(),
              3.0 * M_PI / 180.0 + 1e-9);
  }
  // --mask_erosion=0: the masks are the exact field of view.
  SimulationOptions o;
  o.frame_size = Eigen::Vector3i(20, 20, 16);
  o.min_depth_voxels = 2.0;
  ImageGeometry g;
  g.size = o.frame_size;
  const Mask fov = PyramidFieldOfView(g, o);
  for (const fs::path& folder : {random, walk}) {
    Mask mask;
    ASSERT_TRUE(ReadMask((folder / "mask_01.nii.gz").string(), g, &mask, &error)) << error;
    EXPECT_EQ(mask.voxels, (folder == walk ? fov : ErodeFieldOfView(fov, 1)).voxels) << folder;
  }
}

TEST_F(DsrSimulateCli, InterpolationReachesTheSimulator) {
  // The cubic run's frames are the library's cubic frames of the written source, and differ
  // from the default (linear) run's.
  const fs::path linear = dir_ / "linear", cubic = dir_ / "cubic";
  const std::string common = " " + Tiny() + " --sigma=0 --write_source";
  ASSERT_EQ(Simulate("--out_dir=" + linear.string() + common).exit_code, 0);
  const ToolRun run = Simulate("--out_dir=" + cubic.string() + common + " --interpolation=cubic");
  ASSERT_EQ(run.exit_code, 0) << run.err;
  std::string error;
  Image source;
  ASSERT_TRUE(ReadImage((cubic / "source.nii.gz").string(), &source, &error)) << error;
  SimulationOptions o = TinyOptions();
  o.interpolation = SourceInterpolation::kCubic;
  SimulatedSequence expected;
  ASSERT_TRUE(dsr::Simulate(source, o, &expected, &error)) << error;
  for (int f = 0; f < 3; ++f) {
    const std::string name = "frame_0" + std::to_string(f) + ".nii.gz";
    Image from_linear, from_cubic;
    ASSERT_TRUE(ReadImage((linear / name).string(), &from_linear, &error)) << error;
    ASSERT_TRUE(ReadImage((cubic / name).string(), &from_cubic, &error)) << error;
    EXPECT_EQ(from_cubic.voxels, expected.frames[f].voxels) << name;
    EXPECT_NE(from_cubic.voxels, from_linear.voxels) << name;
  }
}

TEST_F(DsrSimulateCli, IntensityMappingReachesTheSimulator) {
  // The echo run's frames are the library's echo frames of the written source (which is
  // the source as read, not its map), with every echo_ flag passed through, and differ from
  // the default run's.
  const fs::path plain = dir_ / "plain", echo = dir_ / "echo";
  const std::string common = " " + Tiny() + " --sigma=0 --write_source";
  ASSERT_EQ(Simulate("--out_dir=" + plain.string() + common).exit_code, 0);
  const ToolRun run = Simulate("--out_dir=" + echo.string() + common +
                               " --intensity_mapping=echo --echo_reject=60 "
                               "--echo_edge_sigma_mm=1.5 --echo_edge_weight=0.5");
  ASSERT_EQ(run.exit_code, 0) << run.err;
  std::string error;
  Image source, plain_source;
  ASSERT_TRUE(ReadImage((echo / "source.nii.gz").string(), &source, &error)) << error;
  ASSERT_TRUE(ReadImage((plain / "source.nii.gz").string(), &plain_source, &error)) << error;
  EXPECT_EQ(source.voxels, plain_source.voxels);
  SimulationOptions o = TinyOptions();
  o.intensity_mapping = IntensityMapping::kEcho;
  o.echo_reject = 60.0;
  o.echo_edge_sigma_mm = 1.5;
  o.echo_edge_weight = 0.5;
  SimulatedSequence expected, defaults;
  ASSERT_TRUE(dsr::Simulate(source, o, &expected, &error)) << error;
  SimulationOptions d = TinyOptions();
  d.intensity_mapping = IntensityMapping::kEcho;
  ASSERT_TRUE(dsr::Simulate(source, d, &defaults, &error)) << error;
  for (int f = 0; f < 3; ++f) {
    const std::string name = "frame_0" + std::to_string(f) + ".nii.gz";
    Image from_plain, from_echo;
    ASSERT_TRUE(ReadImage((plain / name).string(), &from_plain, &error)) << error;
    ASSERT_TRUE(ReadImage((echo / name).string(), &from_echo, &error)) << error;
    EXPECT_EQ(from_echo.voxels, expected.frames[f].voxels) << name;
    EXPECT_NE(from_echo.voxels, defaults.frames[f].voxels) << name << ": the echo_ flags count";
    EXPECT_NE(from_echo.voxels, from_plain.voxels) << name;
  }
}

TEST_F(DsrSimulateCli, EffectsReachTheSimulatorAndGainsAndOffsetsGoToTheGroundTruth) {
  // The frames are the library's frames of the written source with the same effects, and
  // gt_poses.json holds the corrections to frame 0's scale (exact through JSON).
  const fs::path effects = dir_ / "effects";
  const ToolRun run = Simulate("--out_dir=" + effects.string() + " " + Tiny() +
                               " --sigma=0 --write_source --seed=4 --gain_range=0.25 "
                               "--offset_range=15 --speckle_looks=2 "
                               "--speckle_correlation_voxels=0.8 --attenuation_db_per_cm=4");
  ASSERT_EQ(run.exit_code, 0) << run.err;
  std::string error;
  Image source;
  ASSERT_TRUE(ReadImage((effects / "source.nii.gz").string(), &source, &error)) << error;
  SimulationOptions o = TinyOptions();
  o.seed = 4;
  o.gain_range = 0.25;
  o.offset_range = 15.0;
  o.speckle_looks = 2;
  o.speckle_correlation_voxels = 0.8;
  o.attenuation_db_per_cm = 4.0;
  SimulatedSequence expected;
  ASSERT_TRUE(dsr::Simulate(source, o, &expected, &error)) << error;
  for (int f = 0; f < 3; ++f) {
    const std::string name = "frame_0" + std::to_string(f) + ".nii.gz";
    Image frame;
    ASSERT_TRUE(ReadImage((effects / name).string(), &frame, &error)) << error;
    EXPECT_EQ(frame.voxels, expected.frames[f].voxels) << name;
  }
  std::vector<double> gain, offset;
  Frame0IntensityCorrections(expected.gain, expected.offset, &gain, &offset);
  PosesFile poses;
  ASSERT_TRUE(ReadPoses((effects / "gt_poses.json").string(), 3, &poses, &error)) << error;
  EXPECT_EQ(poses.gain, gain);
  EXPECT_EQ(poses.offset, offset);
  EXPECT_EQ(poses.gain[0], 1.0);
  EXPECT_EQ(poses.offset[0], 0.0);
  EXPECT_NE(poses.gain[1], 1.0);

  // Only the gain: both fields still written (offsets 0 after frame 0's gauge).
  const fs::path gain_only = dir_ / "gain_only";
  ASSERT_EQ(
      Simulate("--out_dir=" + gain_only.string() + " " + Tiny() + " --gain_range=0.1").exit_code,
      0);
  ASSERT_TRUE(ReadPoses((gain_only / "gt_poses.json").string(), 3, &poses, &error)) << error;
  EXPECT_EQ(poses.gain.size(), 3u);
  EXPECT_EQ(poses.offset, std::vector<double>(3, 0.0));

  // The world fraction reaches the library (the frames are its frames) and the log.
  const fs::path world = dir_ / "world";
  const ToolRun world_run = Simulate("--out_dir=" + world.string() + " " + Tiny() +
                                     " --sigma=0 --write_source --seed=4 --speckle_looks=2 "
                                     "--speckle_world_fraction=0.5 --v=1");
  ASSERT_EQ(world_run.exit_code, 0) << world_run.err;
  EXPECT_NE(world_run.err.find("--speckle_world_fraction=0.5"), std::string::npos)
      << "flags are logged at --v=1";
  ASSERT_TRUE(ReadImage((world / "source.nii.gz").string(), &source, &error)) << error;
  SimulationOptions w = TinyOptions();
  w.seed = 4;
  w.speckle_looks = 2;
  w.speckle_world_fraction = 0.5;
  SimulatedSequence world_expected;
  ASSERT_TRUE(dsr::Simulate(source, w, &world_expected, &error)) << error;
  w.speckle_world_fraction = 0.0;
  SimulatedSequence frame_only;
  ASSERT_TRUE(dsr::Simulate(source, w, &frame_only, &error)) << error;
  for (int f = 0; f < 3; ++f) {
    const std::string name = "frame_0" + std::to_string(f) + ".nii.gz";
    Image frame;
    ASSERT_TRUE(ReadImage((world / name).string(), &frame, &error)) << error;
    EXPECT_EQ(frame.voxels, world_expected.frames[f].voxels) << name;
    EXPECT_NE(frame.voxels, frame_only.frames[f].voxels) << name;
  }

  // Speckle and attenuation alone change no intensity scale: no such fields.
  const fs::path speckle_only = dir_ / "speckle_only";
  ASSERT_EQ(Simulate("--out_dir=" + speckle_only.string() + " " + Tiny() +
                     " --speckle_looks=1 --attenuation_db_per_cm=1")
                .exit_code,
            0);
  const std::string text = ReadText(speckle_only / "gt_poses.json");
  EXPECT_EQ(text.find("\"gain\""), std::string::npos) << text;
  EXPECT_EQ(text.find("\"offset\""), std::string::npos) << text;
  ASSERT_TRUE(ReadPoses((speckle_only / "gt_poses.json").string(), 3, &poses, &error)) << error;
  EXPECT_TRUE(poses.gain.empty());
  EXPECT_TRUE(poses.offset.empty());
}

TEST_F(DsrSimulateCli, PhasesWriteEachViewAsA4DImage) {
  // Tiny()'s 16-voxel depth: the default beat radius is 4 mm, so 1 mm at most.
  const fs::path out = dir_ / "beating";
  const ToolRun run = Simulate("--out_dir=" + out.string() + " " + Tiny() +
                               " --sigma=5 --write_source --seed=3 --num_phases=3 "
                               "--beat_amplitude_mm=1");
  ASSERT_EQ(run.exit_code, 0) << run.err;
  EXPECT_NE(run.out.find("wrote 3 frames x 3 phases of 20x20x16"), std::string::npos) << run.out;
  std::string error;
  Image source;
  ASSERT_TRUE(ReadImage((out / "source.nii.gz").string(), &source, &error)) << error;
  SimulationOptions o = TinyOptions();
  o.sigma = 5.0;
  o.seed = 3;
  o.num_phases = 3;
  o.beat_amplitude_mm = 1.0;
  SimulatedSequence expected;
  ASSERT_TRUE(dsr::Simulate(source, o, &expected, &error)) << error;
  PosesFile poses;
  ASSERT_TRUE(ReadPoses((out / "gt_poses.json").string(), 3, &poses, &error)) << error;
  for (int f = 0; f < 3; ++f) {
    const std::string name = "frame_0" + std::to_string(f) + ".nii.gz";
    EXPECT_EQ(poses.images[f], name);
    EXPECT_TRUE(poses.frame_from_world[f].isApprox(expected.frame_from_world[f], 1e-12));
    EXPECT_TRUE(fs::exists(out / ("mask_0" + std::to_string(f) + ".nii.gz")));
    std::vector<Image> phases;
    ASSERT_TRUE(ReadPhases((out / name).string(), &phases, &error)) << error;
    ASSERT_EQ(phases.size(), 3u) << name;
    for (int p = 0; p < 3; ++p) {
      EXPECT_EQ(phases[p].voxels, expected.Phase(f, p).voxels) << name << " phase " << p;
      EXPECT_TRUE(phases[p].geometry.SameGrid(expected.frames[f].geometry));
    }
    EXPECT_NE(expected.Phase(f, 1).voxels, expected.Phase(f, 0).voxels);
  }
  // The default 4 mm beat folds a 4 mm ball: refused before anything is written.
  const ToolRun folds = Simulate("--out_dir=" + (dir_ / "folds").string() + " " + Tiny() +
                                 " --num_phases=2");
  EXPECT_EQ(folds.exit_code, 2) << folds.err;
  EXPECT_NE(folds.err.find("error: --beat_amplitude_mm=4: must be at most 0.25 times the beat's "
                           "radius, 4 mm (--beat_radius_mm=0: a quarter of the frame depth)"),
            std::string::npos)
      << folds.err;
  EXPECT_FALSE(fs::exists(dir_ / "folds"));
}

TEST_F(DsrSimulateCli, BadFlagsExitWithOneLineNamingTheFlag) {
  const std::string out = " --out_dir=" + (dir_ / "bad").string();
  struct Case {
    std::string args, expected;
  };
  const Case cases[] = {
      {"--num_frames=1" + out, "--num_frames=1: must be in [2, 1000]"},
      {"--sigma=-1" + out, "--sigma=-1: must be finite and >= 0"},
      {"--frame_size=96,96" + out, "--frame_size=96,96: must be three integers"},
      {"--frame_size=96,x,80" + out, "--frame_size=96,x,80"},
      {"--azimuth_deg=180" + out, "--azimuth_deg=180: must be in (0, 180)"},
      {"--max_rotation_deg=200" + out, "--max_rotation_deg=200"},
      {"--phantom_size=8" + out, "--phantom_size=8: must be in [16, 512]"},
      {"--pose_model=spiral" + out, "--pose_model=spiral: must be random or walk"},
      {"--pose_model=" + out, "--pose_model=: must be random or walk"},
      {"--interpolation=bspline" + out, "--interpolation=bspline: must be linear or cubic"},
      {"--interpolation=" + out, "--interpolation=: must be linear or cubic"},
      {"--step_rotation_deg=181" + out, "--step_rotation_deg=181: must be in [0, 180]"},
      {"--step_translation_voxels=-2" + out,
       "--step_translation_voxels=-2: must be finite and >= 0"},
      {"--mask_erosion=-1" + out, "--mask_erosion=-1: must be in [0, 50]"},
      {"--mask_erosion=51" + out, "--mask_erosion=51: must be in [0, 50]"},
      {"--gain_range=1" + out, "--gain_range=1: must be in [0, 0.9]"},
      {"--gain_range=-0.5" + out, "--gain_range=-0.5: must be in [0, 0.9]"},
      {"--offset_range=101" + out, "--offset_range=101: must be in [0, 100]"},
      {"--speckle_looks=65" + out, "--speckle_looks=65: must be 0 (no speckle) or in [1, 64]"},
      {"--speckle_looks=-1" + out, "--speckle_looks=-1: must be 0 (no speckle) or in [1, 64]"},
      {"--speckle_correlation_voxels=5" + out,
       "--speckle_correlation_voxels=5: must be in [0, 4]"},
      {"--speckle_world_fraction=1.5 --speckle_looks=2" + out,
       "--speckle_world_fraction=1.5: must be in [0, 1]"},
      {"--speckle_world_fraction=-0.2 --speckle_looks=2" + out,
       "--speckle_world_fraction=-0.2: must be in [0, 1]"},
      {"--speckle_world_fraction=nan --speckle_looks=2" + out,
       "--speckle_world_fraction=nan: must be in [0, 1]"},
      {"--speckle_world_fraction=0.5" + out,
       "--speckle_world_fraction=0.5: needs speckle, but --speckle_looks=0"},
      {"--attenuation_db_per_cm=11" + out, "--attenuation_db_per_cm=11: must be in [0, 10]"},
      {"--attenuation_db_per_cm=nan" + out, "--attenuation_db_per_cm=nan: must be in [0, 10]"},
      {"--intensity_mapping=doppler" + out, "--intensity_mapping=doppler: must be none or echo"},
      {"--intensity_mapping=" + out, "--intensity_mapping=: must be none or echo"},
      {"--echo_reject=251" + out, "--echo_reject=251: must be in [0, 250]"},
      {"--echo_reject=-1" + out, "--echo_reject=-1: must be in [0, 250]"},
      {"--echo_edge_sigma_mm=21" + out, "--echo_edge_sigma_mm=21: must be in [0, 20]"},
      {"--echo_edge_sigma_mm=nan" + out, "--echo_edge_sigma_mm=nan: must be in [0, 20]"},
      {"--echo_edge_weight=1.5" + out, "--echo_edge_weight=1.5: must be in [0, 1]"},
      {"--echo_edge_weight=-0.1" + out, "--echo_edge_weight=-0.1: must be in [0, 1]"},
      {"--num_phases=0" + out, "--num_phases=0: must be in [1, 64]"},
      {"--num_phases=65" + out, "--num_phases=65: must be in [1, 64]"},
      {"--beat_amplitude_mm=51" + out, "--beat_amplitude_mm=51: must be in [0, 50]"},
      {"--beat_amplitude_mm=nan" + out, "--beat_amplitude_mm=nan: must be in [0, 50]"},
      {"--beat_radius_mm=-1" + out, "--beat_radius_mm=-1: must be 0 or in [0.001, 1e+06]"},
      {"--num_phases=2 --beat_radius_mm=10 --beat_amplitude_mm=3" + out,
       "--beat_amplitude_mm=3: must be at most 0.25 --beat_radius_mm=10 (a larger beat would "
       "fold the tissue)"},
      {"--num_frames=abc" + out, "num_frames"},
      {"--no_such_flag=1" + out, "no_such_flag"},
      {"--source=" + (dir_ / "missing.nii.gz").string() + out, "missing.nii.gz: no such file"},
      {"--source=" + dir_.string() + out, "not a regular file"},
      {"", "--out_dir is required"},
      {"extra_argument" + out, "unexpected argument 'extra_argument'"},
  };
  for (const Case& c : cases) {
    const ToolRun run = Simulate(c.args);
    EXPECT_EQ(run.exit_code, 2) << c.args << "\n" << run.err;
    ASSERT_EQ(run.err_lines.size(), 1u) << c.args << "\n" << run.err;
    EXPECT_NE(run.err_lines[0].find(c.expected), std::string::npos) << c.args << "\n" << run.err;
  }
  EXPECT_FALSE(fs::exists(dir_ / "bad")) << "nothing is written on bad input";
}

TEST_F(DsrSimulateCli, BadInputFoundAfterStartExitsWithOneErrorLine) {
  // These are found after the flags are logged: one error line among glog's INFO lines.
  std::ofstream(dir_ / "corrupt.nii.gz") << "not an image";
  std::ofstream(dir_ / "file") << "a file where a folder is needed";
  const std::string out = " --out_dir=" + (dir_ / "out").string();
  struct Case {
    std::string args, expected;
  };
  const Case cases[] = {
      {"--source=" + (dir_ / "corrupt.nii.gz").string() + out, "corrupt.nii.gz"},
      {"--min_depth_voxels=90" + out,
       "a frame depth of 80 leaves no field of view below --min_depth_voxels=90"},
      // The frame too thin for the default cut: --frame_size is named too.
      {"--frame_size=4,4,4" + out, "--frame_size=4,4,4: a frame depth of 4 leaves no field"},
      {"--phantom_size=40" + out, "outside the source grid"},
      {"--mask_erosion=20 --frame_size=20,20,16 --min_depth_voxels=2" + out,
       "empty after the 20-voxel erosion (--mask_erosion)"},
      {"--out_dir=" + (dir_ / "file" / "sub").string() + " " + Tiny(), "cannot create the folder"},
  };
  for (const Case& c : cases) {
    const ToolRun run = Simulate(c.args);
    EXPECT_EQ(run.exit_code, 2) << c.args << "\n" << run.err;
    const std::vector<std::string>& errors = run.error_lines;
    ASSERT_EQ(errors.size(), 1u) << c.args << "\n" << run.err;
    EXPECT_NE(errors[0].find("dsr_simulate: error: "), std::string::npos) << errors[0];
    EXPECT_NE(errors[0].find(c.expected), std::string::npos) << c.args << "\n" << run.err;
  }
}

TEST_F(DsrSimulateCli, HelpDocumentsEveryFlag) {
  for (const char* help : {"--helpshort", "--help"}) {
    const ToolRun run = Simulate(help);
    EXPECT_EQ(run.exit_code, 0) << help;
    for (const char* flag : {"out_dir",
                             "source",
                             "seed",
                             "num_frames",
                             "sigma",
                             "max_rotation_deg",
                             "max_translation_voxels",
                             "pose_model",
                             "step_rotation_deg",
                             "step_translation_voxels",
                             "frame_size",
                             "frame_spacing",
                             "azimuth_deg",
                             "elevation_deg",
                             "min_depth_voxels",
                             "phantom_size",
                             "phantom_seed",
                             "mask_erosion",
                             "interpolation",
                             "gain_range",
                             "offset_range",
                             "speckle_looks",
                             "speckle_correlation_voxels",
                             "speckle_world_fraction",
                             "attenuation_db_per_cm",
                             "intensity_mapping",
                             "echo_reject",
                             "echo_edge_sigma_mm",
                             "echo_edge_weight",
                             "write_source"}) {
      EXPECT_NE(run.out.find(std::string("-") + flag + " ("), std::string::npos)
          << help << " lacks --" << flag;
    }
  }
}

}  // namespace
}  // namespace dsr
