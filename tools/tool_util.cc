#include "tools/tool_util.h"

#include "core/parallel.h"

#include "core/io_image.h"

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>

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

void ExitWithBadInput(int) { std::exit(kExitBadInput); }
void ExitAfterHelp(int) { std::exit(EXIT_SUCCESS); }

std::string Trim(const std::string& text) {
  const size_t begin = text.find_first_not_of(" \t");
  if (begin == std::string::npos) return "";
  const size_t end = text.find_last_not_of(" \t");
  return text.substr(begin, end - begin + 1);
}

}  // namespace

void InitTool(const char* usage,
              const std::vector<std::string>& required_flags,
              int* argc,
              char*** argv) {
  std::string name = (*argv)[0];
  const size_t slash = name.rfind('/');
  if (slash != std::string::npos) name = name.substr(slash + 1);
  ToolName() = name;
  FLAGS_logtostderr = true;
  gflags::SetUsageMessage(usage);

  void (*const previous_exit)(int) = GFLAGS_NAMESPACE::gflags_exitfunc;
  GFLAGS_NAMESPACE::gflags_exitfunc = &ExitWithBadInput;
  gflags::ParseCommandLineNonHelpFlags(argc, argv, /*remove_flags=*/true);
  GFLAGS_NAMESPACE::gflags_exitfunc = &ExitAfterHelp;
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

int Fail(const std::string& message, int code) {
  std::fprintf(stderr, "%s: error: %s\n", ToolName().c_str(), message.c_str());
  std::fflush(stderr);
  return code;
}

void ExitBadFlag(const char* flag, const std::string& value, const std::string& rule) {
  std::exit(Fail(std::string("--") + flag + "=" + value + ": " + rule));
}

bool CheckInputFileFlag(const char* flag, const std::string& path) {
  if (path.empty()) return true;
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) ExitBadFlag(flag, path, "no such file");
  if (!std::filesystem::is_regular_file(path, ec)) ExitBadFlag(flag, path, "not a regular file");
  if (!std::ifstream(path, std::ios::binary).is_open())
    ExitBadFlag(flag, path, "cannot open for reading");
  return true;
}

std::string CanonicalPath(const std::string& path) {
  std::error_code ec;
  const std::filesystem::path p = std::filesystem::weakly_canonical(path, ec);
  return ec ? path : p.string();
}

bool CheckOutputFile(const std::string& flag,
                     const std::string& path,
                     const std::vector<std::string>& canonical_inputs,
                     std::string* error) {
  if (path.empty()) return true;
  const std::string prefix = "--" + flag + "=" + path + ": ";
  const std::string canonical = CanonicalPath(path);
  for (const std::string& input : canonical_inputs) {
    if (input == canonical) {
      *error = prefix + "is one of the inputs; inputs are never overwritten";
      return false;
    }
  }
  std::error_code ec;
  if (std::filesystem::is_directory(path, ec)) {
    *error = prefix + "is a folder, not a file name";
    return false;
  }
  std::filesystem::path folder = std::filesystem::path(path).parent_path();
  if (folder.empty()) folder = ".";
  if (!std::filesystem::is_directory(folder, ec)) {
    *error = prefix + "folder " + folder.string() + " does not exist";
    return false;
  }
  if (access(folder.c_str(), W_OK) != 0) {
    *error = prefix + "folder " + folder.string() + " is not writable";
    return false;
  }
  return true;
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

bool ParseVector3(const std::string& text, Eigen::Vector3d* vector) {
  const std::vector<std::string> items = SplitCommaList(text);
  if (items.size() != 3) return false;
  Eigen::Vector3d parsed;
  for (int a = 0; a < 3; ++a) {
    char* end = nullptr;
    parsed[a] = std::strtod(items[a].c_str(), &end);
    if (end == items[a].c_str() || *end != '\0' || !std::isfinite(parsed[a])) return false;
  }
  *vector = parsed;
  return true;
}

bool ReadFrames(const std::vector<std::string>& image_paths,
                const std::vector<std::string>& mask_paths,
                int mask_erosion,
                int num_threads,
                std::vector<Image>* images,
                std::vector<Mask>* masks,
                std::string* error) {
  const int m = static_cast<int>(image_paths.size());
  images->assign(m, Image());
  masks->assign(m, Mask());
  std::vector<std::string> read_errors(m);
  ParallelFor(0, m, num_threads, [&](int64_t i) {
    std::string& e = read_errors[i];
    if (!ReadImage(image_paths[i], &(*images)[i], &e)) return;
    if (!mask_paths.empty()) {
      ReadMask(mask_paths[i], (*images)[i].geometry, &(*masks)[i], &e);
      return;
    }
    (*masks)[i] = MaskFromNonZero((*images)[i], mask_erosion);
    if (CountInside((*masks)[i]) == 0) {
      e = image_paths[i] + ": no voxel left in the field of view (non-zero voxels eroded by "
          "--mask_erosion=" + std::to_string(mask_erosion) + ")";
    }
  });
  for (const std::string& e : read_errors) {
    if (!e.empty()) {
      *error = e;
      return false;
    }
  }
  return true;
}

}  // namespace dsr
