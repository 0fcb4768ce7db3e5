#include "dsr/pipeline/input_checks.h"

#include <algorithm>
#include <cmath>
#include <sstream>

#include "dsr/model/panorama.h"
#include "dsr/pipeline/registration_options.h"
#include "dsr/util/parallel.h"

namespace dsr {
namespace {

std::string Format(double value) {
  std::ostringstream s;
  s.precision(3);
  s << value;
  return s.str();
}

std::string FormatVector(const Eigen::Vector3d& v) {
  return Format(v[0]) + " " + Format(v[1]) + " " + Format(v[2]);
}

Eigen::Vector3d Extent(const ImageGeometry& g) {
  return g.size.cast<double>().cwiseProduct(g.spacing_mm);
}

// The median of `values` (reordered).
double MedianOf(std::vector<float>* values) {
  const size_t mid = values->size() / 2;
  std::nth_element(values->begin(), values->begin() + mid, values->end());
  return static_cast<double>((*values)[mid]);
}

// A frame whose single largest squared deviation from its median is more than this share
// of the sum over all its voxels: one voxel would outweigh all the others together in the
// sum of squared differences the registration minimises.
constexpr double kMaxOneVoxelShare = 0.5;

// The frames' outlier voxels (a corrupt or saturated value such as 1e30): false with
// `error` naming the frame, the voxel, its value and its share of the frame's squared
// deviation. The median comes from at most about 10^5 evenly spaced voxels.
bool CheckOutlierVoxels(const std::vector<Image>& images, int num_threads, std::string* error) {
  // The frames in parallel, each summed in voxel order; the first frame in order that fails
  // is the one named.
  const size_t m = images.size();
  std::vector<double> largest_share(m, 0.0), median_of(m, 0.0);
  std::vector<size_t> largest_at(m, 0);
  ParallelFor(0, static_cast<int64_t>(m), num_threads, [&](int64_t f) {
    const std::vector<float>& v = images[f].voxels;
    if (v.empty()) return;
    const size_t stride = std::max<size_t>(1, v.size() / 100000);
    std::vector<float> sample;
    for (size_t l = 0; l < v.size(); l += stride) sample.push_back(v[l]);
    const double median = MedianOf(&sample);
    double sum = 0.0, largest = 0.0;
    size_t at = 0;
    for (size_t l = 0; l < v.size(); ++l) {
      const double deviation = static_cast<double>(v[l]) - median;
      const double d = deviation * deviation;
      sum += d;
      if (d > largest) largest = d, at = l;
    }
    median_of[f] = median;
    largest_at[f] = at;
    if (sum > 0.0 && largest > kMaxOneVoxelShare * sum) largest_share[f] = largest / sum;
  });
  for (size_t f = 0; f < m; ++f) {
    if (largest_share[f] == 0.0) continue;
    const std::vector<float>& v = images[f].voxels;
    const size_t at = largest_at[f];
    const Eigen::Vector3i& n = images[f].geometry.size;
    std::ostringstream text;
    text << "frame " << f << " has an outlier intensity: its voxel ("
         << at % n[0] << "," << at / n[0] % n[1] << "," << at / (size_t(n[0]) * n[1]) << ") is "
         << v[at] << " (the frame's median " << median_of[f] << ") and holds "
         << Format(100.0 * largest_share[f]) << "% of the frame's squared deviation from its "
         << "median: that one voxel would outweigh all the others in the registration's cost; "
         << "clip or remove it";
    *error = text.str();
    return false;
  }
  return true;
}

}  // namespace

bool CheckRegistrationGeometry(const std::vector<Image>& images,
                               const std::vector<Eigen::Isometry3d>& initial_frame_from_world,
                               const RegistrationOptions& options,
                               std::string* error) {
  const ImageGeometry& first = images[0].geometry;
  for (size_t i = 1; i < images.size(); ++i) {
    const Eigen::Vector3d ratio = images[i].geometry.spacing_mm.cwiseQuotient(first.spacing_mm);
    const double worst = std::max(ratio.maxCoeff(), 1.0 / ratio.minCoeff());
    if (!(worst <= kMaxSpacingRatio)) {
      *error = "frame " + std::to_string(i) + " has a voxel spacing of " +
               FormatVector(images[i].geometry.spacing_mm) + " mm, " + Format(worst) +
               " times " + (ratio.maxCoeff() > 1.0 ? "coarser" : "finer") + " than frame 0's (" +
               FormatVector(first.spacing_mm) +
               " mm): frames of one sequence share a scale (within a factor of " +
               Format(kMaxSpacingRatio) + "); check that image's header";
      return false;
    }
  }
  const int shortest_axis = first.size.minCoeff();
  if (options.smoothing > 0.25 * shortest_axis) {
    *error = "smoothing=" + Format(options.smoothing) +
             ": a Gaussian of that many voxels erases every structure of frame 0 (" +
             std::to_string(shortest_axis) + " voxels along its shortest axis); must be at most " +
             Format(0.25 * shortest_axis);
    return false;
  }
  if (!CheckPanoramaSpacing(first, options.panorama_spacing, error)) return false;
  // Frame centres in world at the initial poses.
  double largest_extent = 0.0;
  for (const Image& image : images) {
    largest_extent = std::max(largest_extent, Extent(image.geometry).norm());
  }
  const auto centre_in_world = [&](size_t i) {
    const ImageGeometry& g = images[i].geometry;
    const Eigen::Vector3d centre =
        g.IndexToPhysical(0.5 * (g.size.cast<double>() - Eigen::Vector3d::Ones()));
    return Eigen::Vector3d(initial_frame_from_world[i].inverse() * centre);
  };
  const Eigen::Vector3d centre0 = centre_in_world(0);
  const bool identity = std::all_of(
      initial_frame_from_world.begin(), initial_frame_from_world.end(),
      [](const Eigen::Isometry3d& t) { return t.matrix() == Eigen::Matrix4d::Identity(); });
  for (size_t i = 1; i < images.size(); ++i) {
    const double distance = (centre_in_world(i) - centre0).stableNorm();
    if (!(distance <= kMaxInitialSpread * largest_extent) && identity) {
      // No poses were given: the images' own headers put them apart.
      *error = "frame " + std::to_string(i) + " lies " + Format(distance) +
               " mm from frame 0 in physical coordinates (its origin " +
               FormatVector(images[i].geometry.origin_mm) + " mm, frame 0's " +
               FormatVector(first.origin_mm) + " mm), more than " + Format(kMaxInitialSpread) +
               " times the frames' size (" + Format(largest_extent) +
               " mm): check that image's header (origin), or give initial poses (init)";
      return false;
    }
    if (!(distance <= kMaxInitialSpread * largest_extent)) {
      *error = "the initial poses (init) place frame " + std::to_string(i) + " " +
               Format(distance) + " mm from frame 0, more than " + Format(kMaxInitialSpread) +
               " times the frames' size (" + Format(largest_extent) +
               " mm): check the poses file's translations (millimetres, world to frame)";
      return false;
    }
  }
  return true;
}

bool CheckRegistrationInputs(const std::vector<Image>& images,
                             const std::vector<Eigen::Isometry3d>& initial_frame_from_world,
                             const RegistrationOptions& options,
                             std::string* error) {
  return CheckRegistrationGeometry(images, initial_frame_from_world, options, error) &&
         CheckOutlierVoxels(images, options.solve.num_threads, error);
}

double IntensitySpread(const std::vector<Image>& images, const std::vector<Mask>& masks) {
  int64_t total = 0;
  for (const Mask& mask : masks) total += static_cast<int64_t>(mask.voxels.size());
  const int64_t stride = std::max<int64_t>(1, total / 1000000);
  std::vector<float> samples;
  for (size_t f = 0; f < images.size(); ++f) {
    const std::vector<float>& v = images[f].voxels;
    const std::vector<uint8_t>& inside = masks[f].voxels;
    for (size_t l = 0; l < v.size(); l += stride) {
      if (inside[l] && std::isfinite(v[l])) samples.push_back(v[l]);
    }
  }
  if (samples.empty()) return 0.0;
  const double median = MedianOf(&samples);
  std::vector<float> deviations(samples.size());
  double sum = 0.0;
  for (size_t s = 0; s < samples.size(); ++s) {
    const double d = std::abs(static_cast<double>(samples[s]) - median);
    deviations[s] = static_cast<float>(d);
    sum += d;
  }
  const double mad = MedianOf(&deviations);
  return mad > 0.0 ? mad : sum / static_cast<double>(samples.size());
}

int IntensityScaleExponent(double spread) {
  if (!(spread > 0.0) || !std::isfinite(spread)) return 0;
  if (spread >= kMinIntensitySpread && spread <= kMaxIntensitySpread) return 0;
  return static_cast<int>(std::lround(std::log2(kTargetIntensitySpread / spread)));
}

}  // namespace dsr
