// sim/'s own helpers shared by its sources (each group defined in the file its heading
// names) and the tags of the simulator's random streams. Not for use outside dsr/sim.
#ifndef DSR_SIM_SIMULATE_INTERNAL_H_
#define DSR_SIM_SIMULATE_INTERNAL_H_

#include <cstdint>
#include <initializer_list>
#include <random>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "dsr/geometry/volume.h"
#include "dsr/sim/simulate.h"

namespace dsr {
namespace sim_internal {

// Tags of the effects' random streams (ASCII "gain_off", "speckle_", "speckleW"). Fixed for
// good: they decide every seed's gains, offsets and speckle.
constexpr uint64_t kGainOffsetStream = 0x6761696e5f6f6666ull;
constexpr uint64_t kSpeckleStream = 0x737065636b6c655full;
constexpr uint64_t kSpeckleWorldStream = 0x737065636b6c6557ull;
// The beating source's later phases (ASCII "phase_no", "speckleP"): each phase's noise and
// per-frame speckle part.
constexpr uint64_t kPhaseNoiseStream = 0x70686173655f6e6full;
constexpr uint64_t kSpecklePhaseStream = 0x737065636b6c6550ull;

// Defined in simulate.cc.

// The seed of one effect's generator: the run's seed, the effect's tag and the indices
// (frame, look, slice, ...) folded in one after the other. Independent of the
// poses-and-noise generator, which is seeded with `seed` itself.
uint64_t StreamSeed(uint64_t seed, uint64_t tag, std::initializer_list<uint64_t> indices);

// Defined in heartbeat.cc.

// Whether phase `phase` of a sequence with `beat` moves anything.
bool Moves(const BeatRegion* beat, int phase);

// The beat's region for a beating sequence (num_phases >= 2), checked against folding once
// its radius is known; false with `error` naming beat_amplitude_mm.
bool ResolveBeat(const ImageGeometry& source,
                 const SimulationOptions& options,
                 BeatRegion* region,
                 std::string* error);

// Defined in pose_models.cc.

// The poses (frame_from_world, frame 0 first) of `o`'s frames on the frame grid `frame` over
// the source grid `source`, drawn from `rng` by o.pose_model (simulate.h); Simulate then draws
// the frames' noise from `rng`.
std::vector<Eigen::Isometry3d> DrawPoses(const ImageGeometry& source,
                                         const ImageGeometry& frame,
                                         const SimulationOptions& o,
                                         std::mt19937_64* rng);

// Defined in intensity_effects.cc.

// Source value x attenuation x speckle, x gain + offset (0 where `lost`: a dropout), + noise,
// clamped, in the field of view, in voxel order: each step skipped when off, so that a
// sequence without effects is bit for bit the former one. `normal` and `rng` carry on from
// frame to frame.
void ApplyEffectsAndNoise(const Mask& fov,
                          const std::vector<double>& attenuation,
                          const Image& speckle,
                          double gain,
                          double offset,
                          double sigma,
                          const std::vector<uint8_t>& lost,
                          std::normal_distribution<double>* normal,
                          std::mt19937_64* rng,
                          Image* frame);

}  // namespace sim_internal
}  // namespace dsr

#endif  // DSR_SIM_SIMULATE_INTERNAL_H_
