#include "dsr/pipeline/uncertainty.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <random>
#include <sstream>

#include <Eigen/Cholesky>
#include <Eigen/LU>
#include <Eigen/Eigenvalues>

#include "dsr/stream/reduced_system.h"
#include "dsr/util/parallel.h"

namespace dsr {
namespace {

// Edge of the cubes the gradient's covariance is estimated over (panorama voxels).
constexpr int kClusterVoxels = 8;
// At most this many field-of-view points per frame, and draws of the pose error.
constexpr int64_t kMaxTrePoints = 4096;
constexpr int kTreDraws = 256;

// The RMS distance of a frame's field-of-view points from its local origin (mm): how far a
// rotation of one radian moves them.
double RmsRadius(const std::vector<Eigen::Vector3d>& points) {
  double sum = 0.0;
  for (const Eigen::Vector3d& x : points) sum += x.squaredNorm();
  return std::sqrt(sum / std::max<size_t>(1, points.size()));
}

// Points of `mask` in the physical coordinates of `g`, the frame's geometry (the mask's
// grid, in the pipeline's local coordinates).
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

// The observers of candidate voxel v that sample it at their poses: k of them, frame[a]
// with value[a] and Jacobian jacobian[a] (arrays of at least kMaxFrames), and their mean.
int ObserveVoxel(const std::vector<Frame>& frames,
                 const CandidateSet& candidates,
                 const std::vector<Eigen::Isometry3d>& frame_from_world,
                 int64_t v,
                 double* value,
                 RowVector6d* jacobian,
                 int* frame,
                 double* mean) {
  const Eigen::Vector3d centre = candidates.VoxelCenter(v);
  int k = 0;
  double sum = 0.0;
  for (uint32_t bits = candidates.observers[v]; bits != 0; bits &= bits - 1) {
    const int f = __builtin_ctz(bits);
    if (ObserveSample(frames[f], frame_from_world[f], centre, &value[k], &jacobian[k])) {
      frame[k] = f;
      sum += value[k];
      ++k;
    }
  }
  *mean = k > 0 ? sum / k : 0.0;
  return k;
}

// Cov(g) of the DSR gradient g = sum_j sum_a J_aj^T r_aj (6m, all frames), estimated from
// the residuals themselves, cluster by cluster: the panorama is cut into cubes of
// kClusterVoxels voxels, g_B is the gradient's share of cube B, and Cov(g) ~ sum_B g_B g_B^T.
// This holds when residuals in different cubes are independent, whatever their
// correlation inside one cube (trilinear resampling spreads one frame voxel's noise over
// the 8 panorama voxels around it) and whatever their variance (which resampling lowers
// below the frames' own noise, so that s^2 from the cost would be too small). Frames of T
// phases: a cube's share sums its phases' (the tied cost's gradient; docs/design.md 12).
Eigen::MatrixXd ClusteredGradientCovariance(const std::vector<Frame>& frames,
                                            const CandidateSet& candidates,
                                            const std::vector<Eigen::Isometry3d>& frame_from_world,
                                            int num_threads,
                                            int64_t* num_clusters) {
  const int m = static_cast<int>(frames.size());
  const int n = 6 * m;
  const ImageGeometry& grid = candidates.grid;
  const int64_t nx = grid.size[0], nxy = nx * grid.size[1];
  const int64_t cx = (grid.size[0] + kClusterVoxels - 1) / kClusterVoxels;
  const int64_t cy = (grid.size[1] + kClusterVoxels - 1) / kClusterVoxels;
  const int64_t slabs = (grid.size[2] + kClusterVoxels - 1) / kClusterVoxels;
  // Candidates are sorted by linear index, so each slab of cubes (kClusterVoxels planes)
  // is a contiguous range: slabs run in parallel, each summing its own cubes.
  std::vector<int64_t> slab_begin(slabs + 1, candidates.num_voxels());
  for (int64_t v = candidates.num_voxels() - 1; v >= 0; --v) {
    slab_begin[candidates.voxel[v] / nxy / kClusterVoxels] = v;
  }
  for (int64_t s = slabs - 1; s >= 0; --s) slab_begin[s] = std::min(slab_begin[s], slab_begin[s + 1]);
  std::vector<Eigen::MatrixXd> slab_covariance(slabs);
  std::vector<int64_t> slab_clusters(slabs, 0);
  const FramesByPhase phases(frames);
  ParallelFor(0, slabs, num_threads, [&](int64_t s) {
    Eigen::MatrixXd shares = Eigen::MatrixXd::Zero(n, cx * cy);
    std::vector<double> value(kMaxFrames);
    std::vector<RowVector6d> jacobian(kMaxFrames);
    std::vector<int> frame(kMaxFrames);
    for (int64_t v = slab_begin[s]; v < slab_begin[s + 1]; ++v) {
      const int64_t l = candidates.voxel[v];
      const int64_t j = (l % nxy) / nx, i = l % nx;
      const int64_t cluster = (j / kClusterVoxels) * cx + i / kClusterVoxels;
      for (int p = 0; p < phases.size(); ++p) {
        double mean = 0.0;
        const int k = ObserveVoxel(phases[p], candidates, frame_from_world, v, value.data(),
                                   jacobian.data(), frame.data(), &mean);
        if (k < 2) continue;
        for (int a = 0; a < k; ++a) {
          shares.block<6, 1>(6 * frame[a], cluster) +=
              jacobian[a].transpose() * (value[a] - mean);
        }
      }
    }
    for (int64_t c = 0; c < shares.cols(); ++c) {
      if (!shares.col(c).isZero(0.0)) ++slab_clusters[s];
    }
    slab_covariance[s] = shares * shares.transpose();
  });
  Eigen::MatrixXd covariance = Eigen::MatrixXd::Zero(n, n);
  *num_clusters = 0;
  for (int64_t s = 0; s < slabs; ++s) {  // fixed order: deterministic
    covariance += slab_covariance[s];
    *num_clusters += slab_clusters[s];
  }
  return covariance;
}

// Forward-difference step of GradientJacobian: this fraction of a frame voxel (and the
// rotation that moves the field of view's RMS radius as far).
constexpr double kCurvatureStepVoxels = 0.05;
// Fixed number of voxel blocks of GradientJacobian's pass: results do not depend on threads.
constexpr int64_t kCurvatureBlocks = 64;

}  // namespace

namespace {

// GradientJacobian of one phase's frames.
Eigen::MatrixXd OnePhaseGradientJacobian(const std::vector<Frame>& frames,
                                         const CandidateSet& candidates,
                                         const std::vector<Eigen::Isometry3d>& frame_from_world,
                                         const std::vector<double>& step_mm,
                                         const std::vector<double>& step_rad,
                                         int num_threads) {
  const int m = static_cast<int>(frames.size());
  const int n = 6 * m;
  CHECK_EQ(static_cast<int>(frame_from_world.size()), m);
  CHECK_EQ(static_cast<int>(step_mm.size()), m);
  CHECK_EQ(static_cast<int>(step_rad.size()), m);
  // perturbed[6 f + c]: frame f's pose moved by its step along tangent axis c.
  std::vector<Eigen::Isometry3d> perturbed(6 * m);
  std::vector<double> step(6 * m);
  for (int f = 0; f < m; ++f) {
    for (int c = 0; c < 6; ++c) {
      step[6 * f + c] = c < 3 ? step_mm[f] : step_rad[f];
      Vector6d delta = Vector6d::Zero();
      delta[c] = step[6 * f + c];
      perturbed[6 * f + c] = ExpSE3(delta) * frame_from_world[f];
    }
  }
  const int64_t count = candidates.num_voxels();
  const int64_t num_blocks = std::max<int64_t>(1, std::min(kCurvatureBlocks, count));
  const int64_t block_size = (count + num_blocks - 1) / num_blocks;
  std::vector<Eigen::MatrixXd> block_jacobians(num_blocks);
  ParallelFor(0, num_blocks, num_threads, [&](int64_t b) {
    Eigen::MatrixXd a_block = Eigen::MatrixXd::Zero(n, n);
    double value[kMaxFrames];
    int frame[kMaxFrames];
    RowVector6d jacobian[kMaxFrames];
    RowVector6d value_derivative[kMaxFrames];  // d value / d delta, by differences
    for (int64_t v = b * block_size; v < std::min(count, (b + 1) * block_size); ++v) {
      const Eigen::Vector3d centre = candidates.VoxelCenter(v);
      double mean = 0.0;
      const int k = ObserveVoxel(frames, candidates, frame_from_world, v, value, jacobian, frame,
                                 &mean);
      if (k < 2) continue;
      for (int a = 0; a < k; ++a) {
        const int f = frame[a];
        const Vector6d at = jacobian[a].transpose() * (value[a] - mean);
        for (int c = 0; c < 6; ++c) {
          double moved = 0.0;
          RowVector6d moved_jacobian;
          value_derivative[a][c] = 0.0;
          // A sample that leaves the field of view at the step is left out, so that the
          // difference measures the slope, not the observation count.
          if (!ObserveSample(frames[f], perturbed[6 * f + c], centre, &moved, &moved_jacobian)) {
            continue;
          }
          const double h = step[6 * f + c];
          value_derivative[a][c] = (moved - value[a]) / h;
          // Own block: frame f's gradient share with its sample moved and the mean following.
          const double moved_mean = mean + (moved - value[a]) / k;
          a_block.block<6, 1>(6 * f, 6 * f + c) +=
              (moved_jacobian.transpose() * (moved - moved_mean) - at) / h;
        }
      }
      // Other frames' blocks: moving frame fb's sample moves the mean by its change / k.
      for (int a = 0; a < k; ++a) {
        for (int c = 0; c < k; ++c) {
          if (c == a) continue;
          a_block.block<6, 6>(6 * frame[a], 6 * frame[c]).noalias() -=
              jacobian[a].transpose() * (value_derivative[c] / k);
        }
      }
    }
    block_jacobians[b] = std::move(a_block);
  });
  Eigen::MatrixXd jacobian = Eigen::MatrixXd::Zero(n, n);
  for (const Eigen::MatrixXd& block : block_jacobians) jacobian += block;  // fixed order
  return jacobian;
}

}  // namespace

Eigen::MatrixXd GradientJacobian(const std::vector<Frame>& frames,
                                 const CandidateSet& candidates,
                                 const std::vector<Eigen::Isometry3d>& frame_from_world,
                                 const std::vector<double>& step_mm,
                                 const std::vector<double>& step_rad,
                                 int num_threads) {
  // Frames of T phases: the tied cost's gradient is the sum of the phases' (design.md 12).
  const FramesByPhase phases(frames);
  Eigen::MatrixXd jacobian = OnePhaseGradientJacobian(phases[0], candidates, frame_from_world,
                                                      step_mm, step_rad, num_threads);
  for (int p = 1; p < phases.size(); ++p) {
    jacobian += OnePhaseGradientJacobian(phases[p], candidates, frame_from_world, step_mm,
                                         step_rad, num_threads);
  }
  return jacobian;
}

double PredictedTre(const Matrix6d& covariance, const std::vector<Eigen::Vector3d>& points_in_frame) {
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

bool EstimatePoseUncertainty(const std::vector<Frame>& frames,
                             const CandidateSet& candidates,
                             const std::vector<Eigen::Isometry3d>& frame_from_world,
                             const std::vector<Mask>& masks,
                             const StreamContext& context,
                             PoseUncertainty* uncertainty,
                             std::string* why,
                             Eigen::MatrixXd* curvature) {
  const int m = static_cast<int>(frames.size());
  const int n = 6 * (m - 1);
  ReducedSystem system;
  // Cost, observations and voxels only: the covariance uses GradientJacobian, not H.
  AccumulateReducedSystem(frames, candidates, frame_from_world, 0, candidates.num_voxels(),
                          /*with_jacobian=*/false, context, &system);
  const int64_t dof = system.observations - system.voxels - n;
  if (dof < n) {
    *why = "too few observations (" + std::to_string(system.observations) +
           ") for a noise estimate";
    return false;
  }
  // The derivative of the gradient over the free poses (GradientJacobian; the Gauss-Newton
  // matrix would overstate it, see above).
  std::vector<std::vector<Eigen::Vector3d>> points(m);
  std::vector<double> step_mm(m), step_rad(m);
  for (int i = 0; i < m; ++i) {
    points[i] = FieldOfViewPoints(masks[i], frames[i].geometry());
    const double radius = RmsRadius(points[i]);
    step_mm[i] = kCurvatureStepVoxels * frames[i].geometry().spacing_mm.minCoeff();
    step_rad[i] = step_mm[i] / std::max(radius, frames[i].geometry().spacing_mm.maxCoeff());
  }
  const Eigen::MatrixXd a =
      GradientJacobian(frames, candidates, frame_from_world, step_mm, step_rad,
                       context.num_threads)
          .bottomRightCorner(n, n);
  if (curvature != nullptr) *curvature = a;
  const Eigen::PartialPivLU<Eigen::MatrixXd> lu(a);
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eigen(0.5 * (a + a.transpose()),
                                                             Eigen::EigenvaluesOnly);
  if (!(eigen.eigenvalues().minCoeff() > 0.0)) {
    *why = "the cost's curvature at the final poses is not positive definite";
    return false;
  }
  const double variance = system.cost / static_cast<double>(dof);
  // The sandwich H^-1 Cov(g) H^-1 over the free poses (frame 0's rows dropped: the gauge).
  int64_t clusters = 0;
  const Eigen::MatrixXd gradient_covariance =
      ClusteredGradientCovariance(frames, candidates, frame_from_world, context.num_threads,
                                  &clusters)
          .bottomRightCorner(n, n);
  if (clusters < 2 * n) {
    *why = "too few independent parts of the overlap (" + std::to_string(clusters) +
           " cubes of " + std::to_string(kClusterVoxels) + " voxels) for a covariance";
    return false;
  }
  const Eigen::MatrixXd a_inverse = lu.inverse();
  const Eigen::MatrixXd covariance = a_inverse * gradient_covariance * a_inverse.transpose();
  *uncertainty = PoseUncertainty();
  uncertainty->noise_sigma = std::sqrt(variance);
  uncertainty->degrees_of_freedom = dof;
  uncertainty->covariance.assign(m, Matrix6d::Zero());
  uncertainty->predicted_tre_mm.assign(m, 0.0);
  for (int i = 1; i < m; ++i) {
    Matrix6d c = covariance.block<6, 6>(6 * (i - 1), 6 * (i - 1));
    c = 0.5 * (c + c.transpose()).eval();
    uncertainty->covariance[i] = c;
    uncertainty->predicted_tre_mm[i] = PredictedTre(c, points[i]);
  }
  return true;
}

namespace {

// UndeterminedPoses's judgement on `subset` of the candidates, `fraction` of them (its
// covariance scaled by it to all of them).
bool JudgeDetermination(const std::vector<Frame>& frames,
                        const CandidateSet& subset,
                        double fraction,
                        const std::vector<Eigen::Isometry3d>& frame_from_world,
                        const std::vector<Mask>& masks,
                        const StreamContext& context,
                        double max_error_voxels,
                        std::vector<UndeterminedPose>* undetermined,
                        std::string* why,
                        std::vector<double>* error_voxels) {
  const int m = static_cast<int>(frames.size());
  undetermined->clear();
  if (error_voxels != nullptr) error_voxels->clear();
  std::vector<std::vector<Eigen::Vector3d>> points(m);
  std::vector<double> radius(m), voxel(m);
  for (int i = 0; i < m; ++i) {
    points[i] = FieldOfViewPoints(masks[i], frames[i].geometry());
    radius[i] = std::max(RmsRadius(points[i]), frames[i].geometry().spacing_mm.maxCoeff());
    voxel[i] = frames[i].geometry().spacing_mm.minCoeff();
  }
  PoseUncertainty uncertainty;
  Eigen::MatrixXd a;
  if (!EstimatePoseUncertainty(frames, subset, frame_from_world, masks, context, &uncertainty,
                               why, &a)) {
    if (a.size() == 0) return false;  // not measured: too few observations
    // Not positive definite: each motion along which the curvature is not positive names the
    // frame it moves most (rotations weighted by the field of view's radius, so that both
    // are in mm), and whether it turns or shifts it.
    const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eigen(0.5 * (a + a.transpose()));
    if (eigen.eigenvalues()[0] > 0.0) return false;  // too few cubes for a covariance
    for (int e = 0; e < eigen.eigenvalues().size() && !(eigen.eigenvalues()[e] > 0.0); ++e) {
      const Eigen::VectorXd v = eigen.eigenvectors().col(e);
      int worst = 1;
      double largest = -1.0, turn = 0.0, shift = 0.0;
      for (int i = 1; i < m; ++i) {
        const double t = v.segment<3>(6 * (i - 1)).norm();
        const double r = v.segment<3>(6 * (i - 1) + 3).norm() * radius[i];
        if (std::hypot(t, r) > largest) {
          largest = std::hypot(t, r);
          worst = i;
          shift = t;
          turn = r;
        }
      }
      const bool known = std::any_of(undetermined->begin(), undetermined->end(),
                                     [&](const UndeterminedPose& u) { return u.frame == worst; });
      if (!known) {
        undetermined->push_back(
            {worst, turn > shift, std::numeric_limits<double>::infinity()});
      }
    }
    why->clear();
    return true;
  }
  for (int i = 1; i < m; ++i) {
    // The covariance of all the candidates' estimate is about `fraction` times the
    // quarter's (curvature and gradient covariance both grow with the observations).
    const Matrix6d c = fraction * uncertainty.covariance[i];
    const double error = PredictedTre(c, points[i]) / voxel[i];
    if (error_voxels != nullptr) {
      error_voxels->resize(m, 0.0);
      (*error_voxels)[i] = error;
    }
    if (!(error > max_error_voxels)) continue;
    // Mostly rotation when a rotation's spread moves the field of view more than the
    // translation's: (2/3) R^2 trace(C_phi) against trace(C_rho).
    const bool rotation = 2.0 / 3.0 * radius[i] * radius[i] * c.bottomRightCorner<3, 3>().trace() >
                          c.topLeftCorner<3, 3>().trace();
    undetermined->push_back({i, rotation, error});
  }
  std::stable_sort(undetermined->begin(), undetermined->end(),
                   [](const UndeterminedPose& x, const UndeterminedPose& y) {
                     return x.error_voxels > y.error_voxels;
                   });
  return true;
}

}  // namespace

bool UndeterminedPoses(const std::vector<Frame>& frames,
                       const CandidateSet& candidates,
                       const std::vector<Eigen::Isometry3d>& frame_from_world,
                       const std::vector<Mask>& masks,
                       const StreamContext& context,
                       double max_error_voxels,
                       std::vector<UndeterminedPose>* undetermined,
                       std::string* why,
                       std::vector<double>* error_voxels) {
  // A quarter of the cubes the gradient's covariance is clustered in (kClusterVoxels on a
  // side; those whose cube indices sum to a multiple of 4, spread evenly): the estimate costs
  // a pass of 7 samples per observation on the reference sampler, and an order of magnitude
  // is all this check needs. Whole cubes, so that the clusters stay what they are (thinning
  // rows inside them made the covariance 20 times too large on a wide-protocol sequence).
  const CandidateSet quarter = CandidatesInCubes(candidates, kClusterVoxels, 4);
  const double fraction = static_cast<double>(quarter.num_voxels()) /
                          std::max<int64_t>(1, candidates.num_voxels());
  if (JudgeDetermination(frames, quarter, fraction, frame_from_world, masks, context,
                         max_error_voxels, undetermined, why, error_voxels) &&
      undetermined->empty()) {
    return true;
  }
  // Where the quarter finds a pose undetermined (or cannot judge), all of the voxels judge: a
  // weak direction of a featureless frame (the chest CT's heart) can curve up too little for
  // a quarter of its voxels to show it above their noise.
  return JudgeDetermination(frames, candidates, 1.0, frame_from_world, masks, context,
                            max_error_voxels, undetermined, why, error_voxels);
}

std::string UndeterminedPhrase(const std::vector<UndeterminedPose>& undetermined) {
  std::ostringstream text;
  text.precision(3);
  text << "the data do not determine ";
  for (size_t k = 0; k < undetermined.size(); ++k) {
    const UndeterminedPose& u = undetermined[k];
    text << (k == 0 ? "" : k + 1 == undetermined.size() ? " and " : ", ") << "frame " << u.frame
         << "'s " << (u.rotation ? "rotation" : "translation") << " (";
    if (std::isinf(u.error_voxels)) {
      text << "the cost does not curve up along it";
    } else {
      text << "predicted error " << u.error_voxels << " voxels";
    }
    text << ")";
  }
  text << ": the anatomy in view looks the same after that motion (a symmetric or "
          "featureless object); mask out the symmetric part, or give more of the anatomy in "
          "view";
  return text.str();
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
