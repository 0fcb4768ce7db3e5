// dsr_simulate: a sequence following the paper's protocol (DESIGN.md section 6) from the
// built-in phantom or any readable volume. Writes DIR/frame_XX.nii.gz, DIR/mask_XX.nii.gz
// and DIR/gt_poses.json (T = frame_from_world, world = the source's physical space).
#include <cstdio>
#include <filesystem>

#include <gflags/gflags.h>
#include <glog/logging.h>

#include "core/io_image.h"
#include "core/io_poses.h"
#include "sim/phantom.h"
#include "sim/simulate.h"
#include "tools/tool_util.h"

DEFINE_string(out_dir, "", "Output folder (created if missing). Required.");
DEFINE_string(source, "", "Source volume (.nii/.nii.gz/.mha/.mhd/.nrrd); empty = built-in phantom.");
DEFINE_uint64(seed, 1, "Random seed: poses, noise and phantom. Same seed, same sequence.");
DEFINE_int32(num_frames, 11, "Number of frames m (>= 2).");
DEFINE_double(sigma, 25.0, "Standard deviation of the additive Gaussian noise (intensity units, >= 0).");
DEFINE_double(max_rotation_deg, 12.0, "Each Euler angle uniform in +/- this many degrees.");
DEFINE_double(max_translation_voxels, 15.0, "Each translation component uniform in +/- this many voxels.");
DEFINE_string(frame_size, "96,96,80", "Frame grid size in voxels, 'nx,ny,nz' (depth along z).");
DEFINE_double(frame_spacing, 0.0, "Frame voxel spacing in mm; 0 = the source's spacing.");
DEFINE_double(azimuth_deg, 75.0, "Full lateral opening angle of the pyramidal field of view.");
DEFINE_double(elevation_deg, 75.0, "Full elevational opening angle of the pyramidal field of view.");
DEFINE_double(min_depth_voxels, 4.0, "Near-field cut: voxels closer to the apex are outside the field of view.");
DEFINE_int32(phantom_size, 192, "Built-in phantom size in voxels per axis (1 mm spacing).");
DEFINE_bool(write_source, false, "Also write the source volume as DIR/source.nii.gz.");

static bool ValidateNumFrames(const char* flag, int32_t v) { return v >= 2 && v <= 32; }
DEFINE_validator(num_frames, &ValidateNumFrames);
static bool ValidateNonNegative(const char* flag, double v) { return v >= 0.0; }
DEFINE_validator(sigma, &ValidateNonNegative);
static bool ValidatePhantomSize(const char* flag, int32_t v) { return v >= 16 && v <= 1024; }
DEFINE_validator(phantom_size, &ValidatePhantomSize);

int main(int argc, char** argv) {
  dsr::InitTool("Simulates a TEE-like sequence (paper protocol).\n  dsr_simulate --out_dir=DIR [--source=FILE] [--seed=N] [--num_frames=M] [--sigma=S] ...",
                &argc, &argv);
  if (FLAGS_out_dir.empty()) return dsr::Fail("--out_dir is required");
  dsr::SimulationOptions options;
  options.num_frames = FLAGS_num_frames;
  options.noise_sigma = FLAGS_sigma;
  options.seed = FLAGS_seed;
  options.max_rotation_deg = FLAGS_max_rotation_deg;
  options.max_translation_voxels = FLAGS_max_translation_voxels;
  options.frame_spacing_mm = FLAGS_frame_spacing;
  options.azimuth_deg = FLAGS_azimuth_deg;
  options.elevation_deg = FLAGS_elevation_deg;
  options.min_depth_voxels = FLAGS_min_depth_voxels;
  if (!dsr::ParseSize3(FLAGS_frame_size, &options.frame_size)) {
    return dsr::Fail("--frame_size=" + FLAGS_frame_size + ": expected three positive integers 'nx,ny,nz'");
  }
  std::string error;
  if (!options.Validate(&error)) return dsr::Fail(error);

  dsr::Image source;
  if (FLAGS_source.empty()) {
    dsr::PhantomOptions phantom;
    phantom.size = FLAGS_phantom_size;
    phantom.seed = FLAGS_seed;
    source = dsr::MakePhantom(phantom);
  } else if (!dsr::ReadImage(FLAGS_source, &source, &error)) {
    return dsr::Fail("--source: " + error);
  }
  std::error_code ec;
  std::filesystem::create_directories(FLAGS_out_dir, ec);
  if (ec || !std::filesystem::is_directory(FLAGS_out_dir)) {
    return dsr::Fail("--out_dir=" + FLAGS_out_dir + ": cannot create the folder (" + ec.message() + ")");
  }
  dsr::SimulatedSequence sequence;
  if (!dsr::Simulate(source, options, &sequence, &error)) return dsr::Fail(error);

  dsr::PosesFile poses;
  const std::string dir = FLAGS_out_dir + "/";
  for (int f = 0; f < options.num_frames; ++f) {
    char name[64];
    std::snprintf(name, sizeof(name), "frame_%02d.nii.gz", f);
    if (!dsr::WriteImage(sequence.frames[f], dir + name, &error)) return dsr::Fail(error, dsr::kExitFailed);
    poses.images.push_back(name);
    poses.frame_from_world.push_back(sequence.frame_from_world[f]);
    std::snprintf(name, sizeof(name), "mask_%02d.nii.gz", f);
    if (!dsr::WriteMask(sequence.masks[f], dir + name, &error)) return dsr::Fail(error, dsr::kExitFailed);
  }
  if (FLAGS_write_source && !dsr::WriteImage(source, dir + "source.nii.gz", &error)) {
    return dsr::Fail(error, dsr::kExitFailed);
  }
  if (!dsr::WritePoses(poses, dir + "gt_poses.json", &error)) return dsr::Fail(error, dsr::kExitFailed);
  std::printf("dsr_simulate: %d frames of %dx%dx%d voxels (%lld field-of-view voxels each) written to %s\n",
              options.num_frames, options.frame_size[0], options.frame_size[1], options.frame_size[2],
              static_cast<long long>(dsr::CountInside(sequence.masks[0])), FLAGS_out_dir.c_str());
  return EXIT_SUCCESS;
}
