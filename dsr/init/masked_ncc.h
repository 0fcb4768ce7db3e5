// Masked normalised cross-correlation over every integer shift, computed with FFTs
// (Padfield, "Masked object registration in the Fourier domain", IEEE TIP 21(5), 2012).
//
// Used by the global search (init/placement_search.h): for each sampled rotation the moving
// volume is resampled rotated onto a grid with the fixed volume's spacing and axes, and the
// best integer translation between the two fields of view is the peak of this map.
//
// Convention: shift s (integer voxels, index axes i, j, k) places moving voxel q onto fixed
// voxel q + s. With F, Mf the fixed image and mask and G, Mg the moving ones, the overlap is
//   O(s) = { q : Mg(q) != 0 and Mf(q + s) != 0, q + s inside the fixed grid }
// and NCC(s) is the Pearson correlation of {F(q + s)} and {G(q)} over O(s). Voxels whose
// value is not finite count as outside their mask.
//
// Padfield's formulation. Write (A * B)(s) = sum_q A(q + s) B(q) for the (linear)
// cross-correlation of a fixed-grid volume A with a moving-grid volume B. Every sum over
// O(s) is such a correlation of masked volumes:
//   n(s)    = (Mf * Mg)(s)                       number of overlapping voxels
//   Sf(s)   = (F Mf * Mg)(s),    Sff(s) = (F^2 Mf * Mg)(s)
//   Sg(s)   = (Mf * G Mg)(s),    Sgg(s) = (Mf * G^2 Mg)(s)
//   Sfg(s)  = (F Mf * G Mg)(s)
//   num     = Sfg - Sf Sg / n
//   var_f   = Sff - Sf^2 / n,    var_g = Sgg - Sg^2 / n
//   NCC(s)  = num / sqrt(var_f var_g)
// Each correlation is IFFT(FFT(A) conj(FFT(B))) on a zero-padded grid of size P >= fixed +
// moving - 1 per axis, so the circular correlation never wraps one shift onto another: the
// shifts range over [-(moving - 1), fixed - 1] (fixed + moving - 1 values per axis), and
// shift s is read at circular index s mod P. The fixed side's 3 spectra are computed once;
// each moving volume costs 3 forward and 6 inverse real FFTs.
#ifndef DSR_INIT_MASKED_NCC_H_
#define DSR_INIT_MASKED_NCC_H_

#include <complex>
#include <cstdint>
#include <cstdlib>
#include <limits>
#include <memory>
#include <mutex>
#include <vector>

#include <Eigen/Core>

#include "dsr/geometry/volume.h"

namespace dsr {

// Overlaps whose variance per voxel is below this fraction of the whole masked volume's
// variance per voxel count as flat (no NCC): var_f(s) <= kFlatOverlapRelativeVariance *
// n(s) * var(F over Mf), the same for G. A contrast a thousand times below the image's
// (1e-6 in variance) is flat for any image this toolkit sees, and the threshold stays five
// orders of magnitude above the double FFT's round-off in var_f (about 1e-16 sqrt(N_f N_g)
// var(F), N = voxel counts up to 1e6), so round-off never makes a flat overlap look textured.
inline constexpr double kFlatOverlapRelativeVariance = 1e-6;

// One shift and its score. ncc = -inf (shift and overlap 0) when no shift qualifies.
struct NccPeak {
  Eigen::Vector3i shift = Eigen::Vector3i::Zero();  // ijk, moving voxel q -> fixed q + shift
  double ncc = -std::numeric_limits<double>::infinity();
  int64_t overlap = 0;  // n(shift): voxels in the overlap
};

// NCC at every shift s with first_shift <= s < first_shift + size (per axis), stored
// x-fastest: entry e = i + size[0] * (j + size[1] * k) is shift first_shift + (i, j, k).
// first_shift = -(moving size - 1), size = fixed size + moving size - 1: every shift at
// which the two grids overlap. ncc is -inf where the overlap has fewer than min_overlap
// voxels (or none) or is flat on either side; overlap holds n(s) everywhere.
struct NccMap {
  Eigen::Vector3i first_shift = Eigen::Vector3i::Zero();
  Eigen::Vector3i size = Eigen::Vector3i::Zero();
  std::vector<double> ncc;
  std::vector<int64_t> overlap;

  int64_t NumShifts() const { return int64_t{size[0]} * size[1] * size[2]; }
  // The shift of entry e.
  Eigen::Vector3i Shift(int64_t e) const;
};

// The best entry of `map`. Ties go to the smallest shift in lexicographic (z, y, x) order,
// i.e. the first in storage order, so the result is deterministic.
NccPeak BestPeak(const NccMap& map);

// Up to `max_peaks` peaks by greedy non-maximum suppression: the best entry, then the best
// entry farther than `suppression_radius` voxels (Chebyshev distance, max |ds| over the
// axes) from every peak taken so far, and so on. Best first, ties as in BestPeak. The
// first peak is BestPeak(map). Fewer when the qualifying shifts run out.
std::vector<NccPeak> SeparatedPeaks(const NccMap& map, int max_peaks, int suppression_radius);

// How FFTW chooses its algorithm for the padded grid.
enum class FftPlanning {
  // FFTW_ESTIMATE: chosen from the sizes and the CPU alone, so every run on one machine
  // rounds identically (a near-tie between two shifts always breaks the same way), and
  // planning is free. The guess is slower than the measured plan for many sizes.
  kEstimate,
  // FFTW_MEASURE: times candidate algorithms, once per grid size and process (later plans
  // of that size reuse FFTW's wisdom), for the fastest FFTs. The choice depends on the
  // timings of the moment, so two runs may round differently in the last bits.
  kMeasure,
};

struct MaskedNccOptions {
  FftPlanning fft_planning = FftPlanning::kEstimate;
};

// The fixed side of the masked NCC, prepared once for moving volumes of one size.
//
// Precision: double (fftw3). Single precision is only modestly faster (the FFTs are part of
// the time), and its round-off, relative to the whole volumes' energy rather than to an
// overlap's, swamps the variance of an overlap that lies in a constant background: such an
// overlap then gets an arbitrary NCC (up to 1) instead of none, and can win the search.
class MaskedNcc {
 public:
  // Computes the 3 fixed spectra (of F Mf, F^2 Mf and Mf, F minus its mean over Mf) on the
  // padded grid P = the smallest 2^a 3^b 5^c 7^d >= fixed + moving_size - 1 per axis, and
  // makes the FFTW plans (serialised by a process-wide mutex: FFTW's planner is not
  // thread-safe). `fixed` and `fixed_mask` must have the same size; only the index grids
  // are used (the caller resamples both volumes to one spacing and orientation).
  MaskedNcc(const Image& fixed,
            const Mask& fixed_mask,
            const Eigen::Vector3i& moving_size,
            const MaskedNccOptions& options = MaskedNccOptions());
  ~MaskedNcc();
  MaskedNcc(const MaskedNcc&) = delete;
  MaskedNcc& operator=(const MaskedNcc&) = delete;

