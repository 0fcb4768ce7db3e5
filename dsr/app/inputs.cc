// The inputs of a run (dsr/app/inputs.h).
#include "dsr/app/inputs.h"

#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <system_error>

#include "dsr/app/flagfile.h"
#include "dsr/io/io_frames.h"
#include "dsr/io/io_phases.h"
#include "dsr/solve/solve_options.h"
#include "dsr/util/text.h"

namespace dsr {

std::string GiB(double bytes) {
  char text[32];
  std::snprintf(text, sizeof(text), "%.1f GiB", bytes / (1024.0 * 1024.0 * 1024.0));
  return text;
}

// RLIMIT_AS in bytes, or 0 when unlimited.
double AddressSpaceLimitBytes() {
  struct rlimit limit;
  if (getrlimit(RLIMIT_AS, &limit) != 0 || limit.rlim_cur == RLIM_INFINITY) return 0.0;
  return static_cast<double>(limit.rlim_cur);
}

double AvailableMemoryBytes() {
  double available = static_cast<double>(PhysicalMemoryBytes());
  const double limit = AddressSpaceLimitBytes();
  if (limit > 0.0) {
    double mapped = 0.0;
    long pages = 0;
    std::ifstream statm("/proc/self/statm");
    if (statm >> pages) mapped = static_cast<double>(pages) * sysconf(_SC_PAGESIZE);
    const double left = std::max(0.0, limit - mapped);
    available = available > 0.0 ? std::min(available, left) : left;
  }
  return available;
}

bool CheckMemoryEstimate(const std::string& what_flags,
                         double bytes,
                         const std::string& what,
                         std::string* error) {
  const double available = AvailableMemoryBytes();
  if (available <= 0.0 || bytes <= available) return true;
  const double limit = AddressSpaceLimitBytes();
  *error = what_flags + ": needs about " + GiB(bytes) + " for " + what + ", more than the " +
           GiB(available) + " available (physical RAM " +
           GiB(static_cast<double>(PhysicalMemoryBytes())) +
           (limit > 0.0 ? ", address-space limit " + GiB(limit) : std::string()) + ")";
  return false;
}

std::string WithFrameFile(const std::string& message, const std::vector<std::string>& paths) {
  int frame = -1, consumed = 0;
  if (std::sscanf(message.c_str(), "frame %d %n", &frame, &consumed) < 1 || consumed == 0 ||
      frame < 0 || frame >= static_cast<int>(paths.size())) {
    return message;
  }
  return paths[frame] + ": " + message;
}

namespace {

// "frame 4", "frames 0-3,5-10": consecutive frames as ranges.
std::string FrameRanges(const std::vector<int>& frames) {
  std::string out = frames.size() == 1 ? "frame " : "frames ";
  for (size_t a = 0; a < frames.size();) {
    size_t b = a;
    while (b + 1 < frames.size() && frames[b + 1] == frames[b] + 1) ++b;
    out += (a ? "," : "") + std::to_string(frames[a]);
    if (b > a) out += "-" + std::to_string(frames[b]);
    a = b + 1;
  }
  return out;
}

}  // namespace

std::string FieldOfViewSummary(const std::vector<MaskRule>& mask_rules, MaskRule asked) {
  if (mask_rules.empty()) return "field of view: the given masks";
  std::vector<int> hull, nonzero;
  for (size_t i = 0; i < mask_rules.size(); ++i) {
    (mask_rules[i] == MaskRule::kHull ? hull : nonzero).push_back(static_cast<int>(i));
  }
  std::string out = "field of view: ";
  if (!hull.empty()) out += "convex hull of the non-zero voxels (" + FrameRanges(hull) + ")";
  if (!nonzero.empty()) {
    out += std::string(hull.empty() ? "" : "; ") + "non-zero voxels" +
           (asked == MaskRule::kHull ? ", no 3D hull" : "") + " (" + FrameRanges(nonzero) + ")";
  }
  return out;
}

std::string DropoutSummary(const std::vector<double>& dropout_fraction) {
  std::string out;
  for (size_t i = 0; i < dropout_fraction.size(); ++i) {
    if (dropout_fraction[i] <= 0.0) continue;
    char part[64];
    std::snprintf(part, sizeof(part), "%sframe %zu %.1f%%", out.empty() ? "" : ", ", i,
                  100.0 * dropout_fraction[i]);
    out += part;
  }
  if (out.empty()) return out;
  return "; dropouts (beams without signal) left out: " + out;
}

std::string InputFileRule(const std::string& path) {
  if (path.empty()) return "";
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) return "no such file";
  if (!std::filesystem::is_regular_file(path, ec)) return "not a regular file";
  if (!std::ifstream(path, std::ios::binary).is_open()) return "cannot open for reading";
  return "";
}

