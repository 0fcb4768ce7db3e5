// Poses JSON (DESIGN.md section 1) with nlohmann::json.
#include "core/io_poses.h"

#include <cmath>
#include <fstream>
#include <limits>
#include <sstream>

#include <nlohmann/json.hpp>

#include "core/atomic_file.h"
#include "core/se3.h"

namespace dsr {

bool ReadPoses(const std::string& path,
               int expected_frames,
               PosesFile* poses,
               std::string* error) {
  std::ifstream in(path);
  if (!in) {
    *error = path + ": cannot open the poses file";
    return false;
  }
  nlohmann::json doc;
  try {
    doc = nlohmann::json::parse(in);
  } catch (const nlohmann::json::exception& e) {
    std::string what = e.what();
    for (char& c : what) if (c == '\n') c = ' ';
    *error = path + ": not valid JSON (" + what + ")";
    return false;
  }
  if (!doc.is_object() || !doc.contains("frames") || !doc["frames"].is_array()) {
    *error = path + ": expected an object with a \"frames\" array";
    return false;
  }
  const auto& frames = doc["frames"];
  if (frames.empty()) {
    *error = path + ": \"frames\" is empty";
    return false;
  }
  if (expected_frames >= 0 && static_cast<int>(frames.size()) != expected_frames) {
    *error = path + ": has " + std::to_string(frames.size()) + " frames, expected " +
             std::to_string(expected_frames) + " (one per image)";
    return false;
  }
  PosesFile out;
  for (size_t f = 0; f < frames.size(); ++f) {
    const std::string where = path + ": frame " + std::to_string(f) + ": ";
    const auto& frame = frames[f];
    if (!frame.is_object() || !frame.contains("T")) {
      *error = where + "expected an object with \"T\"";
      return false;
    }
    out.images.push_back(frame.contains("image") && frame["image"].is_string()
                             ? frame["image"].get<std::string>()
                             : std::string());
    const auto& t = frame["T"];
    Eigen::Matrix4d m;
    if (!t.is_array() || t.size() != 4) {
      *error = where + "T must be a 4x4 array of numbers";
      return false;
    }
    for (int r = 0; r < 4; ++r) {
      if (!t[r].is_array() || t[r].size() != 4) {
        *error = where + "T must be a 4x4 array of numbers";
        return false;
      }
      for (int c = 0; c < 4; ++c) {
        if (!t[r][c].is_number()) {
          *error = where + "T must be a 4x4 array of numbers";
          return false;
        }
        m(r, c) = t[r][c].get<double>();
        if (!std::isfinite(m(r, c))) {
          *error = where + "T has a non-finite entry";
          return false;
        }
      }
    }
    const Eigen::Matrix3d rot = m.topLeftCorner<3, 3>();
    const double orthogonality = (rot.transpose() * rot - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff();
    const double det = rot.determinant();
    const double last_row = (m.row(3) - Eigen::RowVector4d(0, 0, 0, 1)).cwiseAbs().maxCoeff();
    if (orthogonality > kRigidTolerance || std::abs(det - 1.0) > kRigidTolerance ||
        last_row > kRigidTolerance) {
      std::ostringstream s;
      s << where << "T is not rigid (|R^T R - I| = " << orthogonality << ", det R = " << det
        << ", last row off by " << last_row << "; tolerance " << kRigidTolerance << ")";
      *error = s.str();
      return false;
    }
    Eigen::Isometry3d iso = Eigen::Isometry3d::Identity();
    iso.linear() = rot;
    iso.translation() = m.topRightCorner<3, 1>();
    out.frame_from_world.push_back(Orthonormalized(iso));
  }
  *poses = std::move(out);
  return true;
}

std::string PosesToJson(const PosesFile& poses) {
  nlohmann::json frames = nlohmann::json::array();
  for (size_t f = 0; f < poses.frame_from_world.size(); ++f) {
    const Eigen::Matrix4d m = poses.frame_from_world[f].matrix();
    nlohmann::json t = nlohmann::json::array();
    for (int r = 0; r < 4; ++r) {
      t.push_back({m(r, 0), m(r, 1), m(r, 2), m(r, 3)});
    }
    frames.push_back({{"image", f < poses.images.size() ? poses.images[f] : std::string()},
                      {"T", t}});
  }
  nlohmann::json doc = {{"convention", "T maps world points to frame physical points (LPS, mm)"},
                        {"frames", frames}};
  return doc.dump(2) + "\n";  // nlohmann prints doubles with 17 significant digits
}

bool WritePoses(const PosesFile& poses, const std::string& path, std::string* error) {
  return WriteFileAtomically(path, PosesToJson(poses), error);
}

}  // namespace dsr
