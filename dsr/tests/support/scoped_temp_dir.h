// A fresh, private folder under testing::TempDir() (mkdtemp) for one test or one test
// suite, removed with its contents when the object goes out of scope. Every test that
// writes files uses one, so tests never share files and nothing is left behind.
#ifndef DSR_TESTS_SUPPORT_SCOPED_TEMP_DIR_H_
#define DSR_TESTS_SUPPORT_SCOPED_TEMP_DIR_H_

#include <stdlib.h>

#include <algorithm>
#include <filesystem>
#include <string>
#include <system_error>
#include <vector>

#include <gtest/gtest.h>

namespace dsr {

class ScopedTempDir {
 public:
  // The folder is <TempDir>/<prefix>_XXXXXX: the prefix says which test left a folder
  // behind after a crash.
  explicit ScopedTempDir(const std::string& prefix = "dsr_test") {
    std::string root = ::testing::TempDir();
    while (root.size() > 1 && root.back() == '/') root.pop_back();
    std::string pattern = root + "/" + prefix + "_XXXXXX";
    if (::mkdtemp(pattern.data()) == nullptr) {
      ADD_FAILURE() << "mkdtemp failed for " << pattern;
    }
    path_ = pattern;
  }
  ~ScopedTempDir() {
    std::error_code ignored;
    // Tests may have made the folder read-only; its owner may always remove it again.
    std::filesystem::permissions(
        path_, std::filesystem::perms::owner_all, std::filesystem::perm_options::add, ignored);
    std::filesystem::remove_all(path_, ignored);
  }
  ScopedTempDir(const ScopedTempDir&) = delete;
  ScopedTempDir& operator=(const ScopedTempDir&) = delete;

  const std::string& path() const { return path_; }
  // The folder as a std::filesystem::path, to build paths with `/`.
  std::filesystem::path dir() const { return path_; }
  std::string File(const std::string& name) const { return path_ + "/" + name; }

  // Names of the entries in the folder (hidden ones included), sorted.
  std::vector<std::string> Entries() const {
    std::vector<std::string> names;
    for (const auto& entry : std::filesystem::directory_iterator(path_)) {
      names.push_back(entry.path().filename().string());
    }
    std::sort(names.begin(), names.end());
    return names;
  }

 private:
  std::string path_;
};

}  // namespace dsr

#endif  // DSR_TESTS_SUPPORT_SCOPED_TEMP_DIR_H_
