// Method comparisons (the paper's Fig. 1): run registration methods on sequences
// with ground truth and tabulate accuracy and cost. Each run happens in a child process
// (fork), so that its peak memory is its own (wait4's ru_maxrss) and a crash in one run
// cannot take the others down.
#ifndef DSR_PIPELINE_EXPERIMENT_H_
#define DSR_PIPELINE_EXPERIMENT_H_

#include <limits>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "dsr/geometry/volume.h"
#include "dsr/model/photometric.h"
#include "dsr/pipeline/registration_options.h"

namespace dsr {

struct ExperimentSequence {
  std::string name;
  std::vector<Image> frames;
  std::vector<Mask> masks;
  std::vector<Eigen::Isometry3d> ground_truth;  // frame_from_world (any world)
  // The frames' true intensity corrections on frame 0's scale (io/io_poses.h, "gain" and
  // "offset"), one per frame; empty when unknown.
  std::vector<Photometric> ground_truth_photometric;
};

// One row of the comparison.
struct ComparisonRow {
  std::string method, sequence;
  bool ok = false;
  std::string failure;          // why not ok
  double mae_translation_voxels = 0.0, mae_translation_mm = 0.0, mae_rotation_rad = 0.0;
  double tre_mean_mm = 0.0, tre_max_mm = 0.0;
  // The frames' centre errors split into what they share (frame 0 off against the rest; its
  // length and components in frame 0's axes) and their spread about it (eval/eval.h).
  Eigen::Vector3d shared_offset_mm = Eigen::Vector3d::Zero();
  double frame_spread_mm = 0.0;
  int iterations = 0;               // every solve of every level (initialiser excluded)
  int recoveries = 0;               // recovery rounds (RegistrationResult::recoveries)
  double seconds_per_iteration = 0.0;   // finest level: solve time / iterations
  double differences_per_iteration = 0.0;  // finest level: intensity differences per evaluation
  double seconds = 0.0;             // the whole run (pyramid, initialiser, solves)
  double peak_memory_mb = 0.0;      // the run's process
  // What the run added to the memory its process started with (the inputs, the libraries
  // and whatever the comparison itself holds, e.g. the phantom): peak minus resident at
  // the start of the run. The method's own memory.
  double added_memory_mb = 0.0;
  // With RegistrationOptions::uncertainty (modes dsr and dba; NaN otherwise), over
  // frames 1..m-1: the mean predicted TRE and the mean normalised squared pose error
  // e^T C^-1 e against the ground truth (pipeline/uncertainty.h; 6 when calibrated).
  double predicted_tre_mm = std::numeric_limits<double>::quiet_NaN();
  double nees = std::numeric_limits<double>::quiet_NaN();
  // With RegistrationOptions::photometric kAffine (NaN otherwise, or without a known truth),
  // over frames 1..m-1: the mean absolute error of the estimated gains and offsets against
  // ExperimentSequence::ground_truth_photometric (offsets in intensity units).
  double mae_gain = std::numeric_limits<double>::quiet_NaN();
  double mae_offset = std::numeric_limits<double>::quiet_NaN();
  // The structure check's figures at the final poses (pipeline/structure_check.h): the
  // largest structure fraction over the judged frames, and that frame's significance (in
  // standard errors of noise alone); NaN when no frame was judged.
  double structure_fraction = std::numeric_limits<double>::quiet_NaN();
  double structure_significance = std::numeric_limits<double>::quiet_NaN();
  // The determination check's largest predicted error over the frames (voxels; NaN when it
  // did not run).
  double pose_error_voxels = std::numeric_limits<double>::quiet_NaN();
  std::vector<Eigen::Isometry3d> frame_from_world;
  std::vector<Photometric> photometric;  // the estimate (RegistrationResult::photometric)
};

// The method's name in a comparison's rows and poses files: the mode, then "+pairwise_init",
// "+global_init" or "+auto" for the initialisation, then "+affine" with photometric
// parameters.
std::string MethodLabel(const RegistrationOptions& options);

// Runs `options` (its mode is the method) on the sequence from identity initial poses in
// a child process and fills a row.
ComparisonRow RunMethod(const ExperimentSequence& sequence, const RegistrationOptions& options);

// CSV with a header line; one line per row.
std::string ComparisonCsv(const std::vector<ComparisonRow>& rows);
// Markdown table of medians per method over the sequences (failed runs counted apart),
// methods in the order first seen.
std::string ComparisonMarkdown(const std::vector<ComparisonRow>& rows);

}  // namespace dsr

#endif  // DSR_PIPELINE_EXPERIMENT_H_
