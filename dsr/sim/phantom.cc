// Procedural heart-like phantom (see phantom.h). Built in passes over one float volume:
// background and pericardium, myocardial walls, blood pools, muscle blobs, valve sheets,
// then texture. Each structure pass only visits the bounding box of its structure.
#include "dsr/sim/phantom.h"

#include <algorithm>
#include <cmath>
#include <random>
#include <sstream>
#include <vector>

#include <glog/logging.h>

#include "dsr/util/parallel.h"

namespace dsr {
namespace {

// Soft edges: the quintic smooth step goes from 1 (d <= -w) to 0 (d >= w), C2 smooth, so
// the transition spans 2w = 2.5 voxels.
constexpr double kEdgeHalfWidthVoxels = 1.25;
// Walls, the pericardium and muscle blobs are at least this thick (voxels), whatever the
// phantom size.
constexpr double kMinWallVoxels = 3.0;
// Valve sheets: half thickness of the flat top of the profile, in voxels.
constexpr double kSheetHalfThicknessVoxels = 0.6;
// Texture: scales (Gaussian sigma, voxels) and amplitudes (intensity units).
constexpr double kSlowSigmaVoxels = 12.0;  // background level variation
constexpr double kMediumSigmaVoxels = 4.0;
constexpr double kFineSigmaVoxels = 1.5;  // speckle-like; correlation length ~2 sigma
constexpr double kMediumAmplitude = 6.0;
constexpr double kFineAmplitude = 13.0;  // plus kFineRelativeAmplitude * level
constexpr double kFineRelativeAmplitude = 0.05;

double InsideWeight(double d, double w) {
  const double t = (d + w) / (2.0 * w);
  if (t <= 0.0) return 1.0;
  if (t >= 1.0) return 0.0;
  return 1.0 - t * t * t * (t * (6.0 * t - 15.0) + 10.0);
}

// Separable Gaussian smoothing along `axis` (clamped border), out of place. Axes 1 and 2
// work on whole x-rows so the inner loop is contiguous.
void SmoothAxis(const Eigen::Vector3i& n,
                int axis,
                double sigma,
                const std::vector<float>& in,
                std::vector<float>* out) {
  const int r = std::max(1, static_cast<int>(std::ceil(3.0 * sigma)));
  std::vector<float> kernel(2 * r + 1);
  double sum = 0.0;
  for (int t = -r; t <= r; ++t) {
    kernel[t + r] = static_cast<float>(std::exp(-0.5 * t * t / (sigma * sigma)));
    sum += kernel[t + r];
  }
  for (float& k : kernel) k = static_cast<float>(k / sum);
  out->assign(in.size(), 0.0f);
  const int nx = n[0], ny = n[1], nz = n[2];
  ParallelFor(0, nz, 0, [&](int64_t k) {
    std::vector<float> padded(nx + 2 * r);
    for (int j = 0; j < ny; ++j) {
      float* dst = out->data() + (k * ny + j) * int64_t{nx};
      if (axis == 0) {
        const float* src = in.data() + (k * ny + j) * int64_t{nx};
        for (int t = 0; t < nx + 2 * r; ++t) padded[t] = src[std::clamp(t - r, 0, nx - 1)];
        for (int d = 0; d <= 2 * r; ++d) {
          const float w = kernel[d];
          const float* p = padded.data() + d;
          for (int i = 0; i < nx; ++i) dst[i] += w * p[i];
        }
      } else {
        for (int d = -r; d <= r; ++d) {
          const float w = kernel[d + r];
          const int jj = axis == 1 ? std::clamp(j + d, 0, ny - 1) : j;
          const int kk =
              axis == 2 ? std::clamp(static_cast<int>(k) + d, 0, nz - 1) : static_cast<int>(k);
          const float* src = in.data() + (int64_t{kk} * ny + jj) * nx;
          for (int i = 0; i < nx; ++i) dst[i] += w * src[i];
        }
      }
    }
  });
}

// Linear upsampling along `axis` by `factor`: output index t reads input t / factor.
void UpsampleAxis(const Eigen::Vector3i& in_size,
                  int axis,
                  int out_len,
                  int factor,
                  const std::vector<float>& in,
                  std::vector<float>* out) {
  Eigen::Vector3i out_size = in_size;
  out_size[axis] = out_len;
  out->assign(static_cast<size_t>(out_size.cast<int64_t>().prod()), 0.0f);
  const int64_t in_stride[3] = {1, in_size[0], int64_t{in_size[0]} * in_size[1]};
  const int64_t out_stride[3] = {1, out_size[0], int64_t{out_size[0]} * out_size[1]};
  const int a1 = (axis + 1) % 3, a2 = (axis + 2) % 3;
  for (int t = 0; t < out_len; ++t) {
    const int i0 = std::min(t / factor, in_size[axis] - 2);
    const float f = static_cast<float>(t - i0 * factor) / static_cast<float>(factor);
    for (int q = 0; q < out_size[a2]; ++q) {
      for (int p = 0; p < out_size[a1]; ++p) {
        const int64_t src = i0 * in_stride[axis] + p * in_stride[a1] + q * in_stride[a2];
        (*out)[t * out_stride[axis] + p * out_stride[a1] + q * out_stride[a2]] =
            (1.0f - f) * in[src] + f * in[src + in_stride[axis]];
      }
    }
  }
}

// A zero-mean, unit-variance Gaussian random field on an n-grid whose correlation is a
// Gaussian of `sigma` voxels: white noise on a grid `factor` times coarser, smoothed there,
// linearly upsampled (cheap for slow fields; factor 1 for fine texture).
std::vector<float> RandomField(const Eigen::Vector3i& n,
                               double sigma,
                               int factor,
                               std::mt19937_64* rng) {
  Eigen::Vector3i coarse;
  for (int a = 0; a < 3; ++a) coarse[a] = factor == 1 ? n[a] : (n[a] - 1) / factor + 2;
  std::vector<float> field(static_cast<size_t>(coarse.cast<int64_t>().prod()));
  std::normal_distribution<float> normal(0.0f, 1.0f);
  for (float& v : field) v = normal(*rng);
  std::vector<float> tmp;
  for (int axis = 0; axis < 3; ++axis) {
    SmoothAxis(coarse, axis, sigma / factor, field, &tmp);
    field.swap(tmp);
  }
  if (factor > 1) {
    Eigen::Vector3i size = coarse;
    for (int axis = 0; axis < 3; ++axis) {
      UpsampleAxis(size, axis, n[axis], factor, field, &tmp);
      field.swap(tmp);
      size[axis] = n[axis];
    }
  }
  double sum = 0.0, sum2 = 0.0;
  for (float v : field) {
    sum += v;
    sum2 += double{v} * v;
  }
  const double mean = sum / field.size();
  const double sd = std::sqrt(std::max(1e-20, sum2 / field.size() - mean * mean));
  for (float& v : field) v = static_cast<float>((v - mean) / sd);
  return field;
}

// A rotated ellipsoid in physical mm.
struct Ellipsoid {
  Eigen::Vector3d center = Eigen::Vector3d::Zero();
  Eigen::Vector3d radii = Eigen::Vector3d::Ones();
  Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();  // columns: local axes in world

