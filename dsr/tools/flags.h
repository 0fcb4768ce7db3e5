// The tools' flags: the options of the options table (dsr/app/options.h) that the tool's
// front end takes, registered with gflags by InitTool (dsr/tools/tool_util.h), so that
// --help, --helpshort and gflags' parsing see them; and the Settings of this run, made from
// the command line once it is parsed. A tool reads its options from ToolSettings() and turns
// them into the libraries' options with dsr/app/run_options.h; no flag is defined anywhere
// else.
#ifndef DSR_TOOLS_FLAGS_H_
#define DSR_TOOLS_FLAGS_H_

#include <cstdint>
#include <string>

#include "dsr/app/options.h"
#include "dsr/app/run_options.h"

namespace dsr {

// Registers with gflags every option of the table that `front_end` takes, with its default
// for that front end (DefaultFor: --help shows it); InitTool does.
void DefineToolFlags(uint32_t front_end);
// The front end whose flags are registered (0 before InitTool).
uint32_t ToolFrontEnd();

// Sets the tool's Settings from the parsed command line (InitTool does): every registered
// flag that was given. False with a one-line `error`.
bool SettingsFromFlags(std::string* error);

// The options of this run, after InitTool.
const Settings& ToolSettings();
// The fields of the options table, after InitTool (ConfigFrom(ToolSettings())).
const RunConfig& ToolConfig();

// The value of a flag of this tool (ToolSettings()), by type.
inline const std::string& StringFlag(const char* name) { return ToolSettings().String(name); }
inline int32_t IntFlag(const char* name) { return ToolSettings().Int(name); }
inline uint64_t Uint64Flag(const char* name) { return ToolSettings().Uint64(name); }
inline double DoubleFlag(const char* name) { return ToolSettings().Double(name); }
inline bool BoolFlag(const char* name) { return ToolSettings().Bool(name); }

// Checks `value` for flag `name` as a command line would set it (--name=value): false with
// the message ("--name=value: unknown flag", "...: not a valid int32", "...: must be >= 1").
// The tools check their command lines with it before gflags parses them.
bool CheckFlagValue(const std::string& name, const std::string& value, std::string* error);

}  // namespace dsr

#endif  // DSR_TOOLS_FLAGS_H_
