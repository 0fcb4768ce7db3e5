// The tools' shared flags, each defined once with its validator (tools/flags/*.cc), and the
// functions that turn them into the libraries' options. A tool declares here what it uses
// and defines only the flags that are its alone.
//
// The definitions are split by which tools use them, so that a tool links (and its --help
// lists) only its own flags: the objects of the dsr_tool_flags library are linked only when
// a tool refers to one of their flags or functions.
//   frames.cc        --images --masks --blend --feather_voxels    dsr_register, dsr_fuse
//   mask.cc          --mask_erosion                               dsr_simulate, dsr_register, dsr_fuse
//   field_of_view.cc --mask_rule                                  dsr_register, dsr_fuse, dsr_compare
//   mode.cc          --mode, one registration run's options       dsr_register, the Python module
//   panorama.cc      --panorama_spacing --num_threads             dsr_register, dsr_fuse, dsr_compare
//   registration.cc  the registration's options                   dsr_register, dsr_compare
//   simulation.cc    the simulation's options, --out_dir          dsr_simulate, dsr_compare
// A tool whose default differs (dsr_compare measures every method's poses, so its checks
// are off and its start is the identity) sets it with SetFlagDefault before InitTool.
#ifndef DSR_TOOLS_FLAGS_FLAGS_H_
#define DSR_TOOLS_FLAGS_FLAGS_H_

#include <string>
#include <vector>

#include <gflags/gflags.h>

#include "dsr/geometry/field_of_view.h"
#include "dsr/model/panorama.h"
#include "dsr/pipeline/registration.h"
#include "dsr/sim/phantom.h"
#include "dsr/sim/simulate.h"

// frames.cc
DECLARE_string(images);
DECLARE_string(masks);
DECLARE_string(blend);
DECLARE_double(feather_voxels);
// mask.cc
DECLARE_int32(mask_erosion);
// field_of_view.cc
DECLARE_string(mask_rule);
// mode.cc
DECLARE_string(mode);
// panorama.cc
DECLARE_double(panorama_spacing);
DECLARE_int32(num_threads);
// registration.cc
DECLARE_string(init);
DECLARE_int32(max_recoveries);
DECLARE_string(loss);
DECLARE_double(loss_scale);
DECLARE_string(preset);
DECLARE_string(photometric);
DECLARE_string(intensity_transform);
DECLARE_string(panorama_sampling);
DECLARE_string(gauge);
DECLARE_double(search_rotation_deg);
DECLARE_int32(search_rotations);
DECLARE_int32(search_pair_rotations);
DECLARE_int32(search_max_axis);
DECLARE_string(linear_solver);
DECLARE_string(trust_region);
DECLARE_string(kernels);
DECLARE_int32(max_iterations);
DECLARE_int32(coarse_max_iterations);
DECLARE_double(function_tolerance);
DECLARE_double(gradient_tolerance);
DECLARE_double(parameter_tolerance);
DECLARE_double(step_tolerance);
DECLARE_int32(max_rejected_steps);
DECLARE_int32(pyramid_levels);
DECLARE_int32(pyramid_min_size);
DECLARE_double(pyramid_sigma);
DECLARE_double(smoothing);
DECLARE_int32(max_rebuilds);
DECLARE_double(rebuild_tolerance);
DECLARE_double(min_kept_overlap);
DECLARE_double(max_misfit_ratio);
DECLARE_double(max_pair_mismatch_ratio);
DECLARE_double(max_structure_fraction);
DECLARE_double(max_pose_error_voxels);
DECLARE_int32(num_chunks);
DECLARE_bool(reference_cost);
DECLARE_double(memory_budget_mb);
DECLARE_bool(progress);
DECLARE_bool(uncertainty);
// simulation.cc
DECLARE_string(out_dir);
DECLARE_string(source);
DECLARE_uint64(seed);
DECLARE_int32(num_frames);
DECLARE_double(sigma);
DECLARE_string(pose_model);
DECLARE_double(max_rotation_deg);
DECLARE_double(max_translation_voxels);
DECLARE_double(step_rotation_deg);
DECLARE_double(step_translation_voxels);
DECLARE_string(frame_size);
DECLARE_double(frame_spacing);
DECLARE_double(azimuth_deg);
DECLARE_double(elevation_deg);
DECLARE_double(min_depth_voxels);
DECLARE_int32(phantom_size);
DECLARE_uint64(phantom_seed);
DECLARE_string(interpolation);
DECLARE_double(gain_range);
DECLARE_double(offset_range);
DECLARE_int32(speckle_looks);
DECLARE_double(speckle_correlation_voxels);
DECLARE_double(speckle_world_fraction);
DECLARE_double(attenuation_db_per_cm);
DECLARE_string(intensity_mapping);
DECLARE_double(echo_reject);
DECLARE_double(echo_edge_sigma_mm);
DECLARE_double(echo_edge_weight);

namespace dsr {

// Sets a shared flag's default for this tool (before InitTool, so that --help shows it and
// an explicit value still overrides it). `flag` must be defined.
void SetFlagDefault(const char* flag, const std::string& value);

// Whether the flag kept its default (not given on the command line or in a flagfile).
bool FlagIsDefault(const char* flag);

// The files of --images and --masks: parsed (ParseInputList), between min_frames and
// kMaxFrames images, one mask per image or none, no image given twice. False with a
// one-line `error` naming the flag.
bool FrameFilesFromFlags(int min_frames,
                         std::vector<std::string>* image_paths,
                         std::vector<std::string>* mask_paths,
                         std::string* error);

// field_of_view.cc: --mask_rule and --mask_erosion, how a frame given without a mask gets
// one (validated by their validators).
FieldOfViewOptions FieldOfViewFromFlags();

// --blend: the panorama's fusion, and whether it is feathered.
bool FeatherBlend();

// The registration's options from the flags, but for the mode (--mode is a single run's,
// dsr_compare has --methods) and the photometric model (its default depends on the mode).
// --init: a name sets the start and recovery (SetInitialisation); any other text is a
// poses file, returned in *init_file (the start is then the file's poses, with recovery).
// False with a one-line `error` naming the flag.
bool RegistrationOptionsFromFlags(RegistrationOptions* options,
                                  std::string* init_file,
                                  std::string* error);

// mode.cc: one registration run's options (dsr_register, the Python module): --mode, the
// options above, the photometric model for that mode, and RegistrationOptions::Validate.
// False with a one-line `error` naming the flag (or a field, from Validate).
bool RunOptionsFromFlags(RegistrationOptions* options, std::string* init_file,
                         std::string* error);

// --photometric as the model of `mode`: its value, except that the default applies only to
// the modes that estimate photometric parameters (a baseline runs without them unless
// --photometric is given; then RegistrationOptions::Validate refuses it).
PhotometricModel PhotometricFromFlags(Mode mode);

// `value`, the value of `flag`, or the one --preset gives it when the flag was not given.
std::string PresetFlagValue(const char* flag, const std::string& value);
// "preset echo: --photometric=affine ..." (the flags the preset set), or "" without one.
std::string PresetSummary();

// The simulation's options and the built-in phantom's from the flags (validated by their
// validators; `options` is then checked as a whole). False with a one-line `error`.
bool SimulationOptionsFromFlags(SimulationOptions* options,
                                PhantomOptions* phantom,
                                std::string* error);

}  // namespace dsr

#endif  // DSR_TOOLS_FLAGS_FLAGS_H_
