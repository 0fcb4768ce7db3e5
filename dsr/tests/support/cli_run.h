// Runs a command-line tool for CLI tests: exit code, stdout, stderr and its error lines.
#ifndef DSR_TESTS_SUPPORT_CLI_RUN_H_
#define DSR_TESTS_SUPPORT_CLI_RUN_H_

#include <sys/wait.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

namespace dsr {
namespace testing_cli {

struct ToolRun {
  int exit_code = -1;
  std::string out, err;
  std::vector<std::string> err_lines;    // non-empty stderr lines
  std::vector<std::string> error_lines;  // those that contain "error"/"ERROR"
};

inline std::string ReadText(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

// Runs `binary args` (args are plain shell words) with stdout/stderr captured in `scratch`.
inline ToolRun RunTool(const std::string& binary, const std::string& args,
                       const std::filesystem::path& scratch) {
  const std::filesystem::path out = scratch / "stdout.txt", err = scratch / "stderr.txt";
  const std::string command =
      binary + " " + args + " > " + out.string() + " 2> " + err.string() + " < /dev/null";
  const int status = std::system(command.c_str());
  ToolRun run;
  run.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  run.out = ReadText(out);
  run.err = ReadText(err);
  std::istringstream lines(run.err);
  for (std::string line; std::getline(lines, line);) {
    if (line.empty()) continue;
    run.err_lines.push_back(line);
    if (line.find("error") != std::string::npos || line.find("ERROR") != std::string::npos) {
      run.error_lines.push_back(line);
    }
  }
  std::filesystem::remove(out);
  std::filesystem::remove(err);
  return run;
}

}  // namespace testing_cli
}  // namespace dsr

#endif  // DSR_TESTS_SUPPORT_CLI_RUN_H_
