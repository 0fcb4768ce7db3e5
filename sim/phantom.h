// Built-in procedural heart-like phantom, deterministic by seed, values 0..255, so demos
// and tests need no files: blood pools (dark, smooth ellipsoids), myocardial walls of
// varying brightness, thin bright valve-like sheets, slowly varying background tissue and
// speckle-like fine texture (smoothed noise, correlation ~2 voxels). Edges are soft (~2
// voxels) so image gradients are well defined at every scale.
#ifndef DSR_SIM_PHANTOM_H_
#define DSR_SIM_PHANTOM_H_

#include <cstdint>

#include "core/volume.h"

namespace dsr {

struct PhantomOptions {
  int size = 192;         // voxels per axis
  double spacing_mm = 1.0;
  uint64_t seed = 1;
};

// Geometry: size^3, isotropic spacing, identity direction, centred on the origin.
Image MakePhantom(const PhantomOptions& options);

}  // namespace dsr

#endif  // DSR_SIM_PHANTOM_H_
