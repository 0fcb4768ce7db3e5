// The objective's per-voxel term: the extension point of the streamed normal equations
// (docs/design.md section 11). StreamNormalEquations (stream/voxel_stream.h) samples every
// observer of a panorama voxel and hands the voxel to a term; the term decides what the
// voxel contributes to the cost, the gradient and the Gauss-Newton matrix. A new
// similarity term is a new type with the interface below; the stream, its threads, its
// determinism and its SIMD kernels are shared.
//
// A voxel term `Term` is a type with
//  * `void operator()(const VoxelObservations& obs, bool with_jacobian,
//    VoxelAccumulator* acc) const`: called once per voxel that k >= 2 frames observe, with
//    their frames (increasing), their sampled values and, when with_jacobian, their
//    Jacobians J_a (1 x 6, d value / d frame tangent). It adds the voxel's cost and
//    observation count to acc (acc->cost, acc->observations; acc->frame_cost and
//    acc->frame_observations when it splits its cost by frame, else it leaves them) and,
//    when with_jacobian, its gradient g = J^T r and Gauss-Newton matrix H = J^T J of the
//    cost written as sum r^2 (so the cost's derivative is 2 g): g into acc->gradient (p
//    entries per frame), H into at least the upper block triangle (frame a <= frame b) of
//    the row-major acc->hessian (acc->n x acc->n), the diagonal blocks at least on and
//    above their diagonal (AddOuter does this). Calls run concurrently on different
//    accumulators: the term is read-only.
//  * `bool batched_hessian` and `bool batched_gradient`: when batched_hessian is true the
//    term adds no Gauss-Newton terms itself; the stream adds
//        H_ab += (delta_ab * diagonal + shared) J_a^T J_b
//    for it, a batch of voxels at a time with SIMD kernels (stream/hessian_batch.h). When
//    batched_gradient is true too, the term writes its residual r_a of each observation to
//    obs.residual (set by the stream) instead of adding its gradient, and the stream adds
//    g_{frame[a]} += r_a J_a the same way.
//  * `HessianWeights Weights(int k) const`: the batched form's (diagonal, shared) for a
//    voxel with k observers (read only when batched_hessian).
//  * optionally `static constexpr int kFrameParameters`: 6 (the default: the pose tangent)
//    or 8 (the pose tangent, log gain and offset: docs/design.md section 2.8; the term then
//    writes each observation's wide Jacobian to obs.wide_jac, which the batched kernels
//    read, and its g and H have 8 parameters per frame).
//  * optionally a member `const double* projection_factors` (u_f per frame, not null): the
//    batched form is then H_ab += (delta_ab - u_a u_b / sum_c u_c^2) J_a^T J_b (Weights is
//    not read).
// IsVoxelTerm<Term> checks this at compile time; StreamNormalEquations refuses a type that
// fails it, naming the missing part.
//
// Implementations: SsdToMeanTerm (stream/ssd_to_mean_term.h), DSR's sum of squared
// differences to the per-voxel mean with the batched form; DSR's photometric and weighted
// variants (stream/reduced_system.cc); APE's pairwise term (baselines/ape.cc). A term
// without a batched form sets both flags false and adds its own g and H (AddGradient,
// AddOuter): slower, and the simplest start. Write the per-voxel reference cost first
// (docs/design.md section 4.5) and test the term's cost, gradient and Gauss-Newton matrix
// against it and its Jacobians against numeric differences of its cost.
#ifndef DSR_STREAM_VOXEL_TERM_H_
#define DSR_STREAM_VOXEL_TERM_H_

#include <cstddef>
#include <cstdint>
#include <type_traits>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "dsr/model/observation.h"
#include "dsr/stream/hessian_batch.h"

