// Google Benchmark of the hot kernels on the paper-sized sequence (11 frames of 96x96x80,
// sigma 25, ground-truth poses, full resolution):
//   BM_SampleValueAndGradient                    one sample with its gradient
//                                                (stream/voxel_stream.h)
//   BM_DsrEvaluation/{jacobian}/{threads}        one DSR evaluation (normal equations)
//   BM_ApeEvaluation/{jacobian}/{threads}        one APE evaluation, same voxels
//   BM_ApeEvaluationBatchedHessian               APE with DSR's batched Gauss-Newton form
//   BM_DsrEvaluationPortable/{jacobian}          DSR with the portable (non-SIMD) kernels
//   BM_DsrEvaluationAvx2/1                       DSR with AVX2 kernels only (no AVX-512)
//   BM_GaussNewtonBatch/{path}                   the batched Gauss-Newton matrix and
//                                                gradient of one batch, per kernel path
//   BM_DsrEvaluationFrames/{frames}              DSR with Jacobians, 3..11 frames
//   BM_DsrEvaluationClinical/{jacobian}          DSR, 11 frames of 176x176x200 at 0.6 mm
//   BM_BuildCandidatesClinical                   the candidate set at that size
//   BM_DsrTiedEvaluationClinical/{phases}        DSR's tied problem (DsrProblem) of those
//                                                views with 1, 2 or 4 phases each: one
//                                                evaluation with the gradient
//   BM_DbaEvaluation                             Ceres Problem::Evaluate of DBA with
//                                                Jacobians, 6 frames of 48x48x40
// Counters: ns per observation (an intensity difference the objective evaluates). The
// kernel path is the best this CPU has (stream/voxel_stream.h) unless named.
#include <benchmark/benchmark.h>

#include <memory>
#include <random>

#include "dsr/baselines/baselines.h"
#include "dsr/dba/dba_problem.h"
#include "dsr/dsr_reduced/dsr_solver.h"
#include "dsr/dsr_reduced/reduced_cost.h"
#include "dsr/model/panorama.h"
#include "dsr/sim/phantom.h"
#include "dsr/sim/simulate.h"
#include "dsr/stream/hessian_batch.h"
#include "dsr/stream/voxel_stream.h"

