// The tools' flags (dsr/tools/flags.h).
#include "dsr/tools/flags.h"

#include <deque>
#include <vector>

#include <gflags/gflags.h>

namespace dsr {
namespace {

uint32_t& FrontEndBits() {
  static uint32_t bits = 0;
  return bits;
}

Settings& MutableSettings() {
  static Settings* const settings = new Settings();
  return *settings;
}

// gflags keeps pointers to a flag's name, help, file and storage for the process's life.
template <typename T>
void Register(const OptionSpec& spec, const char* file, const T& value) {
  gflags::FlagRegisterer(spec.name, spec.help, file, new T(value), new T(value));
}

// The "file" gflags files a flag under: --help groups the flags by it, and --helpshort lists
// those of this prefix (tool_util.cc).
const char* GroupFile(const char* group) {
  static auto* const files = new std::deque<std::string>();
  const std::string file = std::string("dsr options: ") + group;
  for (const std::string& f : *files) {
    if (f == file) return f.c_str();
  }
  files->push_back(file);
  return files->back().c_str();
}

}  // namespace

void DefineToolFlags(uint32_t front_end) {
  FrontEndBits() = front_end;
  Settings& settings = MutableSettings();
  settings = Settings::For(front_end);  // the table's defaults, with this tool's own
  for (const OptionSpec& spec : OptionTable()) {
    if ((spec.front_ends & front_end) == 0) continue;
    const char* file = GroupFile(spec.group);
    const OptionValue& value = settings.Value(spec.name);
    switch (spec.type) {
      case OptionType::kBool: Register(spec, file, std::get<bool>(value)); break;
      case OptionType::kInt32: Register(spec, file, std::get<int32_t>(value)); break;
      case OptionType::kUint64: Register(spec, file, std::get<uint64_t>(value)); break;
      case OptionType::kDouble: Register(spec, file, std::get<double>(value)); break;
      case OptionType::kString: Register(spec, file, std::get<std::string>(value)); break;
    }
  }
}

uint32_t ToolFrontEnd() { return FrontEndBits(); }

bool SettingsFromFlags(std::string* error) {
  for (const OptionSpec& spec : OptionTable()) {
    if ((spec.front_ends & FrontEndBits()) == 0) continue;
    gflags::CommandLineFlagInfo info;
    if (!gflags::GetCommandLineFlagInfo(spec.name, &info) || info.is_default) continue;
    if (!MutableSettings().Set(spec.name, info.current_value, error)) return false;
  }
  return true;
}

const Settings& ToolSettings() { return MutableSettings(); }

const RunConfig& ToolConfig() {
  static const RunConfig* const config = new RunConfig(ConfigFrom(ToolSettings()));
  return *config;
}

bool CheckFlagValue(const std::string& name, const std::string& value, std::string* error) {
  const OptionSpec* spec = FindOption(name);
  if (spec != nullptr && (spec->front_ends & FrontEndBits()) != 0) {
    OptionValue parsed;
    return ParseOptionValue(*spec, value, &parsed, error);
  }
  gflags::CommandLineFlagInfo info;  // gflags' own (--v, --logtostderr, ...)
  if (!gflags::GetCommandLineFlagInfo(name.c_str(), &info)) {
    *error = "--" + name + "=" + value + ": unknown flag";
    return false;
  }
  gflags::FlagSaver saver;
  if (gflags::SetCommandLineOption(name.c_str(), value.c_str()).empty()) {
    *error = "--" + name + "=" + value + ": not a valid " + info.type;
    return false;
  }
  return true;
}

}  // namespace dsr
