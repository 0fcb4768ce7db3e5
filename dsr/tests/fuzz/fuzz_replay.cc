// A main for a libFuzzer target without libFuzzer (GCC, the test suite's builds): calls
// LLVMFuzzerTestOneInput on every corpus file and then on a fixed set of mutations of each,
// so that ctest runs the fuzz targets under AddressSanitizer + UBSan on every CI run.
//
//   fuzz_<target>_replay [-mutations=N] [-seed=S] [-prefix=P] [-max_total_time=T]
//                        [-timeout=T] [-malloc_limit_mb=M] [-artifact_prefix=DIR/] PATH...
//
// PATH: a corpus folder (its files in name order) or a file (run as it is, no mutations:
// to replay a saved input). Each input gets N mutations (default 64) drawn from a PRNG
// seeded with S and the file's name, so a run is the same set of inputs on every machine:
// bit flips and byte changes (anywhere, or in the header), truncations, insertions, line
// deletions and duplications in a text header, numbers of a text header replaced by edge
// values (sizes: 0, -1, 2^31, ...), binary header fields (a NIfTI-1 header's dim, datatype,
// bitpix, pixdim, vox_offset, scl_slope, qform/sform) set to edge values, and the same edits
// inside a gzip file (inflated, edited, deflated again). The first P bytes (default 0; 1 for
// targets whose first byte picks the format) are a selector: left out of header detection,
// sometimes changed. T: stop making mutations after T seconds (0: never; every corpus file
// still runs once). A finding (sanitizer report, crash, abort, an input running over the
// timeout, one allocation over M MiB as libFuzzer's -malloc_limit_mb) prints what the input
// was and writes it to <artifact_prefix>crash-<name>, to replay it with this program or the
// libFuzzer build; the exit status is then non-zero.
#include <dirent.h>
#include <fcntl.h>
#include <signal.h>
#include <sys/stat.h>
#include <unistd.h>
#include <zlib.h>

#include <algorithm>
#include <cctype>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <random>
#include <string>
#include <vector>

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size);

#if defined(__SANITIZE_ADDRESS__)
#define DSR_REPLAY_ASAN 1
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
#define DSR_REPLAY_ASAN 1
#endif
#endif
#ifdef DSR_REPLAY_ASAN
// From the sanitizers' allocator_interface.h, which GCC does not install.
extern "C" int __sanitizer_install_malloc_and_free_hooks(
    void (*malloc_hook)(const volatile void*, size_t), void (*free_hook)(const volatile void*));
#endif

