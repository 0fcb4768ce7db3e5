#include "dsr/tools/tool_util.h"

#include "dsr/util/option_fields.h"
#include "dsr/util/parallel.h"

#include "dsr/io/io_image.h"

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <new>
#include <system_error>

#include <sys/resource.h>
#include <sys/stat.h>
#include <unistd.h>

#include <gflags/gflags.h>
#include <glog/logging.h>

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

// Whether RefuseFlag exits (SetBadFlagsExit), and the latest message it did not exit with.
std::atomic<bool> bad_flags_exit{true};
std::mutex last_bad_flag_mutex;
std::string last_bad_flag;

void ExitWithBadInput(int) { std::exit(kExitBadInput); }
void ExitAfterHelp(int) { std::exit(EXIT_SUCCESS); }

std::string Trim(const std::string& text) {
  const size_t begin = text.find_first_not_of(" \t\r");
  if (begin == std::string::npos) return "";
  const size_t end = text.find_last_not_of(" \t\r");
  return text.substr(begin, end - begin + 1);
}

// Reads a small text file (a flagfile or a list file) after checking that it is a regular,
// readable file of at most kMaxFlagfileBytes. Errors start with `prefix` ("--flag=path: ").
bool ReadSmallTextFile(const std::string& path,
                       const std::string& prefix,
                       std::string* text,
                       std::string* error) {
  struct stat st;
  if (stat(path.c_str(), &st) != 0) {
    *error = prefix + (errno == ENOENT ? std::string("no such file") : std::strerror(errno));
    return false;
  }
  if (S_ISDIR(st.st_mode)) {
    *error = prefix + "is a folder, not a file";
    return false;
  }
  if (!S_ISREG(st.st_mode)) {
    *error = prefix + "not a regular file";
    return false;
  }
  if (st.st_size > kMaxFlagfileBytes) {
    *error = prefix + std::to_string(st.st_size) + " bytes, more than the limit of " +
             std::to_string(kMaxFlagfileBytes) + " for a file of flags or paths";
    return false;
  }
  std::ifstream in(path, std::ios::binary);
  if (!in.is_open()) {
    *error = prefix + "cannot open for reading (" + std::strerror(errno) + ")";
    return false;
  }
  text->assign(static_cast<size_t>(kMaxFlagfileBytes) + 1, '\0');
  in.read(&(*text)[0], static_cast<std::streamsize>(text->size()));
  text->resize(static_cast<size_t>(in.gcount()));
  if (in.bad() || static_cast<int64_t>(text->size()) > kMaxFlagfileBytes) {
    *error = prefix + (in.bad() ? "read error" : "grew beyond the limit while being read");
    return false;
  }
  return true;
}

std::vector<std::string> Lines(const std::string& text) {
  std::vector<std::string> lines;
  size_t begin = 0;
  while (begin < text.size()) {
    size_t end = text.find('\n', begin);
    if (end == std::string::npos) end = text.size();
    lines.push_back(text.substr(begin, end - begin));
    begin = end + 1;
  }
  return lines;
}

// "--name=value", "-name=value", "--name", "-name" -> name, value and whether "=" was given.
// False for anything that does not start with "-" and a name character.
bool SplitFlagArgument(const std::string& arg,
                       std::string* name,
                       std::string* value,
                       bool* has_value) {
  const size_t start = arg.compare(0, 2, "--") == 0 ? 2 : (arg.compare(0, 1, "-") == 0 ? 1 : 0);
  if (start == 0 || arg.size() == start || arg[start] == '=') return false;
  const size_t equals = arg.find('=', start);
  *has_value = equals != std::string::npos;
  *name = arg.substr(start, *has_value ? equals - start : std::string::npos);
  *value = *has_value ? arg.substr(equals + 1) : std::string();
  return true;
}

