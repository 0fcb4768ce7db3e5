// The output plan of one tool run: every file the run will write (the output flags, the
// names the tool derives inside output folders, and the data files written next to
// detached image headers) and every file it reads (the input flags and the data files
// their headers name), each resolved to one canonical path. Built in main() right after
// the flags are validated, before any big input is read and before any folder is created,
// so that a run that would overwrite an input, or write one file twice, is refused with a
// one-line error that names both flags, and nothing is written.
//
// Example (dsr_register):
//   OutputPlan plan;
//   plan.AddInputImage("images", "seq/frame_00.nii.gz");
//   plan.AddOutputFile("out_poses", "o/poses.json");
//   plan.AddOutputFolder("report_dir", "o/report");
//   plan.AddOutputFile("report_dir", "o/report", "poses.json");
//   if (!plan.Check(&error)) return Fail(error);   // exit 2, nothing written
//   ... read inputs, run ...
//   if (!plan.CreateFolders(&error)) return Fail(error, kExitFailed);
#ifndef DSR_APP_OUTPUT_PLAN_H_
#define DSR_APP_OUTPUT_PLAN_H_

#include <mutex>
#include <string>
#include <utility>
#include <vector>

namespace dsr {

class OutputPlan {
 public:
  // An input file of `--flag=path` ("" is ignored).
  void AddInputFile(const std::string& flag, const std::string& path);
  // An input image of `--flag=path` ("" is ignored) and the data files its header names
  // (.mhd ElementDataFile, LIST slices included; .nhdr data files). A header that cannot
  // be read adds the path alone: the reader reports it, before anything is written.
  void AddInputImage(const std::string& flag, const std::string& path);
  // The frames of --images and --masks: each image (AddInputImage), and the list file
  // itself when a flag's value is "@LIST" (tool_util.h, ParseInputList).
  void AddFrameInputs(const std::vector<std::string>& image_paths,
                      const std::vector<std::string>& mask_paths,
                      const std::string& images_value,
                      const std::string& masks_value);
  // `file` read from the folder `--flag=value` (dsr_compare's sequences).
  void AddInputFileIn(const std::string& flag,
                      const std::string& value,
                      const std::string& file);
  void AddInputImageIn(const std::string& flag,
                       const std::string& value,
                       const std::string& file);

  // The output file `--flag=path` ("" is ignored).
  void AddOutputFile(const std::string& flag, const std::string& path);
  // The output image `--flag=path` ("" is ignored) and the data file(s) WriteImage writes
  // next to it (.mhd/.nhdr -> .raw).
  void AddOutputImage(const std::string& flag, const std::string& path);
  // A file the tool names itself: `name` (may contain a subfolder) inside the output folder
  // `--flag=folder`.
  void AddDerivedFile(const std::string& flag,
                      const std::string& folder,
                      const std::string& name);
  void AddDerivedImage(const std::string& flag,
                       const std::string& folder,
                       const std::string& name);
  // A folder the run creates if missing (`--flag=value`; `folder` is value itself or a
  // subfolder the tool names).
  void AddOutputFolder(const std::string& flag,
                       const std::string& value,
                       const std::string& folder);

  // True when the plan is safe: no output is an input or one of the input's data files
  // (by canonical path, or by device and inode for hard links), no two outputs are the
  // same file, no output file is a planned or existing folder or an existing FIFO, device
  // or socket (atomic writes would replace it), no planned folder is a file, and every
  // output's folder exists and is writable or can be created. Otherwise
  // one line in `error` naming both flags and paths. Touches nothing on disk.
  bool Check(std::string* error) const;

  // Creates the planned folders (parents first). Note: call after Check and after the
  // inputs are read, right before the first write, so that a bad input leaves nothing.
  bool CreateFolders(std::string* error) const;

 private:
  enum class Kind { kInput, kOutputFile, kOutputFolder };
  struct Entry {
    Kind kind;
    std::string flag;       // without "--"
    std::string value;      // the flag's value as given
    std::string path;       // the file or folder itself (value, or a name derived from it)
    std::string canonical;  // CanonicalPath(path), no trailing separator
    std::string role;       // "", or what the file is to `value` ("its data file")
  };
  void Add(Kind kind,
           const std::string& flag,
           const std::string& value,
           const std::string& path,
           const std::string& role);
  // `path` and the data file(s) WriteImage writes next to it.
  void AddWrittenImage(const std::string& flag, const std::string& value, const std::string& path);
  static std::string Describe(const Entry& entry);
  struct Index;  // the entries by canonical path and by inode (output_plan.cc)
  Index MakeIndex() const;
  const Entry* FindInput(const Index& index, size_t i) const;
  bool CheckFolder(const Index& index, size_t f, std::string* error) const;
  bool CheckOutputFile(const Index& index, size_t o, std::string* error) const;

  std::vector<Entry> entries_;
};

// The inputs a long-lived front end has read (the Python package: every frame, mask and
// poses file a registration or a fusion read in this process), so that none of its later
// writes replaces one: each write is planned with them (AddTo) and checked. Thread-safe.
class InputRegistry {
 public:
  // Remembers the input image (and its data files) or file of `--flag=path` ("" ignored).
  void AddImage(const std::string& flag, const std::string& path);
  void AddFile(const std::string& flag, const std::string& path);
  // Adds every remembered input to `plan`.
  void AddTo(OutputPlan* plan) const;

 private:
  mutable std::mutex mutex_;
  std::vector<std::pair<std::string, std::string>> images_, files_;
};

}  // namespace dsr

#endif  // DSR_APP_OUTPUT_PLAN_H_
