// libFuzzer target: the reader of a view's phases (io/io_phases.h) on arbitrary bytes, as
// the tools call it: NumPhasesInView (header only; --phases is checked against it), then
// ReadView of every phase and of a selection (io_frames.h's ReadFrames reads each view so),
// then ReadMaskPhases on the same file. The first byte picks the extension (modulo 8: .nii,
// .nii.gz, .nrrd, .seq.nrrd, .mha, .nhdr, .seq.nhdr, .mhd; a detached header's data may
// follow it in the same file); the rest is the file: 4D NIfTI, NRRD with a list, vector or
// 4th domain axis (3D Slicer's .seq.nrrd), 4D MetaImage, or a 3D file (one phase).
// Any outcome but a crash, a sanitizer report or a leak is fine; a refusal must explain
// itself, accepted phases must agree with the header's count, share a valid grid and hold
// finite voxels, and a selection must give exactly those phases of the full read.
// DSR_FUZZ_VERBOSE=1 prints each read's outcome (to check that the seeds are accepted).
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "dsr/io/io_phases.h"
#include "dsr/tests/fuzz/fuzz_input.h"

namespace {

void CheckPhases(const std::string& path, const std::vector<dsr::Image>& phases) {
  if (phases.empty()) std::abort();
  std::string error;
  for (const dsr::Image& phase : phases) {
    if (!phase.geometry.SameGrid(phases[0].geometry)) std::abort();
    if (!phase.geometry.Validate(path, &error)) std::abort();
    if (static_cast<int64_t>(phase.voxels.size()) != phase.geometry.NumVoxels()) std::abort();
    for (float v : phase.voxels) {
      if (!std::isfinite(v)) std::abort();
    }
  }
}

// The outcome of one read, with DSR_FUZZ_VERBOSE=1.
void Say(const char* what, bool ok, const std::string& error, size_t phases) {
  static const bool verbose = std::getenv("DSR_FUZZ_VERBOSE") != nullptr;
  if (!verbose) return;
  if (ok) {
    std::fprintf(stderr, "  %s: %zu phase(s)\n", what, phases);
  } else {
    std::fprintf(stderr, "  %s: %s\n", what, error.c_str());
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static const char* const kExtensions[] = {".nii",  ".nii.gz", ".nrrd",     ".seq.nrrd",
                                            ".mha",  ".nhdr",   ".seq.nhdr", ".mhd"};
  const std::string path = dsr::WriteFuzzInput("phases", kExtensions, 8, data, size);
  if (path.empty()) return 0;

  int count = 0;
  std::string error;
  const bool counted = dsr::NumPhasesInView(path, &count, &error);
  Say("NumPhasesInView", counted, error, static_cast<size_t>(count));
  if (counted ? count < 1 : error.empty()) std::abort();
  std::vector<dsr::Image> phases;
  std::string read_error;
  const bool read = dsr::ReadView(path, &phases, &read_error);
  Say("ReadView", read, read_error, phases.size());
  if (!read && read_error.empty()) std::abort();
  if (read) {
    // The header alone said how many phases there are.
    if (!counted || static_cast<int>(phases.size()) != count) std::abort();
    CheckPhases(path, phases);
  }
  if (counted) {
    // The last phase and then phase 0, as --phases=<last>,0 reads them: the same voxels.
    const std::vector<int> which = count > 1 ? std::vector<int>{count - 1, 0} : std::vector<int>{0};
    std::vector<dsr::Image> chosen;
    std::string chosen_error;
    const bool chosen_read = dsr::ReadView(path, which, &chosen, &chosen_error);
    Say("ReadView of a selection", chosen_read, chosen_error, chosen.size());
    if (!chosen_read && chosen_error.empty()) std::abort();
    if (chosen_read) {
      if (chosen.size() != which.size()) std::abort();
      CheckPhases(path, chosen);
      for (size_t k = 0; read && k < which.size(); ++k) {
        if (!chosen[k].geometry.SameGrid(phases[which[k]].geometry) ||
            chosen[k].voxels != phases[which[k]].voxels) {
          std::abort();
        }
      }
    }
    // A full read refused where the selection was accepted is fine (a phase not read is
    // not looked at); a full read accepted where the selection was refused is not.
    if (read && !chosen_read) std::abort();
  }
  if (read) {
    dsr::Mask mask;
    std::string mask_error;
    const bool masked = dsr::ReadMaskPhases(path, phases[0].geometry, &mask, &mask_error);
    Say("ReadMaskPhases", masked, mask_error, 1);
    if (!masked && mask_error.empty()) std::abort();
  }
  std::remove(path.c_str());
  return 0;
}
