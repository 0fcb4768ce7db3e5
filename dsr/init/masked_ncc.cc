#include "dsr/init/masked_ncc.h"

#include <algorithm>
#include <cmath>
#include <mutex>

#include <fftw3.h>
#include <glog/logging.h>

namespace dsr {
namespace {

// FFTW's planner (plan creation and destruction) is not thread-safe; only the execute
// functions are. Every plan of this file is made and destroyed under this lock.
std::mutex& FftwPlannerMutex() {
  static std::mutex mutex;
  return mutex;
}

// Alignment of every FFT buffer. FFTW's new-array execute functions require arrays with the
// same alignment as the planning arrays; 64 bytes covers every SIMD width FFTW uses, so
// all buffers of this file have fftw_alignment_of() = 0, like the planning ones.
constexpr size_t kFftAlignment = 64;

void* AlignedAllocate(size_t bytes) {
  // std::aligned_alloc needs a size that is a multiple of the alignment.
  const size_t rounded = (bytes + kFftAlignment - 1) / kFftAlignment * kFftAlignment;
  void* p = std::aligned_alloc(kFftAlignment, std::max(rounded, kFftAlignment));
  CHECK(p != nullptr) << "out of memory allocating " << bytes << " bytes for FFT buffers";
  return p;
}

bool Inside(uint8_t mask, float value) { return mask != 0 && std::isfinite(value); }

// Mean and per-voxel variance (both over the voxels inside the mask with finite values),
// in double, two passes. Zero for an empty mask.
struct MaskedMoments {
  double mean = 0.0;
  double variance = 0.0;
  int64_t count = 0;
};

MaskedMoments ComputeMaskedMoments(const Image& image, const Mask& mask) {
  MaskedMoments m;
  double sum = 0.0;
  for (size_t l = 0; l < image.voxels.size(); ++l) {
    if (!Inside(mask.voxels[l], image.voxels[l])) continue;
    sum += image.voxels[l];
    ++m.count;
  }
  if (m.count == 0) return m;
  m.mean = sum / m.count;
  double sum_squares = 0.0;
  for (size_t l = 0; l < image.voxels.size(); ++l) {
    if (!Inside(mask.voxels[l], image.voxels[l])) continue;
    const double d = image.voxels[l] - m.mean;
    sum_squares += d * d;
  }
  m.variance = sum_squares / m.count;
  return m;
}

// An overlap of n voxels with sum of squared deviations `centred_sum_squares` is textured
// (has an NCC) when that sum exceeds the flat threshold of kFlatOverlapRelativeVariance.
// A volume with zero variance is flat everywhere (every subset of a constant is constant),
// even where round-off makes the FFT's difference slightly positive.
bool Textured(double centred_sum_squares, double n, double volume_variance) {
  return volume_variance > 0.0 &&
         centred_sum_squares > kFlatOverlapRelativeVariance * n * volume_variance;
}

// Pearson correlation from the centred sums, clamped to [-1, 1] (round-off can push
// |num| a hair above sqrt(var_f var_g) at a perfect correlation).
double ClampedCorrelation(double num, double var_f, double var_g) {
  return std::clamp(num / std::sqrt(var_f * var_g), -1.0, 1.0);
}

void CheckSizes(const Image& image, const Mask& mask, const char* what) {
  CHECK(image.geometry.size == mask.geometry.size)
      << what << ": image size " << image.geometry.size.transpose() << " != mask size "
      << mask.geometry.size.transpose();
  CHECK_EQ(static_cast<int64_t>(image.voxels.size()), image.geometry.NumVoxels()) << what;
  CHECK_EQ(static_cast<int64_t>(mask.voxels.size()), mask.geometry.NumVoxels()) << what;
  CHECK_GE(image.geometry.size.minCoeff(), 1) << what << ": empty volume";
}

// Where every shift of the map lies: its first shift and extent.
NccMap MapShape(const Eigen::Vector3i& fixed_size, const Eigen::Vector3i& moving_size) {
  NccMap shape;
  shape.first_shift = -(moving_size - Eigen::Vector3i::Ones());
  shape.size = fixed_size + moving_size - Eigen::Vector3i::Ones();
  return shape;
}

// A map with no NCC anywhere and zero overlaps.
NccMap EmptyMap(const Eigen::Vector3i& fixed_size, const Eigen::Vector3i& moving_size) {
  NccMap map = MapShape(fixed_size, moving_size);
  map.ncc.assign(map.NumShifts(), -std::numeric_limits<double>::infinity());
  map.overlap.assign(map.NumShifts(), 0);
  return map;
}

}  // namespace

Eigen::Vector3i NccMap::Shift(int64_t e) const {
  const int i = static_cast<int>(e % size[0]);
  const int64_t jk = e / size[0];
  const int j = static_cast<int>(jk % size[1]);
  const int k = static_cast<int>(jk / size[1]);
  return first_shift + Eigen::Vector3i(i, j, k);
}

NccPeak BestPeak(const NccMap& map) {
  NccPeak best;
  int64_t best_entry = -1;
  // Strictly greater: among equal scores the first entry in storage order (x fastest,
  // shifts increasing) wins, i.e. the smallest shift in (z, y, x) lexicographic order.
  for (int64_t e = 0; e < map.NumShifts(); ++e) {
    if (map.ncc[e] > best.ncc) {
      best.ncc = map.ncc[e];
      best_entry = e;
    }
  }
  if (best_entry < 0) return NccPeak();
  best.shift = map.Shift(best_entry);
  best.overlap = map.overlap[best_entry];
  return best;
}

std::vector<NccPeak> SeparatedPeaks(const NccMap& map, int max_peaks, int suppression_radius) {
  CHECK_GE(suppression_radius, 0);
  std::vector<NccPeak> peaks;
  if (max_peaks <= 0) return peaks;
  // Greedy suppression on a copy: take the best entry, set its (2r + 1)^3 neighbourhood to
  // -inf, repeat. Each round is one BestPeak, so ties resolve the same way.
  NccMap remaining = map;
  const int r = suppression_radius;
  while (static_cast<int>(peaks.size()) < max_peaks) {
    const NccPeak peak = BestPeak(remaining);
    if (!std::isfinite(peak.ncc)) break;
    peaks.push_back(peak);
    const Eigen::Vector3i centre = peak.shift - map.first_shift;
    const Eigen::Vector3i lo = (centre.array() - r).max(0);
    const Eigen::Vector3i hi = (centre.array() + r).min(map.size.array() - 1);
    for (int k = lo[2]; k <= hi[2]; ++k) {
      for (int j = lo[1]; j <= hi[1]; ++j) {
        for (int i = lo[0]; i <= hi[0]; ++i) {
          remaining.ncc[i + int64_t{map.size[0]} * (j + int64_t{map.size[1]} * k)] =
              -std::numeric_limits<double>::infinity();
        }
      }
    }
  }
  return peaks;
}

int FftFriendlySize(int n) {
  CHECK_GE(n, 1);
  for (int m = n;; ++m) {
    int rest = m;
    for (int p : {2, 3, 5, 7}) {
      while (rest % p == 0) rest /= p;
    }
    if (rest == 1) return m;
  }
}

// One r2c plan (real P grid -> half spectrum) and one c2r plan (back), both single-threaded:
// the caller parallelises across moving volumes (rotations), which scales better than
// splitting one transform of this size across threads.
struct MaskedNcc::Plans {
  fftw_plan forward = nullptr;
  fftw_plan inverse = nullptr;
};

// The buffers of one call. The six correlations land in n, sf, sff, sg, sgg and sfg;
// `input` holds each zero-padded moving volume and `spectrum` its transform, one at a
// time; `product` is the c2r input (which c2r destroys).
struct MaskedNcc::Workspace {
  RealBuffer input, n, sf, sff, sg, sgg, sfg;
  ComplexBuffer spectrum, product;
};

MaskedNcc::RealBuffer MaskedNcc::AllocateReal(int64_t n) {
  return RealBuffer(static_cast<Real*>(AlignedAllocate(sizeof(Real) * n)));
}

MaskedNcc::ComplexBuffer MaskedNcc::AllocateComplex(int64_t n) {
  return ComplexBuffer(
      static_cast<std::complex<Real>*>(AlignedAllocate(sizeof(std::complex<Real>) * n)));
}

namespace {

// Writes `value(l)` of a volume of size `size` (l its linear index) into the low corner of
// the grid of size `padded` (same x-fastest layout) and zero into the rest of the grid: the
// r2c plans may overwrite their input (planned without FFTW_PRESERVE_INPUT, which makes
// FFTW copy every input), so every transform writes all of it.
template <typename Real, typename ValueFn>
void Embed(const Eigen::Vector3i& size,
           const Eigen::Vector3i& padded,
           const ValueFn& value,
           Real* out) {
  int64_t l = 0;
  const int64_t row_length = padded[0];
  const int64_t slab = row_length * padded[1];
  for (int k = 0; k < size[2]; ++k) {
    Real* slab_start = out + slab * k;
    for (int j = 0; j < size[1]; ++j) {
      Real* row = slab_start + row_length * j;
      for (int i = 0; i < size[0]; ++i, ++l) row[i] = static_cast<Real>(value(l));
      std::fill(row + size[0], row + row_length, Real{0});
    }
    std::fill(slab_start + row_length * size[1], slab_start + slab, Real{0});
  }
  std::fill(out + slab * size[2], out + slab * padded[2], Real{0});
}

}  // namespace

MaskedNcc::MaskedNcc(const Image& fixed,
                     const Mask& fixed_mask,
                     const Eigen::Vector3i& moving_size,
                     const MaskedNccOptions& options)
    : fixed_size_(fixed.geometry.size), moving_size_(moving_size), plans_(new Plans) {
  CheckSizes(fixed, fixed_mask, "MaskedNcc fixed");
  CHECK_GE(moving_size.minCoeff(), 1) << "moving size " << moving_size.transpose();
  for (int a = 0; a < 3; ++a) {
    padded_size_[a] = FftFriendlySize(fixed_size_[a] + moving_size_[a] - 1);
  }
  num_real_ = int64_t{padded_size_[0]} * padded_size_[1] * padded_size_[2];
  num_complex_ = int64_t{padded_size_[0] / 2 + 1} * padded_size_[1] * padded_size_[2];

  RealBuffer real = AllocateReal(num_real_);
  ComplexBuffer complex = AllocateComplex(num_complex_);
  {
    // FFTW's arrays are row-major with the last dimension fastest: (P_z, P_y, P_x) is
    // this file's x-fastest layout. FFTW_MEASURE overwrites the planning arrays: they
    // are filled only after planning.
    const unsigned rigor =
        options.fft_planning == FftPlanning::kMeasure ? FFTW_MEASURE : FFTW_ESTIMATE;
    std::lock_guard<std::mutex> lock(FftwPlannerMutex());
    plans_->forward = fftw_plan_dft_r2c_3d(padded_size_[2],
                                           padded_size_[1],
                                           padded_size_[0],
                                           real.get(),
                                           reinterpret_cast<fftw_complex*>(complex.get()),
                                           rigor);
    plans_->inverse = fftw_plan_dft_c2r_3d(padded_size_[2],
                                           padded_size_[1],
                                           padded_size_[0],
                                           reinterpret_cast<fftw_complex*>(complex.get()),
                                           real.get(),
                                           rigor);
  }
  CHECK(plans_->forward != nullptr && plans_->inverse != nullptr)
      << "FFTW could not plan a " << padded_size_.transpose() << " transform";

  // Centring F on its mean over Mf leaves every NCC unchanged (Pearson is invariant to an
  // offset) but keeps Sff and Sf^2 / n small, so their difference var_f loses fewer digits.
  const MaskedMoments moments = ComputeMaskedMoments(fixed, fixed_mask);
  fixed_variance_ = moments.variance;
  const float* f = fixed.voxels.data();
  const uint8_t* mf = fixed_mask.voxels.data();
  // The inverse FFT is unnormalised (it returns P_x P_y P_z times the correlation): fold
  // the 1 / (P_x P_y P_z) into the fixed spectra once.
  const Real scale = Real{1} / static_cast<Real>(num_real_);
  auto transform = [&](const auto& value, ComplexBuffer* spectrum) {
    Embed<Real>(fixed_size_, padded_size_, value, real.get());
    *spectrum = AllocateComplex(num_complex_);
    fftw_execute_dft_r2c(
        plans_->forward, real.get(), reinterpret_cast<fftw_complex*>(spectrum->get()));
    for (int64_t c = 0; c < num_complex_; ++c) (*spectrum)[c] *= scale;
  };
  transform([&](int64_t l) { return Inside(mf[l], f[l]) ? f[l] - moments.mean : 0.0; },
            &fixed_spectrum_f_);
  transform(
      [&](int64_t l) {
        const double d = f[l] - moments.mean;
        return Inside(mf[l], f[l]) ? d * d : 0.0;
      },
      &fixed_spectrum_ff_);
  transform([&](int64_t l) { return Inside(mf[l], f[l]) ? 1.0 : 0.0; }, &fixed_spectrum_mask_);
}

MaskedNcc::~MaskedNcc() {
  std::lock_guard<std::mutex> lock(FftwPlannerMutex());
  if (plans_->forward != nullptr) fftw_destroy_plan(plans_->forward);
  if (plans_->inverse != nullptr) fftw_destroy_plan(plans_->inverse);
}

std::unique_ptr<MaskedNcc::Workspace> MaskedNcc::AcquireWorkspace() const {
  {
    std::lock_guard<std::mutex> lock(workspace_mutex_);
    if (!idle_workspaces_.empty()) {
      std::unique_ptr<Workspace> workspace = std::move(idle_workspaces_.back());
      idle_workspaces_.pop_back();
      return workspace;
    }
  }
  auto workspace = std::make_unique<Workspace>();
  for (RealBuffer* b : {&workspace->input,
                        &workspace->n,
                        &workspace->sf,
                        &workspace->sff,
                        &workspace->sg,
                        &workspace->sgg,
                        &workspace->sfg}) {
    *b = AllocateReal(num_real_);
  }
  workspace->spectrum = AllocateComplex(num_complex_);
  workspace->product = AllocateComplex(num_complex_);
  return workspace;
}

void MaskedNcc::ReleaseWorkspace(std::unique_ptr<Workspace> workspace) const {
  std::lock_guard<std::mutex> lock(workspace_mutex_);
  idle_workspaces_.push_back(std::move(workspace));
}

template <typename Visit>
void MaskedNcc::ForEachShift(const Image& moving,
                             const Mask& moving_mask,
                             int64_t min_overlap,
                             const Visit& visit) const {
  CheckSizes(moving, moving_mask, "MaskedNcc moving");
  CHECK(moving.geometry.size == moving_size_)
      << "moving size " << moving.geometry.size.transpose() << " != the size MaskedNcc was "
      << "prepared for, " << moving_size_.transpose();
  std::unique_ptr<Workspace> ws = AcquireWorkspace();

  // (A * B) = IFFT(FFT(A) conj(FFT(B))) on the padded grid. One moving spectrum at a time
  // (of Mg, then G Mg, then G^2 Mg, G centred like F in the constructor), each correlated
  // with the fixed spectra that pair with it.
  const MaskedMoments moments = ComputeMaskedMoments(moving, moving_mask);
  const float* g = moving.voxels.data();
  const uint8_t* mg = moving_mask.voxels.data();
  auto transform = [&](const auto& value) {
    Embed<Real>(moving_size_, padded_size_, value, ws->input.get());
    fftw_execute_dft_r2c(
        plans_->forward, ws->input.get(), reinterpret_cast<fftw_complex*>(ws->spectrum.get()));
  };
  auto correlate = [&](const ComplexBuffer& fixed_spectrum, const RealBuffer& out) {
    for (int64_t c = 0; c < num_complex_; ++c) {
      ws->product[c] = fixed_spectrum[c] * std::conj(ws->spectrum[c]);
    }
    fftw_execute_dft_c2r(
        plans_->inverse, reinterpret_cast<fftw_complex*>(ws->product.get()), out.get());
  };
  transform([&](int64_t l) { return Inside(mg[l], g[l]) ? 1.0 : 0.0; });
  correlate(fixed_spectrum_mask_, ws->n);
  correlate(fixed_spectrum_f_, ws->sf);
  correlate(fixed_spectrum_ff_, ws->sff);
  transform([&](int64_t l) { return Inside(mg[l], g[l]) ? g[l] - moments.mean : 0.0; });
  correlate(fixed_spectrum_mask_, ws->sg);
  correlate(fixed_spectrum_f_, ws->sfg);
  transform([&](int64_t l) {
    const double d = g[l] - moments.mean;
    return Inside(mg[l], g[l]) ? d * d : 0.0;
  });
  correlate(fixed_spectrum_mask_, ws->sgg);

  // Shift s sits at circular index s mod P: P >= fixed + moving - 1 keeps the
  // fixed + moving - 1 shifts of each axis on distinct indices.
  const NccMap shape = MapShape(fixed_size_, moving_size_);
  const int64_t min_n = std::max<int64_t>(min_overlap, 1);
  int64_t e = 0;
  for (int k = 0; k < shape.size[2]; ++k) {
    const int sz = shape.first_shift[2] + k;
    const int64_t rz = sz < 0 ? sz + padded_size_[2] : sz;
    for (int j = 0; j < shape.size[1]; ++j) {
      const int sy = shape.first_shift[1] + j;
      const int64_t ry = sy < 0 ? sy + padded_size_[1] : sy;
      for (int i = 0; i < shape.size[0]; ++i, ++e) {
        const int sx = shape.first_shift[0] + i;
        const int64_t rx = sx < 0 ? sx + padded_size_[0] : sx;
        const int64_t r = rx + padded_size_[0] * (ry + padded_size_[1] * rz);
        // n is a count (>= 0) up to FFT round-off: round half up by truncation, inline
        // (std::round is a library call here).
        const int64_t n = static_cast<int64_t>(ws->n[r] + 0.5);
        double ncc = -std::numeric_limits<double>::infinity();
        if (n >= min_n) {
          const double inv_n = 1.0 / static_cast<double>(n);
          const double sf = ws->sf[r], sg = ws->sg[r];
          const double var_f = ws->sff[r] - sf * sf * inv_n;
          const double var_g = ws->sgg[r] - sg * sg * inv_n;
          if (Textured(var_f, n, fixed_variance_) && Textured(var_g, n, moments.variance)) {
            ncc = ClampedCorrelation(ws->sfg[r] - sf * sg * inv_n, var_f, var_g);
          }
        }
        visit(e, n, ncc);
      }
    }
  }
  ReleaseWorkspace(std::move(ws));
}

NccMap MaskedNcc::Map(const Image& moving, const Mask& moving_mask, int64_t min_overlap) const {
  NccMap map = MapShape(fixed_size_, moving_size_);
  map.ncc.resize(map.NumShifts());
  map.overlap.resize(map.NumShifts());
  ForEachShift(moving, moving_mask, min_overlap, [&](int64_t e, int64_t overlap, double ncc) {
    map.overlap[e] = overlap;
    map.ncc[e] = ncc;
  });
  return map;
}

NccPeak MaskedNcc::Best(const Image& moving, const Mask& moving_mask, int64_t min_overlap) const {
  // The scan of BestPeak over the entries as they are computed: strictly greater, so the
  // first of equal entries in storage order wins.
  NccPeak best;
  int64_t best_entry = -1;
  ForEachShift(moving, moving_mask, min_overlap, [&](int64_t e, int64_t overlap, double ncc) {
    if (ncc > best.ncc) {
      best.ncc = ncc;
      best.overlap = overlap;
      best_entry = e;
    }
  });
  if (best_entry < 0) return NccPeak();
  best.shift = MapShape(fixed_size_, moving_size_).Shift(best_entry);
  return best;
}

std::vector<NccPeak> MaskedNcc::Peaks(const Image& moving,
                                      const Mask& moving_mask,
                                      int64_t min_overlap,
                                      int max_peaks,
                                      int suppression_radius) const {
  return SeparatedPeaks(Map(moving, moving_mask, min_overlap), max_peaks, suppression_radius);
}

NccMap NccMapBruteForce(const Image& fixed,
                        const Mask& fixed_mask,
                        const Image& moving,
                        const Mask& moving_mask,
                        int64_t min_overlap) {
  CheckSizes(fixed, fixed_mask, "NccMapBruteForce fixed");
  CheckSizes(moving, moving_mask, "NccMapBruteForce moving");
  const Eigen::Vector3i nf = fixed.geometry.size;
  const Eigen::Vector3i nm = moving.geometry.size;
  NccMap map = EmptyMap(nf, nm);
  const double fixed_variance = ComputeMaskedMoments(fixed, fixed_mask).variance;
  const double moving_variance = ComputeMaskedMoments(moving, moving_mask).variance;
  const int64_t min_n = std::max<int64_t>(min_overlap, 1);

  for (int64_t e = 0; e < map.NumShifts(); ++e) {
    const Eigen::Vector3i s = map.Shift(e);
    // Moving voxels q with q + s inside the fixed grid: max(0, -s) <= q < min(nm, nf - s).
    const Eigen::Vector3i lo = (-s).cwiseMax(Eigen::Vector3i::Zero());
    const Eigen::Vector3i hi = (nf - s).cwiseMin(nm);
    // Visits the overlap's (fixed value, moving value) pairs.
    auto for_each_pair = [&](const auto& fn) {
      for (int k = lo[2]; k < hi[2]; ++k) {
        for (int j = lo[1]; j < hi[1]; ++j) {
          for (int i = lo[0]; i < hi[0]; ++i) {
            const int64_t lf = fixed.geometry.LinearIndex(i + s[0], j + s[1], k + s[2]);
            const int64_t lm = moving.geometry.LinearIndex(i, j, k);
            if (!Inside(fixed_mask.voxels[lf], fixed.voxels[lf]) ||
                !Inside(moving_mask.voxels[lm], moving.voxels[lm])) {
              continue;
            }
            fn(static_cast<double>(fixed.voxels[lf]), static_cast<double>(moving.voxels[lm]));
          }
        }
      }
    };
    int64_t count = 0;
    double sum_f = 0.0, sum_g = 0.0;
    for_each_pair([&](double f, double g) {
      ++count;
      sum_f += f;
      sum_g += g;
    });
    map.overlap[e] = count;
    if (count < min_n) continue;
    const double mean_f = sum_f / count, mean_g = sum_g / count;
    double var_f = 0.0, var_g = 0.0, num = 0.0;
    for_each_pair([&](double f, double g) {
      var_f += (f - mean_f) * (f - mean_f);
      var_g += (g - mean_g) * (g - mean_g);
      num += (f - mean_f) * (g - mean_g);
    });
    if (!Textured(var_f, count, fixed_variance) || !Textured(var_g, count, moving_variance)) {
      continue;
    }
    map.ncc[e] = ClampedCorrelation(num, var_f, var_g);
  }
  return map;
}

NccPeak BestShiftBruteForce(const Image& fixed,
                            const Mask& fixed_mask,
                            const Image& moving,
                            const Mask& moving_mask,
                            int64_t min_overlap) {
  return BestPeak(NccMapBruteForce(fixed, fixed_mask, moving, moving_mask, min_overlap));
}

}  // namespace dsr
