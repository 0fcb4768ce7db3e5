// Poses file IO (io/io_poses.h): exact round trips (the optional gain and offset too), the
// JSON layout, and a one-line error naming the file, the frame and the rule for every
// malformed input.
#include "dsr/io/io_poses.h"

#include <cmath>
#include <fstream>
#include <iterator>
#include <random>
#include <string>
#include <vector>

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "dsr/geometry/se3.h"
#include "dsr/tests/support/scoped_temp_dir.h"

namespace dsr {
namespace {

using ::testing::HasSubstr;

PosesFile RandomPoses(int frames, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> translation(-30.0, 30.0);
  std::uniform_real_distribution<double> angle(-0.6, 0.6);
  PosesFile poses;
  for (int f = 0; f < frames; ++f) {
    Vector6d delta;
    delta << translation(rng), translation(rng), translation(rng), angle(rng), angle(rng),
        angle(rng);
    poses.images.push_back("frame_" + std::to_string(f) + ".nii.gz");
    poses.frame_from_world.push_back(f == 0 ? Eigen::Isometry3d::Identity() : ExpSE3(delta));
  }
  return poses;
}

std::string ReadText(const std::string& path) {
  std::ifstream in(path);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

std::string WriteText(const ScopedTempDir& dir, const std::string& name, const std::string& text) {
  const std::string path = dir.File(name);
  std::ofstream(path) << text;
  return path;
}

// Reads `path` expecting failure; checks the error is one line naming the file.
std::string ReadError(const std::string& path, int expected_frames = -1) {
  PosesFile poses;
  std::string error;
  EXPECT_FALSE(ReadPoses(path, expected_frames, &poses, &error)) << path;
  EXPECT_EQ(error.find('\n'), std::string::npos) << error;
  EXPECT_EQ(error.rfind(path + ": ", 0), 0u) << error;
  return error;
}

// A single-frame file whose T is `t` (JSON text).
std::string OneFrame(const std::string& t) {
  return R"({"frames": [{"image": "a.nii", "T": )" + t + "}]}";
}

TEST(PosesIo, WriteThenReadReturnsTheSamePosesBitForBit) {
  ScopedTempDir dir;
  const PosesFile poses = RandomPoses(6, 3);
  const std::string path = dir.File("poses.json");
  std::string error;
  ASSERT_TRUE(WritePoses(poses, path, &error)) << error;
  PosesFile back;
  ASSERT_TRUE(ReadPoses(path, 6, &back, &error)) << error;
  EXPECT_EQ(back.images, poses.images);
  ASSERT_EQ(back.frame_from_world.size(), poses.frame_from_world.size());
  for (size_t f = 0; f < poses.frame_from_world.size(); ++f) {
    // Bit for bit: every double printed with enough digits and not re-projected.
    EXPECT_EQ(back.frame_from_world[f].matrix(), poses.frame_from_world[f].matrix()) << f;
  }
  EXPECT_EQ(PosesToJson(back), PosesToJson(poses));
}

TEST(PosesIo, WritesIndentedJsonWithFramesArray) {
  const PosesFile poses = RandomPoses(2, 5);
  const std::string text = PosesToJson(poses);
  const nlohmann::json doc = nlohmann::json::parse(text);
  EXPECT_EQ(text, doc.dump(2) + "\n");  // indent 2
  ASSERT_EQ(doc["frames"].size(), 2u);
  EXPECT_EQ(doc["frames"][1]["image"], "frame_1.nii.gz");
  EXPECT_EQ(doc["frames"][1]["T"][3], nlohmann::json::parse("[0.0, 0.0, 0.0, 1.0]"));
  EXPECT_EQ(doc["frames"][1]["T"][0][3].get<double>(), poses.frame_from_world[1].translation().x());
}

TEST(PosesIo, ExtraKeysAndIntegerEntriesAreAccepted) {
  ScopedTempDir dir;
  const std::string path = WriteText(dir,
                                     "annotated.json",
                                     R"({"method": "dsr", "world": {"frame": 0}, "frames": [
      {"T": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]], "note": "reference"},
      {"image": "b.nrrd", "T": [[0,-1,0,10],[1,0,0,-2.5],[0,0,1,3],[0,0,0,1]]}]})");
  PosesFile poses;
  std::string error;
  ASSERT_TRUE(ReadPoses(path, 2, &poses, &error)) << error;
  EXPECT_EQ(poses.images, (std::vector<std::string>{"", "b.nrrd"}));
  EXPECT_TRUE(poses.frame_from_world[0].matrix().isIdentity(0.0));
  EXPECT_EQ(poses.frame_from_world[1].translation(), Eigen::Vector3d(10, -2.5, 3));
  EXPECT_EQ(poses.frame_from_world[1] * Eigen::Vector3d(1, 0, 0), Eigen::Vector3d(10, -1.5, 3));
}

