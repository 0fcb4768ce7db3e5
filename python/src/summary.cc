// The summary dict of a registration's result (register's "summary"): its mode, solves,
// costs, timings, recoveries and the checks' findings.
#include "module_internal.h"

#include <string>

#include "dsr/model/intensity_transform.h"
#include "dsr/pipeline/modes.h"
#include "dsr/pipeline/registration_options.h"
#include "dsr/pipeline/registration_result.h"
#include "dsr/pipeline/structure_check.h"
#include "dsr/pipeline/uncertainty.h"

namespace dsr {
namespace python_internal {

py::dict Summary(const RegistrationOptions& options,
                 const RegistrationResult& result,
                 const std::string& field_of_view,
                 const std::string& preset) {
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
    s["uncertainty"] = AsOptions(UncertaintySummary(result.uncertainty, result.uncertainty_note));
  }
  return s;
}

}  // namespace python_internal
}  // namespace dsr
