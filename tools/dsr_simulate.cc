// dsr_simulate: a sequence following the paper's protocol (docs/design.md section 6, sim/simulate.h)
// cut from the built-in phantom (sim/phantom.h) or from any readable volume.
// Writes DIR/frame_XX.nii.gz, DIR/mask_XX.nii.gz and DIR/gt_poses.json, whose T are
// frame_from_world with world = the source's physical space (not yet frame 0's: consumers
// re-express them relative to frame 0).
#include <chrono>
#include <cinttypes>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>

#include <gflags/gflags.h>
#include <glog/logging.h>

#include "core/io_image.h"
#include "core/io_poses.h"
#include "sim/phantom.h"
#include "sim/simulate.h"
#include "tools/output_plan.h"
#include "tools/tool_util.h"

DEFINE_string(out_dir,
              "",
              "Output folder for frame_XX.nii.gz, mask_XX.nii.gz and gt_poses.json; created if "
              "missing. Required.");
DEFINE_string(source,
              "",
              "Source volume to cut the frames from (.nii, .nii.gz, .mha, .mhd, .nrrd, .nhdr). "
              "Empty: the built-in heart-like phantom (see --phantom_size, --phantom_seed).");
DEFINE_uint64(seed, 1, "Random seed of the poses and the noise: same seed, same sequence.");
DEFINE_int32(num_frames, 11, "Number of frames m, in [2, 1000] (the paper: 11).");
DEFINE_double(sigma,
              25.0,
              "Standard deviation of the additive Gaussian noise inside the field of view, in "
              "intensity units (0..255 scale), >= 0 (the paper: 25).");
DEFINE_string(pose_model,
              "random",
              "How the frames' poses are drawn: random (the paper: every frame independently "
              "uniform in the pose box of --max_rotation_deg and --max_translation_voxels) or "
              "walk (frame 0 as random, then each frame the previous one rotated about its "
              "centre by at most --step_rotation_deg about a random axis and shifted by at "
              "most --step_translation_voxels in a random direction, like a probe moved "
              "between acquisitions; clamped to the pose box).");
DEFINE_double(max_rotation_deg,
              12.0,
              "Each of the three Euler angles of a frame's rotation is within [-this, +this] "
              "degrees (uniform with --pose_model=random), in [0, 180] (the paper: 12). "
              "Larger motions need room in the source: for 96x96x80 frames the default 192^3 "
              "phantom fits 45 degrees with 10 voxels, but 25 degrees with 20 voxels only "
              "just (an unlucky draw leaves it by a voxel): use --phantom_size=208 there.");
DEFINE_double(max_translation_voxels,
              15.0,
              "Each world-axis component of a frame's translation is within [-this, +this] "
              "frame voxels (uniform with --pose_model=random), >= 0 (the paper: 15).");
DEFINE_double(step_rotation_deg,
              6.0,
              "--pose_model=walk: the rotation between consecutive frames, about a uniformly "
              "random axis through the previous frame's centre, is uniform in [0, this] "
              "degrees, in [0, 180].");
DEFINE_double(step_translation_voxels,
              6.0,
              "--pose_model=walk: the shift of the frame centre between consecutive frames, "
              "in a uniformly random direction, is uniform in [0, this] frame voxels, >= 0.");
DEFINE_string(frame_size,
              "96,96,80",
              "Frame grid size in voxels 'nx,ny,nz', each in [4, 2048]; the pyramid's depth "
              "runs along z from the apex at the centre of the z = 0 face.");
DEFINE_double(frame_spacing,
              0.0,
              "Isotropic frame voxel spacing in mm, 0 or in [1e-6, 1e6]; 0 = the source's "
              "spacing along x.");
DEFINE_double(azimuth_deg,
              75.0,
              "Full lateral (x) opening angle of the pyramidal field of view, in (0, 180).");
DEFINE_double(elevation_deg,
              75.0,
              "Full elevational (y) opening angle of the pyramidal field of view, in (0, 180).");
DEFINE_double(min_depth_voxels,
              4.0,
              "Near-field cut: slices with depth z < this are outside the field of view; in "
              "[0, nz - 3].");
DEFINE_int32(phantom_size,
             192,
             "Built-in phantom size in voxels per axis (1 mm spacing), in [16, 512]. The "
             "default fits the default frames and motions; 208 fits them at "
             "--max_rotation_deg=25 --max_translation_voxels=20.");
DEFINE_uint64(phantom_seed,
              1,
              "Seed of the built-in phantom's layout jitter and texture. Kept apart from "
              "--seed so that sequences with different --seed are cut from the same volume, "
              "as in the paper.");
DEFINE_int32(mask_erosion,
             1,
             "Erosion of the written masks mask_XX.nii.gz, in voxels (6-neighbourhood per "
             "voxel), in [0, 50]; 0 writes the exact field of view (the registration's "
             "gradients never read outside a mask, so no erosion is needed for them).");
