// Pose uncertainty of a registration (docs/design.md section 8.6), off by default
// (RegistrationOptions::uncertainty, dsr_register --uncertainty): it costs one pass of one
// sample per observation, with the slopes of the sample's interpolants.
//
// DSR stops where its gradient g = sum_j sum_a J_aj^T r_aj vanishes (r_aj = I_a(p_aj) -
// mu_j, the panorama intensities eliminated). Linearised about the true poses, the pose
// error is delta = -A^-1 g(T_true) with A = dg/d delta, so
//     Cov(delta) = A_ff^-1 C_g A_ff^-T   (frames 1..m-1; frame 0 is the gauge),
// with C_g the covariance of the gradient estimated from the residuals cube by cube (cubes
// of 8 panorama voxels: g_B its share of cube B, C_g = sum_B g_B g_B^T), robust to the
// correlation trilinear resampling puts between neighbouring residuals. A is not the
// Gauss-Newton matrix H = sum J^T J, which is the Schur complement of DBA's information
// matrix (the theorem) and would give s^2 H^-1: with noisy frames the gradient volumes
// are noisy, J^T J overstates the curvature (1.5-2x on the paper's frames at sigma 25) and
// the covariance came out 2-4x too small in TRE. A is measured from the slopes of each
// sample's interpolants (SumForUncertainty; GradientJacobian below is its slow twin).
// delta is the tangent [rho; phi] of a left perturbation T_est = Exp(delta) T_true (mm, rad).
//
// A frame's predicted TRE is the expected mean, over the centres x of its field-of-view
// voxels (frame mm), of the displacement |rho + phi x x| = |[I, -[x]x] delta| that a pose
// error delta ~ N(0, Cov_i) causes (the TRE of eval/eval.h to first order), estimated from
// a fixed set of draws.
//
// What it does not cover: a wrong local minimum, intensities that do not follow the model
// (a gain or offset between frames), and the interpolation bias of resampled frames (about
// 0.01 mm on the simulated sequences without noise; docs/design.md 8.6 has the measured
// calibration).
#ifndef DSR_PIPELINE_UNCERTAINTY_H_
#define DSR_PIPELINE_UNCERTAINTY_H_

#include <string>
#include <vector>

#include "dsr/geometry/se3.h"
#include "dsr/geometry/volume.h"
#include "dsr/image/frame.h"
#include "dsr/model/observation.h"
#include "dsr/model/photometric.h"
#include "dsr/stream/voxel_stream.h"

