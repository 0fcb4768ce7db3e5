// What the sources of the extension module dsr._core share (each group defined in the file
// its heading names): the errors it raises, the options of a call, the conversions between
// arrays and the library's types, the inputs a call reads, and the functions module.cc binds.
// Not for use outside python/src.
#ifndef DSR_PYTHON_SRC_MODULE_INTERNAL_H_
#define DSR_PYTHON_SRC_MODULE_INTERNAL_H_

#include <cstdint>
#include <optional>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

// Every source includes all four, so that each sees the same type casters.
#include <pybind11/functional.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <Eigen/Geometry>

#include "dsr/app/options.h"
#include "dsr/app/output_plan.h"
#include "dsr/geometry/field_of_view.h"
#include "dsr/geometry/volume.h"
#include "dsr/io/io_poses.h"
#include "dsr/pipeline/registration_options.h"
#include "dsr/pipeline/registration_result.h"
#include "dsr/solve/solve_options.h"

namespace dsr {
namespace python_internal {

namespace py = pybind11;

using Options = std::vector<std::pair<std::string, std::string>>;

// A 3D image: the voxels as a C-ordered array indexed [k][j][i] (numpy's and SimpleITK's
// order) and the geometry (spacing, origin, direction as 9 numbers, row-major).
using Geometry = std::tuple<std::vector<double>, std::vector<double>, std::vector<double>>;

// Defined in errors.cc.

// Raised for a run that was set up right but did not give a result (dsr_register's exit
// status 1): the Python class dsr.RegistrationError.
extern PyObject* registration_error;

// Bad input: ValueError with `message`, its field paths written as the keywords of the
// Python functions (FieldPathsAsOptions).
[[noreturn]] void BadInput(const std::string& message);

// `message` with its field paths written as those keywords.
std::string AsOptions(const std::string& message);

// A write that failed (a missing folder, a full disk): OSError with the writer's message.
[[noreturn]] void WriteFailed(const std::string& message);

// Defined in options.cc.

// Every floating-point option of `front_end` finite, whatever its own rule says (those of a
// few, --rebuild_tolerance among them, would take inf or nan): one check for all, made once
// the front end's own checks of its options have passed (their messages are the command
// line's).
void RefuseNonFinite(const Settings& settings, uint32_t front_end);

// The Settings of one call of a function of `front_end` from its (name, value) options, in
// order: "flagfile" reads a flagfile with the command line's checks; an option of another
// function is refused as unknown, and a NUL in a name or value.
Settings MakeSettings(const Options& options, uint32_t front_end);

// MakeSettings' Settings of a registration (kPyRegister or kDsrRegister), its options checked
// as the registration checks them (RunOptionsFrom: each one's rule and the rules between
// them), then RefuseNonFinite.
Settings RegisterSettings(const Options& options, uint32_t front_end);

// The options table: each option's name, type, default, group, front ends and help.
py::list OptionsTable();

// Defined in convert.cc.

// The grid of an array of `shape` (numpy's order, [k][j][i]) with the geometry `g`;
// refused, named by `what`, unless the array is 3D and `g` has 3, 3 and 9 numbers.
ImageGeometry ToGeometry(const std::vector<ssize_t>& shape,
                         const Geometry& g,
                         const std::string& what);

// `g` as a Geometry (ToGeometry's inverse).
Geometry FromGeometry(const ImageGeometry& g);

// `input` on `geometry` as a Volume<T> (T: float, an image; double, a mask's values), named
// by `what`: complex or non-numeric values refused, and for T = float values beyond
// float32's range, non-finite voxels and with `refuse_constant` a constant image (a view's
// phase).
template <typename T>
Volume<T> ToVolume(const py::array& input,
                   const Geometry& geometry,
                   const std::string& what,
                   bool refuse_constant = false);

// A mask as a mask file is read (io/io_image.h, ReadMask): any numeric type, non-zero =
// inside; NaN refused, and a mask with no voxel inside.
Mask ToMask(const py::array& input, const Geometry& geometry, const std::string& what);

// A mask as a mask file of a view is read (io/io_phases.h, ReadMaskPhases): a 3D array as
// ToMask; an array of 4 axes [t][k][j][i] only when every phase has phase 0's inside (then it
// is that 3D mask), refused with the command line's message otherwise.
Mask ToMaskPhases(const py::array& input, const Geometry& geometry, const std::string& what);

// A volume's voxels as a C-ordered array [k][j][i] (T: float, an image; uint8_t, a mask).
template <typename T>
py::array_t<T> ToArray(const Volume<T>& volume);

// A pose as its 4x4 matrix.
py::array_t<double> ToArray(const Eigen::Isometry3d& pose);

// A 4x4 pose with a poses file's rules (finite, rigid: PoseFromMatrix), named by `where`
// ("pose 1: ") in a message.
Eigen::Isometry3d ToPose(const py::array_t<double, py::array::c_style | py::array::forcecast>& a,
                         const std::string& where);

// A poses file's contents as the poses dict (images, frame_from_world, covariance,
// predicted_tre_mm, gain, offset).
py::dict PosesToDict(const PosesFile& poses);

// The poses dict as a PosesFile, with a poses file's rules (ToPose for each pose, 6x6
// covariances, finite gains > 0, one entry per pose in every list given).
PosesFile PosesFromDict(const py::dict& d);

// One phase as a 3D array [k][j][i], T > 1 phases (one grid) as a 4D array [t][k][j][i],
// with the phases' 3D geometry; each phase's voxels freed once copied (one copy at a time).
py::tuple PhasesToArray(std::vector<Image> phases);

// Defined in summary.cc.

// register's "summary" of `result`: the mode, `field_of_view`, the solves and their costs,
// the timings, the recoveries and the checks' findings, and `preset` when not empty.
py::dict Summary(const RegistrationOptions& options,
                 const RegistrationResult& result,
                 const std::string& field_of_view,
                 const std::string& preset);

// Defined in inputs.cc.

// "a,b,c": paths as a list option's value.
std::string JoinPaths(const py::list& paths);

// Images given as (array, geometry) pairs and their masks (the same, or empty for each
// image's field of view by `fov`), with the rules FrameFilesFrom has for --images and
// --masks, named by argument. `mask_rules`: which rule made each mask (empty when given).
// With `later_phases`, an image array of 4 axes [t][k][j][i] is a view of T phases: its
// phase 0 in `frames`, the others in (*later_phases)[i] (a 3D array: none).
void ReadArrays(int min_frames,
                const py::list& images,
                const py::list& masks,
                const FieldOfViewOptions& fov,
                std::vector<Image>* frames,
                std::vector<Mask>* frame_masks,
                std::vector<MaskRule>* mask_rules,
                std::vector<std::vector<Image>>* later_phases = nullptr);

// Every frame, mask and poses file a registration or a fusion read in this process: no
// write of the package replaces one.
InputRegistry& ReadInputs();

// Defined in register.cc.

// register(images, masks, names, options, initial_poses, on_iteration): PrepareRun's run,
// checked as dsr_register checks it and solved without the GIL; the poses file's contents,
// a summary and the input files (Result.save refuses to write over them).
py::dict RegisterImages(const py::list& images,
                        const py::list& masks,
                        const std::vector<std::string>& names,
                        const Options& options_in,
                        const std::optional<std::vector<py::array_t<double>>>& initial_poses,
                        const IterationObserver& on_iteration);

// register_files(options): dsr_register as a function, for front ends that want its outputs
// (dsr.cohort): the options are dsr_register's flags (--images, --out_poses, --report_dir,
// --gt_poses, ...), checked, run and written by the same RegistrationRun, so the files are
// dsr_register's byte for byte. Returns the summary's lines and figures; ValueError for bad
// input, RegistrationError for a registration without a result, OSError for a failed write.
py::dict RegisterFiles(const Options& options_in);

// check_register_files(options): what register_files refuses before it reads an image, with
// its messages: the options' rules, the --images and --masks lists (at least 2 frames, none
// given twice, every file there), --init's and --gt_poses' files, and every output against
// the inputs and its folder (the output plan). Nothing is read or written: dsr.cohort checks
// every study of a manifest with it before any study runs.
void CheckRegisterFiles(const Options& options_in);

// check_register_options(options): the options alone (without files) as register_files
// checks them (RegisterSettings).
void CheckRegisterOptions(const Options& options_in);

// init_is_file(text): whether --init=text is a poses file's path (not one of --init's names).
bool InitIsFile(const std::string& text);

// Defined in simulate.cc.

// simulate(options): dsr_simulate's sequence (frames, masks, ground truth) in memory.
py::dict SimulateSequence(const Options& options_in);

// Defined in fuse.cc.

// fuse(images, masks, names, poses, options): dsr_fuse's panorama (mean, count and the
// field-of-view enlargement) of the images at the poses: a poses file's path (read and
// checked as dsr_fuse reads --poses) or the poses dict of read_poses or a registration;
// gains and offsets correct the intensities as in dsr_fuse.
py::tuple FuseImages(const py::list& images,
                     const py::list& masks,
                     const std::vector<std::string>& names,
                     const py::object& poses_in,
                     const Options& options_in);

// Defined in files.cc.

// write_tfm(pose, path): a 4x4 pose (ToPose) as an ITK transform file.
void WriteTransformFile(const py::array& pose, const std::string& path);

// A 3D file as a 3D array; a 4D file of T > 1 phases (io/io_phases.h) as a 4D array.
py::tuple ReadImageFile(const std::string& path);

// write_image(array, geometry, path): a 3D array as an image file (ToVolume's checks), a
// 4D one [t][k][j][i] as T phases.
void WriteImageFile(const py::array& array, const Geometry& geometry, const std::string& path);

// read_poses(path, expected_frames): a poses file (ReadPoses' checks; any number of poses
// when expected_frames < 0) as the poses dict.
py::dict ReadPosesFile(const std::string& path, int expected_frames);

// write_poses(poses, path): the poses dict (PosesFromDict) as a poses file.
void WritePosesFile(const py::dict& poses, const std::string& path);

}  // namespace python_internal
}  // namespace dsr

#endif  // DSR_PYTHON_SRC_MODULE_INTERNAL_H_
