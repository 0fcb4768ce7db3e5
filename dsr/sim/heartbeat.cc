// The beating source (simulate.h): the beat's region, the tissue's displacement d at a cycle
// fraction and the Jacobian of its pull-back, and for Simulate and the speckle whether a phase
// moves (Moves) and the region checked against folding (ResolveBeat).
#include "dsr/sim/simulate.h"

#include <cmath>
#include <sstream>
#include <string>

#include "dsr/sim/simulate_internal.h"

namespace dsr {
namespace {

// kappa = sqrt(7) (7/6)^3: 1 / max over rho in [0, 1] of rho (1 - rho^2)^3 (at 1/sqrt(7)).
const double kBeatKappa = std::sqrt(7.0) * (343.0 / 216.0);

}  // namespace

namespace sim_internal {

bool Moves(const BeatRegion* beat, int phase) {
  return beat != nullptr && phase > 0 && beat->amplitude_mm > 0.0;
}

bool ResolveBeat(const ImageGeometry& source,
                 const SimulationOptions& options,
                 BeatRegion* region,
                 std::string* error) {
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

}  // namespace sim_internal

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

Eigen::Matrix3d BeatPullbackJacobian(const BeatRegion& region,
                                     double t,
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

}  // namespace dsr
