// Flagfiles (dsr/app/flagfile.h).
#include "dsr/app/flagfile.h"

#include <sys/stat.h>

#include <cerrno>
#include <cstring>
#include <fstream>

#include "dsr/app/inputs.h"
#include "dsr/util/text.h"

namespace dsr {

bool ReadSmallTextFile(const std::string& path, const std::string& prefix, std::string* text,
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
  // A UTF-8 byte-order mark (editors on Windows write one) is not part of the first line,
  // as a CR before each newline is not part of its line.
  if (text->compare(0, 3, "\xEF\xBB\xBF") == 0) text->erase(0, 3);
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

namespace {

// gflags' --fromenv/--tryfromenv=flagfile would read a flagfile behind this check's back.
bool ReadsFlagfileFromEnvironment(const std::string& name, const std::string& value) {
  if (name != "fromenv" && name != "tryfromenv") return false;
  for (const std::string& item : SplitCommaList(value)) {
    if (item == "flagfile") return true;
  }
  return false;
}

// Expands --flagfile arguments in place.
class FlagfileExpander {
 public:
  explicit FlagfileExpander(const FlagLookup& known) : known_(known) {}

  bool ExpandCommandLine(const std::vector<std::string>& argv, std::vector<std::string>* out,
                         std::string* error) {
    const int argc = static_cast<int>(argv.size());
    if (argc > 0) out->push_back(argv[0]);
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
      bool is_bool = false, negated_is_bool = false;
      const bool known = known_(name, &is_bool);
      const bool negated_bool = !known && !has_value && name.compare(0, 2, "no") == 0 &&
                                known_(name.substr(2), &negated_is_bool) && negated_is_bool;
      if (!known && !negated_bool) {
        *error = where + "unknown flag --" + name + " (see --helpshort)";
        return false;
      }
      if (known && !has_value && !is_bool) {
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

 private:
  static constexpr int kMaxDepth = 64;

  const FlagLookup& known_;
  std::vector<std::string> open_;     // canonical paths of the flagfiles being expanded
  std::vector<std::string> spelled_;  // the same, as written
};

}  // namespace

bool ExpandFlagfile(const std::string& path, const FlagLookup& known,
                    std::vector<std::string>* args, std::string* error) {
  return FlagfileExpander(known).ExpandFile(path, args, error);
}

bool ExpandCommandLine(const std::vector<std::string>& argv, const FlagLookup& known,
                       std::vector<std::string>* out, std::string* error) {
  return FlagfileExpander(known).ExpandCommandLine(argv, out, error);
}

}  // namespace dsr
