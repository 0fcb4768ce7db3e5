// The tools' shared flags layer (tools/flags/flags.h): each tool links and lists only its
// own flags, per-tool defaults, and the flags dsr_compare gained from it.
#include <filesystem>
#include <string>

#include <gtest/gtest.h>

#include "dsr/tests/support/cli_run.h"
#include "dsr/tests/support/scoped_temp_dir.h"

namespace dsr {
namespace {

using testing_cli::ReadText;
using testing_cli::RunTool;
using testing_cli::ToolRun;

bool Lists(const ToolRun& help, const std::string& flag) {
  return help.out.find("    -" + flag + " (") != std::string::npos;
}

TEST(ToolFlags, EachToolListsItsOwnAndItsSharedFlagsOnly) {
  ScopedTempDir dir;
  const ToolRun simulate = RunTool(DSR_SIMULATE_BIN, "--helpshort", dir.path());
  const ToolRun registration = RunTool(DSR_REGISTER_BIN, "--helpshort", dir.path());
  const ToolRun fuse = RunTool(DSR_FUSE_BIN, "--helpshort", dir.path());
  const ToolRun compare = RunTool(DSR_COMPARE_BIN, "--helpshort", dir.path());
  for (const ToolRun* run : {&simulate, &registration, &fuse, &compare}) {
    EXPECT_EQ(run->exit_code, 0) << run->err;
    EXPECT_TRUE(Lists(*run, "mask_erosion")) << run->out;  // shared by all four
  }
  // --mask_rule: only the tools that make masks from images (the simulator's are exact).
  EXPECT_FALSE(Lists(simulate, "mask_rule"));
  for (const ToolRun* run : {&registration, &fuse, &compare}) {
    EXPECT_TRUE(Lists(*run, "mask_rule")) << run->out;
  }
  EXPECT_TRUE(Lists(simulate, "speckle_looks"));
  EXPECT_FALSE(Lists(simulate, "images"));
  EXPECT_FALSE(Lists(simulate, "pyramid_levels"));
  EXPECT_TRUE(Lists(registration, "pyramid_levels"));
  EXPECT_TRUE(Lists(registration, "images"));
  EXPECT_FALSE(Lists(registration, "speckle_looks"));
  EXPECT_TRUE(Lists(fuse, "panorama_spacing"));
  EXPECT_FALSE(Lists(fuse, "pyramid_levels"));
  EXPECT_FALSE(Lists(fuse, "mode"));
  EXPECT_TRUE(Lists(compare, "pyramid_levels"));
  EXPECT_TRUE(Lists(compare, "speckle_looks"));
  // The echo-like mapping: with the simulation's flags, not the registration's.
  EXPECT_TRUE(Lists(simulate, "intensity_mapping"));
  EXPECT_TRUE(Lists(compare, "echo_edge_weight"));
  EXPECT_FALSE(Lists(registration, "intensity_mapping"));
  EXPECT_FALSE(Lists(compare, "images"));
  EXPECT_FALSE(Lists(compare, "mode"));
  // dsr_compare's own defaults: the paper's start, checks off.
  EXPECT_NE(compare.out.find("default: \"identity\""), std::string::npos);
  EXPECT_NE(registration.out.find("default: \"auto\""), std::string::npos);
}

TEST(ToolFlags, SharedValidatorsNameTheFlagInEveryTool) {
  ScopedTempDir dir;
  for (const char* tool : {DSR_REGISTER_BIN, DSR_FUSE_BIN, DSR_COMPARE_BIN}) {
    const ToolRun run = RunTool(tool, "--panorama_spacing=0", dir.path());
    EXPECT_EQ(run.exit_code, 2) << tool;
    ASSERT_EQ(run.error_lines.size(), 1u) << run.err;
    EXPECT_NE(run.error_lines[0].find("--panorama_spacing=0: must be in [0.001, 1000]"),
              std::string::npos)
        << run.error_lines[0];
  }
}

TEST(ToolFlags, KernelsNameAPathThisCpuRuns) {
  ScopedTempDir dir;
  for (const char* tool : {DSR_REGISTER_BIN, DSR_COMPARE_BIN}) {
    const ToolRun run = RunTool(tool, "--kernels=avx3", dir.path());
    EXPECT_EQ(run.exit_code, 2) << tool;
    ASSERT_EQ(run.error_lines.size(), 1u) << run.err;
    EXPECT_NE(run.error_lines[0].find("--kernels=avx3: must be auto|portable|avx2|avx512"),
              std::string::npos)
        << run.error_lines[0];
  }
}

// A library's failure names option fields (util/option_fields.h); the tools print and write
// it with their flags, in the log and in dsr_compare's results.csv alike.
TEST(ToolFlags, FailuresNameTheFlagsInTheLogAndTheResults) {
  ScopedTempDir dir;
  const ToolRun run = RunTool(DSR_COMPARE_BIN,
                              "--out_dir=" + dir.File("c") +
                                  " --methods=dsr --num_sequences=1 --num_frames=3 "
                                  "--pyramid_levels=1 --phantom_size=64 --frame_size=28,28,24 "
                                  "--max_translation_voxels=3 --max_rotation_deg=3 "
                                  "--max_misfit_ratio=1.01",
                              dir.path());
  ASSERT_EQ(run.exit_code, 0) << run.err;
  const std::string csv = ReadText(dir.File("c") + "/results.csv");
  EXPECT_NE(csv.find("does not match the others"), std::string::npos) << csv;
  EXPECT_NE(csv.find("--max_misfit_ratio=1.01)"), std::string::npos) << csv;
  EXPECT_NE(csv.find("(--init)"), std::string::npos) << csv;
  EXPECT_NE(run.err.find("--max_misfit_ratio=1.01)"), std::string::npos) << run.err;
}

TEST(ToolFlags, CompareSimulatesFromASourceAndRefusesOneWithSequences) {
  ScopedTempDir dir;
  const std::string sequence = dir.File("sequence");
  const std::string small = "--frame_size=28,28,24 --max_translation_voxels=3 --max_rotation_deg=3";
  ToolRun run = RunTool(DSR_SIMULATE_BIN,
                        "--out_dir=" + sequence + " --num_frames=3 --phantom_size=64 " + small +
                            " --write_source",
                        dir.path());
  ASSERT_EQ(run.exit_code, 0) << run.err;
  const std::string source = sequence + "/source.nii.gz";
  run = RunTool(DSR_COMPARE_BIN,
                "--out_dir=" + dir.File("a") + " --sequences=" + sequence + " --source=" + source,
                dir.path());
  EXPECT_EQ(run.exit_code, 2);
  ASSERT_EQ(run.error_lines.size(), 1u) << run.err;
  EXPECT_NE(run.error_lines[0].find("--source=" + source), std::string::npos) << run.err;
  EXPECT_FALSE(std::filesystem::exists(dir.File("a")));
  // The source read as a file gives the sequence the phantom gives (same voxels, seed).
  for (const std::string& from : {std::string("--phantom_size=64"), "--source=" + source}) {
    run = RunTool(DSR_COMPARE_BIN,
                  "--out_dir=" + dir.File("b") + " --methods=dsr --num_sequences=1 " +
                      "--num_frames=3 --pyramid_levels=1 " + small + " " + from,
                  dir.path());
    ASSERT_EQ(run.exit_code, 0) << from << "\n" << run.err;
    EXPECT_NE(ReadText(dir.File("b") + "/results.csv").find(",seed1,"), std::string::npos);
    std::filesystem::rename(dir.File("b"), dir.File(from.substr(2, 6)));
  }
  EXPECT_EQ(ReadText(dir.File("phanto") + "/poses/seed1_dsr.json"),
            ReadText(dir.File("source") + "/poses/seed1_dsr.json"));
}

}  // namespace
}  // namespace dsr
