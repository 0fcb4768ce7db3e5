// Candidate observations and overlap connectivity (docs/design.md section 2).
#include "dsr/model/observation.h"

#include "dsr/util/parallel.h"

#include <algorithm>
#include <cmath>
#include <queue>
#include <sstream>

#include <glog/logging.h>

namespace dsr {

int64_t CandidateSet::NumObservations() const {
  int64_t total = 0;
  for (uint32_t o : observers) total += __builtin_popcount(o);
  return total;
}

Eigen::Vector3d CandidateSet::VoxelCenter(int64_t v) const {
  const int64_t l = voxel[v];
  const int64_t nx = grid.size[0], nxy = nx * grid.size[1];
  const Eigen::Vector3d ijk(static_cast<double>(l % nx), static_cast<double>((l % nxy) / nx),
                            static_cast<double>(l / nxy));
  return grid.IndexToPhysical(ijk);
}

CandidateSet BuildCandidates(const std::vector<Frame>& frames,
                             const std::vector<Eigen::Isometry3d>& frame_from_world,
                             const ImageGeometry& grid,
                             int margin_cells,
                             int keep_one_row_in) {
  const int m = static_cast<int>(frames.size());
  CHECK_LE(m, kMaxFrames);
  CHECK_EQ(frame_from_world.size(), frames.size());
  CandidateSet out;
  out.grid = grid;
  out.num_frames = m;
  // Cells within the margin of each frame's valid region: the valid-cell bits themselves
  // (margin 0), else a dilated byte map.
  std::vector<std::vector<uint8_t>> dilated(m);
  std::vector<Eigen::Matrix3d> a(m);  // index_i = a p_j + b
  std::vector<Eigen::Vector3d> b(m);
  for (int i = 0; i < m; ++i) {
    if (margin_cells > 0) dilated[i] = frames[i].DilatedValidCells(margin_cells);
    const Eigen::Matrix3d index_from_physical = frames[i].index_from_physical();
    a[i] = index_from_physical * frame_from_world[i].linear();
    b[i] = index_from_physical *
           (frame_from_world[i].translation() - frames[i].geometry().origin_mm);
  }
  const Eigen::Vector3i n = grid.size;
  const Eigen::Matrix3d to_world = grid.IndexToPhysicalMatrix();
  // Slices in parallel, each into its own lists, concatenated in slice order (the result
  // does not depend on the thread count). Along a panorama row the continuous index in
  // frame f is u(i) = u(0) + i * step_f; each frame only visits the i whose cell can lie
  // within the margin of its grid (a conservative clip of that line), then tests its map.
  std::vector<std::vector<int64_t>> slice_voxels(n[2]);
  std::vector<std::vector<uint32_t>> slice_observers(n[2]);
  ParallelFor(0, n[2], 0, [&](int64_t k) {
    std::vector<uint32_t> row(n[0]);
    for (int j = 0; j < n[1]; ++j) {
      if (keep_one_row_in > 1 && (j + 7 * k) % keep_one_row_in != 0) continue;
      std::fill(row.begin(), row.end(), 0u);
      const Eigen::Vector3d p0 = grid.origin_mm + to_world * Eigen::Vector3d(0, j, k);
      for (int f = 0; f < m; ++f) {
        const Eigen::Vector3i& fs = frames[f].geometry().size;
        const Eigen::Vector3d u0 = a[f] * p0 + b[f];
        const Eigen::Vector3d step = a[f] * to_world.col(0);
        // i range where every axis stays within [-margin - 1, n - 1 + margin] (one cell
        // of slack on each side; the exact test follows).
        double lo = 0.0, hi = n[0] - 1.0;
        for (int ax = 0; ax < 3 && lo <= hi; ++ax) {
          const double low = -margin_cells - 1.0, high = fs[ax] - 1.0 + margin_cells;
          if (step[ax] == 0.0) {
            if (!(u0[ax] >= low && u0[ax] <= high)) lo = hi + 1.0;
            continue;
          }
          double t0 = (low - u0[ax]) / step[ax], t1 = (high - u0[ax]) / step[ax];
          if (t0 > t1) std::swap(t0, t1);
          lo = std::max(lo, std::floor(t0));
          hi = std::min(hi, std::ceil(t1));
        }
        if (!(lo <= hi)) continue;  // also false for NaN
        const uint32_t bit = 1u << f;
        const Frame& frame = frames[f];
        const uint8_t* near = margin_cells > 0 ? dilated[f].data() : nullptr;
        const int64_t sy = fs[0], sz = int64_t{fs[0]} * fs[1];
        if (near == nullptr) {  // margin 0: the cell itself must be a valid one
          // floor(u) lies in [0, n - 2] exactly when 0 <= u < n - 1 (n - 1 is an integer a
          // double holds exactly), and there floor is truncation: the cells std::floor
          // would give, without its call per axis and voxel.
          const double end_cell[3] = {fs[0] - 1.0, fs[1] - 1.0, fs[2] - 1.0};
          const uint8_t* bits = frame.valid_bits();
          for (int i = static_cast<int>(lo); i <= static_cast<int>(hi); ++i) {
            const double ux = u0[0] + i * step[0];
            const double uy = u0[1] + i * step[1];
            const double uz = u0[2] + i * step[2];
            if (!(ux >= 0.0 && uy >= 0.0 && uz >= 0.0 && ux < end_cell[0] && uy < end_cell[1] &&
                  uz < end_cell[2])) {
              continue;
            }
            const int64_t cell = static_cast<int64_t>(ux) + sy * static_cast<int64_t>(uy) +
                                 sz * static_cast<int64_t>(uz);
            if ((bits[cell >> 3] >> (cell & 7)) & 1) row[i] |= bit;
          }
          continue;
        }
        for (int i = static_cast<int>(lo); i <= static_cast<int>(hi); ++i) {
          // Cell containing u, clamped into the grid when within the margin outside it.
          int64_t cell = 0;
          bool inside = true;
          for (int ax = 0; ax < 3; ++ax) {
            const double fl = std::floor(u0[ax] + i * step[ax]);
            if (!(fl >= -margin_cells && fl <= fs[ax] - 2 + margin_cells)) {
              inside = false;
              break;
            }
            const int64_t c =
                static_cast<int64_t>(std::clamp(fl, 0.0, std::max(0.0, fs[ax] - 2.0)));
            cell += c * (ax == 0 ? 1 : (ax == 1 ? sy : sz));
          }
          if (inside && near[cell] != 0) row[i] |= bit;
        }
      }
      for (int i = 0; i < n[0]; ++i) {
        if ((row[i] & (row[i] - 1)) != 0) {  // at least two candidate observers
          slice_voxels[k].push_back(grid.LinearIndex(i, j, static_cast<int>(k)));
          slice_observers[k].push_back(row[i]);
        }
      }
    }
  });
  size_t total = 0;
  for (const auto& v : slice_voxels) total += v.size();
  out.voxel.reserve(total);
  out.observers.reserve(total);
  for (int k = 0; k < n[2]; ++k) {
    out.voxel.insert(out.voxel.end(), slice_voxels[k].begin(), slice_voxels[k].end());
    out.observers.insert(out.observers.end(), slice_observers[k].begin(), slice_observers[k].end());
  }
  return out;
}

CandidateSet CandidatesInCubes(const CandidateSet& candidates, int cube, int keep_one_in) {
  CHECK_GE(cube, 1);
  CHECK_GE(keep_one_in, 1);
  CandidateSet out;
  out.grid = candidates.grid;
  out.num_frames = candidates.num_frames;
  const int64_t nx = candidates.grid.size[0], ny = candidates.grid.size[1];
  for (int64_t v = 0; v < candidates.num_voxels(); ++v) {
    const int64_t l = candidates.voxel[v];
    const int64_t cube_sum = (l % nx) / cube + (l / nx) % ny / cube + l / (nx * ny) / cube;
    if (cube_sum % keep_one_in == 0) {
      out.voxel.push_back(l);
      out.observers.push_back(candidates.observers[v]);
    }
  }
  return out;
}

CandidateSet CandidatesInRows(const CandidateSet& candidates, int keep_one_row_in) {
  CHECK_GE(keep_one_row_in, 1);
  CandidateSet out;
  out.grid = candidates.grid;
  out.num_frames = candidates.num_frames;
  const int64_t nx = candidates.grid.size[0], ny = candidates.grid.size[1];
  int64_t row_end = -1;  // the end of the current row's linear indices
  bool kept = false;
  for (int64_t v = 0; v < candidates.num_voxels(); ++v) {
    const int64_t l = candidates.voxel[v];
    if (l >= row_end) {  // a new row: one division per row, not per voxel
      const int64_t row = l / nx;
      row_end = (row + 1) * nx;
      kept = (row % ny + 7 * (row / ny)) % keep_one_row_in == 0;
    }
    if (kept) {
      out.voxel.push_back(l);
      out.observers.push_back(candidates.observers[v]);
    }
  }
  return out;
}

Eigen::MatrixXi CandidateOverlap(const CandidateSet& candidates) {
  const int m = candidates.num_frames;
  Eigen::MatrixXi overlap = Eigen::MatrixXi::Zero(m, m);
  // Neighbouring voxels mostly have the same observers: each run of equal sets adds its
  // length to every pair of the set once.
  const std::vector<uint32_t>& observers = candidates.observers;
  for (size_t v = 0; v < observers.size();) {
    const uint32_t bits = observers[v];
    size_t end = v + 1;
    while (end < observers.size() && observers[end] == bits) ++end;
    const int run = static_cast<int>(end - v);
    for (uint32_t as = bits; as != 0; as &= as - 1) {  // set bits only
      const int a = __builtin_ctz(as);
      for (uint32_t bs = as; bs != 0; bs &= bs - 1) overlap(a, __builtin_ctz(bs)) += run;
    }
    v = end;
  }
  overlap.triangularView<Eigen::StrictlyLower>() = overlap.transpose();
  return overlap;
}

bool CheckConnected(const CandidateSet& candidates,
                    int64_t min_shared_voxels,
                    std::string* error) {
  return CheckConnected(CandidateOverlap(candidates), min_shared_voxels, error);
}

std::vector<int> FramesNotConnected(const Eigen::MatrixXi& overlap, int64_t min_shared_voxels) {
  const int m = static_cast<int>(overlap.rows());
  std::vector<bool> reached(m, false);
  std::queue<int> todo;
  reached[0] = true;
  todo.push(0);
  while (!todo.empty()) {
    const int a = todo.front();
    todo.pop();
    for (int b = 0; b < m; ++b) {
      if (!reached[b] && b != a && overlap(a, b) >= min_shared_voxels) {
        reached[b] = true;
        todo.push(b);
      }
    }
  }
  std::vector<int> missing;
  for (int i = 0; i < m; ++i) {
    if (!reached[i]) missing.push_back(i);
  }
  return missing;
}

std::string FramesPhrase(const std::vector<int>& frames) {
  std::ostringstream s;
  s << (frames.size() == 1 ? "frame " : "frames ");
  for (size_t k = 0; k < frames.size(); ++k) s << (k ? "," : "") << frames[k];
  return s.str();
}

bool CheckConnected(const Eigen::MatrixXi& overlap,
                    int64_t min_shared_voxels,
                    std::string* error) {
  const std::vector<int> missing = FramesNotConnected(overlap, min_shared_voxels);
  if (missing.empty()) return true;
  if (error) {
    *error = FramesPhrase(missing) + (missing.size() == 1 ? " does not" : " do not") +
             std::string(" overlap frame 0 or the frames connected to it at the initial poses "
                         "(fewer than ") +
             std::to_string(min_shared_voxels) +
             " shared panorama voxels); give better initial poses with --init";
  }
  return false;
}

std::vector<Eigen::Isometry3d> RelativeToFrame0(
    const std::vector<Eigen::Isometry3d>& frame_from_world) {
  std::vector<Eigen::Isometry3d> out;
  if (frame_from_world.empty()) return out;
  const Eigen::Isometry3d world_from_frame0 = frame_from_world[0].inverse();
  for (const auto& t : frame_from_world) out.push_back(t * world_from_frame0);
  out[0] = Eigen::Isometry3d::Identity();
  return out;
}

}  // namespace dsr
