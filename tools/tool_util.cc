#include "tools/tool_util.h"

#include <cstdio>
#include <sstream>

#include <gflags/gflags.h>
#include <glog/logging.h>

namespace dsr {
namespace {
std::string tool_name = "dsr";
}

void InitTool(const char* usage, int* argc, char*** argv) {
  tool_name = (*argv)[0];
  const size_t slash = tool_name.rfind('/');
  if (slash != std::string::npos) tool_name = tool_name.substr(slash + 1);
  FLAGS_logtostderr = true;
  FLAGS_minloglevel = 1;  // warnings and errors; --minloglevel=0 or --v=1 for more
  gflags::SetUsageMessage(usage);
  gflags::ParseCommandLineFlags(argc, argv, true);
  google::InitGoogleLogging(tool_name.c_str());
  LOG(INFO) << "flags:\n" << gflags::CommandlineFlagsIntoString();
}

int Fail(const std::string& message, int code) {
  std::fprintf(stderr, "%s: error: %s\n", tool_name.c_str(), message.c_str());
  return code;
}

std::vector<std::string> SplitCommaList(const std::string& text) {
  std::vector<std::string> out;
  std::stringstream s(text);
  std::string item;
  while (std::getline(s, item, ',')) {
    if (!item.empty()) out.push_back(item);
  }
  return out;
}

bool ParseSize3(const std::string& text, Eigen::Vector3i* size) {
  const std::vector<std::string> parts = SplitCommaList(text);
  if (parts.size() != 3) return false;
  for (int a = 0; a < 3; ++a) {
    try {
      size_t used = 0;
      const int v = std::stoi(parts[a], &used);
      if (used != parts[a].size() || v <= 0) return false;
      (*size)[a] = v;
    } catch (const std::exception&) {
      return false;
    }
  }
  return true;
}

}  // namespace dsr
