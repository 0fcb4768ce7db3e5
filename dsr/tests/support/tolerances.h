// Tolerances that several tests share, each with the reason for its size. A test's own
// tolerance (one check, its own measurement) stays beside that test.
#ifndef DSR_TESTS_SUPPORT_TOLERANCES_H_
#define DSR_TESTS_SUPPORT_TOLERANCES_H_

namespace dsr {
namespace testing_tolerances {

// The theorem (docs/design.md section 4): DBA's Schur-reduced Gauss-Newton step and DSR's
// reduced step are two exact linear-algebra routes to one step, so they agree to rounding
// (relative to the step's norm).
constexpr double kStepRelativeTolerance = 1e-9;

// The same sums accumulated in another order (per block or per residual block, batched or
// voxel by voxel, streamed or per pair): relative to the norm of the cost, gradient or matrix.
constexpr double kSystemRelativeTolerance = 1e-10;

// Full solves of DBA and DSR from the same start on lattice-aligned problems, whose fixed
// point is sharp (test_problems.h), run to Ceres's floor: they reach the same poses to
// rounding-level agreement (frames of 1 mm voxels: 1e-6 voxel).
constexpr double kFixedPointRotationRad = 1e-8;
constexpr double kFixedPointTranslationMm = 1e-6;

// A noise-free, lattice-aligned problem has its exact minimum at the ground truth; a
// solve run to convergence ends there to well within this (pose translation or target
// registration error, mm).
constexpr double kNoiseFreeAccuracyMm = 1e-3;

// Voxels are stored as float: values up to a few hundred carry ~3e-5 rounding error.
constexpr double kFloatValueTolerance = 1e-3;

}  // namespace testing_tolerances
}  // namespace dsr

#endif  // DSR_TESTS_SUPPORT_TOLERANCES_H_
