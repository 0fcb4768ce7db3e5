// Field-of-view masks of frames given without one (geometry/field_of_view.h,
// docs/design.md section 2.1): the convex hull of the non-zero voxels keeps a dark region
// that touches the field of view's faces, which the non-zero rule loses; specks do not
// inflate it; it falls back to the non-zero rule where no hull fits.
#include "dsr/geometry/field_of_view.h"

#include <cmath>
#include <random>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "dsr/geometry/convex_hull.h"
#include "dsr/geometry/volume.h"

namespace dsr {
namespace {

// The simulator's pyramid (sim/simulate.h): apex at the centre of the k = 0 face, depth
// along +k, full opening angles 75 degrees, near-field cut at depth 4.
constexpr double kOpeningDeg = 75.0;
constexpr double kMinDepthVoxels = 4.0;
// The simulator's noise: Gaussian, sigma 25, clamped at 0.
constexpr double kNoiseSigma = 25.0;
// Tissue well above the noise (4 sigma: almost no voxel clamps to 0), and dark tissue as
// dark as the background (half of its voxels clamp to exactly 0).
constexpr double kBrightTissue = 100.0;
constexpr double kDarkTissue = 0.0;

ImageGeometry Grid(int nx, int ny, int nz) {
  ImageGeometry g;
  g.size = Eigen::Vector3i(nx, ny, nz);
  return g;
}

Mask Pyramid(const ImageGeometry& g) {
  Mask mask(g, 0);
  const double cx = 0.5 * (g.size[0] - 1), cy = 0.5 * (g.size[1] - 1);
  const double tan_half = std::tan(0.5 * kOpeningDeg * M_PI / 180.0);
  for (int k = 0; k < g.size[2]; ++k)
    for (int j = 0; j < g.size[1]; ++j)
      for (int i = 0; i < g.size[0]; ++i)
        mask.at(i, j, k) = k >= kMinDepthVoxels && std::abs(i - cx) <= k * tan_half &&
                                   std::abs(j - cy) <= k * tan_half
                               ? 1
                               : 0;
  return mask;
}

// Inside the pyramid: `tissue(i, j, k)` plus noise, clamped at 0; outside: 0.
template <typename Tissue>
Image NoisyPyramid(const ImageGeometry& g, Tissue tissue, uint64_t seed) {
  const Mask fov = Pyramid(g);
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> noise(0.0, kNoiseSigma);
  Image image(g, 0.0f);
  for (int k = 0; k < g.size[2]; ++k)
    for (int j = 0; j < g.size[1]; ++j)
      for (int i = 0; i < g.size[0]; ++i)
        if (fov.at(i, j, k)) {
          image.at(i, j, k) =
              static_cast<float>(std::max(0.0, tissue(i, j, k) + noise(rng)));
        }
  return image;
}

// Voxels inside `a` and not inside `b`.
int64_t CountOnlyIn(const Mask& a, const Mask& b) {
  int64_t n = 0;
  for (size_t l = 0; l < a.voxels.size(); ++l) n += a.voxels[l] && !b.voxels[l];
  return n;
}

// Whether voxel (i, j, k) of `mask` is inside with a 6-neighbour outside (or off the grid).
bool OnSurface(const Mask& mask, int i, int j, int k) {
  const Eigen::Vector3i& n = mask.geometry.size;
  if (!mask.at(i, j, k)) return false;
  const int offsets[6][3] = {{1, 0, 0}, {-1, 0, 0}, {0, 1, 0}, {0, -1, 0}, {0, 0, 1}, {0, 0, -1}};
  for (const auto& o : offsets) {
    const int a = i + o[0], b = j + o[1], c = k + o[2];
    if (a < 0 || b < 0 || c < 0 || a >= n[0] || b >= n[1] || c >= n[2]) return true;
    if (!mask.at(a, b, c)) return true;
  }
  return false;
}

TEST(MaskRule, NamesRoundTrip) {
  for (MaskRule rule : {MaskRule::kHull, MaskRule::kNonZero}) {
    MaskRule back = rule == MaskRule::kHull ? MaskRule::kNonZero : MaskRule::kHull;
    ASSERT_TRUE(StringToMaskRule(MaskRuleToString(rule), &back));
    EXPECT_EQ(back, rule);
  }
  MaskRule untouched = MaskRule::kNonZero;
  EXPECT_FALSE(StringToMaskRule("non_zero", &untouched));
  EXPECT_EQ(untouched, MaskRule::kNonZero);
}

TEST(ConvexHullHalfSpaces, CubeHasSixFacetsHoldingEveryPoint) {
  // The corners of a cube and points on its faces and inside: coplanar facets merge.
  std::vector<double> xyz;
  for (int c = 0; c < 8; ++c) {
    xyz.insert(xyz.end(), {2.0 * (c & 1), 2.0 * (c >> 1 & 1), 2.0 * (c >> 2)});
  }
  xyz.insert(xyz.end(), {1.0, 1.0, 0.0, 1.0, 1.0, 1.0, 2.0, 1.0, 1.0});
  std::vector<HalfSpace> half_spaces;
  std::string error;
  ASSERT_TRUE(ConvexHullHalfSpaces(xyz, &half_spaces, &error)) << error;
  EXPECT_EQ(half_spaces.size(), 6u);
  // qhull's rounding on coordinates of order 1.
  constexpr double kPlaneTolerance = 1e-12;
  for (const HalfSpace& h : half_spaces) {
    EXPECT_NEAR(h.head<3>().norm(), 1.0, kPlaneTolerance);
    for (size_t p = 0; p < xyz.size(); p += 3) {
      EXPECT_LE(h.head<3>().dot(Eigen::Vector3d(xyz[p], xyz[p + 1], xyz[p + 2])) + h[3],
                kPlaneTolerance);
    }
  }
}

TEST(ConvexHullHalfSpaces, RefusesFlatInputWithAMessage) {
  const std::vector<double> square = {0, 0, 1, 1, 0, 1, 0, 1, 1, 1, 1, 1, 0.5, 0.5, 1};
  std::vector<HalfSpace> half_spaces;
  std::string error;
  EXPECT_FALSE(ConvexHullHalfSpaces(square, &half_spaces, &error));
  EXPECT_NE(error.find("qhull"), std::string::npos) << error;
  EXPECT_TRUE(half_spaces.empty());
  EXPECT_FALSE(ConvexHullHalfSpaces({0, 0, 0, 1, 0, 0, 0, 1, 0}, &half_spaces, &error));
  EXPECT_NE(error.find("fewer than 4 points"), std::string::npos) << error;
}

// The measured problem: a dark region touching two faces of the pyramid has half of its
// voxels exactly 0, those zeros connect to the outside, and the non-zero rule marks them
// outside. The hull keeps it: it differs from the pyramid only on the pyramid's surface,
// where a face voxel clamped to 0 next to the dark region is not a hull vertex.
TEST(MaskFromConvexHull, KeepsADarkSlabTouchingTheFaces) {
  const ImageGeometry g = Grid(48, 48, 40);
  const double cx = 0.5 * (g.size[0] - 1), cy = 0.5 * (g.size[1] - 1);
  // The slab: depths 14..26 of the quadrant i < cx, j < cy (it meets the faces of low i
  // and low j).
  const auto in_slab = [&](int i, int j, int k) { return i < cx && j < cy && k >= 14 && k <= 26; };
  const Image image = NoisyPyramid(
      g, [&](int i, int j, int k) { return in_slab(i, j, k) ? kDarkTissue : kBrightTissue; }, 7);
  const Mask pyramid = Pyramid(g);
  Mask slab(g, 0);
  int64_t surface = 0;
  for (int k = 0; k < g.size[2]; ++k)
    for (int j = 0; j < g.size[1]; ++j)
      for (int i = 0; i < g.size[0]; ++i) {
        slab.at(i, j, k) = pyramid.at(i, j, k) && in_slab(i, j, k);
        surface += OnSurface(pyramid, i, j, k);
      }
  const int64_t slab_voxels = CountInside(slab);
  ASSERT_GT(slab_voxels, 1000);

  // The non-zero rule loses the slab's zeros, about half of it (6-connected zeros at
  // density 1/2 percolate and reach the faces; measured 47%), and after the tools' erosion
  // by one voxel nearly all of it (measured 99.7%).
  const Mask nonzero = MaskFromNonZero(image, 0);
  constexpr double kMinLostFraction = 0.4;
  EXPECT_GT(CountOnlyIn(slab, nonzero), kMinLostFraction * slab_voxels);
  constexpr double kMinLostFractionEroded = 0.9;
  EXPECT_GT(CountOnlyIn(slab, MaskFromNonZero(image, 1)), kMinLostFractionEroded * slab_voxels);

  Mask hull;
  std::string why;
  ASSERT_TRUE(MaskFromConvexHull(image, 0, &hull, &why)) << why;
  // The hull of voxel centres inside a convex pyramid lies inside the pyramid.
  EXPECT_EQ(CountOnlyIn(hull, pyramid), 0);
  // What it misses lies on the pyramid's surface, and is a small part of it (measured: 2
  // of its 6532 surface voxels; at most 9 over seeds 1-30).
  int64_t missed = 0, missed_off_surface = 0;
  for (int k = 0; k < g.size[2]; ++k)
    for (int j = 0; j < g.size[1]; ++j)
      for (int i = 0; i < g.size[0]; ++i) {
        if (!pyramid.at(i, j, k) || hull.at(i, j, k)) continue;
        ++missed;
        missed_off_surface += !OnSurface(pyramid, i, j, k);
      }
  constexpr double kMaxMissedSurfaceFraction = 0.005;
  EXPECT_EQ(missed_off_surface, 0);
  EXPECT_LE(missed, kMaxMissedSurfaceFraction * surface) << missed << " of " << surface;

  // At the tools' defaults (hull, eroded by one voxel) the slab loses only the layer on the
  // faces that every field of view loses to the erosion.
  MaskRule used = MaskRule::kNonZero;
  const Mask by_default = FieldOfViewFromImage(image, FieldOfViewOptions{}, &used);
  EXPECT_EQ(used, MaskRule::kHull);
  Mask eroded = hull;
  ErodeMask(FieldOfViewOptions{}.mask_erosion, &eroded);
  EXPECT_EQ(by_default.voxels, eroded.voxels);
  Mask pyramid_eroded = pyramid;
  ErodeMask(FieldOfViewOptions{}.mask_erosion, &pyramid_eroded);
  // A missed voxel takes at most its 3x3x3 box with it.
  EXPECT_LE(CountOnlyIn(pyramid_eroded, by_default), 27 * missed);
  EXPECT_EQ(CountOnlyIn(by_default, pyramid_eroded), 0);
}

// A speck of non-zero voxels far outside (an annotation) is below
// kMinHullComponentFraction of the field of view and does not inflate the hull.
TEST(MaskFromConvexHull, IgnoresAStraySpeck) {
  const ImageGeometry g = Grid(48, 48, 40);
  const Image image =
      NoisyPyramid(g, [](int, int, int) { return kBrightTissue; }, 11);
  Image with_speck = image;
  for (int k = 5; k < 8; ++k)
    for (int j = 1; j < 4; ++j)
      for (int i = 1; i < 4; ++i) with_speck.at(i, j, k) = 200.0f;  // outside the pyramid
  Mask hull, hull_with_speck;
  std::string why;
  ASSERT_TRUE(MaskFromConvexHull(image, 0, &hull, &why)) << why;
  ASSERT_TRUE(MaskFromConvexHull(with_speck, 0, &hull_with_speck, &why)) << why;
  EXPECT_EQ(hull_with_speck.voxels, hull.voxels);
  EXPECT_EQ(hull_with_speck.at(2, 2, 6), 0);
  EXPECT_EQ(MaskFromNonZero(with_speck, 0).at(2, 2, 6), 1) << "the non-zero rule keeps it";
}

// A solid band of zeros across the grid cuts the data in two components of equal size:
// both are kept, and the hull spans the band between them.
TEST(MaskFromConvexHull, KeepsBothHalvesAcrossASolidDarkBand) {
  const ImageGeometry g = Grid(24, 24, 24);
  Image image(g, 0.0f);
  for (int k = 3; k <= 20; ++k)
    for (int j = 3; j <= 20; ++j)
      for (int i = 3; i <= 20; ++i) image.at(i, j, k) = (k >= 10 && k <= 13) ? 0.0f : 7.0f;
  EXPECT_EQ(MaskFromNonZero(image, 0).at(10, 10, 11), 0) << "the band reaches the border";
  Mask hull;
  std::string why;
  ASSERT_TRUE(MaskFromConvexHull(image, 0, &hull, &why)) << why;
  EXPECT_EQ(CountInside(hull), 18 * 18 * 18);
  EXPECT_EQ(hull.at(10, 10, 11), 1);
  EXPECT_EQ(hull.at(3, 20, 12), 1);
  EXPECT_EQ(hull.at(2, 10, 12), 0);
}

// Data on one plane or one line spans no 3D hull: the non-zero rule is used.
TEST(FieldOfViewFromImage, FallsBackToTheNonZeroRuleWithoutA3DHull) {
  Image one_slice(Grid(16, 16, 1), 0.0f);
  for (int j = 3; j < 12; ++j)
    for (int i = 2; i < 14; ++i) one_slice.at(i, j, 0) = 5.0f;
  Image plane(Grid(16, 16, 16), 0.0f);
  for (int j = 3; j < 12; ++j)
    for (int i = 2; i < 14; ++i) plane.at(i, j, 7) = 5.0f;
  Image line(Grid(16, 16, 16), 0.0f);
  for (int i = 2; i < 14; ++i) line.at(i, 7, 7) = 5.0f;
  Image empty(Grid(16, 16, 16), 0.0f);
  for (const Image* image : {&one_slice, &plane, &line, &empty}) {
    Mask hull;
    std::string why;
    EXPECT_FALSE(MaskFromConvexHull(*image, 0, &hull, &why));
    EXPECT_TRUE(hull.empty());
    EXPECT_FALSE(why.empty());
    for (int erosion : {0, 1}) {
      MaskRule used = MaskRule::kHull;
      const Mask mask = FieldOfViewFromImage(*image, {MaskRule::kHull, erosion}, &used);
      EXPECT_EQ(used, MaskRule::kNonZero);
      EXPECT_EQ(mask.voxels, MaskFromNonZero(*image, erosion).voxels);
    }
  }
  EXPECT_EQ(CountInside(FieldOfViewFromImage(one_slice, {MaskRule::kHull, 0}, nullptr)), 9 * 12);
}

TEST(FieldOfViewFromImage, FullGridIsTheFullGridThenEroded) {
  const ImageGeometry g = Grid(12, 10, 9);
  const Image full(g, 3.0f);
  MaskRule used = MaskRule::kNonZero;
  EXPECT_EQ(CountInside(FieldOfViewFromImage(full, {MaskRule::kHull, 0}, &used)), 12 * 10 * 9);
  EXPECT_EQ(used, MaskRule::kHull);
  // The grid border counts as outside for the erosion, as in the non-zero rule.
  EXPECT_EQ(CountInside(FieldOfViewFromImage(full, {MaskRule::kHull, 1}, &used)), 10 * 8 * 7);
}

TEST(FieldOfViewFromImage, ErodesTheHull) {
  const Image image =
      NoisyPyramid(Grid(32, 32, 28), [](int, int, int) { return kBrightTissue; }, 3);
  Mask hull;
  std::string why;
  ASSERT_TRUE(MaskFromConvexHull(image, 0, &hull, &why)) << why;
  for (int erosion : {1, 2}) {
    Mask expected = hull;
    ErodeMask(erosion, &expected);
    const Mask mask = FieldOfViewFromImage(image, {MaskRule::kHull, erosion}, nullptr);
    EXPECT_EQ(mask.voxels, expected.voxels) << erosion;
    EXPECT_LT(CountInside(mask), CountInside(hull));
  }
}

TEST(FieldOfViewFromImage, NonZeroRuleIsMaskFromNonZero) {
  const Image image =
      NoisyPyramid(Grid(32, 32, 28), [](int, int, int) { return kDarkTissue; }, 5);
  MaskRule used = MaskRule::kHull;
  const Mask mask = FieldOfViewFromImage(image, {MaskRule::kNonZero, 1}, &used);
  EXPECT_EQ(used, MaskRule::kNonZero);
  EXPECT_EQ(mask.voxels, MaskFromNonZero(image, 1).voxels);
}

TEST(CheckFiniteVoxels, TellsAConstantImageInTheSamePass) {
  ImageGeometry g;
  g.size = Eigen::Vector3i(20, 20, 20);  // 8000 voxels: more than one chunk of the scan
  Image image(g, 0.0f);
  std::string error;
  bool constant = false;
  ASSERT_TRUE(CheckFiniteVoxels(image, "blank", &error, &constant));
  EXPECT_TRUE(constant);
  image.at(19, 19, 19) = -0.0f;  // equal to 0
  ASSERT_TRUE(CheckFiniteVoxels(image, "blank", &error, &constant));
  EXPECT_TRUE(constant);
  image.at(19, 19, 19) = 1e-30f;  // the last voxel differs
  ASSERT_TRUE(CheckFiniteVoxels(image, "image", &error, &constant));
  EXPECT_FALSE(constant);
  // Non-finite voxels are named as the check without `constant` names them.
  for (const float bad : {std::nanf(""), INFINITY, -INFINITY}) {
    Image copy = image;
    copy.at(3, 12, 13) = bad;
    copy.at(4, 12, 13) = bad;
    std::string expected;
    EXPECT_FALSE(CheckFiniteVoxels(copy, "image", &expected));
    EXPECT_FALSE(CheckFiniteVoxels(copy, "image", &error, &constant));
    EXPECT_EQ(error, expected);
    EXPECT_EQ(error, std::string("image: voxel (3,12,13) is ") + (std::isnan(bad) ? "NaN" : "Inf"));
  }
}

}  // namespace
}  // namespace dsr