namespace dsr {
namespace {

// `n` threads with the default (widest) kernels.
StreamContext Threads(int64_t n) { return {static_cast<int>(n), KernelPath::kAuto}; }

struct Problem {
  std::vector<Frame> frames;
  std::vector<Eigen::Isometry3d> poses;
  CandidateSet candidates;
};

std::unique_ptr<Problem> MakeProblem(int num_frames, Eigen::Vector3i frame_size,
                                     double frame_spacing_mm = 0.0) {
  static const Image phantom = [] {
    PhantomOptions p;
    return MakePhantom(p);
  }();
  SimulationOptions o;
  o.num_frames = num_frames;
  o.frame_size = frame_size;
  o.frame_spacing = frame_spacing_mm;
  SimulatedSequence s;
  std::string error;
  if (!Simulate(phantom, o, &s, &error)) {
    std::fprintf(stderr, "%s\n", error.c_str());
    std::abort();
  }
  auto p = std::make_unique<Problem>();
  for (int i = 0; i < num_frames; ++i) p->frames.emplace_back(s.frames[i], s.masks[i]);
  p->poses = RelativeToFrame0(s.frame_from_world);
  ImageGeometry grid;
  if (!BuildPanoramaGrid(p->frames, p->poses, 1.0, &grid, &error)) std::abort();
  p->candidates = BuildCandidates(p->frames, p->poses, grid, 0);
  return p;
}

const Problem& Paper() {
  static const std::unique_ptr<Problem> p = MakeProblem(11, Eigen::Vector3i(96, 96, 80));
  return *p;
}

// One sample of value and gradient (the portable sampler, as in the stream).
void BM_SampleValueAndGradient(benchmark::State& state) {
  const Problem& p = Paper();
  const std::vector<PosedFrame> posed = PoseFrames(p.frames, p.poses);
  std::mt19937 rng(1);
  std::uniform_int_distribution<int64_t> pick(0, p.candidates.num_voxels() - 1);
  std::vector<Eigen::Vector3d> points(4096);
  for (auto& x : points) x = p.candidates.VoxelCenter(pick(rng));
  double out[4];
  double sum = 0.0;
  size_t n = 0;
  for (auto _ : state) {
    const Eigen::Vector3d& x = points[n++ & 4095];
    if (SampleAt(posed[1], x.data(), out)) sum += out[0];
    benchmark::DoNotOptimize(sum);
  }
  state.counters["ns_per_sample"] =
      benchmark::Counter(static_cast<double>(state.iterations()),
                         benchmark::Counter::kIsRate | benchmark::Counter::kInvert);
}
BENCHMARK(BM_SampleValueAndGradient);

void SetObservationCounter(benchmark::State& state, int64_t observations) {
  state.counters["observations"] = static_cast<double>(observations);
  state.counters["ns_per_observation"] = benchmark::Counter(
      static_cast<double>(observations) * state.iterations() * 1e-9,
      benchmark::Counter::kIsRate | benchmark::Counter::kInvert);
}

void BM_DsrEvaluation(benchmark::State& state) {
  const Problem& p = Paper();
  NormalEquations system;
  for (auto _ : state) {
    AccumulateReducedSystem(p.frames, p.candidates, p.poses, 0, p.candidates.num_voxels(),
                            state.range(0) != 0, Threads(state.range(1)), &system);
    benchmark::DoNotOptimize(system.cost);
  }
  SetObservationCounter(state, system.observations);
}
BENCHMARK(BM_DsrEvaluation)
    ->ArgsProduct({{0, 1}, {1, 2}})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

// The same with photometric parameters (8 x 8 blocks per frame pair instead of
// 6 x 6; the target is at most 1.5x BM_DsrEvaluation's time with the same arguments).
// Gains 0.9-1.1 and offsets, so that no multiplication is by 1.
void BM_DsrPhotometricEvaluation(benchmark::State& state) {
  const Problem& p = Paper();
  std::vector<Photometric> photometric(p.frames.size());
  for (size_t i = 1; i < photometric.size(); ++i) {
    photometric[i] = {0.1 * std::sin(static_cast<double>(i)),
                      3.0 * std::cos(static_cast<double>(i))};
  }
  NormalEquations system;
  for (auto _ : state) {
    AccumulateReducedPhotometricSystem(p.frames, p.candidates, p.poses, photometric, 0,
                                       p.candidates.num_voxels(), state.range(0) != 0,
                                       Threads(state.range(1)), &system);
    benchmark::DoNotOptimize(system.cost);
  }
  SetObservationCounter(state, system.observations);
}
BENCHMARK(BM_DsrPhotometricEvaluation)
    ->ArgsProduct({{0, 1}, {1, 2}})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

void BM_ApeEvaluation(benchmark::State& state) {
  const Problem& p = Paper();
  NormalEquations system;
  for (auto _ : state) {
    AccumulateApeSystem(p.frames, p.candidates, p.poses, 0, p.candidates.num_voxels(),
                        state.range(0) != 0, Threads(state.range(1)), &system);
    benchmark::DoNotOptimize(system.cost);
  }
  SetObservationCounter(state, system.observations);
}
BENCHMARK(BM_ApeEvaluation)
    ->ArgsProduct({{0, 1}, {1, 2}})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

// APE with its Gauss-Newton matrix added in DSR's batched form instead of pair by pair (a
// measurement: how much of APE's cost is its pair-by-pair matrix), 2 threads.
void BM_ApeEvaluationBatchedHessian(benchmark::State& state) {
  const Problem& p = Paper();
  NormalEquations system;
  for (auto _ : state) {
    AccumulateApeSystem(p.frames, p.candidates, p.poses, 0, p.candidates.num_voxels(), true,
                        Threads(2), &system, /*batched_hessian=*/true);
    benchmark::DoNotOptimize(system.cost);
  }
  SetObservationCounter(state, system.observations);
}
BENCHMARK(BM_ApeEvaluationBatchedHessian)->Unit(benchmark::kMillisecond)->UseRealTime();

// The batched Gauss-Newton matrix and gradient alone (AddBatchHessian, DSR's weights) on
// one full batch of the sequence (from the middle of its voxels, sampled once; its
// values stand in for residuals), repeated: the group kernels with the batch hot in the
// caches, as the stream runs them right after sampling. Arg: the kernel path.
void BM_GaussNewtonBatch(benchmark::State& state) {
  const KernelPath path = static_cast<KernelPath>(state.range(0));
  if (!KernelPathAvailable(path)) {
    state.SkipWithError("kernel path not available on this CPU");
    return;
  }
  const Problem& p = Paper();
  const std::vector<PosedFrame> posed = PoseFrames(p.frames, p.poses);
  const std::unique_ptr<VoxelBatch> batch(new VoxelBatch);
  const int64_t end = p.candidates.num_voxels();
  SampleVoxelBatch(path, posed, p.candidates, end / 2, end, true, batch.get());
  for (int o = 0; o < batch->num_observations; ++o) batch->residual[o] = batch->value[o];
  HessianWeights weights[kMaxFrames + 1];
  for (int k = 2; k <= kMaxFrames; ++k) weights[k] = {1.0, -1.0 / k};
  const int n = 6 * static_cast<int>(p.frames.size());
  std::vector<double> h(static_cast<size_t>(n) * n, 0.0), g(n, 0.0);
  for (auto _ : state) {
    AddBatchHessian(path, *batch, weights, h.data(), n, g.data());
    benchmark::DoNotOptimize(h.data());
  }
  SetObservationCounter(state, batch->num_observations);
  state.counters["voxels"] = batch->num_voxels;
}
BENCHMARK(BM_GaussNewtonBatch)
    ->Arg(static_cast<int>(KernelPath::kPortable))
    ->Arg(static_cast<int>(KernelPath::kAvx2))
    ->Arg(static_cast<int>(KernelPath::kAvx512))
    ->Unit(benchmark::kMicrosecond);

// DSR with a given kernel path, 2 threads.
void DsrEvaluationOnPath(benchmark::State& state, KernelPath path) {
  if (!KernelPathAvailable(path)) {
    state.SkipWithError("kernel path not available on this CPU");
    return;
  }
  const Problem& p = Paper();
  NormalEquations system;
  for (auto _ : state) {
    AccumulateReducedSystem(p.frames, p.candidates, p.poses, 0, p.candidates.num_voxels(),
                            state.range(0) != 0, StreamContext{2, path}, &system);
    benchmark::DoNotOptimize(system.cost);
  }
  SetObservationCounter(state, system.observations);
}

// The portable kernels (the twin of the SIMD ones).
void BM_DsrEvaluationPortable(benchmark::State& state) {
  DsrEvaluationOnPath(state, KernelPath::kPortable);
}
BENCHMARK(BM_DsrEvaluationPortable)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond)->UseRealTime();

// AVX2 throughout (where the default is the AVX-512 Gauss-Newton kernel, this shows its gain).
void BM_DsrEvaluationAvx2(benchmark::State& state) {
  DsrEvaluationOnPath(state, KernelPath::kAvx2);
}
BENCHMARK(BM_DsrEvaluationAvx2)->Arg(1)->Unit(benchmark::kMillisecond)->UseRealTime();

void BM_DsrEvaluationFrames(benchmark::State& state) {
  const std::unique_ptr<Problem> p =
      MakeProblem(static_cast<int>(state.range(0)), Eigen::Vector3i(96, 96, 80));
  NormalEquations system;
  for (auto _ : state) {
    AccumulateReducedSystem(p->frames, p->candidates, p->poses, 0, p->candidates.num_voxels(),
                            true, Threads(2), &system);
    benchmark::DoNotOptimize(system.cost);
  }
  SetObservationCounter(state, system.observations);
}
BENCHMARK(BM_DsrEvaluationFrames)
    ->DenseRange(3, 11, 2)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

// The clinical size: 11 frames of 176x176x200 at 0.6 mm (target: one evaluation with
// Jacobians under 1.5 s on 2 cores).
const Problem& Clinical() {
  static const std::unique_ptr<Problem> p =
      MakeProblem(11, Eigen::Vector3i(176, 176, 200), 0.6);
  return *p;
}

void BM_DsrEvaluationClinical(benchmark::State& state) {
  const Problem& p = Clinical();
  NormalEquations system;
  for (auto _ : state) {
    AccumulateReducedSystem(p.frames, p.candidates, p.poses, 0, p.candidates.num_voxels(),
                            state.range(0) != 0, Threads(2), &system);
    benchmark::DoNotOptimize(system.cost);
  }
  SetObservationCounter(state, system.observations);
}
BENCHMARK(BM_DsrEvaluationClinical)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond)->UseRealTime();

