// The inputs of a run, as every front end reads them (the command-line tools, the Python
// package): lists of frame files, poses files matched to images by name, canonical paths,
// memory estimates checked against what the process can allocate, and the messages that
// name a frame's file.
#ifndef DSR_APP_INPUTS_H_
#define DSR_APP_INPUTS_H_

#include <string>
#include <vector>

#include <Eigen/Core>

#include "dsr/geometry/field_of_view.h"
#include "dsr/geometry/volume.h"
#include "dsr/io/io_poses.h"
#include "dsr/model/photometric.h"

namespace dsr {

// Range of a voxel spacing given by a flag (mm): beyond it, geometry (inverses, file headers
// in float32) breaks down long before the value could be meant.
constexpr double kMinFrameSpacingMm = 1e-6;
constexpr double kMaxFrameSpacingMm = 1e6;

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

// What the field-of-view line adds about dropouts (RegistrationResult::dropout_fraction):
// "; dropouts (beams without signal) left out: frame 3 19.3%, frame 7 21.7%", or "" when
// no view had one.
std::string DropoutSummary(const std::vector<double>& dropout_fraction);

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

// --phases (RunConfig::phases; empty: all): each view's phases `selected`, in that order, the
// first as its phase 0 (views of images[i] and later_phases[i], io/io_frames.h). False
// naming the view (`names`) that lacks one of them.
bool SelectPhases(const std::vector<int>& selected,
                  const std::vector<std::string>& names,
                  std::vector<Image>* images,
                  std::vector<std::vector<Image>>* later_phases,
                  std::string* error);

// Before any voxel is read: every view of `views` (files, io/io_phases.h ViewFiles) has
// each phase of --phases' selection `selected` (empty: all), by its header
// (NumPhasesInView); false with SelectPhases' error naming the view, or the header's error.
bool CheckSelectedPhases(const std::vector<int>& selected,
                         const std::vector<std::string>& views,
                         std::string* error);

// The views of `image_paths` with their masks as a run reads them (io/io_frames.h
// ReadFrames): --phases' selection `selected` checked first (CheckSelectedPhases), then only
// those phases of each view read, in that order (the others never held in memory), and
// the same phases in every view (CheckSamePhases).
bool ReadViewPhases(const std::vector<int>& selected,
                    const std::vector<std::string>& image_paths,
                    const std::vector<std::string>& mask_paths,
                    const FieldOfViewOptions& field_of_view,
                    int num_threads,
                    std::vector<Image>* images,
                    std::vector<Mask>* masks,
                    std::vector<MaskRule>* mask_rules,
                    std::vector<std::vector<Image>>* later_phases,
                    std::string* error);

// The views' phases in memory as a run takes them: `later_phases` sized to the views when
// empty (views given without), --phases' selection (SelectPhases) and the same phases in
// every view (CheckSamePhases).
bool UseViewPhases(const std::vector<int>& selected,
                   const std::vector<std::string>& names,
                   std::vector<Image>* images,
                   std::vector<std::vector<Image>>* later_phases,
                   std::string* error);

// After reading (and SelectPhases): every view with as many phases as the first, else false
// naming both files (`names`, one per view); 3D views (one phase each) keep no later phases.
bool CheckSamePhases(const std::vector<std::string>& names,
                     std::vector<std::vector<Image>>* later_phases,
                     std::string* error);

// "96,96,80" -> (96, 96, 80). False unless exactly three integers (no trailing junk) in
// [min_value, max_value].
bool ParseSize3(const std::string& text,
                Eigen::Vector3i* size,
                int min_value = 1,
                int max_value = 1 << 20);

// "" when `path` is "" or a readable regular file, else the rule it breaks ("no such file",
// "not a regular file", "cannot open for reading").
std::string InputFileRule(const std::string& path);

// The address-space limit (RLIMIT_AS) in bytes, 0 when unlimited; "1.5 GiB".
double AddressSpaceLimitBytes();
std::string GiB(double bytes);

}  // namespace dsr

#endif  // DSR_APP_INPUTS_H_
