// The paper's simulation protocol (docs/design.md section 6); conventions in simulate.h.
#include "dsr/sim/simulate.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <initializer_list>
#include <limits>
#include <random>
#include <sstream>
#include <string>

#include <glog/logging.h>

#include "dsr/image/frame.h"
#include "dsr/sim/echo_artifacts.h"
#include "dsr/sim/echo_mapping.h"
#include "dsr/util/clock.h"
#include "dsr/util/option_fields.h"
#include "dsr/util/parallel.h"

namespace dsr {
namespace {

constexpr int kMaxFrames = 1000;
constexpr int kMaxFrameSize = 2048;

constexpr int kMaxMaskErosion = 50;

// Bisection steps that clamp a walk's rotation step to the Euler-angle box: 2^-50 of a step.
constexpr int kClampBisections = 50;
// Rounding slack of the Euler-angle box test: angles recomputed from a rotation matrix that
// was built from in-box angles may exceed the bound by a few ulps.
constexpr double kEulerSlack = 1e-12;

// Ranges of the ultrasound-like effects (simulate.h).
constexpr double kMaxGainRange = 0.9;  // keeps every gain >= 0.1
constexpr double kMaxOffsetRange = 100.0;
constexpr int kMaxSpeckleLooks = 64;
constexpr double kMaxSpeckleCorrelation = 4.0;
constexpr double kMaxAttenuationDbPerCm = 10.0;
// Ranges of the echo-like mapping (simulate.h). The reject stays below full scale so that
// the tissue term's 255 - r is at least 5 grey levels; 20 mm of smoothing already blurs
// every structure the simulator's sources have.
constexpr double kMaxEchoReject = 250.0;
constexpr double kMaxEchoEdgeSigmaMm = 20.0;
// Largest world speckle grid per axis, in voxels: far beyond any grid that fits in memory,
// it only keeps the index arithmetic in int.
constexpr int64_t kMaxSpeckleWorldSize = int64_t{1} << 24;

// The speckle kernel is cut at this many standard deviations. The cut weights would carry
// < 1e-4 of the kernel's squared sum; the kept ones are rescaled to a unit squared sum, so
// the speckle's mean stays exactly 1 and the cut only trims the far tail of its
// correlation.
constexpr double kSpeckleKernelSigmas = 3.0;

// Tags of the effects' random streams (ASCII "gain_off", "speckle_", "speckleW"). Fixed for
// good: they decide every seed's gains, offsets and speckle.
constexpr uint64_t kGainOffsetStream = 0x6761696e5f6f6666ull;
constexpr uint64_t kSpeckleStream = 0x737065636b6c655full;
constexpr uint64_t kSpeckleWorldStream = 0x737065636b6c6557ull;
// The beating source's later phases (ASCII "phase_no", "speckleP"): each phase's noise and
// per-frame speckle part.
constexpr uint64_t kPhaseNoiseStream = 0x70686173655f6e6full;
constexpr uint64_t kSpecklePhaseStream = 0x737065636b6c6550ull;

// The lateral point-spread function's largest standard deviation (simulate.h), mm.
constexpr double kMaxPsfLateralMm = 20.0;
// The dropouts' random stream (ASCII "dropout_"; echo_artifacts.h).
constexpr uint64_t kDropoutStream = 0x64726f706f75745full;

// Ranges of the beating source (simulate.h).
constexpr int kMaxPhases = 64;
constexpr double kMaxBeatAmplitudeMm = 50.0;
constexpr double kMinBeatRadiusMm = 1e-3;
constexpr double kMaxBeatRadiusMm = 1e6;
// kappa = sqrt(7) (7/6)^3: 1 / max over rho in [0, 1] of rho (1 - rho^2)^3 (at 1/sqrt(7)).
const double kBeatKappa = std::sqrt(7.0) * (343.0 / 216.0);

// SplitMix64's output function: a bijection of 64-bit words in which every input bit
// changes about half the output bits, so that neighbouring seeds and indices give unrelated
// generator seeds.
uint64_t Mix64(uint64_t x) {
  x += 0x9e3779b97f4a7c15ull;
  x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ull;
  x = (x ^ (x >> 27)) * 0x94d049bb133111ebull;
  return x ^ (x >> 31);
}

// The seed of one effect's generator: the run's seed, the effect's tag and the indices
// (frame, look, slice, ...) folded in one after the other. Independent of the
// poses-and-noise generator, which is seeded with `seed` itself.
uint64_t StreamSeed(uint64_t seed, uint64_t tag, std::initializer_list<uint64_t> indices) {
  uint64_t h = Mix64(seed ^ Mix64(tag));
  for (uint64_t index : indices) h = Mix64(h ^ Mix64(index));
  return h;
}

// The generator seed of one padded slice k of look `look` of frame `frame_index`'s per-frame
// speckle: the still frame's stream for phase 0, a stream of its own for each later phase.
uint64_t FrameSpeckleSeed(uint64_t seed, int frame_index, int phase, int look, int64_t k) {
  const uint64_t f = static_cast<uint64_t>(frame_index), l = static_cast<uint64_t>(look);
  const uint64_t slice = static_cast<uint64_t>(k);
  return phase == 0
             ? StreamSeed(seed, kSpeckleStream, {f, l, slice})
             : StreamSeed(seed, kSpecklePhaseStream, {f, static_cast<uint64_t>(phase), l, slice});
}

// Whether phase `phase` of a sequence with `beat` moves anything.
bool Moves(const BeatRegion* beat, int phase) {
  return beat != nullptr && phase > 0 && beat->amplitude_mm > 0.0;
}

// Translate(c_f) * R * Translate(t - c_s).
Eigen::Isometry3d FrameFromWorld(const Eigen::Matrix3d& rotation,
                                 const Eigen::Vector3d& shift_mm,
                                 const Eigen::Vector3d& frame_center,
                                 const Eigen::Vector3d& source_center) {
  Eigen::Isometry3d frame_from_world = Eigen::Isometry3d::Identity();
  frame_from_world.linear() = rotation;
  frame_from_world.translation() = frame_center + rotation * (shift_mm - source_center);
  return frame_from_world;
}

// Whether R = Rz(gamma) Ry(beta) Rx(alpha) for some angles all within [-max, max]. The
// principal angles (beta in [-pi/2, pi/2]) and their only alternative
// (alpha +- pi, pi - beta, gamma +- pi) are both tried, so bounds >= 90 degrees work too.
bool InEulerBox(const Eigen::Matrix3d& r, double max_angle) {
  const double beta = -std::asin(std::clamp(r(2, 0), -1.0, 1.0));
  const double alpha = std::atan2(r(2, 1), r(2, 2));
  const double gamma = std::atan2(r(1, 0), r(0, 0));
  const double bound = max_angle + kEulerSlack;
  auto in = [bound](double a, double b, double g) {
    return std::abs(a) <= bound && std::abs(b) <= bound && std::abs(g) <= bound;
  };
  auto flip = [](double angle) { return angle > 0.0 ? angle - M_PI : angle + M_PI; };
  return in(alpha, beta, gamma) ||
         in(flip(alpha), (beta >= 0.0 ? M_PI : -M_PI) - beta, flip(gamma));
}

// A unit vector uniform on the sphere from two draws: z = u, azimuth = pi u.
Eigen::Vector3d DrawDirection(std::uniform_real_distribution<double>* u, std::mt19937_64* rng) {
  const double z = (*u)(*rng);
  const double azimuth = M_PI * (*u)(*rng);
  const double rho = std::sqrt(std::max(0.0, 1.0 - z * z));
  return Eigen::Vector3d(rho * std::cos(azimuth), rho * std::sin(azimuth), z);
}

std::vector<Eigen::Isometry3d> DrawPoses(const ImageGeometry& source,
                                         const ImageGeometry& frame,
                                         const SimulationOptions& o,
                                         std::mt19937_64* rng) {
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  const Eigen::Vector3d source_center =
      source.IndexToPhysical(0.5 * (source.size.cast<double>() - Eigen::Vector3d::Ones()));
  const Eigen::Vector3d frame_center =
      frame.IndexToPhysical(0.5 * (frame.size.cast<double>() - Eigen::Vector3d::Ones()));
  const double max_angle = o.max_rotation_deg * M_PI / 180.0;
  const double max_shift_mm = o.max_translation_voxels * frame.spacing_mm[0];
  const double step_angle = o.step_rotation_deg * M_PI / 180.0;
  const double step_shift_mm = o.step_translation_voxels * frame.spacing_mm[0];
  std::vector<Eigen::Isometry3d> poses;
  // The current frame's R and t (frame 0 draws them; the walk steps from them).
  Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();
  Eigen::Vector3d shift_mm = Eigen::Vector3d::Zero();
  for (int f = 0; f < o.num_frames; ++f) {
    if (f == 0 || o.pose_model == PoseModel::kRandom) {
      // Sequenced draws (argument evaluation order is unspecified in C++).
      const double alpha = max_angle * u(*rng);
      const double beta = max_angle * u(*rng);
      const double gamma = max_angle * u(*rng);
      for (int a = 0; a < 3; ++a) shift_mm[a] = max_shift_mm * u(*rng);
      rotation = (Eigen::AngleAxisd(gamma, Eigen::Vector3d::UnitZ()) *
                  Eigen::AngleAxisd(beta, Eigen::Vector3d::UnitY()) *
                  Eigen::AngleAxisd(alpha, Eigen::Vector3d::UnitX()))
                     .toRotationMatrix();
    } else {
      const Eigen::Vector3d axis = DrawDirection(&u, rng);
      const double angle = step_angle * 0.5 * (1.0 + u(*rng));
      const Eigen::Vector3d direction = DrawDirection(&u, rng);
      const double length_mm = step_shift_mm * 0.5 * (1.0 + u(*rng));
      // R_i = R_{i-1} Q^T: Q acts on world_from_frame = R^T about the point the frame
      // centre sees (c_s - t), which the rotation leaves where it is.
      auto stepped = [&](double theta) {
        return Eigen::Matrix3d(rotation * Eigen::AngleAxisd(-theta, axis).toRotationMatrix());
      };
      double inside = angle;
      if (!InEulerBox(stepped(angle), max_angle)) {
        // theta = 0 (the previous rotation) is inside the box; keep the inside end.
        double lo = 0.0, hi = angle;
        for (int i = 0; i < kClampBisections; ++i) {
          const double mid = 0.5 * (lo + hi);
          (InEulerBox(stepped(mid), max_angle) ? lo : hi) = mid;
        }
        inside = lo;
      }
      rotation = stepped(inside);
      // t_i = t_{i-1} - d, clamped per axis to the box (moves each component towards the
      // previous, in-box value, so |t_i - t_{i-1}| <= |d|).
      shift_mm = (shift_mm - length_mm * direction).cwiseMax(-max_shift_mm).cwiseMin(max_shift_mm);
    }
    poses.push_back(FrameFromWorld(rotation, shift_mm, frame_center, source_center));
  }
  return poses;
}

// Keys' cubic convolution weights (a = -0.5) of the taps at offsets -1, 0, 1, 2 from
// floor(x), for t = x - floor(x) in [0, 1) (simulate.h).
void KeysWeights(double t, double w[4]) {
  const double t2 = t * t, t3 = t2 * t;
  w[0] = 0.5 * (-t3 + 2.0 * t2 - t);
  w[1] = 0.5 * (3.0 * t3 - 5.0 * t2 + 2.0);
  w[2] = 0.5 * (-3.0 * t3 + 4.0 * t2 + t);
  w[3] = 0.5 * (t3 - t2);
}

// The speckle's 1-D kernel: weights exp(-d^2 / (2 c^2)), |d| <= radius = ceil(3 c), scaled
// to sum w_d^2 = 1. The 3-D kernel (their product) then has a unit squared sum, so a
// smoothed unit-variance white field keeps its variance, E|z|^2 = 2 with N(0, 1) real and
// imaginary parts (c = 0: the single weight 1, no smoothing).
std::vector<double> SpeckleKernel(double c) {
  const int radius = static_cast<int>(std::ceil(kSpeckleKernelSigmas * c));
  const int taps = 2 * radius + 1;
  std::vector<double> w(taps, 1.0);
  if (radius > 0) {
    double squares = 0.0;
    for (int t = 0; t < taps; ++t) {
      const double d = t - radius;
      w[t] = std::exp(-d * d / (2.0 * c * c));
      squares += w[t] * w[t];
    }
    for (double& weight : w) weight /= std::sqrt(squares);
  }
  return w;
}

// Scratch of one frame look's smoothing (complex, interleaved [re, im], x fastest), reused
// over looks and frames.
struct FrameLookScratch {
  std::vector<double> white;    // the padded grid
  std::vector<double> along_x;  // x smoothed: n_x by the padded y and z
  std::vector<double> along_y;  // x and y smoothed: n_x n_y by the padded z
};

// Look `look` of frame `frame_index`'s per-frame complex field (of phase `phase`: seeds by
// FrameSpeckleSeed) on the frame grid `g`: white
// N(0, 1) components drawn on g padded by the kernel radius on every side (one generator
// per padded slice, its re and im draws in voxel order, so the draws do not depend on which
// thread takes the slice), then the three separable passes of `w`, each dropping the
// padding of one axis, so that every frame voxel sees the whole kernel. The last pass hands
// each frame voxel's smoothed value to add(k, j, i, re, im), in parallel over k: `add`
// must write only voxel (i, j, k)'s outputs.
template <typename Add>
void FrameSpeckleLook(const ImageGeometry& g,
                      const std::vector<double>& w,
                      uint64_t seed,
                      int frame_index,
                      int phase,
                      int look,
                      int num_threads,
                      FrameLookScratch* scratch,
                      const Add& add) {
  const int taps = static_cast<int>(w.size());
  const int radius = taps / 2;
  const Eigen::Vector3i& n = g.size;
  const Eigen::Vector3i p = n + Eigen::Vector3i::Constant(2 * radius);
  const int64_t p_slice = int64_t{p[0]} * p[1];
  std::vector<double>& white = scratch->white;
  std::vector<double>& along_x = scratch->along_x;
  std::vector<double>& along_y = scratch->along_y;
  white.resize(2 * p_slice * p[2]);
  along_x.resize(2 * int64_t{n[0]} * p[1] * p[2]);
  along_y.resize(2 * int64_t{n[0]} * n[1] * p[2]);
  ParallelFor(0, p[2], num_threads, [&](int64_t k) {
    std::mt19937_64 rng(FrameSpeckleSeed(seed, frame_index, phase, look, k));
    // Each component N(0, 1): |z|^2 / 2 then has mean 1 after the unit-norm kernel.
    std::normal_distribution<double> normal(0.0, 1.0);
    double* slice = white.data() + 2 * k * p_slice;
    for (int64_t v = 0; v < 2 * p_slice; ++v) slice[v] = normal(rng);
  });
  ParallelFor(0, p[2], num_threads, [&](int64_t k) {
    for (int j = 0; j < p[1]; ++j) {
      const double* in = white.data() + 2 * (k * p_slice + int64_t{j} * p[0]);
      double* out = along_x.data() + 2 * ((k * p[1] + j) * int64_t{n[0]});
      for (int i = 0; i < n[0]; ++i) {
        double re = 0.0, im = 0.0;
        for (int t = 0; t < taps; ++t) {
          re += w[t] * in[2 * (i + t)];
          im += w[t] * in[2 * (i + t) + 1];
        }
        out[2 * i] = re;
        out[2 * i + 1] = im;
      }
    }
  });
  ParallelFor(0, p[2], num_threads, [&](int64_t k) {
    for (int j = 0; j < n[1]; ++j) {
      double* out = along_y.data() + 2 * ((k * n[1] + j) * int64_t{n[0]});
      for (int i = 0; i < n[0]; ++i) {
        double re = 0.0, im = 0.0;
        for (int t = 0; t < taps; ++t) {
          const int64_t in = 2 * ((k * p[1] + j + t) * int64_t{n[0]} + i);
          re += w[t] * along_x[in];
          im += w[t] * along_x[in + 1];
        }
        out[2 * i] = re;
        out[2 * i + 1] = im;
      }
    }
  });
  ParallelFor(0, n[2], num_threads, [&](int64_t k) {
    for (int j = 0; j < n[1]; ++j) {
      for (int i = 0; i < n[0]; ++i) {
        double re = 0.0, im = 0.0;
        for (int t = 0; t < taps; ++t) {
          const int64_t in = 2 * (((k + t) * n[1] + j) * int64_t{n[0]} + i);
          re += w[t] * along_y[in];
          im += w[t] * along_y[in + 1];
        }
        add(k, j, i, re, im);
      }
    }
  });
}

// Look `look`'s world-fixed complex field on a world grid of `size` voxels, in `field`
// (resized; interleaved [re, im]): white N(0, 1) components drawn on the grid padded by the
// kernel radius R on every side (one generator per padded slice k, seeded from (seed,
// "speckleW", look, k), draws in voxel order), then smoothed in place by the three
// separable passes of `w`. The field keeps the padded strides: world voxel (i, j, k) is at
// 2 (i + p_x (j + p_y k)), p = size + 2R. In place is safe because output i of a line reads
// inputs i .. i + 2R only and the lines are walked upwards: the x and y passes own a slice
// each, the z pass a row j through every slice.
void WorldSpeckleLook(const Eigen::Vector3i& size,
                      const std::vector<double>& w,
                      uint64_t seed,
                      int look,
                      int num_threads,
                      std::vector<double>* field) {
  const int taps = static_cast<int>(w.size());
  const int radius = taps / 2;
  const Eigen::Vector3i p = size + Eigen::Vector3i::Constant(2 * radius);
  const int64_t p_slice = int64_t{p[0]} * p[1];
  field->resize(2 * p_slice * p[2]);
  double* z = field->data();
  ParallelFor(0, p[2], num_threads, [&](int64_t k) {
    std::mt19937_64 rng(StreamSeed(
        seed, kSpeckleWorldStream, {static_cast<uint64_t>(look), static_cast<uint64_t>(k)}));
    std::normal_distribution<double> normal(0.0, 1.0);
    double* slice = z + 2 * k * p_slice;
    for (int64_t v = 0; v < 2 * p_slice; ++v) slice[v] = normal(rng);
  });
  if (radius == 0) return;  // c = 0: white
  ParallelFor(0, p[2], num_threads, [&](int64_t k) {
    for (int j = 0; j < p[1]; ++j) {
      double* line = z + 2 * (k * p_slice + int64_t{j} * p[0]);
      for (int i = 0; i < size[0]; ++i) {
        double re = 0.0, im = 0.0;
        for (int t = 0; t < taps; ++t) {
          re += w[t] * line[2 * (i + t)];
          im += w[t] * line[2 * (i + t) + 1];
        }
        line[2 * i] = re;
        line[2 * i + 1] = im;
      }
    }
  });
  const int64_t row = 2 * int64_t{p[0]};  // doubles per padded row
  ParallelFor(0, p[2], num_threads, [&](int64_t k) {
    double* slice = z + 2 * k * p_slice;
    for (int j = 0; j < size[1]; ++j) {
      for (int i = 0; i < size[0]; ++i) {
        double re = 0.0, im = 0.0;
        for (int t = 0; t < taps; ++t) {
          const double* in = slice + (j + t) * row + 2 * i;
          re += w[t] * in[0];
          im += w[t] * in[1];
        }
        slice[j * row + 2 * i] = re;
        slice[j * row + 2 * i + 1] = im;
      }
    }
  });
  ParallelFor(0, size[1], num_threads, [&](int64_t j) {
    for (int k = 0; k < size[2]; ++k) {
      for (int i = 0; i < size[0]; ++i) {
        double re = 0.0, im = 0.0;
        for (int t = 0; t < taps; ++t) {
          const double* in = z + 2 * ((k + t) * p_slice + j * p[0] + i);
          re += w[t] * in[0];
          im += w[t] * in[1];
        }
        double* out = z + 2 * (k * p_slice + j * p[0] + i);
        out[0] = re;
        out[1] = im;
      }
    }
  });
}

// The world field of one look sampled at a continuous world-grid index u: the trilinear
// interpolant divided by the root of its variance factor, so that it has the variance of a
// grid value (SpeckleFields in simulate.h). Per axis the factor is
// (1 - t)^2 + t^2 + 2 t (1 - t) r1 = 1 - 2 t (1 - t) (1 - r1). An index off the grid (by
// rounding only: the grid holds every field-of-view voxel) reads the nearest border point.
struct WorldLookSampler {
  const double* field = nullptr;  // WorldSpeckleLook's layout
  Eigen::Vector3i size;           // the world grid's
  int64_t stride_y = 0;           // complex values per padded row
  int64_t stride_z = 0;           // complex values per padded slice
  double neighbour_correlation = 0.0;  // r1 = sum_d w_d w_d+1

