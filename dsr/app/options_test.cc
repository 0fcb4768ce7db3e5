// The options table and Settings (dsr/app/options.h), flagfiles (dsr/app/flagfile.h) and
// the options a run is made with (dsr/app/run_options.h).
#include "dsr/app/options.h"

#include <filesystem>
#include <fstream>
#include <map>
#include <regex>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "dsr/app/flagfile.h"
#include "dsr/app/run_options.h"
#include "dsr/tests/support/scoped_temp_dir.h"

namespace dsr {
namespace {

TEST(OptionTable, NamesAreUniqueAndEveryDefaultKeepsItsRule) {
  std::set<std::string> names;
  for (const OptionSpec& spec : OptionTable()) {
    EXPECT_TRUE(names.insert(spec.name).second) << spec.name << " declared twice";
    EXPECT_NE(spec.front_ends, 0u) << spec.name << " belongs to no front end";
    EXPECT_GT(std::string(spec.help).size(), 10u) << spec.name << " has no help";
    OptionValue value;
    std::string error;
    EXPECT_TRUE(ParseOptionValue(spec, spec.default_text, &value, &error)) << error;
    EXPECT_EQ(OptionValueText(value), OptionValueText(Settings().Value(spec.name)));
    EXPECT_EQ(FindOption(spec.name), &spec);
  }
  EXPECT_EQ(FindOption("no_such_option"), nullptr);
}

// Every option that writes a field has the library's default: the value its member
// initialiser writes, so that a caller of the library and a user of the tools get the same
// registration.
TEST(OptionTable, EveryFieldsDefaultIsTheLibrarys) {
  int fields = 0;
  for (const OptionSpec& spec : OptionTable()) {
    if (spec.keeps_library_default == nullptr) continue;
    ++fields;
    OptionValue value;
    std::string error;
    ASSERT_TRUE(ParseOptionValue(spec, spec.default_text, &value, &error)) << error;
    EXPECT_TRUE(spec.keeps_library_default(value))
        << "--" << spec.name << "'s default " << spec.default_text
        << " is not the library's (the member initialiser of its field)";
  }
  EXPECT_GT(fields, 60);
  // It can tell: another value than the initialiser's is not the library's default.
  const OptionSpec* levels = FindOption("pyramid_levels");
  ASSERT_NE(levels->keeps_library_default, nullptr);
  const int32_t other_levels = RegistrationOptions().pyramid_levels + 1;
  EXPECT_FALSE(levels->keeps_library_default(OptionValue(other_levels)));
  const OptionSpec* gauge = FindOption("gauge");
  ASSERT_NE(gauge->keeps_library_default, nullptr);
  EXPECT_FALSE(gauge->keeps_library_default(OptionValue(std::string("frame0"))));
}

// Every option the front ends read by name (settings.Int("num_frames"), ...) is in the
// table, and read with its type's accessor: a typo or a wrong type would otherwise abort a
// run only when it reaches that line.
TEST(OptionTable, EveryNameTheFrontEndsReadIsInTheTableWithItsType) {
  namespace fs = std::filesystem;
  const std::regex call(
      R"re((\.|->)(IsDefault|Value|Bool|Int|Uint64|Double|String|SetDefault|Set))re"
      R"re(\("([a-z0-9_]+)")re");
  const std::map<std::string, OptionType> typed = {{"Bool", OptionType::kBool},
                                                   {"Int", OptionType::kInt32},
                                                   {"Uint64", OptionType::kUint64},
                                                   {"Double", OptionType::kDouble},
                                                   {"String", OptionType::kString}};
  int reads = 0;
  for (const char* folder : {"dsr/app", "dsr/tools", "python/src"}) {
    for (const auto& entry : fs::recursive_directory_iterator(fs::path(DSR_SOURCE_DIR) / folder)) {
      const std::string path = entry.path().string();
      const std::string ext = entry.path().extension().string();
      if ((ext != ".cc" && ext != ".h") || path.find("_test") != std::string::npos) continue;
      std::ifstream in(path);
      std::stringstream text;
      text << in.rdbuf();
      const std::string source = text.str();
      for (std::sregex_iterator it(source.begin(), source.end(), call), end; it != end; ++it) {
        ++reads;
        const std::string accessor = (*it)[2], name = (*it)[3];
        const OptionSpec* spec = FindOption(name);
        ASSERT_NE(spec, nullptr) << path << ": reads \"" << name << "\", which the table lacks";
        const auto type = typed.find(accessor);
        if (type != typed.end()) {
          EXPECT_EQ(spec->type, type->second)
              << path << ": " << accessor << "(\"" << name << "\") does not read the option's type";
        }
      }
    }
  }
  EXPECT_GT(reads, 40);  // the front ends read about 50 options by name
}

// The table's defaults are the library's where the library names one for the tools.
TEST(OptionTable, DefaultsAreTheLibrarysToolDefaults) {
  const Settings settings;
  EXPECT_EQ(settings.Int("max_recoveries"), kDefaultMaxRecoveries);
  EXPECT_EQ(settings.String("photometric"), PhotometricModelToString(kDefaultPhotometricModel));
  const RunConfig config = ConfigFrom(settings);
  const RegistrationOptions library;
  EXPECT_EQ(config.registration.pyramid_levels, library.pyramid_levels);
  EXPECT_EQ(config.registration.max_structure_fraction, library.max_structure_fraction);
  EXPECT_EQ(config.registration.max_pose_error_voxels, library.max_pose_error_voxels);
  EXPECT_EQ(config.registration.min_kept_overlap, library.min_kept_overlap);
  EXPECT_EQ(config.registration.gauge, library.gauge);
  EXPECT_EQ(config.registration.search.rotations, library.search.rotations);
  const SimulationOptions simulation;
  EXPECT_EQ(config.simulation.num_frames, simulation.num_frames);
  EXPECT_EQ(config.simulation.frame_size, simulation.frame_size);
}

TEST(Settings, SetParsesChecksAndNamesTheOption) {
  Settings settings;
  std::string error;
  EXPECT_TRUE(settings.IsDefault("max_iterations"));
  EXPECT_TRUE(settings.Set("max_iterations", "7", &error)) << error;
  EXPECT_FALSE(settings.IsDefault("max_iterations"));
  EXPECT_EQ(settings.Int("max_iterations"), 7);
  EXPECT_FALSE(settings.Set("max_iterations", "7.5", &error));
  EXPECT_EQ(error, "--max_iterations=7.5: not a valid int32");
  EXPECT_FALSE(settings.Set("mask_erosion", "51", &error));
  EXPECT_EQ(error, "--mask_erosion=51: must be in [0, 50]");
  EXPECT_FALSE(settings.Set("typo", "1", &error));
  EXPECT_EQ(error, "--typo=1: unknown option");
  EXPECT_FALSE(settings.Set("seed", "-1", &error));
  EXPECT_EQ(error, "--seed=-1: not a valid uint64");
  EXPECT_TRUE(settings.Set("uncertainty", "yes", &error));
  EXPECT_TRUE(settings.Bool("uncertainty"));
  EXPECT_EQ(settings.Int("max_iterations"), 7);  // a refused value changes nothing
}

TEST(Settings, APresetSetsWhatWasNotGiven) {
  Settings settings;
  std::string error;
  ASSERT_TRUE(settings.Set("photometric", "none", &error));
  ASSERT_TRUE(settings.Set("preset", "echo", &error));
  EXPECT_EQ(settings.String("photometric"), "none");  // given: kept
  EXPECT_EQ(settings.String("intensity_transform"), "sqrt");
  EXPECT_EQ(settings.String("panorama_sampling"), "all_phases");
  EXPECT_TRUE(settings.Bool("detect_dropouts"));
  EXPECT_EQ(settings.PresetSummary(),
            "preset echo: --intensity_transform=sqrt --panorama_sampling=all_phases "
            "--detect_dropouts=true");
  EXPECT_TRUE(settings.IsDefault("intensity_transform"));
}

TEST(RunOptions, RulesBetweenOptionsNameThem) {
  Settings settings;
  RegistrationOptions options;
  std::string init_file, error;
  ASSERT_TRUE(RunOptionsFrom(settings, &options, &init_file, &error)) << error;
  EXPECT_EQ(options.photometric, PhotometricModel::kAuto);
  EXPECT_EQ(options.max_recoveries, kDefaultMaxRecoveries);
  ASSERT_TRUE(settings.Set("mode", "ape", &error));
  ASSERT_TRUE(RunOptionsFrom(settings, &options, &init_file, &error)) << error;
  EXPECT_EQ(options.photometric, PhotometricModel::kNone);  // the default: none for baselines
  ASSERT_TRUE(settings.Set("uncertainty", "true", &error));
  EXPECT_FALSE(RunOptionsFrom(settings, &options, &init_file, &error));
  // The library's rule (RegistrationOptions::Validate), in the option names of the caller.
  EXPECT_EQ(FieldPathsAsOptions(error, kDsrRegister)
                .rfind("--uncertainty=true: needs --mode=dsr or dba", 0),
            0u)
      << error;
  ASSERT_TRUE(settings.Set("init", "start.json", &error));
  ASSERT_TRUE(settings.Set("uncertainty", "false", &error));
  ASSERT_TRUE(RunOptionsFrom(settings, &options, &init_file, &error)) << error;
  EXPECT_EQ(init_file, "start.json");
}

TEST(RunOptions, PhaseListIsDigitsSeparatedBySingleCommas) {
  std::vector<int> phases;
  ASSERT_TRUE(ParsePhaseList("all", &phases));
  EXPECT_TRUE(phases.empty());
  ASSERT_TRUE(ParsePhaseList("2,0,13", &phases));
  EXPECT_EQ(phases, (std::vector<int>{2, 0, 13}));
  ASSERT_TRUE(ParsePhaseList("07", &phases));  // decimal, leading zeros allowed
  EXPECT_EQ(phases, std::vector<int>{7});
  // Spaces, signs and empty items anywhere, repeats, and what is not a number.
  for (const std::string bad : {"", " 1", "1 ", "+1", "-1", "0,1,", ",0", "0,,1", "0, 1", "1,1",
                                "0x1", "1.0", "4097", "99999999999", "ALL", "all,0"}) {
    EXPECT_FALSE(ParsePhaseList(bad, &phases)) << "'" << bad << "'";
    Settings settings = Settings::For(kDsrRegister);
    std::string error;
    EXPECT_FALSE(settings.Set("phases", bad, &error)) << "'" << bad << "'";
    EXPECT_EQ(error.rfind("--phases=" + bad + ": must be all or", 0), 0u) << error;
  }
}

TEST(RunOptions, EachFileOfTheViewsIsGivenOnce) {
  std::string error;
  EXPECT_TRUE(CheckEachFileOnce({"a.nii", "b0.nii;b1.nii", "c.nii"}, &error)) << error;
  // Two frames, as before: the same path once normalised.
  EXPECT_FALSE(CheckEachFileOnce({"a.nii", "x/../a.nii"}, &error));
  EXPECT_EQ(error, "--images: x/../a.nii is given twice");
  // Two phases of one view, a phase file in two views, a phase file that is also a frame.
  EXPECT_FALSE(CheckEachFileOnce({"p0.nii;p0.nii;p2.nii", "b.nii"}, &error));
  EXPECT_EQ(error, "--images: p0.nii is given twice (phase 0 of image 0 and phase 1 of image 0; "
                   "each frame and phase is a file of its own)");
  EXPECT_FALSE(CheckEachFileOnce({"a0.nii;a1.nii", "./a0.nii;b1.nii"}, &error));
  EXPECT_EQ(error, "--images: ./a0.nii is given twice (phase 0 of image 0 and phase 0 of image 1; "
                   "each frame and phase is a file of its own)");
  EXPECT_FALSE(CheckEachFileOnce({"a0.nii;a1.nii", "a1.nii"}, &error));
  EXPECT_EQ(error.rfind("--images: a1.nii is given twice (phase 1 of image 0 and image 1;", 0), 0u)
      << error;
}

class FlagfileTest : public testing::Test {
 protected:
  std::string Write(const std::string& name, const std::string& text) {
    const std::string path = dir_.path() + "/" + name;
    std::ofstream(path) << text;
    return path;
  }
  ScopedTempDir dir_;
};

TEST_F(FlagfileTest, SetsItsValuesInOrderWithNestedFiles) {
  const std::string inner = Write("inner.flags", "--max_iterations=9\n--nouncertainty\n");
  const std::string outer = Write("outer.flags", "# a comment\n\n--max_iterations=3\n"
                                                 "--uncertainty\n--flagfile=" + inner + "\n");
  Settings settings;
  std::string error;
  ASSERT_TRUE(settings.ReadFlagfile(outer, kPyRegister, &error)) << error;
  EXPECT_EQ(settings.Int("max_iterations"), 9);
  EXPECT_FALSE(settings.Bool("uncertainty"));
  EXPECT_FALSE(settings.IsDefault("uncertainty"));
  EXPECT_FALSE(settings.IsDefault("max_iterations"));
}

TEST_F(FlagfileTest, RefusesWhatTheCommandLineRefuses) {
  Settings settings;
  std::string error;
  EXPECT_FALSE(settings.ReadFlagfile(dir_.path() + "/none.flags", kPyRegister, &error));
  EXPECT_NE(error.find("none.flags: no such file"), std::string::npos) << error;
  const std::string self = dir_.path() + "/self.flags";
  Write("self.flags", "--flagfile=" + self + "\n");
  EXPECT_FALSE(settings.ReadFlagfile(self, kPyRegister, &error));
  EXPECT_NE(error.find("includes itself"), std::string::npos) << error;
  EXPECT_FALSE(settings.ReadFlagfile(Write("typo.flags", "--typo_flag=3\n"), kPyRegister,
                                     &error));
  EXPECT_NE(error.find("line 1: unknown flag --typo_flag"), std::string::npos) << error;
  EXPECT_FALSE(settings.ReadFlagfile(Write("junk.flags", "junk line\n"), kPyRegister, &error));
  EXPECT_NE(error.find("junk.flags: line 1: 'junk line' is not --flag=value"),
            std::string::npos) << error;
  EXPECT_FALSE(settings.ReadFlagfile(dir_.path(), kPyRegister, &error));
  EXPECT_NE(error.find("is a folder"), std::string::npos) << error;
  // An option of another front end is unknown here.
  EXPECT_FALSE(settings.ReadFlagfile(Write("sim.flags", "--speckle_looks=2\n"), kPyRegister,
                                     &error));
  EXPECT_NE(error.find("unknown flag --speckle_looks"), std::string::npos) << error;
  EXPECT_FALSE(settings.ReadFlagfile(Write("bad.flags", "--mask_erosion=99\n"), kPyRegister,
                                     &error));
  EXPECT_NE(error.find("--mask_erosion=99: must be in [0, 50]"), std::string::npos) << error;
}

TEST(FieldPathsAsOptions, NamesTheOptionOfTheFrontEnd) {
  EXPECT_EQ(FieldPathsAsOptions("solve.max_iterations=0: must be >= 1", kPyRegister),
            "--max_iterations=0: must be >= 1");
  // dsr_fuse has no --max_iterations: the field keeps its name.
  EXPECT_EQ(FieldPathsAsOptions("solve.max_iterations=0: must be >= 1", kDsrFuse),
            "solve.max_iterations=0: must be >= 1");
}

}  // namespace
}  // namespace dsr