namespace {

using Bytes = std::vector<uint8_t>;

// ---- What runs now, for the report of a finding (read by the signal handlers) ----

char g_what[512] = "";
char g_artifact[4096] = "";
const Bytes* g_input = nullptr;
size_t g_malloc_limit = size_t{2048} << 20;
bool g_running = false;

void Say(const char* text) {
  const ssize_t ignored = write(2, text, std::strlen(text));
  (void)ignored;
}

// Writes the running input to its artifact file and says so; async-signal-safe.
void ReportRunningInput(const char* why) {
  if (!g_running || g_input == nullptr) return;
  g_running = false;
  Say("\nfuzz_replay: ");
  Say(why);
  Say(" on input ");
  Say(g_what);
  const int fd = open(g_artifact, O_WRONLY | O_CREAT | O_TRUNC, 0644);
  if (fd >= 0) {
    const ssize_t ignored = write(fd, g_input->data(), g_input->size());
    (void)ignored;
    close(fd);
    Say("\nfuzz_replay: the input is saved as ");
    Say(g_artifact);
  }
  Say("\n");
}

// Then dies of `sig` (of SIGABRT after a timeout).
void OnSignal(int sig) {
  ReportRunningInput(sig == SIGALRM ? "timeout (an input ran over -timeout)" : "a crash or abort");
  if (sig == SIGALRM) sig = SIGABRT;
  signal(sig, SIG_DFL);
  raise(sig);
}

void OnDeath() { ReportRunningInput("a sanitizer report"); }

#ifdef DSR_REPLAY_ASAN
void OnMalloc(const volatile void*, size_t size) {
  if (!g_running || size <= g_malloc_limit) return;
  char line[96];
  std::snprintf(line, sizeof(line), "one allocation of %zu bytes (over -malloc_limit_mb)", size);
  ReportRunningInput(line);
  signal(SIGABRT, SIG_DFL);
  std::abort();
}
void OnFree(const volatile void*) {}
#endif

extern "C" void __sanitizer_set_death_callback(void (*callback)()) __attribute__((weak));

// ---- Mutations ----

const char* const kNumbers[] = {
    "0",          "1",           "-1",          "2",          "3",
    "4",          "5",           "7",           "8",          "255",
    "256",        "65535",       "65536",       "100000",     "2147483647",
    "2147483648", "-2147483648", "4294967296",  "1e9",        "9223372036854775807",
    "18446744073709551616",      "99999999999999999999999",   "1e308",      "-1e308",
    "nan",        "inf",         "0.0",         "-0",         "0.5",
    "00000001",   "",            "1 1",         "-",          "+3"};
const uint8_t kBytes[] = {0, 1, 0x7f, 0x80, 0xff, '0', '9', ' ', '\n', ':', '=', '%', '(', ','};
const int64_t kIntegers[] = {0, 1, -1, 2, 3, 4, 5, 7, 8, 16, 100000, 32767, -32768, 65535,
                             2147483647, -2147483648LL};
const float kFloats[] = {0.0f, 1.0f, -1.0f, 0.5f, 1e-30f, 1e30f, 3.4e38f, -3.4e38f, NAN,
                         INFINITY, -INFINITY, 1e-45f};

// NIfTI-1 header fields (offset, bytes, float?): dim[0..7], intent, datatype, bitpix,
// slice_start, pixdim[0..7], vox_offset, scl_slope, scl_inter, slice codes, xyzt_units,
// qform/sform codes, quatern b/c/d, qoffset x/y/z, srow_x/y/z.
struct Field {
  int offset;
  int bytes;
  bool real;
};
std::vector<Field> NiftiFields() {
  std::vector<Field> fields;
  for (int i = 0; i < 8; ++i) fields.push_back({40 + 2 * i, 2, false});
  for (int o : {68, 70, 72, 74}) fields.push_back({o, 2, false});
  for (int i = 0; i < 8; ++i) fields.push_back({76 + 4 * i, 4, true});
  for (int o : {108, 112, 116}) fields.push_back({o, 4, true});
  fields.push_back({120, 2, false});
  fields.push_back({123, 1, false});
  fields.push_back({252, 2, false});
  fields.push_back({254, 2, false});
  for (int i = 0; i < 18; ++i) fields.push_back({256 + 4 * i, 4, true});
  return fields;
}

bool IsGzip(const Bytes& b, size_t at) {
  return b.size() >= at + 2 && b[at] == 0x1f && b[at + 1] == 0x8b;
}

bool Inflate(const uint8_t* data, size_t size, Bytes* out) {
  z_stream z{};
  if (inflateInit2(&z, 15 + 32) != Z_OK) return false;
  z.next_in = const_cast<Bytes::value_type*>(data);
  z.avail_in = static_cast<uInt>(size);
  uint8_t buffer[1 << 14];
  int status = Z_OK;
  while (status == Z_OK && out->size() < (size_t{64} << 20)) {
    z.next_out = buffer;
    z.avail_out = sizeof(buffer);
    status = inflate(&z, Z_NO_FLUSH);
    out->insert(out->end(), buffer, buffer + (sizeof(buffer) - z.avail_out));
  }
  inflateEnd(&z);
  return status == Z_STREAM_END;
}

Bytes Gzip(const Bytes& in) {
  z_stream z{};
  deflateInit2(&z, 6, Z_DEFLATED, 15 + 16, 8, Z_DEFAULT_STRATEGY);
  Bytes out(deflateBound(&z, in.size()) + 64);
  z.next_in = const_cast<Bytes::value_type*>(in.data());
  z.avail_in = static_cast<uInt>(in.size());
  z.next_out = out.data();
  z.avail_out = static_cast<uInt>(out.size());
  deflate(&z, Z_FINISH);
  out.resize(out.size() - z.avail_out);
  deflateEnd(&z);
  return out;
}

class Mutator {
 public:
  Mutator(uint64_t seed, size_t prefix) : rng_(seed), prefix_(prefix) {}

  // A mutation of `in`; `what` says which.
  Bytes Mutate(const Bytes& in, std::string* what) {
    // A whole-file gzip (.nii.gz): its content edited and compressed again, half the time.
    Bytes content;
    if (IsGzip(in, prefix_) && Pick(2) == 0 &&
        Inflate(in.data() + prefix_, in.size() - prefix_, &content)) {
      content.insert(content.begin(), in.begin(), in.begin() + prefix_);
      Bytes edited = MutatePlain(content, what);
      if (edited.size() < prefix_) return edited;
      Bytes out(edited.begin(), edited.begin() + prefix_);
      const Bytes packed = Gzip(Bytes(edited.begin() + prefix_, edited.end()));
      out.insert(out.end(), packed.begin(), packed.end());
      *what = "inside the gzip: " + *what;
      return out;
    }
    return MutatePlain(in, what);
  }