TEST(PosesIo, NearlyRigidTransformIsProjectedToARotation) {
  ScopedTempDir dir;
  // Off by 1e-7 (printed by a tool with 8 digits): accepted, then made exactly orthonormal.
  const std::string path = WriteText(
      dir, "rounded.json", OneFrame("[[1.0000001,0,0,1],[0,1,0,2],[0,0,0.9999999,3],[0,0,0,1]]"));
  PosesFile poses;
  std::string error;
  ASSERT_TRUE(ReadPoses(path, 1, &poses, &error)) << error;
  const Eigen::Matrix3d r = poses.frame_from_world[0].linear();
  EXPECT_LT((r.transpose() * r - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff(), 1e-15);
  EXPECT_EQ(poses.frame_from_world[0].translation(), Eigen::Vector3d(1, 2, 3));
}

TEST(PosesIo, MissingFileIsAnError) {
  ScopedTempDir dir;
  EXPECT_EQ(ReadError(dir.File("none.json")), dir.File("none.json") + ": no such file");
}

TEST(PosesIo, WrongFrameCountIsAnError) {
  ScopedTempDir dir;
  const std::string path = dir.File("poses.json");
  std::string error;
  ASSERT_TRUE(WritePoses(RandomPoses(2, 1), path, &error)) << error;
  EXPECT_EQ(ReadError(path, 3), path + ": has 2 frames, expected 3 (one per image)");
}

TEST(PosesIo, NonRigidTransformMessageGivesTheDeviation) {
  ScopedTempDir dir;
  const std::string path =
      WriteText(dir,
                "poses.json",
                R"({"frames": [{"T": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]},
                     {"T": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]},
                     {"T": [[1.01,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}]})");
  EXPECT_EQ(ReadError(path), path + ": frame 2: T is not rigid (|R^T R - I| = 0.0201 > 1e-05)");
}

