// Robust losses for outlying intensities (shadows, reverberation;
// docs/design.md section 4.7), shared by both solver modes.
//
// Ceres's convention: an observation with residual r contributes rho(s), s = r^2 (the
// Ceres cost is 1/2 sum rho). With the scale a (grey levels):
//   squared:  rho(s) = s
//   huber:    rho(s) = s                    for s <= a^2,
//                      2 a sqrt(s) - a^2    otherwise
//   cauchy:   rho(s) = a^2 log(1 + s / a^2)
// DBA hands the matching ceres::LossFunction to every residual block (CeresLoss). DSR
// solves by iteratively reweighted least squares with the weight of an observation
//   w(r) = rho'(r^2):  squared 1,  huber 1 for |r| <= a else a / |r|,  cauchy 1 / (1 + r^2 / a^2),
// the factor Ceres applies too (for both losses rho'' <= 0, and Ceres's corrector then
// scales residual and Jacobian by sqrt(rho'): model/robust_loss.cc). Both modes therefore
// have the same stationarity conditions (docs/design.md section 4.7).
#ifndef DSR_MODEL_ROBUST_LOSS_H_
#define DSR_MODEL_ROBUST_LOSS_H_

#include <memory>
#include <string>

#include <ceres/loss_function.h>

namespace dsr {

struct RobustLoss {
  enum class Kind { kSquared, kHuber, kCauchy };
  Kind kind = Kind::kSquared;
  // a in grey levels (after the photometric correction, on frame 0's scale); unused (and
  // unchecked) for squared.
  double scale = 0.0;

  bool IsSquared() const { return kind == Kind::kSquared; }
  // Huber and Cauchy need a finite scale > 0. `error` names the fields kind and scale
  // (util/option_fields.h).
  bool Validate(std::string* error) const;
  // rho(s) for s = r^2 >= 0.
  double Rho(double s) const;
  // The IRLS weight rho'(r^2), in (0, 1]: as Ceres's rho[1], clamped below at the
  // smallest normal double.
  double Weight(double r) const;
  // The Ceres loss with the same rho, or null for squared (Ceres's "no loss").
  std::unique_ptr<ceres::LossFunction> CeresLoss() const;
  // "squared", "huber(5)", ... for logs.
  std::string ToString() const;
};

// "squared", "huber", "cauchy".
const char* RobustLossKindName(RobustLoss::Kind kind);
// Parses and validates a loss from its name and scale (RegistrationOptions::loss); the
// error names the fields loss, loss.kind and loss.scale (util/option_fields.h).
bool MakeRobustLoss(const std::string& name, double scale, RobustLoss* loss, std::string* error);

// The robust location (M-estimate) of k values c_0..c_{k-1} by IRLS, the closed-form
// panorama intensity of a voxel under `loss`: from mu = sum w c / sum w with the given
// `weight` (in), up to `max_iterations` steps
//   w_a = rho'((c_a - mu)^2),  mu = sum_a w_a c_a / sum_a w_a,
// stopping early when mu changes by no more than 1e-9 (|mu| + scale). Writes the last
// weights to `weight` and returns the weighted mean with them (so the pair is consistent:
// the location the next weighted solve starts from). Weights must be > 0.
// With `unit` (k factors u_a > 0; null: all 1), value a's residual is u_a (c_a - mu) (the
// observations of photometric frames in their own grey levels, docs/design.md 2.8):
//   w_a = rho'(u_a^2 (c_a - mu)^2),  mu = sum_a w_a u_a^2 c_a / sum_a w_a u_a^2.
double RobustLocation(const RobustLoss& loss,
                      const double* c,
                      int k,
                      double* weight,
                      int max_iterations,
                      const double* unit = nullptr);

}  // namespace dsr

#endif  // DSR_MODEL_ROBUST_LOSS_H_
