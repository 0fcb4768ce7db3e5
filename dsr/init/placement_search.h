// Global search for the rigid placement of one volume (the moving frame) relative to
// another (a frame or a panorama), independent of any starting pose (docs/design.md
// section 9, "Global initialisation").
//
//   screen the rotations within max_rotation of a centre (init/rotation_grid.h) by the
//   steps below on both volumes at half resolution, and keep the best num_screened;
//   for each kept rotation R:
//     resample the moving field of view rotated by R^T about its centre onto a grid with
//     the fixed volume's spacing and axes;
//     the best integer translation by masked normalised cross-correlation over every
//     shift at which the two fields of view overlap enough (init/masked_ncc.h, FFTs);
//   keep the best few distinct (rotation, translation) peaks, refine each with the local
//   pair solver (mean squared difference over the overlap, baselines/RegisterPair), and
//   score each refined placement by the masked NCC of the overlap.
//
// Both volumes are given as `Frame`s on one pyramid level (coarse: the search costs
// rotations x FFTs of the padded grids); a volume's field of view for the NCC is its
// valid-cell map (the cells whose 8 corners are inside its mask). NCC, not the squared difference,
// ranks the candidates: it does not reward a small overlap with a low variance, and it is blind to
// a gain and an offset between the volumes (a panorama mixes several frames).
#ifndef DSR_INIT_PLACEMENT_SEARCH_H_
#define DSR_INIT_PLACEMENT_SEARCH_H_

#include <limits>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "dsr/geometry/volume.h"
#include "dsr/image/frame.h"
#include "dsr/solve/solve_options.h"

namespace dsr {

struct PlacementSearchOptions {
  // Rotations sampled within this angle of the centre rotation, about `rotations` of them
  // (200 within 45 degrees: about 8 degrees apart, well inside the local solver's reach).
  double rotation_deg = 45.0;
  int rotations = 200;
  // Best distinct peaks refined by the local solver (plus the caller's extra starts).
  int num_refined = 3;
  // Rotations per pair of the pair graph (init/pair_graph.h), which searches m(m-1)/2 pairs:
  // fewer than `rotations`, about 11 degrees apart within 45 degrees.
  int pair_rotations = 60;
  // The coarse screen: every sampled rotation is first scored with both volumes at half
  // resolution (an eighth of the voxels), and only the best num_screened rotations are
  // searched at the given level. 0: no screen, every rotation at the given level.
  int num_screened = 12;
  // Two peaks are the same candidate when their rotations differ by less than this and
  // their translations by less than 3 fixed voxels.
  double distinct_rotation_deg = 15.0;
  // A placement counts only when this fraction of the moving field of view lies inside
  // the fixed one in the NCC search, and half of it in the final score (whose overlap
  // counts the moving valid voxels that land on valid cells of the fixed volume: a
  // refinement by the mean squared difference may also trade a little overlap for fit).
  double min_overlap_fraction = 0.25;
  // Local refinement of each candidate (a pair solve on the search level).
  SolveOptions refine;
  int num_threads = 0;  // <= 0: all hardware threads

  // `error` names the field (util/option_fields.h).
  bool Validate(std::string* error) const;
};

struct Placement {
  Eigen::Isometry3d moving_from_fixed = Eigen::Isometry3d::Identity();  // physical mm
  // Masked NCC of the two volumes over their overlap at this placement (-inf: the overlap
  // is below min_overlap_fraction of the moving field of view).
  double ncc = -std::numeric_limits<double>::infinity();
  int64_t overlap = 0;       // moving valid voxels that land in the fixed field of view
  double overlap_fraction = 0.0;  // of the moving field of view
  int extra_start = -1;  // refined from the caller's extra_starts[extra_start]; -1: a peak
};

// The overlap fraction below which ScorePlacement gives -inf in the search (see
// min_overlap_fraction).
double ScoreMinOverlap(const PlacementSearchOptions& options);

// Masked NCC of `fixed` and `moving` at `moving_from_fixed`: over the moving frame's valid
// voxels (integer indices) whose point lands on a valid sample of `fixed`. The overlap
// fields are filled; ncc is -inf when the overlap is below `min_overlap_fraction` of the
// moving field of view or either side is flat there.
Placement ScorePlacement(const Frame& fixed,
                         const Frame& moving,
                         const Eigen::Isometry3d& moving_from_fixed,
                         double min_overlap_fraction);

// The search described above. `centre` is the rotation part of moving_from_fixed the
// rotations are sampled around; `extra_starts` are further moving_from_fixed poses to
// refine and score alongside (e.g. the current pose). Returns every refined candidate,
// best NCC first; empty when nothing overlaps enough. Deterministic.
std::vector<Placement> SearchPlacement(const Frame& fixed,
                                       const Frame& moving,
                                       const Eigen::Matrix3d& centre,
                                       const std::vector<Eigen::Isometry3d>& extra_starts,
                                       const PlacementSearchOptions& options);

// The search without refinement: the best translation for each sampled rotation that
// passed the coarse screen (every rotation with num_screened = 0), as placements sorted
// best NCC first (for tests and measurements).
std::vector<Placement> SearchPeaks(const Frame& fixed,
                                   const Frame& moving,
                                   const Eigen::Matrix3d& centre,
                                   const PlacementSearchOptions& options);

}  // namespace dsr

#endif  // DSR_INIT_PLACEMENT_SEARCH_H_
