// The registration functions: register (images in memory or files), register_files
// (dsr_register as a function), the checks dsr.cohort makes before a run (check_register_files,
// check_register_options) and init_is_file; the run's preparation (PrepareRun) and its solve
// without the GIL (SolveRun).
#include "module_internal.h"

#include <chrono>
#include <exception>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Geometry>

#include "dsr/app/options.h"
#include "dsr/app/output_plan.h"
#include "dsr/app/registration_run.h"
#include "dsr/app/run_options.h"
#include "dsr/pipeline/registration.h"
#include "dsr/pipeline/report.h"
#include "dsr/util/clock.h"

namespace dsr {
namespace python_internal {
namespace {

// The run dsr_register makes of `images` (file paths, read as dsr_register reads them,
// masks too; or (array, geometry) pairs) and `masks` (the same kind, or empty for each
// image's field of view by --mask_rule eroded by --mask_erosion), named `names` in the
// poses file. The start: `initial` (4x4 arrays, one per image, with recovery as a poses
// file has) when given, else --init's (a poses file is matched to the images by name as
// dsr_register matches it: to the paths, or to `names`).
void PrepareRun(const py::list& images,
                const py::list& masks,
                const std::vector<std::string>& names,
                Settings settings,
                const std::optional<std::vector<py::array_t<double>>>& initial,
                RegistrationRun* run) {
  std::string error;
  const int m = static_cast<int>(images.size());
  if (static_cast<int>(names.size()) != m) BadInput("names: need one name per image");
  std::vector<Eigen::Isometry3d> start;
  if (initial.has_value()) {
    if (static_cast<int>(initial->size()) != m) {
      BadInput("initial_poses: " + std::to_string(initial->size()) + " poses for " +
               std::to_string(m) + " images");
    }
    for (int i = 0; i < m; ++i) {
      start.push_back(ToPose((*initial)[i], "initial_poses: pose " + std::to_string(i) + ": "));
    }
    if (!settings.Set("init", "auto", &error)) BadInput(error);
  }
  if (m > 0 && py::isinstance<py::str>(images[0])) {
    if (!settings.Set("images", JoinPaths(images), &error) ||
        !settings.Set("masks", JoinPaths(masks), &error) ||
        !run->PlanFiles(settings, RegistrationOutputs(), &error) || !run->ReadFiles(&error)) {
      BadInput(error);
    }
    run->RememberInputs(&ReadInputs());
    run->set_names(names);
    if (!start.empty()) run->set_start(std::move(start));
    return;
  }
  std::vector<Image> frames;
  std::vector<Mask> frame_masks;
  std::vector<MaskRule> mask_rules;
  std::vector<std::vector<Image>> later_phases;
  ReadArrays(2, images, masks, ConfigFrom(settings).field_of_view, &frames, &frame_masks,
             &mask_rules, &later_phases);
  if (!run->SetFrames(settings, std::move(frames), std::move(frame_masks), std::move(mask_rules),
                      names, std::move(start), &error, std::move(later_phases))) {
    BadInput(error);
  }
}

// Checks `run` as dsr_register checks it and solves it without the GIL. After every
// iteration Python's signal handlers run (Ctrl-C raises KeyboardInterrupt between
// iterations, not when the solve ends), then `on_iteration` when given; their exception stops
// the solve and is raised once it returns. ValueError for bad input, RegistrationError (its
// message through `as_options`) for a registration without a result.
void SolveRun(RegistrationRun* run,
              const IterationObserver& on_iteration,
              std::string (*as_options)(const std::string&)) {
  std::exception_ptr callback_error;
  run->options().solve.on_iteration = [&](const std::string& label, const IterationRecord& r) {
    if (callback_error) return false;
    py::gil_scoped_acquire gil;
    try {
      if (PyErr_CheckSignals() != 0) throw py::error_already_set();
      return on_iteration ? on_iteration(label, r) : true;
    } catch (...) {
      callback_error = std::current_exception();
      return false;
    }
  };
  std::string error;
  if (!run->Check(&error)) BadInput(error);
  bool ok = false;
  {
    py::gil_scoped_release release;
    ok = run->Run(&error);
  }
  if (callback_error) std::rethrow_exception(callback_error);
  if (!ok) BadInput(error);
  if (!run->result().usable) {
    PyErr_SetString(registration_error, as_options(run->result().failure).c_str());
    throw py::error_already_set();
  }
}

}  // namespace

py::dict RegisterImages(const py::list& images,
                        const py::list& masks,
                        const std::vector<std::string>& names,
                        const Options& options_in,
                        const std::optional<std::vector<py::array_t<double>>>& initial_poses,
                        const IterationObserver& on_iteration) {
  RegistrationRun run(kPyRegister);
  PrepareRun(images, masks, names, RegisterSettings(options_in, kPyRegister), initial_poses, &run);
  RegistrationOptions& options = run.options();
  options.solve.progress = false;  // Python has on_iteration and progress_bar instead
  SolveRun(&run, on_iteration, [](const std::string& m) { return AsOptions(m); });
  const RegistrationResult& result = run.result();
  py::dict out;
  out["poses"] = PosesToDict(ResultPoses(result, run.names()));
  out["summary"] = Summary(options, result, run.FieldOfViewLine(), run.preset_summary());
  return out;
}

py::dict RegisterFiles(const Options& options_in) {
  Settings settings = RegisterSettings(options_in, kDsrRegister);
  const auto start = std::chrono::steady_clock::now();
  const RegistrationOutputs outputs = RegistrationOutputsFrom(settings);
  std::string error;
  if (settings.String("images").empty() || outputs.poses.empty()) {
    BadInput("--images and --out_poses are required");
  }
  RegistrationRun run(kDsrRegister);
  if (!run.PlanFiles(settings, outputs, &error) || !run.ReadFiles(&error)) BadInput(error);
  run.RememberInputs(&ReadInputs());
  const double load_seconds = SecondsSince(start);
  SolveRun(&run, nullptr,
           [](const std::string& m) { return FieldPathsAsOptions(m, kDsrRegister); });
  const RegistrationResult& result = run.result();
  if (!run.Write(&error)) WriteFailed(error);
  py::dict out;
  out["lines"] = run.SummaryLines(SecondsSince(start), load_seconds);
  out["iterations"] = result.total_iterations;
  out["recoveries"] = result.recoveries.size();
  out["seconds"] = SecondsSince(start);
  out["report_index"] = run.report_index();
  if (!outputs.gt_poses.empty()) {
    const PoseErrorSummary& e = run.gt_errors();
    out["tre_mean_mm"] = e.tre_mean_mm;
    out["tre_max_mm"] = e.tre_max_mm;
    out["mae_rotation_rad"] = e.mae_rotation_rad;
    out["mae_translation_mm"] = e.mae_translation_mm;
  }
  if (!result.uncertainty.predicted_tre_mm.empty()) {
    out["predicted_tre_mm"] = result.uncertainty.predicted_tre_mm;
  }
  return out;
}

void CheckRegisterFiles(const Options& options_in) {
  const Settings settings = RegisterSettings(options_in, kDsrRegister);
  RegistrationRun run(kDsrRegister);
  std::string error;
  if (!run.PlanFiles(settings, RegistrationOutputsFrom(settings), &error)) BadInput(error);
}

void CheckRegisterOptions(const Options& options_in) { RegisterSettings(options_in, kDsrRegister); }

bool InitIsFile(const std::string& text) {
  RegistrationOptions options;
  return !SetInitialisation(text, 0, &options);
}

}  // namespace python_internal
}  // namespace dsr
