// The pair-based baselines: pair registration, pairwise chaining, Lie normalisation and
// sequential registration to the growing panorama (docs/design.md section 5).
#include <algorithm>
#include <numeric>
#include <sstream>

#include <glog/logging.h>

#include "dsr/baselines/baselines.h"
#include "dsr/model/panorama.h"
#include "dsr/util/option_fields.h"

namespace dsr {
namespace {

// Appends a sub-solve to a method's total report: iterations concatenated (cumulative
// seconds continue), costs and iteration counts summed, observations per iteration
// averaged over iterations.
class ReportMerger {
 public:
  void Add(const SolveReport& part) {
    for (IterationRecord record : part.iterations) {
      record.iteration += total_.num_iterations;
      record.seconds += total_.seconds;
      total_.iterations.push_back(record);
    }
    total_.initial_cost += part.initial_cost;
    total_.final_cost += part.final_cost;
    total_.num_iterations += part.num_iterations;
    total_.seconds += part.seconds;
    observations_ += static_cast<double>(part.observations_per_iteration) *
                     std::max(1, part.num_iterations);
    weight_ += std::max(1, part.num_iterations);
    if (!part.usable) {
      usable_ = false;
      if (failure_.empty()) failure_ = part.termination;
    }
    ++solves_;
  }

  SolveReport Finish(const std::vector<Eigen::Isometry3d>& poses, const std::string& what) {
    SolveReport out = total_;
    out.frame_from_world = poses;
    out.usable = usable_;
    out.seconds_per_iteration = out.seconds / std::max(1, out.num_iterations);
    out.observations_per_iteration =
        weight_ > 0.0 ? static_cast<int64_t>(observations_ / weight_ + 0.5) : 0;
    std::ostringstream s;
    s << what << ": " << solves_ << " solves, " << out.num_iterations << " iterations";
    if (!usable_) s << "; a solve was not usable: " << failure_;
    out.termination = s.str();
    return out;
  }

 private:
  SolveReport total_;
  double observations_ = 0.0, weight_ = 0.0;
  bool usable_ = true;
  std::string failure_;
  int solves_ = 0;
};

// A pair's objective: the mean of the squared differences over the voxels both frames
// observe at the current poses (ITK's MeanSquares). The plain sum would reward shrinking
// the overlap: with two frames nothing else holds them together, and every sample that
// leaves a field of view lowers the sum (a 300-fold "improvement" on the demo's first
// pair at the coarsest level, with the frames sliding apart). The mean does not change
// when average samples leave. The normal equations are scaled by the same count, so the
// Gauss-Newton model stays exact for the current overlap.
class PairMeanSquaresCost final : public StreamedPoseCost {
 public:
  PairMeanSquaresCost(const std::vector<Frame>* pair,
                      const CandidateSet* candidates,
                      const Eigen::Isometry3d& fixed_from_world,
                      int64_t begin,
                      int64_t end,
                      const StreamContext& context)
      : StreamedPoseCost(2, fixed_from_world),
        pair_(pair),
        candidates_(candidates),
        begin_(begin),
        end_(end),
        context_(context) {}

 private:
  void Accumulate(const std::vector<Eigen::Isometry3d>& frame_from_world,
                  const std::vector<Photometric>& /*photometric: none*/,
                  bool with_jacobian,
                  NormalEquations* out) const override {
    AccumulateApeSystem(*pair_, *candidates_, frame_from_world, begin_, end_, with_jacobian,
                        context_, out);
    if (out->observations == 0) return;
    const double scale = 1.0 / static_cast<double>(out->observations);
    out->cost *= scale;
    if (with_jacobian) {
      out->hessian *= scale;
      out->gradient *= scale;
    }
  }

