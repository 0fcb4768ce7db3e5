// A comparison of registration methods on sequences with ground truth (the paper's Fig. 1):
// what dsr_compare runs, the files it reads and writes, and the runs themselves. The policy
// of each method's options lives here (ComparisonFrom), so that another front end (a cohort
// runner) compares methods the same way.
#ifndef DSR_APP_COMPARISON_H_
#define DSR_APP_COMPARISON_H_

#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "dsr/app/options.h"
#include "dsr/app/output_plan.h"
#include "dsr/app/run_options.h"
#include "dsr/io/io_poses.h"
#include "dsr/pipeline/experiment.h"

namespace dsr {

// The files of one --sequences folder (written by dsr_simulate).
struct SequenceFiles {
  std::string folder;
  std::string name;  // the folder's name: names its rows and poses files
  std::vector<std::string> frames, masks;  // sorted; masks empty with --sequence_masks=false
  std::string gt_poses;
  PosesFile ground_truth;
};

struct Comparison {
  std::vector<std::string> methods;                 // --methods
  std::vector<RegistrationOptions> method_options;  // one per method
  // --sequences, listed and checked but for the voxels; empty: simulated sequences.
  std::vector<SequenceFiles> sequences;
  bool sequence_masks = true;
  FieldOfViewOptions field_of_view;  // of frames without masks (--sequence_masks=false)
  // Simulated sequences (no --sequences): num_sequences of them, sequence s with seed
  // simulation.seed + s, from the built-in phantom or source_path.
  int num_sequences = 0;
  SimulationOptions simulation;
  PhantomOptions phantom;
  std::string source_path;
  std::string out_dir;
  uint32_t front_end = kDsrCompare;  // whose option names the rows' failures use
};

// The comparison `settings` ask for: the methods (known, none twice), each method's options
// (the registration options, the method's mode; the pairwise baseline started from the
// pairwise baseline is the baseline itself; photometric parameters and a robust loss only
// for the modes that have them; with recovery (--init=auto or global), dsr_register's checks
// unless one of them is set), and the sequences (each --sequences folder listed and checked
// before any run). False with a one-line `error` naming the option.
bool ComparisonFrom(const Settings& settings, Comparison* comparison, std::string* error);

// Every file the comparison reads (the sequences' files, --source) and writes (results.csv,
// results.md and poses/<sequence>_<method>.json in --out_dir).
void PlanComparisonFiles(const Comparison& comparison, OutputPlan* plan);

// The frames and masks of a listed sequence, read (without masks, each frame's field of view
// by the comparison's rule; `mask_rules` then says which rule built each).
bool LoadSequence(const Comparison& comparison, const SequenceFiles& files,
                  ExperimentSequence* out, std::vector<MaskRule>* mask_rules, std::string* error);

// Reads every listed sequence's frames and masks once (then drops them), so that a bad
// voxel file is found before any run. False with `error` naming the file.
bool ReadEverySequence(const Comparison& comparison, std::string* error);

// Runs every method on every sequence, one sequence in memory at a time, each run in its own
// process (RunMethod), calling `on_row` after each with the row (its failure naming the
// front end's options) and `on_note` with where a sequence's masks came from when they were
// made from the frames; a usable run's poses are written
// to poses/, and results.csv and results.md after every run, so that an interrupted
// comparison keeps what it measured. False with `error` when a sequence cannot be read or
// simulated or an output cannot be written; *bad_input tells which (a simulation refused).
bool RunComparison(const Comparison& comparison,
                   const std::function<void(const ComparisonRow&)>& on_row,
                   const std::function<void(const std::string&)>& on_note,
                   std::vector<ComparisonRow>* rows, bool* bad_input, std::string* error);

}  // namespace dsr

#endif  // DSR_APP_COMPARISON_H_
