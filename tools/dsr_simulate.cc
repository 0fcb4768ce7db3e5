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
#include "dsr/tools/output_plan.h"
#include "dsr/tools/tool_util.h"

DEFINE_string(out_dir,
              "",
              "Output folder for frame_XX.nii.gz, mask_XX.nii.gz and gt_poses.json; created if "
              "missing. Required.");
DEFINE_string(source,
              "",
              "Source volume to cut the frames from (.nii, .nii.gz, .mha, .mhd, .nrrd, .nhdr). "
              "Empty: the built-in heart-like phantom (see --phantom_size, --phantom_seed).");
DEFINE_uint64(seed,
              1,
              "Random seed of the poses, the noise and the ultrasound-like effects: same seed, "
              "same sequence.");
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
DEFINE_double(gain_range,
              0.0,
              "Ultrasound-like effect (off at 0): each frame's intensities are multiplied by a "
              "gain drawn uniformly in [1 - this, 1 + this], in [0, 0.9]. With --gain_range "
              "or --offset_range, gt_poses.json gets per-frame \"gain\" and \"offset\": the "
              "correction that puts frame i on frame 0's intensity scale, gain_i * I_i + "
              "offset_i (frame 0: 1 and 0).");
DEFINE_double(offset_range,
              0.0,
              "Ultrasound-like effect (off at 0): each frame's intensities get an offset drawn "
              "uniformly in [-this, this] grey levels (after the gain), in [0, 100].");
DEFINE_int32(speckle_looks,
             0,
             "Ultrasound-like effect (off at 0): multiplicative speckle of mean 1, drawn anew "
             "for each frame on its own grid (it follows the probe, not the tissue; see "
             "--speckle_world_fraction): the mean of this many looks of |z|^2, each z a complex "
             "Gaussian field smoothed over --speckle_correlation_voxels; a gamma distribution "
             "with variance 1/looks. 0 or in [1, 64].");
DEFINE_double(speckle_correlation_voxels,
              1.0,
              "With --speckle_looks: standard deviation, in frame voxels, of the Gaussian that "
              "smooths each look's complex field (the speckle's correlation at a lag of d "
              "voxels is about exp(-d^2 / (2 this^2)) for this >= 1), in [0, 4]; 0: "
              "independent voxels.");
DEFINE_double(speckle_world_fraction,
              0.0,
              "With --speckle_looks: the fraction rho of each look's complex field that is "
              "fixed in the world (the tissue) and shared by all frames, the rest drawn per "
              "frame: z = sqrt(rho) z_world + sqrt(1 - rho) z_frame, so the speckle keeps its "
              "mean and variance and two frames' speckle at one world point correlates by "
              "about rho^2. In [0, 1]; 0: independent per frame (the former sequences); > 0 "
              "needs --speckle_looks >= 1.");
