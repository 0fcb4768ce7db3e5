// Atomic output through a temporary file in the destination folder plus rename(2).
#include "core/atomic_file.h"

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <random>
#include <unistd.h>

namespace dsr {
namespace {

namespace fs = std::filesystem;

// "name.nii.gz" -> ".nii.gz", "a.json" -> ".json", "a" -> "".
std::string FullExtension(const std::string& filename) {
  const std::string name = fs::path(filename).filename().string();
  if (name.size() > 7 && name.compare(name.size() - 7, 7, ".nii.gz") == 0) return ".nii.gz";
  return fs::path(name).extension().string();
}

std::string TemporaryPathFor(const std::string& path) {
  static std::mt19937_64 rng(std::random_device{}() ^ static_cast<uint64_t>(getpid()));
  const fs::path p(path);
  const std::string ext = FullExtension(path);
  std::string stem = p.filename().string();
  stem = stem.substr(0, stem.size() - ext.size());
  char suffix[32];
  std::snprintf(suffix, sizeof(suffix), ".tmp-%08llx", static_cast<unsigned long long>(rng() & 0xffffffffu));
  return (p.parent_path() / ("." + stem + suffix + ext)).string();
}

}  // namespace

bool CheckWritableOutputPath(const std::string& path, std::string* error) {
  if (path.empty()) {
    *error = "output path is empty";
    return false;
  }
  const fs::path p(path);
  std::error_code ec;
  if (fs::is_directory(p, ec)) {
    *error = path + ": is a folder, expected a file name";
    return false;
  }
  const fs::path folder = p.has_parent_path() ? p.parent_path() : fs::path(".");
  if (!fs::is_directory(folder, ec)) {
    *error = path + ": folder " + folder.string() + " does not exist";
    return false;
  }
  if (access(folder.c_str(), W_OK) != 0) {
    *error = path + ": folder " + folder.string() + " is not writable";
    return false;
  }
  return true;
}

bool WriteViaTemporaryFile(const std::string& path,
                           const std::function<bool(const std::string&, std::string*)>& write,
                           std::string* error) {
  if (!CheckWritableOutputPath(path, error)) return false;
  const std::string temp = TemporaryPathFor(path);
  std::string why;
  if (!write(temp, &why)) {
    std::remove(temp.c_str());
    *error = why.empty() ? path + ": write failed" : why;
    return false;
  }
  if (std::rename(temp.c_str(), path.c_str()) != 0) {
    const std::string reason = std::strerror(errno);
    std::remove(temp.c_str());
    *error = path + ": cannot move the finished file into place (" + reason + ")";
    return false;
  }
  return true;
}

bool WriteFileAtomically(const std::string& path,
                         const std::string& contents,
                         std::string* error) {
  return WriteViaTemporaryFile(
      path,
      [&](const std::string& temp, std::string* why) {
        std::ofstream out(temp, std::ios::binary | std::ios::trunc);
        out.write(contents.data(), static_cast<std::streamsize>(contents.size()));
        out.flush();
        if (!out) {
          *why = path + ": write failed (" + std::strerror(errno) + ")";
          return false;
        }
        return true;
      },
      error);
}

}  // namespace dsr
