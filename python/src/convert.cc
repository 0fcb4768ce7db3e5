// Conversions between numpy arrays and the library's types, with the rules the files have:
// images and masks (arrays with their geometry) to and from Volumes, 4x4 arrays to and from
// poses, and the poses dict to and from a PosesFile.
#include "module_internal.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <sstream>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

#include <Eigen/Geometry>

#include "dsr/geometry/volume.h"
#include "dsr/io/io_phases.h"
#include "dsr/io/io_poses.h"

namespace dsr {
namespace python_internal {
namespace {

// Wider floating-point values beyond float32's range (which the cast would make Inf):
// named as what they are, not as Inf.
void CheckFloatRange(const py::array& input, const std::string& what) {
  // The dtype's Python attribute: pybind11's itemsize() reads a field numpy 2 moved.
  if (input.dtype().kind() != 'f' || input.dtype().attr("itemsize").cast<int>() <= 4) return;
  const auto wide = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(input);
  if (!wide || wide.ndim() != 3) return;
  const double* v = wide.data();
  for (ssize_t n = 0; n < wide.size(); ++n) {
    if (!std::isfinite(v[n]) || std::abs(v[n]) <= std::numeric_limits<float>::max()) continue;
    const ssize_t nx = wide.shape(2), ny = wide.shape(1);
    std::ostringstream value;
    value << v[n];
    BadInput(what + ": voxel (" + std::to_string(n % nx) + "," + std::to_string(n / nx % ny) + "," +
             std::to_string(n / (nx * ny)) + ") is " + value.str() +
             ", beyond float32's range (dsr registers float32 intensities): rescale the image");
  }
}

}  // namespace

ImageGeometry ToGeometry(const std::vector<ssize_t>& shape,
                         const Geometry& g,
                         const std::string& what) {
  const auto& [spacing, origin, direction] = g;
  if (shape.size() != 3) {
    BadInput(what + ": " + std::to_string(shape.size()) + "D array; dsr registers 3D images " +
             "of scalar voxels (an array of 3 axes)");
  }
  if (spacing.size() != 3 || origin.size() != 3 || direction.size() != 9) {
    BadInput(what + ": spacing and origin need 3 numbers and the direction 9 (a 3x3 matrix)");
  }
  ImageGeometry out;
  out.size = Eigen::Vector3i(static_cast<int>(shape[2]), static_cast<int>(shape[1]),
                             static_cast<int>(shape[0]));
  for (int d = 0; d < 3; ++d) {
    out.spacing_mm[d] = spacing[d];
    out.origin_mm[d] = origin[d];
    for (int e = 0; e < 3; ++e) out.direction(d, e) = direction[3 * d + e];
  }
  return out;
}

Geometry FromGeometry(const ImageGeometry& g) {
  std::vector<double> direction(9);
  for (int d = 0; d < 3; ++d) {
    for (int e = 0; e < 3; ++e) direction[3 * d + e] = g.direction(d, e);
  }
  return {{g.spacing_mm[0], g.spacing_mm[1], g.spacing_mm[2]},
          {g.origin_mm[0], g.origin_mm[1], g.origin_mm[2]},
          direction};
}

template <typename T>
Volume<T> ToVolume(const py::array& input,
                   const Geometry& geometry,
                   const std::string& what,
                   bool refuse_constant) {
  // numpy would cast complex values to their real part with no more than a warning.
  if (input.dtype().kind() == 'c') {
    BadInput(what + ": complex pixels (" + std::string(py::str(input.dtype())) +
             "); dsr registers real intensities: pass the magnitude (numpy.abs) or the real part");
  }
  if constexpr (std::is_same_v<T, float>) CheckFloatRange(input, what);  // before the cast
  const auto array = py::array_t<T, py::array::c_style | py::array::forcecast>::ensure(input);
  if (!array) BadInput(what + ": not an array of numbers");
  std::vector<ssize_t> shape(array.shape(), array.shape() + array.ndim());
  Volume<T> out(ToGeometry(shape, geometry, what));
  std::string error;
  if (!out.geometry.Validate(what, &error)) BadInput(error);
  std::copy(array.data(), array.data() + out.voxels.size(), out.voxels.begin());
  if constexpr (std::is_same_v<T, float>) {
    bool constant = false;
    if (!CheckFiniteVoxels(out, what, &error, refuse_constant ? &constant : nullptr)) {
      BadInput(error);
    }
    // A view's phase as a 4D file's is read (io/io_phases.h, ReadView).
    if (constant) BadInput(ConstantPhaseError(what, out));
  }
  return out;
}

Mask ToMask(const py::array& input, const Geometry& geometry, const std::string& what) {
  const Volume<double> values = ToVolume<double>(input, geometry, what);
  Mask mask(values.geometry);
  bool any = false;
  for (size_t v = 0; v < values.voxels.size(); ++v) {
    if (std::isnan(values.voxels[v])) BadInput(what + ": a voxel is NaN (masks are 0 or not)");
    mask.voxels[v] = values.voxels[v] != 0.0;
    any = any || mask.voxels[v] != 0;
  }
  if (!any) BadInput(what + ": no voxel inside (every voxel is 0)");
  return mask;
}

Mask ToMaskPhases(const py::array& input, const Geometry& geometry, const std::string& what) {
  if (input.ndim() != 4) return ToMask(input, geometry, what);
  if (input.shape(0) == 0) BadInput(what + ": an array of 0 phases");
  Mask mask = ToMask(input.attr("__getitem__")(0), geometry, what);
  const Eigen::Vector3i& n = mask.geometry.size;
  for (ssize_t t = 1; t < input.shape(0); ++t) {
    const Volume<double> phase = ToVolume<double>(input.attr("__getitem__")(t), geometry,
                                                  what + " phase " + std::to_string(t));
    for (size_t v = 0; v < phase.voxels.size(); ++v) {
      if ((phase.voxels[v] != 0.0) == (mask.voxels[v] != 0)) continue;
      BadInput(what + ": mask phase " + std::to_string(t) + " differs from phase 0 at " +
               VoxelName(static_cast<int64_t>(v), n[0], n[1]) +
               " (a 4D mask is taken only when every phase has the same inside)");
    }
  }
  return mask;
}

template <typename T>
py::array_t<T> ToArray(const Volume<T>& volume) {
  const Eigen::Vector3i& n = volume.geometry.size;
  py::array_t<T> out(
      {static_cast<ssize_t>(n[2]), static_cast<ssize_t>(n[1]), static_cast<ssize_t>(n[0])});
  std::copy(volume.voxels.begin(), volume.voxels.end(), out.mutable_data());
  return out;
}

py::array_t<double> ToArray(const Eigen::Isometry3d& pose) {
  py::array_t<double> out({4, 4});
  for (int r = 0; r < 4; ++r) {
    for (int c = 0; c < 4; ++c) out.mutable_at(r, c) = pose.matrix()(r, c);
  }
  return out;
}

Eigen::Isometry3d ToPose(const py::array_t<double, py::array::c_style | py::array::forcecast>& a,
                         const std::string& where) {
  if (a.ndim() != 2 || a.shape(0) != 4 || a.shape(1) != 4) {
    BadInput(where + "a pose must be a 4x4 matrix");
  }
  Eigen::Matrix4d m;
  for (int r = 0; r < 4; ++r) {
    for (int c = 0; c < 4; ++c) m(r, c) = a.at(r, c);
  }
  Eigen::Isometry3d pose;
  std::string error;
  if (!PoseFromMatrix(m, where, &pose, &error)) BadInput(error);
  return pose;
}

py::dict PosesToDict(const PosesFile& poses) {
  py::dict out;
  py::list matrices, covariance;
  for (const Eigen::Isometry3d& pose : poses.frame_from_world) matrices.append(ToArray(pose));
  for (const auto& c : poses.covariance) {
    py::array_t<double> m({6, 6});
    for (int r = 0; r < 6; ++r) {
      for (int k = 0; k < 6; ++k) m.mutable_at(r, k) = c(r, k);
    }
    covariance.append(m);
  }
  out["images"] = poses.images;
  out["frame_from_world"] = matrices;
  out["covariance"] = covariance;
  out["predicted_tre_mm"] = poses.predicted_tre_mm;
  out["gain"] = poses.gain;
  out["offset"] = poses.offset;
  return out;
}

PosesFile PosesFromDict(const py::dict& d) {
  PosesFile poses;
  poses.images = d["images"].cast<std::vector<std::string>>();
  for (const py::handle& m : d["frame_from_world"]) {
    const std::string where = "pose " + std::to_string(poses.frame_from_world.size()) + ": ";
    poses.frame_from_world.push_back(ToPose(py::reinterpret_borrow<py::object>(m), where));
  }
  if (d.contains("covariance")) {
    for (const py::handle& m : d["covariance"]) {
      const auto a = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(m);
      if (!a || a.ndim() != 2 || a.shape(0) != 6 || a.shape(1) != 6) {
        BadInput("a covariance must be a 6x6 matrix");
      }
      Eigen::Matrix<double, 6, 6> c;
      for (int r = 0; r < 6; ++r) {
        for (int k = 0; k < 6; ++k) c(r, k) = a.at(r, k);
      }
      poses.covariance.push_back(c);
    }
  }
  if (d.contains("predicted_tre_mm")) {
    poses.predicted_tre_mm = d["predicted_tre_mm"].cast<std::vector<double>>();
  }
  if (d.contains("gain")) poses.gain = d["gain"].cast<std::vector<double>>();
  if (d.contains("offset")) poses.offset = d["offset"].cast<std::vector<double>>();
  for (double g : poses.gain) {
    if (!(g > 0.0 && std::isfinite(g))) BadInput("gain: every gain must be finite and > 0");
  }
  // One entry per pose in every list given (WritePoses's contract).
  const size_t m = poses.frame_from_world.size();
  for (const auto& [what, count] : {std::pair<const char*, size_t>{"images", poses.images.size()},
                                    {"covariance", poses.covariance.size()},
                                    {"predicted_tre_mm", poses.predicted_tre_mm.size()},
                                    {"gain", poses.gain.size()},
                                    {"offset", poses.offset.size()}}) {
    if (count != 0 && count != m) {
      BadInput(std::string(what) + ": " + std::to_string(count) + " entries for " +
               std::to_string(m) + " poses");
    }
  }
  return poses;
}

py::tuple PhasesToArray(std::vector<Image> phases) {
  if (phases.size() == 1) {
    return py::make_tuple(ToArray(phases[0]), FromGeometry(phases[0].geometry));
  }
  const Eigen::Vector3i& n = phases[0].geometry.size;
  py::array_t<float> out({static_cast<ssize_t>(phases.size()), static_cast<ssize_t>(n[2]),
                          static_cast<ssize_t>(n[1]), static_cast<ssize_t>(n[0])});
  float* data = out.mutable_data();
  for (Image& phase : phases) {
    data = std::copy(phase.voxels.begin(), phase.voxels.end(), data);
    std::vector<float>().swap(phase.voxels);
  }
  return py::make_tuple(out, FromGeometry(phases[0].geometry));
}

// The types the other files convert (Image, Mask and the masks' values).
template Volume<float> ToVolume<float>(const py::array&, const Geometry&, const std::string&, bool);
template Volume<double> ToVolume<double>(const py::array&,
                                         const Geometry&,
                                         const std::string&,
                                         bool);
template py::array_t<float> ToArray<float>(const Volume<float>&);
template py::array_t<uint8_t> ToArray<uint8_t>(const Volume<uint8_t>&);

}  // namespace python_internal
}  // namespace dsr
