// dsr_simulate: a sequence following the paper's protocol (docs/design.md section 6,
// sim/simulate.h) cut from the built-in phantom (sim/phantom.h) or from any readable volume.
// Writes DIR/frame_XX.nii.gz, DIR/mask_XX.nii.gz and DIR/gt_poses.json, whose T are
// frame_from_world with world = the source's physical space (not yet frame 0's: consumers
// re-express them relative to frame 0). With --gain_range or --offset_range, each frame of
// gt_poses.json also has "gain" and "offset": the correction gain_i * I_i + offset_i that
// puts frame i on frame 0's intensity scale (dsr::Frame0IntensityCorrections). With
// --num_phases=T > 1 (a beating source) each DIR/frame_XX.nii.gz is a 4D image of the view's
// T phases (its phases share its pose).
#include <chrono>
#include <cinttypes>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <string>

#include <gflags/gflags.h>
#include <glog/logging.h>

#include "dsr/io/io_image.h"
#include "dsr/io/io_poses.h"
#include "dsr/sim/phantom.h"
#include "dsr/sim/simulate.h"
#include "dsr/tools/flags.h"
#include "dsr/app/output_plan.h"
#include "dsr/app/simulation_run.h"
#include "dsr/tools/tool_util.h"
#include "dsr/util/clock.h"


namespace {

int Main(int argc, char** argv) {
  dsr::InitTool(
      "simulates a TEE-like sequence with the paper's protocol (random rigid poses, pyramidal "
      "field of view, Gaussian noise) from the built-in phantom or --source, optionally with "
      "ultrasound-like effects (per-frame gain and offset, speckle, depth attenuation), "
      "real-echo artefacts (view-dependent echogenicity, shadows, a lateral blur that "
      "widens with depth, dropouts) and an echo-like mapping of the source's intensities.\n"
      "  dsr_simulate --out_dir=DIR [--source=FILE] [--seed=N] [--num_frames=11] [--sigma=25] "
      "[--pose_model=random|walk] [--interpolation=linear|cubic] [--gain_range=0] "
      "[--offset_range=0] [--speckle_looks=0] [--speckle_world_fraction=0] "
      "[--attenuation_db_per_cm=0] [--echogenicity_range=0] [--shadow_strength=0] "
      "[--psf_lateral_mm=0] [--dropout_fraction=0] [--intensity_mapping=none|echo] "
      "[--num_phases=1] "
      "[--beat_amplitude_mm=4] ...\n"
      "Writes DIR/frame_XX.nii.gz (with --num_phases=T > 1: 4D, T phases), "
      "DIR/mask_XX.nii.gz, DIR/gt_poses.json. Exit status: 0 ok, "
      "2 bad input, 1 failure. --helpshort lists this tool's flags only.",
      dsr::kDsrSimulate, {"out_dir"}, &argc, &argv);

  dsr::SimulationOptions options;
  dsr::PhantomOptions phantom;
  std::string error;
  if (!dsr::SimulationOptionsFrom(dsr::ToolSettings(), &options, &phantom, &error)) {
    return dsr::Fail(error);
  }
  // Every file this run reads and writes, before the source is read or the folder created.
  const std::string& out_dir = dsr::StringFlag("out_dir");
  const std::string& source_path = dsr::StringFlag("source");
  dsr::OutputPlan plan;
  plan.AddInputImage("source", source_path);
  dsr::PlanSequenceFiles(out_dir, options.num_frames, options.num_phases,
                         dsr::BoolFlag("write_source"), &plan);
  if (!plan.Check(&error)) return dsr::Fail(error);

  auto start = std::chrono::steady_clock::now();
  dsr::Image source;
  if (!dsr::LoadSimulationSource(options, phantom, source_path, &source, &error)) {
    return dsr::Fail(error);
  }
  const double source_seconds = dsr::SecondsSince(start);
  LOG(INFO) << (source_path.empty() ? "phantom " : "read ") << source.geometry.DebugString()
            << " in " << source_seconds << " s";

  start = std::chrono::steady_clock::now();
  dsr::SimulatedSequence sequence;
  if (!dsr::Simulate(source, options, &sequence, &error)) return dsr::Fail(error);
  const double simulate_seconds = dsr::SecondsSince(start);
  LOG(INFO) << "simulated " << options.num_frames << " frames in " << simulate_seconds << " s";
  start = std::chrono::steady_clock::now();
  if (!plan.CreateFolders(&error) ||
      !dsr::WriteSequence(out_dir, options, sequence,
                          dsr::BoolFlag("write_source") ? &source : nullptr, &error)) {
    return dsr::Fail(error, dsr::kExitFailed);
  }
  const double write_seconds = dsr::SecondsSince(start);

  const dsr::ImageGeometry& g = sequence.frames[0].geometry;
  const int64_t fov_voxels = dsr::CountInside(dsr::PyramidFieldOfView(g, options));
  const std::string phases =
      options.num_phases > 1 ? " x " + std::to_string(options.num_phases) + " phases" : "";
  std::printf("dsr_simulate: wrote %d frames%s of %dx%dx%d voxels at %g mm (%" PRId64
              " field-of-view voxels, %" PRId64
              " mask voxels each), %d masks and gt_poses.json%s to %s "
              "(source %.2f s, simulation %.2f s, writing %.2f s)\n",
              options.num_frames,
              phases.c_str(),
              g.size[0],
              g.size[1],
              g.size[2],
              g.spacing_mm[0],
              fov_voxels,
              dsr::CountInside(sequence.masks[0]),
              options.num_frames,
              dsr::BoolFlag("write_source") ? ", source.nii.gz" : "",
              out_dir.c_str(),
              source_seconds,
              simulate_seconds,
              write_seconds);
  return EXIT_SUCCESS;
}

}  // namespace

int main(int argc, char** argv) { return dsr::RunToolMain(argc, argv, &Main); }
