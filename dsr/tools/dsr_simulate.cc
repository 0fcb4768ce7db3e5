// dsr_simulate: a sequence following the paper's protocol (docs/design.md section 6, sim/simulate.h)
// cut from the built-in phantom (sim/phantom.h) or from any readable volume.
// Writes DIR/frame_XX.nii.gz, DIR/mask_XX.nii.gz and DIR/gt_poses.json, whose T are
// frame_from_world with world = the source's physical space (not yet frame 0's: consumers
// re-express them relative to frame 0). With --gain_range or --offset_range, each frame of
// gt_poses.json also has "gain" and "offset": the correction gain_i * I_i + offset_i that
// puts frame i on frame 0's intensity scale (dsr::Frame0IntensityCorrections).
#include <chrono>
#include <cinttypes>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>

#include <gflags/gflags.h>
#include <glog/logging.h>

#include "dsr/io/io_image.h"
#include "dsr/io/io_poses.h"
#include "dsr/sim/phantom.h"
#include "dsr/sim/simulate.h"
#include "dsr/tools/flags.h"
#include "dsr/app/output_plan.h"
#include "dsr/tools/tool_util.h"
#include "dsr/util/clock.h"


namespace {

int Main(int argc, char** argv) {
  dsr::InitTool(
      "simulates a TEE-like sequence with the paper's protocol (random rigid poses, pyramidal "
      "field of view, Gaussian noise) from the built-in phantom or --source, optionally with "
      "ultrasound-like effects (per-frame gain and offset, speckle, depth attenuation) and an "
      "echo-like mapping of the source's intensities.\n"
      "  dsr_simulate --out_dir=DIR [--source=FILE] [--seed=N] [--num_frames=11] [--sigma=25] "
      "[--pose_model=random|walk] [--interpolation=linear|cubic] [--gain_range=0] "
      "[--offset_range=0] [--speckle_looks=0] [--speckle_world_fraction=0] "
      "[--attenuation_db_per_cm=0] [--intensity_mapping=none|echo] ...\n"
      "Writes DIR/frame_XX.nii.gz, DIR/mask_XX.nii.gz, DIR/gt_poses.json. Exit status: 0 ok, "
      "2 bad input, 1 failure. --helpshort lists this tool's flags only.",
      dsr::kDsrSimulate, {"out_dir"}, &argc, &argv);

  dsr::SimulationOptions options;
  dsr::PhantomOptions phantom;
  std::string error;
  if (!dsr::SimulationOptionsFrom(dsr::ToolSettings(), &options, &phantom, &error)) {
    return dsr::Fail(error);
  }
  // Clear cases of too little memory are refused before any work: the frames (float) and
  // masks (uint8), the field of view and one frame's copies while it is written, the
  // source (checked again once a --source is read), and the effects' scratch: the
  // attenuation (double) and the speckle's three complex double grids, padded by
  // 3 --speckle_correlation_voxels per side, its sum (double) and its field (float); with
  // --speckle_world_fraction also every frame's field (float) and one look's world field
  // (complex double on the world grid padded likewise; the fields of view lie in the
  // source, so at most the source's axis-aligned box in frame voxels). With
  // --intensity_mapping=echo the source's map (sim/echo_mapping.h) adds, at its peak, three
  // float grids of the source's size and an all-ones mask (its smoothing), 13 bytes per
  // source voxel; afterwards the map (float) is kept while the frames are cut.
  const double frame_voxels = options.frame_size.cast<double>().prod();
  const double speckle_padding = 2.0 * std::ceil(3.0 * options.speckle_correlation_voxels);
  const double padded_voxels =
      (options.frame_size.cast<double>().array() + speckle_padding).prod();
  const bool world_speckle = options.speckle_looks > 0 && options.speckle_world_fraction > 0.0;
  const double effects_bytes =
      (options.attenuation_db_per_cm > 0.0 ? 8.0 * frame_voxels : 0.0) +
      (options.speckle_looks > 0 ? 48.0 * padded_voxels + 12.0 * frame_voxels : 0.0) +
      (world_speckle ? 4.0 * frame_voxels * options.num_frames : 0.0);
  const auto world_speckle_bytes = [&](const dsr::ImageGeometry& source) {
    if (!world_speckle) return 0.0;
    const double spacing = dsr::SimulatedFrameGeometry(source, options).spacing_mm[0];
    Eigen::Vector3d lo = Eigen::Vector3d::Constant(INFINITY), hi = -lo;
    for (int corner = 0; corner < 8; ++corner) {
      const Eigen::Vector3d xyz_mm = source.IndexToPhysical(
          Eigen::Vector3d(corner & 1 ? source.size[0] - 1 : 0,
                          corner & 2 ? source.size[1] - 1 : 0,
                          corner & 4 ? source.size[2] - 1 : 0));
      lo = lo.cwiseMin(xyz_mm);
      hi = hi.cwiseMax(xyz_mm);
    }
    return 16.0 * ((hi - lo).array() / spacing + 2.0 + speckle_padding).prod();
  };
  const auto check_memory = [&](double source_voxels, double world_bytes) {
    const double echo_bytes_per_voxel =
        options.intensity_mapping == dsr::IntensityMapping::kEcho ? 13.0 : 0.0;
    const double bytes = frame_voxels * (5.0 * options.num_frames + 9.0) + effects_bytes +
                         world_bytes + (4.0 + echo_bytes_per_voxel) * source_voxels;
    return dsr::CheckMemoryEstimate(
        "--frame_size=" + dsr::StringFlag("frame_size") + " --num_frames=" + std::to_string(options.num_frames),
        bytes,
        std::to_string(options.num_frames) + " frames and masks and the source",
        &error);
  };
  const double phantom_voxels = std::pow(static_cast<double>(dsr::IntFlag("phantom_size")), 3);
  dsr::ImageGeometry phantom_grid;  // the phantom's extent (1 mm voxels) before it is made
  phantom_grid.size = Eigen::Vector3i::Constant(dsr::IntFlag("phantom_size"));
  if (!check_memory(dsr::StringFlag("source").empty() ? phantom_voxels : 0.0,
                    dsr::StringFlag("source").empty() ? world_speckle_bytes(phantom_grid) : 0.0)) {
    return dsr::Fail(error);
  }
  // Every file this run reads and writes, before the source is read or the folder created.
  dsr::OutputPlan plan;
  plan.AddInputImage("source", dsr::StringFlag("source"));
  plan.AddOutputFolder("out_dir", dsr::StringFlag("out_dir"), dsr::StringFlag("out_dir"));
  for (int f = 0; f < options.num_frames; ++f) {
    char frame_name[32], mask_name[32];
    std::snprintf(frame_name, sizeof(frame_name), "frame_%02d.nii.gz", f);
    std::snprintf(mask_name, sizeof(mask_name), "mask_%02d.nii.gz", f);
    plan.AddDerivedImage("out_dir", dsr::StringFlag("out_dir"), frame_name);
    plan.AddDerivedImage("out_dir", dsr::StringFlag("out_dir"), mask_name);
  }
  if (dsr::BoolFlag("write_source")) plan.AddDerivedImage("out_dir", dsr::StringFlag("out_dir"), "source.nii.gz");
  plan.AddDerivedFile("out_dir", dsr::StringFlag("out_dir"), "gt_poses.json");
  if (!plan.Check(&error)) return dsr::Fail(error);

  auto start = std::chrono::steady_clock::now();
  dsr::Image source;
  if (dsr::StringFlag("source").empty()) {
    source = dsr::MakePhantom(phantom);
  } else if (!dsr::ReadImage(dsr::StringFlag("source"), &source, &error)) {
    return dsr::Fail("--source: " + error);
  }
  if (!dsr::StringFlag("source").empty() && !check_memory(static_cast<double>(source.voxels.size()),
                                              world_speckle_bytes(source.geometry))) {
    return dsr::Fail(error);
  }
  const double source_seconds = dsr::SecondsSince(start);
  LOG(INFO) << (dsr::StringFlag("source").empty() ? "phantom " : "read ") << source.geometry.DebugString()
            << " in " << source_seconds << " s";

  start = std::chrono::steady_clock::now();
  dsr::SimulatedSequence sequence;
  if (!dsr::Simulate(source, options, &sequence, &error)) return dsr::Fail(error);
  const double simulate_seconds = dsr::SecondsSince(start);
  LOG(INFO) << "simulated " << options.num_frames << " frames in " << simulate_seconds << " s";
  if (!plan.CreateFolders(&error)) return dsr::Fail(error, dsr::kExitFailed);

  start = std::chrono::steady_clock::now();
  const std::filesystem::path dir(dsr::StringFlag("out_dir"));
  dsr::PosesFile poses;
  if (options.gain_range > 0.0 || options.offset_range > 0.0) {
    // The ground truth of the intensity corrections a registration estimates.
    dsr::Frame0IntensityCorrections(sequence.gain, sequence.offset, &poses.gain, &poses.offset);
  }
  for (int f = 0; f < options.num_frames; ++f) {
    char frame_name[32], mask_name[32];
    std::snprintf(frame_name, sizeof(frame_name), "frame_%02d.nii.gz", f);
    std::snprintf(mask_name, sizeof(mask_name), "mask_%02d.nii.gz", f);
    if (!dsr::WriteImage(sequence.frames[f], (dir / frame_name).string(), &error) ||
        !dsr::WriteMask(sequence.masks[f], (dir / mask_name).string(), &error)) {
      return dsr::Fail(error, dsr::kExitFailed);
    }
    poses.images.push_back(frame_name);
    poses.frame_from_world.push_back(sequence.frame_from_world[f]);
  }
  if (dsr::BoolFlag("write_source") && !dsr::WriteImage(source, (dir / "source.nii.gz").string(), &error)) {
    return dsr::Fail(error, dsr::kExitFailed);
  }
  if (!dsr::WritePoses(poses, (dir / "gt_poses.json").string(), &error)) {
    return dsr::Fail(error, dsr::kExitFailed);
  }
  const double write_seconds = dsr::SecondsSince(start);

  const dsr::ImageGeometry& g = sequence.frames[0].geometry;
  const int64_t fov_voxels = dsr::CountInside(dsr::PyramidFieldOfView(g, options));
  std::printf("dsr_simulate: wrote %d frames of %dx%dx%d voxels at %g mm (%" PRId64
              " field-of-view voxels, %" PRId64
              " mask voxels each), %d masks and gt_poses.json%s to %s "
              "(source %.2f s, simulation %.2f s, writing %.2f s)\n",
              options.num_frames,
              g.size[0],
              g.size[1],
              g.size[2],
              g.spacing_mm[0],
              fov_voxels,
              dsr::CountInside(sequence.masks[0]),
              options.num_frames,
              dsr::BoolFlag("write_source") ? ", source.nii.gz" : "",
              dsr::StringFlag("out_dir").c_str(),
              source_seconds,
              simulate_seconds,
              write_seconds);
  return EXIT_SUCCESS;
}

}  // namespace

int main(int argc, char** argv) { return dsr::RunToolMain(argc, argv, &Main); }