TEST(PosesIo, MalformedFilesGiveOneLineErrors) {
  struct Case {
    const char* name;
    std::string text;
    const char* expected;  // the error after "<path>: "
  };
  const Case cases[] = {
      {"truncated",
       R"({"frames": [{"T": [[1,0)",
       "not valid JSON (parse error at line 1, column 24: syntax error while parsing array - "
       "unexpected end of input; expected ']')"},
      {"not_json", "{not json", "not valid JSON (parse error at line 1, column 3"},
      {"array", "[1, 2]", "expected a JSON object with a \"frames\" array, got array"},
      {"no_frames", R"({"poses": []})", "expected a \"frames\" array (key missing)"},
      {"frames_object", R"({"frames": {}})", "expected a \"frames\" array (got object)"},
      {"empty", R"({"frames": []})", "\"frames\" is empty"},
      {"frame_number", R"({"frames": [3]})", "frame 0: expected an object with \"T\", got number"},
      {"no_t", R"({"frames": [{"image": "a.nii"}]})", "frame 0: missing \"T\""},
      {"image_number",
       R"({"frames": [{"image": 7, "T": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}]})",
       "frame 0: \"image\" must be a string, got number"},
      {"t_string",
       OneFrame("\"identity\""),
       "frame 0: T must be a 4x4 array of numbers (got string)"},
      {"t_3x3",
       OneFrame("[[1,0,0],[0,1,0],[0,0,1]]"),
       "frame 0: T must be a 4x4 array of numbers (got 3 rows)"},
      {"t_short_row",
       OneFrame("[[1,0,0,0],[0,1,0],[0,0,1,0],[0,0,0,1]]"),
       "frame 0: T must be a 4x4 array of numbers (row 1 is an array of 3)"},
      {"t_row_object",
       OneFrame("[[1,0,0,0],{},[0,0,1,0],[0,0,0,1]]"),
       "frame 0: T must be a 4x4 array of numbers (row 1 is an object)"},
      {"t_text",
       OneFrame("[[1,0,0,\"x\"],[0,1,0,0],[0,0,1,0],[0,0,0,1]]"),
       "frame 0: T must be a 4x4 array of numbers (T[0][3] is a string)"},
      {"t_null",
       OneFrame("[[1,0,0,0],[0,1,0,null],[0,0,1,0],[0,0,0,1]]"),
       "frame 0: T must be a 4x4 array of numbers (T[1][3] is a null)"},
      // JSON has no NaN or Inf; nlohmann rejects overflowing numbers while parsing.
      {"t_overflow",
       OneFrame("[[1,0,0,1e999],[0,1,0,0],[0,0,1,0],[0,0,0,1]]"),
       "not valid JSON (number overflow parsing '1e999')"},
      {"t_nan",
       OneFrame("[[1,0,0,NaN],[0,1,0,0],[0,0,1,0],[0,0,0,1]]"),
       "not valid JSON (parse error"},
      {"t_scaled",
       OneFrame("[[2,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]"),
       "frame 0: T is not rigid (|R^T R - I| = 3 > 1e-05)"},
      {"t_reflection",
       OneFrame("[[-1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]"),
       "frame 0: T is not rigid (det R = -1, a reflection; expected 1)"},
      {"t_last_row",
       OneFrame("[[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0.5,1]]"),
       "frame 0: T is not rigid (last row [0,0,0.5,1], expected [0,0,0,1])"},
  };
  ScopedTempDir dir;
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    const std::string path = WriteText(dir, std::string(c.name) + ".json", c.text);
    EXPECT_THAT(ReadError(path), HasSubstr(path + ": " + c.expected));
  }
}

TEST(PosesIo, WriteErrors) {
  ScopedTempDir dir;
  PosesFile poses = RandomPoses(3, 2);
  std::string error;
  EXPECT_FALSE(WritePoses(poses, dir.File("missing/poses.json"), &error));
  EXPECT_EQ(error,
            dir.File("missing/poses.json") + ": folder " + dir.File("missing") + " does not exist");
  poses.frame_from_world[2].translation().y() = std::nan("");
  EXPECT_FALSE(WritePoses(poses, dir.File("nan.json"), &error));
  EXPECT_EQ(error, dir.File("nan.json") + ": frame 2: T has a non-finite entry; not written");
  EXPECT_TRUE(dir.Entries().empty());
}