DEFINE_string(interpolation,
              "linear",
              "How a frame voxel samples the source at its world point: linear (trilinear, "
              "the default) or cubic (Keys' cubic convolution, a = -0.5, over 4x4x4 voxels, "
              "indices clamped at the source's border). Either way the frames are exact "
              "samples of one continuous interpolant of the source.");
DEFINE_bool(write_source, false, "Also write the source volume as DIR/source.nii.gz.");

namespace {

bool ValidateNumFrames(const char* flag, int32_t v) {
  return dsr::CheckFlag(v >= 2 && v <= 1000, flag, v, "must be in [2, 1000]");
}
bool ValidateNonNegative(const char* flag, double v) {
  return dsr::CheckFlag(std::isfinite(v) && v >= 0.0, flag, v, "must be finite and >= 0");
}
bool ValidateRotation(const char* flag, double v) {
  return dsr::CheckFlag(std::isfinite(v) && v >= 0.0 && v <= 180.0, flag, v, "must be in [0, 180]");
}
bool ValidatePoseModel(const char* flag, const std::string& v) {
  dsr::PoseModel model;
  return dsr::CheckFlag(dsr::StringToPoseModel(v, &model), flag, v, "must be random or walk");
}
bool ValidateInterpolation(const char* flag, const std::string& v) {
  dsr::SourceInterpolation interpolation;
  return dsr::CheckFlag(dsr::StringToSourceInterpolation(v, &interpolation),
                        flag,
                        v,
                        "must be linear or cubic");
}
bool ValidateMaskErosion(const char* flag, int32_t v) {
  return dsr::CheckFlag(v >= 0 && v <= 50, flag, v, "must be in [0, 50]");
}
bool ValidateOpeningAngle(const char* flag, double v) {
  return dsr::CheckFlag(std::isfinite(v) && v > 0.0 && v < 180.0, flag, v, "must be in (0, 180)");
}
bool ValidateFrameSize(const char* flag, const std::string& v) {
  Eigen::Vector3i size;
  return dsr::CheckFlag(dsr::ParseSize3(v, &size, 4, 2048),
                        flag,
                        v,
                        "must be three integers 'nx,ny,nz', each in [4, 2048]");
}
bool ValidatePhantomSize(const char* flag, int32_t v) {
  return dsr::CheckFlag(v >= 16 && v <= 512, flag, v, "must be in [16, 512]");
}
bool ValidateFrameSpacing(const char* flag, double v) {
  return dsr::CheckFlag(v == 0.0 || (v >= dsr::kMinFrameSpacingMm && v <= dsr::kMaxFrameSpacingMm),
                        flag,
                        v,
                        "must be 0 (the source's spacing) or in [1e-06, 1e+06] mm");
}
bool ValidateSource(const char* flag, const std::string& v) {
  return dsr::CheckInputFileFlag(flag, v);
}

}  // namespace

DEFINE_validator(num_frames, &ValidateNumFrames);
DEFINE_validator(sigma, &ValidateNonNegative);
DEFINE_validator(max_rotation_deg, &ValidateRotation);
DEFINE_validator(max_translation_voxels, &ValidateNonNegative);
DEFINE_validator(pose_model, &ValidatePoseModel);
DEFINE_validator(step_rotation_deg, &ValidateRotation);
DEFINE_validator(step_translation_voxels, &ValidateNonNegative);
DEFINE_validator(mask_erosion, &ValidateMaskErosion);
DEFINE_validator(interpolation, &ValidateInterpolation);
DEFINE_validator(frame_size, &ValidateFrameSize);
DEFINE_validator(frame_spacing, &ValidateFrameSpacing);
DEFINE_validator(azimuth_deg, &ValidateOpeningAngle);
DEFINE_validator(elevation_deg, &ValidateOpeningAngle);
DEFINE_validator(min_depth_voxels, &ValidateNonNegative);
DEFINE_validator(phantom_size, &ValidatePhantomSize);
DEFINE_validator(source, &ValidateSource);

