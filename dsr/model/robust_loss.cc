// Robust losses (model/robust_loss.h).
//
// Why IRLS with w = rho'(r^2) is what Ceres does with the loss: for a residual block with
// loss, Ceres's Corrector (internal/ceres/corrector.cc) scales the residual by sqrt(rho')
// and the Jacobian by sqrt(rho') when rho'' <= 0, and adds a curvature term otherwise.
// Huber (rho'' = 0 inside, < 0 outside) and Cauchy (rho'' < 0) always take the first
// branch, so every DBA Gauss-Newton step is the weighted least-squares step with the
// weights rho'(e^2) of its current residuals. The formulas below follow Ceres's
// HuberLoss and CauchyLoss operation for operation, so the weights agree bit for bit.
#include "dsr/model/robust_loss.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

#include <glog/logging.h>

#include "dsr/util/option_fields.h"

namespace dsr {

const char* RobustLossKindName(RobustLoss::Kind kind) {
  switch (kind) {
    case RobustLoss::Kind::kSquared:
      return "squared";
    case RobustLoss::Kind::kHuber:
      return "huber";
    case RobustLoss::Kind::kCauchy:
      return "cauchy";
  }
  return "?";
}

namespace {

// The kind named `name` (exactly one of RobustLossKindName's names); false with `error`
// otherwise.
bool StringToRobustLossKind(const std::string& name, RobustLoss::Kind* kind, std::string* error) {
  if (FindNamed(name,
                {RobustLoss::Kind::kSquared, RobustLoss::Kind::kHuber, RobustLoss::Kind::kCauchy},
                RobustLossKindName, kind)) {
    return true;
  }
  *error = "loss=" + name + ": must be squared, huber or cauchy";
  return false;
}

}  // namespace

bool RobustLoss::Validate(std::string* error) const {
  if (kind != Kind::kSquared && kind != Kind::kHuber && kind != Kind::kCauchy) {
    *error = "kind=" + std::to_string(static_cast<int>(kind)) + ": unknown loss kind";
    return false;
  }
  if (IsSquared()) return true;
  if (!std::isfinite(scale) || !(scale > 0.0)) {
    std::ostringstream s;
    s << "scale=" << scale << ": must be finite and > 0 (grey levels) for kind="
      << RobustLossKindName(kind);
    *error = s.str();
    return false;
  }
  return true;
}

bool MakeRobustLoss(const std::string& name, double scale, RobustLoss* loss, std::string* error) {
  RobustLoss out;
  if (!StringToRobustLossKind(name, &out.kind, error)) return false;
  out.scale = scale;
  if (!out.Validate(error)) {
    *error = PrefixFieldPaths("loss", *error);  // the fields of a RegistrationOptions
    return false;
  }
  *loss = out;
  return true;
}

double RobustLoss::Rho(double s) const {
  const double a = scale, b = scale * scale;
  switch (kind) {
    case Kind::kSquared:
      return s;
    case Kind::kHuber:
      return s > b ? 2.0 * a * std::sqrt(s) - b : s;
    case Kind::kCauchy:
      return b * std::log(1.0 + s * (1.0 / b));
  }
  return s;
}

double RobustLoss::Weight(double r) const {
  const double s = r * r;
  const double a = scale, b = scale * scale;
  constexpr double kMin = std::numeric_limits<double>::min();
  switch (kind) {
    case Kind::kSquared:
      return 1.0;
    case Kind::kHuber:
      return s > b ? std::max(kMin, a / std::sqrt(s)) : 1.0;
    case Kind::kCauchy:
      return std::max(kMin, 1.0 / (1.0 + s * (1.0 / b)));
  }
  return 1.0;
}

std::unique_ptr<ceres::LossFunction> RobustLoss::CeresLoss() const {
  switch (kind) {
    case Kind::kSquared:
      return nullptr;
    case Kind::kHuber:
      return std::make_unique<ceres::HuberLoss>(scale);
    case Kind::kCauchy:
      return std::make_unique<ceres::CauchyLoss>(scale);
  }
  return nullptr;
}

std::string RobustLoss::ToString() const {
  if (IsSquared()) return "squared";
  std::ostringstream s;
  s << RobustLossKindName(kind) << "(" << scale << ")";
  return s.str();
}

double RobustLocation(const RobustLoss& loss,
                      const double* c,
                      int k,
                      double* weight,
                      int max_iterations,
                      const double* unit) {
  CHECK_GE(k, 1);
  // Without units the sums are the plain weighted mean's, bit for bit.
  auto weighted_mean = [&] {
    double sum = 0.0, total = 0.0;
    for (int a = 0; a < k; ++a) {
      const double w = unit != nullptr ? weight[a] * unit[a] * unit[a] : weight[a];
      sum += w * c[a];
      total += w;
    }
    CHECK_GT(total, 0.0) << "robust location: weights must be > 0";
    return sum / total;
  };
  double mu = weighted_mean();
  for (int it = 0; it < max_iterations; ++it) {
    for (int a = 0; a < k; ++a) {
      weight[a] = loss.Weight(unit != nullptr ? unit[a] * (c[a] - mu) : c[a] - mu);
    }
    const double next = weighted_mean();
    const bool settled = std::abs(next - mu) <= 1e-9 * (std::abs(mu) + loss.scale);
    mu = next;
    if (settled) break;
  }
  return mu;
}

}  // namespace dsr
