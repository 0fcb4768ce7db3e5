// libFuzzer target: the poses-JSON reader (io/io_poses.h) on arbitrary bytes. The bytes
// are written to a file in /dev/shm (or /tmp) because ReadPoses reads a path, as users call
// it. Any outcome but a crash, a sanitizer report or a leak is fine; when the reader
// accepts a file, its poses (and optional gains and offsets) must be finite and rigid (gains
// > 0) and survive a write/read round trip.
#include <unistd.h>

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "dsr/io/io_poses.h"

namespace {

std::string ScratchPath(const char* suffix) {
  const char* dir = access("/dev/shm", W_OK) == 0 ? "/dev/shm" : "/tmp";
  return std::string(dir) + "/dsr_fuzz_poses_" + std::to_string(getpid()) + suffix;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static const std::string path = ScratchPath(".json");
  static const std::string copy = ScratchPath("_copy.json");
  FILE* f = std::fopen(path.c_str(), "wb");
  if (f == nullptr) return 0;
  std::fwrite(data, 1, size, f);
  std::fclose(f);
  dsr::PosesFile poses;
  std::string error;
  if (!dsr::ReadPoses(path, -1, &poses, &error)) {
    if (error.empty()) std::abort();  // every refusal explains itself
    return 0;
  }
  for (const Eigen::Isometry3d& t : poses.frame_from_world) {
    if (!t.matrix().allFinite()) std::abort();
    const double orthogonality = (t.linear().transpose() * t.linear() -
                                  Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff();
    if (orthogonality > 1e-4) std::abort();
  }
  if (!dsr::WritePoses(poses, copy, &error)) std::abort();
  dsr::PosesFile again;
  if (!dsr::ReadPoses(copy, static_cast<int>(poses.frame_from_world.size()), &again, &error)) {
    std::abort();
  }
  for (size_t i = 0; i < poses.frame_from_world.size(); ++i) {
    if (!(again.frame_from_world[i].matrix() == poses.frame_from_world[i].matrix())) std::abort();
  }
  // The optional intensity corrections: one per frame or none, and exact through the copy.
  for (const std::vector<double>* values : {&poses.gain, &poses.offset}) {
    if (!values->empty() && values->size() != poses.frame_from_world.size()) std::abort();
  }
  for (double gain : poses.gain) {
    if (!(std::isfinite(gain) && gain > 0.0)) std::abort();
  }
  if (again.gain != poses.gain || again.offset != poses.offset) std::abort();
  return 0;
}