 private:
  size_t Pick(size_t n) { return n == 0 ? 0 : static_cast<size_t>(rng_() % n); }

  // Where the header ends: a NIfTI-1 header's 352 bytes, a text header's first empty line
  // (NRRD) or its ElementDataFile line (MetaImage), else the first 512 bytes.
  size_t HeaderEnd(const Bytes& b) const {
    const size_t n = b.size();
    if (IsNifti(b)) return std::min(n, prefix_ + 352);
    const std::string text(b.begin() + std::min(prefix_, n),
                           b.begin() + std::min(n, prefix_ + 4096));
    size_t end = text.find("\n\n");
    if (end == std::string::npos) {
      const size_t element = text.find("ElementDataFile");
      end = element == std::string::npos ? std::string::npos : text.find('\n', element);
    }
    return end == std::string::npos ? std::min(n, prefix_ + 512) : prefix_ + end + 1;
  }

  bool IsNifti(const Bytes& b) const {
    if (b.size() < prefix_ + 348) return false;
    int32_t size = 0;
    std::memcpy(&size, b.data() + prefix_, 4);
    return size == 348 || size == 0x5c010000;  // either byte order
  }

  size_t PositionIn(size_t begin, size_t end) { return begin + Pick(end - begin); }

  Bytes MutatePlain(const Bytes& in, std::string* what) {
    Bytes b = in;
    const size_t n = b.size();
    if (n == 0) return b;
    const size_t header = std::max(HeaderEnd(b), std::min(n, prefix_ + 1));
    char line[160];
    switch (Pick(10)) {
      case 0: {  // bit flips anywhere (the selector too)
        const int flips = 1 + static_cast<int>(Pick(4));
        for (int i = 0; i < flips; ++i) b[Pick(n)] ^= static_cast<uint8_t>(1u << Pick(8));
        std::snprintf(line, sizeof(line), "%d bit flips", flips);
        break;
      }
      case 1:
      case 2: {  // bytes of the header set to edge values or random ones
        const int count = 1 + static_cast<int>(Pick(3));
        for (int i = 0; i < count; ++i) {
          const size_t at = PositionIn(std::min(prefix_, header - 1), header);
          b[at] = Pick(2) ? kBytes[Pick(sizeof(kBytes))] : static_cast<uint8_t>(Pick(256));
        }
        std::snprintf(line, sizeof(line), "%d header bytes changed", count);
        break;
      }
      case 3: {  // truncated: in the header or anywhere
        const size_t size = Pick(2) ? Pick(std::min(n, header + 8)) : Pick(n);
        b.resize(size);
        std::snprintf(line, sizeof(line), "truncated to %zu of %zu bytes", size, n);
        break;
      }
      case 4:
      case 5:
      case 6:
        if (IsNifti(b)) return EditNiftiField(b, what);
        return EditNumber(b, header, what);
      case 7: {  // a header line deleted or repeated
        if (IsNifti(b)) return EditNiftiField(b, what);
        std::vector<size_t> starts;
        for (size_t i = prefix_; i < header; ++i) {
          if (i == prefix_ || b[i - 1] == '\n') starts.push_back(i);
        }
        const size_t k = Pick(starts.size());
        const size_t from = starts[k];
        const size_t to = k + 1 < starts.size() ? starts[k + 1] : header;
        const Bytes text(b.begin() + from, b.begin() + to);
        const bool repeat = Pick(2) == 0;
        if (repeat) {
          b.insert(b.begin() + to, text.begin(), text.end());
        } else {
          b.erase(b.begin() + from, b.begin() + to);
        }
        std::snprintf(line, sizeof(line), "header line at byte %zu %s", from,
                      repeat ? "repeated" : "deleted");
        break;
      }
      case 8: {  // bytes inserted
        const size_t at = PositionIn(prefix_ < n ? prefix_ : 0, n + 1);
        const size_t count = 1 + Pick(16);
        Bytes extra(count);
        for (uint8_t& c : extra) {
          c = Pick(2) ? kBytes[Pick(sizeof(kBytes))] : static_cast<uint8_t>(Pick(256));
        }
        b.insert(b.begin() + at, extra.begin(), extra.end());
        std::snprintf(line, sizeof(line), "%zu bytes inserted at %zu", count, at);
        break;
      }
      default: {  // random bytes anywhere
        const int count = 1 + static_cast<int>(Pick(8));
        for (int i = 0; i < count; ++i) b[Pick(n)] = static_cast<uint8_t>(Pick(256));
        std::snprintf(line, sizeof(line), "%d random bytes", count);
        break;
      }
    }
    *what = line;
    return b;
  }