namespace dsr {

struct PoseUncertainty {
  std::vector<Matrix6d> covariance;      // per frame; frame 0's is zero (the gauge)
  std::vector<double> predicted_tre_mm;  // per frame; frame 0's is 0
  double noise_sigma = 0.0;              // s, in the frames' intensity units
  int64_t degrees_of_freedom = 0;
};

// What the estimate sums over candidate voxels, in one pass of one sample per observation
// (SumForUncertainty): the cost and its observations, the gradient's clustered covariance
// (cubes of 8 panorama voxels) and its derivative A, each kept per group of whole cubes
// (cubes assigned to kUncertaintyGroups groups by a hash of their index), so that the
// spread of an estimate from a subset of the cubes can be measured by a jackknife over the
// groups (UndeterminedPoses).
constexpr int kUncertaintyGroups = 8;
struct UncertaintySums {
  int64_t observations = 0;  // in (voxel, phase) pairs with at least 2 valid observations
  int64_t voxels = 0;        // such (voxel, phase) pairs
  int64_t clusters = 0;      // cubes with a non-zero share of the gradient
  double cost = 0.0;         // sum of squared residuals
  // Per group (kUncertaintyGroups): A over its voxels and sum_B g_B g_B^T over its cubes
  // (6m x 6m, all frames), its voxels.
  std::vector<Eigen::MatrixXd> curvature;
  std::vector<Eigen::MatrixXd> gradient_covariance;
  std::vector<int64_t> group_voxels;
  // The sums over every group, or over every group but `left_out` (>= 0).
  Eigen::MatrixXd Curvature(int left_out = -1) const;
  Eigen::MatrixXd GradientCovariance(int left_out = -1) const;
};

// The sums above at `frame_from_world` over `candidates` (views of T phases: the phases'
// sums, as the tied cost's gradient). A comes from the slopes of each sample's interpolants
// (Frame::SampleSlopesAtIndex): the derivative of the gradient at the sample itself, where
// GradientJacobian below, its slow twin, moves each sample by a step and samples again.
// Deterministic for any thread count.
// With keep_one_in > 1, over 1 in keep_one_in of the cubes only (chosen by a fixed hash of
// their indices): about 1 / keep_one_in of the candidates, spread evenly, in whole cubes.
// With `photometric` (one per frame), on the corrected samples gain * I + offset: the sums of
// frames whose voxels were so corrected, the gains and offsets held fixed.
UncertaintySums SumForUncertainty(const std::vector<Frame>& frames,
                                  const CandidateSet& candidates,
                                  const std::vector<Eigen::Isometry3d>& frame_from_world,
                                  int num_threads,
                                  int keep_one_in = 1,
                                  const std::vector<Photometric>* photometric = nullptr);

// The estimate above at `frame_from_world` (frame 0 first, the gauge) over `candidates`, on
// the frames of the finest level; `masks` (the frames' input masks) give the field-of-view
// points of the predicted TRE. noise_sigma is the residuals' RMS over the degrees of
// freedom (observations - voxels - 6 (m - 1)). False, with `why`, when the poses are not
// determined (H_ff not positive definite), too few observations are left, or the overlap
// has fewer than 2 cubes per free pose parameter.
// With `curvature` (may be null), A over the free poses (6 (m - 1) square) whenever it was
// measured, positive definite or not.
bool EstimatePoseUncertainty(const std::vector<Frame>& frames,
                             const CandidateSet& candidates,
                             const std::vector<Eigen::Isometry3d>& frame_from_world,
                             const std::vector<Mask>& masks,
                             const StreamContext& context,
                             PoseUncertainty* uncertainty,
                             std::string* why,
                             Eigen::MatrixXd* curvature = nullptr);
// The same from sums already taken over all of `candidates` (SumForUncertainty).
bool EstimatePoseUncertainty(const UncertaintySums& sums,
                             const std::vector<Frame>& frames,
                             const std::vector<Mask>& masks,
                             PoseUncertainty* uncertainty,
                             std::string* why,
                             Eigen::MatrixXd* curvature = nullptr);

// A frame whose pose the data do not fix (symmetric anatomy, a featureless overlap): its
// predicted error (one standard deviation, RMS over its field of view) in its own voxels,
// infinite where the cost's curvature along some motion of it is not positive, and whether
// that is mostly its rotation (else its translation).
struct UndeterminedPose {
  int frame = 0;
  bool rotation = false;
  double error_voxels = 0.0;
};

// The determination check of the final poses (docs/design.md 8.7): every frame whose
// predicted error (the RMS over its field of view of the displacement one standard
// deviation of the estimate above puts on it) exceeds max_error_voxels of its voxels, or
// along whose motion the curvature is not positive, worst first. Judged first on a subset
// of the candidates in whole cubes of the gradient's clusters (about 4 cubes per free pose
// parameter, where that is at most half of them; its covariance scaled to all of them),
// whose verdict stands only where every pose's error, less the subset's bias, stays under
// the limit by 5 standard errors of the subset's own spread (a jackknife over the groups of
// cubes, which estimates both); otherwise on all of them. With
// `all_sums` (the sums over all of `candidates`, already taken for --uncertainty) on those
// alone. True when it could judge (false, with `why`, when too few observations are left
// for a noise estimate). `error_voxels` (may be null): every frame's predicted error in its
// voxels where the curvature is positive (frame 0: 0). With `photometric` (runs that
// estimate gains and offsets), on the corrected frames, whose cost the solve minimised (the
// gains and offsets held fixed): brightness the correction removes neither counts as noise
// nor bends the curvature (frames whose gains differ by 30 % looked undetermined on their
// own intensities).
bool UndeterminedPoses(const std::vector<Frame>& frames,
                       const CandidateSet& candidates,
                       const std::vector<Eigen::Isometry3d>& frame_from_world,
                       const std::vector<Mask>& masks,
                       const StreamContext& context,
                       double max_error_voxels,
                       std::vector<UndeterminedPose>* undetermined,
                       std::string* why,
                       std::vector<double>* error_voxels = nullptr,
                       const UncertaintySums* all_sums = nullptr,
                       const std::vector<Photometric>* photometric = nullptr);

// "the data do not determine frame 2's rotation (...)" for the frames found, naming each
// frame, what is undetermined and its predicted error.
std::string UndeterminedPhrase(const std::vector<UndeterminedPose>& undetermined);

// One line for the tools' summaries: the predicted TRE over frames 1..m-1 (median and
// largest, with its frame), the residual sigma and the degrees of freedom; or, when the
// covariance is empty, "not estimated: " and `note`.
std::string UncertaintySummary(const PoseUncertainty& uncertainty, const std::string& note);

// A = dg/d delta (6m x 6m, all frames), the derivative of the reduced gradient
// g_f = sum_j J_fj^T (I_f(p_fj) - mu_j) with respect to the poses, by forward differences
// of the samples (the slow twin of SumForUncertainty's A, which takes the same derivative
// from the interpolants' slopes at each sample, in one pass): frame f's samples are moved by
// step_mm[f] along each translation axis and step_rad[f] about each rotation axis, mu_j follows,
// the other frames' samples stay (the samples are trilinear, linear along each axis inside a cell,
// so a small forward step is as good as a central one and costs half).
//   own block  (f, f): Gauss-Newton's J^T J (1 - 1/k) plus sum_j r_fj dJ_fj / d delta_f,
//   other block (f, b): -sum_j J_fj^T (d I_b(p_bj) / d delta_b) / k_j.
// Not the Gauss-Newton matrix: J is the interpolated gradient volume, not the derivative of
// the interpolated intensity, and with noisy frames the residual term is not small. The
// registration stops where g = 0, so A (not J^T J) maps the noise of g to the poses. A
// sample that leaves the field of view at the step is left out of that difference.
// Deterministic for any thread count.
Eigen::MatrixXd GradientJacobian(const std::vector<Frame>& frames,
                                 const CandidateSet& candidates,
                                 const std::vector<Eigen::Isometry3d>& frame_from_world,
                                 const std::vector<double>& step_mm,
                                 const std::vector<double>& step_rad,
                                 int num_threads);

// The expected mean displacement over `points_in_frame` (mm) of a pose error with
// covariance `covariance` (see above); deterministic.
double PredictedTre(const Matrix6d& covariance,
                    const std::vector<Eigen::Vector3d>& points_in_frame);

// The normalised squared error e^T Cov^-1 e of a pose estimate against the truth, with
// e = Log(T_est T_true^-1) (both relative to frame 0): about 6 on average when the
// covariance is calibrated.
double NormalisedSquaredError(const Eigen::Isometry3d& estimated_frame_from_world,
                              const Eigen::Isometry3d& true_frame_from_world,
                              const Matrix6d& covariance);

}  // namespace dsr

#endif  // DSR_PIPELINE_UNCERTAINTY_H_
