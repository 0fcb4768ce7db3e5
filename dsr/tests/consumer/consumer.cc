// Simulates a small sequence from the built-in phantom and registers it with the installed
// dsr; exits 0 when the poses are within 0.5 mm of the truth (frame-0-relative).
#include <cstdio>

#include <dsr/pipeline/registration.h>
#include <dsr/sim/phantom.h>
#include <dsr/sim/simulate.h>

int main() {
  dsr::PhantomOptions phantom;
  phantom.size = 64;
  dsr::SimulationOptions simulation;
  simulation.num_frames = 3;
  simulation.frame_size = Eigen::Vector3i(32, 32, 28);
  simulation.max_rotation_deg = 4.0;
  simulation.max_translation_voxels = 3.0;
  dsr::SimulatedSequence sequence;
  std::string error;
  if (!dsr::Simulate(dsr::MakePhantom(phantom), simulation, &sequence, &error)) {
    std::fprintf(stderr, "consumer: %s\n", error.c_str());
    return 1;
  }
  dsr::RegistrationOptions options;
  dsr::RegistrationResult result;
  const std::vector<Eigen::Isometry3d> identity(3, Eigen::Isometry3d::Identity());
  if (!dsr::Register(sequence.frames, sequence.masks, identity, options, &result, &error) ||
      !result.usable) {
    std::fprintf(stderr, "consumer: %s\n", error.empty() ? result.failure.c_str() : error.c_str());
    return 1;
  }
  const Eigen::Isometry3d frame0 = sequence.frame_from_world[0];
  double worst_mm = 0.0;
  for (int i = 1; i < 3; ++i) {
    const Eigen::Isometry3d truth = sequence.frame_from_world[i] * frame0.inverse();
    worst_mm =
        std::max(worst_mm, (result.frame_from_world[i].translation() - truth.translation()).norm());
  }
  std::printf("consumer: registered 3 frames, largest translation error %.4f mm\n", worst_mm);
  return worst_mm < 0.5 ? 0 : 1;
}
