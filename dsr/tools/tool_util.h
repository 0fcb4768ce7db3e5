// Start-up and errors of the command-line tools (dsr/tools/ is the only place gflags is
// used): flags from the options table, glog, one-line errors with the project's exit codes.
// What the tools share with the Python package (file lists, poses files, memory checks)
// is in dsr/app/.
//
// Exit codes: 0 success, 2 bad input (flags, files), 1 a run that started but failed.
#ifndef DSR_TOOLS_TOOL_UTIL_H_
#define DSR_TOOLS_TOOL_UTIL_H_

#include <cstdint>
#include <string>
#include <vector>

#include "dsr/app/inputs.h"

namespace dsr {

constexpr int kExitBadInput = 2;
constexpr int kExitFailed = 1;

// Tool start-up, in this order:
//  1. FLAGS_logtostderr defaults to true (glog to stderr; --logtostderr=false overrides).
//  2. Registers the options table's flags of `front_end` (dsr/tools/flags.h, with the
//     tool's own defaults, FrontEndDefaults).
//  3. Expands every --flagfile=FILE (also "--flagfile FILE", and inside flagfiles) in place,
//     so that flags after it override it, as gflags does, with the checks of
//     dsr/app/flagfile.h (one line naming the flagfile and exit kExitBadInput).
//  4. Checks every --flag=value in command-line order (CheckFlagValue: unknown flags,
//     values not of their flag's type, the table's rules), then parses flags.
//  5. Handles --help, --helpshort (this tool's options only), --version: print and exit 0.
//  6. Rejects positional arguments and empty `required_flags` (names without "--") with
//     one line on stderr and kExitBadInput.
//  7. Makes the tool's Settings (ToolSettings()), initialises glog and logs the options
//     set at --v=1.
// Note: call first in main, before any other use of flags.
void InitTool(const char* usage,
              uint32_t front_end,
              const std::vector<std::string>& required_flags,
              int* argc,
              char*** argv);

// Runs a tool's main function `body` (which calls InitTool first) so that it never ends in
// an uncaught exception: std::bad_alloc, from any thread, ends the run with one line
// "<tool>: error: out of memory (...)" and kExitFailed; any other exception (a last resort:
// none is expected) with one line naming it and kExitFailed. Use as
//   int main(int argc, char** argv) { return dsr::RunToolMain(argc, argv, &Main); }
int RunToolMain(int argc, char** argv, int (*body)(int, char**));

// `message` (a library's error or failure) with each option field path it names written as
// this tool's flag (FieldPathsAsOptions of the tool's front end).
std::string FieldPathsAsFlags(const std::string& message);

// Prints "<tool>: error: <message>" as one line on stderr, with FieldPathsAsFlags, and
// returns `code`, so that main can `return Fail(...)`.
int Fail(const std::string& message, int code = kExitBadInput);

}  // namespace dsr

#endif  // DSR_TOOLS_TOOL_UTIL_H_
