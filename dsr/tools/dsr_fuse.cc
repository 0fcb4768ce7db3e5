// dsr_fuse: the panorama of registered frames (paper eq. 10, or a feathered blend) on the
// shared panorama grid, and the field-of-view enlargement ratio the paper reports.
#include <cstdio>
#include <cstdlib>
#include <string>

#include "dsr/app/fusion_run.h"
#include "dsr/tools/flags.h"
#include "dsr/tools/tool_util.h"

namespace {

int Main(int argc, char** argv) {
  dsr::InitTool(
      "fuses registered frames into one panorama and prints the field-of-view enlargement.\n"
      "  dsr_fuse --images=a.nii.gz,b.nii.gz,... --poses=poses.json --out=panorama.nii.gz\n"
      "      [--masks=...] [--blend=mean|feather] [--panorama_spacing=1]\n"
      "Exit status: 0 ok, 2 bad input, 1 a write failed.",
      dsr::kDsrFuse, {"images", "poses", "out"}, &argc, &argv);
  using dsr::Fail;
  std::string error;
  const dsr::Settings& settings = dsr::ToolSettings();
  dsr::FusionRun run(settings);
  // Every file this run reads and writes, before anything is read.
  if (!run.PlanFiles(settings, settings.String("poses"), settings.String("out"),
                     settings.String("out_count"), &error) ||
      !run.ReadFiles(&error) || !run.Prepare(&error)) {
    return Fail(error);
  }
  run.Fuse();
  if (!run.Write(&error)) return Fail(error, dsr::kExitFailed);
  for (const std::string& line : run.SummaryLines()) std::printf("dsr_fuse: %s\n", line.c_str());
  return EXIT_SUCCESS;
}

}  // namespace

int main(int argc, char** argv) { return dsr::RunToolMain(argc, argv, &Main); }
