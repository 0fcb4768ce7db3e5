// A simulation run (dsr/app/simulation_run.h).
#include "dsr/app/simulation_run.h"

#include <cmath>
#include <cstdio>
#include <filesystem>

#include "dsr/app/inputs.h"
#include "dsr/io/io_image.h"
#include "dsr/io/io_phases.h"
#include "dsr/io/io_poses.h"

namespace dsr {

std::string SimulatedFrameName(int f) {
  char name[32];
  std::snprintf(name, sizeof(name), "frame_%02d.nii.gz", f);
  return name;
}

std::string SimulatedMaskName(int f) {
  char name[32];
  std::snprintf(name, sizeof(name), "mask_%02d.nii.gz", f);
  return name;
}

namespace {

// One look's world speckle field: complex double on the source's axis-aligned box in frame
// voxels, padded as a frame's.
double WorldSpeckleBytes(const SimulationOptions& options, const ImageGeometry& source,
                         double speckle_padding) {
  const double spacing = SimulatedFrameGeometry(source, options).spacing_mm[0];
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(INFINITY), hi = -lo;
  for (int corner = 0; corner < 8; ++corner) {
    const Eigen::Vector3d xyz_mm = source.IndexToPhysical(
        Eigen::Vector3d(corner & 1 ? source.size[0] - 1 : 0, corner & 2 ? source.size[1] - 1 : 0,
                        corner & 4 ? source.size[2] - 1 : 0));
    lo = lo.cwiseMin(xyz_mm);
    hi = hi.cwiseMax(xyz_mm);
  }
  return 16.0 * ((hi - lo).array() / spacing + 2.0 + speckle_padding).prod();
}

}  // namespace

bool CheckSimulationMemory(const SimulationOptions& options, const ImageGeometry& source,
                           std::string* error) {
  const double frame_voxels = options.frame_size.cast<double>().prod();
  const double speckle_padding = 2.0 * std::ceil(3.0 * options.speckle_correlation_voxels);
  const double padded_voxels =
      (options.frame_size.cast<double>().array() + speckle_padding).prod();
  const bool world_speckle = options.speckle_looks > 0 && options.speckle_world_fraction > 0.0;
  const double effects_bytes =
      (options.attenuation_db_per_cm > 0.0 ? 8.0 * frame_voxels : 0.0) +
      (options.speckle_looks > 0 ? 48.0 * padded_voxels + 12.0 * frame_voxels : 0.0) +
      // Real-echo artefacts: a gradient and its magnitude, two double maps for the shadows,
      // a byte per voxel and view for the dropout wedges.
      (options.echogenicity_range > 0.0 || options.shadow_strength > 0.0 ? 16.0 * frame_voxels
                                                                         : 0.0) +
      (options.dropout_fraction > 0.0 ? frame_voxels * options.num_frames : 0.0) +
      (world_speckle ? 4.0 * frame_voxels * options.num_frames : 0.0) +
      (world_speckle && source.size.minCoeff() > 0
           ? WorldSpeckleBytes(options, source, speckle_padding)
           : 0.0);
  const double echo_bytes_per_voxel =
      options.intensity_mapping == IntensityMapping::kEcho ? 13.0 : 0.0;
  const double source_voxels = source.size.cast<double>().prod();
  // A beating sequence's later phases: a float frame each.
  const double phase_bytes = 4.0 * frame_voxels * options.num_frames * (options.num_phases - 1);
  const double bytes = frame_voxels * (5.0 * options.num_frames + 9.0) + effects_bytes +
                       phase_bytes + (4.0 + echo_bytes_per_voxel) * source_voxels;
  const Eigen::Vector3i& n = options.frame_size;
  return CheckMemoryEstimate("--frame_size=" + std::to_string(n[0]) + "," + std::to_string(n[1]) +
                                 "," + std::to_string(n[2]) +
                                 " --num_frames=" + std::to_string(options.num_frames) +
                                 (options.num_phases > 1
                                      ? " --num_phases=" + std::to_string(options.num_phases)
                                      : ""),
                             bytes,
                             std::to_string(options.num_frames) +
                                 " frames and masks and the source",
                             error);
}

bool LoadSimulationSource(const SimulationOptions& options, const PhantomOptions& phantom,
                          const std::string& source_path, Image* source, std::string* error) {
  if (source_path.empty()) {
    ImageGeometry grid;  // the phantom's extent (1 mm voxels) before it is made
    grid.size = Eigen::Vector3i::Constant(phantom.size);
    if (!CheckSimulationMemory(options, grid, error)) return false;
    *source = MakePhantom(phantom);
    return true;
  }
  // The frames alone first (the source's grid is known once it is read).
  if (!CheckSimulationMemory(options, ImageGeometry(), error)) return false;
  if (!ReadImage(source_path, source, error)) {
    *error = "--source: " + *error;
    return false;
  }
  return CheckSimulationMemory(options, source->geometry, error);
}

void PlanSequenceFiles(const std::string& folder, int num_frames, int num_phases,
                       bool write_source, OutputPlan* plan) {
  plan->AddOutputFolder("out_dir", folder, folder);
  for (int f = 0; f < num_frames; ++f) {
    plan->AddDerivedImage("out_dir", folder, SimulatedFrameName(f));  // 4D with phases
    plan->AddDerivedImage("out_dir", folder, SimulatedMaskName(f));
  }
  if (write_source) plan->AddDerivedImage("out_dir", folder, "source.nii.gz");
  plan->AddDerivedFile("out_dir", folder, "gt_poses.json");
}

bool WriteSequence(const std::string& folder, const SimulationOptions& options,
                   const SimulatedSequence& sequence, const Image* source, std::string* error) {
  const std::filesystem::path dir(folder);
  PosesFile poses;
  if (options.gain_range > 0.0 || options.offset_range > 0.0) {
    // The ground truth of the intensity corrections a registration estimates.
    Frame0IntensityCorrections(sequence.gain, sequence.offset, &poses.gain, &poses.offset);
  }
  const int num_phases = sequence.num_phases();
  for (size_t f = 0; f < sequence.frames.size(); ++f) {
    const int view = static_cast<int>(f);
    const std::string frame_name = SimulatedFrameName(view);
    const std::string path = (dir / frame_name).string();
    // A beating sequence: the view's phases as one 4D image (io/io_phases.h).
    std::vector<const float*> phases;
    for (int p = 0; p < num_phases; ++p) phases.push_back(sequence.Phase(view, p).voxels.data());
    if (!(num_phases > 1 ? WritePhases(sequence.frames[f].geometry, phases, path, error)
                         : WriteImage(sequence.frames[f], path, error)) ||
        !WriteMask(sequence.masks[f], (dir / SimulatedMaskName(view)).string(), error)) {
      return false;
    }
    poses.images.push_back(frame_name);
    poses.frame_from_world.push_back(sequence.frame_from_world[f]);
  }
  if (source != nullptr && !WriteImage(*source, (dir / "source.nii.gz").string(), error)) {
    return false;
  }
  return WritePoses(poses, (dir / "gt_poses.json").string(), error);
}

}  // namespace dsr