// The optional uncertainty fields: written per frame (covariance 6x6 row-major, exact
// doubles), ignored by ReadPoses (the poses read back bit for bit), refused when not finite.
TEST(PosesIo, UncertaintyFieldsAreWrittenAndIgnoredOnRead) {
  ScopedTempDir dir;
  PosesFile poses = RandomPoses(3, 5);
  std::mt19937 rng(3);
  std::normal_distribution<double> normal(0.0, 1.0);
  for (int f = 0; f < 3; ++f) {
    Eigen::Matrix<double, 6, 6> a;
    for (int i = 0; i < 36; ++i) a(i / 6, i % 6) = normal(rng) * 1e-3;
    poses.covariance.push_back(f == 0 ? Eigen::Matrix<double, 6, 6>::Zero().eval()
                                      : (a * a.transpose()).eval());
    poses.predicted_tre_mm.push_back(f == 0 ? 0.0 : 0.01 * f + 1e-17);
  }
  std::string error;
  ASSERT_TRUE(WritePoses(poses, dir.File("p.json"), &error)) << error;
  std::ifstream in(dir.File("p.json"));
  const nlohmann::json doc = nlohmann::json::parse(in);
  for (int f = 0; f < 3; ++f) {
    const nlohmann::json& frame = doc["frames"][f];
    ASSERT_EQ(frame["covariance"].size(), 6u);
    for (int r = 0; r < 6; ++r) {
      ASSERT_EQ(frame["covariance"][r].size(), 6u);
      for (int c = 0; c < 6; ++c) {
        EXPECT_EQ(frame["covariance"][r][c].get<double>(), poses.covariance[f](r, c));
      }
    }
    EXPECT_EQ(frame["predicted_tre_mm"].get<double>(), poses.predicted_tre_mm[f]);
  }
  PosesFile read;
  ASSERT_TRUE(ReadPoses(dir.File("p.json"), 3, &read, &error)) << error;
  EXPECT_TRUE(read.covariance.empty());
  for (int f = 0; f < 3; ++f) {
    EXPECT_TRUE(read.frame_from_world[f].matrix() == poses.frame_from_world[f].matrix());
  }
  // Without them, no such keys.
  PosesFile plain = RandomPoses(2, 1);
  ASSERT_TRUE(WritePoses(plain, dir.File("plain.json"), &error)) << error;
  std::ifstream plain_in(dir.File("plain.json"));
  const nlohmann::json plain_doc = nlohmann::json::parse(plain_in);
  EXPECT_FALSE(plain_doc["frames"][1].contains("covariance"));
  EXPECT_FALSE(plain_doc["frames"][1].contains("predicted_tre_mm"));
  poses.covariance[2](4, 1) = std::nan("");
  EXPECT_FALSE(WritePoses(poses, dir.File("nan.json"), &error));
  EXPECT_EQ(error, dir.File("nan.json") +
                       ": frame 2: the covariance or predicted_tre_mm has a non-finite entry; "
                       "not written");
}

// The optional intensity corrections: written per frame, read back bit for bit.
TEST(PosesIo, GainAndOffsetRoundTripExactly) {
  ScopedTempDir dir;
  PosesFile poses = RandomPoses(4, 7);
  poses.gain = {1.0, 0.8123456789012345, 1.2999999999999998, 5e-3};
  poses.offset = {0.0, -12.25, 3.0000000000000001e-5, 99.9};
  std::string error;
  ASSERT_TRUE(WritePoses(poses, dir.File("p.json"), &error)) << error;
  std::ifstream in(dir.File("p.json"));
  const nlohmann::json doc = nlohmann::json::parse(in);
  for (int f = 0; f < 4; ++f) {
    EXPECT_EQ(doc["frames"][f]["gain"].get<double>(), poses.gain[f]) << f;
    EXPECT_EQ(doc["frames"][f]["offset"].get<double>(), poses.offset[f]) << f;
  }
  PosesFile back;
  ASSERT_TRUE(ReadPoses(dir.File("p.json"), 4, &back, &error)) << error;
  EXPECT_EQ(back.gain, poses.gain);
  EXPECT_EQ(back.offset, poses.offset);
  EXPECT_EQ(PosesToJson(back), PosesToJson(poses));
  for (int f = 0; f < 4; ++f) {
    EXPECT_TRUE(back.frame_from_world[f].matrix() == poses.frame_from_world[f].matrix());
  }
}

