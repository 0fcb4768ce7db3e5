// The paper's simulation protocol (docs/design.md section 6); conventions in simulate.h.
#include "sim/simulate.h"

#include <algorithm>
#include <cmath>
#include <initializer_list>
#include <limits>
#include <random>
#include <sstream>
#include <string>

#include <glog/logging.h>

#include "core/frame.h"
#include "core/parallel.h"

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

// The speckle kernel is cut at this many standard deviations. The cut weights would carry
// < 1e-4 of the kernel's squared sum; the kept ones are rescaled to a unit squared sum, so
// the speckle's mean stays exactly 1 and the cut only trims the far tail of its
// correlation.
constexpr double kSpeckleKernelSigmas = 3.0;

// Tags of the effects' random streams (ASCII "gain_off", "speckle_"). Fixed for good: they
// decide every seed's gains, offsets and speckle.
constexpr uint64_t kGainOffsetStream = 0x6761696e5f6f6666ull;
constexpr uint64_t kSpeckleStream = 0x737065636b6c655full;

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
  for (SourceInterpolation m : {SourceInterpolation::kLinear, SourceInterpolation::kCubic}) {
    if (text == SourceInterpolationToString(m)) {
      *interpolation = m;
      return true;
    }
  }
  return false;
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
  for (PoseModel m : {PoseModel::kRandom, PoseModel::kWalk}) {
    if (text == PoseModelToString(m)) {
      *model = m;
      return true;
    }
  }
  return false;
}

bool SimulationOptions::Validate(std::string* error) const {
  std::ostringstream s;
  auto range = [](double v, double lo, double hi) {
    return std::isfinite(v) && v >= lo && v <= hi;
  };
  if (num_frames < 2 || num_frames > kMaxFrames) {
    s << "--num_frames=" << num_frames << ": must be in [2, " << kMaxFrames << "]";
  } else if (!range(max_rotation_deg, 0.0, 180.0)) {
    s << "--max_rotation_deg=" << max_rotation_deg << ": must be in [0, 180]";
  } else if (!range(max_translation_voxels, 0.0, std::numeric_limits<double>::max())) {
    s << "--max_translation_voxels=" << max_translation_voxels << ": must be finite and >= 0";
  } else if (*PoseModelToString(pose_model) == '\0') {
    s << "--pose_model=" << static_cast<int>(pose_model) << ": must be random or walk";
  } else if (!range(step_rotation_deg, 0.0, 180.0)) {
    s << "--step_rotation_deg=" << step_rotation_deg << ": must be in [0, 180]";
  } else if (!range(step_translation_voxels, 0.0, std::numeric_limits<double>::max())) {
    s << "--step_translation_voxels=" << step_translation_voxels << ": must be finite and >= 0";
  } else if (!range(noise_sigma, 0.0, std::numeric_limits<double>::max())) {
    s << "--sigma=" << noise_sigma << ": must be finite and >= 0";
  } else if ((frame_size.array() < 4).any() || (frame_size.array() > kMaxFrameSize).any()) {
    s << "--frame_size=" << frame_size[0] << "," << frame_size[1] << "," << frame_size[2]
      << ": every size must be in [4, " << kMaxFrameSize << "]";
  } else if (!range(frame_spacing_mm, 0.0, std::numeric_limits<double>::max())) {
    s << "--frame_spacing=" << frame_spacing_mm << ": must be finite and >= 0 (0 = source spacing)";
  } else if (!(std::isfinite(azimuth_deg) && azimuth_deg > 0.0 && azimuth_deg < 180.0)) {
    s << "--azimuth_deg=" << azimuth_deg << ": must be in (0, 180)";
  } else if (!(std::isfinite(elevation_deg) && elevation_deg > 0.0 && elevation_deg < 180.0)) {
    s << "--elevation_deg=" << elevation_deg << ": must be in (0, 180)";
  } else if (!range(min_depth_voxels, 0.0, frame_size[2] - 3.0)) {
    s << "--min_depth_voxels=" << min_depth_voxels
      << ": must be in [0, frame depth - 3 = " << frame_size[2] - 3 << "]";
  } else if (mask_erosion_voxels < 0 || mask_erosion_voxels > kMaxMaskErosion) {
    s << "--mask_erosion=" << mask_erosion_voxels << ": must be in [0, " << kMaxMaskErosion
      << "]";
  } else if (*SourceInterpolationToString(interpolation) == '\0') {
    s << "--interpolation=" << static_cast<int>(interpolation) << ": must be linear or cubic";
  } else if (!range(gain_range, 0.0, kMaxGainRange)) {
    s << "--gain_range=" << gain_range << ": must be in [0, " << kMaxGainRange << "]";
  } else if (!range(offset_range, 0.0, kMaxOffsetRange)) {
    s << "--offset_range=" << offset_range << ": must be in [0, " << kMaxOffsetRange << "]";
  } else if (speckle_looks < 0 || speckle_looks > kMaxSpeckleLooks) {
    s << "--speckle_looks=" << speckle_looks << ": must be 0 (no speckle) or in [1, "
      << kMaxSpeckleLooks << "]";
  } else if (!range(speckle_correlation_voxels, 0.0, kMaxSpeckleCorrelation)) {
    s << "--speckle_correlation_voxels=" << speckle_correlation_voxels << ": must be in [0, "
      << kMaxSpeckleCorrelation << "]";
  } else if (!range(attenuation_db_per_cm, 0.0, kMaxAttenuationDbPerCm)) {
    s << "--attenuation_db_per_cm=" << attenuation_db_per_cm << ": must be in [0, "
      << kMaxAttenuationDbPerCm << "]";
  } else {
    return true;
  }
  if (error != nullptr) *error = s.str();
  return false;
}