std::string CanonicalPath(const std::string& path) {
  if (path.empty()) return path;
  // Absolute first: weakly_canonical leaves a relative path relative when its first
  // component does not exist yet ("new/./x" -> "new/x", while "/abs/new/x" stays absolute).
  // The existing prefix has its symlinks, "." and ".." resolved; the rest is normalised.
  std::error_code ec;
  const std::filesystem::path absolute = std::filesystem::absolute(path, ec);
  if (ec) return std::filesystem::path(path).lexically_normal().string();
  const std::filesystem::path p = std::filesystem::weakly_canonical(absolute, ec);
  return ec ? absolute.lexically_normal().string() : p.string();
}

namespace {

// Whether a poses entry named `name` is the image `path` (see MatchPosesToImages).
bool PoseNameMatches(const std::string& name, const std::string& path) {
  if (name.empty()) return false;
  if (name == path) return true;
  // A view given as its phases' files joined by ';' goes by its first file, the name a poses
  // file written for it holds.
  const std::vector<std::string> files = ViewFiles(path);
  const std::string& first = files.empty() ? path : files.front();
  const std::string file = std::filesystem::path(first).filename().string();
  if (name == first || name == file) return true;
  const std::string lower = Lower(file);
  for (const std::string extension : {".nii.gz", ".nii", ".mha", ".mhd", ".nrrd", ".nhdr"}) {
    if (lower.size() > extension.size() && EndsWith(lower, extension)) {
      return name == file.substr(0, file.size() - extension.size());
    }
  }
  return false;
}

}  // namespace