  // A number of the text header (a run of digits, with its sign and decimals) replaced.
  Bytes EditNumber(Bytes b, size_t header, std::string* what) {
    std::vector<std::pair<size_t, size_t>> numbers;
    for (size_t i = prefix_; i < header;) {
      if (!std::isdigit(b[i])) {
        ++i;
        continue;
      }
      size_t from = i > prefix_ && b[i - 1] == '-' ? i - 1 : i;
      while (i < header && (std::isdigit(b[i]) || b[i] == '.' || b[i] == 'e')) ++i;
      numbers.emplace_back(from, i);
    }
    if (numbers.empty()) {
      *what = "no number to edit";
      return b;
    }
    const auto [from, to] = numbers[Pick(numbers.size())];
    const std::string old(b.begin() + from, b.begin() + to);
    const std::string value = kNumbers[Pick(sizeof(kNumbers) / sizeof(kNumbers[0]))];
    b.erase(b.begin() + from, b.begin() + to);
    b.insert(b.begin() + from, value.begin(), value.end());
    *what = "number '" + old + "' at byte " + std::to_string(from) + " -> '" + value + "'";
    return b;
  }

  // A NIfTI-1 field (in the header's byte order) set to an edge value.
  Bytes EditNiftiField(Bytes b, std::string* what) {
    static const std::vector<Field> fields = NiftiFields();
    const Field f = fields[Pick(fields.size())];
    int32_t size = 0;
    std::memcpy(&size, b.data() + prefix_, 4);
    const bool swap = size != 348;
    uint8_t raw[4] = {};
    std::string value;
    if (f.real) {
      const float v = kFloats[Pick(sizeof(kFloats) / sizeof(kFloats[0]))];
      std::memcpy(raw, &v, 4);
      value = std::to_string(v);
    } else {
      const int64_t v = kIntegers[Pick(sizeof(kIntegers) / sizeof(kIntegers[0]))];
      const int16_t v16 = static_cast<int16_t>(v);
      const uint8_t v8 = static_cast<uint8_t>(v);
      if (f.bytes == 2) std::memcpy(raw, &v16, 2);
      if (f.bytes == 1) raw[0] = v8;
      value = std::to_string(f.bytes == 2 ? v16 : v8);
    }
    if (swap) std::reverse(raw, raw + f.bytes);
    std::memcpy(b.data() + prefix_ + f.offset, raw, f.bytes);
    *what = "NIfTI field at " + std::to_string(f.offset) + " -> " + value;
    return b;
  }

  std::mt19937_64 rng_;
  size_t prefix_;
};

// ---- Inputs ----

bool ReadFile(const std::string& path, Bytes* out) {
  FILE* f = std::fopen(path.c_str(), "rb");
  if (f == nullptr) return false;
  uint8_t buffer[1 << 14];
  size_t got = 0;
  while ((got = std::fread(buffer, 1, sizeof(buffer), f)) > 0) {
    out->insert(out->end(), buffer, buffer + got);
  }
  std::fclose(f);
  return true;
}

uint64_t NameHash(const std::string& name) {
  uint64_t h = 1469598103934665603ull;  // FNV-1a
  for (unsigned char c : name) h = (h ^ c) * 1099511628211ull;
  return h;
}

struct Options {
  long mutations = 64;
  uint64_t seed = 1;
  size_t prefix = 0;
  double max_total_time = 0;
  unsigned timeout = 10;
  long malloc_limit_mb = 2048;
  std::string artifact_prefix = "./";
  std::vector<std::string> paths;
};

bool ParseOptions(int argc, char** argv, Options* o) {
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    const size_t eq = arg.find('=');
    const std::string key = arg[0] == '-' && eq != std::string::npos ? arg.substr(1, eq - 1) : "";
    const char* value = key.empty() ? "" : argv[i] + eq + 1;
    if (key == "mutations") {
      o->mutations = std::atol(value);
    } else if (key == "seed") {
      o->seed = std::strtoull(value, nullptr, 10);
    } else if (key == "prefix") {
      o->prefix = static_cast<size_t>(std::atol(value));
    } else if (key == "max_total_time") {
      o->max_total_time = std::atof(value);
    } else if (key == "timeout") {
      o->timeout = static_cast<unsigned>(std::atol(value));
    } else if (key == "malloc_limit_mb") {
      o->malloc_limit_mb = std::atol(value);
    } else if (key == "artifact_prefix") {
      o->artifact_prefix = value;
    } else if (arg[0] == '-') {
      std::fprintf(stderr, "fuzz_replay: unknown option %s\n", argv[i]);
      return false;
    } else {
      o->paths.push_back(arg);
    }
  }
  return !o->paths.empty();
}

