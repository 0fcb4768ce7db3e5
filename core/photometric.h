// A frame's gain and offset against the panorama (issue 21, docs/design.md section 2.8).
#ifndef DSR_CORE_PHOTOMETRIC_H_
#define DSR_CORE_PHOTOMETRIC_H_

#include <cmath>

namespace dsr {

// Photometric parameters of a frame (issue 21, docs/design.md section 2.8): frame i observes
// the panorama intensity M_j as gain_i * I_i(p_ij) + offset_i, with gain_i = exp(log_gain)
// (always positive). Frame 0 holds the gauge (log_gain 0, offset 0).
struct Photometric {
  double log_gain = 0.0;
  double offset = 0.0;
  double gain() const { return std::exp(log_gain); }
  // The corrected observation gain * value + offset.
  double Correct(double value) const { return gain() * value + offset; }
};

}  // namespace dsr

#endif  // DSR_CORE_PHOTOMETRIC_H_
