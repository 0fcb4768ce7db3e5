// A frame's gain and offset against the panorama (docs/design.md section 2.8).
#ifndef DSR_MODEL_PHOTOMETRIC_H_
#define DSR_MODEL_PHOTOMETRIC_H_

#include <cmath>
#include <string>
#include <vector>

namespace dsr {

// Photometric parameters of a frame (docs/design.md section 2.8): frame i observes the
// panorama intensity M_j as gain_i * I_i(p_ij) + offset_i, with gain_i = exp(log_gain)
// (always positive). Frame 0 holds the gauge (log_gain 0, offset 0). The residuals are in
// the frame's own grey levels, e_ij = (M_j - offset_i) / gain_i - I_i(p_ij), so that every
// frame's noise counts once whatever its gain (section 2.8 says why that matters).
struct Photometric {
  double log_gain = 0.0;
  double offset = 0.0;
  double gain() const { return std::exp(log_gain); }
  // 1 / gain: the factor u_i that takes frame 0's grey levels to the frame's own.
  double unit() const { return std::exp(-log_gain); }
  // The corrected observation gain * value + offset.
  double Correct(double value) const { return gain() * value + offset; }
};

// Checks a solver's starting photometric parameters: none, or (only when `enabled`) finite
// ones with frame 0 at the gauge. False with `error` otherwise.
inline bool ValidateInitialPhotometric(bool enabled,
                                       const std::vector<Photometric>& initial,
                                       std::string* error) {
  if (initial.empty()) return true;
  if (!enabled) {
    *error = "initial photometric parameters given without photometric estimation";
    return false;
  }
  for (const Photometric& p : initial) {
    if (!std::isfinite(p.log_gain) || !std::isfinite(p.offset)) {
      *error = "initial photometric parameters: not finite";
      return false;
    }
  }
  if (initial[0].log_gain != 0.0 || initial[0].offset != 0.0) {
    *error = "initial photometric parameters: frame 0 must hold the gauge (gain 1, offset 0)";
    return false;
  }
  return true;
}

}  // namespace dsr

#endif  // DSR_MODEL_PHOTOMETRIC_H_
