#include "dsr/app/output_plan.h"

#include <sys/stat.h>
#include <unistd.h>

#include <filesystem>
#include <map>
#include <optional>
#include <system_error>
#include <utility>

#include "dsr/io/io_image.h"
#include "dsr/app/inputs.h"
#include "dsr/io/io_phases.h"

namespace dsr {
namespace {

namespace fs = std::filesystem;

// CanonicalPath without a trailing separator, so that "o/" and "o" compare equal.
std::string Canonical(const std::string& path) {
  std::string canonical = CanonicalPath(path);
  while (canonical.size() > 1 && canonical.back() == '/') canonical.pop_back();
  return canonical;
}

std::string Join(const std::string& folder, const std::string& name) {
  return (fs::path(folder) / name).string();
}

}  // namespace

void OutputPlan::Add(Kind kind,
                     const std::string& flag,
                     const std::string& value,
                     const std::string& path,
                     const std::string& role) {
  entries_.push_back(Entry{kind, flag, value, path, Canonical(path), role});
}

void OutputPlan::AddInputFile(const std::string& flag, const std::string& path) {
  if (!path.empty()) Add(Kind::kInput, flag, path, path, "");
}

void OutputPlan::AddInputImage(const std::string& flag, const std::string& path) {
  if (path.empty()) return;
  AddInputImageIn(flag, path, path);
}

void OutputPlan::AddFrameInputs(const std::vector<std::string>& image_paths,
                                const std::vector<std::string>& mask_paths,
                                const std::string& images_value,
                                const std::string& masks_value) {
  for (const std::string& view : image_paths) {
    for (const std::string& p : ViewFiles(view)) AddInputImage("images", p);
  }
  for (const std::string& p : mask_paths) AddInputImage("masks", p);
  for (const auto& [flag, value] :
       {std::pair<const char*, const std::string&>{"images", images_value},
                                    {"masks", masks_value}}) {
    if (value.rfind('@', 0) == 0) AddInputFileIn(flag, value, value.substr(1));  // @LIST
  }
}

void OutputPlan::AddInputFileIn(const std::string& flag,
                                const std::string& value,
                                const std::string& file) {
  Add(Kind::kInput, flag, value, file, "");
}

void OutputPlan::AddInputImageIn(const std::string& flag,
                                 const std::string& value,
                                 const std::string& file) {
  Add(Kind::kInput, flag, value, file, "");
  std::vector<std::string> files;
  std::string ignored;  // the reader reports a broken header, before anything is written
  if (!ImageDataFiles(file, &files, &ignored)) return;
  for (const std::string& data : files) {
    if (data != file) Add(Kind::kInput, flag, value, data, "its data file");
  }
}

void OutputPlan::AddOutputFile(const std::string& flag, const std::string& path) {
  if (!path.empty()) Add(Kind::kOutputFile, flag, path, path, "");
}

void OutputPlan::AddOutputImage(const std::string& flag, const std::string& path) {
  if (!path.empty()) AddWrittenImage(flag, path, path);
}

void OutputPlan::AddDerivedFile(const std::string& flag,
                                const std::string& folder,
                                const std::string& name) {
  Add(Kind::kOutputFile, flag, folder, Join(folder, name), "");
}

void OutputPlan::AddDerivedImage(const std::string& flag,
                                 const std::string& folder,
                                 const std::string& name) {
  AddWrittenImage(flag, folder, Join(folder, name));
}

void OutputPlan::AddWrittenImage(const std::string& flag,
                                 const std::string& value,
                                 const std::string& path) {
  Add(Kind::kOutputFile, flag, value, path, "");
  for (const std::string& file : WrittenImageFiles(path)) {
    if (file != path) Add(Kind::kOutputFile, flag, value, file, "its data file");
  }
}

void OutputPlan::AddOutputFolder(const std::string& flag,
                                 const std::string& value,
                                 const std::string& folder) {
  if (!folder.empty()) Add(Kind::kOutputFolder, flag, value, folder, "");
}

std::string OutputPlan::Describe(const Entry& e) {
  std::string text = "--" + e.flag + "=" + e.value;
  if (e.path != e.value || !e.role.empty()) {
    text += " (" + (e.role.empty() ? std::string() : e.role + " ") + e.path + ")";
  }
  return text;
}

// Each entry's identity: its canonical path, and for an existing file its device and inode
// (one file under two names: hard links, bind mounts).
struct OutputPlan::Index {
  using Inode = std::pair<dev_t, ino_t>;
  std::vector<std::optional<Inode>> inodes;
  std::vector<mode_t> modes;  // of existing entries (0: none)
  std::map<std::string, size_t> input_by_path, folder_by_path;
  std::map<Inode, size_t> input_by_inode;
};

OutputPlan::Index OutputPlan::MakeIndex() const {
  Index index;
  index.inodes.resize(entries_.size());
  index.modes.assign(entries_.size(), 0);
  for (size_t i = 0; i < entries_.size(); ++i) {
    const Entry& e = entries_[i];
    struct stat st;
    if (::stat(e.canonical.c_str(), &st) == 0) {
      index.inodes[i] = Index::Inode(st.st_dev, st.st_ino);
      index.modes[i] = st.st_mode;
    }
    if (e.kind == Kind::kInput) {
      index.input_by_path.emplace(e.canonical, i);
      if (index.inodes[i]) index.input_by_inode.emplace(*index.inodes[i], i);
    } else if (e.kind == Kind::kOutputFolder) {
      index.folder_by_path.emplace(e.canonical, i);
    }
  }
  return index;
}

const OutputPlan::Entry* OutputPlan::FindInput(const Index& index, size_t i) const {
  auto by_path = index.input_by_path.find(entries_[i].canonical);
  if (by_path != index.input_by_path.end()) return &entries_[by_path->second];
  if (!index.inodes[i]) return nullptr;
  auto by_inode = index.input_by_inode.find(*index.inodes[i]);
  return by_inode == index.input_by_inode.end() ? nullptr : &entries_[by_inode->second];
}

namespace {

// Longest file name (one path component) Linux file systems take (NAME_MAX).
constexpr size_t kMaxNameBytes = 255;

// Why `path` cannot be written or created whatever the permissions, or "": a component
// longer than kMaxNameBytes, or a symlink on it whose target is missing or loops.
std::string PathProblem(const std::string& path) {
  fs::path prefix;
  for (const fs::path& part : fs::path(path)) {
    const std::string name = part.string();
    if (name.size() > kMaxNameBytes) {
      return "a name in it is " + std::to_string(name.size()) + " bytes long, more than the " +
             std::to_string(kMaxNameBytes) + " a file system takes";
    }
    prefix /= part;
    std::error_code ec;
    if (!fs::is_symlink(fs::symlink_status(prefix, ec))) continue;
    if (fs::exists(fs::status(prefix, ec)) && !ec) continue;
    std::error_code read_ec;
    const fs::path target = fs::read_symlink(prefix, read_ec);
    return prefix.string() + " is a symlink" +
           (ec == std::errc::no_such_file_or_directory
                ? " to a missing file or folder (" + target.string() + ")"
                : " that cannot be followed (" + ec.message() + ")");
  }
  return "";
}

}  // namespace

bool OutputPlan::CheckFolder(const Index& index, size_t f, std::string* error) const {
  const Entry& folder = entries_[f];
  const std::string prefix = "--" + folder.flag + "=" + folder.value + ": ";
  const std::string what = folder.path == folder.value ? "" : " " + folder.path;
  const std::string problem = PathProblem(folder.path);
  if (!problem.empty()) {
    *error = prefix + "cannot create the folder" + what + ": " + problem;
    return false;
  }
  if (const Entry* input = FindInput(index, f)) {
    *error = prefix + "cannot create the folder" + what + ": it is the input " + Describe(*input);
    return false;
  }
  // The folder itself, else its nearest existing ancestor, must be a writable folder.
  std::error_code ec;
  fs::path existing(folder.canonical);
  while (!fs::exists(existing, ec) && existing.has_parent_path() &&
         existing.parent_path() != existing) {
    existing = existing.parent_path();
  }
  if (!fs::is_directory(existing, ec)) {
    *error = prefix + "cannot create the folder" + what + " (" + existing.string() +
             " is not a folder)";
    return false;
  }
  if (::access(existing.c_str(), W_OK) != 0) {
    *error = prefix + (existing.string() == folder.canonical
                           ? "folder" + what + " is not writable"
                           : "cannot create the folder" + what + " (" + existing.string() +
                                 " is not writable)");
    return false;
  }
  return true;
}

namespace {

// What an existing non-regular file is ("a FIFO"), or "" for a regular file or none.
std::string SpecialFileKind(mode_t mode) {
  if (mode == 0 || S_ISREG(mode) || S_ISDIR(mode)) return "";
  if (S_ISFIFO(mode)) return "a FIFO";
  if (S_ISCHR(mode)) return "a character device";
  if (S_ISBLK(mode)) return "a block device";
  if (S_ISSOCK(mode)) return "a socket";
  return "not a regular file";
}

}  // namespace

bool OutputPlan::CheckOutputFile(const Index& index, size_t o, std::string* error) const {
  const Entry& out = entries_[o];
  const std::string prefix = Describe(out) + ": ";
  if (!out.path.empty() && out.path.back() == '/') {
    *error = prefix + "ends with '/', expected a file name";
    return false;
  }
  const std::string problem = PathProblem(out.path);
  if (!problem.empty()) {
    *error = prefix + problem;
    return false;
  }
  const auto folder = index.folder_by_path.find(out.canonical);
  if (folder != index.folder_by_path.end()) {
    *error = Describe(out) + " is the folder that " + Describe(entries_[folder->second]) +
             " creates";
    return false;
  }
  std::error_code ec;
  if (fs::is_directory(out.canonical, ec)) {
    *error = prefix + "is a folder, not a file name";
    return false;
  }
  // Every output is written to a new file renamed into place, which would replace a FIFO or
  // a device by a regular file.
  const std::string special = SpecialFileKind(index.modes[o]);
  if (!special.empty()) {
    *error = prefix + "is " + special + ", not a regular file (outputs are written to a new "
             "file renamed into place, which would replace it)";
    return false;
  }
  const std::string parent = fs::path(out.canonical).parent_path().string();
  if (index.folder_by_path.count(parent) != 0) return true;  // checked with the folders
  if (!fs::is_directory(parent, ec)) {
    *error = prefix + "folder " + fs::path(out.path).parent_path().string() + " does not exist";
    return false;
  }
  if (::access(parent.c_str(), W_OK) != 0) {
    *error = prefix + "folder " + fs::path(out.path).parent_path().string() + " is not writable";
    return false;
  }
  return true;
}

bool OutputPlan::Check(std::string* error) const {
  const Index index = MakeIndex();
  // Folders first: a file output inside a folder that cannot be made is reported once, at
  // the folder.
  for (size_t f = 0; f < entries_.size(); ++f) {
    if (entries_[f].kind == Kind::kOutputFolder && !CheckFolder(index, f, error)) return false;
  }
  std::map<std::string, size_t> output_by_path;
  std::map<Index::Inode, size_t> output_by_inode;
  for (size_t o = 0; o < entries_.size(); ++o) {
    const Entry& out = entries_[o];
    if (out.kind != Kind::kOutputFile) continue;
    if (const Entry* input = FindInput(index, o)) {
      *error = Describe(out) + " would overwrite the input " + Describe(*input) +
               ": inputs are never overwritten";
      return false;
    }
    size_t earlier = output_by_path.emplace(out.canonical, o).first->second;
    if (earlier == o && index.inodes[o]) {
      earlier = output_by_inode.emplace(*index.inodes[o], o).first->second;
    }
    if (earlier != o) {
      *error = Describe(entries_[earlier]) + " and " + Describe(out) +
               " are the same file " + out.canonical + ": one would overwrite the other";
      return false;
    }
    if (!CheckOutputFile(index, o, error)) return false;
  }
  return true;
}

bool OutputPlan::CreateFolders(std::string* error) const {
  for (const Entry& e : entries_) {
    if (e.kind != Kind::kOutputFolder) continue;
    std::error_code ec;
    fs::create_directories(e.path, ec);
    if (ec || !fs::is_directory(e.path, ec)) {
      *error = "--" + e.flag + "=" + e.value + ": cannot create the folder" +
               (e.path == e.value ? std::string() : " " + e.path) +
               (ec ? " (" + ec.message() + ")" : std::string());
      return false;
    }
  }
  return true;
}

void InputRegistry::AddImage(const std::string& flag, const std::string& path) {
  if (path.empty()) return;
  const std::lock_guard<std::mutex> lock(mutex_);
  images_.emplace_back(flag, path);
}

void InputRegistry::AddFile(const std::string& flag, const std::string& path) {
  if (path.empty()) return;
  const std::lock_guard<std::mutex> lock(mutex_);
  files_.emplace_back(flag, path);
}

void InputRegistry::AddTo(OutputPlan* plan) const {
  const std::lock_guard<std::mutex> lock(mutex_);
  for (const auto& [flag, path] : images_) plan->AddInputImage(flag, path);
  for (const auto& [flag, path] : files_) plan->AddInputFile(flag, path);
}

}  // namespace dsr
