// The front ends of the application layer are an extension point: a new front end (here a
// small batch runner, as a cohort runner would be) makes its runs through dsr/app and gets
// exactly dsr_register's results and guards, with no code of the tools.
#include <filesystem>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "dsr/app/options.h"
#include "dsr/app/registration_run.h"
#include "dsr/app/run_options.h"
#include "dsr/app/simulation_run.h"
#include "dsr/io/io_frames.h"
#include "dsr/io/io_image.h"
#include "dsr/tests/support/cli_run.h"
#include "dsr/tests/support/scoped_temp_dir.h"

namespace dsr {
namespace {

namespace fs = std::filesystem;

// A sequence of 3 small frames written as dsr_simulate writes it.
std::string WriteSmallSequence(const fs::path& folder, uint64_t seed) {
  Settings settings;
  std::string error;
  for (const auto& [name, value] :
       {std::pair<const char*, const char*>{"num_frames", "3"}, {"phantom_size", "64"},
        {"frame_size", "32,32,28"}, {"max_rotation_deg", "6"}, {"max_translation_voxels", "3"},
        {"min_depth_voxels", "2"}, {"sigma", "10"}}) {
    EXPECT_TRUE(settings.Set(name, value, &error)) << error;
  }
  EXPECT_TRUE(settings.Set("seed", std::to_string(seed), &error)) << error;
  SimulationOptions options;
  PhantomOptions phantom;
  Image source;
  SimulatedSequence sequence;
  EXPECT_TRUE(SimulationOptionsFrom(settings, &options, &phantom, &error)) << error;
  EXPECT_TRUE(LoadSimulationSource(options, phantom, "", &source, &error)) << error;
  EXPECT_TRUE(Simulate(source, options, &sequence, &error)) << error;
  fs::create_directories(folder);
  EXPECT_TRUE(WriteSequence(folder.string(), options, sequence, nullptr, &error)) << error;
  return folder.string();
}

std::string FrameList(const std::string& folder, const char* kind) {
  std::string list;
  for (int f = 0; f < 3; ++f) {
    list += (f ? "," : "") + (fs::path(folder) /
                              (std::string(kind) == "frame" ? SimulatedFrameName(f)
                                                            : SimulatedMaskName(f))).string();
  }
  return list;
}

// The batch front end: one registration per sequence, every option from one Settings.
bool RegisterBatch(const std::vector<std::string>& folders, const fs::path& out,
                   std::string* error) {
  fs::create_directories(out);
  for (const std::string& folder : folders) {
    Settings settings;
    RegistrationOutputs outputs;
    outputs.poses = (out / (fs::path(folder).filename().string() + ".json")).string();
    if (!settings.Set("images", FrameList(folder, "frame"), error) ||
        !settings.Set("masks", FrameList(folder, "mask"), error) ||
        !settings.Set("pyramid_levels", "2", error) ||
        !settings.Set("pyramid_min_size", "8", error) || !settings.Set("progress", "0", error)) {
      return false;
    }
    RegistrationRun run(kDsrRegister);
    if (!run.PlanFiles(settings, outputs, error) || !run.ReadFiles(error) ||
        !run.Check(error) || !run.Run(error) || !run.result().usable || !run.Write(error)) {
      return false;
    }
  }
  return true;
}

TEST(AppFrontEnds, ABatchRunnerGetsDsrRegistersPosesByteForByte) {
  ScopedTempDir dir;
  const fs::path root(dir.path());
  const std::vector<std::string> folders = {WriteSmallSequence(root / "s1", 1),
                                            WriteSmallSequence(root / "s2", 2)};
  std::string error;
  ASSERT_TRUE(RegisterBatch(folders, root / "batch", &error)) << error;
  for (const std::string& folder : folders) {
    const std::string name = fs::path(folder).filename().string();
    const std::string cli = (root / (name + "_cli.json")).string();
    const testing_cli::ToolRun run = testing_cli::RunTool(
        DSR_REGISTER_BIN,
        "--images=" + FrameList(folder, "frame") + " --masks=" + FrameList(folder, "mask") +
            " --pyramid_levels=2 --pyramid_min_size=8 --progress=false --out_poses=" + cli,
        root);
    ASSERT_EQ(run.exit_code, 0) << run.err;
    EXPECT_EQ(testing_cli::ReadText(root / "batch" / (name + ".json")), testing_cli::ReadText(cli));
  }
}

TEST(AppFrontEnds, FramesInMemoryGiveTheFilesPoses) {
  ScopedTempDir dir;
  const std::string folder = WriteSmallSequence(fs::path(dir.path()) / "s", 3);
  Settings settings;
  std::string error;
  ASSERT_TRUE(settings.Set("images", FrameList(folder, "frame"), &error));
  ASSERT_TRUE(settings.Set("masks", FrameList(folder, "mask"), &error));
  ASSERT_TRUE(settings.Set("pyramid_levels", "2", &error));
  ASSERT_TRUE(settings.Set("pyramid_min_size", "8", &error));
  RegistrationRun from_files(kPyRegister);
  ASSERT_TRUE(from_files.PlanFiles(settings, RegistrationOutputs(), &error) &&
              from_files.ReadFiles(&error) && from_files.Check(&error) && from_files.Run(&error))
      << error;
  std::vector<Image> images;
  std::vector<Mask> masks;
  std::vector<MaskRule> rules;
  ASSERT_TRUE(ReadFrames(from_files.image_paths(), {}, FieldOfViewOptions(), 0, &images, &masks,
                         &rules, &error));
  masks.clear();
  for (int f = 0; f < 3; ++f) {
    Mask mask;
    ASSERT_TRUE(ReadMask((fs::path(folder) / SimulatedMaskName(f)).string(), images[f].geometry,
                         &mask, &error));
    masks.push_back(mask);
  }
  RegistrationRun in_memory(kPyRegister);
  ASSERT_TRUE(in_memory.SetFrames(settings, images, masks, {}, from_files.names(), {}, &error) &&
              in_memory.Check(&error) && in_memory.Run(&error))
      << error;
  ASSERT_TRUE(from_files.result().usable && in_memory.result().usable);
  for (int f = 0; f < 3; ++f) {
    EXPECT_TRUE(from_files.result().frame_from_world[f].matrix() ==
                in_memory.result().frame_from_world[f].matrix());
  }
}

// Its guards are the command line's: an output that would replace an input is refused
// before anything is read.
TEST(AppFrontEnds, TheRunsGuardsHoldForEveryFrontEnd) {
  ScopedTempDir dir;
  const std::string folder = WriteSmallSequence(fs::path(dir.path()) / "s", 4);
  Settings settings;
  std::string error;
  ASSERT_TRUE(settings.Set("images", FrameList(folder, "frame"), &error));
  RegistrationOutputs outputs;
  outputs.poses = (fs::path(folder) / SimulatedFrameName(1)).string();
  RegistrationRun run(kPyRegister);
  EXPECT_FALSE(run.PlanFiles(settings, outputs, &error));
  EXPECT_NE(error.find("inputs are never overwritten"), std::string::npos) << error;
}

}  // namespace
}  // namespace dsr
