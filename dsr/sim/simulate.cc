// The paper's simulation protocol (docs/design.md section 6); conventions in simulate.h.
// This file holds the options (their names and Validate), the random streams' seeds, the
// frames' sampling of the source and the sequence assembly (Simulate). The pose models are in
// pose_models.cc, the speckle in speckle.cc, the beat in heartbeat.cc, the frame grid and its
// field of view in frame_field_of_view.cc, the intensity effects in intensity_effects.cc;
// what they share in simulate_internal.h.
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
#include "dsr/sim/simulate_internal.h"
#include "dsr/util/clock.h"
#include "dsr/util/option_fields.h"
#include "dsr/util/parallel.h"

namespace dsr {
namespace {

using sim_internal::ApplyEffectsAndNoise;
using sim_internal::DrawPoses;
using sim_internal::kGainOffsetStream;
using sim_internal::kPhaseNoiseStream;
using sim_internal::Moves;
using sim_internal::ResolveBeat;
using sim_internal::StreamSeed;

constexpr int kMaxFrames = 1000;
constexpr int kMaxFrameSize = 2048;

constexpr int kMaxMaskErosion = 50;

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

// The lateral point-spread function's largest standard deviation (simulate.h), mm.
constexpr double kMaxPsfLateralMm = 20.0;
// The dropouts' random stream (ASCII "dropout_"; echo_artifacts.h).
constexpr uint64_t kDropoutStream = 0x64726f706f75745full;

// Ranges of the beating source (simulate.h).
constexpr int kMaxPhases = 64;
constexpr double kMaxBeatAmplitudeMm = 50.0;
constexpr double kMinBeatRadiusMm = 1e-3;
constexpr double kMaxBeatRadiusMm = 1e6;

// SplitMix64's output function: a bijection of 64-bit words in which every input bit
// changes about half the output bits, so that neighbouring seeds and indices give unrelated
// generator seeds.
uint64_t Mix64(uint64_t x) {
  x += 0x9e3779b97f4a7c15ull;
  x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ull;
  x = (x ^ (x >> 27)) * 0x94d049bb133111ebull;
  return x ^ (x >> 31);
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

namespace sim_internal {

uint64_t StreamSeed(uint64_t seed, uint64_t tag, std::initializer_list<uint64_t> indices) {
  uint64_t h = Mix64(seed ^ Mix64(tag));
  for (uint64_t index : indices) h = Mix64(h ^ Mix64(index));
  return h;
}

}  // namespace sim_internal

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
