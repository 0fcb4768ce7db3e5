// Helpers shared by the command-line tools (tools/ is the only place gflags is used):
// start-up (flags, glog), one-line errors with the project's exit codes, flag validators
// that name the broken rule, and small parsers for list-valued flags.
//
// Exit codes: 0 success, 2 bad input (flags, files), 1 a run that started but failed.
#ifndef DSR_TOOLS_TOOL_UTIL_H_
#define DSR_TOOLS_TOOL_UTIL_H_

#include <sstream>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "core/volume.h"

namespace dsr {

constexpr int kExitBadInput = 2;
constexpr int kExitFailed = 1;

// Tool start-up, in this order:
//  1. FLAGS_logtostderr defaults to true (glog to stderr; --logtostderr=false overrides).
//  2. Parses flags. gflags reports unknown flags, malformed values and failed validators
//     with its own one-line messages; this makes it exit with kExitBadInput instead of 1.
//  3. Handles --help, --helpshort (this tool's flags only), --version: print and exit 0.
//  4. Rejects positional arguments and empty `required_flags` (names without "--") with
//     one line on stderr and kExitBadInput.
//  5. Initialises glog and logs gflags::CommandlineFlagsIntoString() at --v=1.
// Note: call first in main, before any other use of flags.
void InitTool(const char* usage,
              const std::vector<std::string>& required_flags,
              int* argc,
              char*** argv);

// Prints "<tool>: error: <message>" as one line on stderr and returns `code`, so that
// main can `return Fail(...)`.
int Fail(const std::string& message, int code = kExitBadInput);

// Prints "<tool>: error: --<flag>=<value>: <rule>" and exits with kExitBadInput.
[[noreturn]] void ExitBadFlag(const char* flag, const std::string& value, const std::string& rule);

// For DEFINE_validator functions: returns true when `ok`, else ExitBadFlag. (A validator
// that returns false makes gflags print "failed validation of new value" without saying
// which rule failed.) gflags also runs validators on unchanged defaults, so defaults must
// pass. Example:
//   bool ValidateNumFrames(const char* flag, int32_t v) {
//     return dsr::CheckFlag(v >= 2, flag, v, "must be >= 2");
//   }
template <typename T>
bool CheckFlag(bool ok, const char* flag, const T& value, const std::string& rule) {
  if (ok) return true;
  std::ostringstream s;
  s << value;
  ExitBadFlag(flag, s.str(), rule);
}

// Validator for optional input-file flags: true for "" or a readable regular file;
// otherwise ExitBadFlag (missing, a folder, unreadable).
bool CheckInputFileFlag(const char* flag, const std::string& path);

// The absolute, normalised form of a path (symlinks resolved where they exist), so that two
// spellings of one file compare equal.
std::string CanonicalPath(const std::string& path);

// Checks an output-file flag before any work is done: "" is accepted (no output); else the
// file must not be one of `canonical_inputs` (CanonicalPath of every input), must not be a
// folder, and its folder must exist and be writable. On failure `error` reads
// "--<flag>=<path>: <rule>".
bool CheckOutputFile(const std::string& flag,
                     const std::string& path,
                     const std::vector<std::string>& canonical_inputs,
                     std::string* error);

// "a,b,,c" -> {"a", "b", "c"}: items trimmed of spaces, empty items dropped.
std::vector<std::string> SplitCommaList(const std::string& text);

// "96,96,80" -> (96, 96, 80). False unless exactly three integers (no trailing junk) in
// [min_value, max_value].
bool ParseSize3(const std::string& text,
                Eigen::Vector3i* size,
                int min_value = 1,
                int max_value = 1 << 20);

// "1,1.5,2" -> (1, 1.5, 2). False unless exactly three finite numbers.
bool ParseVector3(const std::string& text, Eigen::Vector3d* vector);

// Reads frames in parallel (decompression dominates) with their masks: `mask_paths` one per
// image, or empty for each image's non-zero voxels eroded by `mask_erosion` voxels. The
// first failing frame in input order is reported (one line naming the file).
bool ReadFrames(const std::vector<std::string>& image_paths,
                const std::vector<std::string>& mask_paths,
                int mask_erosion,
                int num_threads,
                std::vector<Image>* images,
                std::vector<Mask>* masks,
                std::string* error);

}  // namespace dsr

#endif  // DSR_TOOLS_TOOL_UTIL_H_