ImageGeometry SimulatedFrameGeometry(const ImageGeometry& source, const SimulationOptions& o) {
  ImageGeometry g;
  g.size = o.frame_size;
  g.spacing_mm = Eigen::Vector3d::Constant(o.frame_spacing_mm > 0.0 ? o.frame_spacing_mm
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
                   int num_threads) {
  std::string error;
  CHECK(options.Validate(&error)) << error;
  CHECK_GE(options.speckle_looks, 1);
  CHECK_GE(frame_index, 0);
  const double c = options.speckle_correlation_voxels;
  const int radius = static_cast<int>(std::ceil(kSpeckleKernelSigmas * c));
  const int taps = 2 * radius + 1;
  // 1-D weights exp(-d^2 / (2 c^2)), |d| <= radius, scaled to sum w_d^2 = 1: the 3-D kernel
  // (their product) then has a unit squared sum, so a smoothed unit-variance white field
  // keeps its variance, E|z|^2 = 1 (c = 0: the single weight 1, no smoothing).
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
  // The white fields live on the frame grid padded by the radius on every side, so that
  // every frame voxel sees the whole kernel (no border effects); the three separable
  // passes each drop the padding of one axis. Complex values are stored interleaved
  // [re, im], x fastest.
  const Eigen::Vector3i& n = g.size;
  const Eigen::Vector3i p = n + Eigen::Vector3i::Constant(2 * radius);
  const int64_t p_slice = int64_t{p[0]} * p[1];
  std::vector<double> white(2 * p_slice * p[2]);
  std::vector<double> along_x(2 * int64_t{n[0]} * p[1] * p[2]);
  std::vector<double> along_y(2 * int64_t{n[0]} * n[1] * p[2]);
  std::vector<double> sum(g.NumVoxels(), 0.0);
  for (int look = 0; look < options.speckle_looks; ++look) {
    // One generator per padded slice (its re and im draws in voxel order), so the draws do
    // not depend on which thread takes the slice.
    ParallelFor(0, p[2], num_threads, [&](int64_t k) {
      std::mt19937_64 rng(StreamSeed(options.seed,
                                     kSpeckleStream,
                                     {static_cast<uint64_t>(frame_index),
                                      static_cast<uint64_t>(look),
                                      static_cast<uint64_t>(k)}));
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
    // Each voxel adds its looks in look order: the same sum for any thread count.
    ParallelFor(0, n[2], num_threads, [&](int64_t k) {
      for (int j = 0; j < n[1]; ++j) {
        for (int i = 0; i < n[0]; ++i) {
          double re = 0.0, im = 0.0;
          for (int t = 0; t < taps; ++t) {
            const int64_t in = 2 * (((k + t) * n[1] + j) * int64_t{n[0]} + i);
            re += w[t] * along_y[in];
            im += w[t] * along_y[in + 1];
          }
          sum[g.LinearIndex(i, j, static_cast<int>(k))] += 0.5 * (re * re + im * im);
        }
      }
    });
  }
  Image speckle(g, 0.0f);
  for (size_t l = 0; l < sum.size(); ++l) {
    speckle.voxels[l] = static_cast<float>(sum[l] / options.speckle_looks);
  }
  return speckle;
}

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
  const Mask mask = ErodeFieldOfView(fov, options.mask_erosion_voxels);
  if (CountInside(mask) == 0) {
    *error = "the field of view is empty after the " +
             std::to_string(options.mask_erosion_voxels) +
             "-voxel erosion (--mask_erosion): increase --frame_size, --azimuth_deg or "
             "--elevation_deg, or decrease --min_depth_voxels or --mask_erosion";
    return false;
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

  const Frame source_frame(source, Mask(source.geometry, 1));
  const Eigen::Vector3d upper = source.geometry.size.cast<double>() - Eigen::Vector3d::Ones();
  // Slack for rounding: a voxel that maps to -1e-9 still samples the border voxel.
  constexpr double kIndexSlack = 1e-6;
  std::normal_distribution<double> normal(0.0, 1.0);
  SimulatedSequence out;
  for (int f = 0; f < options.num_frames; ++f) {
    Image frame(g, 0.0f);
    const Eigen::Isometry3d world_from_frame = poses[f].inverse();
    // Sample in parallel (each slice writes its own voxels and its own first-miss record),
    // then add noise in a fixed serial order so the result does not depend on threads.
    std::vector<int64_t> first_miss(g.size[2], -1);  // linear index of the first miss per slice
    ParallelFor(0, g.size[2], 0, [&](int64_t k) {
      for (int j = 0; j < g.size[1]; ++j) {
        for (int i = 0; i < g.size[0]; ++i) {
          const int64_t l = g.LinearIndex(i, j, static_cast<int>(k));
          if (!fov.voxels[l]) continue;
          const Eigen::Vector3d x_in_world =
              world_from_frame * g.IndexToPhysical(Eigen::Vector3d(i, j, static_cast<double>(k)));
          const Eigen::Vector3d ijk_source = source_frame.ToIndex(x_in_world);
          if ((ijk_source.array() < -kIndexSlack).any() ||
              (ijk_source.array() > upper.array() + kIndexSlack).any()) {
            if (first_miss[k] < 0) first_miss[k] = l;
            continue;
          }
          frame.voxels[l] = static_cast<float>(
              options.interpolation == SourceInterpolation::kCubic
                  ? CubicInterpolateValue(source, ijk_source)
                  : source_frame.InterpolateValue(ijk_source));
        }
      }
    });
    for (int k = 0; k < g.size[2]; ++k) {
      if (first_miss[k] < 0) continue;
      const int64_t l = first_miss[k];
      const Eigen::Vector3d ijk(l % g.size[0], (l / g.size[0]) % g.size[1], k);
      const Eigen::Vector3d ijk_source =
          source_frame.ToIndex(world_from_frame * g.IndexToPhysical(ijk));
      std::ostringstream s;
      s << "frame " << f << ": field-of-view voxel (" << ijk.transpose()
        << ") maps to source index (" << ijk_source.transpose() << "), outside the source grid ("
        << source.geometry.DebugString()
        << "); use a larger source (--phantom_size), a smaller --frame_size or smaller motions";
      *error = s.str();
      return false;
    }
    const Image speckle =
        options.speckle_looks > 0 ? SpeckleField(g, options, f, 0) : Image();
    const double gain = gains[f], offset = offsets[f];
    // Source value x attenuation x speckle, x gain + offset, + noise, clamped: each step
    // skipped when off, so that a sequence without effects is bit for bit the former one.
    for (size_t l = 0; l < frame.voxels.size(); ++l) {
      if (!fov.voxels[l]) continue;
      double value = frame.voxels[l];
      if (!attenuation.empty()) value *= attenuation[l];
      if (!speckle.empty()) value *= speckle.voxels[l];
      if (gain != 1.0 || offset != 0.0) value = value * gain + offset;
      const double noisy = value + options.noise_sigma * normal(rng);
      frame.voxels[l] = static_cast<float>(std::clamp(noisy, 0.0, 255.0));
    }
    out.frames.push_back(std::move(frame));
    out.masks.push_back(mask);
    out.frame_from_world.push_back(poses[f]);
    out.gain.push_back(gain);
    out.offset.push_back(offset);
  }
  *sequence = std::move(out);
  return true;
}

}  // namespace dsr
