// dsr_register: registers several 3D images simultaneously (pipeline/registration.h) and
// writes the poses (docs/design.md section 1), optionally the panorama, and, with
// --gt_poses, prints per-frame errors against ground truth (eval/eval.h).
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <string>

#include "dsr/app/registration_run.h"
#include "dsr/tools/flags.h"
#include "dsr/tools/tool_util.h"
#include "dsr/util/clock.h"

namespace {

using dsr::Fail;

int Main(int argc, char** argv) {
  dsr::InitTool(
      "registers several 3D images simultaneously (DSR: direct simultaneous registration).\n"
      "  dsr_register --images=a.nii.gz,b.nii.gz,... --out_poses=poses.json [--masks=...]\n"
      "      [--mode=dsr|dba|pairwise|lie_normalization|sequential|ape]\n"
      "      [--init=auto|identity|pairwise|global|FILE] [--panorama_spacing=1] [--gt_poses=FILE]\n"
      "Exit status: 0 ok, 2 bad input, 1 the solve failed (no pose file written). "
      "--helpshort lists this tool's flags only.",
      dsr::kDsrRegister, {"images", "out_poses"}, &argc, &argv);
  const auto start = std::chrono::steady_clock::now();
  std::string error;
  // Options and files first, so that their errors come before any file is read.
  dsr::RegistrationRun run(dsr::kDsrRegister);
  const dsr::RegistrationOutputs outputs = dsr::RegistrationOutputsFrom(dsr::ToolSettings());
  if (!run.PlanFiles(dsr::ToolSettings(), outputs, &error) || !run.ReadFiles(&error)) {
    return Fail(error);
  }
  const double load_seconds = dsr::SecondsSince(start);
  if (!run.Check(&error) || !run.Run(&error)) return Fail(error);
  for (const std::string& line : run.RecoveryLines()) {
    std::printf("dsr_register: %s\n", line.c_str());
  }
  if (!run.result().usable) return Fail(run.result().failure, dsr::kExitFailed);
  if (!run.Write(&error)) return Fail(error, dsr::kExitFailed);
  for (const std::string& line : run.SummaryLines(dsr::SecondsSince(start), load_seconds)) {
    std::printf("dsr_register: %s\n", line.c_str());
  }
  if (!outputs.gt_poses.empty()) {
    std::printf("errors against %s (frame-0-relative):\n%s", outputs.gt_poses.c_str(),
                run.gt_errors().Table().c_str());
  }
  if (!run.report_index().empty()) {
    std::printf("dsr_register: report in %s\n", run.report_index().c_str());
  }
  return EXIT_SUCCESS;
}

}  // namespace

int main(int argc, char** argv) { return dsr::RunToolMain(argc, argv, &Main); }