// Building the candidate set (observers of every panorama voxel) at clinical size.
void BM_BuildCandidatesClinical(benchmark::State& state) {
  const Problem& p = Clinical();
  for (auto _ : state) {
    CandidateSet c = BuildCandidates(p.frames, p.poses, p.candidates.grid, 0);
    benchmark::DoNotOptimize(c.voxel.data());
  }
}
BENCHMARK(BM_BuildCandidatesClinical)->Unit(benchmark::kMillisecond)->UseRealTime();

// The clinical views with `phases` phases each: phase 0 the simulated frame, phase t > 0 the
// same with independent Gaussian noise of the simulator's sigma (25) added, on the one mask.
std::unique_ptr<Problem> ClinicalPhases(int phases) {
  static const SimulatedSequence s = [] {
    PhantomOptions phantom_options;
    SimulationOptions o;
    o.frame_size = Eigen::Vector3i(176, 176, 200);
    o.frame_spacing = 0.6;
    SimulatedSequence out;
    std::string error;
    if (!Simulate(MakePhantom(phantom_options), o, &out, &error)) std::abort();
    return out;
  }();
  auto p = std::make_unique<Problem>();
  std::mt19937_64 rng(7);
  std::normal_distribution<float> noise(0.0f, 25.0f);
  for (size_t i = 0; i < s.frames.size(); ++i) {
    std::vector<Image> views(1, s.frames[i]);
    for (int t = 1; t < phases; ++t) {
      views.push_back(s.frames[i]);
      for (float& v : views.back().voxels) v += noise(rng);
    }
    p->frames.emplace_back(views, s.masks[i]);
  }
  p->poses = RelativeToFrame0(s.frame_from_world);
  p->candidates = Clinical().candidates;
  return p;
}