// gflags' --fromenv/--tryfromenv=flagfile would read a flagfile behind this check's back.
bool ReadsFlagfileFromEnvironment(const std::string& name, const std::string& value) {
  if (name != "fromenv" && name != "tryfromenv") return false;
  for (const std::string& item : SplitCommaList(value)) {
    if (item == "flagfile") return true;
  }
  return false;
}

// Sets each --name=value of `args` (after argv[0], up to "--") with SetFlagValue under a
// FlagSaver, so that nothing stays set: the first refusal's message. The forms gflags also
// takes are followed: --bool, --nobool, and "--name value" for a flag that is not a bool.
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
  const bool exit_before = bad_flags_exit.exchange(false);
  gflags::FlagSaver saver;
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
      if (a + 1 == args.size()) {
        *error = "--" + name + ": needs a value (--" + name + "=VALUE)";
        ok = false;
        break;
      }
      value = args[++a];
    }
    ok = SetFlagValue(name, value, error);
  }
  bad_flags_exit = exit_before;
  return ok;
}

// Expands --flagfile arguments in place (InitTool step 2).
class FlagfileExpander {
 public:
  bool ExpandCommandLine(int argc, char** argv, std::vector<std::string>* out, std::string* error) {
    out->push_back(argv[0]);
    for (int a = 1; a < argc; ++a) {
      const std::string arg = argv[a];
      if (arg == "--") {  // gflags: the end of the flags; the rest is positional
        for (; a < argc; ++a) out->push_back(argv[a]);
        break;
      }
      std::string name, value;
      bool has_value = false;
      if (!SplitFlagArgument(arg, &name, &value, &has_value) || name != "flagfile") {
        if (SplitFlagArgument(arg, &name, &value, &has_value) &&
            ReadsFlagfileFromEnvironment(name, value)) {
          *error = arg + ": a flagfile cannot be read from the environment; use --flagfile=FILE";
          return false;
        }
        out->push_back(arg);
        continue;
      }
      if (!has_value) {
        if (a + 1 == argc) {  // gflags reports the missing value
          out->push_back(arg);
          continue;
        }
        value = argv[++a];
      }
      if (!ExpandFile(value, out, error)) return false;
    }
    return true;
  }

 private:
  static constexpr int kMaxDepth = 64;

  bool ExpandFile(const std::string& path, std::vector<std::string>* out, std::string* error) {
    if (path.empty()) return true;  // gflags: no flagfile
    const std::string prefix = "--flagfile=" + path + ": ";
    std::string text;
    if (!ReadSmallTextFile(path, prefix, &text, error)) return false;
    const std::string canonical = CanonicalPath(path);
    for (size_t f = 0; f < open_.size(); ++f) {
      if (open_[f] != canonical) continue;
      std::string chain;
      for (size_t g = f; g < open_.size(); ++g) chain += spelled_[g] + " -> ";
      *error = prefix + "includes itself (" + chain + path + ")";
      return false;
    }
    if (static_cast<int>(open_.size()) >= kMaxDepth) {
      *error = prefix + "flagfiles nested more than " + std::to_string(kMaxDepth) + " deep";
      return false;
    }
    open_.push_back(canonical);
    spelled_.push_back(path);
    const std::vector<std::string> lines = Lines(text);
    for (size_t l = 0; l < lines.size(); ++l) {
      const std::string line = Trim(lines[l]);
      if (line.empty() || line[0] == '#') continue;
      const std::string where = prefix + "line " + std::to_string(l + 1) + ": ";
      std::string name, value;
      bool has_value = false;
      if (!SplitFlagArgument(line, &name, &value, &has_value) ||
          name.find_first_of(" \t") != std::string::npos) {
        *error = where + "'" + line.substr(0, 80) +
                 "' is not --flag=value (every line is one --flag=value, a '#' comment or "
                 "blank)";
        return false;
      }
      if (name == "flagfile") {
        if (!has_value) {
          *error = where + "--flagfile needs a value (--flagfile=FILE)";
          return false;
        }
        if (!ExpandFile(value, out, error)) return false;
        continue;
      }
      if (ReadsFlagfileFromEnvironment(name, value)) {
        *error = where + "a flagfile cannot be read from the environment";
        return false;
      }
      gflags::CommandLineFlagInfo info;
      const bool known = gflags::GetCommandLineFlagInfo(name.c_str(), &info);
      gflags::CommandLineFlagInfo negated;
      const bool negated_bool = !known && !has_value && name.compare(0, 2, "no") == 0 &&
                                gflags::GetCommandLineFlagInfo(name.substr(2).c_str(), &negated) &&
                                negated.type == "bool";
      if (!known && !negated_bool) {
        *error = where + "unknown flag --" + name + " (see --helpshort)";
        return false;
      }
      if (known && !has_value && info.type != "bool") {
        *error = where + "--" + name + " needs a value (--" + name + "=VALUE on one line)";
        return false;
      }
      out->push_back(line);
      if (static_cast<int>(out->size()) > kMaxExpandedArguments) {
        *error = prefix + "the flagfiles expand to more than " +
                 std::to_string(kMaxExpandedArguments) + " arguments";
        return false;
      }
    }
    open_.pop_back();
    spelled_.pop_back();
    return true;
  }

