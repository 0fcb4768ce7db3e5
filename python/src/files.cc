// The package's reads and writes of files: images (3D, or 4D of phases), poses files and ITK
// transforms, each write checked first against the inputs read and its folder (CheckWrite).
#include "module_internal.h"

#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include "dsr/app/output_plan.h"
#include "dsr/geometry/volume.h"
#include "dsr/io/io_image.h"
#include "dsr/io/io_phases.h"
#include "dsr/io/io_poses.h"
#include "dsr/io/io_transform.h"

namespace dsr {
namespace python_internal {
namespace {

// Before a write of the package: OSError naming both files when `path` is an input a
// registration or a fusion of this process read (inputs are never overwritten), or a FIFO
// or device (an atomic write would replace it), or its folder is missing or not writable.
void CheckWrite(const std::string& path, bool image) {
  OutputPlan plan;
  ReadInputs().AddTo(&plan);
  if (image) {
    plan.AddOutputImage("path", path);
  } else {
    plan.AddOutputFile("path", path);
  }
  std::string error;
  if (!plan.Check(&error)) WriteFailed(error);
}

// A 4D array [t][k][j][i] written as T phases (io/io_phases.h, WritePhases) straight from
// the array (float32, C order: no copy unless numpy must convert), after the checks
// ToVolume makes for a 3D one (a 3D grid, finite voxels, named by phase).
void WritePhasesFile(const py::array& input, const Geometry& geometry, const std::string& path) {
  if (input.dtype().kind() == 'c') {
    BadInput("image: complex pixels (" + std::string(py::str(input.dtype())) +
             "); dsr writes real intensities: pass the magnitude (numpy.abs) or the real part");
  }
  const auto array = py::array_t<float, py::array::c_style | py::array::forcecast>::ensure(input);
  if (!array) BadInput("image: not an array of numbers");
  const ImageGeometry grid =
      ToGeometry({array.shape(1), array.shape(2), array.shape(3)}, geometry, "image");
  std::string error;
  if (!grid.Validate("image", &error)) BadInput(error);
  const size_t count = static_cast<size_t>(grid.NumVoxels());
  std::vector<const float*> voxels;
  for (ssize_t t = 0; t < array.shape(0); ++t) {
    const float* phase = array.data() + static_cast<size_t>(t) * count;
    const float* bad =
        std::find_if(phase, phase + count, [](float v) { return !std::isfinite(v); });
    if (bad != phase + count) {
      BadInput("image: phase " + std::to_string(t) + ": " +
               VoxelName(bad - phase, grid.size[0], grid.size[1]) + " is " +
               (std::isnan(*bad) ? "NaN" : "Inf"));
    }
    voxels.push_back(phase);
  }
  if (!WritePhases(grid, voxels, path, &error)) WriteFailed(error);
}

}  // namespace

void WriteTransformFile(const py::array& pose, const std::string& path) {
  CheckWrite(path, /*image=*/false);
  std::string error;
  if (!WriteItkTransform(ToPose(pose, "pose: "), path, &error)) WriteFailed(error);
}

py::tuple ReadImageFile(const std::string& path) {
  std::vector<Image> phases;
  std::string error;
  if (!ReadPhases(path, &phases, &error)) BadInput(error);
  return PhasesToArray(std::move(phases));
}

void WriteImageFile(const py::array& array, const Geometry& geometry, const std::string& path) {
  CheckWrite(path, /*image=*/true);
  if (array.ndim() == 4) return WritePhasesFile(array, geometry, path);
  std::string error;
  if (!WriteImage(ToVolume<float>(array, geometry, "image"), path, &error)) WriteFailed(error);
}

py::dict ReadPosesFile(const std::string& path, int expected_frames) {
  PosesFile poses;
  std::string error;
  if (!ReadPoses(path, expected_frames, &poses, &error)) BadInput(error);
  return PosesToDict(poses);
}

void WritePosesFile(const py::dict& poses, const std::string& path) {
  CheckWrite(path, /*image=*/false);
  std::string error;
  if (!WritePoses(PosesFromDict(poses), path, &error)) WriteFailed(error);
}

}  // namespace python_internal
}  // namespace dsr
