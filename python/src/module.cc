// dsr._core: the C++ side of the Python package (python/dsr/__init__.py is the API users
// call). It is a front end like the command-line tools: options arrive as names and values
// and go through the application layer (dsr/app: the options table's rules and defaults,
// the mapping to RegistrationOptions and SimulationOptions), so a registration from Python
// is the registration dsr_register runs, with its messages. Each call has its own Settings:
// no state is shared between calls, so registrations in several threads do not meet. Only
// conversions live here.
#include <pybind11/functional.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <exception>
#include <filesystem>
#include <limits>
#include <memory>
#include <optional>
#include <sstream>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

#include <Eigen/Geometry>

#include "dsr/app/fusion_run.h"
#include "dsr/app/inputs.h"
#include "dsr/app/options.h"
#include "dsr/app/output_plan.h"
#include "dsr/app/registration_run.h"
#include "dsr/app/run_options.h"
#include "dsr/app/simulation_run.h"
#include "dsr/io/io_frames.h"
#include "dsr/io/io_image.h"
#include "dsr/io/io_phases.h"
#include "dsr/io/io_poses.h"
#include "dsr/io/io_transform.h"
#include "dsr/model/panorama.h"
#include "dsr/pipeline/input_checks.h"
#include "dsr/pipeline/registration.h"
#include "dsr/pipeline/report.h"
#include "dsr/util/clock.h"
#include "dsr/sim/phantom.h"
#include "dsr/sim/simulate.h"

namespace py = pybind11;