// One evaluation of DSR's tied problem (every phase's chunk costs over the views' pose
// blocks; Ceres sums them) with the gradient, 2 threads. Counters: the phases, the
// observations per phase and the frames' MiB per phase (the time per phase: Time / phases).
void BM_DsrTiedEvaluationClinical(benchmark::State& state) {
  const int phases = static_cast<int>(state.range(0));
  const std::unique_ptr<Problem> p = ClinicalPhases(phases);
  DsrOptions options;
  options.solve.num_threads = 2;
  DsrProblem dsr(p->frames, p->candidates, p->poses, options);
  std::vector<double> gradient;
  double cost = 0.0;
  for (auto _ : state) {
    dsr.problem().Evaluate(ceres::Problem::EvaluateOptions(), &cost, nullptr, &gradient, nullptr);
    benchmark::DoNotOptimize(cost);
  }
  const int64_t voxels = p->frames.size() * p->frames[0].geometry().NumVoxels();
  state.counters["phases"] = phases;  // the time per phase: Time / phases
  state.counters["observations_per_phase"] =
      static_cast<double>(dsr.LastObservations()) / phases;
  state.counters["frame_MiB_per_phase"] = 16.0 * voxels / 1048576.0;
}
BENCHMARK(BM_DsrTiedEvaluationClinical)->Arg(1)->Arg(2)->Arg(4)->Unit(benchmark::kMillisecond)
    ->UseRealTime()->Iterations(3);

// DSR and DBA evaluations with Jacobians of the same small problem.
const Problem& Small() {
  static const std::unique_ptr<Problem> p = MakeProblem(6, Eigen::Vector3i(48, 48, 40));
  return *p;
}

void BM_DbaEvaluation(benchmark::State& state) {
  const Problem& p = Small();
  DbaProblem dba(p.frames, p.candidates, p.poses);
  double cost = 0.0;
  std::vector<double> residuals;
  ceres::CRSMatrix jacobian;
  ceres::Problem::EvaluateOptions evaluate;
  evaluate.num_threads = 2;
  for (auto _ : state) {
    dba.problem().Evaluate(evaluate, &cost, &residuals, nullptr, &jacobian);
    benchmark::DoNotOptimize(cost);
  }
  NormalEquations counts;
  AccumulateReducedSystem(p.frames, p.candidates, p.poses, 0, p.candidates.num_voxels(), false,
                          Threads(2), &counts);
  SetObservationCounter(state, counts.observations);
}
BENCHMARK(BM_DbaEvaluation)->Unit(benchmark::kMillisecond)->UseRealTime();

void BM_DsrEvaluationSmall(benchmark::State& state) {
  const Problem& p = Small();
  NormalEquations system;
  for (auto _ : state) {
    AccumulateReducedSystem(p.frames, p.candidates, p.poses, 0, p.candidates.num_voxels(), true,
                            Threads(2), &system);
    benchmark::DoNotOptimize(system.cost);
  }
  SetObservationCounter(state, system.observations);
}
BENCHMARK(BM_DsrEvaluationSmall)->Unit(benchmark::kMillisecond)->UseRealTime();

}  // namespace
}  // namespace dsr

BENCHMARK_MAIN();
