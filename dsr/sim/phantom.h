// Built-in procedural heart-like phantom, so demos and tests need no files (docs/design.md
// section 6 cuts its frames from "a real 3D scan"; this stands in for it).
//
// Content, on a background of tissue (~70-110, slowly varying, scale ~12 voxels):
//  - a pericardium-like bright shell around the heart, darker tissue outside it;
//  - four chambers (atria above, ventricles below) and two great vessels: smooth rotated
//    ellipsoids filled with dark blood (~15-40), each surrounded by a thick myocardial wall
//    whose brightness varies per chamber and over space (~140-230); overlapping walls form
//    septa, slightly overlapping pools form the atrio-ventricular openings;
//  - bright thin dome-shaped sheets (mitral, tricuspid and aortic valve-like leaflets) and a
//    few muscle blobs (papillary-like) inside the ventricles;
//  - texture everywhere at two scales: medium (Gaussian-smoothed noise, sigma 4 voxels,
//    amplitude ~6) and speckle-like fine texture (smoothed noise, sigma 1.5 voxels, i.e. a
//    correlation length of ~3 voxels, amplitude 13 + 5% of the local level, ~14-25).
// Edges are soft (quintic smooth step over ~2.5 voxels), so image gradients are defined
// everywhere and registration has signal at every scale. Values are clamped to 0..255.
//
// Structure sizes scale with the volume (a 64^3 phantom is a small heart, though walls stay
// at least 3 voxels thick); edge widths and texture scales are in voxels. Deterministic for
// a seed with a given standard library, whatever the thread count (std::normal_distribution's
// output is implementation-defined, so tests must not rely on exact values). Its cost grows
// with size^3.
#ifndef DSR_SIM_PHANTOM_H_
#define DSR_SIM_PHANTOM_H_

#include <cstdint>
#include <string>

#include "dsr/geometry/volume.h"

namespace dsr {

struct PhantomOptions {
  int size = 192;           // voxels per axis, in [16, 512]
  double spacing_mm = 1.0;  // isotropic, finite and > 0
  uint64_t seed = 1;        // layout jitter and texture

  // False with a one-line message naming the field (util/option_fields.h) when a value
  // is out of range.
  bool Validate(std::string* error) const;
};

// Returns a size^3 float image: spacing `spacing_mm`, identity direction, origin such that
// the grid is centred on the world origin (voxel centre (size-1)/2 at 0 mm).
// Note: call options.Validate first; invalid options are a programming error (CHECK).
Image MakePhantom(const PhantomOptions& options);

}  // namespace dsr

#endif  // DSR_SIM_PHANTOM_H_
