// libFuzzer target: the image-loading wrapper (io/io_image.h ReadImage and ReadMask,
// io/io_phases.h ReadPhases, ITK underneath) on arbitrary bytes. The first byte picks the
// format (.nii, .nii.gz, .mha, .nrrd); the rest is the file. Any outcome but a crash, a
// sanitizer report or a leak is fine; an accepted image (each accepted phase) must have a
// valid grid and finite voxels.
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "dsr/io/io_image.h"
#include "dsr/io/io_phases.h"
#include "dsr/tests/fuzz/fuzz_input.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static const char* const kExtensions[] = {".nii", ".nii.gz", ".mha", ".nrrd"};
  const std::string path = dsr::WriteFuzzInput("image", kExtensions, 4, data, size);
  if (path.empty()) return 0;
  dsr::Image image;
  std::string error;
  const bool ok = dsr::ReadImage(path, &image, &error);
  if (ok) {
    if (!image.geometry.Validate(path, &error)) std::abort();
    if (static_cast<int64_t>(image.voxels.size()) != image.geometry.NumVoxels()) std::abort();
    for (float v : image.voxels) {
      if (!std::isfinite(v)) std::abort();
    }
    dsr::Mask mask;
    if (!dsr::ReadMask(path, image.geometry, &mask, &error) && error.empty()) std::abort();
  } else if (error.empty()) {
    std::abort();
  }
  std::vector<dsr::Image> phases;
  std::string phases_error;
  if (dsr::ReadPhases(path, &phases, &phases_error)) {
    if (phases.empty()) std::abort();
    for (const dsr::Image& phase : phases) {
      if (!phase.geometry.SameGrid(phases[0].geometry)) std::abort();
      if (!phase.geometry.Validate(path, &phases_error)) std::abort();
      if (static_cast<int64_t>(phase.voxels.size()) != phase.geometry.NumVoxels()) std::abort();
      for (float v : phase.voxels) {
        if (!std::isfinite(v)) std::abort();
      }
    }
  } else if (phases_error.empty()) {
    std::abort();
  }
  std::remove(path.c_str());
  return 0;
}