  void Sample(const Eigen::Vector3d& u, double* re, double* im) const {
    int lower[3];
    double t[3];
    int64_t step[3];
    double variance = 1.0;
    for (int a = 0; a < 3; ++a) {
      const double x = std::clamp(u[a], 0.0, static_cast<double>(size[a] - 1));
      lower[a] = std::min(static_cast<int>(x), std::max(size[a] - 2, 0));
      t[a] = x - lower[a];
      step[a] = lower[a] + 1 < size[a] ? 1 : 0;
      variance *= 1.0 - 2.0 * t[a] * (1.0 - t[a]) * (1.0 - neighbour_correlation);
    }
    // Offsets in doubles ([re, im] interleaved) of the upper neighbour along each axis.
    const int64_t sx = 2 * step[0], sy = 2 * step[1] * stride_y, sz = 2 * step[2] * stride_z;
    const double* base = field + 2 * (lower[0] + lower[1] * stride_y + lower[2] * stride_z);
    const auto lerp = [](double a, double b, double s) { return a + s * (b - a); };
    double value[2];
    for (int part = 0; part < 2; ++part) {
      const double* c = base + part;
      const double x00 = lerp(c[0], c[sx], t[0]);
      const double x10 = lerp(c[sy], c[sy + sx], t[0]);
      const double x01 = lerp(c[sz], c[sz + sx], t[0]);
      const double x11 = lerp(c[sz + sy], c[sz + sy + sx], t[0]);
      value[part] = lerp(lerp(x00, x10, t[1]), lerp(x01, x11, t[1]), t[2]);
    }
    const double scale = 1.0 / std::sqrt(variance);
    *re = value[0] * scale;
    *im = value[1] * scale;
  }
};

}  // namespace

const char* SourceInterpolationToString(SourceInterpolation interpolation) {
  switch (interpolation) {
    case SourceInterpolation::kLinear:
      return "linear";
    case SourceInterpolation::kCubic:
      return "cubic";
  }
  return "";
}

bool StringToSourceInterpolation(const std::string& text, SourceInterpolation* interpolation) {
  CHECK(interpolation != nullptr);
  return FindNamed(text, {SourceInterpolation::kLinear, SourceInterpolation::kCubic},
                   SourceInterpolationToString, interpolation);
}

double CubicInterpolateValue(const Image& image, const Eigen::Vector3d& ijk) {
  CHECK(ijk.allFinite()) << ijk.transpose();
  CHECK(!image.empty());
  const Eigen::Vector3i& n = image.geometry.size;
  // Per axis: the 4 clamped tap indices and their weights.
  int index[3][4];
  double weight[3][4];
  for (int a = 0; a < 3; ++a) {
    // Clamping x first keeps the int conversion defined; it moves no tap of an x inside
    // the grid.
    const double x = std::clamp(ijk[a], -1.0, static_cast<double>(n[a]));
    const double lower = std::floor(x);
    KeysWeights(x - lower, weight[a]);
    for (int tap = 0; tap < 4; ++tap) {
      index[a][tap] = std::clamp(static_cast<int>(lower) - 1 + tap, 0, n[a] - 1);
    }
  }
  double value = 0.0;
  for (int tk = 0; tk < 4; ++tk) {
    double plane = 0.0;
    for (int tj = 0; tj < 4; ++tj) {
      double row = 0.0;
      for (int ti = 0; ti < 4; ++ti) {
        row += weight[0][ti] * image.at(index[0][ti], index[1][tj], index[2][tk]);
      }
      plane += weight[1][tj] * row;
    }
    value += weight[2][tk] * plane;
  }
  return value;
}

const char* IntensityMappingToString(IntensityMapping mapping) {
  switch (mapping) {
    case IntensityMapping::kNone:
      return "none";
    case IntensityMapping::kEcho:
      return "echo";
  }
  return "";
}

bool StringToIntensityMapping(const std::string& text, IntensityMapping* mapping) {
  CHECK(mapping != nullptr);
  return FindNamed(text, {IntensityMapping::kNone, IntensityMapping::kEcho},
                   IntensityMappingToString, mapping);
}

const char* PoseModelToString(PoseModel model) {
  switch (model) {
    case PoseModel::kRandom:
      return "random";
    case PoseModel::kWalk:
      return "walk";
  }
  return "";
}

bool StringToPoseModel(const std::string& text, PoseModel* model) {
  CHECK(model != nullptr);
  return FindNamed(text, {PoseModel::kRandom, PoseModel::kWalk}, PoseModelToString, model);
}

bool SimulationOptions::Validate(std::string* error) const {
  std::ostringstream s;
  auto range = [](double v, double lo, double hi) {
    return std::isfinite(v) && v >= lo && v <= hi;
  };
  if (num_frames < 2 || num_frames > kMaxFrames) {
    s << "num_frames=" << num_frames << ": must be in [2, " << kMaxFrames << "]";
  } else if (!range(max_rotation_deg, 0.0, 180.0)) {
    s << "max_rotation_deg=" << max_rotation_deg << ": must be in [0, 180]";
  } else if (!range(max_translation_voxels, 0.0, std::numeric_limits<double>::max())) {
    s << "max_translation_voxels=" << max_translation_voxels << ": must be finite and >= 0";
  } else if (*PoseModelToString(pose_model) == '\0') {
    s << "pose_model=" << static_cast<int>(pose_model) << ": must be random or walk";
  } else if (!range(step_rotation_deg, 0.0, 180.0)) {
    s << "step_rotation_deg=" << step_rotation_deg << ": must be in [0, 180]";
  } else if (!range(step_translation_voxels, 0.0, std::numeric_limits<double>::max())) {
    s << "step_translation_voxels=" << step_translation_voxels << ": must be finite and >= 0";
  } else if (!range(sigma, 0.0, std::numeric_limits<double>::max())) {
    s << "sigma=" << sigma << ": must be finite and >= 0";
  } else if ((frame_size.array() < 4).any() || (frame_size.array() > kMaxFrameSize).any()) {
    s << "frame_size=" << frame_size[0] << "," << frame_size[1] << "," << frame_size[2]
      << ": every size must be in [4, " << kMaxFrameSize << "]";
  } else if (!range(frame_spacing, 0.0, std::numeric_limits<double>::max())) {
    s << "frame_spacing=" << frame_spacing << ": must be finite and >= 0 (0 = source spacing)";
  } else if (!(std::isfinite(azimuth_deg) && azimuth_deg > 0.0 && azimuth_deg < 180.0)) {
    s << "azimuth_deg=" << azimuth_deg << ": must be in (0, 180)";
  } else if (!(std::isfinite(elevation_deg) && elevation_deg > 0.0 && elevation_deg < 180.0)) {
    s << "elevation_deg=" << elevation_deg << ": must be in (0, 180)";
  } else if (std::isfinite(min_depth_voxels) && min_depth_voxels >= 0.0 &&
             min_depth_voxels > frame_size[2] - 3.0) {
    // A depth the frame cannot hold: the frame may be too thin as well as the cut too deep.
    s << "frame_size=" << frame_size[0] << "," << frame_size[1] << "," << frame_size[2]
      << ": a frame depth of " << frame_size[2] << " leaves no field of view below "
      << "min_depth_voxels=" << min_depth_voxels << " (the depth must be at least "
      << "min_depth_voxels + 3 = " << min_depth_voxels + 3.0 << ")";
  } else if (!range(min_depth_voxels, 0.0, frame_size[2] - 3.0)) {
    s << "min_depth_voxels=" << min_depth_voxels
      << ": must be in [0, frame depth - 3 = " << frame_size[2] - 3 << "]";
  } else if (mask_erosion < 0 || mask_erosion > kMaxMaskErosion) {
    s << "mask_erosion=" << mask_erosion << ": must be in [0, " << kMaxMaskErosion
      << "]";
  } else if (*SourceInterpolationToString(interpolation) == '\0') {
    s << "interpolation=" << static_cast<int>(interpolation) << ": must be linear or cubic";
  } else if (!range(gain_range, 0.0, kMaxGainRange)) {
    s << "gain_range=" << gain_range << ": must be in [0, " << kMaxGainRange << "]";
  } else if (!range(offset_range, 0.0, kMaxOffsetRange)) {
    s << "offset_range=" << offset_range << ": must be in [0, " << kMaxOffsetRange << "]";
  } else if (speckle_looks < 0 || speckle_looks > kMaxSpeckleLooks) {
    s << "speckle_looks=" << speckle_looks << ": must be 0 (no speckle) or in [1, "
      << kMaxSpeckleLooks << "]";
  } else if (!range(speckle_correlation_voxels, 0.0, kMaxSpeckleCorrelation)) {
    s << "speckle_correlation_voxels=" << speckle_correlation_voxels << ": must be in [0, "
      << kMaxSpeckleCorrelation << "]";
  } else if (!range(speckle_world_fraction, 0.0, 1.0)) {
    s << "speckle_world_fraction=" << speckle_world_fraction << ": must be in [0, 1]";
  } else if (speckle_world_fraction > 0.0 && speckle_looks == 0) {
    s << "speckle_world_fraction=" << speckle_world_fraction
      << ": needs speckle, but speckle_looks=0";
  } else if (!range(attenuation_db_per_cm, 0.0, kMaxAttenuationDbPerCm)) {
    s << "attenuation_db_per_cm=" << attenuation_db_per_cm << ": must be in [0, "
      << kMaxAttenuationDbPerCm << "]";
  } else if (*IntensityMappingToString(intensity_mapping) == '\0') {
    s << "intensity_mapping=" << static_cast<int>(intensity_mapping)
      << ": must be none or echo";
  } else if (!range(echo_reject, 0.0, kMaxEchoReject)) {
    s << "echo_reject=" << echo_reject << ": must be in [0, " << kMaxEchoReject << "]";
  } else if (!range(echo_edge_sigma_mm, 0.0, kMaxEchoEdgeSigmaMm)) {
    s << "echo_edge_sigma_mm=" << echo_edge_sigma_mm << ": must be in [0, "
      << kMaxEchoEdgeSigmaMm << "]";
  } else if (!range(echo_edge_weight, 0.0, 1.0)) {
    s << "echo_edge_weight=" << echo_edge_weight << ": must be in [0, 1]";
  } else if (!range(echogenicity_range, 0.0, 0.9)) {
    s << "echogenicity_range=" << echogenicity_range << ": must be in [0, 0.9]";
  } else if (!range(shadow_strength, 0.0, 1.0)) {
    s << "shadow_strength=" << shadow_strength << ": must be in [0, 1]";
  } else if (!range(shadow_threshold, 0.0, kMaxEchoReject)) {
    s << "shadow_threshold=" << shadow_threshold << ": must be in [0, " << kMaxEchoReject << "]";
  } else if (!range(psf_lateral_mm, 0.0, kMaxPsfLateralMm)) {
    s << "psf_lateral_mm=" << psf_lateral_mm << ": must be in [0, " << kMaxPsfLateralMm << "]";
  } else if (!range(dropout_fraction, 0.0, 0.9)) {
    s << "dropout_fraction=" << dropout_fraction << ": must be in [0, 0.9]";
  } else if (!range(dropout_view_fraction, 0.0, 1.0)) {
    s << "dropout_view_fraction=" << dropout_view_fraction << ": must be in [0, 1]";
  } else if (num_phases < 1 || num_phases > kMaxPhases) {
    s << "num_phases=" << num_phases << ": must be in [1, " << kMaxPhases << "]";
  } else if (!range(beat_amplitude_mm, 0.0, kMaxBeatAmplitudeMm)) {
    s << "beat_amplitude_mm=" << beat_amplitude_mm << ": must be in [0, " << kMaxBeatAmplitudeMm
      << "]";
  } else if (!(beat_radius_mm == 0.0 ||
               range(beat_radius_mm, kMinBeatRadiusMm, kMaxBeatRadiusMm))) {
    s << "beat_radius_mm=" << beat_radius_mm << ": must be 0 (a quarter of the frame depth) or in ["
      << kMinBeatRadiusMm << ", " << kMaxBeatRadiusMm << "]";
  } else if (!beat_center_offset_mm.allFinite()) {
    s << "beat_center_offset_mm=" << beat_center_offset_mm[0] << "," << beat_center_offset_mm[1]
      << "," << beat_center_offset_mm[2] << ": must be finite";
  } else if (num_phases > 1 && beat_radius_mm > 0.0 &&
             beat_amplitude_mm > kMaxBeatAmplitudeRatio * beat_radius_mm) {
    s << "beat_amplitude_mm=" << beat_amplitude_mm << ": must be at most "
      << kMaxBeatAmplitudeRatio << " beat_radius_mm=" << beat_radius_mm
      << " (a larger beat would fold the tissue)";
  } else {
    return true;
  }
  if (error != nullptr) *error = s.str();
  return false;
}

BeatRegion SimulatedBeatRegion(const ImageGeometry& source, const SimulationOptions& o) {
  BeatRegion region;
  region.center_mm =
      source.IndexToPhysical(0.5 * (source.size.cast<double>() - Eigen::Vector3d::Ones())) +
      o.beat_center_offset_mm;
  region.radius_mm = o.beat_radius_mm > 0.0
                         ? o.beat_radius_mm
                         : 0.25 * o.frame_size[2] * SimulatedFrameGeometry(source, o).spacing_mm[0];
  region.amplitude_mm = o.beat_amplitude_mm;
  return region;
}

double BeatCycleWeight(double t) { return 0.5 * (1.0 - std::cos(2.0 * M_PI * t)); }

Eigen::Vector3d BeatDisplacement(const BeatRegion& region, double t, const Eigen::Vector3d& x_mm) {
  const Eigen::Vector3d r = x_mm - region.center_mm;
  const double rho2 = r.squaredNorm() / (region.radius_mm * region.radius_mm);
  if (rho2 >= 1.0) return Eigen::Vector3d::Zero();
  const double q = (1.0 - rho2) * (1.0 - rho2) * (1.0 - rho2);
  const double beta = region.amplitude_mm * BeatCycleWeight(t) * kBeatKappa / region.radius_mm;
  return -beta * q * r;
}

Eigen::Matrix3d BeatPullbackJacobian(const BeatRegion& region, double t,
                                     const Eigen::Vector3d& x_mm) {
  const Eigen::Vector3d r = x_mm - region.center_mm;
  const double radius2 = region.radius_mm * region.radius_mm;
  const double rho2 = r.squaredNorm() / radius2;
  if (rho2 >= 1.0) return Eigen::Matrix3d::Identity();
  const double beta = region.amplitude_mm * BeatCycleWeight(t) * kBeatKappa / region.radius_mm;
  const double s = 1.0 - rho2;
  return Eigen::Matrix3d::Identity() + beta * (s * s * s * Eigen::Matrix3d::Identity() -
                                               (6.0 * s * s / radius2) * r * r.transpose());
}

ImageGeometry SimulatedFrameGeometry(const ImageGeometry& source, const SimulationOptions& o) {
  ImageGeometry g;
  g.size = o.frame_size;
  g.spacing_mm = Eigen::Vector3d::Constant(o.frame_spacing > 0.0 ? o.frame_spacing
                                                                    : source.spacing_mm[0]);
  return g;  // origin 0, identity direction
}

Mask PyramidFieldOfView(const ImageGeometry& g, const SimulationOptions& o) {
  Mask mask(g, 0);
  const double cx = 0.5 * (g.size[0] - 1), cy = 0.5 * (g.size[1] - 1);
  const double tan_azimuth = std::tan(0.5 * o.azimuth_deg * M_PI / 180.0);
  const double tan_elevation = std::tan(0.5 * o.elevation_deg * M_PI / 180.0);
  // Voxels exactly on a pyramid face are inside; the slack absorbs tan's rounding (e.g.
  // tan(45 deg) = 1 - 1e-16), so the shape does not depend on the last bit.
  constexpr double kSlack = 1e-9;
  for (int k = 0; k < g.size[2]; ++k) {
    if (k + kSlack < o.min_depth_voxels) continue;
    for (int j = 0; j < g.size[1]; ++j) {
      if (std::abs(j - cy) > k * tan_elevation + kSlack) continue;
      for (int i = 0; i < g.size[0]; ++i) {
        mask.at(i, j, k) = std::abs(i - cx) <= k * tan_azimuth + kSlack ? 1 : 0;
      }
    }
  }
  return mask;
}

Mask ErodeFieldOfView(const Mask& fov, int erosion_voxels) {
  CHECK_GE(erosion_voxels, 0);
  const Eigen::Vector3i& n = fov.geometry.size;
  Mask mask = fov;
  for (int pass = 0; pass < erosion_voxels; ++pass) {
    const Mask m = mask;
    std::fill(mask.voxels.begin(), mask.voxels.end(), 0);
    for (int k = 1; k + 1 < n[2]; ++k) {
      for (int j = 1; j + 1 < n[1]; ++j) {
        for (int i = 1; i + 1 < n[0]; ++i) {
          mask.at(i, j, k) = m.at(i, j, k) && m.at(i - 1, j, k) && m.at(i + 1, j, k) &&
                                     m.at(i, j - 1, k) && m.at(i, j + 1, k) &&
                                     m.at(i, j, k - 1) && m.at(i, j, k + 1)
                                 ? 1
                                 : 0;
        }
      }
    }
  }
  return mask;
}

std::vector<Eigen::Isometry3d> SimulatedPoses(const ImageGeometry& source,
                                              const SimulationOptions& options) {
  std::string error;
  CHECK(options.Validate(&error)) << error;
  std::mt19937_64 rng(options.seed);
  return DrawPoses(source, SimulatedFrameGeometry(source, options), options, &rng);
}

void Frame0IntensityCorrections(const std::vector<double>& gain,
                                const std::vector<double>& offset,
                                std::vector<double>* corrected_gain,
                                std::vector<double>* corrected_offset) {
  CHECK(corrected_gain != nullptr);
  CHECK(corrected_offset != nullptr);
  CHECK_EQ(gain.size(), offset.size());
  CHECK(!gain.empty());
  corrected_gain->assign(gain.size(), 1.0);
  corrected_offset->assign(gain.size(), 0.0);
  // Frame 0 is set, not computed: o_0 - g_0 o_0 / g_0 need not round to 0.
  for (size_t i = 1; i < gain.size(); ++i) {
    CHECK_GT(gain[i], 0.0) << "frame " << i;
    (*corrected_gain)[i] = gain[0] / gain[i];
    (*corrected_offset)[i] = offset[0] - gain[0] * offset[i] / gain[i];
  }
}

Image SpeckleField(const ImageGeometry& g,
                   const SimulationOptions& options,
                   int frame_index,
                   int num_threads,
                   int phase) {
  std::string error;
  CHECK(options.Validate(&error)) << error;
  CHECK_GE(options.speckle_looks, 1);
  CHECK_EQ(options.speckle_world_fraction, 0.0) << "a world-fixed part needs SpeckleFields";
  CHECK_GE(frame_index, 0);
  CHECK_GE(phase, 0);
  const std::vector<double> w = SpeckleKernel(options.speckle_correlation_voxels);
  FrameLookScratch scratch;
  std::vector<double> sum(g.NumVoxels(), 0.0);
  for (int look = 0; look < options.speckle_looks; ++look) {
    // Each voxel adds its looks in look order: the same sum for any thread count.
    FrameSpeckleLook(g,
                     w,
                     options.seed,
                     frame_index,
                     phase,
                     look,
                     num_threads,
                     &scratch,
                     [&](int64_t k, int j, int i, double re, double im) {
                       sum[g.LinearIndex(i, j, static_cast<int>(k))] += 0.5 * (re * re + im * im);
                     });
  }
  Image speckle(g, 0.0f);
  for (size_t l = 0; l < sum.size(); ++l) {
    speckle.voxels[l] = static_cast<float>(sum[l] / options.speckle_looks);
  }
  return speckle;
}

ImageGeometry SpeckleWorldGrid(const ImageGeometry& g,
                               const std::vector<Eigen::Isometry3d>& frame_from_world,
                               const SimulationOptions& options,
                               const BeatRegion* beat) {
  std::string error;
  CHECK(options.Validate(&error)) << error;
  CHECK(!frame_from_world.empty());
  CHECK((g.spacing_mm.array() == g.spacing_mm[0]).all())
      << "the frame spacing must be isotropic: " << g.spacing_mm.transpose();
  const double s = g.spacing_mm[0];
  const Mask fov = PyramidFieldOfView(g, options);
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
  Eigen::Vector3d hi = -lo;
  for (const Eigen::Isometry3d& frame_from_world_i : frame_from_world) {
    const Eigen::Isometry3d world_from_frame = frame_from_world_i.inverse();
    const auto extend = [&](int i, int j, int k) {
      const Eigen::Vector3d x_in_world =
          world_from_frame * g.IndexToPhysical(Eigen::Vector3d(i, j, k));
      lo = lo.cwiseMin(x_in_world);
      hi = hi.cwiseMax(x_in_world);
    };
    // The map is affine, so the box of the voxel centres is the box of each row's two
    // ends (they include every vertex of the set's convex hull).
    bool any = false;
    for (int k = 0; k < g.size[2]; ++k) {
      for (int j = 0; j < g.size[1]; ++j) {
        int first = -1, last = -1;
        for (int i = 0; i < g.size[0]; ++i) {
          if (!fov.at(i, j, k)) continue;
          if (first < 0) first = i;
          last = i;
        }
        if (first < 0) continue;
        any = true;
        extend(first, j, k);
        extend(last, j, k);
      }
    }
    if (!any) {  // an empty field of view: the whole frame grid
      for (int corner = 0; corner < 8; ++corner) {
        extend(corner & 1 ? g.size[0] - 1 : 0,
               corner & 2 ? g.size[1] - 1 : 0,
               corner & 4 ? g.size[2] - 1 : 0);
      }
    }
  }
  if (beat != nullptr) {  // psi_p keeps the ball's points in the ball (simulate.h)
    lo = lo.cwiseMin(beat->center_mm - Eigen::Vector3d::Constant(beat->radius_mm));
    hi = hi.cwiseMax(beat->center_mm + Eigen::Vector3d::Constant(beat->radius_mm));
  }
  ImageGeometry world;
  world.spacing_mm = Eigen::Vector3d::Constant(s);
  for (int a = 0; a < 3; ++a) {
    const double first = std::floor(lo[a] / s), last = std::ceil(hi[a] / s);
    CHECK(std::isfinite(first) && std::isfinite(last) && last - first < kMaxSpeckleWorldSize)
        << "world speckle grid from " << lo.transpose() << " to " << hi.transpose() << " mm";
    world.size[a] = static_cast<int>(last - first) + 1;
    world.origin_mm[a] = first * s;
  }
  return world;
}

std::vector<Image> SpeckleFields(const ImageGeometry& g,
                                 const std::vector<Eigen::Isometry3d>& frame_from_world,
                                 const SimulationOptions& options,
                                 int num_threads,
                                 int phase,
                                 const BeatRegion* beat) {
  std::string error;
  CHECK(options.Validate(&error)) << error;
  CHECK_GE(options.speckle_looks, 1);
  CHECK(!frame_from_world.empty());
  CHECK_GE(phase, 0);
  CHECK(phase == 0 || (beat != nullptr && phase < options.num_phases)) << phase;
  const int num_frames = static_cast<int>(frame_from_world.size());
  std::vector<Image> fields;
  const double rho = options.speckle_world_fraction;
  if (rho == 0.0) {
    for (int f = 0; f < num_frames; ++f) {
      fields.push_back(SpeckleField(g, options, f, num_threads, phase));
    }
    return fields;
  }
  const bool moves = Moves(beat, phase);
  const double t = static_cast<double>(phase) / options.num_phases;
  const std::vector<double> w = SpeckleKernel(options.speckle_correlation_voxels);
  const int radius = static_cast<int>(w.size()) / 2;
  const ImageGeometry world = SpeckleWorldGrid(g, frame_from_world, options, beat);
  WorldLookSampler sampler;
  sampler.size = world.size;
  sampler.stride_y = world.size[0] + 2 * radius;
  sampler.stride_z = sampler.stride_y * (world.size[1] + 2 * radius);
  for (size_t t = 0; t + 1 < w.size(); ++t) sampler.neighbour_correlation += w[t] * w[t + 1];
  // Frame index -> world-grid index, u = index_from_frame * ijk + shift.
  std::vector<Eigen::Matrix3d> index_from_frame(num_frames);
  std::vector<Eigen::Vector3d> shift(num_frames);
  std::vector<Eigen::Isometry3d> world_from_frames(num_frames);  // for a moving phase
  for (int f = 0; f < num_frames; ++f) {
    const Eigen::Isometry3d world_from_frame = frame_from_world[f].inverse();
    world_from_frames[f] = world_from_frame;
    index_from_frame[f] =
        world.PhysicalToIndexMatrix() * world_from_frame.linear() * g.IndexToPhysicalMatrix();
    shift[f] = world.PhysicalToIndex(world_from_frame * g.origin_mm);
  }
  // The looks' |z|^2 / 2 are summed in each frame's returned field (float: the field is
  // returned as float anyway, and 64 float additions lose < 1e-5 of it), in the field of
  // view only: Simulate uses nothing else, and the world sampling is most of the cost.
  const Mask fov = PyramidFieldOfView(g, options);
  for (int f = 0; f < num_frames; ++f) fields.emplace_back(g, 0.0f);
  const double world_weight = std::sqrt(rho), frame_weight = std::sqrt(1.0 - rho);
  std::vector<double> world_field;  // one look at a time
  FrameLookScratch scratch;
  for (int look = 0; look < options.speckle_looks; ++look) {
    WorldSpeckleLook(world.size, w, options.seed, look, num_threads, &world_field);
    sampler.field = world_field.data();
    for (int f = 0; f < num_frames; ++f) {
      float* sum = fields[f].voxels.data();
      const auto add = [&](int64_t k, int j, int i, double re, double im) {
        const int64_t l = g.LinearIndex(i, j, static_cast<int>(k));
        if (!fov.voxels[l]) return;
        double world_re = 0.0, world_im = 0.0;
        const Eigen::Vector3d ijk(i, j, static_cast<double>(k));
        if (moves) {  // the tissue's scatterers: the world field at psi_p(x)
          const Eigen::Vector3d x = world_from_frames[f] * g.IndexToPhysical(ijk);
          sampler.Sample(world.PhysicalToIndex(x - BeatDisplacement(*beat, t, x)), &world_re,
                         &world_im);
        } else {
          sampler.Sample(index_from_frame[f] * ijk + shift[f], &world_re, &world_im);
        }
        const double z_re = world_weight * world_re + frame_weight * re;
        const double z_im = world_weight * world_im + frame_weight * im;
        sum[l] = static_cast<float>(sum[l] + 0.5 * (z_re * z_re + z_im * z_im));
      };
      if (rho < 1.0) {
        FrameSpeckleLook(g, w, options.seed, f, phase, look, num_threads, &scratch, add);
      } else {  // the per-frame fields have weight 0: not drawn
        ParallelFor(0, g.size[2], num_threads, [&](int64_t k) {
          for (int j = 0; j < g.size[1]; ++j) {
            for (int i = 0; i < g.size[0]; ++i) add(k, j, i, 0.0, 0.0);
          }
        });
      }
    }
  }
  for (Image& field : fields) {
    for (size_t l = 0; l < field.voxels.size(); ++l) {
      field.voxels[l] =
          fov.voxels[l] ? static_cast<float>(double{field.voxels[l]} / options.speckle_looks)
                        : 1.0f;
    }
  }
  return fields;
}

namespace {

// What a frame samples and how (Simulate): the source or its echo map, as a Frame for the
// trilinear values and the index map.
struct SourceSampler {
  const Image* sampled = nullptr;
  const Frame* frame = nullptr;
  const ImageGeometry* grid = nullptr;  // the source's
  SourceInterpolation interpolation = SourceInterpolation::kLinear;
};

// View `view`'s frame at `frame_from_world` sampled into *frame (zero outside `fov`); in
// phase `phase` of a beat (Moves) at psi_p of each world point (t = phase / num_phases).
// False with `error` naming the first field-of-view voxel that maps outside the source.
bool SampleFrame(const SourceSampler& source, const ImageGeometry& g, const Mask& fov,
                 const Eigen::Isometry3d& frame_from_world, int view, int phase,
                 const BeatRegion* beat, double t, Image* frame, std::string* error) {
  const bool moves = Moves(beat, phase);
  const Eigen::Isometry3d world_from_frame = frame_from_world.inverse();
  const auto world_point = [&](const Eigen::Vector3d& ijk) {
    const Eigen::Vector3d x_in_world = world_from_frame * g.IndexToPhysical(ijk);
    return moves ? Eigen::Vector3d(x_in_world - BeatDisplacement(*beat, t, x_in_world))
                 : x_in_world;
  };
  const Eigen::Vector3d upper = source.grid->size.cast<double>() - Eigen::Vector3d::Ones();
  // Slack for rounding: a voxel that maps to -1e-9 still samples the border voxel.
  constexpr double kIndexSlack = 1e-6;
  // Sample in parallel (each slice writes its own voxels and its own first-miss record).
  std::vector<int64_t> first_miss(g.size[2], -1);  // linear index of the first miss per slice
  ParallelFor(0, g.size[2], 0, [&](int64_t k) {
    for (int j = 0; j < g.size[1]; ++j) {
      for (int i = 0; i < g.size[0]; ++i) {
        const int64_t l = g.LinearIndex(i, j, static_cast<int>(k));
        if (!fov.voxels[l]) continue;
        const Eigen::Vector3d ijk_source =
            source.frame->ToIndex(world_point(Eigen::Vector3d(i, j, static_cast<double>(k))));
        if ((ijk_source.array() < -kIndexSlack).any() ||
            (ijk_source.array() > upper.array() + kIndexSlack).any()) {
          if (first_miss[k] < 0) first_miss[k] = l;
          continue;
        }
        frame->voxels[l] = static_cast<float>(
            source.interpolation == SourceInterpolation::kCubic
                ? CubicInterpolateValue(*source.sampled, ijk_source)
                : source.frame->InterpolateValue(ijk_source));
      }
    }
  });
  for (int k = 0; k < g.size[2]; ++k) {
    if (first_miss[k] < 0) continue;
    const int64_t l = first_miss[k];
    const Eigen::Vector3d ijk(l % g.size[0], (l / g.size[0]) % g.size[1], k);
    const Eigen::Vector3d ijk_source = source.frame->ToIndex(world_point(ijk));
    std::ostringstream s;
    s << "frame " << view;
    if (phase > 0) s << " phase " << phase;
    s << ": field-of-view voxel (" << ijk.transpose() << ") maps to source index ("
      << ijk_source.transpose() << "), outside the source grid (" << source.grid->DebugString()
      << "); use a larger source, a smaller frame_size or smaller motions";
    *error = s.str();
    return false;
  }
  return true;
}

// Source value x attenuation x speckle, x gain + offset (0 where `lost`: a dropout), + noise,
// clamped, in the field of view, in voxel order: each step skipped when off, so that a
// sequence without effects is bit for bit the former one. `normal` and `rng` carry on from
// frame to frame.
void ApplyEffectsAndNoise(const Mask& fov, const std::vector<double>& attenuation,
                          const Image& speckle, double gain, double offset, double sigma,
                          const std::vector<uint8_t>& lost,
                          std::normal_distribution<double>* normal, std::mt19937_64* rng,
                          Image* frame) {
  for (size_t l = 0; l < frame->voxels.size(); ++l) {
    if (!fov.voxels[l]) continue;
    double value = frame->voxels[l];
    if (!attenuation.empty()) value *= attenuation[l];
    if (!speckle.empty()) value *= speckle.voxels[l];
    if (gain != 1.0 || offset != 0.0) value = value * gain + offset;
    if (!lost.empty() && lost[l]) value = 0.0;  // a dropout: only the noise remains
    const double noisy = value + sigma * (*normal)(*rng);
    frame->voxels[l] = static_cast<float>(std::clamp(noisy, 0.0, 255.0));
  }
}

// The beat's region for a beating sequence (num_phases >= 2), checked against folding once
// its radius is known; false with `error` naming beat_amplitude_mm.
bool ResolveBeat(const ImageGeometry& source, const SimulationOptions& options,
                 BeatRegion* region, std::string* error) {
  *region = SimulatedBeatRegion(source, options);
  if (region->amplitude_mm <= kMaxBeatAmplitudeRatio * region->radius_mm) return true;
  std::ostringstream s;
  s << "beat_amplitude_mm=" << options.beat_amplitude_mm << ": must be at most "
    << kMaxBeatAmplitudeRatio << " times the beat's radius, " << region->radius_mm << " mm"
    << (options.beat_radius_mm > 0.0 ? "" : " (beat_radius_mm=0: a quarter of the frame depth)")
    << ", i.e. <= " << kMaxBeatAmplitudeRatio * region->radius_mm
    << " (a larger beat would fold the tissue); decrease it or set beat_radius_mm";
  *error = s.str();
  return false;
}

}  // namespace

bool Simulate(const Image& source,
              const SimulationOptions& options,
              SimulatedSequence* sequence,
              std::string* error) {
  CHECK(sequence != nullptr);
  CHECK(error != nullptr);
  if (!options.Validate(error)) return false;
  if (source.empty() || static_cast<int64_t>(source.voxels.size()) != source.geometry.NumVoxels()) {
    *error = "source volume is empty or its voxel count does not match its grid";
    return false;
  }
  if (!source.geometry.Validate("source volume", error)) return false;

  const ImageGeometry g = SimulatedFrameGeometry(source.geometry, options);
  const Mask fov = PyramidFieldOfView(g, options);
  const Mask mask = ErodeFieldOfView(fov, options.mask_erosion);
  if (CountInside(mask) == 0) {
    std::ostringstream s;
    s << "the field of view is empty after the " << options.mask_erosion
      << "-voxel erosion (mask_erosion): increase frame_size=" << options.frame_size[0] << ","
      << options.frame_size[1] << "," << options.frame_size[2]
      << ", azimuth_deg=" << options.azimuth_deg << " or elevation_deg=" << options.elevation_deg
      << ", or decrease min_depth_voxels=" << options.min_depth_voxels
      << " or mask_erosion=" << options.mask_erosion;
    *error = s.str();
    return false;
  }
  BeatRegion region;
  const BeatRegion* beat = nullptr;  // only for a beating sequence
  if (options.num_phases > 1) {
    if (!ResolveBeat(source.geometry, options, &region, error)) return false;
    beat = &region;
  }
  std::mt19937_64 rng(options.seed);
  const std::vector<Eigen::Isometry3d> poses = DrawPoses(source.geometry, g, options, &rng);

  // The effects' per-frame draws, from their own stream: gain first, then offset, whatever
  // the ranges, so that each is the same whether the other is on or not.
  std::vector<double> gains(options.num_frames), offsets(options.num_frames);
  for (int f = 0; f < options.num_frames; ++f) {
    std::mt19937_64 gain_offset_rng(
        StreamSeed(options.seed, kGainOffsetStream, {static_cast<uint64_t>(f)}));
    std::uniform_real_distribution<double> u(-1.0, 1.0);
    const double u_gain = u(gain_offset_rng);
    const double u_offset = u(gain_offset_rng);
    gains[f] = 1.0 + options.gain_range * u_gain;
    offsets[f] = options.offset_range > 0.0 ? options.offset_range * u_offset : 0.0;
  }
  // a(r) = 10^(-A r / 20), r the distance (cm) of the voxel centre from the apex, the
  // centre of the k = 0 face. The same for every frame; empty when off.
  std::vector<double> attenuation;
  if (options.attenuation_db_per_cm > 0.0) {
    attenuation.assign(g.NumVoxels(), 0.0);
    const Eigen::Vector3d apex_mm =
        g.IndexToPhysical(Eigen::Vector3d(0.5 * (g.size[0] - 1), 0.5 * (g.size[1] - 1), 0.0));
    for (int k = 0; k < g.size[2]; ++k) {
      for (int j = 0; j < g.size[1]; ++j) {
        for (int i = 0; i < g.size[0]; ++i) {
          const double r_cm =
              0.1 * (g.IndexToPhysical(Eigen::Vector3d(i, j, k)) - apex_mm).norm();
          attenuation[g.LinearIndex(i, j, k)] =
              std::pow(10.0, -options.attenuation_db_per_cm * r_cm / 20.0);
        }
      }
    }
  }

  // The frames sample `sampled`: the source, or its echo-like map on the same grid (made
  // once for all frames; without the mapping no copy is made).
  Image mapped;
  if (options.intensity_mapping == IntensityMapping::kEcho) {
    const auto start = std::chrono::steady_clock::now();
    double p99 = 0.0;
    mapped = EchoIntensityMap(source, options, 0, &p99);
    const int64_t black = std::count(mapped.voxels.begin(), mapped.voxels.end(), 0.0f);
    LOG(INFO) << "echo-like mapping of the source: gradient 99th percentile " << p99
              << " grey levels/mm, " << 100.0 * black / mapped.voxels.size()
              << " % of its voxels black, " << SecondsSince(start) << " s";
  }
  const Image& sampled = mapped.empty() ? source : mapped;
  const Frame source_frame(sampled, Mask(source.geometry, 1));
  const SourceSampler sampler{&sampled, &source_frame, &source.geometry, options.interpolation};
  std::normal_distribution<double> normal(0.0, 1.0);
  SimulatedSequence out;
  // Every frame is sampled (and checked against the source grid) before the effects: a
  // world-fixed speckle needs all the poses, and its world grid is only bounded once every
  // field of view is known to lie in the source.
  for (int f = 0; f < options.num_frames; ++f) {
    Image frame(g, 0.0f);
    if (!SampleFrame(sampler, g, fov, poses[f], f, 0, beat, 0.0, &frame, error)) return false;
    ApplyBeamArtifacts(fov, options, &frame);
    out.frames.push_back(std::move(frame));
  }
  std::vector<std::vector<uint8_t>> lost(options.num_frames);  // each view's dropout wedge
  for (int f = 0; f < options.num_frames; ++f) {
    lost[f] = DropoutWedge(g, fov, options,
                           StreamSeed(options.seed, kDropoutStream, {static_cast<uint64_t>(f)}));
  }
  const bool world_part = options.speckle_looks > 0 && options.speckle_world_fraction > 0.0;
  std::vector<Image> world_speckle;  // all frames' speckle when it has a world-fixed part
  if (world_part) world_speckle = SpeckleFields(g, poses, options, 0, 0, beat);
  for (int f = 0; f < options.num_frames; ++f) {
    Image speckle;
    if (!world_speckle.empty()) {
      speckle = std::move(world_speckle[f]);  // freed with this frame
    } else if (options.speckle_looks > 0) {
      speckle = SpeckleField(g, options, f, 0);
    }
    ApplyEffectsAndNoise(fov, attenuation, speckle, gains[f], offsets[f], options.sigma, lost[f],
                         &normal, &rng, &out.frames[f]);
    out.masks.push_back(mask);
    if (options.dropouts_out_of_masks) {
      for (size_t l = 0; l < lost[f].size(); ++l) {
        if (lost[f][l]) out.masks.back().voxels[l] = 0;
      }
    }
    out.frame_from_world.push_back(poses[f]);
    out.gain.push_back(gains[f]);
    out.offset.push_back(offsets[f]);
  }
  // The later phases of a beating sequence, phase by phase (one phase's world speckle at a
  // time), each view's frame sampled, speckled and made noisy from its own streams.
  out.later_phases.assign(options.num_frames, {});
  for (int p = 1; p < options.num_phases; ++p) {
    const double t = static_cast<double>(p) / options.num_phases;
    if (world_part) world_speckle = SpeckleFields(g, poses, options, 0, p, beat);
    for (int f = 0; f < options.num_frames; ++f) {
      Image frame(g, 0.0f);
      if (!SampleFrame(sampler, g, fov, poses[f], f, p, beat, t, &frame, error)) return false;
      ApplyBeamArtifacts(fov, options, &frame);
      Image speckle;
      if (world_part) {
        speckle = std::move(world_speckle[f]);
      } else if (options.speckle_looks > 0) {
        speckle = SpeckleField(g, options, f, 0, p);
      }
      std::mt19937_64 phase_rng(StreamSeed(
          options.seed, kPhaseNoiseStream, {static_cast<uint64_t>(f), static_cast<uint64_t>(p)}));
      std::normal_distribution<double> phase_normal(0.0, 1.0);
      ApplyEffectsAndNoise(fov, attenuation, speckle, gains[f], offsets[f], options.sigma,
                           lost[f], &phase_normal, &phase_rng, &frame);
      out.later_phases[f].push_back(std::move(frame));
    }
  }
  *sequence = std::move(out);
  return true;
}

}  // namespace dsr