DEFINE_double(attenuation_db_per_cm,
              0.0,
              "Ultrasound-like effect (off at 0): depth attenuation; a voxel at distance r cm "
              "from the pyramid's apex (the centre of the z = 0 face) is multiplied by "
              "10^(-this * r / 20), in [0, 10] dB/cm. Applied, like the speckle, before the "
              "gain, the offset and the noise.");
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
bool ValidateGainRange(const char* flag, double v) {
  return dsr::CheckFlag(std::isfinite(v) && v >= 0.0 && v <= 0.9, flag, v, "must be in [0, 0.9]");
}
bool ValidateOffsetRange(const char* flag, double v) {
  return dsr::CheckFlag(std::isfinite(v) && v >= 0.0 && v <= 100.0, flag, v, "must be in [0, 100]");
}
bool ValidateSpeckleLooks(const char* flag, int32_t v) {
  return dsr::CheckFlag(v >= 0 && v <= 64, flag, v, "must be 0 (no speckle) or in [1, 64]");
}
bool ValidateSpeckleCorrelation(const char* flag, double v) {
  return dsr::CheckFlag(std::isfinite(v) && v >= 0.0 && v <= 4.0, flag, v, "must be in [0, 4]");
}
bool ValidateSpeckleWorldFraction(const char* flag, double v) {
  return dsr::CheckFlag(std::isfinite(v) && v >= 0.0 && v <= 1.0, flag, v, "must be in [0, 1]");
}
bool ValidateAttenuation(const char* flag, double v) {
  return dsr::CheckFlag(std::isfinite(v) && v >= 0.0 && v <= 10.0, flag, v, "must be in [0, 10]");
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
DEFINE_validator(gain_range, &ValidateGainRange);
DEFINE_validator(offset_range, &ValidateOffsetRange);
DEFINE_validator(speckle_looks, &ValidateSpeckleLooks);
DEFINE_validator(speckle_correlation_voxels, &ValidateSpeckleCorrelation);
DEFINE_validator(speckle_world_fraction, &ValidateSpeckleWorldFraction);
DEFINE_validator(attenuation_db_per_cm, &ValidateAttenuation);

namespace {

double SecondsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

int Main(int argc, char** argv) {
  dsr::InitTool(
      "simulates a TEE-like sequence with the paper's protocol (random rigid poses, pyramidal "
      "field of view, Gaussian noise) from the built-in phantom or --source, optionally with "
      "ultrasound-like effects (per-frame gain and offset, speckle, depth attenuation).\n"
      "  dsr_simulate --out_dir=DIR [--source=FILE] [--seed=N] [--num_frames=11] [--sigma=25] "
      "[--pose_model=random|walk] [--interpolation=linear|cubic] [--gain_range=0] "
      "[--offset_range=0] [--speckle_looks=0] [--speckle_world_fraction=0] "
      "[--attenuation_db_per_cm=0] ...\n"
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
  options.gain_range = FLAGS_gain_range;
  options.offset_range = FLAGS_offset_range;
  options.speckle_looks = FLAGS_speckle_looks;
  options.speckle_correlation_voxels = FLAGS_speckle_correlation_voxels;
  options.speckle_world_fraction = FLAGS_speckle_world_fraction;
  options.attenuation_db_per_cm = FLAGS_attenuation_db_per_cm;
  std::string error;
  if (!options.Validate(&error)) return dsr::Fail(error);
  // Clear cases of too little memory are refused before any work: the frames (float) and
  // masks (uint8), the field of view and one frame's copies while it is written, the
  // source (checked again once a --source is read), and the effects' scratch: the
  // attenuation (double) and the speckle's three complex double grids, padded by
  // 3 --speckle_correlation_voxels per side, its sum (double) and its field (float); with
  // --speckle_world_fraction also every frame's field (float) and one look's world field
  // (complex double on the world grid padded likewise; the fields of view lie in the
  // source, so at most the source's axis-aligned box in frame voxels).
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
    const double bytes = frame_voxels * (5.0 * options.num_frames + 9.0) + effects_bytes +
                         world_bytes + 4.0 * source_voxels;
    return dsr::CheckMemoryEstimate(
        "--frame_size=" + FLAGS_frame_size + " --num_frames=" + std::to_string(options.num_frames),
        bytes,
        std::to_string(options.num_frames) + " frames and masks and the source",
        &error);
  };
  const double phantom_voxels = std::pow(static_cast<double>(FLAGS_phantom_size), 3);
  dsr::ImageGeometry phantom_grid;  // the phantom's extent (1 mm voxels) before it is made
  phantom_grid.size = Eigen::Vector3i::Constant(FLAGS_phantom_size);
  if (!check_memory(FLAGS_source.empty() ? phantom_voxels : 0.0,
                    FLAGS_source.empty() ? world_speckle_bytes(phantom_grid) : 0.0)) {
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
  if (!FLAGS_source.empty() && !check_memory(static_cast<double>(source.voxels.size()),
                                              world_speckle_bytes(source.geometry))) {
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