namespace dsr {
namespace {

// Raised for a run that was set up right but did not give a result (dsr_register's exit
// status 1): the Python class dsr.RegistrationError.
PyObject* registration_error = nullptr;

// The options of the Python functions, by FrontEnd bit: every option of any of them names
// its keyword in a message.
constexpr uint32_t kPythonFrontEnds = kPyRegister | kPyFuse | kPySimulate;

[[noreturn]] void BadInput(const std::string& message) {
  throw py::value_error(FieldPathsAsOptions(message, kPythonFrontEnds));
}

using Options = std::vector<std::pair<std::string, std::string>>;

std::string AsOptions(const std::string& message) {
  return FieldPathsAsOptions(message, kPythonFrontEnds);
}

// `text` with each NUL character written as \0 (a message holding one would end there).
std::string ShowNul(const std::string& text) {
  std::string out;
  for (const char c : text) out += c == '\0' ? std::string("\\0") : std::string(1, c);
  return out;
}

// A name or value with a NUL character in it: C strings end there, so "50\0junk" would be
// read as 50 and a message that shows it would be cut. Refused, naming the option.
void RefuseNul(const std::string& name, const std::string& value) {
  if (name.find('\0') == std::string::npos && value.find('\0') == std::string::npos) return;
  BadInput("--" + ShowNul(name) + "=" + ShowNul(value) +
           ": contains a NUL character (a string ends there); give it without");
}

// Every floating-point option of `front_end` finite, whatever its own rule says (those of a
// few, --rebuild_tolerance among them, would take inf or nan): one check for all, made once
// the front end's own checks of its options have passed (their messages are the command
// line's).
void RefuseNonFinite(const Settings& settings, uint32_t front_end) {
  for (const OptionSpec& spec : OptionTable()) {
    if (spec.type != OptionType::kDouble || (spec.front_ends & front_end) == 0) continue;
    if (std::isfinite(settings.Double(spec.name))) continue;
    BadInput("--" + std::string(spec.name) + "=" + OptionValueText(settings.Value(spec.name)) +
             ": must be a finite number");
  }
}

// The Settings of one call of a function of `front_end` from its (name, value) options, in
// order: "flagfile" reads a flagfile with the command line's checks; an option of another
// function is refused as unknown, and a NUL in a name or value.
Settings MakeSettings(const Options& options, uint32_t front_end) {
  Settings settings = Settings::For(front_end);
  std::string error;
  for (const auto& [name, value] : options) {
    RefuseNul(name, value);
    if (name == "flagfile") {
      if (!settings.ReadFlagfile(value, front_end, &error)) BadInput(error);
      continue;
    }
    const OptionSpec* spec = FindOption(name);
    if (spec == nullptr || (spec->front_ends & front_end) == 0) {
      BadInput("--" + name + "=" + value + ": unknown flag");  // the command line's words
    }
    if (!settings.Set(name, value, &error)) BadInput(error);
  }
  return settings;
}

// MakeSettings' Settings of a registration (kPyRegister or kDsrRegister), its options checked
// as the registration checks them (RunOptionsFrom: each one's rule and the rules between
// them), then RefuseNonFinite.
Settings RegisterSettings(const Options& options, uint32_t front_end) {
  Settings settings = MakeSettings(options, front_end);
  RegistrationOptions checked;
  std::string init_file, error;
  if (!RunOptionsFrom(settings, &checked, &init_file, &error)) BadInput(error);
  RefuseNonFinite(settings, front_end);
  return settings;
}

// A write that failed (a missing folder, a full disk): OSError with the writer's message.
[[noreturn]] void WriteFailed(const std::string& message) {
  PyErr_SetString(PyExc_OSError, message.c_str());
  throw py::error_already_set();
}

// A 3D image: the voxels as a C-ordered array indexed [k][j][i] (numpy's and SimpleITK's
// order) and the geometry (spacing, origin, direction as 9 numbers, row-major).
using Geometry = std::tuple<std::vector<double>, std::vector<double>, std::vector<double>>;

ImageGeometry ToGeometry(const std::vector<ssize_t>& shape, const Geometry& g,
                         const std::string& what) {
  const auto& [spacing, origin, direction] = g;
  if (shape.size() != 3) {
    BadInput(what + ": " + std::to_string(shape.size()) + "D array; dsr registers 3D images " +
             "of scalar voxels (an array of 3 axes)");
  }
  if (spacing.size() != 3 || origin.size() != 3 || direction.size() != 9) {
    BadInput(what + ": spacing and origin need 3 numbers and the direction 9 (a 3x3 matrix)");
  }
  ImageGeometry out;
  out.size = Eigen::Vector3i(static_cast<int>(shape[2]), static_cast<int>(shape[1]),
                             static_cast<int>(shape[0]));
  for (int d = 0; d < 3; ++d) {
    out.spacing_mm[d] = spacing[d];
    out.origin_mm[d] = origin[d];
    for (int e = 0; e < 3; ++e) out.direction(d, e) = direction[3 * d + e];
  }
  return out;
}

Geometry FromGeometry(const ImageGeometry& g) {
  std::vector<double> direction(9);
  for (int d = 0; d < 3; ++d) {
    for (int e = 0; e < 3; ++e) direction[3 * d + e] = g.direction(d, e);
  }
  return {{g.spacing_mm[0], g.spacing_mm[1], g.spacing_mm[2]},
          {g.origin_mm[0], g.origin_mm[1], g.origin_mm[2]},
          direction};
}

// Wider floating-point values beyond float32's range (which the cast would make Inf):
// named as what they are, not as Inf.
void CheckFloatRange(const py::array& input, const std::string& what) {
  // The dtype's Python attribute: pybind11's itemsize() reads a field numpy 2 moved.
  if (input.dtype().kind() != 'f' || input.dtype().attr("itemsize").cast<int>() <= 4) return;
  const auto wide = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(input);
  if (!wide || wide.ndim() != 3) return;
  const double* v = wide.data();
  for (ssize_t n = 0; n < wide.size(); ++n) {
    if (!std::isfinite(v[n]) || std::abs(v[n]) <= std::numeric_limits<float>::max()) continue;
    const ssize_t nx = wide.shape(2), ny = wide.shape(1);
    std::ostringstream value;
    value << v[n];
    BadInput(what + ": voxel (" + std::to_string(n % nx) + "," + std::to_string(n / nx % ny) +
             "," + std::to_string(n / (nx * ny)) + ") is " + value.str() +
             ", beyond float32's range (dsr registers float32 intensities): rescale the image");
  }
}

template <typename T>
Volume<T> ToVolume(const py::array& input, const Geometry& geometry, const std::string& what,
                   bool refuse_constant = false) {
  // numpy would cast complex values to their real part with no more than a warning.
  if (input.dtype().kind() == 'c') {
    BadInput(what + ": complex pixels (" + std::string(py::str(input.dtype())) +
             "); dsr registers real intensities: pass the magnitude (numpy.abs) or the real part");
  }
  if constexpr (std::is_same_v<T, float>) CheckFloatRange(input, what);  // before the cast
  const auto array = py::array_t<T, py::array::c_style | py::array::forcecast>::ensure(input);
  if (!array) BadInput(what + ": not an array of numbers");
  std::vector<ssize_t> shape(array.shape(), array.shape() + array.ndim());
  Volume<T> out(ToGeometry(shape, geometry, what));
  std::string error;
  if (!out.geometry.Validate(what, &error)) BadInput(error);
  std::copy(array.data(), array.data() + out.voxels.size(), out.voxels.begin());
  if constexpr (std::is_same_v<T, float>) {
    bool constant = false;
    if (!CheckFiniteVoxels(out, what, &error, refuse_constant ? &constant : nullptr)) {
      BadInput(error);
    }
    // A view's phase as a 4D file's is read (io/io_phases.h, ReadView).
    if (constant) BadInput(ConstantPhaseError(what, out));
  }
  return out;
}

// A mask as a mask file is read (io/io_image.h, ReadMask): any numeric type, non-zero =
// inside; NaN refused, and a mask with no voxel inside.
Mask ToMask(const py::array& input, const Geometry& geometry, const std::string& what) {
  const Volume<double> values = ToVolume<double>(input, geometry, what);
  Mask mask(values.geometry);
  bool any = false;
  for (size_t v = 0; v < values.voxels.size(); ++v) {
    if (std::isnan(values.voxels[v])) BadInput(what + ": a voxel is NaN (masks are 0 or not)");
    mask.voxels[v] = values.voxels[v] != 0.0;
    any = any || mask.voxels[v] != 0;
  }
  if (!any) BadInput(what + ": no voxel inside (every voxel is 0)");
  return mask;
}

// A mask as a mask file of a view is read (io/io_phases.h, ReadMaskPhases): a 3D array as
// ToMask; an array of 4 axes [t][k][j][i] only when every phase has phase 0's inside (then it
// is that 3D mask), refused with the command line's message otherwise.
Mask ToMaskPhases(const py::array& input, const Geometry& geometry, const std::string& what) {
  if (input.ndim() != 4) return ToMask(input, geometry, what);
  if (input.shape(0) == 0) BadInput(what + ": an array of 0 phases");
  Mask mask = ToMask(input.attr("__getitem__")(0), geometry, what);
  const Eigen::Vector3i& n = mask.geometry.size;
  for (ssize_t t = 1; t < input.shape(0); ++t) {
    const Volume<double> phase = ToVolume<double>(input.attr("__getitem__")(t), geometry,
                                                  what + " phase " + std::to_string(t));
    for (size_t v = 0; v < phase.voxels.size(); ++v) {
      if ((phase.voxels[v] != 0.0) == (mask.voxels[v] != 0)) continue;
      BadInput(what + ": mask phase " + std::to_string(t) + " differs from phase 0 at " +
               VoxelName(static_cast<int64_t>(v), n[0], n[1]) +
               " (a 4D mask is taken only when every phase has the same inside)");
    }
  }
  return mask;
}

template <typename T>
py::array_t<T> ToArray(const Volume<T>& volume) {
  const Eigen::Vector3i& n = volume.geometry.size;
  py::array_t<T> out({static_cast<ssize_t>(n[2]), static_cast<ssize_t>(n[1]),
                      static_cast<ssize_t>(n[0])});
  std::copy(volume.voxels.begin(), volume.voxels.end(), out.mutable_data());
  return out;
}

py::array_t<double> ToArray(const Eigen::Isometry3d& pose) {
  py::array_t<double> out({4, 4});
  for (int r = 0; r < 4; ++r) {
    for (int c = 0; c < 4; ++c) out.mutable_at(r, c) = pose.matrix()(r, c);
  }
  return out;
}

// A 4x4 pose with a poses file's rules (finite, rigid: PoseFromMatrix), named by `where`
// ("pose 1: ") in a message.
Eigen::Isometry3d ToPose(const py::array_t<double, py::array::c_style | py::array::forcecast>& a,
                         const std::string& where) {
  if (a.ndim() != 2 || a.shape(0) != 4 || a.shape(1) != 4) {
    BadInput(where + "a pose must be a 4x4 matrix");
  }
  Eigen::Matrix4d m;
  for (int r = 0; r < 4; ++r) {
    for (int c = 0; c < 4; ++c) m(r, c) = a.at(r, c);
  }
  Eigen::Isometry3d pose;
  std::string error;
  if (!PoseFromMatrix(m, where, &pose, &error)) BadInput(error);
  return pose;
}

py::dict PosesToDict(const PosesFile& poses) {
  py::dict out;
  py::list matrices, covariance;
  for (const Eigen::Isometry3d& pose : poses.frame_from_world) matrices.append(ToArray(pose));
  for (const auto& c : poses.covariance) {
    py::array_t<double> m({6, 6});
    for (int r = 0; r < 6; ++r) {
      for (int k = 0; k < 6; ++k) m.mutable_at(r, k) = c(r, k);
    }
    covariance.append(m);
  }
  out["images"] = poses.images;
  out["frame_from_world"] = matrices;
  out["covariance"] = covariance;
  out["predicted_tre_mm"] = poses.predicted_tre_mm;
  out["gain"] = poses.gain;
  out["offset"] = poses.offset;
  return out;
}

PosesFile PosesFromDict(const py::dict& d) {
  PosesFile poses;
  poses.images = d["images"].cast<std::vector<std::string>>();
  for (const py::handle& m : d["frame_from_world"]) {
    const std::string where = "pose " + std::to_string(poses.frame_from_world.size()) + ": ";
    poses.frame_from_world.push_back(ToPose(py::reinterpret_borrow<py::object>(m), where));
  }
  if (d.contains("covariance")) {
    for (const py::handle& m : d["covariance"]) {
      const auto a = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(m);
      if (!a || a.ndim() != 2 || a.shape(0) != 6 || a.shape(1) != 6) {
        BadInput("a covariance must be a 6x6 matrix");
      }
      Eigen::Matrix<double, 6, 6> c;
      for (int r = 0; r < 6; ++r) {
        for (int k = 0; k < 6; ++k) c(r, k) = a.at(r, k);
      }
      poses.covariance.push_back(c);
    }
  }
  if (d.contains("predicted_tre_mm")) {
    poses.predicted_tre_mm = d["predicted_tre_mm"].cast<std::vector<double>>();
  }
  if (d.contains("gain")) poses.gain = d["gain"].cast<std::vector<double>>();
  if (d.contains("offset")) poses.offset = d["offset"].cast<std::vector<double>>();
  for (double g : poses.gain) {
    if (!(g > 0.0 && std::isfinite(g))) BadInput("gain: every gain must be finite and > 0");
  }
  // One entry per pose in every list given (WritePoses's contract).
  const size_t m = poses.frame_from_world.size();
  for (const auto& [what, count] : {std::pair<const char*, size_t>{"images", poses.images.size()},
                                    {"covariance", poses.covariance.size()},
                                    {"predicted_tre_mm", poses.predicted_tre_mm.size()},
                                    {"gain", poses.gain.size()},
                                    {"offset", poses.offset.size()}}) {
    if (count != 0 && count != m) {
      BadInput(std::string(what) + ": " + std::to_string(count) + " entries for " +
               std::to_string(m) + " poses");
    }
  }
  return poses;
}

py::dict Summary(const RegistrationOptions& options, const RegistrationResult& result,
                 const std::string& field_of_view, const std::string& preset) {
  py::dict s;
  s["mode"] = ModeToString(options.mode);
  s["field_of_view"] = field_of_view;
  // Per view, the share of its field of view left out as a dropout (empty when off).
  s["dropout_fraction"] = result.dropout_fraction;
  s["frames"] = result.frame_from_world.size();
  s["solves"] = result.solves.size();
  s["levels"] = result.solves.empty() ? 0 : result.solves.front().level + 1;
  s["iterations"] = result.total_iterations;
  if (!result.solves.empty()) {
    const LevelSolve& last = result.solves.back();
    s["final_cost"] = last.report.final_cost;
    s["termination"] = last.report.termination;
    s["voxels"] = last.candidate_voxels;
    s["observations"] = last.candidate_observations;
  }
  s["seconds"] = result.seconds;
  s["pyramid_seconds"] = result.pyramid_seconds;
  // The checks' share of `seconds` (docs/design.md section 8), per check.
  const CheckSeconds& checks = result.check_seconds;
  py::dict check_seconds;
  check_seconds["structure"] = checks.structure;
  check_seconds["determination"] = checks.determination;
  check_seconds["brightness"] = checks.brightness;
  check_seconds["uncertainty"] = checks.uncertainty;
  check_seconds["other"] = checks.other;
  s["check_seconds"] = check_seconds;
  s["recoveries"] = result.recoveries.size();
  py::list recoveries;
  for (const RegistrationResult::Recovery& r : result.recoveries) {
    recoveries.append(AsOptions(r.why));
  }
  s["recovery_reasons"] = recoveries;
  if (result.intensity_transform != IntensityTransform::kNone) {
    // The final cost above is on the transform's scale (docs/design.md 2.9).
    s["intensity_transform"] = IntensityTransformToString(result.intensity_transform);
    s["intensity_transform_scale"] = result.intensity_transform_scale;
  }
  if (!result.frame_structure.empty()) {
    py::list fractions;
    for (const FrameStructure& f : result.frame_structure) {
      fractions.append(f.judged ? py::object(py::float_(f.fraction)) : py::object(py::none()));
    }
    s["structure_fraction"] = fractions;  // per frame; None: too flat to judge
  }
  if (!result.pose_error_voxels.empty()) {
    // per frame: the determination check's predicted error, in the frame's voxels
    s["pose_error_voxels"] = result.pose_error_voxels;
  }
  if (!preset.empty()) s["preset"] = preset;
  if (!result.photometric_choice.empty()) {
    s["photometric"] = AsOptions(result.photometric_choice);
  }
  if (options.uncertainty) {
    s["uncertainty"] = AsOptions(UncertaintySummary(result.uncertainty,
                                                            result.uncertainty_note));
  }
  return s;
}

// "a,b,c": paths as a list option's value.
std::string JoinPaths(const py::list& paths) {
  std::string out;
  for (const std::string& p : paths.cast<std::vector<std::string>>()) {
    out += (out.empty() ? "" : ",") + p;
  }
  return out;
}

// Images given as (array, geometry) pairs and their masks (the same, or empty for each
// image's field of view by `fov`), with the rules FrameFilesFrom has for --images and
// --masks, named by argument. `mask_rules`: which rule made each mask (empty when given).
// With `later_phases`, an image array of 4 axes [t][k][j][i] is a view of T phases: its
// phase 0 in `frames`, the others in (*later_phases)[i] (a 3D array: none).
void ReadArrays(int min_frames, const py::list& images, const py::list& masks,
                const FieldOfViewOptions& fov, std::vector<Image>* frames,
                std::vector<Mask>* frame_masks, std::vector<MaskRule>* mask_rules,
                std::vector<std::vector<Image>>* later_phases = nullptr) {
  std::string error;
  const int m = static_cast<int>(images.size());
  if (m < min_frames) {
    BadInput("images: need at least " + std::to_string(min_frames) + " images, got " +
             std::to_string(m));
  }
  if (!masks.empty() && static_cast<int>(masks.size()) != m) {
    BadInput("masks: " + std::to_string(masks.size()) + " masks for " + std::to_string(m) +
             " images");
  }
  mask_rules->assign(masks.empty() ? m : 0, MaskRule::kHull);
  if (later_phases != nullptr) later_phases->assign(m, {});
  for (int i = 0; i < m; ++i) {
    const auto [array, geometry] = images[i].cast<std::pair<py::array, Geometry>>();
    const std::string what = "image " + std::to_string(i);
    if (later_phases != nullptr && array.ndim() == 4) {  // a view's phases, leading axis
      if (array.shape(3) == 1) {
        BadInput(what + ": 4D array of shape (" + std::to_string(array.shape(0)) + ", " +
                 std::to_string(array.shape(1)) + ", " + std::to_string(array.shape(2)) +
                 ", 1): a view's phases go along the first axis, (T, z, y, x); a last axis of "
                 "1 looks like a channel axis (squeeze it)");
      }
      for (ssize_t t = 0; t < array.shape(0); ++t) {
        const py::array phase = array.attr("__getitem__")(t);
        Image volume = ToVolume<float>(phase, geometry, what + " phase " + std::to_string(t),
                                       /*refuse_constant=*/array.shape(0) > 1);
        if (t == 0) {
          frames->push_back(std::move(volume));
        } else {
          (*later_phases)[i].push_back(std::move(volume));
        }
      }
      if (array.shape(0) == 0) BadInput(what + ": an array of 0 phases");
    } else {
      frames->push_back(ToVolume<float>(array, geometry, what));
    }
    if (masks.empty()) {
      frame_masks->emplace_back();
      if (!MaskFromImage(frames->back(), fov, "image " + std::to_string(i), &frame_masks->back(),
                         &(*mask_rules)[i], &error)) {
        BadInput(error);
      }
      continue;
    }
    const auto [mask, mask_geometry] = masks[i].cast<std::pair<py::array, Geometry>>();
    const std::string mask_what = "mask " + std::to_string(i);
    frame_masks->push_back(later_phases != nullptr ? ToMaskPhases(mask, mask_geometry, mask_what)
                                                   : ToMask(mask, mask_geometry, mask_what));
    if (!frame_masks->back().geometry.SameGrid(frames->back().geometry, 1e-3)) {
      BadInput("mask " + std::to_string(i) + ": not on its image's voxel grid");
    }
  }
}

// Every frame, mask and poses file a registration or a fusion read in this process: no
// write of the package replaces one.
InputRegistry& ReadInputs() {
  static InputRegistry* const registry = new InputRegistry();
  return *registry;
}

// The fusion's images and masks (at least one): file paths, read as dsr_fuse reads them
// (masks too), or (array, geometry) pairs, with `settings`' --mask_rule, --mask_erosion and
// --num_threads. `match_names`: what a poses file's entries are matched to (the paths, or
// `names`). True when the views hold --phases' selection already: files are read with it
// (ReadViewPhases, only those phases read), arrays are selected from by FusionRun.
bool ReadFusionInputs(const py::list& images, const py::list& masks,
                      const std::vector<std::string>& names, Settings settings,
                      std::vector<Image>* frames, std::vector<Mask>* frame_masks,
                      std::vector<std::string>* match_names,
                      std::vector<std::vector<Image>>* later_phases) {
  std::string error;
  if (names.size() != images.size()) BadInput("names: need one name per image");
  *match_names = names;
  const RunConfig config = ConfigFrom(settings);
  std::vector<MaskRule> mask_rules;
  if (images.empty() || !py::isinstance<py::str>(images[0])) {
    ReadArrays(1, images, masks, config.field_of_view, frames, frame_masks, &mask_rules,
               later_phases);
    return false;
  }
  // As --images and --masks, so that the paths get dsr_fuse's checks and messages.
  std::vector<std::string> image_paths, mask_paths;
  if (!settings.Set("images", JoinPaths(images), &error) ||
      !settings.Set("masks", JoinPaths(masks), &error) ||
      !FrameFilesFrom(settings, 1, &image_paths, &mask_paths, &error) ||
      !ReadViewPhases(config.phases, image_paths, mask_paths, config.field_of_view,
                      config.num_threads, frames, frame_masks, &mask_rules, later_phases,
                      &error)) {
    BadInput(error);
  }
  for (const std::string& path : image_paths) ReadInputs().AddImage("images", path);
  for (const std::string& path : mask_paths) ReadInputs().AddImage("masks", path);
  *match_names = image_paths;
  return true;
}

// The run dsr_register makes of `images` (file paths, read as dsr_register reads them,
// masks too; or (array, geometry) pairs) and `masks` (the same kind, or empty for each
// image's field of view by --mask_rule eroded by --mask_erosion), named `names` in the
// poses file. The start: `initial` (4x4 arrays, one per image, with recovery as a poses
// file has) when given, else --init's (a poses file is matched to the images by name as
// dsr_register matches it: to the paths, or to `names`).
void PrepareRun(const py::list& images, const py::list& masks,
                const std::vector<std::string>& names, Settings settings,
                const std::optional<std::vector<py::array_t<double>>>& initial,
                RegistrationRun* run) {
  std::string error;
  const int m = static_cast<int>(images.size());
  if (static_cast<int>(names.size()) != m) BadInput("names: need one name per image");
  std::vector<Eigen::Isometry3d> start;
  if (initial.has_value()) {
    if (static_cast<int>(initial->size()) != m) {
      BadInput("initial_poses: " + std::to_string(initial->size()) + " poses for " +
               std::to_string(m) + " images");
    }
    for (int i = 0; i < m; ++i) {
      start.push_back(ToPose((*initial)[i], "initial_poses: pose " + std::to_string(i) + ": "));
    }
    if (!settings.Set("init", "auto", &error)) BadInput(error);
  }
  if (m > 0 && py::isinstance<py::str>(images[0])) {
    if (!settings.Set("images", JoinPaths(images), &error) ||
        !settings.Set("masks", JoinPaths(masks), &error) ||
        !run->PlanFiles(settings, RegistrationOutputs(), &error) || !run->ReadFiles(&error)) {
      BadInput(error);
    }
    run->RememberInputs(&ReadInputs());
    run->set_names(names);
    if (!start.empty()) run->set_start(std::move(start));
    return;
  }
  std::vector<Image> frames;
  std::vector<Mask> frame_masks;
  std::vector<MaskRule> mask_rules;
  std::vector<std::vector<Image>> later_phases;
  ReadArrays(2, images, masks, ConfigFrom(settings).field_of_view, &frames, &frame_masks,
             &mask_rules, &later_phases);
  if (!run->SetFrames(settings, std::move(frames), std::move(frame_masks), std::move(mask_rules),
                      names, std::move(start), &error, std::move(later_phases))) {
    BadInput(error);
  }
}

// Checks `run` as dsr_register checks it and solves it without the GIL. After every
// iteration Python's signal handlers run (Ctrl-C raises KeyboardInterrupt between
// iterations, not when the solve ends), then `on_iteration` when given; their exception stops
// the solve and is raised once it returns. ValueError for bad input, RegistrationError (its
// message through `as_options`) for a registration without a result.
void SolveRun(RegistrationRun* run, const IterationObserver& on_iteration,
              std::string (*as_options)(const std::string&)) {
  std::exception_ptr callback_error;
  run->options().solve.on_iteration = [&](const std::string& label, const IterationRecord& r) {
    if (callback_error) return false;
    py::gil_scoped_acquire gil;
    try {
      if (PyErr_CheckSignals() != 0) throw py::error_already_set();
      return on_iteration ? on_iteration(label, r) : true;
    } catch (...) {
      callback_error = std::current_exception();
      return false;
    }
  };
  std::string error;
  if (!run->Check(&error)) BadInput(error);
  bool ok = false;
  {
    py::gil_scoped_release release;
    ok = run->Run(&error);
  }
  if (callback_error) std::rethrow_exception(callback_error);
  if (!ok) BadInput(error);
  if (!run->result().usable) {
    PyErr_SetString(registration_error, as_options(run->result().failure).c_str());
    throw py::error_already_set();
  }
}

// register(images, masks, names, options, initial_poses, on_iteration): PrepareRun's run,
// checked as dsr_register checks it and solved without the GIL; the poses file's contents,
// a summary and the input files (Result.save refuses to write over them).
py::dict RegisterImages(const py::list& images,
                        const py::list& masks,
                        const std::vector<std::string>& names,
                        const Options& options_in,
                        const std::optional<std::vector<py::array_t<double>>>& initial_poses,
                        const IterationObserver& on_iteration) {
  RegistrationRun run(kPyRegister);
  PrepareRun(images, masks, names, RegisterSettings(options_in, kPyRegister), initial_poses,
             &run);
  RegistrationOptions& options = run.options();
  options.solve.progress = false;  // Python has on_iteration and progress_bar instead
  SolveRun(&run, on_iteration, [](const std::string& m) { return AsOptions(m); });
  const RegistrationResult& result = run.result();
  py::dict out;
  out["poses"] = PosesToDict(ResultPoses(result, run.names()));
  out["summary"] = Summary(options, result, run.FieldOfViewLine(), run.preset_summary());
  return out;
}

// register_files(options): dsr_register as a function, for front ends that want its outputs
// (dsr.cohort): the options are dsr_register's flags (--images, --out_poses, --report_dir,
// --gt_poses, ...), checked, run and written by the same RegistrationRun, so the files are
// dsr_register's byte for byte. Returns the summary's lines and figures; ValueError for bad
// input, RegistrationError for a registration without a result, OSError for a failed write.
py::dict RegisterFiles(const Options& options_in) {
  Settings settings = RegisterSettings(options_in, kDsrRegister);
  const auto start = std::chrono::steady_clock::now();
  const RegistrationOutputs outputs = RegistrationOutputsFrom(settings);
  std::string error;
  if (settings.String("images").empty() || outputs.poses.empty()) {
    BadInput("--images and --out_poses are required");
  }
  RegistrationRun run(kDsrRegister);
  if (!run.PlanFiles(settings, outputs, &error) || !run.ReadFiles(&error)) BadInput(error);
  run.RememberInputs(&ReadInputs());
  const double load_seconds = SecondsSince(start);
  SolveRun(&run, nullptr,
           [](const std::string& m) { return FieldPathsAsOptions(m, kDsrRegister); });
  const RegistrationResult& result = run.result();
  if (!run.Write(&error)) WriteFailed(error);
  py::dict out;
  out["lines"] = run.SummaryLines(SecondsSince(start), load_seconds);
  out["iterations"] = result.total_iterations;
  out["recoveries"] = result.recoveries.size();
  out["seconds"] = SecondsSince(start);
  out["report_index"] = run.report_index();
  if (!outputs.gt_poses.empty()) {
    const PoseErrorSummary& e = run.gt_errors();
    out["tre_mean_mm"] = e.tre_mean_mm;
    out["tre_max_mm"] = e.tre_max_mm;
    out["mae_rotation_rad"] = e.mae_rotation_rad;
    out["mae_translation_mm"] = e.mae_translation_mm;
  }
  if (!result.uncertainty.predicted_tre_mm.empty()) {
    out["predicted_tre_mm"] = result.uncertainty.predicted_tre_mm;
  }
  return out;
}

// check_register_files(options): what register_files refuses before it reads an image, with
// its messages: the options' rules, the --images and --masks lists (at least 2 frames, none
// given twice, every file there), --init's and --gt_poses' files, and every output against
// the inputs and its folder (the output plan). Nothing is read or written: dsr.cohort checks
// every study of a manifest with it before any study runs.
void CheckRegisterFiles(const Options& options_in) {
  const Settings settings = RegisterSettings(options_in, kDsrRegister);
  RegistrationRun run(kDsrRegister);
  std::string error;
  if (!run.PlanFiles(settings, RegistrationOutputsFrom(settings), &error)) BadInput(error);
}

// check_register_options(options): the options alone (without files) as register_files
// checks them (RegisterSettings).
void CheckRegisterOptions(const Options& options_in) {
  RegisterSettings(options_in, kDsrRegister);
}

// init_is_file(text): whether --init=text is a poses file's path (not one of --init's names).
bool InitIsFile(const std::string& text) {
  RegistrationOptions options;
  return !SetInitialisation(text, 0, &options);
}

// simulate(options): dsr_simulate's sequence (frames, masks, ground truth) in memory.
py::dict SimulateSequence(const Options& options_in) {
  SimulationOptions options;
  PhantomOptions phantom;
  std::string error;
  const Settings settings = MakeSettings(options_in, kPySimulate);
  if (!SimulationOptionsFrom(settings, &options, &phantom, &error)) BadInput(error);
  RefuseNonFinite(settings, kPySimulate);
  // As dsr_simulate: what would not fit in memory is refused before any of it is allocated.
  Image source;
  if (!LoadSimulationSource(options, phantom, settings.String("source"), &source, &error)) {
    BadInput(error);
  }
  SimulatedSequence sequence;
  bool ok = false;
  {
    py::gil_scoped_release release;
    ok = Simulate(source, options, &sequence, &error);
  }
  if (!ok) BadInput(error);
  py::list frames, masks, truth;
  for (size_t f = 0; f < sequence.frames.size(); ++f) {
    frames.append(py::make_tuple(ToArray(sequence.frames[f]),
                                 FromGeometry(sequence.frames[f].geometry)));
    masks.append(py::make_tuple(ToArray(sequence.masks[f]),
                                FromGeometry(sequence.masks[f].geometry)));
    truth.append(ToArray(sequence.frame_from_world[f]));
  }
  py::dict out;
  out["frames"] = frames;
  out["masks"] = masks;
  out["frame_from_world"] = truth;
  if (sequence.num_phases() > 1) {  // a beating source: later_phases[i][p - 1], p >= 1
    py::list later_phases;
    for (const std::vector<Image>& view : sequence.later_phases) {
      py::list phases;
      for (const Image& phase : view) {
        phases.append(py::make_tuple(ToArray(phase), FromGeometry(phase.geometry)));
      }
      later_phases.append(phases);
    }
    out["later_phases"] = later_phases;
  }
  if (options.gain_range > 0.0 || options.offset_range > 0.0) {
    std::vector<double> gain, offset;
    Frame0IntensityCorrections(sequence.gain, sequence.offset, &gain, &offset);
    out["gain"] = gain;
    out["offset"] = offset;
  }
  return out;
}

// One phase as a 3D array [k][j][i], T > 1 phases (one grid) as a 4D array [t][k][j][i],
// with the phases' 3D geometry; each phase's voxels freed once copied (one copy at a time).
py::tuple PhasesToArray(std::vector<Image> phases) {
  if (phases.size() == 1) {
    return py::make_tuple(ToArray(phases[0]), FromGeometry(phases[0].geometry));
  }
  const Eigen::Vector3i& n = phases[0].geometry.size;
  py::array_t<float> out({static_cast<ssize_t>(phases.size()), static_cast<ssize_t>(n[2]),
                          static_cast<ssize_t>(n[1]), static_cast<ssize_t>(n[0])});
  float* data = out.mutable_data();
  for (Image& phase : phases) {
    data = std::copy(phase.voxels.begin(), phase.voxels.end(), data);
    std::vector<float>().swap(phase.voxels);
  }
  return py::make_tuple(out, FromGeometry(phases[0].geometry));
}

// fuse(images, masks, names, poses, options): dsr_fuse's panorama (mean, count and the
// field-of-view enlargement) of the images at the poses: a poses file's path (read and
// checked as dsr_fuse reads --poses) or the poses dict of read_poses or a registration;
// gains and offsets correct the intensities as in dsr_fuse.
py::tuple FuseImages(const py::list& images,
                     const py::list& masks,
                     const std::vector<std::string>& names,
                     const py::object& poses_in,
                     const Options& options_in) {
  const int m = static_cast<int>(images.size());
  std::string error, poses_name = "poses";
  PosesFile poses;
  if (py::isinstance<py::str>(poses_in)) {
    poses_name = poses_in.cast<std::string>();
    if (!ReadPoses(poses_name, m, &poses, &error)) BadInput("--poses: " + error);
    ReadInputs().AddFile("poses", poses_name);
  } else {
    poses = PosesFromDict(poses_in.cast<py::dict>());
  }
  std::vector<Image> frames_in;
  std::vector<Mask> masks_in;
  std::vector<std::string> match_names;
  std::vector<std::vector<Image>> later_phases;
  const Settings settings = MakeSettings(options_in, kPyFuse);
  RefuseNonFinite(settings, kPyFuse);  // (its double options' rules refuse inf and nan)
  const bool phases_selected = ReadFusionInputs(images, masks, names, settings, &frames_in,
                                                &masks_in, &match_names, &later_phases);
  FusionRun run(settings);
  if (!run.SetFrames(std::move(frames_in), std::move(masks_in), {}, match_names, std::move(poses),
                     poses_name, &error, std::move(later_phases), phases_selected) ||
      !run.Prepare(&error)) {
    BadInput(error);
  }
  {
    py::gil_scoped_release release;
    run.Fuse();
  }
  const PanoramaImages& fused = run.fused();
  std::vector<Image> means(1, fused.mean);  // every phase's mean: (T, z, y, x) when T > 1
  means.insert(means.end(), run.later_means().begin(), run.later_means().end());
  return py::make_tuple(PhasesToArray(std::move(means)),
                        py::make_tuple(ToArray(fused.count), FromGeometry(run.grid())),
                        fused.EnlargementRatio());
}

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

void WriteTransformFile(const py::array& pose, const std::string& path) {
  CheckWrite(path, /*image=*/false);
  std::string error;
  if (!WriteItkTransform(ToPose(pose, "pose: "), path, &error)) WriteFailed(error);
}

// A 3D file as a 3D array; a 4D file of T > 1 phases (io/io_phases.h) as a 4D array.
py::tuple ReadImageFile(const std::string& path) {
  std::vector<Image> phases;
  std::string error;
  if (!ReadPhases(path, &phases, &error)) BadInput(error);
  return PhasesToArray(std::move(phases));
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

// The options table: each option's name, type, default, group, front ends and help.
py::list OptionsTable() {
  py::list out;
  for (const OptionSpec& spec : OptionTable()) {
    py::dict defaults;  // where a front end's default differs from the table's
    for (const FrontEndDefault& d : FrontEndDefaults()) {
      if (spec.name != std::string(d.name)) continue;
      defaults[FrontEndNames(d.front_end)[0].c_str()] = d.value;
    }
    out.append(py::make_tuple(spec.name, OptionTypeName(spec.type), spec.default_text,
                              spec.group, FrontEndNames(spec.front_ends), spec.help, defaults));
  }
  return out;
}

}  // namespace
}  // namespace dsr

PYBIND11_MODULE(_core, m) {
  m.doc() = "C++ core of the dsr package (see dsr/__init__.py for the API).";
  static py::exception<std::runtime_error> error(m, "RegistrationError", PyExc_RuntimeError);
  dsr::registration_error = error.ptr();
  py::class_<dsr::IterationRecord>(m, "IterationRecord")
      .def_readonly("iteration", &dsr::IterationRecord::iteration)
      .def_readonly("cost", &dsr::IterationRecord::cost)
      .def_readonly("step_norm", &dsr::IterationRecord::step_norm)
      .def_readonly("seconds", &dsr::IterationRecord::seconds)
      .def_readonly("step_accepted", &dsr::IterationRecord::step_accepted);
  m.def("register", &dsr::RegisterImages, py::arg("images"), py::arg("masks"), py::arg("names"),
        py::arg("options"), py::arg("initial_poses"), py::arg("on_iteration"));
  m.def("simulate", &dsr::SimulateSequence, py::arg("options"));
  m.def("register_files", &dsr::RegisterFiles, py::arg("options"));
  m.def("check_register_options", &dsr::CheckRegisterOptions, py::arg("options"));
  m.def("check_register_files", &dsr::CheckRegisterFiles, py::arg("options"));
  m.def("init_is_file", &dsr::InitIsFile, py::arg("text"));
  m.def("fuse", &dsr::FuseImages, py::arg("images"), py::arg("masks"), py::arg("names"),
        py::arg("poses"), py::arg("options"));
  m.def("write_tfm", &dsr::WriteTransformFile, py::arg("pose"), py::arg("path"));
  m.def("read_image", &dsr::ReadImageFile, py::arg("path"));
  m.def("write_image", &dsr::WriteImageFile, py::arg("array"), py::arg("geometry"),
        py::arg("path"));
  m.def("read_poses", &dsr::ReadPosesFile, py::arg("path"), py::arg("expected_frames") = -1);
  m.def("write_poses", &dsr::WritePosesFile, py::arg("poses"), py::arg("path"));
  m.def("options", &dsr::OptionsTable);
}