  const std::vector<Frame>* pair_;
  const CandidateSet* candidates_;
  int64_t begin_, end_;
  StreamContext context_;
};

BaselineOptions WithPrefix(const BaselineOptions& options, const std::string& prefix) {
  BaselineOptions out = options;
  out.solve.progress_prefix = options.solve.progress_prefix + prefix;
  return out;
}

}  // namespace

bool BaselineOptions::Validate(std::string* error) const {
  if (!solve.Validate(error)) {
    *error = PrefixFieldPaths("solve", *error);
    return false;
  }
  if (!ValidatePoseOnlyLinearSolver(solve, "the baselines solve", error)) return false;
  if (!(panorama_spacing > 0.0) || !std::isfinite(panorama_spacing)) {
    *error = FieldError("panorama_spacing", panorama_spacing, "must be a positive number");
    return false;
  }
  if (min_shared_voxels < 1) {
    *error = FieldError("min_shared_voxels", min_shared_voxels, "must be >= 1");
    return false;
  }
  if (num_chunks < 1) {
    *error = FieldError("num_chunks", num_chunks, "must be >= 1");
    return false;
  }
  return true;
}

bool RegisterPair(const Frame& fixed,
                  const Eigen::Isometry3d& fixed_from_world,
                  const Frame& moving,
                  const BaselineOptions& options,
                  Eigen::Isometry3d* moving_from_world,
                  SolveReport* report,
                  std::string* error) {
  const std::vector<Frame> pair = {fixed, moving};  // shares the sampler data
  const std::vector<Eigen::Isometry3d> poses = {fixed_from_world, *moving_from_world};
  ImageGeometry grid;
  if (!BuildPanoramaGrid(pair, poses, options.panorama_spacing, &grid, error)) return false;
  const CandidateSet candidates = BuildCandidates(pair, poses, grid, /*margin_cells=*/0);
  if (candidates.num_voxels() < options.min_shared_voxels) {
    *error = "the pair shares " + std::to_string(candidates.num_voxels()) +
             " voxels at the start poses, fewer than " +
             std::to_string(options.min_shared_voxels);
    return false;
  }
  const StreamContext context = StreamContextFor(options.solve);
  // One block: the mean is over the whole overlap.
  if (!SolveStreamedPoses(
          pair, poses, candidates.num_voxels(), 1,
          [&](int64_t begin, int64_t end) {
            return new PairMeanSquaresCost(&pair, &candidates, fixed_from_world, begin, end,
                                           context);
          },
          options.solve, "pair", report, error)) {
    return false;
  }
  if (report->usable) *moving_from_world = report->frame_from_world[1];
  report->frame_from_world = {fixed_from_world, *moving_from_world};
  return true;
}

bool SolvePairwise(const std::vector<Frame>& frames,
                   const std::vector<Eigen::Isometry3d>& initial,
                   const BaselineOptions& options,
                   SolveReport* report,
                   std::string* error) {
  const int m = static_cast<int>(frames.size());
  std::vector<Eigen::Isometry3d> poses = initial;
  ReportMerger merger;
  for (int k = 1; k < m; ++k) {
    // Start from the initial relative pose of the pair, placed on the chained frame k-1.
    poses[k] = initial[k] * initial[k - 1].inverse() * poses[k - 1];
    SolveReport part;
    std::string why;
    const std::string name = "pair " + std::to_string(k - 1) + "-" + std::to_string(k) + " ";
    if (!RegisterPair(frames[k - 1], poses[k - 1], frames[k], WithPrefix(options, name),
                      &poses[k], &part, &why)) {
      *error = "pairwise: frames " + std::to_string(k - 1) + " and " + std::to_string(k) +
               ": " + why;
      return false;
    }
    merger.Add(part);
  }
  *report = merger.Finish(poses, "pairwise");
  return true;
}

bool SolveLieNormalization(const std::vector<Frame>& frames,
                           const CandidateSet& candidates,
                           const std::vector<Eigen::Isometry3d>& initial,
                           const BaselineOptions& options,
                           SolveReport* report,
                           std::string* error) {
  const int m = static_cast<int>(frames.size());
  const Eigen::MatrixXi overlap = CandidateOverlap(candidates);
  std::vector<RelativePose> measurements;
  ReportMerger merger;
  // Union-find over the measured pairs, to refuse a graph that leaves a frame unconstrained.
  std::vector<int> parent(m);
  std::iota(parent.begin(), parent.end(), 0);
  auto root = [&](int x) {
    while (parent[x] != x) x = parent[x] = parent[parent[x]];
    return x;
  };
  for (int i = 0; i < m; ++i) {
    for (int k = i + 1; k < m; ++k) {
      if (overlap(i, k) < options.min_shared_voxels) continue;
      Eigen::Isometry3d frame_k = initial[k];
      SolveReport part;
      std::string why;
      const std::string name = "pair " + std::to_string(i) + "-" + std::to_string(k) + " ";
      if (!RegisterPair(frames[i], initial[i], frames[k], WithPrefix(options, name), &frame_k,
                        &part, &why)) {
        LOG(WARNING) << "lie_normalization: skipping frames " << i << " and " << k << ": " << why;
        continue;
      }
      merger.Add(part);
      if (!part.usable) continue;
      measurements.push_back({i, k, frame_k * initial[i].inverse()});
      parent[root(i)] = root(k);
    }
  }
  for (int k = 1; k < m; ++k) {
    if (root(k) != root(0)) {
      *error = "lie_normalization: frame " + std::to_string(k) +
               " has no registered pair path to frame 0";
      return false;
    }
  }
  std::vector<Eigen::Isometry3d> poses;
  SolveReport graph;
  if (!SolvePoseGraph(measurements, initial, options.solve, &poses, &graph, error)) return false;
  SolveReport total = merger.Finish(poses, "lie_normalization (" +
                                               std::to_string(measurements.size()) + " pairs)");
  total.usable = total.usable && graph.usable;
  total.seconds += graph.seconds;
  *report = total;
  return true;
}

bool SolveSequential(const std::vector<Frame>& frames,
                     const std::vector<Eigen::Isometry3d>& initial,
                     const BaselineOptions& options,
                     SolveReport* report,
                     std::string* error) {
  const int m = static_cast<int>(frames.size());
  std::vector<Eigen::Isometry3d> poses = initial;
  std::vector<Frame> placed = {frames[0]};
  std::vector<Eigen::Isometry3d> placed_poses = {initial[0]};
  // The panorama is already on the panorama grid: pair grids use its spacing as is.
  BaselineOptions pair_options = options;
  pair_options.panorama_spacing = 1.0;
  ReportMerger merger;
  for (int k = 1; k < m; ++k) {
    ImageGeometry grid;
    if (!BuildPanoramaGrid(placed, placed_poses, options.panorama_spacing, &grid, error)) {
      return false;
    }
    const PanoramaImages fused =
        FusePanoramaMean(placed, placed_poses, grid, options.solve.num_threads);
    const Frame panorama = PanoramaAsFrame(fused);
    SolveReport part;
    std::string why;
    const std::string name = "frame " + std::to_string(k) + " to panorama ";
    if (!RegisterPair(panorama, Eigen::Isometry3d::Identity(), frames[k],
                      WithPrefix(pair_options, name), &poses[k], &part, &why)) {
      *error = "sequential: frame " + std::to_string(k) + " and the panorama of frames 0.." +
               std::to_string(k - 1) + ": " + why;
      return false;
    }
    merger.Add(part);
    placed.push_back(frames[k]);
    placed_poses.push_back(poses[k]);
  }
  *report = merger.Finish(poses, "sequential");
  return true;
}

}  // namespace dsr
