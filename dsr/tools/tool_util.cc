#include "dsr/tools/tool_util.h"

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <new>
#include <system_error>

#include <gflags/gflags.h>
#include <glog/logging.h>

#include "dsr/app/flagfile.h"
#include "dsr/tools/flags.h"
#include "dsr/util/atomic_file.h"

// gflags calls this on parse errors and after printing --help (both with status 1). It is
// exported by libgflags and used by its own tests; InitTool swaps it while parsing.
namespace GFLAGS_NAMESPACE {
extern void (*gflags_exitfunc)(int);
}  // namespace GFLAGS_NAMESPACE

namespace dsr {
namespace {

std::string& ToolName() {
  static std::string name = "dsr";
  return name;
}

void ExitWithBadInput(int) { std::exit(kExitBadInput); }
void ExitAfterHelp(int) { std::exit(EXIT_SUCCESS); }

// Checks each --name=value of `args` (after argv[0], up to "--") with CheckFlagValue: the
// first refusal's message. The forms gflags also takes are followed: --bool, --nobool, and
// "--name value" for a flag that is not a bool.
// With --undefok (names gflags lets pass unknown) or flags gflags acts on when set
// (--fromenv, --tryfromenv), the unknown-name check is left to gflags.
bool CheckFlagArguments(const std::vector<std::string>& args, std::string* error) {
  std::string name, value;
  bool has_value = false;
  bool check_unknown = true;
  for (size_t a = 1; a < args.size() && args[a] != "--"; ++a) {
    if (SplitFlagArgument(args[a], &name, &value, &has_value) &&
        (name == "undefok" || name == "fromenv" || name == "tryfromenv")) {
      check_unknown = false;
    }
  }
  bool ok = true;
  for (size_t a = 1; ok && a < args.size() && args[a] != "--"; ++a) {
    if (!SplitFlagArgument(args[a], &name, &value, &has_value)) continue;  // gflags: positional
    if (name == "fromenv" || name == "tryfromenv" || name == "undefok") continue;
    gflags::CommandLineFlagInfo info;
    const bool known = gflags::GetCommandLineFlagInfo(name.c_str(), &info);
    if (!known && name.compare(0, 2, "no") == 0 && !has_value &&
        gflags::GetCommandLineFlagInfo(name.substr(2).c_str(), &info) && info.type == "bool") {
      continue;  // --nobool
    }
    if (!known) {
      if (!check_unknown) continue;
      *error = "--" + name + (has_value ? "=" + value : "") + ": unknown flag";
      ok = false;
      break;
    }
    if (!has_value) {
      if (info.type == "bool") continue;  // --bool
      // "--images --out_poses=x": gflags would take the next flag as the value.
      if (a + 1 == args.size() || args[a + 1].compare(0, 2, "--") == 0) {
        *error = "--" + name + ": needs a value (--" + name + "=VALUE)" +
                 (a + 1 == args.size() ? "" : "; the next argument, " + args[a + 1] +
                                                  ", is a flag of its own");
        ok = false;
        break;
      }
      value = args[++a];
    }
    ok = CheckFlagValue(name, value, error);
  }
  return ok;
}

// The address-space limit for the out-of-memory message (0 = none), taken at start-up.
double& LimitAtStart() {
  static double bytes = 0.0;
  return bytes;
}

std::string OutOfMemoryMessage(const std::string& detail) {
  std::string message = "out of memory (" + detail;
  if (LimitAtStart() > 0.0) message += "; address-space limit " + GiB(LimitAtStart());
  return message + "): free memory, raise the limit (ulimit -v) or give a smaller problem";
}

[[noreturn]] void ExitOnException(std::exception_ptr exception) {
  std::string message = "internal error: std::terminate without an exception";
  try {
    if (exception) std::rethrow_exception(exception);
  } catch (const std::bad_alloc& e) {
    message = OutOfMemoryMessage(e.what());
  } catch (const std::system_error& e) {
    // Starting a thread fails with EAGAIN when its stack cannot be mapped.
    message = e.code() == std::errc::resource_unavailable_try_again
                  ? OutOfMemoryMessage(std::string("cannot start a thread: ") + e.what())
                  : std::string("internal error: ") + e.what();
  } catch (const std::exception& e) {
    message = std::string("internal error: uncaught exception: ") + e.what();
  } catch (...) {
    message = "internal error: uncaught exception of unknown type";
  }
  Fail(message);
  std::_Exit(kExitFailed);
}

// Exceptions that leave a worker thread (ParallelFor) end in std::terminate.
[[noreturn]] void OnTerminate() { ExitOnException(std::current_exception()); }

void SetToolName(const char* argv0) {
  std::string name = argv0 != nullptr ? argv0 : "dsr";
  const size_t slash = name.rfind('/');
  if (slash != std::string::npos) name = name.substr(slash + 1);
  ToolName() = name;
}

}  // namespace

int RunToolMain(int argc, char** argv, int (*body)(int, char**)) {
  SetToolName(argc > 0 ? argv[0] : nullptr);
  LimitAtStart() = AddressSpaceLimitBytes();
  std::set_terminate(&OnTerminate);
  RemoveTemporaryFilesOnTermination();  // an interrupted write leaves no temporary file
  try {
    return body(argc, argv);
  } catch (...) {
    std::fflush(stdout);  // what the run printed before (not in OnTerminate: a thread may hold it)
    ExitOnException(std::current_exception());
  }
}

namespace {

// gflags' lookup, for the flagfile reader: this tool's flags and gflags' own.
bool KnownFlag(const std::string& name, bool* is_bool) {
  gflags::CommandLineFlagInfo info;
  if (!gflags::GetCommandLineFlagInfo(name.c_str(), &info)) return false;
  *is_bool = info.type == "bool";
  return true;
}

// gflags' --helpshort lists the flags of the file named as the program only; a tool's
// flags are the options table's, filed by group (dsr/tools/flags.cc).
[[noreturn]] void PrintHelpShort() {
  std::printf("%s: %s\n", ToolName().c_str(), gflags::ProgramUsage());
  std::vector<gflags::CommandLineFlagInfo> flags;
  gflags::GetAllFlags(&flags);  // sorted by file, then name
  std::string file;
  for (const gflags::CommandLineFlagInfo& flag : flags) {
    if (flag.filename.rfind("dsr options: ", 0) != 0) continue;
    if (flag.filename != file) {
      file = flag.filename;
      std::printf("\n  %s:\n", file.substr(std::string("dsr options: ").size()).c_str());
    }
    std::printf("%s", gflags::DescribeOneFlag(flag).c_str());
  }
  std::exit(EXIT_SUCCESS);
}

// InitTool's steps 3-5: the flagfiles expanded in place, every value checked, parsed, help.
void ParseCommandLine(int* argc, char*** argv) {
  // gflags permutes and keeps pointers into the expanded arguments: they live as long as
  // the process.
  static std::vector<std::string>* const expanded = new std::vector<std::string>();
  static std::vector<char*>* const expanded_argv = new std::vector<char*>();
  std::string error;
  if (!ExpandCommandLine(std::vector<std::string>(*argv, *argv + *argc), &KnownFlag, expanded,
                         &error)) {
    std::exit(Fail(error));
  }
  for (std::string& arg : *expanded) expanded_argv->push_back(&arg[0]);
  expanded_argv->push_back(nullptr);
  *argc = static_cast<int>(expanded->size());
  *argv = expanded_argv->data();
  // Unknown flags, values that are not of their flag's type and values an option's rule
  // refuses get the one-line error the rest of the tool's errors have (gflags' own lines
  // differ), checked in command-line order as gflags would.
  if (!CheckFlagArguments(*expanded, &error)) std::exit(Fail(error));

  void (*const previous_exit)(int) = GFLAGS_NAMESPACE::gflags_exitfunc;
  GFLAGS_NAMESPACE::gflags_exitfunc = &ExitWithBadInput;
  gflags::ParseCommandLineNonHelpFlags(argc, argv, /*remove_flags=*/true);
  GFLAGS_NAMESPACE::gflags_exitfunc = &ExitAfterHelp;
  std::string helpshort;
  if (gflags::GetCommandLineOption("helpshort", &helpshort) && helpshort == "true") {
    PrintHelpShort();
  }
  gflags::HandleCommandLineHelpFlags();
  GFLAGS_NAMESPACE::gflags_exitfunc = previous_exit;
}

}  // namespace

void InitTool(const char* usage,
              uint32_t front_end,
              const std::vector<std::string>& required_flags,
              int* argc,
              char*** argv) {
  SetToolName((*argv)[0]);
  FLAGS_logtostderr = true;
  gflags::SetUsageMessage(usage);
  DefineToolFlags(front_end);
  ParseCommandLine(argc, argv);
  if (*argc > 1) {
    std::exit(Fail(std::string("unexpected argument '") + (*argv)[1] +
                   "' (every input is a --flag=value; see --helpshort)"));
  }
  std::string error;
  if (!SettingsFromFlags(&error)) std::exit(Fail(error));
  for (const std::string& flag : required_flags) {
    if (ToolSettings().String(flag).empty()) {
      std::exit(Fail("--" + flag + " is required (see --helpshort)"));
    }
  }
  google::InitGoogleLogging((*argv)[0]);
  VLOG(1) << "flags: " << ToolSettings().SetOptionsText();
}

std::string FieldPathsAsFlags(const std::string& message) {
  return FieldPathsAsOptions(message, ToolFrontEnd() != 0 ? ToolFrontEnd() : ~0u);
}

int Fail(const std::string& message, int code) {
  std::fprintf(stderr, "%s: error: %s\n", ToolName().c_str(), FieldPathsAsFlags(message).c_str());
  std::fflush(stderr);
  return code;
}

}  // namespace dsr
