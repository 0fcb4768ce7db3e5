// Poses JSON (docs/design.md section 1, format in io_poses.h) with nlohmann::json: strict
// validation on read (shape, finiteness, rigidity, count) with one-line errors naming the
// file, the frame and the rule; shortest round-trip number printing on write, so a
// write/read cycle returns the same doubles bit for bit.
#include "dsr/io/io_poses.h"

#include <cerrno>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>

#include <glog/logging.h>
#include <nlohmann/json.hpp>

#include "dsr/geometry/se3.h"
#include "dsr/util/atomic_file.h"

namespace dsr {
namespace {

using Json = nlohmann::json;

// Rotations closer than this to orthonormal (max |R^T R - I|) are already orthonormal to
// double precision: they are kept bit for bit, so a write/read round trip is exact.
// Others (within kRigidTolerance) are projected to the nearest rotation.
constexpr double kOrthonormalAsIs = 1e-14;

// nlohmann's what() is "[json.exception.parse_error.101] parse error at line 1, ...":
// drop the bracketed id and keep the rest on one line.
std::string JsonMessage(const Json::exception& e) {
  std::string text = e.what();
  const size_t close = text.find("] ");
  if (!text.empty() && text.front() == '[' && close != std::string::npos) {
    text = text.substr(close + 2);
  }
  for (char& c : text) {
    if (c == '\n' || c == '\r') c = ' ';
  }
  return text;
}

bool ReadText(const std::string& path, std::string* text, std::string* error) {
  namespace fs = std::filesystem;
  std::error_code ec;
  if (!fs::exists(path, ec)) {
    *error = path + ": no such file";
    return false;
  }
  if (fs::is_directory(path, ec)) {
    *error = path + ": is a folder, expected a poses file";
    return false;
  }
  // A FIFO or a device would block or never end: a poses file is a regular file.
  if (!fs::is_regular_file(path, ec)) {
    *error = path + ": not a regular file (a poses file is a JSON file)";
    return false;
  }
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    *error = path + ": cannot open (" + std::strerror(errno) + ")";
    return false;
  }
  std::ostringstream contents;
  contents << in.rdbuf();
  if (in.bad()) {
    *error = path + ": cannot read (" + std::strerror(errno) + ")";
    return false;
  }
  *text = contents.str();
  return true;
}

// "a string", "an array", "an object", ... for error messages.
std::string WithArticle(const Json& value) {
  const std::string name = value.type_name();
  return (name[0] == 'a' || name[0] == 'o' ? "an " : "a ") + name;
}

std::string Number(double value) {
  std::ostringstream s;
  s << value;
  return s.str();
}

// Parses "T" of one frame into `m`; `where` is "<path>: frame <f>: ".
bool ParseMatrix(const Json& t, const std::string& where, Eigen::Matrix4d* m, std::string* error) {
  const std::string shape = where + "T must be a 4x4 array of numbers";
  if (!t.is_array()) {
    *error = shape + " (got " + t.type_name() + ")";
    return false;
  }
  if (t.size() != 4) {
    *error = shape + " (got " + std::to_string(t.size()) + " rows)";
    return false;
  }
  for (int r = 0; r < 4; ++r) {
    const Json& row = t[r];
    if (!row.is_array() || row.size() != 4) {
      *error = shape + " (row " + std::to_string(r) + " is " +
               (row.is_array() ? "an array of " + std::to_string(row.size()) : WithArticle(row)) +
               ")";
      return false;
    }
    for (int c = 0; c < 4; ++c) {
      const std::string entry = "T[" + std::to_string(r) + "][" + std::to_string(c) + "]";
      if (!row[c].is_number()) {
        *error = shape + " (" + entry + " is " + WithArticle(row[c]) + ")";
        return false;
      }
      (*m)(r, c) = row[c].get<double>();  // finite and rigid: PoseFromMatrix
    }
  }
  return true;
}

// Checks that `m` is a rigid transform within kRigidTolerance.
bool CheckRigid(const Eigen::Matrix4d& m, const std::string& where, std::string* error) {
  const Eigen::Matrix3d rotation = m.topLeftCorner<3, 3>();
  const double orthonormality =
      (rotation.transpose() * rotation - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff();
  if (orthonormality > kRigidTolerance) {
    *error = where + "T is not rigid (|R^T R - I| = " + Number(orthonormality) + " > " +
             Number(kRigidTolerance) + ")";
    return false;
  }
  const double det = rotation.determinant();
  if (std::abs(det - 1.0) > kRigidTolerance) {
    *error = where + "T is not rigid (det R = " + Number(det) + ", a reflection; expected 1)";
    return false;
  }
  const Eigen::RowVector4d last = m.row(3);
  if ((last - Eigen::RowVector4d(0, 0, 0, 1)).cwiseAbs().maxCoeff() > kRigidTolerance) {
    *error = where + "T is not rigid (last row [" + Number(last[0]) + "," + Number(last[1]) + "," +
             Number(last[2]) + "," + Number(last[3]) + "], expected [0,0,0,1])";
    return false;
  }
  return true;
}

// Reads the optional number `key` ("gain" or "offset") of frame f into `values`, which
// must end up with one value per frame or none; finite, and > 0 when `positive` (a gain).
// `where` is "<path>: frame <f>: ".
bool ReadOptionalNumber(const Json& frame,
                        const char* key,
                        bool positive,
                        size_t f,
                        const std::string& where,
                        std::vector<double>* values,
                        std::string* error) {
  const auto it = frame.find(key);
  const bool present = it != frame.end();
  const std::string quoted = std::string("\"") + key + "\"";
  if (f > 0 && present != (values->size() == f)) {
    *error = where + (present ? "has " + quoted + " but frame 0 has none"
                              : "missing " + quoted + ", which frame 0 has") +
             " (give it on every frame or on none)";
    return false;
  }
  if (!present) return true;
  if (!it->is_number()) {
    *error = where + quoted + " must be a number, got " + it->type_name();
    return false;
  }
  const double value = it->get<double>();
  if (!std::isfinite(value) || (positive && !(value > 0.0))) {
    *error = where + quoted + " must be " + (positive ? "finite and > 0" : "finite") + " (got " +
             Number(value) + ")";
    return false;
  }
  values->push_back(value);
  return true;
}

}  // namespace

bool PoseFromMatrix(const Eigen::Matrix4d& m, const std::string& where,
                    Eigen::Isometry3d* pose, std::string* error) {
  for (int r = 0; r < 4; ++r) {
    for (int c = 0; c < 4; ++c) {
      if (std::isfinite(m(r, c))) continue;
      *error = where + "T[" + std::to_string(r) + "][" + std::to_string(c) +
               "] is not finite (" + Number(m(r, c)) + ")";
      return false;
    }
  }
  if (!CheckRigid(m, where, error)) return false;
  *pose = Eigen::Isometry3d::Identity();
  pose->linear() = m.topLeftCorner<3, 3>();
  pose->translation() = m.topRightCorner<3, 1>();
  const Eigen::Matrix3d& r = pose->linear();
  if ((r.transpose() * r - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff() >
      kOrthonormalAsIs) {
    *pose = Orthonormalized(*pose);
  }
  return true;
}

bool ReadPoses(const std::string& path, int expected_frames, PosesFile* poses, std::string* error) {
  std::string text;
  if (!ReadText(path, &text, error)) return false;
  Json doc;
  try {
    doc = Json::parse(text);
  } catch (const Json::exception& e) {
    *error = path + ": not valid JSON (" + JsonMessage(e) + ")";
    return false;
  }
  if (!doc.is_object()) {
    *error = path + ": expected a JSON object with a \"frames\" array, got " + doc.type_name();
    return false;
  }
  const auto frames_it = doc.find("frames");
  if (frames_it == doc.end() || !frames_it->is_array()) {
    *error = path + ": expected a \"frames\" array" +
             (frames_it == doc.end() ? std::string(" (key missing)")
                                     : " (got " + std::string(frames_it->type_name()) + ")");
    return false;
  }
  const Json& frames = *frames_it;
  if (frames.empty()) {
    *error = path + ": \"frames\" is empty";
    return false;
  }
  if (expected_frames >= 0 && static_cast<int64_t>(frames.size()) != expected_frames) {
    *error = path + ": has " + std::to_string(frames.size()) + " frames, expected " +
             std::to_string(expected_frames) + " (one per image)";
    return false;
  }
  PosesFile out;
  for (size_t f = 0; f < frames.size(); ++f) {
    const std::string where = path + ": frame " + std::to_string(f) + ": ";
    const Json& frame = frames[f];
    if (!frame.is_object()) {
      *error = where + "expected an object with \"T\", got " + frame.type_name();
      return false;
    }
    std::string image;
    const auto image_it = frame.find("image");
    if (image_it != frame.end()) {
      if (!image_it->is_string()) {
        *error = where + "\"image\" must be a string, got " + image_it->type_name();
        return false;
      }
      image = image_it->get<std::string>();
    }
    const auto t_it = frame.find("T");
    if (t_it == frame.end()) {
      *error = where + "missing \"T\" (a 4x4 array of numbers)";
      return false;
    }
    Eigen::Matrix4d m;
    Eigen::Isometry3d frame_from_world;
    if (!ParseMatrix(*t_it, where, &m, error) ||
        !PoseFromMatrix(m, where, &frame_from_world, error)) {
      return false;
    }
    if (!ReadOptionalNumber(frame, "gain", /*positive=*/true, f, where, &out.gain, error) ||
        !ReadOptionalNumber(frame, "offset", /*positive=*/false, f, where, &out.offset, error)) {
      return false;
    }
    out.images.push_back(image);
    out.frame_from_world.push_back(frame_from_world);
  }
  *poses = std::move(out);
  return true;
}

std::string PosesToJson(const PosesFile& poses) {
  CHECK(poses.images.empty() || poses.images.size() == poses.frame_from_world.size())
      << "PosesFile has " << poses.images.size() << " image names for "
      << poses.frame_from_world.size() << " poses";
  const size_t m = poses.frame_from_world.size();
  CHECK(poses.covariance.empty() || poses.covariance.size() == m);
  CHECK(poses.predicted_tre_mm.empty() || poses.predicted_tre_mm.size() == m);
  CHECK(poses.gain.empty() || poses.gain.size() == m);
  CHECK(poses.offset.empty() || poses.offset.size() == m);
  Json frames = Json::array();
  for (size_t f = 0; f < m; ++f) {
    const Eigen::Matrix4d t_matrix = poses.frame_from_world[f].matrix();
    Json t = Json::array();
    for (int r = 0; r < 4; ++r) {
      t.push_back({t_matrix(r, 0), t_matrix(r, 1), t_matrix(r, 2), t_matrix(r, 3)});
    }
    Json frame = Json::object();
    frame["image"] = poses.images.empty() ? std::string() : poses.images[f];
    frame["T"] = std::move(t);
    if (!poses.covariance.empty()) {
      Json c = Json::array();
      for (int r = 0; r < 6; ++r) {
        Json row = Json::array();
        for (int k = 0; k < 6; ++k) row.push_back(poses.covariance[f](r, k));
        c.push_back(std::move(row));
      }
      frame["covariance"] = std::move(c);
    }
    if (!poses.predicted_tre_mm.empty()) frame["predicted_tre_mm"] = poses.predicted_tre_mm[f];
    if (!poses.gain.empty()) frame["gain"] = poses.gain[f];
    if (!poses.offset.empty()) frame["offset"] = poses.offset[f];
    frames.push_back(std::move(frame));
  }
  Json doc = Json::object();
  doc["convention"] = "T maps world points to frame physical points (frame_from_world, LPS, mm)";
  doc["frames"] = std::move(frames);
  // nlohmann prints each double with the fewest digits that parse back to the same value
  // (at most max_digits10 = 17), so the round trip is exact.
  return doc.dump(2) + "\n";
}

bool WritePoses(const PosesFile& poses, const std::string& path, std::string* error) {
  const size_t m = poses.frame_from_world.size();
  CHECK(poses.covariance.empty() || poses.covariance.size() == m);
  CHECK(poses.predicted_tre_mm.empty() || poses.predicted_tre_mm.size() == m);
  CHECK(poses.gain.empty() || poses.gain.size() == m);
  CHECK(poses.offset.empty() || poses.offset.size() == m);
  for (size_t f = 0; f < poses.frame_from_world.size(); ++f) {
    const std::string where = path + ": frame " + std::to_string(f) + ": ";
    if (!poses.frame_from_world[f].matrix().allFinite()) {
      *error = where + "T has a non-finite entry; not written";
      return false;
    }
    if ((!poses.covariance.empty() && !poses.covariance[f].allFinite()) ||
        (!poses.predicted_tre_mm.empty() && !std::isfinite(poses.predicted_tre_mm[f]))) {
      *error = where + "the covariance or predicted_tre_mm has a non-finite entry; not written";
      return false;
    }
    if ((!poses.gain.empty() && !(std::isfinite(poses.gain[f]) && poses.gain[f] > 0.0)) ||
        (!poses.offset.empty() && !std::isfinite(poses.offset[f]))) {
      *error = where + "the gain is not finite and > 0 or the offset is not finite; not written";
      return false;
    }
  }
  return WriteFileAtomically(path, PosesToJson(poses), error);
}

}  // namespace dsr
