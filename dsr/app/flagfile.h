// Flagfiles: one --name=value per line, '#' comments and blank lines, nested
// --flagfile=FILE. The command-line tools (dsr/tools/tool_util.h, InitTool) and the Python
// package (Settings::ReadFlagfile) read them with the same checks and messages: a missing,
// unreadable or oversized file, a folder or other non-regular file, a flagfile that
// includes itself (directly or through others), a line that is not --flag=value, and an
// unknown flag are each refused with one line naming the flagfile (and the line).
#ifndef DSR_APP_FLAGFILE_H_
#define DSR_APP_FLAGFILE_H_

#include <cstdint>
#include <functional>
#include <string>
#include <vector>

namespace dsr {

// Largest flagfile or list file read (a flagfile is a few lines; this refuses /dev/zero and
// data files).
constexpr int64_t kMaxFlagfileBytes = int64_t{1} << 20;
// Most arguments all flagfiles together may expand to (a flagfile included twice by each of
// a chain of flagfiles doubles at each link).
constexpr int kMaxExpandedArguments = 100000;

// Whether `name` is a flag the reader knows, and whether it is a bool (which may be given
// as --name or --noname without a value).
using FlagLookup = std::function<bool(const std::string& name, bool* is_bool)>;

// Appends the --flag=value lines of the flagfile `path` to `args`, with the lines of the
// flagfiles it names expanded in place (so that later lines override earlier ones, as on a
// command line). Relative paths, in flagfiles too, are relative to the working folder. ""
// reads nothing. False with one line in `error` ("--flagfile=PATH: ...").
bool ExpandFlagfile(const std::string& path, const FlagLookup& known,
                    std::vector<std::string>* args, std::string* error);

// A command line with each --flagfile=FILE (also "--flagfile FILE") expanded in place by
// ExpandFlagfile. Arguments after "--" are kept as they are. gflags' --fromenv and
// --tryfromenv naming flagfile are refused (they would read a flagfile past these checks).
bool ExpandCommandLine(const std::vector<std::string>& argv, const FlagLookup& known,
                       std::vector<std::string>* out, std::string* error);

// "--name=value", "-name=value", "--name", "-name" -> name, value and whether "=" was given.
// False for anything that does not start with "-" and a name character.
bool SplitFlagArgument(const std::string& arg, std::string* name, std::string* value,
                       bool* has_value);

// Reads a small text file (a flagfile or a list file) after checking that it is a regular,
// readable file of at most kMaxFlagfileBytes, without a leading UTF-8 byte-order mark.
// Errors start with `prefix` ("--flag=path: ").
bool ReadSmallTextFile(const std::string& path, const std::string& prefix, std::string* text,
                       std::string* error);

// The lines of `text` (without their '\n').
std::vector<std::string> Lines(const std::string& text);

}  // namespace dsr

#endif  // DSR_APP_FLAGFILE_H_
