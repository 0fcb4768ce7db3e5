// The simulation's options as flags (tools/flags/flags.h): dsr_simulate's, and
// dsr_compare's for the sequences it simulates.
#include <cmath>

#include <glog/logging.h>

#include "dsr/tools/flags/flags.h"
#include "dsr/tools/tool_util.h"
#include "dsr/util/option_fields.h"

DEFINE_string(out_dir,
              "",
              "Output folder, created if missing: dsr_simulate writes frame_XX.nii.gz, "
              "mask_XX.nii.gz and gt_poses.json there, dsr_compare results.csv, results.md and "
              "poses/. Required.");
DEFINE_string(source,
              "",
              "Source volume to cut the frames from (.nii, .nii.gz, .mha, .mhd, .nrrd, .nhdr). "
              "Empty: the built-in heart-like phantom (see --phantom_size, --phantom_seed).");
DEFINE_uint64(seed,
              1,
              "Random seed of the poses, the noise and the ultrasound-like effects: same seed, "
              "same sequence (dsr_compare: of its first simulated sequence; sequence s uses "
              "--seed + s).");
DEFINE_int32(num_frames, 11, "Number of frames m, in [2, 1000] (the paper: 11; a registration takes at most 32).");
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
DEFINE_string(intensity_mapping,
              "none",
              "How the source's intensities are mapped before the frames are cut: none (as "
              "they are) or echo (echocardiography-like, for any source: the source is mapped "
              "once on its own grid to 255 clamp((1 - w) max(0, S - r) / (255 - r) + w min(1, "
              "|grad G * S| / g99), 0, 1), with r = --echo_reject (darker regions such as a "
              "blood pool, lungs or CSF go black), G a Gaussian of --echo_edge_sigma_mm, g99 "
              "the 99th percentile of the gradient magnitude over the non-zero source voxels "
              "and w = --echo_edge_weight (bright interfaces); the effects and the noise are "
              "then applied to the frames as without it).");
DEFINE_double(echo_reject,
              76.5,
              "--intensity_mapping=echo: source values up to this (grey levels) map to black, "
              "as below an echo machine's reject; the rest is rescaled to the full scale. In "
              "[0, 250]; the default is 30 % of full scale.");
DEFINE_double(echo_edge_sigma_mm,
              1.0,
              "--intensity_mapping=echo: standard deviation in mm (physical, also on "
              "anisotropic sources) of the Gaussian that smooths the source before its "
              "gradient is taken for the interfaces, in [0, 20]; 0: the raw source.");
DEFINE_double(echo_edge_weight,
              0.35,
              "--intensity_mapping=echo: the share of the full scale that the interfaces add "
              "(gradient magnitude at or above its 99th percentile: the whole share), in "
              "[0, 1]; 0: no interfaces.");

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
bool ValidateIntensityMapping(const char* flag, const std::string& v) {
  dsr::IntensityMapping mapping;
  return dsr::CheckFlag(
      dsr::StringToIntensityMapping(v, &mapping), flag, v, "must be none or echo");
}
bool ValidateEchoReject(const char* flag, double v) {
  return dsr::CheckFlag(std::isfinite(v) && v >= 0.0 && v <= 250.0, flag, v, "must be in [0, 250]");
}
bool ValidateEchoEdgeSigma(const char* flag, double v) {
  return dsr::CheckFlag(std::isfinite(v) && v >= 0.0 && v <= 20.0, flag, v, "must be in [0, 20]");
}
bool ValidateEchoEdgeWeight(const char* flag, double v) {
  return dsr::CheckFlag(std::isfinite(v) && v >= 0.0 && v <= 1.0, flag, v, "must be in [0, 1]");
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
DEFINE_validator(intensity_mapping, &ValidateIntensityMapping);
DEFINE_validator(echo_reject, &ValidateEchoReject);
DEFINE_validator(echo_edge_sigma_mm, &ValidateEchoEdgeSigma);
DEFINE_validator(echo_edge_weight, &ValidateEchoEdgeWeight);

namespace dsr {

bool SimulationOptionsFromFlags(SimulationOptions* options,
                                PhantomOptions* phantom,
                                std::string* error) {
  options->num_frames = FLAGS_num_frames;
  options->max_rotation_deg = FLAGS_max_rotation_deg;
  options->max_translation_voxels = FLAGS_max_translation_voxels;
  CHECK(StringToPoseModel(FLAGS_pose_model, &options->pose_model));  // validated
  options->step_rotation_deg = FLAGS_step_rotation_deg;
  options->step_translation_voxels = FLAGS_step_translation_voxels;
  options->mask_erosion = FLAGS_mask_erosion;
  CHECK(StringToSourceInterpolation(FLAGS_interpolation, &options->interpolation));  // validated
  options->sigma = FLAGS_sigma;
  options->seed = FLAGS_seed;
  CHECK(ParseSize3(FLAGS_frame_size, &options->frame_size));  // validated
  options->frame_spacing = FLAGS_frame_spacing;
  options->azimuth_deg = FLAGS_azimuth_deg;
  options->elevation_deg = FLAGS_elevation_deg;
  options->min_depth_voxels = FLAGS_min_depth_voxels;
  options->gain_range = FLAGS_gain_range;
  options->offset_range = FLAGS_offset_range;
  options->speckle_looks = FLAGS_speckle_looks;
  options->speckle_correlation_voxels = FLAGS_speckle_correlation_voxels;
  options->speckle_world_fraction = FLAGS_speckle_world_fraction;
  options->attenuation_db_per_cm = FLAGS_attenuation_db_per_cm;
  // validated
  CHECK(StringToIntensityMapping(FLAGS_intensity_mapping, &options->intensity_mapping));
  options->echo_reject = FLAGS_echo_reject;
  options->echo_edge_sigma_mm = FLAGS_echo_edge_sigma_mm;
  options->echo_edge_weight = FLAGS_echo_edge_weight;
  phantom->size = FLAGS_phantom_size;
  phantom->seed = FLAGS_phantom_seed;
  if (!options->Validate(error)) return false;
  if (!phantom->Validate(error)) {
    *error = PrefixFieldPaths("phantom", *error);
    return false;
  }
  return true;
}

}  // namespace dsr
