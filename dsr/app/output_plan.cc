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
  for (const std::string& p : image_paths) AddInputImage("images", p);
  for (const std::string& p : mask_paths) AddInputImage("masks", p);
  for (const auto& [flag, value] : {std::pair<const char*, const std::string&>{"images", images_value},
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

bool OutputPlan::Check(std::string* error) const {
  std::error_code ec;
  // Each entry's identity: its canonical path, and for an existing file its device and
  // inode (one file under two names: hard links, bind mounts).
  using Inode = std::pair<dev_t, ino_t>;
  std::vector<std::optional<Inode>> inodes(entries_.size());
  std::map<std::string, size_t> input_by_path, folder_by_path;
  std::map<Inode, size_t> input_by_inode;
  for (size_t i = 0; i < entries_.size(); ++i) {
    const Entry& e = entries_[i];
    struct stat st;
    if (::stat(e.canonical.c_str(), &st) == 0) inodes[i] = Inode(st.st_dev, st.st_ino);
    if (e.kind == Kind::kInput) {
      input_by_path.emplace(e.canonical, i);
      if (inodes[i]) input_by_inode.emplace(*inodes[i], i);
    } else if (e.kind == Kind::kOutputFolder) {
      folder_by_path.emplace(e.canonical, i);
    }
  }
  const auto find_input = [&](size_t i) -> const Entry* {
    auto by_path = input_by_path.find(entries_[i].canonical);
    if (by_path != input_by_path.end()) return &entries_[by_path->second];
    if (!inodes[i]) return nullptr;
    auto by_inode = input_by_inode.find(*inodes[i]);
    return by_inode == input_by_inode.end() ? nullptr : &entries_[by_inode->second];
  };
  // Folders first: a file output inside a folder that cannot be made is reported once,
  // at the folder.
  for (size_t f = 0; f < entries_.size(); ++f) {
    const Entry& folder = entries_[f];
    if (folder.kind != Kind::kOutputFolder) continue;
    const std::string prefix = "--" + folder.flag + "=" + folder.value + ": ";
    const std::string what = folder.path == folder.value ? "" : " " + folder.path;
    if (const Entry* input = find_input(f)) {
      *error = prefix + "cannot create the folder" + what + ": it is the input " + Describe(*input);
      return false;
    }
    // The folder itself, else its nearest existing ancestor, must be a writable folder.
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
  }
  std::map<std::string, size_t> output_by_path;
  std::map<Inode, size_t> output_by_inode;
  for (size_t o = 0; o < entries_.size(); ++o) {
    const Entry& out = entries_[o];
    if (out.kind != Kind::kOutputFile) continue;
    if (const Entry* input = find_input(o)) {
      *error = Describe(out) + " would overwrite the input " + Describe(*input) +
               ": inputs are never overwritten";
      return false;
    }
    size_t earlier = output_by_path.emplace(out.canonical, o).first->second;
    if (earlier == o && inodes[o]) earlier = output_by_inode.emplace(*inodes[o], o).first->second;
    if (earlier != o) {
      *error = Describe(entries_[earlier]) + " and " + Describe(out) +
               " are the same file " + out.canonical + ": one would overwrite the other";
      return false;
    }
    auto folder = folder_by_path.find(out.canonical);
    if (folder != folder_by_path.end()) {
      *error = Describe(out) + " is the folder that " + Describe(entries_[folder->second]) +
               " creates";
      return false;
    }
    const std::string prefix = Describe(out) + ": ";
    if (fs::is_directory(out.canonical, ec)) {
      *error = prefix + "is a folder, not a file name";
      return false;
    }
    const std::string parent = fs::path(out.canonical).parent_path().string();
    if (folder_by_path.count(parent) != 0) continue;  // checked with the folders above
    if (!fs::is_directory(parent, ec)) {
      *error = prefix + "folder " + fs::path(out.path).parent_path().string() + " does not exist";
      return false;
    }
    if (::access(parent.c_str(), W_OK) != 0) {
      *error = prefix + "folder " + fs::path(out.path).parent_path().string() + " is not writable";
      return false;
    }
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

}  // namespace dsr