  // Approximate signed distance (mm), < 0 inside: (q - 1) / |grad q| with q the normalised
  // radius; exact on the surface to first order, so wall thickness is uniform.
  double SignedDistance(const Eigen::Vector3d& x) const {
    const Eigen::Vector3d local = rotation.transpose() * (x - center);
    const Eigen::Vector3d scaled = local.cwiseQuotient(radii);
    const double q = scaled.norm();
    const double grad = scaled.cwiseQuotient(radii).norm();  // |grad q| * q
    if (grad < 1e-12) return -radii.minCoeff();
    return (q - 1.0) * q / grad;
  }
  // Half extents of an axis-aligned box around the centre that holds every point with
  // SignedDistance < margin. q is a norm, hence convex, so SignedDistance underestimates the
  // true distance outside by at most a factor r_min / r_max: the true distance is then
  // < margin * r_max / r_min, and the box adds that to the ellipsoid's own half extents.
  Eigen::Vector3d HalfExtents(double margin) const {
    return rotation.cwiseAbs() * radii +
           Eigen::Vector3d::Constant(std::max(0.0, margin) * radii.maxCoeff() / radii.minCoeff());
  }
};

struct Chamber {
  Ellipsoid shape;
  double wall_mm = 0.0;
  double wall_level = 0.0;
};

// A valve-like leaflet: the cap of a sphere (centre `center`, radius `radius`) on the side
// of `axis`, cut to the disc of radius `rim` around the axis.
struct Sheet {
  Eigen::Vector3d center = Eigen::Vector3d::Zero();
  Eigen::Vector3d axis = Eigen::Vector3d::UnitZ();
  double radius = 1.0;
  double rim = 1.0;
};

Eigen::Matrix3d EulerZyx(const Eigen::Vector3d& angles_rad) {
  return (Eigen::AngleAxisd(angles_rad[2], Eigen::Vector3d::UnitZ()) *
          Eigen::AngleAxisd(angles_rad[1], Eigen::Vector3d::UnitY()) *
          Eigen::AngleAxisd(angles_rad[0], Eigen::Vector3d::UnitX()))
      .toRotationMatrix();
}

// Calls fn(linear index, physical point) for every voxel of `geometry` whose centre lies
// in the axis-aligned box [lo, hi] (mm). Parallel over slices; fn must only touch its voxel.
template <typename Fn>
void ForEachVoxelInBox(const ImageGeometry& g,
                       const Eigen::Vector3d& lo,
                       const Eigen::Vector3d& hi,
                       const Fn& fn) {
  // Identity direction and positive spacing (MakePhantom builds the grid).
  Eigen::Vector3i first, last;
  for (int a = 0; a < 3; ++a) {
    first[a] = std::max(0, static_cast<int>(std::ceil((lo[a] - g.origin_mm[a]) / g.spacing_mm[a])));
    last[a] = std::min(g.size[a] - 1,
                       static_cast<int>(std::floor((hi[a] - g.origin_mm[a]) / g.spacing_mm[a])));
    if (last[a] < first[a]) return;
  }
  ParallelFor(first[2], last[2] + 1, 0, [&](int64_t k) {
    for (int j = first[1]; j <= last[1]; ++j) {
      for (int i = first[0]; i <= last[0]; ++i) {
        const Eigen::Vector3d x =
            g.origin_mm + g.spacing_mm.cwiseProduct(Eigen::Vector3d(i, j, static_cast<double>(k)));
        fn(g.LinearIndex(i, j, static_cast<int>(k)), x);
      }
    }
  });
}

float Mix(float a, float b, double weight) { return static_cast<float>(a + (b - a) * weight); }

}  // namespace

bool PhantomOptions::Validate(std::string* error) const {
  std::ostringstream s;
  if (size < 16 || size > 512) {
    s << "size=" << size << ": must be in [16, 512]";
  } else if (!std::isfinite(spacing_mm) || spacing_mm <= 0.0) {
    s << "spacing_mm=" << spacing_mm << ": must be finite and > 0";
  } else {
    return true;
  }
  if (error != nullptr) *error = s.str();
  return false;
}

Image MakePhantom(const PhantomOptions& options) {
  std::string error;
  CHECK(options.Validate(&error)) << error;
  ImageGeometry g;
  g.size = Eigen::Vector3i::Constant(options.size);
  g.spacing_mm = Eigen::Vector3d::Constant(options.spacing_mm);
  g.origin_mm = Eigen::Vector3d::Constant(-0.5 * (options.size - 1) * options.spacing_mm);
  const double e = 0.5 * options.size * options.spacing_mm;  // half extent: layout unit
  const double w = kEdgeHalfWidthVoxels * options.spacing_mm;

  std::mt19937_64 rng(options.seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  const double deg = M_PI / 180.0;
  // Returns a Vector3d, not an Eigen expression (which would outlive its temporary).
  auto jitter = [&](const Eigen::Vector3d& v, double amount) -> Eigen::Vector3d {
    Eigen::Vector3d out;
    for (int a = 0; a < 3; ++a) out[a] = v[a] + amount * u(rng);  // sequenced draws
    return out;
  };

  // Layout in units of e: {centre, radii, base tilt (deg, x/y/z), wall thickness, level}.
  struct Spec {
    Eigen::Vector3d center, radii, tilt_deg;
    double wall, level;
  };
  const Spec specs[] = {
      {{0.20, 0.18, 0.00}, {0.24, 0.30, 0.26}, {0, 0, 12}, 0.085, 200},      // left ventricle
      {{-0.30, 0.14, 0.02}, {0.17, 0.28, 0.22}, {0, 0, -10}, 0.045, 170},    // right ventricle
      {{0.18, -0.22, -0.04}, {0.17, 0.15, 0.17}, {0, 0, 0}, 0.035, 165},     // left atrium
      {{-0.28, -0.23, 0.03}, {0.16, 0.16, 0.18}, {0, 0, 0}, 0.035, 160},     // right atrium
      {{0.02, -0.06, 0.34}, {0.08, 0.08, 0.28}, {20, 0, 0}, 0.030, 215},     // aorta
      {{-0.17, -0.14, 0.36}, {0.07, 0.07, 0.26}, {-25, 20, 0}, 0.030, 190},  // pulmonary artery
  };
  std::vector<Chamber> chambers;
  for (const Spec& spec : specs) {
    Chamber c;
    c.shape.center = e * jitter(spec.center, 0.03);
    c.shape.radii = e * spec.radii.cwiseProduct(jitter(Eigen::Vector3d::Ones(), 0.1));
    c.shape.rotation = EulerZyx(deg * jitter(spec.tilt_deg, 12.0));
    // Walls stay >= 3 voxels thick in small phantoms, so they remain resolved structures.
    c.wall_mm =
        std::max(e * spec.wall * (1.0 + 0.15 * u(rng)), kMinWallVoxels * options.spacing_mm);
    c.wall_level = spec.level + 15.0 * u(rng);
    chambers.push_back(c);
  }
  Ellipsoid pericardium;
  pericardium.center = e * jitter(Eigen::Vector3d(0.0, 0.04, 0.0), 0.02);
  pericardium.radii =
      e * Eigen::Vector3d(0.66, 0.66, 0.54).cwiseProduct(jitter(Eigen::Vector3d::Ones(), 0.05));
  pericardium.rotation = EulerZyx(deg * jitter(Eigen::Vector3d::Zero(), 8.0));
  const double pericardium_half_thickness =
      std::max(0.018 * e, 0.5 * kMinWallVoxels * options.spacing_mm);
  // Papillary-like muscle blobs inside the ventricles.
  std::vector<Ellipsoid> blobs;
  const Eigen::Vector3d blob_centers[] = {
      {0.12, 0.32, -0.08}, {0.30, 0.28, 0.08}, {-0.34, 0.25, 0.0}};
  for (const Eigen::Vector3d& center : blob_centers) {
    Ellipsoid b;
    b.center = e * jitter(center, 0.02);
    const Eigen::Vector3d scale = jitter(Eigen::Vector3d::Ones(), 0.15);
    b.radii = (e * Eigen::Vector3d(0.045, 0.08, 0.045).cwiseProduct(scale))
                  .cwiseMax(0.5 * kMinWallVoxels * options.spacing_mm);
    b.rotation = EulerZyx(deg * jitter(Eigen::Vector3d::Zero(), 25.0));
    blobs.push_back(b);
  }
  // Valve-like sheets: domes at the atrio-ventricular junctions, bulging into the
  // ventricle, and one at the aortic root.
  std::vector<Sheet> sheets;
  for (const auto& [atrium, ventricle] : {std::pair<int, int>{2, 0}, std::pair<int, int>{3, 1}}) {
    const Ellipsoid& a = chambers[atrium].shape;
    const Ellipsoid& v = chambers[ventricle].shape;
    Sheet s;
    s.axis = (v.center - a.center).normalized();
    const Eigen::Vector3d junction =
        a.center + (v.center - a.center) * a.radii[1] / (a.radii[1] + v.radii[1]);
    s.radius = 0.25 * e;
    s.rim = 0.10 * e * (1.0 + 0.1 * u(rng));
    s.center = junction - s.radius * s.axis;
    sheets.push_back(s);
  }
  {
    const Ellipsoid& aorta = chambers[4].shape;
    Sheet s;
    s.axis = aorta.rotation.col(2);
    s.radius = 0.12 * e;
    s.rim = 0.8 * aorta.radii[0];
    s.center = aorta.center - 0.75 * aorta.radii[2] * s.axis - s.radius * s.axis;
    sheets.push_back(s);
  }

  // Random fields: slow (background level), medium (texture and wall brightness), fine
  // (speckle). Coarse grids keep the slow ones cheap.
  const std::vector<float> slow = RandomField(g.size, kSlowSigmaVoxels, 8, &rng);
  const std::vector<float> medium = RandomField(g.size, kMediumSigmaVoxels, 2, &rng);
  const std::vector<float> fine = RandomField(g.size, kFineSigmaVoxels, 1, &rng);

  Image image(g);
  std::vector<float>& value = image.voxels;
  // Background: tissue outside the pericardium ~82, inside ~98, slowly varying.
  for (size_t l = 0; l < value.size(); ++l) value[l] = 82.0f + 14.0f * slow[l];
  const Eigen::Vector3d pericardium_half = pericardium.HalfExtents(pericardium_half_thickness + w);
  ForEachVoxelInBox(g,
                    pericardium.center - pericardium_half,
                    pericardium.center + pericardium_half,
                    [&](int64_t l, const Eigen::Vector3d& x) {
                      const double d = pericardium.SignedDistance(x);
                      float v = Mix(value[l], 98.0f + 12.0f * slow[l], InsideWeight(d, w));
                      v = Mix(v,
                              175.0f * (1.0f + 0.1f * medium[l]),
                              InsideWeight(std::abs(d) - pericardium_half_thickness, w));
                      value[l] = v;
                    });
  // Walls first, then pools: a later wall never cuts into an earlier pool, overlapping
  // walls form septa, overlapping pools form openings.
  for (const Chamber& c : chambers) {
    const Eigen::Vector3d half = c.shape.HalfExtents(c.wall_mm + w);
    ForEachVoxelInBox(
        g, c.shape.center - half, c.shape.center + half, [&](int64_t l, const Eigen::Vector3d& x) {
          const double weight = InsideWeight(c.shape.SignedDistance(x) - c.wall_mm, w);
          if (weight > 0.0) {
            value[l] =
                Mix(value[l], static_cast<float>(c.wall_level) * (1.0f + 0.1f * medium[l]), weight);
          }
        });
  }
  for (const Chamber& c : chambers) {
    const Eigen::Vector3d half = c.shape.HalfExtents(w);
    ForEachVoxelInBox(
        g, c.shape.center - half, c.shape.center + half, [&](int64_t l, const Eigen::Vector3d& x) {
          const double weight = InsideWeight(c.shape.SignedDistance(x), w);
          if (weight > 0.0) value[l] = Mix(value[l], 26.0f + 5.0f * medium[l], weight);
        });
  }
  for (const Ellipsoid& b : blobs) {
    const Eigen::Vector3d half = b.HalfExtents(w);
    ForEachVoxelInBox(
        g, b.center - half, b.center + half, [&](int64_t l, const Eigen::Vector3d& x) {
          const double weight = InsideWeight(b.SignedDistance(x), w);
          if (weight > 0.0) value[l] = Mix(value[l], 175.0f * (1.0f + 0.1f * medium[l]), weight);
        });
  }
  const double sheet_half = kSheetHalfThicknessVoxels * options.spacing_mm;
  for (const Sheet& s : sheets) {
    // Where the weight is non-zero, the radial distance is < rim + w and 0 < along <
    // radius + sheet_half + w, so such points lie within rim + w + radius of the top point.
    const Eigen::Vector3d top = s.center + s.radius * s.axis;
    const Eigen::Vector3d half =
        Eigen::Vector3d::Constant(s.rim + w + std::max(s.radius, sheet_half + w));
    ForEachVoxelInBox(g, top - half, top + half, [&](int64_t l, const Eigen::Vector3d& x) {
      const Eigen::Vector3d r = x - s.center;
      const double along = r.dot(s.axis);
      if (along <= 0.0) return;
      const double radial = (r - along * s.axis).norm();
      const double weight = InsideWeight(std::abs(r.norm() - s.radius) - sheet_half, 0.8 * w) *
                            InsideWeight(radial - s.rim, w);
      if (weight > 0.0) value[l] = Mix(value[l], 225.0f, weight);
    });
  }
  // Texture on every voxel, then clamp.
  ParallelFor(0, g.size[2], 0, [&](int64_t k) {
    const int64_t begin = k * int64_t{g.size[0]} * g.size[1];
    const int64_t end = begin + int64_t{g.size[0]} * g.size[1];
    for (int64_t l = begin; l < end; ++l) {
      const double level = value[l];
      const double textured = level + kMediumAmplitude * medium[l] +
                              (kFineAmplitude + kFineRelativeAmplitude * level) * fine[l];
      value[l] = static_cast<float>(std::clamp(textured, 0.0, 255.0));
    }
  });
  return image;
}

}  // namespace dsr
