#include "dsr/pipeline/modes.h"

#include <glog/logging.h>

#include "dsr/pipeline/registration_options.h"
#include "dsr/util/option_fields.h"

namespace dsr {

namespace {
constexpr Mode kModes[] = {Mode::kDsr,        Mode::kDba,        Mode::kPairwise,
                           Mode::kLieNormalization, Mode::kSequential, Mode::kApe};
}  // namespace

const char* ModeToString(Mode mode) {
  switch (mode) {
    case Mode::kDsr: return "dsr";
    case Mode::kDba: return "dba";
    case Mode::kPairwise: return "pairwise";
    case Mode::kLieNormalization: return "lie_normalization";
    case Mode::kSequential: return "sequential";
    case Mode::kApe: return "ape";
  }
  return "";  // a value cast into Mode that names none (Validate refuses it)
}

bool StringToMode(const std::string& name, Mode* mode) {
  return FindNamed(name, kModes, ModeToString, mode);
}

std::vector<std::string> ModeNames() {
  std::vector<std::string> names;
  for (Mode m : kModes) names.push_back(ModeToString(m));
  return names;
}

bool ModeEstimatesPhotometric(Mode mode) { return mode == Mode::kDsr || mode == Mode::kDba; }

bool ModeTakesGauge(Mode mode) { return mode == Mode::kDsr || mode == Mode::kDba; }

bool ModeIsPairBased(Mode mode) {
  return mode == Mode::kPairwise || mode == Mode::kLieNormalization || mode == Mode::kSequential;
}

BaselineOptions ToBaselineOptions(const RegistrationOptions& options, const SolveOptions& solve) {
  BaselineOptions baseline;
  baseline.solve = solve;
  baseline.panorama_spacing = options.panorama_spacing;
  baseline.min_shared_voxels = options.min_shared_voxels;
  baseline.num_chunks = options.dsr.num_chunks;
  return baseline;
}

DsrOptions ToDsrOptions(const RegistrationOptions& options, const SolveOptions& solve) {
  DsrOptions dsr;
  dsr.solve = solve;
  dsr.num_chunks = options.dsr.num_chunks;
  dsr.reference_cost = options.dsr.reference_cost;
  dsr.photometric = options.photometric == PhotometricModel::kAffine;
  dsr.loss = options.loss;
  dsr.gauge = options.gauge;
  return dsr;
}

DbaOptions ToDbaOptions(const RegistrationOptions& options, const SolveOptions& solve) {
  DbaOptions dba;
  dba.solve = solve;
  dba.memory_budget_mb = options.dba.memory_budget_mb;
  dba.photometric = options.photometric == PhotometricModel::kAffine;
  dba.loss = options.loss;
  dba.gauge = options.gauge;
  return dba;
}

LevelSolver MakeLevelSolver(const RegistrationOptions& options) {
  // The solver copies `options` (the returned function may outlive it).
  return [options](const SolveOptions& solve, const std::vector<Frame>& frames,
                   const CandidateSet& candidates, const std::vector<Eigen::Isometry3d>& initial,
                   const std::vector<Photometric>& photometric, SolveReport* report,
                   std::vector<float>* dba_intensities, std::string* error) {
    switch (options.mode) {
      case Mode::kDsr: {
        DsrOptions dsr = ToDsrOptions(options, solve);
        if (dsr.photometric) dsr.initial_photometric = photometric;
        return SolveDsr(frames, candidates, initial, dsr, report, error);
      }
      case Mode::kDba: {
        DbaOptions dba = ToDbaOptions(options, solve);
        if (dba.photometric) dba.initial_photometric = photometric;
        return SolveDba(frames, candidates, initial, dba, report, dba_intensities, error);
      }
      case Mode::kApe:
        return SolveApe(frames, candidates, initial, ToBaselineOptions(options, solve), report,
                        error);
      case Mode::kPairwise:
        return SolvePairwise(frames, initial, ToBaselineOptions(options, solve), report, error);
      case Mode::kLieNormalization:
        return SolveLieNormalization(frames, candidates, initial,
                                     ToBaselineOptions(options, solve), report, error);
      case Mode::kSequential:
        return SolveSequential(frames, initial, ToBaselineOptions(options, solve), report, error);
    }
    LOG(FATAL) << "no solver for mode " << static_cast<int>(options.mode);
    return false;
  };
}

}  // namespace dsr