  std::vector<std::string> open_;     // canonical paths of the flagfiles being expanded
  std::vector<std::string> spelled_;  // the same, as written
};

// The address-space limit for the out-of-memory message (0 = none), taken at start-up.
double& LimitAtStart() {
  static double bytes = 0.0;
  return bytes;
}

std::string GiB(double bytes) {
  char text[32];
  std::snprintf(text, sizeof(text), "%.1f GiB", bytes / (1024.0 * 1024.0 * 1024.0));
  return text;
}

double PhysicalMemoryBytes() {
  const long pages = sysconf(_SC_PHYS_PAGES);
  const long page_size = sysconf(_SC_PAGESIZE);
  return pages > 0 && page_size > 0 ? static_cast<double>(pages) * page_size : 0.0;
}

// RLIMIT_AS in bytes, or 0 when unlimited.
double AddressSpaceLimitBytes() {
  struct rlimit limit;
  if (getrlimit(RLIMIT_AS, &limit) != 0 || limit.rlim_cur == RLIM_INFINITY) return 0.0;
  return static_cast<double>(limit.rlim_cur);
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
  try {
    return body(argc, argv);
  } catch (...) {
    std::fflush(stdout);  // what the run printed before (not in OnTerminate: a thread may hold it)
    ExitOnException(std::current_exception());
  }
}

double AvailableMemoryBytes() {
  double available = PhysicalMemoryBytes();
  const double limit = AddressSpaceLimitBytes();
  if (limit > 0.0) {
    double mapped = 0.0;
    long pages = 0;
    std::ifstream statm("/proc/self/statm");
    if (statm >> pages) mapped = static_cast<double>(pages) * sysconf(_SC_PAGESIZE);
    const double left = std::max(0.0, limit - mapped);
    available = available > 0.0 ? std::min(available, left) : left;
  }
  return available;
}

bool CheckMemoryEstimate(const std::string& what_flags,
                         double bytes,
                         const std::string& what,
                         std::string* error) {
  const double available = AvailableMemoryBytes();
  if (available <= 0.0 || bytes <= available) return true;
  const double limit = AddressSpaceLimitBytes();
  *error = what_flags + ": needs about " + GiB(bytes) + " for " + what + ", more than the " +
           GiB(available) + " available (physical RAM " + GiB(PhysicalMemoryBytes()) +
           (limit > 0.0 ? ", address-space limit " + GiB(limit) : std::string()) + ")";
  return false;
}

