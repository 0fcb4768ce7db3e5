// --mode and the options of one registration run (tools/flags/flags.h): dsr_register's and
// the Python module's (dsr_compare runs several modes, from --methods).
#include "dsr/tools/flags/flags.h"
#include "dsr/tools/tool_util.h"

DEFINE_string(mode, "dsr", "Solver: dsr (reduced problem, intensities eliminated), dba "
              "(full direct bundle adjustment in Ceres; small problems only), or one of the "
              "paper's baselines: pairwise, lie_normalization, sequential, ape.");

namespace dsr {

bool RunOptionsFromFlags(RegistrationOptions* options, std::string* init_file,
                         std::string* error) {
  if (!StringToMode(FLAGS_mode, &options->mode)) {
    std::string names;
    for (const std::string& name : ModeNames()) names += (names.empty() ? "" : "|") + name;
    *error = "--mode=" + FLAGS_mode + ": unknown mode (one of " + names + ")";
    return false;
  }
  if (!RegistrationOptionsFromFlags(options, init_file, error)) return false;
  options->photometric = PhotometricFromFlags(options->mode);
  if (!FlagIsDefault("gauge") && options->gauge != Gauge::kFrame0 &&
      !ModeTakesGauge(options->mode)) {
    *error = "--gauge=" + FLAGS_gauge + ": needs --mode=dsr or dba (--mode=" + FLAGS_mode +
             " holds frame 0 constant)";
    return false;
  }
  if (FLAGS_uncertainty && !ModeEstimatesPhotometric(options->mode)) {
    *error = "--uncertainty: needs --mode=dsr or dba (got --mode=" + FLAGS_mode + ")";
    return false;
  }
  return options->Validate(error);
}

}  // namespace dsr
