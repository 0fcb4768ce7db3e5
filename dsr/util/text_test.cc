// The text helpers (util/text.h).
#include "dsr/util/text.h"

#include <gtest/gtest.h>

namespace dsr {
namespace {

TEST(Text, LowerChangesOnlyAsciiLetters) {
  EXPECT_EQ(Lower("A.NII.Gz"), "a.nii.gz");
  EXPECT_EQ(Lower("x_1-Y\xC3\x89"), "x_1-y\xC3\x89");  // UTF-8 bytes kept as they are
  EXPECT_EQ(Lower(""), "");
}

TEST(Text, EndsWithComparesTheLastCharacters) {
  EXPECT_TRUE(EndsWith("frame.nii.gz", ".nii.gz"));
  EXPECT_TRUE(EndsWith("frame.nii.gz", ""));
  EXPECT_TRUE(EndsWith(".gz", ".gz"));
  EXPECT_FALSE(EndsWith("gz", ".gz"));                // shorter than the suffix
  EXPECT_FALSE(EndsWith("frame.NII.GZ", ".nii.gz"));  // case-sensitive
  EXPECT_FALSE(EndsWith("frame.nii", ".nii.gz"));
}

TEST(Text, TrimRemovesSpacesTabsAndCarriageReturnsAtBothEnds) {
  EXPECT_EQ(Trim("  key = value \t\r"), "key = value");
  EXPECT_EQ(Trim("\t\r \r"), "");
  EXPECT_EQ(Trim(""), "");
  EXPECT_EQ(Trim("a\nb"), "a\nb");  // a newline is not trimmed, inside or at the ends
  EXPECT_EQ(Trim("\na "), "\na");
}

}  // namespace
}  // namespace dsr