void InitTool(const char* usage,
              const std::vector<std::string>& required_flags,
              int* argc,
              char*** argv) {
  SetToolName((*argv)[0]);
  FLAGS_logtostderr = true;
  gflags::SetUsageMessage(usage);

  // gflags permutes and keeps pointers into the expanded arguments: they live as long as
  // the process.
  static std::vector<std::string>* const expanded = new std::vector<std::string>();
  static std::vector<char*>* const expanded_argv = new std::vector<char*>();
  std::string error;
  if (!FlagfileExpander().ExpandCommandLine(*argc, *argv, expanded, &error)) std::exit(Fail(error));
  for (std::string& arg : *expanded) expanded_argv->push_back(&arg[0]);
  expanded_argv->push_back(nullptr);
  *argc = static_cast<int>(expanded->size());
  *argv = expanded_argv->data();

  // Unknown flags and values that are not of their flag's type get the one-line error
  // the rest of the tool's errors have (gflags' own lines differ, and the Python module
  // prints these), checked in command-line order as gflags would.
  if (!CheckFlagArguments(*expanded, &error)) std::exit(Fail(error));

  void (*const previous_exit)(int) = GFLAGS_NAMESPACE::gflags_exitfunc;
  GFLAGS_NAMESPACE::gflags_exitfunc = &ExitWithBadInput;
  gflags::ParseCommandLineNonHelpFlags(argc, argv, /*remove_flags=*/true);
  GFLAGS_NAMESPACE::gflags_exitfunc = &ExitAfterHelp;
  // gflags' --helpshort lists the flags of the file named as the program only; a tool's
  // flags are also the shared ones of tools/flags/ it links.
  std::string helpshort;
  if (gflags::GetCommandLineOption("helpshort", &helpshort) && helpshort == "true") {
    std::printf("%s: %s\n", ToolName().c_str(), gflags::ProgramUsage());
    std::vector<gflags::CommandLineFlagInfo> flags;
    gflags::GetAllFlags(&flags);  // sorted by file, then name
    std::string file;
    for (const gflags::CommandLineFlagInfo& flag : flags) {
      if (flag.filename.find("/tools/") == std::string::npos) continue;
      if (flag.filename != file) {
        file = flag.filename;
        std::printf("\n  Flags from %s:\n", file.c_str());
      }
      std::printf("%s", gflags::DescribeOneFlag(flag).c_str());
    }
    std::exit(EXIT_SUCCESS);
  }
  gflags::HandleCommandLineHelpFlags();
  GFLAGS_NAMESPACE::gflags_exitfunc = previous_exit;

  if (*argc > 1) {
    std::exit(Fail(std::string("unexpected argument '") + (*argv)[1] +
                   "' (every input is a --flag=value; see --helpshort)"));
  }
  for (const std::string& flag : required_flags) {
    std::string value;
    CHECK(gflags::GetCommandLineOption(flag.c_str(), &value)) << "no flag --" << flag;
    if (value.empty()) std::exit(Fail("--" + flag + " is required (see --helpshort)"));
  }
  google::InitGoogleLogging((*argv)[0]);
  VLOG(1) << "flags:\n" << gflags::CommandlineFlagsIntoString();
}

std::string FieldPathsAsFlags(const std::string& message) {
  return RewriteFieldPaths(message, [](const std::string& path) {
    std::string joined = path;
    std::replace(joined.begin(), joined.end(), '.', '_');
    const size_t last = path.rfind('.');
    for (const std::string& name : {joined, path.substr(last == std::string::npos ? 0 : last + 1),
                                    path.substr(0, path.find('.'))}) {
      gflags::CommandLineFlagInfo info;
      if (gflags::GetCommandLineFlagInfo(name.c_str(), &info)) return "--" + name;
    }
    return path;
  });
}

int Fail(const std::string& message, int code) {
  std::fprintf(stderr, "%s: error: %s\n", ToolName().c_str(), FieldPathsAsFlags(message).c_str());
  std::fflush(stderr);
  return code;
}

