// Helpers shared by the command-line tools (the only place gflags is used).
#ifndef DSR_TOOLS_TOOL_UTIL_H_
#define DSR_TOOLS_TOOL_UTIL_H_

#include <string>
#include <vector>

#include <Eigen/Core>

namespace dsr {

// Exit codes: 2 for bad input (flags, files), 1 for a run that failed.
constexpr int kExitBadInput = 2;
constexpr int kExitFailed = 1;

// Parses flags, sets glog to stderr, logs the effective flags. Returns false (after
// printing one error line) on a nonsense command line.
void InitTool(const char* usage, int* argc, char*** argv);

// Prints "<tool>: error: <message>" as one line on stderr and returns `code`.
int Fail(const std::string& message, int code = kExitBadInput);

// "a,b,c" -> {"a","b","c"} (empty items dropped).
std::vector<std::string> SplitCommaList(const std::string& text);

// "96,96,80" -> (96,96,80); false when not three positive integers.
bool ParseSize3(const std::string& text, Eigen::Vector3i* size);

}  // namespace dsr

#endif  // DSR_TOOLS_TOOL_UTIL_H_
