#include "dsr/pipeline/pair_check.h"

#include <algorithm>
#include <cmath>
#include <numeric>
#include <sstream>

#include <glog/logging.h>

#include "dsr/init/placement_search.h"
#include "dsr/pipeline/divergence_guard.h"
#include "dsr/util/parallel.h"

namespace dsr {

std::vector<PairMismatch> PairMismatches(const std::vector<Frame>& frames,
                                         const std::vector<Eigen::Isometry3d>& frame_from_world,
                                         int num_threads) {
  const int m = static_cast<int>(frames.size());
  CHECK_EQ(frame_from_world.size(), frames.size());
  std::vector<std::pair<int, int>> all;
  for (int i = 0; i < m; ++i) {
    for (int j = i + 1; j < m; ++j) all.emplace_back(i, j);
  }
  std::vector<PairMismatch> scored(all.size());
  std::vector<char> judged(all.size(), 0);
  ParallelFor(0, static_cast<int64_t>(all.size()), num_threads, [&](int64_t k) {
    const auto [i, j] = all[k];
    // Scored both ways: the overlap counts the moving frame's voxels, and the direction in
    // which it covers more of a field of view is the better-sampled one.
    const Placement forward = ScorePlacement(
        frames[i], frames[j], frame_from_world[j] * frame_from_world[i].inverse(), 0.0);
    const Placement backward = ScorePlacement(
        frames[j], frames[i], frame_from_world[i] * frame_from_world[j].inverse(), 0.0);
    const Placement& best =
        forward.overlap_fraction >= backward.overlap_fraction ? forward : backward;
    if (best.overlap_fraction < kPairCheckMinOverlap || !std::isfinite(best.ncc)) return;
    scored[k] = PairMismatch{i, j, best.overlap_fraction, 1.0 - best.ncc};
    judged[k] = 1;
  });
  std::vector<PairMismatch> pairs;
  for (size_t k = 0; k < all.size(); ++k) {
    if (judged[k]) pairs.push_back(scored[k]);
  }
  return pairs;
}

bool PairDisagreement(const std::vector<PairMismatch>& pairs,
                      int num_frames,
                      double max_ratio,
                      std::vector<int>* flagged,
                      std::string* why) {
  flagged->clear();
  if (!(max_ratio > 0.0) || pairs.size() < 3) return false;
  std::vector<double> mismatches;
  for (const PairMismatch& p : pairs) mismatches.push_back(p.mismatch);
  const double reference = std::max(LowerQuartile(mismatches), kMinReferenceMismatch);
  const double limit = max_ratio * reference;
  const auto worst = std::max_element(
      pairs.begin(), pairs.end(),
      [](const PairMismatch& a, const PairMismatch& b) { return a.mismatch < b.mismatch; });
  if (!(worst->mismatch > limit)) return false;

  // Groups of frames joined by agreeing pairs (union-find), and each frame's tally.
  std::vector<int> parent(num_frames);
  std::iota(parent.begin(), parent.end(), 0);
  const auto root = [&](int f) {
    while (parent[f] != f) f = parent[f] = parent[parent[f]];
    return f;
  };
  std::vector<int> agree(num_frames, 0), disagree(num_frames, 0);
  for (const PairMismatch& p : pairs) {
    if (p.mismatch > limit) {
      ++disagree[p.first];
      ++disagree[p.second];
    } else {
      ++agree[p.first];
      ++agree[p.second];
      parent[root(p.first)] = root(p.second);
    }
  }
  // The largest group (ties: the one holding the lowest frame index) is the reference.
  std::vector<int> size(num_frames, 0);
  for (int f = 0; f < num_frames; ++f) ++size[root(f)];
  int largest = root(0);
  for (int f = 0; f < num_frames; ++f) {
    if (size[root(f)] > size[largest]) largest = root(f);
  }
  for (int f = 0; f < num_frames; ++f) {
    if (root(f) != largest || disagree[f] > agree[f]) flagged->push_back(f);
  }
  if (flagged->empty()) {
    flagged->push_back(worst->first);
    flagged->push_back(worst->second);
  }
  std::stable_sort(flagged->begin(), flagged->end(),
                   [&](int a, int b) { return disagree[a] > disagree[b]; });

  const int disagreeing = static_cast<int>(std::count_if(
      pairs.begin(), pairs.end(), [&](const PairMismatch& p) { return p.mismatch > limit; }));
  std::ostringstream s;
  s.precision(3);
  s << "frames " << worst->first << " and " << worst->second
    << " do not match each other at the poses reached: 1 - NCC over their overlap ("
    << static_cast<int>(100.0 * worst->overlap_fraction + 0.5) << "% of a field of view) is "
    << worst->mismatch << ", " << worst->mismatch / reference
    << " times the pairs' lower quartile (" << reference << "; max_pair_mismatch_ratio="
    << max_ratio << "); " << disagreeing << " of " << pairs.size()
    << " overlapping pairs disagree: a wrong local minimum; give better initial poses (init)";
  *why = s.str();
  return true;
}

}  // namespace dsr