bool MatchPosesToImages(const std::string& flag,
                        const std::string& path,
                        const std::vector<std::string>& image_paths,
                        PosesFile* poses,
                        std::string* error) {
  const std::vector<std::string>& names = poses->images;
  const int m = static_cast<int>(image_paths.size());
  if (std::all_of(names.begin(), names.end(), [](const std::string& n) { return n.empty(); })) {
    return true;
  }
  // Entry i names image i: kept as is, also when two images share a file name.
  bool in_order = true;
  for (int i = 0; i < m && in_order; ++i) in_order = PoseNameMatches(names[i], image_paths[i]);
  if (in_order) return true;
  const std::string prefix = "--" + flag + "=" + path + ": ";
  std::vector<int> entry_of_image(m, -1), image_of_entry(m, -1);
  for (int i = 0; i < m; ++i) {
    for (int e = 0; e < m; ++e) {
      if (!PoseNameMatches(names[e], image_paths[i])) continue;
      if (entry_of_image[i] >= 0) {
        *error = prefix + "entries " + std::to_string(entry_of_image[i]) + " and " +
                 std::to_string(e) + " both name the image " + image_paths[i];
        return false;
      }
      entry_of_image[i] = e;
    }
    if (entry_of_image[i] < 0) {
      std::string listed;
      for (int e = 0; e < m && e < 4; ++e) listed += (e > 0 ? ", " : "") + names[e];
      *error = prefix + "no entry names the image " + image_paths[i] + " (image " +
               std::to_string(i) + " of --images; the file's names: " + listed +
               (m > 4 ? ", ..." : "") + ")";
      return false;
    }
    const int e = entry_of_image[i];
    if (image_of_entry[e] >= 0) {
      *error = prefix + "entry " + std::to_string(e) + " (" + names[e] + ") names both " +
               image_paths[image_of_entry[e]] + " and " + image_paths[i];
      return false;
    }
    image_of_entry[e] = i;
  }
  PosesFile reordered;
  for (int i = 0; i < m; ++i) {
    reordered.images.push_back(names[entry_of_image[i]]);
    reordered.frame_from_world.push_back(poses->frame_from_world[entry_of_image[i]]);
  }
  // Gains and offsets are on the first entry's intensity scale: bring them to the scale of
  // the entry that is now frame 0 (g_i I_i + o_i = g_n I_n + o_n becomes
  // (g_i / g_n) I_i + (o_i - o_n) / g_n = I_n).
  // Either field may be absent (gain 1, offset 0); a field absent from the file stays so
  // when the re-gauging leaves it at its default.
  if (!poses->gain.empty() || !poses->offset.empty()) {
    const auto gain = [&](int e) { return poses->gain.empty() ? 1.0 : poses->gain[e]; };
    const auto offset = [&](int e) { return poses->offset.empty() ? 0.0 : poses->offset[e]; };
    const int first = entry_of_image[0];
    const double g_n = gain(first), o_n = offset(first);
    for (int i = 0; i < m; ++i) {
      const int e = entry_of_image[i];
      reordered.gain.push_back(i == 0 ? 1.0 : gain(e) / g_n);
      reordered.offset.push_back(i == 0 ? 0.0 : (offset(e) - o_n) / g_n);
    }
    const auto all_equal = [](const std::vector<double>& v, double x) {
      return std::all_of(v.begin(), v.end(), [x](double y) { return y == x; });
    };
    if (poses->gain.empty() && all_equal(reordered.gain, 1.0)) reordered.gain.clear();
    if (poses->offset.empty() && all_equal(reordered.offset, 0.0)) reordered.offset.clear();
  }
  LOG(INFO) << "--" << flag << "=" << path << ": entries reordered to the order of --images";
  *poses = std::move(reordered);
  return true;
}