bool RefuseFlag(const char* flag, const std::string& value, const std::string& rule) {
  const std::string message = std::string("--") + flag + "=" + value + ": " + rule;
  if (bad_flags_exit) std::exit(Fail(message));
  const std::lock_guard<std::mutex> lock(last_bad_flag_mutex);
  last_bad_flag = message;
  return false;
}

void SetBadFlagsExit(bool exit) { bad_flags_exit = exit; }

namespace {
// The message of the latest RefuseFlag that returned false since the last call ("" when
// none); the next call returns "" unless another value was refused in between.
std::string TakeLastBadFlag() {
  const std::lock_guard<std::mutex> lock(last_bad_flag_mutex);
  std::string message;
  message.swap(last_bad_flag);
  return message;
}
}  // namespace

bool SetFlagValue(const std::string& name, const std::string& value, std::string* error) {
  gflags::CommandLineFlagInfo info;
  if (!gflags::GetCommandLineFlagInfo(name.c_str(), &info)) {
    *error = "--" + name + "=" + value + ": unknown flag";
    return false;
  }
  TakeLastBadFlag();  // only this value's refusal counts
  if (!gflags::SetCommandLineOption(name.c_str(), value.c_str()).empty()) return true;
  // The validator's message, or gflags refused the text itself (not a number).
  *error = TakeLastBadFlag();
  if (error->empty()) *error = "--" + name + "=" + value + ": not a valid " + info.type;
  return false;
}

std::string WithFrameFile(const std::string& message, const std::vector<std::string>& paths) {
  int frame = -1, consumed = 0;
  if (std::sscanf(message.c_str(), "frame %d %n", &frame, &consumed) < 1 || consumed == 0 ||
      frame < 0 || frame >= static_cast<int>(paths.size())) {
    return message;
  }
  return paths[frame] + ": " + message;
}

namespace {

// "frame 4", "frames 0-3,5-10": consecutive frames as ranges.
std::string FrameRanges(const std::vector<int>& frames) {
  std::string out = frames.size() == 1 ? "frame " : "frames ";
  for (size_t a = 0; a < frames.size();) {
    size_t b = a;
    while (b + 1 < frames.size() && frames[b + 1] == frames[b] + 1) ++b;
    out += (a ? "," : "") + std::to_string(frames[a]);
    if (b > a) out += "-" + std::to_string(frames[b]);
    a = b + 1;
  }
  return out;
}

}  // namespace

std::string FieldOfViewSummary(const std::vector<MaskRule>& mask_rules, MaskRule asked) {
  if (mask_rules.empty()) return "field of view: the given masks";
  std::vector<int> hull, nonzero;
  for (size_t i = 0; i < mask_rules.size(); ++i) {
    (mask_rules[i] == MaskRule::kHull ? hull : nonzero).push_back(static_cast<int>(i));
  }
  std::string out = "field of view: ";
  if (!hull.empty()) out += "convex hull of the non-zero voxels (" + FrameRanges(hull) + ")";
  if (!nonzero.empty()) {
    out += std::string(hull.empty() ? "" : "; ") + "non-zero voxels" +
           (asked == MaskRule::kHull ? ", no 3D hull" : "") + " (" + FrameRanges(nonzero) + ")";
  }
  return out;
}

bool CheckInputFileFlag(const char* flag, const std::string& path) {
  if (path.empty()) return true;
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) return RefuseFlag(flag, path, "no such file");
  if (!std::filesystem::is_regular_file(path, ec)) {
    return RefuseFlag(flag, path, "not a regular file");
  }
  if (!std::ifstream(path, std::ios::binary).is_open())
    return RefuseFlag(flag, path, "cannot open for reading");
  return true;
}

std::string CanonicalPath(const std::string& path) {
  if (path.empty()) return path;
  // Absolute first: weakly_canonical leaves a relative path relative when its first
  // component does not exist yet ("new/./x" -> "new/x", while "/abs/new/x" stays absolute).
  // The existing prefix has its symlinks, "." and ".." resolved; the rest is normalised.
  std::error_code ec;
  const std::filesystem::path absolute = std::filesystem::absolute(path, ec);
  if (ec) return std::filesystem::path(path).lexically_normal().string();
  const std::filesystem::path p = std::filesystem::weakly_canonical(absolute, ec);
  return ec ? absolute.lexically_normal().string() : p.string();
}