namespace dsr {

// Jacobian layout in a batch: J_ij = [d/d rho (3), d/d phi (3)], 6 doubles, the k
// Jacobians of a voxel contiguous (its row of the stacked S = [J_0 ... J_{k-1}], which the
// Gauss-Newton kernel reads as 6k consecutive doubles).
constexpr int kJacobianSize = 6;
// With photometric parameters (docs/design.md section 2.8) a term works with wide
// Jacobians J'_ij = [a_i J_ij, a_i I_i(p_ij), 1] (pose, log gain, offset of frame i).
constexpr int kWideJacobianSize = 8;

// The observers of one voxel, as the stream hands them to a term: k >= 2 frames
// `frame[a]` with value `value[a]` and, when Jacobians are wanted, J in `jac[a]`.
struct VoxelObservations {
  int k = 0;
  int64_t voxel = -1;  // the voxel's index in the CandidateSet
  const int* frame = nullptr;
  const double* value = nullptr;
  const double (*jac)[kJacobianSize] = nullptr;
  // Set (with Jacobians) for terms with batched_gradient: the term writes its residual
  // r_a of each observation here instead of adding g_{frame[a]} += r_a J_a itself.
  double* residual = nullptr;
  // Set (with Jacobians) for terms with 8 parameters per frame: the term writes each
  // observation's wide Jacobian here (the stream's batched kernels read it).
  double (*wide_jac)[kWideJacobianSize] = nullptr;
};

// Per-block accumulator: H (row-major, n x n with n = p m, p the term's parameters per
// frame; terms fill at least the upper block triangle, see above), g (n), cost.
struct VoxelAccumulator {
  int n = 0;
  std::vector<double> hessian, gradient;
  double cost = 0.0;
  int64_t observations = 0;
  int64_t voxels = 0;
  double frame_cost[kMaxFrames] = {};
  int64_t frame_observations[kMaxFrames] = {};
};

// g_a += s J_a (6 tangent entries of frame fa).
// (Eigen's fixed-size maps: three 2-lane packets; a plain loop stayed scalar here.)
inline void AddGradient(double* g, int fa, const double* ja, double s) {
  Eigen::Map<Eigen::Matrix<double, 6, 1>>(g + 6 * static_cast<ptrdiff_t>(fa)) +=
      s * Eigen::Map<const Eigen::Matrix<double, 6, 1>>(ja);
}

// Adds J_a^T s J_b (6 entries each) to the (frame fa, frame fb) block of a row-major
// n x n matrix; only the upper triangle of the block when fa == fb.
inline void AddOuter(double* h, int n, int fa, int fb, const double* ja, const double* jb,
                     double s) {
  if (fa == fb) {
    for (int i = 0; i < 6; ++i) {
      const double si = s * ja[i];
      double* row = h + (6 * fa + i) * n + 6 * fa;
      for (int j = i; j < 6; ++j) row[j] += si * jb[j];
    }
    return;
  }
  for (int i = 0; i < 6; ++i) {
    const double si = s * ja[i];
    double* row = h + (6 * fa + i) * n + 6 * fb;
    for (int j = 0; j < 6; ++j) row[j] += si * jb[j];
  }
}

namespace internal {

// A term's parameters per frame: Term::kFrameParameters when it declares it, else 6.
template <class Term, class = void>
struct FrameParametersOf {
  static constexpr int value = kJacobianSize;
};
template <class Term>
struct FrameParametersOf<Term, std::void_t<decltype(Term::kFrameParameters)>> {
  static constexpr int value = Term::kFrameParameters;
};

// A term's projection factors (one per frame, for the batched H of a weighted mean:
// stream/hessian_batch.h) when it has a member `const double* projection_factors`, else none.
template <class Term, class = void>
struct ProjectionFactorsOf {
  static const double* Get(const Term&) { return nullptr; }
};
template <class Term>
struct ProjectionFactorsOf<Term, std::void_t<decltype(Term::projection_factors)>> {
  static const double* Get(const Term& term) { return term.projection_factors; }
};

// The compile-time check of the interface in this header's comment, part by part.

template <class Term, class = void>
struct HasVoxelCall : std::false_type {};
template <class Term>
struct HasVoxelCall<Term,
                    std::void_t<decltype(std::declval<const Term&>()(
                        std::declval<const VoxelObservations&>(), std::declval<bool>(),
                        std::declval<VoxelAccumulator*>()))>> : std::true_type {};

template <class Term, class = void>
struct HasBatchFlags : std::false_type {};
template <class Term>
struct HasBatchFlags<Term,
                     std::void_t<decltype(std::declval<const Term&>().batched_hessian),
                                 decltype(std::declval<const Term&>().batched_gradient)>>
    : std::integral_constant<
          bool,
          std::is_convertible<decltype(std::declval<const Term&>().batched_hessian), bool>::value &&
              std::is_convertible<decltype(std::declval<const Term&>().batched_gradient),
                                  bool>::value> {};

template <class Term, class = void>
struct HasHessianWeights : std::false_type {};
template <class Term>
struct HasHessianWeights<Term, std::void_t<decltype(std::declval<const Term&>().Weights(2))>>
    : std::is_same<decltype(std::declval<const Term&>().Weights(2)), HessianWeights> {};

template <class Term>
struct HasValidFrameParameters
    : std::integral_constant<bool, FrameParametersOf<Term>::value == kJacobianSize ||
                                       FrameParametersOf<Term>::value == kWideJacobianSize> {};

}  // namespace internal

// Whether `Term` is a voxel term (the interface in this header's comment).
template <class Term>
struct IsVoxelTerm
    : std::integral_constant<bool, internal::HasVoxelCall<Term>::value &&
                                       internal::HasBatchFlags<Term>::value &&
                                       internal::HasHessianWeights<Term>::value &&
                                       internal::HasValidFrameParameters<Term>::value> {};

// The same, part by part, with messages: StreamNormalEquations calls it.
template <class Term>
constexpr void CheckVoxelTerm() {
  static_assert(internal::HasVoxelCall<Term>::value,
                "a voxel term is callable as term(const VoxelObservations&, bool with_jacobian, "
                "VoxelAccumulator*) const (stream/voxel_term.h)");
  static_assert(internal::HasBatchFlags<Term>::value,
                "a voxel term has bool members batched_hessian and batched_gradient "
                "(stream/voxel_term.h)");
  static_assert(internal::HasHessianWeights<Term>::value,
                "a voxel term has HessianWeights Weights(int k) const (stream/voxel_term.h)");
  static_assert(internal::HasValidFrameParameters<Term>::value,
                "a voxel term's kFrameParameters is 6 or 8 (stream/voxel_term.h)");
}

}  // namespace dsr

#endif  // DSR_STREAM_VOXEL_TERM_H_