  // NCC at every shift (see NccMap). `moving` and `moving_mask` must have size
  // moving_size. Thread-safe (FFTW's new-array execute functions are), so callers run
  // many rotations in parallel: each concurrent call takes its own set of FFT buffers
  // (7 real P grids and 2 half spectra, about 9 P_x P_y P_z doubles) from a pool that
  // keeps them for the next call and is freed with this object.
  NccMap Map(const Image& moving, const Mask& moving_mask, int64_t min_overlap) const;

  // BestPeak(Map(...)), without storing the map: the best shift with at least min_overlap
  // voxels of overlap, not flat on either side (kFlatOverlapRelativeVariance), or
  // ncc = -inf when there is none. Thread-safe like Map.
  NccPeak Best(const Image& moving, const Mask& moving_mask, int64_t min_overlap) const;

  // SeparatedPeaks(Map(...), max_peaks, suppression_radius).
  std::vector<NccPeak> Peaks(const Image& moving,
                             const Mask& moving_mask,
                             int64_t min_overlap,
                             int max_peaks,
                             int suppression_radius) const;

  const Eigen::Vector3i& fixed_size() const { return fixed_size_; }
  const Eigen::Vector3i& moving_size() const { return moving_size_; }
  // The FFT grid P (ijk order).
  const Eigen::Vector3i& padded_size() const { return padded_size_; }

 private:
  struct Plans;      // FFTW plans (fftw3.h stays out of this header)
  struct Workspace;  // one call's FFT buffers
  struct FreeDeleter {
    void operator()(void* p) const { std::free(p); }
  };
  using Real = double;  // the FFTs' precision (see the class comment)
  using RealBuffer = std::unique_ptr<Real[], FreeDeleter>;
  using ComplexBuffer = std::unique_ptr<std::complex<Real>[], FreeDeleter>;

  static RealBuffer AllocateReal(int64_t n);
  static ComplexBuffer AllocateComplex(int64_t n);
  std::unique_ptr<Workspace> AcquireWorkspace() const;
  void ReleaseWorkspace(std::unique_ptr<Workspace> workspace) const;
  // Calls visit(e, overlap, ncc) for every entry e of the map of `moving` in storage order
  // (ncc = -inf where undefined): Map stores them, Best keeps the best.
  template <typename Visit>
  void ForEachShift(const Image& moving,
                    const Mask& moving_mask,
                    int64_t min_overlap,
                    const Visit& visit) const;

  Eigen::Vector3i fixed_size_;
  Eigen::Vector3i moving_size_;
  Eigen::Vector3i padded_size_;
  int64_t num_real_ = 0;     // P_x P_y P_z
  int64_t num_complex_ = 0;  // (P_x / 2 + 1) P_y P_z: r2c keeps half of the x axis
  // Per-voxel variance of F over Mf (threshold of flat overlaps).
  double fixed_variance_ = 0.0;
  // Spectra of F Mf, F^2 Mf and Mf, already divided by P_x P_y P_z (FFTW's inverse is
  // unnormalised) so that an inverse transform of a product is the correlation itself.
  ComplexBuffer fixed_spectrum_f_;
  ComplexBuffer fixed_spectrum_ff_;
  ComplexBuffer fixed_spectrum_mask_;
  std::unique_ptr<Plans> plans_;
  // Buffers of finished calls. Fresh P-sized buffers per call cost nearly as much as the FFTs
  // (the kernel maps and zeroes every page); a pool keeps one set per concurrent caller.
  mutable std::mutex workspace_mutex_;
  mutable std::vector<std::unique_ptr<Workspace>> idle_workspaces_;
};

// The smallest m >= n whose only prime factors are 2, 3, 5 and 7 (sizes FFTW is fast at).
int FftFriendlySize(int n);

// Slow twin of MaskedNcc::Map for tests: every shift by direct summation in double, each
// overlap's means first and then its centred sums (two passes), with the same flat-overlap
// rule. O(shifts x moving voxels).
NccMap NccMapBruteForce(const Image& fixed,
                        const Mask& fixed_mask,
                        const Image& moving,
                        const Mask& moving_mask,
                        int64_t min_overlap);

// BestPeak(NccMapBruteForce(...)).
NccPeak BestShiftBruteForce(const Image& fixed,
                            const Mask& fixed_mask,
                            const Image& moving,
                            const Mask& moving_mask,
                            int64_t min_overlap);

}  // namespace dsr

#endif  // DSR_INIT_MASKED_NCC_H_
