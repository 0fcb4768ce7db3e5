// Google Benchmark of the field-of-view masks of frames given without one
// (geometry/field_of_view.h): the convex hull of the non-zero voxels against the non-zero
// rule, both eroded by one voxel (the tools' default), on the simulator's pyramid filled
// with noise clamped at 0 and a dark region touching two of its faces, at the paper's frame
// size (96x96x80) and at 200^3.
#include <benchmark/benchmark.h>

#include <algorithm>
#include <random>

#include "dsr/geometry/field_of_view.h"
#include "dsr/sim/simulate.h"

namespace dsr {
namespace {

Image NoisyPyramid(int nx, int ny, int nz) {
  ImageGeometry g;
  g.size = Eigen::Vector3i(nx, ny, nz);
  const Mask fov = PyramidFieldOfView(g, SimulationOptions{});
  std::mt19937_64 rng(1);
  std::normal_distribution<double> noise(0.0, 25.0);
  Image image(g, 0.0f);
  for (int k = 0; k < nz; ++k)
    for (int j = 0; j < ny; ++j)
      for (int i = 0; i < nx; ++i) {
        if (!fov.at(i, j, k)) continue;
        // Dark (as the background) in the quadrant of low i and j at mid depth.
        const bool dark = i < nx / 2 && j < ny / 2 && k > nz / 3 && k < 2 * nz / 3;
        image.at(i, j, k) = static_cast<float>(std::max(0.0, (dark ? 0.0 : 100.0) + noise(rng)));
      }
  return image;
}

void BM_FieldOfView(benchmark::State& state) {
  const MaskRule rule = state.range(0) == 0 ? MaskRule::kHull : MaskRule::kNonZero;
  const int n = static_cast<int>(state.range(1));
  const Image image = n == 96 ? NoisyPyramid(96, 96, 80) : NoisyPyramid(n, n, n);
  MaskRule used = rule;
  int64_t inside = 0;
  for (auto _ : state) {
    const Mask mask = FieldOfViewFromImage(image, {rule, 1}, &used);
    inside = CountInside(mask);
    benchmark::DoNotOptimize(inside);
  }
  state.SetLabel(std::string(MaskRuleToString(used)) + ", " + std::to_string(inside) +
                 " voxels inside");
}
// (rule: 0 hull, 1 nonzero; size: 96 = 96x96x80, else n^3)
BENCHMARK(BM_FieldOfView)
    ->ArgsProduct({{0, 1}, {96, 200}})
    ->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace dsr

BENCHMARK_MAIN();
