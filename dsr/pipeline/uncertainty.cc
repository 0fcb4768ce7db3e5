// The pose covariance estimate and the predicted TRE (uncertainty.h): the free poses'
// covariance A^-1 C_g A^-T from the sums, EstimatePoseUncertainty, PredictedTre,
// NormalisedSquaredError and the tools' UncertaintySummary line.
#include "dsr/pipeline/uncertainty.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <random>
#include <string>
#include <vector>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <Eigen/LU>

#include "dsr/pipeline/uncertainty_internal.h"

namespace dsr {
namespace {

using uncertainty_internal::FieldOfViewPoints;
using uncertainty_internal::FrameCovariance;
using uncertainty_internal::FreePoseCovariance;
using uncertainty_internal::kClusterVoxels;

// At most this many field-of-view points per frame, and draws of the pose error.
constexpr int64_t kMaxTrePoints = 4096;
constexpr int kTreDraws = 256;

}  // namespace

namespace uncertainty_internal {

std::vector<Eigen::Vector3d> FieldOfViewPoints(const Mask& mask, const ImageGeometry& g) {
  const int64_t inside = CountInside(mask);
  // The same stride along every axis, so that the points spread evenly.
  int stride = 1;
  while (inside / (int64_t{stride} * stride * stride) > kMaxTrePoints) ++stride;
  std::vector<Eigen::Vector3d> points;
  for (int k = 0; k < g.size[2]; k += stride) {
    for (int j = 0; j < g.size[1]; j += stride) {
      for (int i = 0; i < g.size[0]; i += stride) {
        if (mask.at(i, j, k)) points.push_back(g.IndexToPhysical(Eigen::Vector3d(i, j, k)));
      }
    }
  }
  return points;
}

bool FreePoseCovariance(const UncertaintySums& sums,
                        int left_out,
                        Eigen::MatrixXd* covariance,
                        Eigen::MatrixXd* curvature) {
  const int n = static_cast<int>(sums.curvature[0].rows()) - 6;
  const Eigen::MatrixXd a = sums.Curvature(left_out).bottomRightCorner(n, n);
  if (curvature != nullptr) *curvature = a;
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eigen(0.5 * (a + a.transpose()),
                                                             Eigen::EigenvaluesOnly);
  if (!(eigen.eigenvalues().minCoeff() > 0.0)) return false;
  const Eigen::MatrixXd a_inverse = Eigen::PartialPivLU<Eigen::MatrixXd>(a).inverse();
  *covariance =
      a_inverse * sums.GradientCovariance(left_out).bottomRightCorner(n, n) * a_inverse.transpose();
  return true;
}

Matrix6d FrameCovariance(const Eigen::MatrixXd& covariance, int i) {
  const Matrix6d c = covariance.block<6, 6>(6 * (i - 1), 6 * (i - 1));
  return 0.5 * (c + c.transpose());
}

}  // namespace uncertainty_internal

double PredictedTre(const Matrix6d& covariance,
                    const std::vector<Eigen::Vector3d>& points_in_frame) {
  if (points_in_frame.empty()) return 0.0;
  // A square root of the covariance (it is positive semi-definite).
  const Eigen::SelfAdjointEigenSolver<Matrix6d> eigen(covariance);
  const Matrix6d root = eigen.eigenvectors() *
                        eigen.eigenvalues().cwiseMax(0.0).cwiseSqrt().asDiagonal();
  std::mt19937_64 rng(20261124);
  std::normal_distribution<double> normal(0.0, 1.0);
  double sum = 0.0;
  for (int d = 0; d < kTreDraws; ++d) {
    Vector6d z;
    for (int c = 0; c < 6; ++c) z[c] = normal(rng);
    const Vector6d delta = root * z;
    const Eigen::Vector3d rho = delta.head<3>(), phi = delta.tail<3>();
    double mean = 0.0;
    for (const Eigen::Vector3d& x : points_in_frame) mean += (rho + phi.cross(x)).norm();
    sum += mean / static_cast<double>(points_in_frame.size());
  }
  return sum / kTreDraws;
}

double NormalisedSquaredError(const Eigen::Isometry3d& estimated_frame_from_world,
                              const Eigen::Isometry3d& true_frame_from_world,
                              const Matrix6d& covariance) {
  const Vector6d e = LogSE3(estimated_frame_from_world * true_frame_from_world.inverse());
  return e.dot(covariance.ldlt().solve(e));
}

bool EstimatePoseUncertainty(const UncertaintySums& sums,
                             const std::vector<Frame>& frames,
                             const std::vector<Mask>& masks,
                             PoseUncertainty* uncertainty,
                             std::string* why,
                             Eigen::MatrixXd* curvature) {
  const int m = static_cast<int>(frames.size());
  const int n = 6 * (m - 1);
  const int64_t dof = sums.observations - sums.voxels - n;
  if (dof < n) {
    *why = "too few observations (" + std::to_string(sums.observations) +
           ") for a noise estimate";
    return false;
  }
  // The sandwich A^-1 Cov(g) A^-T, A the derivative of the gradient (the Gauss-Newton
  // matrix would overstate the curvature, see the header).
  Eigen::MatrixXd covariance;
  if (!FreePoseCovariance(sums, -1, &covariance, curvature)) {
    *why = "the cost's curvature at the final poses is not positive definite";
    return false;
  }
  if (sums.clusters < 2 * n) {
    *why = "too few independent parts of the overlap (" + std::to_string(sums.clusters) +
           " cubes of " + std::to_string(kClusterVoxels) + " voxels) for a covariance";
    return false;
  }
  *uncertainty = PoseUncertainty();
  uncertainty->noise_sigma = std::sqrt(sums.cost / static_cast<double>(dof));
  uncertainty->degrees_of_freedom = dof;
  uncertainty->covariance.assign(m, Matrix6d::Zero());
  uncertainty->predicted_tre_mm.assign(m, 0.0);
  for (int i = 1; i < m; ++i) {
    uncertainty->covariance[i] = FrameCovariance(covariance, i);
    uncertainty->predicted_tre_mm[i] =
        PredictedTre(uncertainty->covariance[i], FieldOfViewPoints(masks[i], frames[i].geometry()));
  }
  return true;
}

bool EstimatePoseUncertainty(const std::vector<Frame>& frames,
                             const CandidateSet& candidates,
                             const std::vector<Eigen::Isometry3d>& frame_from_world,
                             const std::vector<Mask>& masks,
                             const StreamContext& context,
                             PoseUncertainty* uncertainty,
                             std::string* why,
                             Eigen::MatrixXd* curvature) {
  return EstimatePoseUncertainty(
      SumForUncertainty(frames, candidates, frame_from_world, context.num_threads), frames, masks,
      uncertainty, why, curvature);
}

std::string UncertaintySummary(const PoseUncertainty& uncertainty, const std::string& note) {
  const int m = static_cast<int>(uncertainty.predicted_tre_mm.size());
  if (uncertainty.covariance.empty() || m < 2) {
    return "pose uncertainty not estimated: " + (note.empty() ? std::string("no result") : note);
  }
  std::vector<double> tre(uncertainty.predicted_tre_mm.begin() + 1,
                          uncertainty.predicted_tre_mm.end());
  const int worst = 1 + static_cast<int>(std::max_element(tre.begin(), tre.end()) - tre.begin());
  std::sort(tre.begin(), tre.end());
  const double median = tre.size() % 2 == 1
                            ? tre[tre.size() / 2]
                            : 0.5 * (tre[tre.size() / 2 - 1] + tre[tre.size() / 2]);
  char line[320];
  std::snprintf(line, sizeof(line),
                "pose uncertainty (noise only, docs/design.md section 8.6): predicted TRE "
                "median %.4f mm, max %.4f mm (frame %d); residual sigma %.4g over %lld "
                "degrees of freedom",
                median, uncertainty.predicted_tre_mm[worst], worst, uncertainty.noise_sigma,
                static_cast<long long>(uncertainty.degrees_of_freedom));
  return line;
}

}  // namespace dsr
