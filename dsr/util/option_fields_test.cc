// Field paths in library errors (util/option_fields.h): which words are paths, and the
// prefix a struct adds to the errors of its members.
#include "dsr/util/option_fields.h"

#include <string>

#include <gtest/gtest.h>

namespace dsr {
namespace {

std::string Bracketed(const std::string& message) {
  return RewriteFieldPaths(message, [](const std::string& path) { return "<" + path + ">"; });
}

TEST(OptionFields, PathsAreWordsBeforeAnEqualsSignOrAloneInParentheses) {
  EXPECT_EQ(Bracketed("solve.max_iterations=0: must be >= 1"),
            "<solve.max_iterations>=0: must be >= 1");
  EXPECT_EQ(Bracketed("needs mode=dsr or dba (mode=ape; use photometric=none)"),
            "needs <mode>=dsr or dba (<mode>=ape; use <photometric>=none)");
  EXPECT_EQ(Bracketed("a=1,b2=2;c_d=3"), "<a>=1,<b2>=2;<c_d>=3");
  EXPECT_EQ(Bracketed("the initial poses (init) place frame 2"),
            "the initial poses (<init>) place frame 2");
  // Not paths: flags, file names, upper case, words without '=' or outside parentheses,
  // a path ending in a dot, and "(a b)".
  for (const std::string& kept :
       {std::string("--max_iterations=0: must be >= 1"), std::string("/tmp/a_b=1"),
        std::string("Mode=dsr"), std::string("smoothing must be >= 0"),
        std::string("solve.=1"), std::string("(init place)"),
        std::string("")}) {
    EXPECT_EQ(Bracketed(kept), kept);
  }
}

TEST(OptionFields, PrefixNamesTheMember) {
  EXPECT_EQ(PrefixFieldPaths("loss", "scale=0: must be finite and > 0 for kind=huber"),
            "loss.scale=0: must be finite and > 0 for loss.kind=huber");
  EXPECT_EQ(PrefixFieldPaths("search", PrefixFieldPaths("refine", "max_iterations=0: x")),
            "search.refine.max_iterations=0: x");
}

TEST(OptionFields, FieldErrorPrintsTheValue) {
  EXPECT_EQ(FieldError("smoothing", -1.0, "must be >= 0"), "smoothing=-1: must be >= 0");
  EXPECT_EQ(FieldError("mode", "ape", "unknown"), "mode=ape: unknown");
}

}  // namespace
}  // namespace dsr
