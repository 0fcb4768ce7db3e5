#include "dsr/image/pyramid.h"

#include <algorithm>
#include <cmath>

#include <glog/logging.h>

#include "dsr/util/huge_pages.h"
#include "dsr/util/parallel.h"

namespace dsr {

std::vector<float> GaussianKernel(double sigma) {
  const int radius = std::max(1, static_cast<int>(std::ceil(3.0 * sigma)));
  std::vector<float> w(2 * radius + 1);
  double sum = 0.0;
  for (int d = -radius; d <= radius; ++d) {
    const double x = std::exp(-0.5 * d * d / (sigma * sigma));
    w[d + radius] = static_cast<float>(x);
    sum += x;
  }
  for (float& x : w) x = static_cast<float>(x / sum);
  return w;
}

namespace {

// A dense float volume with plain sizes (intermediate results of separable passes).
struct Grid3 {
  Eigen::Vector3i size;
  std::vector<float> v;
  int64_t Index(int i, int j, int k) const {
    return i + int64_t{size[0]} * (j + int64_t{size[1]} * k);
  }
};

int OutputSize(int n, int stride) { return stride == 1 ? n : (n - 1) / stride + 1; }

// Convolves along `axis` with `kernel` (empty = copy), keeping every `stride`-th output
// (output o at input index stride * o). Samples outside the grid count as 0 (the
// normalised convolution divides that out).
Grid3 ConvolveAxis(const Grid3& in, int axis, const std::vector<float>& kernel, int stride,
                   int num_threads) {
  Grid3 out;
  out.size = in.size;
  out.size[axis] = OutputSize(in.size[axis], stride);
  AssignWithHugePages(&out.v, static_cast<size_t>(out.size.cast<int64_t>().prod()), 0.0f);
  const int radius = static_cast<int>(kernel.size()) / 2;
  const int n = in.size[axis];
  const int64_t in_stride = axis == 0   ? 1
                            : axis == 1 ? in.size[0]
                                        : int64_t{in.size[0]} * in.size[1];
  const int64_t out_stride =
      axis == 0 ? 1 : axis == 1 ? out.size[0] : int64_t{out.size[0]} * out.size[1];
  if (axis != 0) {
    // Along y or z the line's samples lie a row or a plane apart: each output row (along x)
    // is the kernel-weighted sum of whole input rows, added tap by tap in the order the line
    // sum below takes them, so every output is the same float sum, with unit-stride rows.
    const int nx = in.size[0];
    const int outer = axis == 1 ? in.size[2] : 1;  // planes (y pass) or one (z pass)
    const int64_t plane_in = int64_t{in.size[0]} * in.size[1];
    const int64_t plane_out = int64_t{out.size[0]} * out.size[1];
    // Work items: (plane, output line index along the axis) pairs, or for z whole outputs.
    const int64_t lines = int64_t{outer} * out.size[axis];
    ParallelFor(0, lines, num_threads, [&](int64_t item) {
      const int c2 = static_cast<int>(item / out.size[axis]);
      const int o = static_cast<int>(item % out.size[axis]);
      const int64_t in_plane = axis == 1 ? c2 * plane_in : 0;
      const int64_t out_plane = axis == 1 ? c2 * plane_out : 0;
      // For the z pass, every row of output plane o; for the y pass, output row o.
      const int rows = axis == 1 ? 1 : in.size[1];
      const int center = stride * o;
      for (int r = 0; r < rows; ++r) {
        float* dst = out.v.data() + out_plane + o * out_stride + int64_t{r} * nx;
        const float* src = in.v.data() + in_plane + int64_t{r} * nx;
        if (kernel.empty()) {
          std::copy(src + center * in_stride, src + center * in_stride + nx, dst);
          continue;
        }
        const int lo = std::max(0, center - radius), hi = std::min(n - 1, center + radius);
        for (int x = lo; x <= hi; ++x) {
          const float w = kernel[x - center + radius];
          const float* line = src + x * in_stride;
          for (int i = 0; i < nx; ++i) dst[i] += w * line[i];
        }
      }
    });
    return out;
  }
  // Lines along x: indexed by the two other output coordinates.
  const int a1 = 1, a2 = 2;
  ParallelFor(0, out.size[a2], num_threads, [&](int64_t c2) {
    for (int c1 = 0; c1 < out.size[a1]; ++c1) {
      int in_ijk[3] = {0, 0, 0};
      in_ijk[a1] = c1;
      in_ijk[a2] = static_cast<int>(c2);
      const int64_t in_base = in.Index(in_ijk[0], in_ijk[1], in_ijk[2]);
      const int64_t out_base = out.Index(in_ijk[0], in_ijk[1], in_ijk[2]);
      for (int o = 0; o < out.size[axis]; ++o) {
        const int center = stride * o;
        float sum = 0.0f;
        if (kernel.empty()) {
          sum = in.v[in_base + center * in_stride];
        } else {
          const int lo = std::max(0, center - radius), hi = std::min(n - 1, center + radius);
          for (int x = lo; x <= hi; ++x)
            sum += kernel[x - center + radius] * in.v[in_base + x * in_stride];
        }
        out.v[out_base + o * out_stride] = sum;
      }
    }
  });
  return out;
}

// Separable smoothing of `g` with stride `stride` on every axis from `first_axis` on that
// has more than one voxel (stride 1 on single-voxel axes), with sigma[axis] along each
// (<= 0: not smoothed along that axis).
Grid3 SmoothAndStride(Grid3 g, const Eigen::Vector3d& sigma, int stride, int first_axis,
                      int num_threads) {
  for (int axis = first_axis; axis < 3; ++axis) {
    const bool flat = g.size[axis] == 1;
    const std::vector<float> kernel =
        sigma[axis] > 0.0 && !flat ? GaussianKernel(sigma[axis]) : std::vector<float>();
    g = ConvolveAxis(g, axis, kernel, flat ? 1 : stride, num_threads);
  }
  return g;
}

// The first (x) pass of the normalised convolution, straight from the image and its mask:
// value = G_x * (I M), weight = G_x * M, every `stride`-th output along x (stride 1 and
// no smoothing on a single-voxel x axis). Saves the full-resolution masked copies.
void MaskedPassX(const Image& image, const Mask& mask, double sigma, int stride,
                 int num_threads, Grid3* value, Grid3* weight) {
  const Eigen::Vector3i n = image.geometry.size;
  const bool flat = n[0] == 1;
  const std::vector<float> kernel =
      sigma > 0.0 && !flat ? GaussianKernel(sigma) : std::vector<float>{1.0f};
  const int radius = static_cast<int>(kernel.size()) / 2;
  const int step = flat ? 1 : stride;
  value->size = weight->size = n;
  value->size[0] = weight->size[0] = OutputSize(n[0], step);
  const int64_t out_count = value->size.cast<int64_t>().prod();
  AssignWithHugePages(&value->v, static_cast<size_t>(out_count), 0.0f);
  AssignWithHugePages(&weight->v, static_cast<size_t>(out_count), 0.0f);
  const int nx = n[0], ox = value->size[0];
  // With stride 2, the outputs whose taps all lie inside the row (o_lo..o_hi) are summed
  // tap by tap over the whole run of them, from the row's even and odd voxels (masked: 0
  // outside the mask, whose term then adds +0 and changes no sum), unit-stride loops the
  // compiler vectorises. Each output still adds its taps in increasing x from 0, so it is
  // the per-output loop's float sum bit for bit (that loop still makes the row's ends).
  const bool runs = step == 2;
  const int o_lo = (radius + 1) / 2, o_hi = (nx - 1 - radius) / 2;
  ParallelFor(0, n[2], num_threads, [&](int64_t k) {
    std::vector<float> even_value, odd_value, even_weight, odd_weight;
    if (runs) {
      even_value.resize((nx + 1) / 2);
      even_weight.resize((nx + 1) / 2);
      odd_value.resize(nx / 2 + 1);
      odd_weight.resize(nx / 2 + 1);
    }
    for (int j = 0; j < n[1]; ++j) {
      const int64_t in_base = image.geometry.LinearIndex(0, j, static_cast<int>(k));
      const int64_t out_base = value->Index(0, j, static_cast<int>(k));
      const float* im = image.voxels.data() + in_base;
      const uint8_t* ma = mask.voxels.data() + in_base;
      const auto one_output = [&](int o) {
        const int center = step * o;
        const int lo = std::max(0, center - radius), hi = std::min(nx - 1, center + radius);
        float v = 0.0f, w = 0.0f;
        for (int x = lo; x <= hi; ++x) {
          if (ma[x] == 0) continue;
          const float c = kernel[x - center + radius];
          v += c * im[x];
          w += c;
        }
        value->v[out_base + o] = v;
        weight->v[out_base + o] = w;
      };
      if (!runs || o_lo > o_hi) {
        for (int o = 0; o < ox; ++o) one_output(o);
        continue;
      }
      for (int x = 0; x < nx; x += 2) {
        even_value[x / 2] = ma[x] != 0 ? im[x] : 0.0f;
        even_weight[x / 2] = ma[x] != 0 ? 1.0f : 0.0f;
      }
      for (int x = 1; x < nx; x += 2) {
        odd_value[x / 2] = ma[x] != 0 ? im[x] : 0.0f;
        odd_weight[x / 2] = ma[x] != 0 ? 1.0f : 0.0f;
      }
      for (int o = 0; o < o_lo; ++o) one_output(o);
      float* __restrict v = value->v.data() + out_base;
      float* __restrict w = weight->v.data() + out_base;
      for (int t = 0; t <= 2 * radius; ++t) {
        // Tap t of output o reads voxel 2 o + d: even voxel o + d / 2, or odd o + (d - 1) / 2.
        const int d = t - radius;
        const bool odd = (d & 1) != 0;
        const int shift = odd ? (d - 1) / 2 : d / 2;
        const float* __restrict sv = (odd ? odd_value : even_value).data();
        const float* __restrict sw = (odd ? odd_weight : even_weight).data();
        const float c = kernel[t];
        for (int o = o_lo; o <= o_hi; ++o) {
          v[o] += c * sv[o + shift];
          w[o] += c * sw[o + shift];
        }
      }
      for (int o = o_hi + 1; o < ox; ++o) one_output(o);
    }
  });
}

// Normalised convolution with sigma[axis] voxels along each axis: returns the smoothed
// image and the smoothed mask weight.
void NormalisedSmooth(const Image& image, const Mask& mask, const Eigen::Vector3d& sigma,
                      int stride, int num_threads, Grid3* value, Grid3* weight) {
  CHECK(image.geometry.SameGrid(mask.geometry));
  MaskedPassX(image, mask, sigma[0], stride, num_threads, value, weight);
  *value = SmoothAndStride(std::move(*value), sigma, stride, 1, num_threads);
  *weight = SmoothAndStride(std::move(*weight), sigma, stride, 1, num_threads);
  // Weights below this carry too little data to be trusted (far outside the mask).
  constexpr float kMinWeight = 1e-3f;
  for (size_t l = 0; l < value->v.size(); ++l) {
    value->v[l] = weight->v[l] > kMinWeight ? value->v[l] / weight->v[l] : 0.0f;
  }
}

}  // namespace

Image SmoothInsideMask(const Image& image, const Mask& mask, double sigma_voxels, int num_threads) {
  return SmoothInsideMask(image, mask, Eigen::Vector3d::Constant(sigma_voxels), num_threads);
}

Image SmoothInsideMask(const Image& image,
                       const Mask& mask,
                       const Eigen::Vector3d& sigma_voxels,
                       int num_threads) {
  if ((sigma_voxels.array() <= 0.0).all()) return image;
  Grid3 value, weight;
  NormalisedSmooth(image, mask, sigma_voxels, 1, num_threads, &value, &weight);
  Image out(image.geometry);
  out.voxels = std::move(value.v);
  return out;
}

ImageLevel Downsample(const Image& image, const Mask& mask, double sigma_voxels, int num_threads) {
  Grid3 value, weight;
  NormalisedSmooth(image, mask, Eigen::Vector3d::Constant(sigma_voxels), 2, num_threads, &value,
                   &weight);
  ImageGeometry g = image.geometry;
  for (int a = 0; a < 3; ++a) {
    if (g.size[a] > 1) {
      g.size[a] = OutputSize(g.size[a], 2);
      g.spacing_mm[a] *= 2.0;
    }
  }
  CHECK_EQ(g.size, value.size);
  ImageLevel level;
  level.image = Image(g);
  level.image.voxels = std::move(value.v);
  // The coarse mask: the fine mask at 2c (see pyramid.h).
  level.mask = Mask(g, 0);
  const Eigen::Vector3i& n = image.geometry.size;
  for (int k = 0; k < g.size[2]; ++k) {
    for (int j = 0; j < g.size[1]; ++j) {
      for (int i = 0; i < g.size[0]; ++i) {
        const int c[3] = {n[0] > 1 ? 2 * i : i, n[1] > 1 ? 2 * j : j, n[2] > 1 ? 2 * k : k};
        level.mask.at(i, j, k) = mask.voxels[image.geometry.LinearIndex(c[0], c[1], c[2])] != 0;
      }
    }
  }
  return level;
}

std::vector<ImageLevel> BuildPyramid(const Image& image,
                                     const Mask& mask,
                                     int num_levels,
                                     double sigma_voxels,
                                     double finest_sigma_voxels,
                                     int min_size,
                                     int num_threads) {
  std::vector<ImageLevel> levels(1);
  if (finest_sigma_voxels > 0.0) {
    levels[0].image = SmoothInsideMask(image, mask, finest_sigma_voxels, num_threads);
    levels[0].mask = mask;
  }
  // The finest level as it is, whether kept in levels[0] or the input itself.
  const Image* finer_image = finest_sigma_voxels > 0.0 ? &levels[0].image : &image;
  const Mask* finer_mask = finest_sigma_voxels > 0.0 ? &levels[0].mask : &mask;
  for (int l = 1; l < num_levels; ++l) {
    const Eigen::Vector3i& n = finer_image->geometry.size;
    bool too_small = false;
    for (int a = 0; a < 3; ++a) {
      if (n[a] > 1 && OutputSize(n[a], 2) < min_size) too_small = true;
    }
    if (too_small) break;
    levels.push_back(Downsample(*finer_image, *finer_mask, sigma_voxels, num_threads));
    finer_image = &levels.back().image;
    finer_mask = &levels.back().mask;
  }
  return levels;
}

}  // namespace dsr
