// The frames' intensity effects (simulate.h): the effects and noise Simulate applies to a
// sampled frame (Simulate itself draws the gains and offsets and makes the attenuation), and
// Frame0IntensityCorrections, the corrections the gains and offsets call for.
#include "dsr/sim/simulate.h"

#include <algorithm>
#include <random>
#include <vector>

#include <glog/logging.h>

#include "dsr/sim/simulate_internal.h"

namespace dsr {
namespace sim_internal {

void ApplyEffectsAndNoise(const Mask& fov,
                          const std::vector<double>& attenuation,
                          const Image& speckle,
                          double gain,
                          double offset,
                          double sigma,
                          const std::vector<uint8_t>& lost,
                          std::normal_distribution<double>* normal,
                          std::mt19937_64* rng,
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

}  // namespace sim_internal

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

}  // namespace dsr