namespace {

// Whether a poses entry named `name` is the image `path` (see MatchPosesToImages).
bool PoseNameMatches(const std::string& name, const std::string& path) {
  if (name.empty()) return false;
  const std::string file = std::filesystem::path(path).filename().string();
  if (name == path || name == file) return true;
  std::string lower = file;
  std::transform(lower.begin(), lower.end(), lower.begin(),
                 [](unsigned char c) { return std::tolower(c); });
  for (const std::string extension : {".nii.gz", ".nii", ".mha", ".mhd", ".nrrd", ".nhdr"}) {
    if (lower.size() > extension.size() &&
        lower.compare(lower.size() - extension.size(), extension.size(), extension) == 0) {
      return name == file.substr(0, file.size() - extension.size());
    }
  }
  return false;
}

}  // namespace

bool MatchPosesToImages(const std::string& flag,
                        const std::string& path,
                        const std::vector<std::string>& image_paths,
                        PosesFile* poses,
                        std::string* error) {
  const std::vector<std::string>& names = poses->images;
  const int m = static_cast<int>(image_paths.size());
  if (std::all_of(names.begin(), names.end(), [](const std::string& n) { return n.empty(); })) {
    return true;
  }
  // Entry i names image i: kept as is, also when two images share a file name.
  bool in_order = true;
  for (int i = 0; i < m && in_order; ++i) in_order = PoseNameMatches(names[i], image_paths[i]);
  if (in_order) return true;
  const std::string prefix = "--" + flag + "=" + path + ": ";
  std::vector<int> entry_of_image(m, -1), image_of_entry(m, -1);
  for (int i = 0; i < m; ++i) {
    for (int e = 0; e < m; ++e) {
      if (!PoseNameMatches(names[e], image_paths[i])) continue;
      if (entry_of_image[i] >= 0) {
        *error = prefix + "entries " + std::to_string(entry_of_image[i]) + " and " +
                 std::to_string(e) + " both name the image " + image_paths[i];
        return false;
      }
      entry_of_image[i] = e;
    }
    if (entry_of_image[i] < 0) {
      std::string listed;
      for (int e = 0; e < m && e < 4; ++e) listed += (e > 0 ? ", " : "") + names[e];
      *error = prefix + "no entry names the image " + image_paths[i] + " (image " +
               std::to_string(i) + " of --images; the file's names: " + listed +
               (m > 4 ? ", ..." : "") + ")";
      return false;
    }
    const int e = entry_of_image[i];
    if (image_of_entry[e] >= 0) {
      *error = prefix + "entry " + std::to_string(e) + " (" + names[e] + ") names both " +
               image_paths[image_of_entry[e]] + " and " + image_paths[i];
      return false;
    }
    image_of_entry[e] = i;
  }
  PosesFile reordered;
  for (int i = 0; i < m; ++i) {
    reordered.images.push_back(names[entry_of_image[i]]);
    reordered.frame_from_world.push_back(poses->frame_from_world[entry_of_image[i]]);
  }
  // Gains and offsets are on the first entry's intensity scale: bring them to the scale of
  // the entry that is now frame 0 (g_i I_i + o_i = g_n I_n + o_n becomes
  // (g_i / g_n) I_i + (o_i - o_n) / g_n = I_n).
  // Either field may be absent (gain 1, offset 0); a field absent from the file stays so
  // when the re-gauging leaves it at its default.
  if (!poses->gain.empty() || !poses->offset.empty()) {
    const auto gain = [&](int e) { return poses->gain.empty() ? 1.0 : poses->gain[e]; };
    const auto offset = [&](int e) { return poses->offset.empty() ? 0.0 : poses->offset[e]; };
    const int first = entry_of_image[0];
    const double g_n = gain(first), o_n = offset(first);
    for (int i = 0; i < m; ++i) {
      const int e = entry_of_image[i];
      reordered.gain.push_back(i == 0 ? 1.0 : gain(e) / g_n);
      reordered.offset.push_back(i == 0 ? 0.0 : (offset(e) - o_n) / g_n);
    }
    const auto all_equal = [](const std::vector<double>& v, double x) {
      return std::all_of(v.begin(), v.end(), [x](double y) { return y == x; });
    };
    if (poses->gain.empty() && all_equal(reordered.gain, 1.0)) reordered.gain.clear();
    if (poses->offset.empty() && all_equal(reordered.offset, 0.0)) reordered.offset.clear();
  }
  LOG(INFO) << "--" << flag << "=" << path << ": entries reordered to the order of --images";
  *poses = std::move(reordered);
  return true;
}

