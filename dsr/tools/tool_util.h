// Helpers shared by the command-line tools (tools/ is the only place gflags is used):
// start-up (flags, glog), one-line errors with the project's exit codes, flag validators
// that name the broken rule, and small parsers for list-valued flags.
//
// Exit codes: 0 success, 2 bad input (flags, files), 1 a run that started but failed.
#ifndef DSR_TOOLS_TOOL_UTIL_H_
#define DSR_TOOLS_TOOL_UTIL_H_

#include <cstdint>
#include <sstream>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "dsr/geometry/field_of_view.h"
#include "dsr/geometry/volume.h"
#include "dsr/io/io_poses.h"
#include "dsr/model/photometric.h"

namespace dsr {

constexpr int kExitBadInput = 2;
constexpr int kExitFailed = 1;

// Range of a voxel spacing given by a flag (mm): beyond it, geometry (inverses, file headers
// in float32) breaks down long before the value could be meant.
constexpr double kMinFrameSpacingMm = 1e-6;
constexpr double kMaxFrameSpacingMm = 1e6;

// Largest flagfile read (a flagfile is a few lines; this refuses /dev/zero and data files).
constexpr int64_t kMaxFlagfileBytes = int64_t{1} << 20;
// Most arguments all flagfiles together may expand to (a flagfile included twice by each of
// a chain of flagfiles doubles at each link).
constexpr int kMaxExpandedArguments = 100000;

// Tool start-up, in this order:
//  1. FLAGS_logtostderr defaults to true (glog to stderr; --logtostderr=false overrides).
//  2. Expands every --flagfile=FILE (also "--flagfile FILE", and inside flagfiles) in place,
//     so that flags after it override it, as gflags does; but first refuses, with one line
//     naming the flagfile and exit kExitBadInput: a missing or unreadable file, a folder or
//     other non-regular file, one over kMaxFlagfileBytes, a flagfile that includes itself
//     (directly or through others), and any line that is not blank, a '#' comment, or
//     --flag=value (--flag / --noflag for booleans) naming a flag this tool defines.
//     (gflags itself recurses forever on cycles, ignores unknown flags in flagfiles and
//     reads a line without "--" as a program-name filter.) Relative paths, in flagfiles
//     too, are relative to the working folder.
//  3. Parses flags. gflags reports unknown flags, malformed values and failed validators
//     with its own one-line messages; this makes it exit with kExitBadInput instead of 1.
//  4. Handles --help, --helpshort (this tool's flags only), --version: print and exit 0.
//  5. Rejects positional arguments and empty `required_flags` (names without "--") with
//     one line on stderr and kExitBadInput.
//  6. Initialises glog and logs gflags::CommandlineFlagsIntoString() at --v=1.
// Note: call first in main, before any other use of flags.
void InitTool(const char* usage,
              const std::vector<std::string>& required_flags,
              int* argc,
              char*** argv);

// Runs a tool's main function `body` (which calls InitTool first) so that it never ends in
// an uncaught exception: std::bad_alloc, from any thread, ends the run with one line
// "<tool>: error: out of memory (...)" and kExitFailed; any other exception (a last resort:
// none is expected) with one line naming it and kExitFailed. Use as
//   int main(int argc, char** argv) { return dsr::RunToolMain(argc, argv, &Main); }
int RunToolMain(int argc, char** argv, int (*body)(int, char**));

// Bytes this process can still allocate, as far as it can tell up front: the physical RAM,
// and under an address-space limit (RLIMIT_AS, `ulimit -v`) what the limit leaves beyond
// what is mapped already.
double AvailableMemoryBytes();

// For clear cases, before any work: true when `bytes` (an estimate) fits in
// AvailableMemoryBytes(); otherwise `error` reads "<what_flags>: needs about X GiB for
// <what>, more than the Y GiB available (...)".
bool CheckMemoryEstimate(const std::string& what_flags,
                         double bytes,
                         const std::string& what,
                         std::string* error);

// `message` (a library's error or failure) with each option field path it names
// (util/option_fields.h) written as this tool's flag: "--" and the first of the path with
// '.' as '_' (search.rotations -> --search_rotations), its last part (solve.max_iterations
// -> --max_iterations) and its first part (loss.kind -> --loss) that is a flag of this
// tool. A path with none of them (an option no flag sets) stays as it is.
std::string FieldPathsAsFlags(const std::string& message);

// Prints "<tool>: error: <message>" as one line on stderr, with FieldPathsAsFlags, and
// returns `code`, so that main can `return Fail(...)`.
int Fail(const std::string& message, int code = kExitBadInput);

// A refused flag value, "--<flag>=<value>: <rule>": a tool prints it as its error and exits
// with kExitBadInput; a front end that lives on after a bad value (the Python module,
// after SetBadFlagsExit(false)) gets false, and SetFlagValue returns the message.
bool RefuseFlag(const char* flag, const std::string& value, const std::string& rule);
// Whether RefuseFlag exits the process (the default) or returns false.
void SetBadFlagsExit(bool exit);

// Sets flag `name` to `value` as a command line would (--name=value): false with the
// message when no flag has that name ("--name=value: unknown flag"), the text is not a
// value of the flag's type ("--name=value: not a valid int32") or its validator refuses it
// (RefuseFlag's message). Needs SetBadFlagsExit(false) for the validator's message to come
// back rather than exit. The tools check their command lines with it before gflags parses
// them, and the Python module sets its options with it, so both print the same lines.
bool SetFlagValue(const std::string& name, const std::string& value, std::string* error);

// The pipeline names frames by index: a message that starts with "frame N " also gets
// frame N's file in front ("a.nii.gz: frame 1 has ..."), so that the line names what to
// fix. Other messages are returned as they are.
std::string WithFrameFile(const std::string& message, const std::vector<std::string>& paths);

// The summary line that says where the frames' fields of view came from (dsr_register,
// the Python module's summary): `mask_rules` is ReadFrames's (empty: masks were given),
// `asked` the rule of --mask_rule. E.g. "field of view: convex hull of the non-zero voxels
// (frames 0-10)", "field of view: convex hull of the non-zero voxels (frames 0-3,5-10);
// non-zero voxels, no 3D hull (frame 4)", "field of view: the given masks".
std::string FieldOfViewSummary(const std::vector<MaskRule>& mask_rules, MaskRule asked);

// For DEFINE_validator functions: returns true when `ok`, else RefuseFlag. (A validator
// that returns false makes gflags print "failed validation of new value" without saying
// which rule failed.) gflags also runs validators on unchanged defaults, so defaults must
// pass. Example:
//   bool ValidateNumFrames(const char* flag, int32_t v) {
//     return dsr::CheckFlag(v >= 2, flag, v, "must be >= 2");
//   }
template <typename T>
bool CheckFlag(bool ok, const char* flag, const T& value, const std::string& rule) {
  if (ok) return true;
  std::ostringstream s;
  s << value;
  return RefuseFlag(flag, s.str(), rule);
}

// Validator for optional input-file flags: true for "" or a readable regular file;
// otherwise RefuseFlag (missing, a folder, unreadable).
bool CheckInputFileFlag(const char* flag, const std::string& path);

// The absolute, normalised form of a path (symlinks resolved where they exist), so that two
// spellings of one file compare equal.
std::string CanonicalPath(const std::string& path);

// Reorders `poses` (read from --<flag>=<path>, one entry per image) to the order of
// `image_paths` by the entries' "image" names: an entry names an image by its path as
// given, its file name, or its file name without the extension. A file whose names are all
// empty is kept in its order. An image that no entry names, or an entry naming two images,
// is an error naming --<flag>: a pose applied to the wrong frame gives a wrong result with
// no other sign, so any doubt is an error. Gains and offsets, when the file has them, move
// with their entries and are brought to the new frame 0's intensity scale; the covariance
// and predicted TRE are dropped (they belong to the file's gauge).
bool MatchPosesToImages(const std::string& flag,
                        const std::string& path,
                        const std::vector<std::string>& image_paths,
                        PosesFile* poses,
                        std::string* error);

// The per-frame intensity corrections of a poses file (its "gain" and "offset"; a field the
// file lacks is 1, resp. 0, on every frame), as Photometric: frame i's corrected intensity
// is gain_i I_i + offset_i. Empty when the file has neither field.
std::vector<Photometric> PhotometricFromPoses(const PosesFile& poses);

// "a,b,,c" -> {"a", "b", "c"}: items trimmed of spaces, empty items dropped.
std::vector<std::string> SplitCommaList(const std::string& text);

// The files of a list-valued input flag (--images, --masks): "a,b,c" as SplitCommaList, or
// "@LIST": the lines of the file LIST (at most kMaxFlagfileBytes), one path per line as
// written (a name may contain commas), blank lines and lines starting with '#' skipped.
// Then every file must exist. False with `error` naming --<flag> (and LIST), e.g. for a
// missing item that names are split at commas and that @LIST takes any name.
bool ParseInputList(const std::string& flag,
                    const std::string& text,
                    std::vector<std::string>* paths,
                    std::string* error);

// "96,96,80" -> (96, 96, 80). False unless exactly three integers (no trailing junk) in
// [min_value, max_value].
bool ParseSize3(const std::string& text,
                Eigen::Vector3i* size,
                int min_value = 1,
                int max_value = 1 << 20);

}  // namespace dsr

#endif  // DSR_TOOLS_TOOL_UTIL_H_
