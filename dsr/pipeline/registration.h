// The registration pipeline every mode runs: load-independent, flag-free.
//
//   Register
//     scale intensities far from a usual range by a power of two (pipeline/input_checks.h)
//     start        the given poses, the pairwise baseline's, or the pair graph's (init/)
//     pyramids     of every frame (image/pyramid.h) and the coarse search level
//     rounds       CoarseToFine (pipeline/coarse_to_fine.h): every level's solves, coarse to
//                  fine, with candidate rebuilds and the checks; when the checks flag frames,
//                  Recover re-places them (init/recovery.h) and the next round starts again
//                  from the coarsest level, at most max_recoveries times
//
// The candidate set is fixed during one solve (so each solve minimises one function of
// the poses, the same for every mode); rebuilding it between solves lets frames that
// moved into or out of each other's field of view enter or leave. The mode's solver comes
// from one factory (pipeline/modes.h).
//
// Its settings are pipeline/registration_options.h, what it returns
// pipeline/registration_result.h; both come with this header.
#ifndef DSR_PIPELINE_REGISTRATION_H_
#define DSR_PIPELINE_REGISTRATION_H_

#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "dsr/geometry/volume.h"
#include "dsr/pipeline/registration_options.h"
#include "dsr/pipeline/registration_result.h"

namespace dsr {

// Recoveries of the tools' --init=auto, global and FILE starts (--max_recoveries default).
constexpr int kDefaultMaxRecoveries = 2;

// The tools' --init values other than a poses file:
//   auto      the given poses (identity), recovery when the checks flag frames (default);
//   identity  the given poses, no recovery (the paper's start; faithful comparisons);
//   pairwise  the pairwise baseline's poses, no recovery (the paper's initialiser);
//   global    the pair graph's poses (init/pair_graph.h), then recovery when needed.
// Sets options->init and options->max_recoveries (to `max_recoveries` where recovery
// applies, else 0). Returns false for any other name (then a poses file is meant: the
// given poses, with recovery).
bool SetInitialisation(const std::string& name, int max_recoveries, RegistrationOptions* options);

// Registers. `initial_frame_from_world` is re-expressed relative to frame 0 first.
// Returns false with `error` for bad input or set-up problems (e.g. frames that do not
// overlap, a DBA problem over the memory budget); a solve that ran but is not usable
// returns true with result->usable = false and result->failure.
bool Register(const std::vector<Image>& images,
              const std::vector<Mask>& masks,
              const std::vector<Eigen::Isometry3d>& initial_frame_from_world,
              const RegistrationOptions& options,
              RegistrationResult* result,
              std::string* error);
// Views recorded over T > 1 phases of the heart cycle (docs/design.md section 12): `images`
// are the views' phase 0, `later_phases[i][p - 1]` view i's phase p, every view with the
// same phases on its own grid, all under its one mask and its one pose (empty: 3D views,
// the call above). Modes dsr and dba register every phase at once (their solves and the
// checks that stream the cost sum the phases); the global search, recovery and pair check
// look at phase 0. The result has one pose per view; with mode dba, DBA's intensities of
// phase 0 in dba_intensities and of the later phases in dba_later_phases.
bool Register(const std::vector<Image>& images,
              const std::vector<std::vector<Image>>& later_phases,
              const std::vector<Mask>& masks,
              const std::vector<Eigen::Isometry3d>& initial_frame_from_world,
              const RegistrationOptions& options,
              RegistrationResult* result,
              std::string* error);

}  // namespace dsr

#endif  // DSR_PIPELINE_REGISTRATION_H_
