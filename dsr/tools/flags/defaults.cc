// Per-tool defaults of the shared flags (tools/flags/flags.h).
#include <glog/logging.h>

#include "dsr/tools/flags/flags.h"

namespace dsr {

void SetFlagDefault(const char* flag, const std::string& value) {
  CHECK(!gflags::SetCommandLineOptionWithMode(flag, value.c_str(), gflags::SET_FLAGS_DEFAULT)
             .empty())
      << "cannot set the default of --" << flag << " to " << value;
}

bool FlagIsDefault(const char* flag) { return gflags::GetCommandLineFlagInfoOrDie(flag).is_default; }

}  // namespace dsr
