// The MetaImage (.mha/.mhd) and NRRD (.nrrd/.nhdr) headers read as text next to ITK's
// readers, Eigen-free (see io_itk.h): where their voxels are (attached, in a data file, in
// LIST slice files, NRRD file patterns) as MetaIO 5.2 and teem find them, the MetaImage
// header lines to check before MetaIO parses them, and the data-block checks of both formats
// (see io_itk_checks.cc).
#include "dsr/io/io_itk_internal.h"

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <regex>
#include <sstream>
#include <string>
#include <system_error>
#include <vector>

#include "dsr/util/text.h"

namespace dsr {
namespace itk_io {
namespace internal {
namespace {

bool IsTrue(const std::string& value) {
  return !value.empty() && (value[0] == 'T' || value[0] == 't' || value[0] == '1');
}

// A data file named in a detached header, as MetaIO and teem open it: an absolute name as
// is, a relative one after the header's folder, textually (the path stays as the user gave
// it: "d/in.mhd" names "d/in.raw").
std::string BesideHeader(const std::string& header, const std::string& name) {
  if (!name.empty() && name[0] == '/') return name;
  const size_t slash = header.rfind('/');
  return slash == std::string::npos ? name : header.substr(0, slash + 1) + name;
}

// Most data files a LIST or pattern may name (one per slice of a 3D image in practice).
constexpr uint64_t kMaxDataFiles = 100000;

}  // namespace

std::vector<std::string> Words(const std::string& text) {
  std::vector<std::string> words;
  std::istringstream in(text);
  for (std::string word; in >> word;) words.push_back(word);
  return words;
}

bool IsRegularFile(const std::string& path) {
  std::error_code ec;
  return std::filesystem::is_regular_file(path, ec);
}

// False with `reason` when the header names its data in a way that cannot be followed
// (or, with `found_data_file` false, has no ElementDataFile line at all).
bool ParseMetaImageLayout(const std::string& path,
                          MetaImageLayout* layout,
                          bool* found_data_file,
                          std::string* reason) {
  *found_data_file = false;
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    *reason = std::string("cannot open the header (") + std::strerror(errno) + ")";
    return false;
  }
  std::string line;
  std::string value;
  size_t read = 0;
  while (read < kMaxHeaderBytes && std::getline(in, line)) {
    read += line.size() + 1;
    const size_t equals = line.find('=');
    if (equals == std::string::npos) continue;
    const std::string key = Trim(line.substr(0, equals));
    const std::string text = Trim(line.substr(equals + 1));
    if (key == "CompressedData") layout->compressed = IsTrue(text);
    if (key == "HeaderSize") layout->header_size = std::atoll(text.c_str());
    if (key == "BinaryDataByteOrderMSB" || key == "ElementByteOrderMSB") layout->msb = IsTrue(text);
    if (key == "BinaryData") layout->binary = IsTrue(text);
    if (key == "DimSize") {
      layout->dims.clear();
      for (const std::string& word : Words(text)) layout->dims.push_back(std::atoll(word.c_str()));
    }
    if (key == "ElementDataFile") {
      value = text;
      *found_data_file = true;
      break;
    }
  }
  if (!*found_data_file) {
    *reason = "the MetaImage header has no ElementDataFile line";
    return false;
  }
  if (value == "LOCAL" || value == "Local" || value == "local") {
    layout->kind = MetaImageLayout::Kind::kLocal;
    layout->local_offset = static_cast<uint64_t>(in.tellg());
    return true;
  }
  if (value.compare(0, 4, "LIST") == 0) {
    layout->kind = MetaImageLayout::Kind::kList;
    const int ndims = static_cast<int>(layout->dims.size());
    const std::vector<std::string> words = Words(value);
    // MetaIO: "LIST 2D" -> 2; 0 (none given) or more than NDims -> NDims - 1.
    int file_dims = words.size() > 1 ? static_cast<int>(std::atof(words[1].c_str())) : 0;
    if (file_dims == 0 || file_dims > ndims) file_dims = ndims - 1;
    // MetaIO indexes its sizes with this number unchecked: a negative one or NDims itself
    // reads outside them, so only 1..NDims-1 is followed.
    if (file_dims < 1 || file_dims >= ndims) {
      *reason = "ElementDataFile = " + value + ": each LIST file must hold 1 to " +
                std::to_string(ndims - 1) + " dimensions";
      return false;
    }
    uint64_t count = 1;
    for (int d = file_dims; d < ndims; ++d) {
      count *= static_cast<uint64_t>(std::max<int64_t>(layout->dims[d], 1));
      if (count > kMaxDataFiles) {
        *reason = "ElementDataFile = " + value + " needs more than " +
                  std::to_string(kMaxDataFiles) + " slice files";
        return false;
      }
    }
    while (layout->files.size() < count && std::getline(in, line)) {
      // MetaIO skips a last name that is not followed by a line end (it stops at eof), so
      // that slice would be left unread.
      if (in.eof()) break;
      // MetaIO strips trailing blanks and unprintable characters but keeps the first one,
      // and an empty line makes it index before the start of the name.
      size_t end = line.size();
      while (end > 1 && (std::isspace(static_cast<unsigned char>(line[end - 1])) ||
                         !std::isprint(static_cast<unsigned char>(line[end - 1])))) {
        --end;
      }
      if (end == 0) {
        *reason = "ElementDataFile = LIST: slice file name " +
                  std::to_string(layout->files.size() + 1) + " is empty";
        return false;
      }
      layout->files.push_back(BesideHeader(path, line.substr(0, end)));
    }
    if (layout->files.size() < count) {
      *reason = "ElementDataFile = " + value + " names " + std::to_string(layout->files.size()) +
                " of the " + std::to_string(count) + " slice files (each on a line of its own)";
      return false;
    }
    return true;
  }
  if (value.find('%') != std::string::npos) {
    // A printf pattern that MetaIO passes to snprintf unchecked (found by fuzzing: "%s"
    // crashes). Frames are single volumes: LOCAL, one data file, or LIST.
    *reason = "MetaImage ElementDataFile patterns (with %) are not supported";
    return false;
  }
  layout->kind = MetaImageLayout::Kind::kFile;
  std::string file = BesideHeader(path, value);
  if (!IsRegularFile(file)) {
    for (const char* suffix : {".gz", ".Z"}) {
      if (IsRegularFile(file + suffix)) {
        file += suffix;
        layout->compressed = true;
        break;
      }
    }
  }
  layout->files.push_back(file);
  return true;
}

// MetaImage: `bytes` of voxel data must follow the header (LOCAL), be in the data file, or
// be spread over the LIST slice files, compressed or not; exactly so if `exact`.
bool CheckMetaImageData(const std::string& path, uint64_t bytes, bool exact, std::string* reason) {
  MetaImageLayout layout;
  bool found_data_file = false;
  if (!ParseMetaImageLayout(path, &layout, &found_data_file, reason)) {
    return !found_data_file && !exact;  // ITK parsed a header this check does not follow
  }
  if (layout.kind == MetaImageLayout::Kind::kLocal) {
    if (layout.compressed) {
      return CheckCompressedStream(path, layout.local_offset, bytes, exact, "data", reason);
    }
    return CheckPlainData(path, layout.local_offset, bytes, exact, "data", reason);
  }
  if (layout.kind == MetaImageLayout::Kind::kList && layout.compressed) {
    // MetaIO inflates each slice with the whole image's CompressedDataSize: not followed.
    *reason = "compressed LIST slice files are not supported";
    return false;
  }
  const uint64_t file_bytes = bytes / layout.files.size();
  for (const std::string& file : layout.files) {
    const std::string what = layout.kind == MetaImageLayout::Kind::kList
                                 ? "slice file " + file
                                 : "data file " + std::filesystem::path(file).filename().string();
    if (!IsRegularFile(file)) {
      *reason = (layout.kind == MetaImageLayout::Kind::kList ? "slice file " : "data file ") +
                file + " does not exist";
      return false;
    }
    if (layout.compressed) {
      if (!CheckCompressedStream(file, 0, file_bytes, exact, what, reason)) return false;
      continue;
    }
    // HeaderSize > 0 skips that many bytes; -1 means "the data is at the end".
    const uint64_t offset = layout.header_size > 0 ? static_cast<uint64_t>(layout.header_size) : 0;
    if (!CheckPlainData(file, offset, file_bytes, exact && layout.header_size >= 0, what, reason)) {
      return false;
    }
  }
  return true;
}

// ITK's MetaIO copies each header key into a fixed 255-byte buffer with strcpy: a longer
// key (a line without "=" counts whole) overflows it and the process aborts; control
// characters in a value make it read past a buffer (both found by fuzzing). Checks the
// header lines, up to ElementDataFile, first.
bool CheckMetaImageKeys(const std::string& path, std::string* reason) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return true;  // later stages report unreadable files
  constexpr size_t kMaxKey = 250;
  std::string line;
  size_t read = 0;
  for (int number = 1; std::getline(in, line) && read < kMaxHeaderBytes; ++number) {
    read += line.size() + 1;
    const size_t equals = line.find('=');
    const std::string key = Trim(equals == std::string::npos ? line : line.substr(0, equals));
    // MetaIO splits some values into words without bounds checks; control characters in a
    // header line (found by fuzzing in ElementDataFile) make it read past its buffer.
    for (const char c : line) {
      const unsigned char u = static_cast<unsigned char>(c);
      if (u < 0x20 && c != '\t' && c != '\r') {
        *reason = "MetaImage header line " + std::to_string(number) +
                  " contains control characters (not a text header)";
        return false;
      }
    }
    if (key.size() > kMaxKey) {
      *reason = "MetaImage header line " + std::to_string(number) + " has a key of " +
                std::to_string(key.size()) + " characters (at most " + std::to_string(kMaxKey) +
                ")";
      return false;
    }
    if (equals == std::string::npos && !key.empty()) {
      // MetaIO reads a key up to the next '=', across line ends: "ElementDataFile" alone on
      // a line took the next lines as its value, and a "%" there as a file pattern whose
      // step parsed as 0 (found by fuzzing: integer division by zero in ReadStream).
      *reason = "MetaImage header line " + std::to_string(number) + " is not a 'key = value' line";
      return false;
    }
    if (key == "NDims") {
      // MetaIO reads NDims numbers for every array field; a huge NDims (found by fuzzing:
      // 1111...113) made it loop for hours over an exhausted stream.
      const std::string value = Trim(line.substr(equals + 1));
      if (value.empty() || value.size() > 2 ||
          value.find_first_not_of("0123456789") != std::string::npos || std::stoi(value) < 1 ||
          std::stoi(value) > 16) {
        *reason = "MetaImage header line " + std::to_string(number) + ": NDims = '" +
                  value.substr(0, 20) + "' is not a dimension in [1, 16]";
        return false;
      }
    }
    if (key == "ElementDataFile") {
      // A "%" makes MetaIO treat the value as a printf pattern for a file series and pass
      // it to snprintf as the format (found by fuzzing: "%s" crashes). Frames are single
      // volumes: LOCAL, one data file, or LIST.
      if (equals != std::string::npos && line.find('%', equals) != std::string::npos) {
        *reason = "MetaImage ElementDataFile patterns (with %) are not supported";
        return false;
      }
      break;
    }
  }
  return true;
}

namespace {

// Expands a teem file pattern: `format` must hold exactly one integer conversion
// ("%d", "%03d", ...), anything else could make snprintf read arguments that are not there.
bool ExpandNrrdPattern(const std::string& header,
                       const std::vector<std::string>& words,
                       std::vector<std::string>* files,
                       std::string* reason) {
  static const std::regex kOneInteger(R"(([^%]|%%)*%[-+ 0#]?[0-9]{0,3}[diu]([^%]|%%)*)");
  static const std::regex kInteger(R"([-+]?[0-9]{1,9})");
  const std::string& format = words[0];
  if (!std::regex_match(format, kOneInteger) || !std::regex_match(words[1], kInteger) ||
      !std::regex_match(words[2], kInteger) || !std::regex_match(words[3], kInteger)) {
    *reason = "data file pattern '" + format + " " + words[1] + " " + words[2] + " " + words[3] +
              "' is not '<format with one %d> <min> <max> <step>'";
    return false;
  }
  const int64_t first = std::stoll(words[1]);
  const int64_t last = std::stoll(words[2]);
  const int64_t step = std::stoll(words[3]);
  if (step == 0 || (last - first) / step < 0 ||
      static_cast<uint64_t>((last - first) / step) >= kMaxDataFiles) {
    *reason = "data file pattern '" + format + "' has an unusable range " + words[1] + ".." +
              words[2] + " step " + words[3];
    return false;
  }
  for (int64_t i = first; step > 0 ? i <= last : i >= last; i += step) {
    char name[4096];
    std::snprintf(name, sizeof(name), format.c_str(), static_cast<int>(i));
    files->push_back(BesideHeader(header, name));
  }
  return true;
}

}  // namespace

bool ParseNrrdLayout(const std::string& path, NrrdLayout* layout, std::string* reason) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    *reason = std::string("cannot open the header (") + std::strerror(errno) + ")";
    return false;
  }
  std::string line;
  if (!std::getline(in, line) || line.compare(0, 4, "NRRD") != 0) {
    *reason = "not a NRRD header (the first line is not NRRD000x)";
    return false;
  }
  size_t read = line.size() + 1;
  bool list = false;
  while (read < kMaxHeaderBytes && std::getline(in, line)) {
    read += line.size() + 1;
    if (list) {  // the rest of the header file names the data files
      const std::string name = Trim(line);
      if (!name.empty()) layout->files.push_back(BesideHeader(path, name));
      continue;
    }
    if (Trim(line).empty()) break;  // the header ends at its first empty line
    if (line[0] == '#' || line.find(":=") != std::string::npos) continue;  // comment, key/value
    const size_t colon = line.find(':');
    if (colon == std::string::npos) continue;
    const std::string field = Trim(line.substr(0, colon));
    const std::string value = Trim(line.substr(colon + 1));
    if (field == "encoding") layout->encoding = value;
    if (field == "sizes") layout->sizes = Words(value);
    if (field == "kinds") layout->kinds = Words(value);
    if (field == "endian") layout->endian = value;
    if (field == "line skip" || field == "lineskip") layout->line_skip = value;
    if (field == "byte skip" || field == "byteskip") layout->byte_skip = value;
    if (field == "data file" || field == "datafile") {
      const std::vector<std::string> words = Words(value);
      if (!words.empty() && words[0] == "LIST") {
        list = true;
      } else if ((words.size() == 4 || words.size() == 5) &&
                 words[0].find('%') != std::string::npos) {
        if (!ExpandNrrdPattern(path, words, &layout->files, reason)) return false;
      } else {
        layout->files.push_back(BesideHeader(path, value));
      }
    }
  }
  layout->data_offset = in ? static_cast<uint64_t>(in.tellg()) : 0;
  return true;
}

// NRRD just written (raw or gzip encoding): `bytes` of voxels, exactly, after the header
// or in its data file. Reading leaves this to teem, which checks sizes itself.
bool CheckWrittenNrrdData(const std::string& path, uint64_t bytes, std::string* reason) {
  NrrdLayout layout;
  if (!ParseNrrdLayout(path, &layout, reason)) return false;
  const bool gzip = layout.encoding == "gzip" || layout.encoding == "gz";
  if (!gzip && layout.encoding != "raw") {
    *reason = "unexpected NRRD encoding " + layout.encoding;
    return false;
  }
  if (layout.files.size() > 1) {
    *reason = "NRRD data split over " + std::to_string(layout.files.size()) + " files";
    return false;
  }
  const std::string file = layout.files.empty() ? path : layout.files[0];
  const uint64_t offset = layout.files.empty() ? layout.data_offset : 0;
  const std::string what = layout.files.empty()
                               ? "data"
                               : "data file " + std::filesystem::path(file).filename().string();
  if (gzip) return CheckCompressedStream(file, offset, bytes, true, what, reason);
  return CheckPlainData(file, offset, bytes, true, what, reason);
}

}  // namespace internal
}  // namespace itk_io
}  // namespace dsr
