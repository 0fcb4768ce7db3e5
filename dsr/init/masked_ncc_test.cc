// Tests of init/masked_ncc.h: the FFT masked NCC against its brute-force twin, recovery of a
// known shift between two fields of view, invariances, the overlap floor and thread safety.
#include "dsr/init/masked_ncc.h"

#include <cmath>
#include <limits>
#include <random>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

namespace dsr {
namespace {

// FFT (double) against direct summation. The FFT's round-off in an overlap's centred sums is
// about 1e-16 sqrt(N_f N_g) var(F) ~ 1e-13 var(F) here (N = voxel counts), whatever the
// overlap; an NCC divides it by the overlap's variance, at least kFlatOverlapRelativeVariance
// n var(F) = 3e-6 var(F) for the 3-voxel overlaps tested: worst case ~3e-8 (measured: 1e-10).
constexpr double kNccTolerance = 1e-7;
// Noise-free crops of one image: the true shift correlates perfectly (NCC = 1 up to
// round-off).
constexpr double kPerfectNccTolerance = 1e-9;
// 3 v - 50 rounded to float moves each voxel by up to 2^-24 |3 v - 50| (~4e-5 here),
// which changes a small overlap's NCC by ~1e-6 (its standard deviation is ~10).
constexpr double kFloatRoundedNccTolerance = 1e-5;

ImageGeometry GridOfSize(const Eigen::Vector3i& size) {
  ImageGeometry g;
  g.size = size;
  return g;
}

// One pass of the separable [1 2 1] / 4 filter along every axis (edges clamped).
Image Smooth(const Image& in) {
  Image out = in;
  const Eigen::Vector3i n = in.geometry.size;
  for (int axis = 0; axis < 3; ++axis) {
    const Image src = out;
    for (int k = 0; k < n[2]; ++k) {
      for (int j = 0; j < n[1]; ++j) {
        for (int i = 0; i < n[0]; ++i) {
          Eigen::Vector3i lo(i, j, k), hi(i, j, k);
          lo[axis] = std::max(lo[axis] - 1, 0);
          hi[axis] = std::min(hi[axis] + 1, n[axis] - 1);
          out.at(i, j, k) = 0.25f * src.at(lo[0], lo[1], lo[2]) + 0.5f * src.at(i, j, k) +
                            0.25f * src.at(hi[0], hi[1], hi[2]);
        }
      }
    }
  }
  return out;
}

// Smooth random texture with values spread over about 0..255.
Image RandomSmoothImage(const Eigen::Vector3i& size, std::mt19937* rng) {
  Image image(GridOfSize(size));
  std::uniform_real_distribution<float> uniform(0.0f, 255.0f);
  for (float& v : image.voxels) v = uniform(*rng);
  for (int pass = 0; pass < 3; ++pass) image = Smooth(image);
  // Smoothing shrinks the spread; stretch it back around 128.
  double mean = 0.0;
  for (float v : image.voxels) mean += v;
  mean /= image.voxels.size();
  for (float& v : image.voxels) v = static_cast<float>(128.0 + 4.0 * (v - mean));
  return image;
}

// A non-convex random mask: a smooth random field thresholded at its median (blobs with
// holes and concavities), with a random box cut out of it.
Mask RandomNonConvexMask(const Eigen::Vector3i& size, std::mt19937* rng) {
  const Image field = RandomSmoothImage(size, rng);
  std::vector<float> sorted = field.voxels;
  std::nth_element(sorted.begin(), sorted.begin() + sorted.size() / 2, sorted.end());
  const float median = sorted[sorted.size() / 2];
  Mask mask(GridOfSize(size), 0);
  for (size_t l = 0; l < mask.voxels.size(); ++l) mask.voxels[l] = field.voxels[l] > median;
  std::uniform_int_distribution<int> corner(0, size.minCoeff() / 2);
  const Eigen::Vector3i lo(corner(*rng), corner(*rng), corner(*rng));
  for (int k = lo[2]; k < lo[2] + size[2] / 3; ++k) {
    for (int j = lo[1]; j < lo[1] + size[1] / 3; ++j) {
      for (int i = lo[0]; i < lo[0] + size[0] / 3; ++i) mask.at(i, j, k) = 0;
    }
  }
  return mask;
}

// An ultrasound-like field of view: a square pyramid (or a cone) with its apex at the
// middle of the k = 0 face, opening along +k with half-angle atan(`slope`).
Mask FieldOfView(const Eigen::Vector3i& size, double slope, bool cone) {
  Mask mask(GridOfSize(size), 0);
  const double cx = 0.5 * (size[0] - 1), cy = 0.5 * (size[1] - 1);
  for (int k = 0; k < size[2]; ++k) {
    const double radius = slope * (k + 1);
    for (int j = 0; j < size[1]; ++j) {
      for (int i = 0; i < size[0]; ++i) {
        const double dx = std::abs(i - cx), dy = std::abs(j - cy);
        const bool inside = cone ? std::hypot(dx, dy) <= radius : std::max(dx, dy) <= radius;
        mask.at(i, j, k) = inside ? 1 : 0;
      }
    }
  }
  return mask;
}

// The `size` block of `image` starting at voxel `offset`.
Image Crop(const Image& image, const Eigen::Vector3i& offset, const Eigen::Vector3i& size) {
  Image out(GridOfSize(size));
  for (int k = 0; k < size[2]; ++k) {
    for (int j = 0; j < size[1]; ++j) {
      for (int i = 0; i < size[0]; ++i) {
        out.at(i, j, k) = image.at(i + offset[0], j + offset[1], k + offset[2]);
      }
    }
  }
  return out;
}

Mask FullMask(const Eigen::Vector3i& size) { return Mask(GridOfSize(size), 1); }

Eigen::Vector3i RandomSize(int lo, int hi, std::mt19937* rng) {
  std::uniform_int_distribution<int> d(lo, hi);
  return Eigen::Vector3i(d(*rng), d(*rng), d(*rng));
}

// Every entry of two maps: same shape and overlaps, NCC defined at the same shifts and
// equal within `tolerance` there.
void ExpectMapsEqual(const NccMap& expected, const NccMap& actual, double tolerance) {
  ASSERT_EQ(expected.first_shift, actual.first_shift);
  ASSERT_EQ(expected.size, actual.size);
  int64_t defined = 0;
  double max_difference = 0.0;
  for (int64_t e = 0; e < expected.NumShifts(); ++e) {
    ASSERT_EQ(expected.overlap[e], actual.overlap[e]) << "shift " << expected.Shift(e).transpose();
    ASSERT_EQ(std::isfinite(expected.ncc[e]), std::isfinite(actual.ncc[e]))
        << "shift " << expected.Shift(e).transpose() << ": " << expected.ncc[e] << " vs "
        << actual.ncc[e] << ", overlap " << expected.overlap[e];
    if (!std::isfinite(expected.ncc[e])) continue;
    ++defined;
    max_difference = std::max(max_difference, std::abs(expected.ncc[e] - actual.ncc[e]));
  }
  EXPECT_GT(defined, 0);
  EXPECT_LE(max_difference, tolerance);
}

void ExpectPeaksEqual(const NccPeak& expected, const NccPeak& actual, double tolerance) {
  EXPECT_EQ(expected.shift, actual.shift);
  EXPECT_EQ(expected.overlap, actual.overlap);
  EXPECT_NEAR(expected.ncc, actual.ncc, tolerance);
}

TEST(FftFriendlySize, SmallestProductOfTwoThreeFiveSeven) {
  EXPECT_EQ(FftFriendlySize(1), 1);
  EXPECT_EQ(FftFriendlySize(11), 12);
  EXPECT_EQ(FftFriendlySize(13), 14);
  EXPECT_EQ(FftFriendlySize(17), 18);
  EXPECT_EQ(FftFriendlySize(29), 30);
  EXPECT_EQ(FftFriendlySize(47), 48);
  EXPECT_EQ(FftFriendlySize(87), 90);
  EXPECT_EQ(FftFriendlySize(97), 98);
  EXPECT_EQ(FftFriendlySize(121), 125);
}

TEST(MaskedNcc, PaddedGridHoldsEveryShiftWithoutWrapAround) {
  const Eigen::Vector3i fixed_size(13, 16, 11), moving_size(9, 17, 6);
  const MaskedNcc ncc(Image(GridOfSize(fixed_size)), FullMask(fixed_size), moving_size);
  for (int a = 0; a < 3; ++a) {
    EXPECT_GE(ncc.padded_size()[a], fixed_size[a] + moving_size[a] - 1);
  }
}

// The FFT map equals direct summation at every shift, including negative shifts and the
// ones at the edge of the overlap range (a single corner voxel), for random smooth images
// under random non-convex masks, fixed and moving of different sizes.
TEST(MaskedNcc, MapEqualsBruteForce) {
  std::mt19937 rng(19);
  for (int trial = 0; trial < 4; ++trial) {
    SCOPED_TRACE(trial);
    const Eigen::Vector3i fixed_size = RandomSize(12, 17, &rng);
    const Eigen::Vector3i moving_size = RandomSize(9, 14, &rng);
    ASSERT_NE(fixed_size, moving_size);
    Image fixed = RandomSmoothImage(fixed_size, &rng);
    const Mask fixed_mask = RandomNonConvexMask(fixed_size, &rng);
    Image moving = RandomSmoothImage(moving_size, &rng);
    const Mask moving_mask = RandomNonConvexMask(moving_size, &rng);
    if (trial == 1) {
      // A non-finite value inside a mask counts as outside, identically in both.
      fixed.voxels[fixed.voxels.size() / 2] = std::numeric_limits<float>::quiet_NaN();
      moving.voxels[7] = std::numeric_limits<float>::infinity();
    }
    // min_overlap = 3: the smallest overlaps with a defined NCC are compared too.
    const int64_t min_overlap = 3;
    const MaskedNcc ncc(fixed, fixed_mask, moving_size);
    const NccMap fast = ncc.Map(moving, moving_mask, min_overlap);
    const NccMap slow = NccMapBruteForce(fixed, fixed_mask, moving, moving_mask, min_overlap);
    ExpectMapsEqual(slow, fast, kNccTolerance);
    // The extreme shifts overlap in one corner voxel only (or not at all).
    EXPECT_LE(fast.overlap.front(), 1);
    EXPECT_LE(fast.overlap.back(), 1);
    EXPECT_EQ(fast.Shift(0), -(moving_size - Eigen::Vector3i::Ones()));
    EXPECT_EQ(fast.Shift(fast.NumShifts() - 1), fixed_size - Eigen::Vector3i::Ones());

    // With a realistic overlap floor the best shifts agree exactly.
    const int64_t floor = CountInside(moving_mask) / 4;
    ExpectPeaksEqual(BestShiftBruteForce(fixed, fixed_mask, moving, moving_mask, floor),
                     ncc.Best(moving, moving_mask, floor),
                     kNccTolerance);
  }
}

// Measured FFTW plans round differently from estimated ones, within the same tolerance.
TEST(MaskedNcc, MeasuredPlansMatchBruteForce) {
  std::mt19937 rng(29);
  const Eigen::Vector3i fixed_size(14, 16, 13), moving_size(11, 9, 12);
  const Image fixed = RandomSmoothImage(fixed_size, &rng);
  const Mask fixed_mask = RandomNonConvexMask(fixed_size, &rng);
  const Image moving = RandomSmoothImage(moving_size, &rng);
  const Mask moving_mask = RandomNonConvexMask(moving_size, &rng);
  MaskedNccOptions options;
  options.fft_planning = FftPlanning::kMeasure;
  const MaskedNcc ncc(fixed, fixed_mask, moving_size, options);
  const NccMap slow = NccMapBruteForce(fixed, fixed_mask, moving, moving_mask, 3);
  ExpectMapsEqual(slow, ncc.Map(moving, moving_mask, 3), kNccTolerance);
  ExpectPeaksEqual(BestPeak(slow), ncc.Best(moving, moving_mask, 3), kNccTolerance);
}

// Crops of one image at a negative offset whose overlap is a thin corner slab: the true
// shift (NCC = 1) is found at the edge of the shift range, by both paths.
TEST(MaskedNcc, RecoversNegativeShiftNearTheOverlapEdge) {
  std::mt19937 rng(7);
  const Image world = RandomSmoothImage(Eigen::Vector3i(24, 24, 24), &rng);
  const Eigen::Vector3i fixed_offset(9, 8, 8), fixed_size(14, 15, 13);
  const Eigen::Vector3i moving_offset(0, 2, 1), moving_size(12, 11, 12);
  // Moving voxel q is world voxel q + moving_offset = fixed voxel q + moving - fixed offset.
  const Eigen::Vector3i true_shift = moving_offset - fixed_offset;  // (-9, -6, -7)
  const Image fixed = Crop(world, fixed_offset, fixed_size);
  const Image moving = Crop(world, moving_offset, moving_size);
  // Overlap 3 x 5 x 5 = 75 voxels; on x the shift is 2 from the extreme one, -(12 - 1).
  const int64_t min_overlap = 60;
  const MaskedNcc ncc(fixed, FullMask(fixed_size), moving_size);
  const NccPeak fast = ncc.Best(moving, FullMask(moving_size), min_overlap);
  EXPECT_EQ(fast.shift, true_shift);
  EXPECT_EQ(fast.overlap, 75);
  EXPECT_NEAR(fast.ncc, 1.0, kPerfectNccTolerance);
  ExpectPeaksEqual(
      BestShiftBruteForce(fixed, FullMask(fixed_size), moving, FullMask(moving_size), min_overlap),
      fast,
      kNccTolerance);
}

// Moving = a noisy crop of the fixed image's scene, both seen through ultrasound-like
// fields of view (a pyramid and a cone): the crop offset is recovered.
TEST(MaskedNcc, RecoversKnownShiftBetweenConeFieldsOfView) {
  std::mt19937 rng(2012);
  const Image world = RandomSmoothImage(Eigen::Vector3i(36, 36, 32), &rng);
  const Eigen::Vector3i fixed_offset(4, 6, 3), fixed_size(20, 20, 18);
  const Image fixed = Crop(world, fixed_offset, fixed_size);
  const Mask fixed_mask = FieldOfView(fixed_size, 0.6, /*cone=*/false);
  const Eigen::Vector3i moving_size(16, 17, 14);
  std::normal_distribution<float> noise(0.0f, 10.0f);
  // Shifts (5, 2, 7), (-2, 7, 2), (2, -2, -2), (-3, 2, 9); true overlaps of 791, 772, 754
  // and 441 voxels, all above the floor (a quarter of the moving cone, 380 voxels).
  for (const Eigen::Vector3i& moving_offset : {Eigen::Vector3i(9, 8, 10),
                                               Eigen::Vector3i(2, 13, 5),
                                               Eigen::Vector3i(6, 4, 1),
                                               Eigen::Vector3i(1, 8, 12)}) {
    SCOPED_TRACE(moving_offset.transpose());
    Image moving = Crop(world, moving_offset, moving_size);
    for (float& v : moving.voxels) v += noise(rng);
    const Mask moving_mask = FieldOfView(moving_size, 0.7, /*cone=*/true);
    const int64_t min_overlap = CountInside(moving_mask) / 4;
    const MaskedNcc ncc(fixed, fixed_mask, moving_size);
    const NccPeak fast = ncc.Best(moving, moving_mask, min_overlap);
    EXPECT_EQ(fast.shift, moving_offset - fixed_offset);
    EXPECT_GT(fast.ncc, 0.9);
    EXPECT_GE(fast.overlap, min_overlap);
    ExpectPeaksEqual(BestShiftBruteForce(fixed, fixed_mask, moving, moving_mask, min_overlap),
                     fast,
                     kNccTolerance);
  }
}

// Pearson correlation ignores a gain and an offset of either image; so does the flat rule
// (relative to the image's own variance).
TEST(MaskedNcc, InvariantToAffineIntensityChangeOfMoving) {
  std::mt19937 rng(3);
  const Eigen::Vector3i fixed_size(16, 14, 15), moving_size(11, 13, 10);
  const Image fixed = RandomSmoothImage(fixed_size, &rng);
  const Mask fixed_mask = RandomNonConvexMask(fixed_size, &rng);
  const Image moving = RandomSmoothImage(moving_size, &rng);
  const Mask moving_mask = RandomNonConvexMask(moving_size, &rng);
  Image changed = moving;
  for (float& v : changed.voxels) v = 3.0f * v - 50.0f;
  const MaskedNcc ncc(fixed, fixed_mask, moving_size);
  const int64_t min_overlap = 10;
  ExpectMapsEqual(ncc.Map(moving, moving_mask, min_overlap),
                  ncc.Map(changed, moving_mask, min_overlap),
                  kFloatRoundedNccTolerance);
  ExpectPeaksEqual(ncc.Best(moving, moving_mask, min_overlap),
                   ncc.Best(changed, moving_mask, min_overlap),
                   kFloatRoundedNccTolerance);
}

// Unrelated images: tiny overlaps correlate almost perfectly by chance (any 2 points have
// NCC +-1), and the overlap floor keeps them out.
TEST(MaskedNcc, RespectsMinOverlap) {
  std::mt19937 rng(11);
  const Eigen::Vector3i fixed_size(14, 14, 14), moving_size(12, 12, 12);
  const Image fixed = RandomSmoothImage(fixed_size, &rng);
  const Image moving = RandomSmoothImage(moving_size, &rng);
  const Mask fixed_mask = FullMask(fixed_size), moving_mask = FullMask(moving_size);
  const MaskedNcc ncc(fixed, fixed_mask, moving_size);

  const NccPeak spurious = ncc.Best(moving, moving_mask, 2);
  EXPECT_GT(spurious.ncc, 0.99);
  EXPECT_LT(spurious.overlap, 20);

  const int64_t min_overlap = 500;
  const NccMap map = ncc.Map(moving, moving_mask, min_overlap);
  for (int64_t e = 0; e < map.NumShifts(); ++e) {
    if (map.overlap[e] < min_overlap) {
      EXPECT_FALSE(std::isfinite(map.ncc[e]));
    }
  }
  const NccPeak best = ncc.Best(moving, moving_mask, min_overlap);
  EXPECT_GE(best.overlap, min_overlap);
  EXPECT_LT(best.ncc, spurious.ncc);
  ExpectPeaksEqual(BestShiftBruteForce(fixed, fixed_mask, moving, moving_mask, min_overlap),
                   best,
                   kNccTolerance);

  // No shift overlaps by more than the moving volume: nothing qualifies.
  const NccPeak none = ncc.Best(moving, moving_mask, 12 * 12 * 12 + 1);
  EXPECT_EQ(none.ncc, -std::numeric_limits<double>::infinity());
  EXPECT_EQ(none.overlap, 0);
  EXPECT_EQ(none.shift, Eigen::Vector3i::Zero());
}

// A constant image has no NCC anywhere, even where FFT round-off leaves a tiny variance.
TEST(MaskedNcc, FlatImageHasNoPeak) {
  std::mt19937 rng(5);
  const Eigen::Vector3i fixed_size(13, 12, 14), moving_size(10, 11, 9);
  const Image fixed = RandomSmoothImage(fixed_size, &rng);
  const MaskedNcc ncc(fixed, FullMask(fixed_size), moving_size);
  const Image flat(GridOfSize(moving_size), 77.0f);
  const NccMap map = ncc.Map(flat, FullMask(moving_size), 1);
  for (double v : map.ncc) EXPECT_EQ(v, -std::numeric_limits<double>::infinity());
  EXPECT_EQ(ncc.Best(flat, FullMask(moving_size), 1).ncc, -std::numeric_limits<double>::infinity());
}

// Ties go to the smallest shift in (z, y, x) order, in both BestPeak and SeparatedPeaks.
TEST(BestPeak, TiesGoToTheSmallestShiftInZyxOrder) {
  NccMap map;
  map.first_shift = Eigen::Vector3i(-2, -1, -3);
  map.size = Eigen::Vector3i(4, 3, 5);
  map.ncc.assign(map.NumShifts(), 0.1);
  map.overlap.assign(map.NumShifts(), 9);
  const int64_t later_z = 0 + 4 * (0 + 3 * 3);    // shift (-2, -1, 0)
  const int64_t earlier_z = 3 + 4 * (2 + 3 * 1);  // shift (1, 1, -2)
  map.ncc[later_z] = 0.5;
  map.ncc[earlier_z] = 0.5;
  const NccPeak best = BestPeak(map);
  EXPECT_EQ(best.shift, Eigen::Vector3i(1, 1, -2));
  EXPECT_EQ(best.ncc, 0.5);
  const std::vector<NccPeak> peaks = SeparatedPeaks(map, 2, 1);
  ASSERT_EQ(peaks.size(), 2u);
  EXPECT_EQ(peaks[0].shift, Eigen::Vector3i(1, 1, -2));
  EXPECT_EQ(peaks[1].shift, Eigen::Vector3i(-2, -1, 0));
}

// Peaks: the first is Best, every pair is farther apart than the radius, each is the best
// shift outside the earlier ones' neighbourhoods, and the brute-force map gives the same.
TEST(MaskedNcc, SeparatedPeaksMatchBruteForce) {
  std::mt19937 rng(23);
  const Eigen::Vector3i fixed_size(15, 13, 14), moving_size(10, 12, 9);
  const Image fixed = RandomSmoothImage(fixed_size, &rng);
  const Mask fixed_mask = RandomNonConvexMask(fixed_size, &rng);
  const Image moving = RandomSmoothImage(moving_size, &rng);
  const Mask moving_mask = RandomNonConvexMask(moving_size, &rng);
  const int64_t min_overlap = 100;
  const int radius = 3;
  const MaskedNcc ncc(fixed, fixed_mask, moving_size);
  const std::vector<NccPeak> peaks = ncc.Peaks(moving, moving_mask, min_overlap, 5, radius);
  ASSERT_EQ(peaks.size(), 5u);
  ExpectPeaksEqual(ncc.Best(moving, moving_mask, min_overlap), peaks[0], 0.0);
  const NccMap map = ncc.Map(moving, moving_mask, min_overlap);
  for (size_t p = 0; p < peaks.size(); ++p) {
    for (size_t q = 0; q < p; ++q) {
      EXPECT_GT((peaks[p].shift - peaks[q].shift).cwiseAbs().maxCoeff(), radius);
      EXPECT_LE(peaks[p].ncc, peaks[q].ncc);
    }
    // No unsuppressed shift beats it.
    for (int64_t e = 0; e < map.NumShifts(); ++e) {
      bool suppressed = false;
      for (size_t q = 0; q < p; ++q) {
        suppressed |= (map.Shift(e) - peaks[q].shift).cwiseAbs().maxCoeff() <= radius;
      }
      if (!suppressed) {
        EXPECT_LE(map.ncc[e], peaks[p].ncc);
      }
    }
  }
  const std::vector<NccPeak> slow = SeparatedPeaks(
      NccMapBruteForce(fixed, fixed_mask, moving, moving_mask, min_overlap), 5, radius);
  ASSERT_EQ(slow.size(), peaks.size());
  for (size_t p = 0; p < peaks.size(); ++p) ExpectPeaksEqual(slow[p], peaks[p], kNccTolerance);
}

// Best scans the map as it is computed: the same peak as BestPeak(Map), bit for bit. And a
// MaskedNcc reuses its buffers across calls: results do not depend on what ran before.
TEST(MaskedNcc, BestIsBestPeakOfMapAndIndependentOfEarlierCalls) {
  std::mt19937 rng(41);
  const Eigen::Vector3i fixed_size(17, 15, 16), moving_size(12, 10, 13);
  const Image fixed = RandomSmoothImage(fixed_size, &rng);
  const Mask fixed_mask = RandomNonConvexMask(fixed_size, &rng);
  const MaskedNcc shared(fixed, fixed_mask, moving_size);
  for (int m = 0; m < 3; ++m) {
    const Image moving = RandomSmoothImage(moving_size, &rng);
    const Mask moving_mask = RandomNonConvexMask(moving_size, &rng);
    const MaskedNcc fresh(fixed, fixed_mask, moving_size);
    const NccPeak expected = BestPeak(fresh.Map(moving, moving_mask, 40));
    ExpectPeaksEqual(expected, shared.Best(moving, moving_mask, 40), 0.0);
    ExpectPeaksEqual(expected, BestPeak(shared.Map(moving, moving_mask, 40)), 0.0);
  }
}

// Best is const and takes its buffers per call: two threads sharing one MaskedNcc get
// bit-identical results to sequential calls.
TEST(MaskedNcc, ConcurrentCallsMatchSequentialOnes) {
  std::mt19937 rng(31);
  const Eigen::Vector3i fixed_size(18, 16, 17), moving_size(12, 13, 11);
  const Image fixed = RandomSmoothImage(fixed_size, &rng);
  const Mask fixed_mask = RandomNonConvexMask(fixed_size, &rng);
  constexpr int kMovingVolumes = 6;
  std::vector<Image> moving;
  std::vector<Mask> moving_masks;
  for (int m = 0; m < kMovingVolumes; ++m) {
    moving.push_back(RandomSmoothImage(moving_size, &rng));
    moving_masks.push_back(RandomNonConvexMask(moving_size, &rng));
  }
  const MaskedNcc ncc(fixed, fixed_mask, moving_size);
  const int64_t min_overlap = 50;
  std::vector<NccPeak> sequential;
  for (int m = 0; m < kMovingVolumes; ++m) {
    sequential.push_back(ncc.Best(moving[m], moving_masks[m], min_overlap));
  }
  // Each thread runs every volume several times, in a different order from the other.
  constexpr int kRepeats = 4;
  std::vector<std::vector<NccPeak>> results(2, std::vector<NccPeak>(kMovingVolumes * kRepeats));
  auto run = [&](int thread) {
    for (int r = 0; r < kMovingVolumes * kRepeats; ++r) {
      const int m = thread == 0 ? r % kMovingVolumes : kMovingVolumes - 1 - r % kMovingVolumes;
      results[thread][r] = ncc.Best(moving[m], moving_masks[m], min_overlap);
    }
  };
  std::thread other(run, 1);
  run(0);
  other.join();
  for (int thread = 0; thread < 2; ++thread) {
    for (int r = 0; r < kMovingVolumes * kRepeats; ++r) {
      const int m = thread == 0 ? r % kMovingVolumes : kMovingVolumes - 1 - r % kMovingVolumes;
      EXPECT_EQ(results[thread][r].shift, sequential[m].shift);
      EXPECT_EQ(results[thread][r].overlap, sequential[m].overlap);
      EXPECT_EQ(results[thread][r].ncc, sequential[m].ncc);  // bit-identical
    }
  }
}

TEST(MaskedNccDeathTest, RejectsMovingOfAnotherSize) {
  const Eigen::Vector3i fixed_size(8, 8, 8), moving_size(5, 6, 7);
  const MaskedNcc ncc(Image(GridOfSize(fixed_size), 1.0f), FullMask(fixed_size), moving_size);
  const Eigen::Vector3i other(5, 6, 8);
  EXPECT_DEATH(ncc.Best(Image(GridOfSize(other)), FullMask(other), 1), "prepared for");
}

}  // namespace
}  // namespace dsr