std::vector<Photometric> PhotometricFromPoses(const PosesFile& poses) {
  std::vector<Photometric> photometric;
  if (poses.gain.empty() && poses.offset.empty()) return photometric;
  const size_t m = poses.frame_from_world.size();
  CHECK(poses.gain.empty() || poses.gain.size() == m);
  CHECK(poses.offset.empty() || poses.offset.size() == m);
  for (size_t i = 0; i < m; ++i) {
    Photometric p;
    // ReadPoses refuses gains <= 0.
    if (!poses.gain.empty()) p.log_gain = std::log(poses.gain[i]);
    if (!poses.offset.empty()) p.offset = poses.offset[i];
    photometric.push_back(p);
  }
  return photometric;
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

bool ParseInputList(const std::string& flag,
                    const std::string& text,
                    std::vector<std::string>* paths,
                    std::string* error) {
  std::vector<std::string> items;
  const bool from_list = !text.empty() && text[0] == '@';
  const std::string list = from_list ? text.substr(1) : std::string();
  if (from_list) {
    std::string content;
    if (!ReadSmallTextFile(list, "--" + flag + "=" + text + ": ", &content, error)) return false;
    for (const std::string& line : Lines(content)) {
      const std::string item = Trim(line);
      if (!item.empty() && item[0] != '#') items.push_back(item);
    }
  } else {
    items = SplitCommaList(text);
  }
  for (const std::string& view : items) {
    for (const std::string& item : ViewFiles(view)) {  // a view's phases may be files joined by ';'
      std::error_code ec;
      if (std::filesystem::exists(item, ec) || ec) continue;  // other errors: the reader's
      *error = from_list ? "--" + flag + "=" + text + ": " + item + ": no such file"
                         : "--" + flag + ": " + item + ": no such file (--" + flag +
                               " is split at commas; a name that contains a comma can be given "
                               "in a list file, --" + flag + "=@LIST, one path per line)";
      return false;
    }
  }
  *paths = std::move(items);
  return true;
}

namespace {

// --phases' error for a view of `count` phases that lacks phase `p`.
std::string NoSuchPhase(const std::string& name, size_t count, int p) {
  return "--phases: " + name + " has " + std::to_string(count) + " phase" +
         (count > 1 ? "s" : "") + " (0 to " + std::to_string(count - 1) + "), no phase " +
         std::to_string(p);
}

}  // namespace

bool CheckSelectedPhases(const std::vector<int>& selected,
                         const std::vector<std::string>& views,
                         std::string* error) {
  if (selected.empty()) return true;
  for (const std::string& view : views) {
    int count = 0;
    if (!NumPhasesInView(view, &count, error)) return false;
    for (int p : selected) {
      if (p >= count) {
        *error = NoSuchPhase(view, static_cast<size_t>(count), p);
        return false;
      }
    }
  }
  return true;
}

bool ReadViewPhases(const std::vector<int>& selected,
                    const std::vector<std::string>& image_paths,
                    const std::vector<std::string>& mask_paths,
                    const FieldOfViewOptions& field_of_view,
                    int num_threads,
                    std::vector<Image>* images,
                    std::vector<Mask>* masks,
                    std::vector<MaskRule>* mask_rules,
                    std::vector<std::vector<Image>>* later_phases,
                    std::string* error) {
  return CheckSelectedPhases(selected, image_paths, error) &&
         ReadFrames(image_paths, mask_paths, field_of_view, num_threads, images, masks,
                    mask_rules, error, later_phases, selected) &&
         CheckSamePhases(image_paths, later_phases, error);
}

bool SelectPhases(const std::vector<int>& selected,
                  const std::vector<std::string>& names,
                  std::vector<Image>* images,
                  std::vector<std::vector<Image>>* later_phases,
                  std::string* error) {
  if (selected.empty()) return true;
  for (size_t i = 0; i < images->size(); ++i) {
    std::vector<Image> all;
    all.push_back(std::move((*images)[i]));
    for (Image& phase : (*later_phases)[i]) all.push_back(std::move(phase));
    for (int p : selected) {
      if (p >= static_cast<int>(all.size())) {
        *error = NoSuchPhase(i < names.size() ? names[i] : "view " + std::to_string(i),
                             all.size(), p);
        return false;
      }
    }
    (*images)[i] = std::move(all[selected[0]]);
    (*later_phases)[i].clear();
    for (size_t k = 1; k < selected.size(); ++k) {
      (*later_phases)[i].push_back(std::move(all[selected[k]]));
    }
  }
  return true;
}

bool CheckSamePhases(const std::vector<std::string>& names,
                     std::vector<std::vector<Image>>* later_phases,
                     std::string* error) {
  const auto count = [&](size_t i) { return (*later_phases)[i].size() + 1; };
  for (size_t i = 1; i < later_phases->size(); ++i) {
    if (count(i) != count(0)) {
      *error = names[i] + ": " + std::to_string(count(i)) + " phase" + (count(i) > 1 ? "s" : "") +
               ", but " + names[0] + " has " + std::to_string(count(0)) +
               ": every view needs the same phases of the heart cycle, aligned by index (pick "
               "them with --phases)";
      return false;
    }
  }
  if (count(0) == 1) later_phases->clear();
  return true;
}

bool UseViewPhases(const std::vector<int>& selected,
                   const std::vector<std::string>& names,
                   std::vector<Image>* images,
                   std::vector<std::vector<Image>>* later_phases,
                   std::string* error) {
  if (later_phases->empty()) later_phases->assign(images->size(), {});
  return SelectPhases(selected, names, images, later_phases, error) &&
         CheckSamePhases(names, later_phases, error);
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

}  // namespace dsr