namespace {

double SecondsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

int Main(int argc, char** argv) {
  dsr::InitTool(
      "simulates a TEE-like sequence with the paper's protocol (random rigid poses, pyramidal "
      "field of view, Gaussian noise) from the built-in phantom or --source.\n"
      "  dsr_simulate --out_dir=DIR [--source=FILE] [--seed=N] [--num_frames=11] [--sigma=25] "
      "[--pose_model=random|walk] [--interpolation=linear|cubic] ...\n"
      "Writes DIR/frame_XX.nii.gz, DIR/mask_XX.nii.gz, DIR/gt_poses.json. Exit status: 0 ok, "
      "2 bad input, 1 failure. --helpshort lists this tool's flags only.",
      {"out_dir"},
      &argc,
      &argv);

  dsr::SimulationOptions options;
  options.num_frames = FLAGS_num_frames;
  options.max_rotation_deg = FLAGS_max_rotation_deg;
  options.max_translation_voxels = FLAGS_max_translation_voxels;
  CHECK(dsr::StringToPoseModel(FLAGS_pose_model, &options.pose_model));  // validated
  options.step_rotation_deg = FLAGS_step_rotation_deg;
  options.step_translation_voxels = FLAGS_step_translation_voxels;
  options.mask_erosion_voxels = FLAGS_mask_erosion;
  // Validated by its validator.
  CHECK(dsr::StringToSourceInterpolation(FLAGS_interpolation, &options.interpolation));
  options.noise_sigma = FLAGS_sigma;
  options.seed = FLAGS_seed;
  CHECK(dsr::ParseSize3(FLAGS_frame_size, &options.frame_size));  // validated by its validator
  options.frame_spacing_mm = FLAGS_frame_spacing;
  options.azimuth_deg = FLAGS_azimuth_deg;
  options.elevation_deg = FLAGS_elevation_deg;
  options.min_depth_voxels = FLAGS_min_depth_voxels;
  std::string error;
  if (!options.Validate(&error)) return dsr::Fail(error);
  // Clear cases of too little memory are refused before any work: the frames (float) and
  // masks (uint8), the field of view and one frame's copies while it is written, and the
  // source (checked again once a --source is read).
  const double frame_voxels = options.frame_size.cast<double>().prod();
  const auto check_memory = [&](double source_voxels) {
    const double bytes = frame_voxels * (5.0 * options.num_frames + 9.0) + 4.0 * source_voxels;
    return dsr::CheckMemoryEstimate(
        "--frame_size=" + FLAGS_frame_size + " --num_frames=" + std::to_string(options.num_frames),
        bytes,
        std::to_string(options.num_frames) + " frames and masks and the source",
        &error);
  };
  const double phantom_voxels = std::pow(static_cast<double>(FLAGS_phantom_size), 3);
  if (!check_memory(FLAGS_source.empty() ? phantom_voxels : 0.0)) {
    return dsr::Fail(error);
  }
  // Every file this run reads and writes, before the source is read or the folder created.
  dsr::OutputPlan plan;
  plan.AddInputImage("source", FLAGS_source);
  plan.AddOutputFolder("out_dir", FLAGS_out_dir, FLAGS_out_dir);
  for (int f = 0; f < options.num_frames; ++f) {
    char frame_name[32], mask_name[32];
    std::snprintf(frame_name, sizeof(frame_name), "frame_%02d.nii.gz", f);
    std::snprintf(mask_name, sizeof(mask_name), "mask_%02d.nii.gz", f);
    plan.AddDerivedImage("out_dir", FLAGS_out_dir, frame_name);
    plan.AddDerivedImage("out_dir", FLAGS_out_dir, mask_name);
  }
  if (FLAGS_write_source) plan.AddDerivedImage("out_dir", FLAGS_out_dir, "source.nii.gz");
  plan.AddDerivedFile("out_dir", FLAGS_out_dir, "gt_poses.json");
  if (!plan.Check(&error)) return dsr::Fail(error);

  auto start = std::chrono::steady_clock::now();
  dsr::Image source;
  if (FLAGS_source.empty()) {
    dsr::PhantomOptions phantom;
    phantom.size = FLAGS_phantom_size;
    phantom.seed = FLAGS_phantom_seed;
    if (!phantom.Validate(&error)) return dsr::Fail(error);
    source = dsr::MakePhantom(phantom);
  } else if (!dsr::ReadImage(FLAGS_source, &source, &error)) {
    return dsr::Fail("--source: " + error);
  }
  if (!FLAGS_source.empty() && !check_memory(static_cast<double>(source.voxels.size()))) {
    return dsr::Fail(error);
  }
  const double source_seconds = SecondsSince(start);
  LOG(INFO) << (FLAGS_source.empty() ? "phantom " : "read ") << source.geometry.DebugString()
            << " in " << source_seconds << " s";

  start = std::chrono::steady_clock::now();
  dsr::SimulatedSequence sequence;
  if (!dsr::Simulate(source, options, &sequence, &error)) return dsr::Fail(error);
  const double simulate_seconds = SecondsSince(start);
  LOG(INFO) << "simulated " << options.num_frames << " frames in " << simulate_seconds << " s";
  if (!plan.CreateFolders(&error)) return dsr::Fail(error, dsr::kExitFailed);

  start = std::chrono::steady_clock::now();
  const std::filesystem::path dir(FLAGS_out_dir);
  dsr::PosesFile poses;
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
  if (FLAGS_write_source && !dsr::WriteImage(source, (dir / "source.nii.gz").string(), &error)) {
    return dsr::Fail(error, dsr::kExitFailed);
  }
  if (!dsr::WritePoses(poses, (dir / "gt_poses.json").string(), &error)) {
    return dsr::Fail(error, dsr::kExitFailed);
  }
  const double write_seconds = SecondsSince(start);

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
              FLAGS_write_source ? ", source.nii.gz" : "",
              FLAGS_out_dir.c_str(),
              source_seconds,
              simulate_seconds,
              write_seconds);
  return EXIT_SUCCESS;
}

}  // namespace

int main(int argc, char** argv) { return dsr::RunToolMain(argc, argv, &Main); }
