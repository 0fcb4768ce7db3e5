// dsr_compare: the paper's comparison (Fig. 1). Runs registration methods on sequences with
// ground truth (folders written by dsr_simulate, or sequences simulated here from the
// built-in phantom or --source) and writes OUT_DIR/results.csv (one line per method and sequence),
// OUT_DIR/results.md (medians per method) and OUT_DIR/poses/<sequence>_<method>.json.
// scripts/plot_compare.py turns the CSV into the paper's box plots.
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "dsr/app/comparison.h"
#include "dsr/app/output_plan.h"
#include "dsr/pipeline/experiment.h"
#include "dsr/tools/flags.h"
#include "dsr/tools/tool_util.h"

namespace {

using dsr::Fail;

// One line per run on stderr, and why a run failed.
void PrintRow(const dsr::ComparisonRow& row) {
  std::fprintf(stderr,
               "dsr_compare: %-28s %-10s %s MAE %.4f voxels, %.3g rad, %d iterations, %.2f s\n",
               row.method.c_str(), row.sequence.c_str(), row.ok ? "ok    " : "FAILED",
               row.mae_translation_voxels, row.mae_rotation_rad, row.iterations, row.seconds);
  if (!row.ok) std::fprintf(stderr, "dsr_compare:   %s\n", row.failure.c_str());
}

int Main(int argc, char** argv) {
  // Every method's poses are measured, diverged or not, from the paper's start: the
  // options table's defaults for dsr_compare (FrontEndDefaults).
  dsr::InitTool(
      "compares registration methods on sequences with ground truth (the paper's Fig. 1).\n"
      "  dsr_compare --out_dir=DIR [--methods=dsr,ape,...] [--sequences=DIR1,DIR2 | "
      "--num_sequences=5 ...]\n"
      "  dsr_compare --flagfile=configs/paper_simulated.flags\n"
      "Exit status: 0 ok (a method that fails on a sequence is a row, not an error), 2 bad "
      "input.",
      dsr::kDsrCompare, {"out_dir"}, &argc, &argv);
  std::string error;
  dsr::Comparison comparison;
  if (!dsr::ComparisonFrom(dsr::ToolSettings(), &comparison, &error)) return Fail(error);
  // Every file this run reads and writes, then the voxels (every frame and mask is read
  // once here and again for its run, so that only one sequence is held in memory).
  dsr::OutputPlan plan;
  dsr::PlanComparisonFiles(comparison, &plan);
  if (!plan.Check(&error) || !dsr::ReadEverySequence(comparison, &error)) return Fail(error);
  if (!plan.CreateFolders(&error)) return Fail(error);
  std::vector<dsr::ComparisonRow> rows;
  bool bad_input = false;
  if (!dsr::RunComparison(
          comparison, &PrintRow,
          [](const std::string& note) { std::fprintf(stderr, "dsr_compare: %s\n", note.c_str()); },
          &rows, &bad_input, &error)) {
    return Fail(error, bad_input ? dsr::kExitBadInput : dsr::kExitFailed);
  }
  std::printf("%s", dsr::ComparisonMarkdown(rows).c_str());
  std::printf("dsr_compare: wrote %s/results.csv and results.md\n", comparison.out_dir.c_str());
  return EXIT_SUCCESS;
}

}  // namespace

int main(int argc, char** argv) { return dsr::RunToolMain(argc, argv, &Main); }
