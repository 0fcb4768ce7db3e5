// The registration modes: their names (the tools' --mode values), what each estimates, and
// the one factory that turns RegistrationOptions into the mode's solver of one level.
//
//   dsr                the reduced problem (dsr_reduced/), intensities eliminated
//   dba                full direct bundle adjustment in Ceres (dba/)
//   pairwise, lie_normalization, sequential, ape
//                      the paper's baselines (baselines/); the first three are pair-based:
//                      they build their own pair problems in every solve
#ifndef DSR_PIPELINE_MODES_H_
#define DSR_PIPELINE_MODES_H_

#include <functional>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "dsr/baselines/baselines.h"
#include "dsr/dba/dba_problem.h"
#include "dsr/dsr_reduced/dsr_solver.h"
#include "dsr/image/frame.h"
#include "dsr/model/observation.h"
#include "dsr/model/photometric.h"
#include "dsr/solve/solve_options.h"

namespace dsr {

struct RegistrationOptions;

enum class Mode {
  kDsr,
  kDba,
  kPairwise,
  kLieNormalization,
  kSequential,
  kApe,
};

// "dsr", "dba", "pairwise", "lie_normalization", "sequential", "ape".
const char* ModeToString(Mode mode);
// The inverse of ModeToString; false (and *mode untouched) for any other text.
bool StringToMode(const std::string& name, Mode* mode);
// Every mode's name, in the enum's order.
std::vector<std::string> ModeNames();
// Whether the mode can estimate photometric parameters and a robust loss: dsr and dba.
bool ModeEstimatesPhotometric(Mode mode);
// Whether the mode's solves take RegistrationOptions::gauge (solve/gauge.h): dsr and dba,
// in the same gauge so that they minimise one function. The others hold frame 0 constant.
bool ModeTakesGauge(Mode mode);
// Whether the mode builds its own pair problems in every solve (pairwise, Lie
// normalisation, sequential): the shared candidates are not its cost.
bool ModeIsPairBased(Mode mode);

// Each mode's own options, from the registration's and the solve's of this level.
DsrOptions ToDsrOptions(const RegistrationOptions& options, const SolveOptions& solve);
DbaOptions ToDbaOptions(const RegistrationOptions& options, const SolveOptions& solve);
BaselineOptions ToBaselineOptions(const RegistrationOptions& options, const SolveOptions& solve);

// One solve of the poses with the candidates fixed. With photometric parameters they start
// at `photometric` (one per frame, frame 0 the gauge; empty: every gain 1, offset 0) and the
// estimate is in report->photometric. `dba_intensities` (may be null) receives DBA's
// optimised intensities per candidate voxel; other modes leave it alone.
using LevelSolver = std::function<bool(const SolveOptions& solve,
                                       const std::vector<Frame>& frames,
                                       const CandidateSet& candidates,
                                       const std::vector<Eigen::Isometry3d>& initial,
                                       const std::vector<Photometric>& photometric,
                                       SolveReport* report,
                                       std::vector<float>* dba_intensities,
                                       std::string* error)>;

// The solver of options.mode (the only place that dispatches on the mode to solve).
LevelSolver MakeLevelSolver(const RegistrationOptions& options);

}  // namespace dsr

#endif  // DSR_PIPELINE_MODES_H_