void Run(const Bytes& input, const std::string& what, const std::string& name, unsigned timeout) {
  std::snprintf(g_what, sizeof(g_what), "%s", what.c_str());
  std::snprintf(g_artifact, sizeof(g_artifact), "%s", name.c_str());
  g_input = &input;
  g_running = true;
  alarm(timeout);
  LLVMFuzzerTestOneInput(input.data(), input.size());
  alarm(0);
  g_running = false;
}

}  // namespace

int main(int argc, char** argv) {
  Options o;
  if (!ParseOptions(argc, argv, &o)) {
    std::fprintf(stderr, "usage: %s [-mutations=N] [-seed=S] [-prefix=P] [-max_total_time=T] "
                 "[-timeout=T] [-malloc_limit_mb=M] [-artifact_prefix=DIR/] PATH...\n", argv[0]);
    return 2;
  }
  g_malloc_limit = static_cast<size_t>(o.malloc_limit_mb) << 20;
  // Under AddressSanitizer its own handlers report a crash (then the death callback runs);
  // without it, these do.
  for (int sig : {SIGABRT, SIGALRM}) signal(sig, OnSignal);
#ifdef DSR_REPLAY_ASAN
  __sanitizer_install_malloc_and_free_hooks(OnMalloc, OnFree);
#else
  for (int sig : {SIGSEGV, SIGBUS, SIGFPE, SIGILL}) signal(sig, OnSignal);
#endif
  if (__sanitizer_set_death_callback != nullptr) __sanitizer_set_death_callback(OnDeath);
  // Corpus files (each with its mutations) and single files (as they are).
  std::vector<std::pair<std::string, bool>> files;
  for (const std::string& path : o.paths) {
    struct stat st {};
    if (stat(path.c_str(), &st) != 0) {
      std::fprintf(stderr, "fuzz_replay: %s: no such file or folder\n", path.c_str());
      return 2;
    }
    if (!S_ISDIR(st.st_mode)) {
      files.emplace_back(path, false);
      continue;
    }
    std::vector<std::string> names;
    if (DIR* dir = opendir(path.c_str())) {
      while (dirent* entry = readdir(dir)) {
        if (entry->d_name[0] != '.') names.push_back(entry->d_name);
      }
      closedir(dir);
    }
    std::sort(names.begin(), names.end());
    for (const std::string& name : names) files.emplace_back(path + "/" + name, true);
  }
  const auto start = std::chrono::steady_clock::now();
  const auto elapsed = [&] {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  };
  long runs = 0;
  bool stopped = false;
  for (const auto& [path, mutate] : files) {
    Bytes input;
    if (!ReadFile(path, &input)) {
      std::fprintf(stderr, "fuzz_replay: %s cannot be read\n", path.c_str());
      return 2;
    }
    const std::string name = path.substr(path.find_last_of('/') + 1);
    Run(input, path, o.artifact_prefix + "crash-" + name, o.timeout);
    ++runs;
    Mutator mutator(o.seed ^ NameHash(name), o.prefix);
    for (long m = 0; mutate && m < o.mutations; ++m) {
      if (o.max_total_time > 0 && elapsed() > o.max_total_time) {
        stopped = true;
        break;
      }
      std::string what;
      const Bytes mutated = mutator.Mutate(input, &what);
      const std::string id = name + "-" + std::to_string(m);
      Run(mutated, path + ", mutation " + std::to_string(m) + " (" + what + ")",
          o.artifact_prefix + "crash-" + id, o.timeout);
      ++runs;
    }
  }
  std::printf("fuzz_replay: %ld inputs (%zu files, %ld mutations each, seed %llu) in %.1f s%s, "
              "no finding\n", runs, files.size(), o.mutations,
              static_cast<unsigned long long>(o.seed), elapsed(),
              stopped ? " (stopped at -max_total_time: not every mutation ran)" : "");
  return 0;
}
