// What the fuzz targets share: the input written to a file whose extension its first byte
// picks, in /dev/shm where it is writable (else /tmp), one file per process and target.
#ifndef DSR_TESTS_FUZZ_FUZZ_INPUT_H_
#define DSR_TESTS_FUZZ_FUZZ_INPUT_H_

#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <string>

namespace dsr {

// Writes data[1..size) to /dev/shm (or /tmp)/dsr_fuzz_<target>_<pid><extension>, the
// extension extensions[data[0] % count]; its path, or "" when size is 0 or the file cannot be
// written.
inline std::string WriteFuzzInput(const char* target,
                                  const char* const* extensions,
                                  size_t count,
                                  const uint8_t* data,
                                  size_t size) {
  if (size < 1) return "";
  const char* dir = access("/dev/shm", W_OK) == 0 ? "/dev/shm" : "/tmp";
  const std::string path = std::string(dir) + "/dsr_fuzz_" + target + "_" +
                           std::to_string(getpid()) + extensions[data[0] % count];
  FILE* f = std::fopen(path.c_str(), "wb");
  if (f == nullptr) return "";
  std::fwrite(data + 1, 1, size - 1, f);
  std::fclose(f);
  return path;
}

}  // namespace dsr

#endif  // DSR_TESTS_FUZZ_FUZZ_INPUT_H_
