// The beating source (sim/simulate.h, num_phases and beat_*): num_phases = 1 leaves every
// sequence bit for bit as before the option existed; phase 0 is the still source's
// sequence (the same noise draws); the displacement field is periodic, smooth, zero outside
// its region and folds nothing (Jacobian determinant > 0); away from the region the phases
// of a view agree up to noise and inside it they differ; every phase draws its own noise;
// Validate refuses bad values naming the field.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <random>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "dsr/sim/phantom.h"
#include "dsr/sim/simulate.h"

namespace dsr {
namespace {

// 4 views of 32^3 with small motions, cut from an 80^3 phantom (simulate_test.cc's
// SmallOptions).
SimulationOptions SmallOptions() {
  SimulationOptions o;
  o.num_frames = 4;
  o.frame_size = Eigen::Vector3i(32, 32, 32);
  o.max_rotation_deg = 8.0;
  o.max_translation_voxels = 4.0;
  o.sigma = 0.0;
  o.min_depth_voxels = 2.0;
  return o;
}

const Image& SmallSource() {
  static const Image* const source = [] {
    PhantomOptions p;
    p.size = 80;
    return new Image(MakePhantom(p));
  }();
  return *source;
}

// FNV-1a (64 bit) over the images' float bit patterns, in order.
uint64_t Checksum(const std::vector<Image>& images) {
  uint64_t hash = 14695981039346656037ull;
  for (const Image& image : images) {
    for (float v : image.voxels) {
      uint32_t bits = 0;
      std::memcpy(&bits, &v, sizeof(bits));
      for (int b = 0; b < 4; ++b) {
        hash ^= (bits >> (8 * b)) & 0xffu;
        hash *= 1099511628211ull;
      }
    }
  }
  return hash;
}

// Configurations whose frames were checksummed with the simulator before num_phases
// existed: every path a frame goes through (linear and cubic sampling, noise, walk poses,
// gain, offset, attenuation, per-frame and world-fixed speckle, the echo mapping).
struct Recorded {
  const char* name;
  void (*edit)(SimulationOptions*);
  uint64_t checksum;
};

void Noisy(SimulationOptions* o) { o->sigma = 25.0; }
void AllEffects(SimulationOptions* o) {
  o->sigma = 15.0;
  o->pose_model = PoseModel::kWalk;
  o->step_rotation_deg = 4.0;
  o->step_translation_voxels = 3.0;
  o->gain_range = 0.2;
  o->offset_range = 10.0;
  o->attenuation_db_per_cm = 1.0;
  o->speckle_looks = 3;
  o->speckle_world_fraction = 0.6;
}
void EchoCubic(SimulationOptions* o) {
  o->sigma = 20.0;
  o->interpolation = SourceInterpolation::kCubic;
  o->intensity_mapping = IntensityMapping::kEcho;
  o->speckle_looks = 2;
}

const Recorded kRecorded[] = {
    {"noise", Noisy, 0x24d5d7dc47e47602ull},
    {"all effects, world speckle", AllEffects, 0x599a1d91d3638aa8ull},
    {"echo, cubic, per-frame speckle", EchoCubic, 0x064650b48ebe2cfeull},
};

TEST(Beating, OnePhaseIsBitIdenticalToBefore) {
  for (const Recorded& r : kRecorded) {
    SimulationOptions o = SmallOptions();
    r.edit(&o);
    SimulatedSequence s;
    std::string error;
    ASSERT_TRUE(Simulate(SmallSource(), o, &s, &error)) << error;
    EXPECT_EQ(Checksum(s.frames), r.checksum) << r.name << ": 0x" << std::hex
                                              << Checksum(s.frames);
  }
}

// --- The displacement field ---

BeatRegion TestRegion(double amplitude_mm) {
  BeatRegion region;
  region.center_mm = Eigen::Vector3d(1.5, -2.0, 0.5);
  region.radius_mm = 20.0;
  region.amplitude_mm = amplitude_mm;
  return region;
}

// Points uniform in the box of the region's ball enlarged by a quarter.
std::vector<Eigen::Vector3d> PointsAround(const BeatRegion& region, int count) {
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> u(-1.25, 1.25);
  std::vector<Eigen::Vector3d> points;
  for (int n = 0; n < count; ++n) {
    const Eigen::Vector3d v(u(rng), u(rng), u(rng));
    points.push_back(region.center_mm + region.radius_mm * v);
  }
  return points;
}

TEST(BeatDisplacement, ZeroOutsideTheRegionAndAtPhaseZeroPeriodicAndAtMostTheAmplitude) {
  const BeatRegion region = TestRegion(4.0);
  double largest = 0.0;
  int inside = 0;
  for (const Eigen::Vector3d& x : PointsAround(region, 20000)) {
    EXPECT_EQ(BeatDisplacement(region, 0.0, x), Eigen::Vector3d::Zero());
    const bool in_ball = (x - region.center_mm).norm() < region.radius_mm;
    inside += in_ball;
    for (double t : {0.25, 0.5, 0.75}) {
      const Eigen::Vector3d d = BeatDisplacement(region, t, x);
      if (!in_ball) {
        EXPECT_EQ(d, Eigen::Vector3d::Zero()) << x.transpose();
      }
      // Periodic: one cycle later, the same field.
      EXPECT_LT((BeatDisplacement(region, t + 1.0, x) - d).norm(), 1e-12);
      EXPECT_LE(d.norm(), region.amplitude_mm * BeatCycleWeight(t) * (1.0 + 1e-12));
      // A contraction: towards the centre.
      EXPECT_LE(d.dot(x - region.center_mm), 0.0);
      largest = std::max(largest, d.norm());
    }
    EXPECT_LT(BeatDisplacement(region, 1.0, x).norm(), 1e-12);
  }
  EXPECT_GT(inside, 5000);
  // The largest displacement, at t = 1/2 and rho = 1/sqrt(7), is the amplitude.
  EXPECT_GT(largest, 0.97 * region.amplitude_mm);
  const Eigen::Vector3d peak =
      region.center_mm + region.radius_mm / std::sqrt(7.0) * Eigen::Vector3d::UnitY();
  EXPECT_NEAR(BeatDisplacement(region, 0.5, peak).norm(), region.amplitude_mm, 1e-12);
  EXPECT_DOUBLE_EQ(BeatCycleWeight(0.5), 1.0);
  EXPECT_EQ(BeatCycleWeight(0.0), 0.0);
}

TEST(BeatDisplacement, PullbackJacobianIsTheDerivativeIsSmoothAndNeverFolds) {
  // The largest amplitude Validate allows: the worst case.
  const BeatRegion region = TestRegion(kMaxBeatAmplitudeRatio * 20.0);
  const auto pullback = [&](double t, const Eigen::Vector3d& x) {
    return Eigen::Vector3d(x - BeatDisplacement(region, t, x));
  };
  double smallest_det = 1e300, largest_error = 0.0;
  for (const Eigen::Vector3d& x : PointsAround(region, 20000)) {
    for (double t : {0.25, 0.5}) {
      const Eigen::Matrix3d jacobian = BeatPullbackJacobian(region, t, x);
      smallest_det = std::min(smallest_det, jacobian.determinant());
      constexpr double h = 1e-5;
      for (int a = 0; a < 3; ++a) {
        const Eigen::Vector3d e = h * Eigen::Vector3d::Unit(a);
        const Eigen::Vector3d column = (pullback(t, x + e) - pullback(t, x - e)) / (2.0 * h);
        largest_error = std::max(largest_error, (column - jacobian.col(a)).cwiseAbs().maxCoeff());
      }
    }
  }
  EXPECT_LT(largest_error, 1e-6);
  // Analytic minimum along a ray at rho^2 = 3/7: (1 + beta q)^2 (1 - 32/49 beta) ~ 0.45.
  EXPECT_GT(smallest_det, 0.4);
  // C^1 across the sphere: the Jacobian tends to the identity there.
  const Eigen::Vector3d near_sphere =
      region.center_mm + 0.999 * region.radius_mm * Eigen::Vector3d(0.6, 0.0, 0.8);
  EXPECT_LT((BeatPullbackJacobian(region, 0.5, near_sphere) - Eigen::Matrix3d::Identity()).norm(),
            1e-4);
}

// --- Validation ---

TEST(Beating, ValidateRefusesBadValuesNamingTheField) {
  struct Bad {
    void (*edit)(SimulationOptions*);
    const char* field;
  };
  const Bad bad[] = {
      {[](SimulationOptions* o) { o->num_phases = 0; }, "num_phases=0: "},
      {[](SimulationOptions* o) { o->num_phases = 65; }, "num_phases=65: "},
      {[](SimulationOptions* o) { o->beat_amplitude_mm = -1.0; }, "beat_amplitude_mm=-1: "},
      {[](SimulationOptions* o) { o->beat_amplitude_mm = NAN; }, "beat_amplitude_mm=nan: "},
      {[](SimulationOptions* o) { o->beat_amplitude_mm = 51.0; }, "beat_amplitude_mm=51: "},
      {[](SimulationOptions* o) { o->beat_radius_mm = -2.0; }, "beat_radius_mm=-2: "},
      {[](SimulationOptions* o) { o->beat_radius_mm = 1e-4; }, "beat_radius_mm=0.0001: "},
      {[](SimulationOptions* o) { o->beat_radius_mm = INFINITY; }, "beat_radius_mm=inf: "},
      {[](SimulationOptions* o) { o->beat_center_offset_mm[1] = NAN; },
       "beat_center_offset_mm=0,nan,0: "},
      {[](SimulationOptions* o) {
         o->num_phases = 2;
         o->beat_radius_mm = 10.0;
         o->beat_amplitude_mm = 2.6;
       },
       "beat_amplitude_mm=2.6: must be at most 0.25 beat_radius_mm=10"},
  };
  for (const Bad& b : bad) {
    SimulationOptions o;
    b.edit(&o);
    std::string error;
    EXPECT_FALSE(o.Validate(&error)) << b.field;
    EXPECT_EQ(error.rfind(b.field, 0), 0u) << error;
  }
  SimulationOptions o;
  std::string error;
  EXPECT_TRUE(o.Validate(&error)) << error;
  EXPECT_EQ(o.num_phases, 1);
  o.beat_radius_mm = 10.0;
  o.beat_amplitude_mm = 2.6;  // unused without phases
  EXPECT_TRUE(o.Validate(&error)) << error;
  o.num_phases = 64;
  o.beat_amplitude_mm = 2.5;  // the limit itself
  EXPECT_TRUE(o.Validate(&error)) << error;
  // The default radius (a quarter of the 32-voxel depth: 8 mm) is only known to Simulate.
  SimulationOptions small = SmallOptions();
  small.num_phases = 4;
  SimulatedSequence s;
  EXPECT_FALSE(Simulate(SmallSource(), small, &s, &error));
  EXPECT_EQ(error.rfind("beat_amplitude_mm=4: must be at most 0.25 times the beat's radius, 8 mm",
                        0),
            0u)
      << error;
  EXPECT_TRUE(s.frames.empty());
  small.beat_amplitude_mm = 2.0;
  EXPECT_TRUE(Simulate(SmallSource(), small, &s, &error)) << error;
}

// --- Sequences ---

// SmallOptions with T = 4 phases, a 2 mm beat in the default 8 mm ball.
SimulationOptions BeatingOptions() {
  SimulationOptions o = SmallOptions();
  o.num_phases = 4;
  o.beat_amplitude_mm = 2.0;
  return o;
}

TEST(Beating, PhaseZeroIsTheStillSequenceBitForBit) {
  for (const Recorded& r : kRecorded) {
    SimulationOptions o = BeatingOptions();
    r.edit(&o);
    SimulatedSequence s;
    std::string error;
    ASSERT_TRUE(Simulate(SmallSource(), o, &s, &error)) << error;
    EXPECT_EQ(Checksum(s.frames), r.checksum) << r.name;
    ASSERT_EQ(s.num_phases(), 4) << r.name;
    ASSERT_EQ(s.later_phases.size(), 4u);
    o.num_phases = 1;
    SimulatedSequence still;
    ASSERT_TRUE(Simulate(SmallSource(), o, &still, &error)) << error;
    EXPECT_EQ(still.num_phases(), 1);
    for (int f = 0; f < o.num_frames; ++f) {
      EXPECT_EQ(s.frame_from_world[f].matrix(), still.frame_from_world[f].matrix());
      EXPECT_EQ(s.masks[f].voxels, still.masks[f].voxels);
      EXPECT_EQ(&s.Phase(f, 0), &s.frames[f]);
      EXPECT_EQ(s.later_phases[f].size(), 3u);
      EXPECT_TRUE(still.later_phases[f].empty());
    }
    EXPECT_EQ(s.gain, still.gain);
    EXPECT_EQ(s.offset, still.offset);
  }
}

// The world point of voxel l of frame f, its distance from the beat's centre in radii.
double RadiiFromCentre(const SimulatedSequence& s, const BeatRegion& region, int f, int64_t l) {
  const ImageGeometry& g = s.frames[f].geometry;
  const Eigen::Vector3d ijk(l % g.size[0], (l / g.size[0]) % g.size[1],
                            l / (int64_t{g.size[0]} * g.size[1]));
  const Eigen::Vector3d x = s.frame_from_world[f].inverse() * g.IndexToPhysical(ijk);
  return (x - region.center_mm).norm() / region.radius_mm;
}

TEST(Beating, OutsideTheRegionPhasesAgreeInsideTheyMoveAndTheCycleIsSymmetric) {
  const SimulationOptions o = BeatingOptions();  // noise-free
  SimulatedSequence s;
  std::string error;
  ASSERT_TRUE(Simulate(SmallSource(), o, &s, &error)) << error;
  const BeatRegion region = SimulatedBeatRegion(SmallSource().geometry, o);
  int64_t outside = 0, inside = 0;
  double inside_difference = 0.0, largest_asymmetry = 0.0;
  for (int f = 0; f < o.num_frames; ++f) {
    for (int64_t l = 0; l < static_cast<int64_t>(s.frames[f].voxels.size()); ++l) {
      if (!s.masks[f].voxels[l]) continue;
      const double radii = RadiiFromCentre(s, region, f, l);
      const float phase0 = s.Phase(f, 0).voxels[l];
      if (radii >= 1.0) {
        ++outside;
        for (int p = 1; p < 4; ++p) ASSERT_EQ(s.Phase(f, p).voxels[l], phase0) << f << " " << l;
      } else if (radii < 0.8) {
        ++inside;
        inside_difference += std::abs(s.Phase(f, 2).voxels[l] - phase0);
      }
      // b(1/4) = b(3/4): phase T - p is phase p.
      largest_asymmetry = std::max(
          largest_asymmetry, double{std::abs(s.Phase(f, 1).voxels[l] - s.Phase(f, 3).voxels[l])});
    }
  }
  EXPECT_GT(outside, 10000);
  EXPECT_GT(inside, 2000);
  EXPECT_GT(inside_difference / inside, 3.0);
  EXPECT_LT(largest_asymmetry, 1e-3);
}

TEST(Beating, EveryPhaseDrawsItsOwnNoise) {
  SimulationOptions o = BeatingOptions();
  SimulatedSequence clean, noisy;
  std::string error;
  ASSERT_TRUE(Simulate(SmallSource(), o, &clean, &error)) << error;
  o.sigma = 10.0;
  ASSERT_TRUE(Simulate(SmallSource(), o, &noisy, &error)) << error;
  const BeatRegion region = SimulatedBeatRegion(SmallSource().geometry, o);
  // Per view: the noise e_p = noisy - clean of each phase where the anatomy is still and
  // no clamp bites; var(e_p) ~ sigma^2, var(phase p - phase q) ~ 2 sigma^2, and the
  // correlation of e_p and e_q ~ 0 for every pair of phases.
  for (int f = 0; f < o.num_frames; ++f) {
    std::vector<std::vector<double>> noise(4);
    for (int64_t l = 0; l < static_cast<int64_t>(clean.frames[f].voxels.size()); ++l) {
      if (!clean.masks[f].voxels[l] || RadiiFromCentre(clean, region, f, l) < 1.0) continue;
      const double value = clean.Phase(f, 0).voxels[l];
      if (value < 50.0 || value > 205.0) continue;
      for (int p = 0; p < 4; ++p) {
        noise[p].push_back(noisy.Phase(f, p).voxels[l] - clean.Phase(f, p).voxels[l]);
      }
    }
    const double n = static_cast<double>(noise[0].size());
    ASSERT_GT(n, 5000);
    for (int p = 0; p < 4; ++p) {
      double epep = 0.0;
      for (double e : noise[p]) epep += e * e;
      EXPECT_NEAR(epep / n, 100.0, 8.0) << f << " " << p;
      for (int q = p + 1; q < 4; ++q) {
        double eqeq = 0.0, epeq = 0.0, dd = 0.0;
        for (size_t v = 0; v < noise[p].size(); ++v) {
          eqeq += noise[q][v] * noise[q][v];
          epeq += noise[p][v] * noise[q][v];
          // Outside the region the clean phases are equal: the difference is noise alone.
          dd += (noise[q][v] - noise[p][v]) * (noise[q][v] - noise[p][v]);
        }
        EXPECT_NEAR(dd / n, 200.0, 16.0) << f << " " << p << " " << q;
        // 4 standard errors of a correlation of independent draws.
        EXPECT_LT(std::abs(epeq / std::sqrt(epep * eqeq)), 4.0 / std::sqrt(n))
            << f << " " << p << " " << q;
      }
    }
  }
  // Deterministic: the same seed, the same phases.
  SimulatedSequence again;
  ASSERT_TRUE(Simulate(SmallSource(), o, &again, &error)) << error;
  for (int f = 0; f < o.num_frames; ++f) {
    for (int p = 0; p < 4; ++p) EXPECT_EQ(again.Phase(f, p).voxels, noisy.Phase(f, p).voxels);
  }
}

double FieldCorrelation(const Image& a, const Image& b, const Mask& fov) {
  double sa = 0.0, sb = 0.0, saa = 0.0, sbb = 0.0, sab = 0.0;
  int64_t n = 0;
  for (size_t l = 0; l < a.voxels.size(); ++l) {
    if (!fov.voxels[l]) continue;
    sa += a.voxels[l];
    sb += b.voxels[l];
    saa += double{a.voxels[l]} * a.voxels[l];
    sbb += double{b.voxels[l]} * b.voxels[l];
    sab += double{a.voxels[l]} * b.voxels[l];
    ++n;
  }
  const double ca = saa / n - (sa / n) * (sa / n), cb = sbb / n - (sb / n) * (sb / n);
  return (sab / n - (sa / n) * (sb / n)) / std::sqrt(ca * cb);
}

TEST(Beating, EveryPhaseDrawsItsOwnPerFrameSpeckleAndTheWorldPartMovesWithTheTissue) {
  SimulationOptions o = BeatingOptions();
  o.speckle_looks = 2;
  o.speckle_correlation_voxels = 0.0;  // independent voxels: a sharp correlation test
  const ImageGeometry g = SimulatedFrameGeometry(SmallSource().geometry, o);
  const Mask fov = PyramidFieldOfView(g, o);
  const Image phase0 = SpeckleField(g, o, 1, 0);
  for (int p = 1; p < 4; ++p) {
    const Image phase = SpeckleField(g, o, 1, 1, p);
    EXPECT_EQ(phase.voxels, SpeckleField(g, o, 1, 3, p).voxels);  // any thread count
    EXPECT_LT(std::abs(FieldCorrelation(phase0, phase, fov)), 0.03) << p;
  }
  EXPECT_EQ(SpeckleField(g, o, 1, 2, 0).voxels, phase0.voxels);
  // Simulate speckles each phase with its own field: on a uniform source without noise the
  // frames are 100 x the speckle, uncorrelated between phases.
  const Image uniform(SmallSource().geometry, 100.0f);
  SimulatedSequence per_frame;
  std::string error;
  ASSERT_TRUE(Simulate(uniform, o, &per_frame, &error)) << error;
  for (int p = 0; p < 4; ++p) {
    for (int q = p + 1; q < 4; ++q) {
      EXPECT_LT(std::abs(FieldCorrelation(per_frame.Phase(1, p), per_frame.Phase(1, q), fov)),
                0.03)
          << p << " " << q;
    }
  }
  // All world-fixed (rho = 1) on a uniform source, so that the frames are the speckle
  // alone: the still anatomy keeps its speckle in every phase, the moving tissue carries it
  // along.
  o.speckle_world_fraction = 1.0;
  SimulatedSequence s;
  ASSERT_TRUE(Simulate(uniform, o, &s, &error)) << error;
  const BeatRegion region = SimulatedBeatRegion(SmallSource().geometry, o);
  int64_t still = 0, moved = 0;
  for (int f = 0; f < o.num_frames; ++f) {
    for (int64_t l = 0; l < static_cast<int64_t>(s.frames[f].voxels.size()); ++l) {
      if (!s.masks[f].voxels[l]) continue;
      const double radii = RadiiFromCentre(s, region, f, l);
      if (radii >= 1.0) {
        ++still;
        ASSERT_EQ(s.Phase(f, 2).voxels[l], s.Phase(f, 0).voxels[l]);
      } else if (radii < 0.8) {
        moved += s.Phase(f, 2).voxels[l] != s.Phase(f, 0).voxels[l];
      }
    }
  }
  EXPECT_GT(still, 10000);
  EXPECT_GT(moved, 2000);
}

}  // namespace
}  // namespace dsr
