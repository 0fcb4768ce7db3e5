// Atomic output (see atomic_file.h): the data goes to a hidden temporary file created
// exclusively (O_EXCL) in the destination's folder (or, for multi-file formats, a hidden
// private folder there), is flushed to disk (fsync), and is then renamed over the
// destination with rename(2), which replaces it in one step on POSIX file systems. On any
// failure the temporary file is removed and the destination is untouched.
#include "dsr/util/atomic_file.h"

#include <fcntl.h>
#include <signal.h>
#include <unistd.h>

#include <atomic>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <random>
#include <thread>
#include <vector>

#include "dsr/util/text.h"

namespace dsr {
namespace {

namespace fs = std::filesystem;

// Longest file name most Linux file systems accept (NAME_MAX).
constexpr size_t kMaxFileNameLength = 255;
// Length of the ".tmp-XXXXXXXX" part of temporary names.
constexpr size_t kSuffixLength = 13;
// Attempts at finding an unused temporary name before giving up.
constexpr int kTemporaryNameAttempts = 100;

// "a.nii.gz" -> ".nii.gz", "a.raw.gz" -> ".raw.gz", "a.json" -> ".json", "a" -> "". A
// compression suffix keeps the extension before it, so writers that pick the format from
// the name (ITK) see the same format in the temporary name.
std::string FullExtension(const std::string& filename) {
  const fs::path name(filename);
  std::string ext = name.extension().string();
  if (Lower(ext) == ".gz" || Lower(ext) == ".bz2" || Lower(ext) == ".xz") {
    ext = name.stem().extension().string() + ext;
  }
  return ext;
}

std::string RandomSuffix() {
  thread_local std::mt19937_64 rng(std::random_device{}() ^ static_cast<uint64_t>(getpid()) ^
                                   std::hash<std::thread::id>{}(std::this_thread::get_id()));
  char suffix[32];
  std::snprintf(
      suffix, sizeof(suffix), ".tmp-%08llx", static_cast<unsigned long long>(rng() & 0xffffffffu));
  return suffix;
}

fs::path FolderOf(const std::string& path) {
  const fs::path p(path);
  return p.has_parent_path() ? p.parent_path() : fs::path(".");
}

// The temporary files being written, so that a signal that ends the process removes them
// (RemoveTemporaryFilesOnTermination): fixed slots a signal handler can read without
// allocating or locking. A path that does not fit a slot is not recorded.
constexpr int kPendingSlots = 64;
constexpr size_t kPendingPathBytes = 4096;
// A slot is free (0), being filled (1) or holds the path of a file being written (2): the
// handler reads only filled slots, so it never sees half a path.
struct PendingSlot {
  std::atomic<int> state{0};
  char path[kPendingPathBytes];
};
PendingSlot pending_slots[kPendingSlots];

// Records `path` as a temporary file being written while it lives.
class PendingTemporary {
 public:
  explicit PendingTemporary(const std::string& path) {
    if (path.size() >= kPendingPathBytes) return;
    for (int i = 0; i < kPendingSlots; ++i) {
      int expected = 0;
      PendingSlot& s = pending_slots[i];
      if (s.state.load(std::memory_order_relaxed) == 0 &&
          s.state.compare_exchange_strong(expected, 1, std::memory_order_acquire)) {
        std::memcpy(s.path, path.c_str(), path.size() + 1);
        s.state.store(2, std::memory_order_release);
        slot_ = i;
        return;
      }
    }
  }
  ~PendingTemporary() {
    if (slot_ >= 0) pending_slots[slot_].state.store(0, std::memory_order_release);
  }
  PendingTemporary(const PendingTemporary&) = delete;
  PendingTemporary& operator=(const PendingTemporary&) = delete;