TEST(PosesIo, AbsentGainAndOffsetReadAsEmpty) {
  ScopedTempDir dir;
  std::string error;
  ASSERT_TRUE(WritePoses(RandomPoses(3, 1), dir.File("plain.json"), &error)) << error;
  EXPECT_EQ(ReadText(dir.File("plain.json")).find("gain"), std::string::npos);
  PosesFile read;
  ASSERT_TRUE(ReadPoses(dir.File("plain.json"), 3, &read, &error)) << error;
  EXPECT_TRUE(read.gain.empty());
  EXPECT_TRUE(read.offset.empty());
  // Each field on its own: a gain on every frame and no offset.
  const std::string path = WriteText(dir,
                                     "gain_only.json",
                                     R"({"frames": [
      {"T": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]], "gain": 1},
      {"T": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]], "gain": 0.5}]})");
  ASSERT_TRUE(ReadPoses(path, 2, &read, &error)) << error;
  EXPECT_EQ(read.gain, (std::vector<double>{1.0, 0.5}));
  EXPECT_TRUE(read.offset.empty());
}

TEST(PosesIo, BadGainOrOffsetIsAnErrorNamingTheFileAndTheFrame) {
  // Frames whose T is the identity, with the given extra members (JSON text, "" for none).
  const auto frames = [](std::vector<std::string> extras) {
    std::string text = R"({"frames": [)";
    for (size_t f = 0; f < extras.size(); ++f) {
      text += std::string(f > 0 ? ", " : "") +
              R"({"T": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]])" +
              (extras[f].empty() ? "" : ", " + extras[f]) + "}";
    }
    return text + "]}";
  };
  struct Case {
    const char* name;
    std::string text;
    const char* expected;  // the error after "<path>: "
  };
  const Case cases[] = {
      {"gain_zero",
       frames({R"("gain": 1, "offset": 0)", R"("gain": 0, "offset": 2)"}),
       "frame 1: \"gain\" must be finite and > 0 (got 0)"},
      {"gain_negative",
       frames({R"("gain": -0.5)"}),
       "frame 0: \"gain\" must be finite and > 0 (got -0.5)"},
      {"gain_text",
       frames({R"("gain": 1)", R"("gain": "1.2")"}),
       "frame 1: \"gain\" must be a number, got string"},
      {"offset_null",
       frames({R"("offset": null)"}),
       "frame 0: \"offset\" must be a number, got null"},
      {"gain_overflow", frames({R"("gain": 1e999)"}), "not valid JSON (number overflow"},
      {"gain_missing_later",
       frames({R"("gain": 1, "offset": 0)", R"("gain": 1.1, "offset": 3)", R"("offset": 1)"}),
       "frame 2: missing \"gain\", which frame 0 has (give it on every frame or on none)"},
      {"offset_only_later",
       frames({"", R"("offset": 4)"}),
       "frame 1: has \"offset\" but frame 0 has none (give it on every frame or on none)"},
  };
  ScopedTempDir dir;
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    const std::string path = WriteText(dir, std::string(c.name) + ".json", c.text);
    EXPECT_THAT(ReadError(path), HasSubstr(path + ": " + c.expected));
  }
}

TEST(PosesIo, BadGainOrOffsetIsNotWritten) {
  ScopedTempDir dir;
  PosesFile poses = RandomPoses(3, 4);
  poses.gain = {1.0, 1.1, 0.0};
  poses.offset = {0.0, 1.0, 2.0};
  std::string error;
  EXPECT_FALSE(WritePoses(poses, dir.File("zero.json"), &error));
  EXPECT_EQ(error,
            dir.File("zero.json") +
                ": frame 2: the gain is not finite and > 0 or the offset is not finite; not "
                "written");
  poses.gain[2] = 0.9;
  poses.offset[1] = std::nan("");
  EXPECT_FALSE(WritePoses(poses, dir.File("nan.json"), &error));
  EXPECT_NE(error.find(dir.File("nan.json") + ": frame 1: "), std::string::npos) << error;
  EXPECT_TRUE(dir.Entries().empty());
}

}  // namespace
}  // namespace dsr