std::vector<Photometric> PhotometricFromPoses(const PosesFile& poses) {
  std::vector<Photometric> photometric;
  if (poses.gain.empty() && poses.offset.empty()) return photometric;
  const size_t m = poses.frame_from_world.size();
  CHECK(poses.gain.empty() || poses.gain.size() == m);
  CHECK(poses.offset.empty() || poses.offset.size() == m);
  for (size_t i = 0; i < m; ++i) {
    Photometric p;
    // ReadPoses refuses gains <= 0.
    if (!poses.gain.empty()) p.log_gain = std::log(poses.gain[i]);
    if (!poses.offset.empty()) p.offset = poses.offset[i];
    photometric.push_back(p);
  }
  return photometric;
}

std::vector<std::string> SplitCommaList(const std::string& text) {
  std::vector<std::string> items;
  size_t begin = 0;
  while (begin <= text.size()) {
    size_t end = text.find(',', begin);
    if (end == std::string::npos) end = text.size();
    const std::string item = Trim(text.substr(begin, end - begin));
    if (!item.empty()) items.push_back(item);
    begin = end + 1;
  }
  return items;
}

bool ParseInputList(const std::string& flag,
                    const std::string& text,
                    std::vector<std::string>* paths,
                    std::string* error) {
  std::vector<std::string> items;
  const bool from_list = !text.empty() && text[0] == '@';
  const std::string list = from_list ? text.substr(1) : std::string();
  if (from_list) {
    std::string content;
    if (!ReadSmallTextFile(list, "--" + flag + "=" + text + ": ", &content, error)) return false;
    for (const std::string& line : Lines(content)) {
      const std::string item = Trim(line);
      if (!item.empty() && item[0] != '#') items.push_back(item);
    }
  } else {
    items = SplitCommaList(text);
  }
  for (const std::string& item : items) {
    std::error_code ec;
    if (std::filesystem::exists(item, ec) || ec) continue;  // other errors: the reader's
    *error = from_list ? "--" + flag + "=" + text + ": " + item + ": no such file"
                       : "--" + flag + ": " + item + ": no such file (--" + flag +
                             " is split at commas; a name that contains a comma can be given "
                             "in a list file, --" + flag + "=@LIST, one path per line)";
    return false;
  }
  *paths = std::move(items);
  return true;
}

bool ParseSize3(const std::string& text, Eigen::Vector3i* size, int min_value, int max_value) {
  const std::vector<std::string> items = SplitCommaList(text);
  if (items.size() != 3) return false;
  Eigen::Vector3i parsed;
  for (int a = 0; a < 3; ++a) {
    char* end = nullptr;
    const long v = std::strtol(items[a].c_str(), &end, 10);
    if (end == items[a].c_str() || *end != '\0' || v < min_value || v > max_value) return false;
    parsed[a] = static_cast<int>(v);
  }
  *size = parsed;
  return true;
}

}  // namespace dsr