 private:
  int slot_ = -1;
};

// Removes the temporary files being written (unlink is async-signal-safe), then ends the
// process as the signal would have.
extern "C" void RemoveTemporaryFilesAndReraise(int signal_number) {
  for (PendingSlot& s : pending_slots) {
    if (s.state.load(std::memory_order_acquire) == 2) ::unlink(s.path);
  }
  ::signal(signal_number, SIG_DFL);
  ::raise(signal_number);
}

// Creates an empty, unused file ".<stem>.tmp-XXXXXXXX<ext>" next to `path` (mode 0666
// minus the umask, as for any new file) and returns its name in `temp`.
bool CreateTemporaryFile(const std::string& path, std::string* temp, std::string* error) {
  const fs::path p(path);
  const std::string filename = p.filename().string();
  const std::string ext = FullExtension(filename);
  std::string stem = filename.substr(0, filename.size() - ext.size());
  const size_t fixed = 1 + kSuffixLength + ext.size();
  if (stem.size() + fixed > kMaxFileNameLength) {
    stem.resize(kMaxFileNameLength > fixed ? kMaxFileNameLength - fixed : 0);
  }
  int last_errno = 0;
  for (int attempt = 0; attempt < kTemporaryNameAttempts; ++attempt) {
    const std::string candidate = (FolderOf(path) / ("." + stem + RandomSuffix() + ext)).string();
    const int fd = ::open(candidate.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0666);
    if (fd >= 0) {
      ::close(fd);
      *temp = candidate;
      return true;
    }
    last_errno = errno;
    if (last_errno != EEXIST) break;
  }
  *error = path + ": cannot create a file in folder " + FolderOf(path).string() + " (" +
           std::strerror(last_errno) + ")";
  return false;
}

// Flushes a finished file to disk so that the rename never publishes a file whose data is
// still only in the page cache (a crash would then leave an empty or partial file).
bool SyncFile(const std::string& file, std::string* reason) {
  const int fd = ::open(file.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0 || ::fsync(fd) != 0) {
    *reason = std::strerror(errno);
    if (fd >= 0) ::close(fd);
    return false;
  }
  ::close(fd);
  return true;
}

// Makes the rename itself durable. Best effort: some file systems refuse fsync on folders.
void SyncFolder(const fs::path& folder) {
  const int fd = ::open(folder.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (fd < 0) return;
  ::fsync(fd);
  ::close(fd);
}

std::string ReplaceAll(std::string text, const std::string& from, const std::string& to) {
  if (from.empty()) return text;
  for (size_t at = text.find(from); at != std::string::npos; at = text.find(from, at + to.size())) {
    text.replace(at, from.size(), to);
  }
  return text;
}

bool WriteAll(int fd, const std::string& contents) {
  const char* data = contents.data();
  size_t left = contents.size();
  while (left > 0) {
    const ssize_t written = ::write(fd, data, left);
    if (written < 0) {
      if (errno == EINTR) continue;
      return false;
    }
    data += written;
    left -= static_cast<size_t>(written);
  }
  return true;
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
  if (!p.has_filename()) {
    *error = path + ": ends with '/', expected a file name";
    return false;
  }
  const fs::path folder = FolderOf(path);
  if (!fs::exists(folder, ec)) {
    *error = path + ": folder " + folder.string() + " does not exist";
    return false;
  }
  if (!fs::is_directory(folder, ec)) {
    *error = path + ": " + folder.string() + " is not a folder";
    return false;
  }
  if (::access(folder.c_str(), W_OK | X_OK) != 0) {
    *error = path + ": folder " + folder.string() + " is not writable";
    return false;
  }
  return true;
}

bool WriteViaTemporaryFile(
    const std::string& path,
    const std::function<bool(const std::string& temp_path, std::string* error)>& write,
    std::string* error) {
  if (!CheckWritableOutputPath(path, error)) return false;
  std::string temp;
  if (!CreateTemporaryFile(path, &temp, error)) return false;
  const PendingTemporary pending(temp);
  std::string why;
  bool written = false;
  try {
    written = write(temp, &why);
  } catch (...) {
    std::remove(temp.c_str());
    throw;
  }
  if (!written) {
    std::remove(temp.c_str());
    // Writers name the file they were given; the user knows only `path`.
    *error = why.empty() ? path + ": write failed" : ReplaceAll(why, temp, path);
    return false;
  }
  std::string reason;
  if (!SyncFile(temp, &reason)) {
    std::remove(temp.c_str());
    *error = path + ": cannot flush the written data to disk (" + reason + ")";
    return false;
  }
  if (std::rename(temp.c_str(), path.c_str()) != 0) {
    reason = std::strerror(errno);
    std::remove(temp.c_str());
    *error = path + ": cannot move the finished file into place (" + reason + ")";
    return false;
  }
  SyncFolder(FolderOf(path));
  return true;
}

bool WriteFilesViaTemporaryFolder(
    const std::string& path,
    const std::function<bool(const std::string& temp_path, std::string* error)>& write,
    std::string* error) {
  if (!CheckWritableOutputPath(path, error)) return false;
  const fs::path folder = FolderOf(path);
  const std::string filename = fs::path(path).filename().string();
  std::string temp_folder =
      (folder / ("." + filename.substr(0, kMaxFileNameLength - 12) + ".tmp-XXXXXX")).string();
  if (::mkdtemp(temp_folder.data()) == nullptr) {
    *error =
        path + ": cannot create a folder in " + folder.string() + " (" + std::strerror(errno) + ")";
    return false;
  }
  const fs::path temp_path = fs::path(temp_folder) / filename;
  auto clean_up = [&] {
    std::error_code ignored;
    fs::remove_all(temp_folder, ignored);
  };
  std::string why;
  bool written = false;
  try {
    written = write(temp_path.string(), &why);
  } catch (...) {
    clean_up();
    throw;
  }
  if (!written) {
    clean_up();
    *error = why.empty() ? path + ": write failed" : ReplaceAll(why, temp_path.string(), path);
    return false;
  }
  std::vector<fs::path> files;
  std::error_code ec;
  for (fs::directory_iterator it(temp_folder, ec), end; !ec && it != end; it.increment(ec)) {
    if (it->path().filename() != filename) files.push_back(it->path());
  }
  if (ec) {
    // A data file missed here would be left behind while its header is published.
    clean_up();
    *error = path + ": cannot list the written files (" + ec.message() + ")";
    return false;
  }
  files.push_back(temp_path);  // the header goes last
  for (const fs::path& file : files) {
    std::string reason;
    if (!SyncFile(file.string(), &reason)) {
      clean_up();
      *error = path + ": cannot flush " + file.filename().string() + " to disk (" + reason + ")";
      return false;
    }
  }
  for (const fs::path& file : files) {
    const fs::path destination = folder / file.filename();
    if (std::rename(file.c_str(), destination.c_str()) != 0) {
      const std::string reason = std::strerror(errno);
      clean_up();
      *error = path + ": cannot move " + destination.string() + " into place (" + reason + ")";
      return false;
    }
  }
  clean_up();
  SyncFolder(folder);
  return true;
}

bool WriteFileAtomically(const std::string& path, const std::string& contents, std::string* error) {
  return WriteViaTemporaryFile(
      path,
      [&](const std::string& temp, std::string* why) {
        const int fd = ::open(temp.c_str(), O_WRONLY | O_TRUNC | O_CLOEXEC);
        if (fd < 0 || !WriteAll(fd, contents)) {
          *why = path + ": write failed (" + std::strerror(errno) + ")";
          if (fd >= 0) ::close(fd);
          return false;
        }
        if (::close(fd) != 0) {
          *why = path + ": write failed (" + std::strerror(errno) + ")";
          return false;
        }
        return true;
      },
      error);
}

void RemoveTemporaryFilesOnTermination() {
  struct sigaction action;
  std::memset(&action, 0, sizeof(action));
  action.sa_handler = &RemoveTemporaryFilesAndReraise;
  sigemptyset(&action.sa_mask);
  for (const int signal_number : {SIGINT, SIGTERM, SIGHUP}) {
    struct sigaction previous;
    // A signal the caller ignores (nohup, a shell's background job) stays ignored.
    if (::sigaction(signal_number, nullptr, &previous) == 0 && previous.sa_handler == SIG_IGN) {
      continue;
    }
    ::sigaction(signal_number, &action, nullptr);
  }
}

}  // namespace dsr
