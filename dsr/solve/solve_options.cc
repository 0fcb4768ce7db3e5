#include "dsr/solve/solve_options.h"

#include <cmath>
#include <cstdio>
#include <fstream>
#include <sstream>
#include <unistd.h>

#include <ceres/types.h>

#include "dsr/util/option_fields.h"

namespace dsr {

bool SolveOptions::Validate(std::string* error) const {
  if (trust_region != ceres::LEVENBERG_MARQUARDT && trust_region != ceres::DOGLEG) {
    return RefuseField(error, "trust_region", static_cast<int>(trust_region),
                       "must be LEVENBERG_MARQUARDT or DOGLEG");
  }
  if (max_iterations < 1) {
    return RefuseField(error, "max_iterations", max_iterations, "must be >= 1");
  }
  const std::pair<const char*, double> tolerances[] = {
      {"function_tolerance", function_tolerance},
      {"gradient_tolerance", gradient_tolerance},
      {"parameter_tolerance", parameter_tolerance}};
  for (const auto& [name, value] : tolerances) {
    if (!std::isfinite(value) || value < 0.0) {
      return RefuseField(error, name, value, "must be finite and >= 0");
    }
  }
  if (!std::isfinite(step_tolerance) || step_tolerance < 0.0) {
    return RefuseField(error, "step_tolerance", step_tolerance, "must be finite and >= 0");
  }
  if (max_rejected_steps < 0) {
    return RefuseField(error, "max_rejected_steps", max_rejected_steps, "must be >= 0");
  }
  if (!KernelPathAvailable(kernels)) {
    return RefuseField(error, "kernels", KernelPathToString(kernels),
                       "this CPU does not run them");
  }
  return true;
}

bool ValidatePoseOnlyLinearSolver(const SolveOptions& solve, const std::string& who,
                                  std::string* error) {
  if (!solve.linear_solver || *solve.linear_solver == ceres::DENSE_QR ||
      *solve.linear_solver == ceres::DENSE_NORMAL_CHOLESKY ||
      *solve.linear_solver == ceres::SPARSE_NORMAL_CHOLESKY) {
    return true;
  }
  return RefuseField(error, "solve.linear_solver",
                     ceres::LinearSolverTypeToString(*solve.linear_solver),
                     who + " only the poses; use DENSE_QR, DENSE_NORMAL_CHOLESKY or "
                           "SPARSE_NORMAL_CHOLESKY");
}

void SolveOptions::ToCeres(ceres::LinearSolverType mode_default,
                           ceres::Solver::Options* out) const {
  out->trust_region_strategy_type = trust_region;
  out->linear_solver_type = LinearSolverOr(mode_default);
  out->max_num_iterations = max_iterations;
  out->function_tolerance = function_tolerance;
  out->gradient_tolerance = gradient_tolerance;
  out->parameter_tolerance = parameter_tolerance;
  out->num_threads =
      num_threads > 0 ? num_threads : static_cast<int>(std::max(1L, sysconf(_SC_NPROCESSORS_ONLN)));
  out->min_relative_decrease = min_relative_decrease;
  out->minimizer_progress_to_stdout = false;
  out->logging_type = ceres::SILENT;
  out->update_state_every_iteration = false;
}

ceres::CallbackReturnType ProgressCallback::operator()(const ceres::IterationSummary& s) {
  IterationRecord r;
  r.iteration = s.iteration;
  r.cost = s.cost;
  r.step_norm = s.step_norm;
  r.seconds = s.cumulative_time_in_seconds;
  r.step_accepted = s.step_is_successful;
  records_.push_back(r);
  if (log_) {
    std::fprintf(stderr, "%s iter %3d  cost % .9e  step %.3e  radius %.1e  %s  %.3f s\n",
                 label_.c_str(), s.iteration, s.cost, s.step_norm, s.trust_region_radius,
                 s.step_is_successful ? "accepted" : "rejected", s.cumulative_time_in_seconds);
  }
  if (observer_ && !observer_(label_, r)) return ceres::SOLVER_ABORT;
  return ceres::SOLVER_CONTINUE;
}

void FillReport(const ceres::Solver::Summary& summary,
                const ProgressCallback& progress,
                SolveReport* report) {
  report->iterations = progress.records();
  report->termination = summary.message;
  report->usable = summary.IsSolutionUsable() && std::isfinite(summary.final_cost);
  report->initial_cost = summary.initial_cost;
  report->final_cost = summary.final_cost;
  report->num_iterations = static_cast<int>(summary.iterations.size()) - 1;
  report->seconds = summary.total_time_in_seconds;
  report->seconds_per_iteration =
      summary.minimizer_time_in_seconds / std::max(1, report->num_iterations);
}

namespace {

// A "Vm...:  N kB" line of /proc/self/status in bytes, 0 when absent.
int64_t StatusBytes(const std::string& key) {
  std::ifstream status("/proc/self/status");
  std::string line;
  while (std::getline(status, line)) {
    if (line.rfind(key, 0) == 0) {
      std::istringstream s(line.substr(key.size()));
      int64_t kb = 0;
      s >> kb;
      return kb * 1024;
    }
  }
  return 0;
}

}  // namespace

int64_t PeakResidentBytes() { return StatusBytes("VmHWM:"); }

int64_t CurrentResidentBytes() { return StatusBytes("VmRSS:"); }

int64_t PhysicalMemoryBytes() {
  const long pages = sysconf(_SC_PHYS_PAGES), page_size = sysconf(_SC_PAGE_SIZE);
  return pages > 0 && page_size > 0 ? int64_t{pages} * page_size : 0;
}

}  // namespace dsr
