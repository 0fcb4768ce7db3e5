// Google Benchmark programs for the global initialisation (init/): one masked NCC over
// every shift (the FFTs), the search of one frame against another over the sampled
// rotations, the search of one frame against the panorama of ten others (what one
// recovery costs) and the pipeline's pair check of all frames, all at the search level of
// the paper's 96x96x80 frames (24x24x20 voxels of 4 mm). bench/accuracy.sh measures what
// the search buys.
#include <benchmark/benchmark.h>

#include <memory>

#include "dsr/image/pyramid.h"
#include "dsr/init/masked_ncc.h"
#include "dsr/init/placement_search.h"
#include "dsr/model/panorama.h"
#include "dsr/pipeline/pair_check.h"
#include "dsr/sim/phantom.h"
#include "dsr/sim/simulate.h"

namespace dsr {
namespace {

// The paper's sequence (seed 1) at the search level: two halvings of 96x96x80, and its
// ground-truth poses.
std::vector<Eigen::Isometry3d>& TruePoses() {
  static std::vector<Eigen::Isometry3d> poses;
  return poses;
}

const std::vector<Frame>& SearchLevelFrames() {
  static const std::vector<Frame> frames = [] {
    PhantomOptions p;
    const Image phantom = MakePhantom(p);
    SimulationOptions o;
    SimulatedSequence s;
    std::string error;
    if (!Simulate(phantom, o, &s, &error)) {
      std::fprintf(stderr, "%s\n", error.c_str());
      std::abort();
    }
    TruePoses() = s.frame_from_world;
    std::vector<Frame> out;
    for (size_t i = 0; i < s.frames.size(); ++i) {
      ImageLevel level{s.frames[i], s.masks[i]};
      for (int h = 0; h < 2; ++h) level = Downsample(level.image, level.mask, 1.0, 1);
      out.emplace_back(level.image, level.mask);
    }
    return out;
  }();
  return frames;
}

PlacementSearchOptions Options(int rotations) {
  PlacementSearchOptions o;
  o.rotations = rotations;
  o.num_threads = 1;
  o.refine.progress = false;
  o.refine.num_threads = 1;
  return o;
}

// One MaskedNcc::Best: fixed 24x24x20, moving 35^3 (a rotated frame's grid).
void BM_MaskedNccBest(benchmark::State& state) {
  ImageGeometry fixed_grid, moving_grid;
  fixed_grid.size = Eigen::Vector3i(24, 24, 20);
  moving_grid.size = Eigen::Vector3i(35, 35, 35);
  Image fixed(fixed_grid, 0.0f), moving(moving_grid, 0.0f);
  Mask fixed_mask(fixed_grid, 1), moving_mask(moving_grid, 1);
  for (size_t l = 0; l < fixed.voxels.size(); ++l)
    fixed.voxels[l] = static_cast<float>((l * 7919) % 255);
  for (size_t l = 0; l < moving.voxels.size(); ++l)
    moving.voxels[l] = static_cast<float>((l * 104729) % 255);
  const MaskedNcc ncc(fixed, fixed_mask, moving_grid.size);
  for (auto _ : state) benchmark::DoNotOptimize(ncc.Best(moving, moving_mask, 100));
}
BENCHMARK(BM_MaskedNccBest)->Unit(benchmark::kMillisecond);

// The peaks of frame 1 against frame 0 over range(0) rotations within 45 degrees, the
// best range(1) of them kept by the coarse screen (0: no screen, every rotation searched
// at the search level).
void BM_SearchPeaksPair(benchmark::State& state) {
  const std::vector<Frame>& frames = SearchLevelFrames();
  PlacementSearchOptions o = Options(static_cast<int>(state.range(0)));
  o.num_screened = static_cast<int>(state.range(1));
  for (auto _ : state) {
    benchmark::DoNotOptimize(SearchPeaks(frames[0], frames[1], Eigen::Matrix3d::Identity(), o));
  }
}
BENCHMARK(BM_SearchPeaksPair)
    ->Args({60, 12})
    ->Args({60, 0})
    ->Args({200, 12})
    ->Args({200, 0})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

// Frame 5 against the panorama of the ten others: recovery's search (200 rotations,
// refinement of the best 3 peaks included).
void BM_SearchPlacementPanorama(benchmark::State& state) {
  const std::vector<Frame>& frames = SearchLevelFrames();
  std::vector<Frame> others;
  std::vector<Eigen::Isometry3d> poses;
  for (size_t i = 0; i < frames.size(); ++i) {
    if (i == 5) continue;
    others.push_back(frames[i]);
    poses.push_back(Eigen::Isometry3d::Identity());
  }
  ImageGeometry grid;
  std::string error;
  if (!BuildPanoramaGrid(others, poses, 1.0, &grid, &error)) std::abort();
  const Frame panorama = PanoramaAsFrame(FusePanoramaMean(others, poses, grid, 1));
  PlacementSearchOptions o = Options(200);
  o.num_threads = static_cast<int>(state.range(0));
  o.num_screened = static_cast<int>(state.range(1));
  o.refine.num_threads = o.num_threads;
  for (auto _ : state) {
    benchmark::DoNotOptimize(
        SearchPlacement(panorama, frames[5], Eigen::Matrix3d::Identity(), {}, o));
  }
}
// Threads, screened rotations (0: no screen).
BENCHMARK(BM_SearchPlacementPanorama)
    ->Args({1, 12})
    ->Args({1, 0})
    ->Args({2, 12})
    ->Args({2, 0})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

// The pipeline's pair check (pipeline/pair_check.h) of the 11 frames at their true poses:
// what it adds after each level and at the final poses.
void BM_PairCheck(benchmark::State& state) {
  const std::vector<Frame>& frames = SearchLevelFrames();
  const int threads = static_cast<int>(state.range(0));
  for (auto _ : state) {
    benchmark::DoNotOptimize(PairMismatches(frames, TruePoses(), threads));
  }
}
BENCHMARK(BM_PairCheck)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime();

}  // namespace
}  // namespace dsr

BENCHMARK_MAIN();
