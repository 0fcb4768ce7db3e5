// Options and reports shared by every solver mode, mapped onto ceres::Solver::Options.
// Libraries take these structs; only tools/ parse flags into them.
#ifndef DSR_SOLVE_SOLVE_OPTIONS_H_
#define DSR_SOLVE_SOLVE_OPTIONS_H_

#include <functional>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Geometry>
#include <ceres/iteration_callback.h>
#include <ceres/solver.h>

#include "dsr/model/photometric.h"
#include "dsr/util/cpu.h"

namespace dsr {

struct IterationRecord;

// Told of every iteration of every solve, with the solve's progress label (e.g. "level 0
// dsr"); returning false stops that solve (Ceres's SOLVER_ABORT: the solve is then not
// usable). Called on the thread that runs the solve.
using IterationObserver = std::function<bool(const std::string& label, const IterationRecord&)>;

struct SolveOptions {
  ceres::TrustRegionStrategyType trust_region = ceres::LEVENBERG_MARQUARDT;
  // Empty: the mode's default.
  std::optional<ceres::LinearSolverType> linear_solver;
  int max_iterations = 100;
  double function_tolerance = 1e-8;
  double gradient_tolerance = 1e-12;
  double parameter_tolerance = 1e-10;
  int num_threads = 0;  // <= 0: all hardware threads
  // The SIMD kernels of the streamed costs (util/cpu.h); Validate checks the CPU runs them.
  KernelPath kernels = KernelPath::kAuto;
  bool progress = true;  // one line per iteration on stderr
  // Prepended to the mode's name on progress lines (e.g. "level 2 " -> "level 2 dsr iter").
  std::string progress_prefix;
  // Optional: called after every iteration (the Python module's progress callback).
  IterationObserver on_iteration;
  // Ceres accepts a step only when the cost drops by at least this fraction of the model's
  // prediction. Tests that study Gauss-Newton fixed points lower it (see
  // docs/design.md section 4.4); users keep Ceres's default.
  double min_relative_decrease = 1e-3;
  // The pose stopping rule of solve/convergence.h: stop when the distance still to go,
  // estimated from the last accepted steps, moves no field of view by more than this many
  // voxels (0 = off), or after this many rejected steps in a row (0 = off). Tests that
  // converge to 1e-8 turn both off.
  double step_tolerance = 5e-3;
  int max_rejected_steps = 5;
  // Streamed costs (DSR, APE, pair registrations): compute Jacobians along with a trial
  // point's cost and skip the Jacobians of the point that ends the solve
  // (stream/streamed_cost.h). Same poses and costs either way; fewer passes over the voxels.
  bool reuse_evaluations = true;

  // Checks names and ranges; `error` names the field (util/option_fields.h).
  bool Validate(std::string* error) const;
  // The linear solver: linear_solver, or `mode_default` when it is empty.
  ceres::LinearSolverType LinearSolverOr(ceres::LinearSolverType mode_default) const {
    return linear_solver.value_or(mode_default);
  }
  // Fills a ceres::Solver::Options (linear solver: LinearSolverOr(mode_default)).
  void ToCeres(ceres::LinearSolverType mode_default, ceres::Solver::Options* out) const;
};

// For solvers whose problem has only the poses (DSR, the baselines): an empty
// solve.linear_solver or one of DENSE_QR, DENSE_NORMAL_CHOLESKY, SPARSE_NORMAL_CHOLESKY;
// otherwise false with "solve.linear_solver=X: <who> only the poses; ...".
bool ValidatePoseOnlyLinearSolver(const SolveOptions& solve, const std::string& who,
                                  std::string* error);

// Per-iteration record, kept for reports and convergence plots.
struct IterationRecord {
  int iteration = 0;
  double cost = 0.0;       // Ceres cost = 0.5 * sum of squared residuals
  double step_norm = 0.0;  // |delta| of the accepted step (tangent space)
  double seconds = 0.0;    // cumulative wall time
  bool step_accepted = true;
};

// Logs each iteration to stderr (when enabled), keeps the records and tells `observer`
// (when set; its false aborts the solve).
class ProgressCallback final : public ceres::IterationCallback {
 public:
  ProgressCallback(std::string label, bool log, IterationObserver observer = nullptr)
      : label_(std::move(label)), log_(log), observer_(std::move(observer)) {}
  ceres::CallbackReturnType operator()(const ceres::IterationSummary& summary) override;
  const std::vector<IterationRecord>& records() const { return records_; }

 private:
  std::string label_;
  bool log_;
  IterationObserver observer_;
  std::vector<IterationRecord> records_;
};

// What every mode returns.
struct SolveReport {
  std::vector<Eigen::Isometry3d> frame_from_world;
  std::vector<IterationRecord> iterations;
  std::string termination;        // Ceres's message
  bool usable = false;            // summary.IsSolutionUsable() and finite cost
  double initial_cost = 0.0;      // 0.5 * f at the start (Ceres convention)
  double final_cost = 0.0;
  int num_iterations = 0;
  double seconds = 0.0;
  double seconds_per_iteration = 0.0;
  int64_t observations_per_iteration = 0;  // intensity differences per evaluation
  // Streamed costs: passes over the voxels with Jacobians and cost-only, summed over the
  // solve's blocks (0 for other costs).
  int jacobian_passes = 0;
  int cost_passes = 0;
  // DSR's fast path: per frame, the sum of squared residuals and their number at the final
  // poses, from the solve's last pass when it was made there (else empty).
  std::vector<double> final_frame_cost;
  std::vector<int64_t> final_frame_observations;
  // Per frame, the estimated gain and offset (solves with photometric parameters; else
  // empty). Frame 0: 1 and 0.
  std::vector<Photometric> photometric;
};

// Fills the common fields of a report from a Ceres summary.
void FillReport(const ceres::Solver::Summary& summary,
                const ProgressCallback& progress,
                SolveReport* report);

// Peak resident set size of this process in bytes (VmHWM), 0 when unknown.
int64_t PeakResidentBytes();
// Resident set size of this process now in bytes (VmRSS), 0 when unknown.
int64_t CurrentResidentBytes();
// Physical memory of the machine in bytes, 0 when unknown.
int64_t PhysicalMemoryBytes();

}  // namespace dsr

#endif  // DSR_SOLVE_SOLVE_OPTIONS_H_
