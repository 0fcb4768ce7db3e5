#include "dsr/pipeline/report.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <sstream>

#include <glog/logging.h>

#include "dsr/io/io_picture.h"
#include "dsr/io/io_poses.h"
#include "dsr/io/io_transform.h"
#include "dsr/pipeline/uncertainty.h"
#include "dsr/util/atomic_file.h"

namespace dsr {
namespace {

const Rgb kPalette[] = {{230, 25, 75},  {60, 180, 75},  {255, 225, 25}, {0, 130, 200},
                        {245, 130, 48}, {145, 30, 180}, {70, 240, 240}, {240, 50, 230},
                        {210, 245, 60}, {250, 190, 212}, {0, 128, 128}};
const Rgb kWhite = {255, 255, 255};

Rgb PaletteColor(int i) { return kPalette[i % (sizeof(kPalette) / sizeof(kPalette[0]))]; }

// Intensity window over the values > 0 (seen voxels): 1st and 99th percentiles.
std::pair<float, float> Window(const std::vector<float>& values) {
  std::vector<float> seen;
  for (float v : values) {
    if (v > 0.0f) seen.push_back(v);
  }
  if (seen.empty()) return {0.0f, 1.0f};
  const size_t lo = seen.size() / 100, hi = seen.size() - 1 - seen.size() / 100;
  std::nth_element(seen.begin(), seen.begin() + lo, seen.end());
  const float a = seen[lo];
  std::nth_element(seen.begin(), seen.begin() + hi, seen.end());
  const float b = seen[hi];
  return {a, b > a ? b : a + 1.0f};
}

uint8_t Grey(double v, std::pair<float, float> w) {
  return static_cast<uint8_t>(std::clamp(255.0 * (v - w.first) / (w.second - w.first), 0.0, 255.0));
}

// One panorama slice: axis `normal` fixed at index `at`; the picture's x runs along the
// first remaining axis and y along the second, each voxel `scale` pixels wide.
struct SliceAxes {
  int normal, u, v;
};

Picture RenderSlice(const Image& panorama,
                    const std::vector<Frame>& frames,
                    const std::vector<Eigen::Isometry3d>& poses,
                    const std::vector<int>& outlined,
                    SliceAxes axes,
                    int scale,
                    std::pair<float, float> window) {
  const ImageGeometry& g = panorama.geometry;
  const int nu = g.size[axes.u], nv = g.size[axes.v];
  const int at = g.size[axes.normal] / 2;
  Picture pic(nu * scale, nv * scale);
  auto voxel = [&](int iu, int iv) {
    Eigen::Vector3i ijk;
    ijk[axes.normal] = at;
    ijk[axes.u] = iu;
    ijk[axes.v] = iv;
    return ijk;
  };
  for (int iv = 0; iv < nv; ++iv) {
    for (int iu = 0; iu < nu; ++iu) {
      const Eigen::Vector3i ijk = voxel(iu, iv);
      const uint8_t grey = Grey(panorama.at(ijk[0], ijk[1], ijk[2]), window);
      for (int dy = 0; dy < scale; ++dy)
        for (int dx = 0; dx < scale; ++dx)
          pic.Set(iu * scale + dx, iv * scale + dy, {grey, grey, grey});
    }
  }
  for (int f : outlined) {
    // Which slice voxels frame f observes; its outline = observed with an unobserved
    // 4-neighbour (or on the slice border).
    std::vector<uint8_t> seen(size_t(nu) * nv, 0);
    for (int iv = 0; iv < nv; ++iv) {
      for (int iu = 0; iu < nu; ++iu) {
        const Eigen::Vector3i ijk = voxel(iu, iv);
        double value;
        seen[size_t(iv) * nu + iu] =
            frames[f].Sample(poses[f] * g.IndexToPhysical(ijk.cast<double>()), &value, nullptr);
      }
    }
    auto is_seen = [&](int iu, int iv) {
      return iu >= 0 && iv >= 0 && iu < nu && iv < nv && seen[size_t(iv) * nu + iu];
    };
    for (int iv = 0; iv < nv; ++iv) {
      for (int iu = 0; iu < nu; ++iu) {
        if (!is_seen(iu, iv)) continue;
        if (is_seen(iu - 1, iv) && is_seen(iu + 1, iv) && is_seen(iu, iv - 1) &&
            is_seen(iu, iv + 1)) {
          continue;
        }
        for (int dy = 0; dy < scale; ++dy)
          for (int dx = 0; dx < scale; ++dx)
            pic.Set(iu * scale + dx, iv * scale + dy, PaletteColor(f));
      }
    }
  }
  return pic;
}

// Samples frame f on the axial slice `k` of `grid` under `pose`: value (corrected by
// `correction`) and validity.
void SampleSlice(const Frame& frame,
                 const Eigen::Isometry3d& pose,
                 const ImageGeometry& grid,
                 int k,
                 const Photometric& correction,
                 std::vector<float>* value,
                 std::vector<uint8_t>* seen) {
  const int nx = grid.size[0], ny = grid.size[1];
  value->assign(size_t(nx) * ny, 0.0f);
  seen->assign(size_t(nx) * ny, 0);
  for (int j = 0; j < ny; ++j) {
    for (int i = 0; i < nx; ++i) {
      double v;
      if (frame.Sample(pose * grid.IndexToPhysical(Eigen::Vector3d(i, j, k)), &v, nullptr)) {
        (*value)[size_t(j) * nx + i] = static_cast<float>(correction.Correct(v));
        (*seen)[size_t(j) * nx + i] = 1;
      }
    }
  }
}

}  // namespace

Picture RenderPanoramaSlices(const Image& panorama,
                             const std::vector<Frame>& frames,
                             const std::vector<Eigen::Isometry3d>& frame_from_world,
                             const std::vector<int>& outlined) {
  const ImageGeometry& g = panorama.geometry;
  const int largest = std::max({g.size[0], g.size[1], g.size[2]});
  const int scale = std::max(1, 320 / std::max(1, largest));
  const auto window = Window(panorama.voxels);
  const SliceAxes views[3] = {{2, 0, 1}, {1, 0, 2}, {0, 1, 2}};
  const char* names[3] = {"axial (z)", "coronal (y)", "sagittal (x)"};
  std::vector<Picture> slices;
  int width = 0, height = 0;
  for (const SliceAxes& a : views) {
    slices.push_back(RenderSlice(panorama, frames, frame_from_world, outlined, a, scale, window));
    width += slices.back().width + 10;
    height = std::max(height, slices.back().height);
  }
  const int legend = 22 + 16 * static_cast<int>((outlined.size() + 5) / 6);
  Picture out(width + 10, height + 30 + legend, {20, 20, 20});
  int x = 10;
  for (int s = 0; s < 3; ++s) {
    out.Paste(slices[s], x, 25);
    DrawText(names[s], x, 18, 0.45, kWhite, &out);
    x += slices[s].width + 10;
  }
  for (size_t n = 0; n < outlined.size(); ++n) {
    const int lx = 10 + static_cast<int>(n % 6) * 90,
              ly = height + 45 + static_cast<int>(n / 6) * 16;
    DrawText("frame " + std::to_string(outlined[n]), lx, ly, 0.45, PaletteColor(outlined[n]), &out);
  }
  return out;
}

Picture RenderPairComparison(const std::vector<Frame>& frames,
                             int a,
                             int b,
                             const std::vector<Eigen::Isometry3d>& before,
                             const std::vector<Eigen::Isometry3d>& after,
                             const ImageGeometry& grid,
                             const std::vector<Photometric>& photometric) {
  CHECK(photometric.empty() || photometric.size() == frames.size());
  const Photometric none;
  const Photometric& ca = photometric.empty() ? none : photometric[a];
  const Photometric& cb = photometric.empty() ? none : photometric[b];
  const int nx = grid.size[0], ny = grid.size[1];
  // The axial slice with the most voxels both frames observe after registration.
  int best_k = grid.size[2] / 2;
  int64_t best = -1;
  std::vector<float> va, vb;
  std::vector<uint8_t> sa, sb;
  for (int k = 0; k < grid.size[2]; k += std::max(1, grid.size[2] / 24)) {
    SampleSlice(frames[a], after[a], grid, k, ca, &va, &sa);
    SampleSlice(frames[b], after[b], grid, k, cb, &vb, &sb);
    int64_t both = 0;
    for (size_t l = 0; l < sa.size(); ++l) both += sa[l] && sb[l];
    if (both > best) {
      best = both;
      best_k = k;
    }
  }
  const int scale = std::max(1, 280 / std::max(nx, ny));
  std::vector<float> all;
  for (const auto* poses : {&before, &after}) {
    for (int f : {a, b}) {
      SampleSlice(frames[f], (*poses)[f], grid, best_k, f == a ? ca : cb, &va, &sa);
      all.insert(all.end(), va.begin(), va.end());
    }
  }
  const auto window = Window(all);
  const int w = nx * scale, h = ny * scale;
  Picture out(2 * w + 30, 2 * h + 60, {20, 20, 20});
  const char* rows[2] = {"before", "after"};
  int row = 0;
  for (const auto* poses : {&before, &after}) {
    SampleSlice(frames[a], (*poses)[a], grid, best_k, ca, &va, &sa);
    SampleSlice(frames[b], (*poses)[b], grid, best_k, cb, &vb, &sb);
    Picture checker(w, h), overlay(w, h);
    for (int y = 0; y < h; ++y) {
      for (int x = 0; x < w; ++x) {
        const size_t l = size_t(y / scale) * nx + x / scale;
        const bool tile_a = ((x / 8) + (y / 8)) % 2 == 0;
        const bool use_a = sa[l] && (tile_a || !sb[l]);
        const bool use_b = sb[l] && !use_a;
        const uint8_t c = use_a ? Grey(va[l], window) : use_b ? Grey(vb[l], window) : 0;
        checker.Set(x, y, {c, c, c});
        const uint8_t ga = sa[l] ? Grey(va[l], window) : 0, gb = sb[l] ? Grey(vb[l], window) : 0;
        overlay.Set(x, y, {ga, gb, ga});
      }
    }
    const int top = 25 + row * (h + 30);
    out.Paste(checker, 10, top);
    out.Paste(overlay, 20 + w, top);
    DrawText(std::string(rows[row]) + ": checkerboard", 10, top - 6, 0.42, kWhite, &out);
    DrawText(std::string(rows[row]) + ": frame " + std::to_string(a) + " magenta, " +
                 std::to_string(b) + " green",
             20 + w, top - 6, 0.42, kWhite, &out);
    ++row;
  }
  return out;
}

Picture RenderConvergence(const std::vector<LevelSolve>& solves) {
  const int width = 720, height = 300, left = 60, right = 15, top = 28, bottom = 40;
  std::vector<double> cost, step;
  std::vector<size_t> boundaries;
  for (const LevelSolve& s : solves) {
    if (!cost.empty()) boundaries.push_back(cost.size());
    for (const IterationRecord& r : s.report.iterations) {
      cost.push_back(r.cost);
      step.push_back(r.step_norm);
    }
  }
  Picture out(2 * width, height, {255, 255, 255});
  const Rgb kBlack = {0, 0, 0}, kGrey = {190, 190, 190}, kBlue = {31, 119, 180};
  for (int panel = 0; panel < 2; ++panel) {
    const std::vector<double>& y = panel == 0 ? cost : step;
    const int x0 = panel * width + left, x1 = (panel + 1) * width - right;
    const int y0 = top, y1 = height - bottom;
    std::vector<double> logs;
    for (double v : y) {
      if (v > 0.0 && std::isfinite(v)) logs.push_back(std::log10(v));
    }
    double lo = logs.empty() ? 0.0 : *std::min_element(logs.begin(), logs.end());
    double hi = logs.empty() ? 1.0 : *std::max_element(logs.begin(), logs.end());
    if (hi - lo < 1e-9) hi = lo + 1.0;
    const double n = std::max<double>(1.0, y.size() - 1.0);
    auto px = [&](double i) { return x0 + (x1 - x0) * i / n; };
    auto py = [&](double v) { return y1 - (y1 - y0) * (std::log10(v) - lo) / (hi - lo); };
    for (size_t b : boundaries)
      DrawPolyline({{px(b), double(y0)}, {px(b), double(y1)}}, kGrey, 1, &out);
    DrawPolyline({{double(x0), double(y0)}, {double(x0), double(y1)}, {double(x1), double(y1)}},
                 kBlack, 1, &out);
    std::vector<std::pair<double, double>> line;
    for (size_t i = 0; i < y.size(); ++i) {
      if (y[i] > 0.0 && std::isfinite(y[i])) line.emplace_back(px(i), py(y[i]));
    }
    DrawPolyline(line, kBlue, 2, &out);
    char label[64];
    std::snprintf(label, sizeof(label), "1e%.1f", hi);
    DrawText(label, panel * width + 5, y0 + 5, 0.4, kBlack, &out);
    std::snprintf(label, sizeof(label), "1e%.1f", lo);
    DrawText(label, panel * width + 5, y1, 0.4, kBlack, &out);
    DrawText(panel == 0 ? "cost (log scale) per iteration" : "accepted step norm (log scale)",
             x0 + 10, 18, 0.5, kBlack, &out);
    DrawText("iteration (all solves, coarse to fine; grey lines separate solves): " +
                 std::to_string(y.size()),
             x0, height - 12, 0.4, kBlack, &out);
  }
  return out;
}

void PhotometricToPoses(const std::vector<Photometric>& photometric, PosesFile* poses) {
  poses->gain.clear();
  poses->offset.clear();
  for (const Photometric& p : photometric) {
    poses->gain.push_back(p.gain());
    poses->offset.push_back(p.offset);
  }
}

std::vector<std::string> ReportFiles(int num_frames, int pair_a, int pair_b) {
  char name[64];
  std::snprintf(name, sizeof(name), "pair_%02d_%02d.png", pair_a, pair_b);
  std::vector<std::string> files = {"panorama_slices.png", name, "convergence.png", "poses.json"};
  for (int i = 0; i < num_frames; ++i) {
    std::snprintf(name, sizeof(name), "transforms/frame_%02d.tfm", i);
    files.push_back(name);
  }
  files.push_back("index.md");
  return files;
}

namespace {

// The report's index.md: the pictures, the poses table and the errors.
std::string ReportIndex(const ReportInputs& in, const std::string& pair_picture) {
  const RegistrationResult& r = *in.result;
  const int m = static_cast<int>(in.frames.size());
  const bool uncertainty = !r.uncertainty.covariance.empty();
  const bool photometric = !r.photometric.empty();
  std::ostringstream md;
  md << "# Registration report\n\n"
     << "Mode `" << in.mode << "`, " << m << " frames, " << r.total_iterations
     << " iterations in " << r.solves.size() << " solves, " << r.seconds << " s.\n\n";
  if (r.intensity_transform != IntensityTransform::kNone) {
    md << "Registered on " << IntensityTransformToString(r.intensity_transform) << "(c I), c = "
       << r.intensity_transform_scale
       << " (intensity_transform): the convergence plot's costs are on that scale; gains, "
          "offsets and pictures are on the input's grey levels.\n\n";
  }
  md
     << "## Panorama with fields of view\n\n![panorama slices](panorama_slices.png)\n\n"
     << "Outlined: the field of view of each listed frame, in its colour.\n\n"
     << "## Frames " << in.pair_a << " and " << in.pair_b << ", before and after\n\n![pair]("
     << pair_picture << ")\n\n"
     << "## Convergence\n\n![convergence](convergence.png)\n\n"
     << "## Poses\n\n`poses.json` (T maps world = frame 0 to each frame) and ITK transforms "
        "`transforms/frame_XX.tfm` (world -> frame, LPS: resampling frame XX with its file "
        "puts it on the panorama in 3D Slicer, ITK/SimpleITK, ANTs or elastix).\n\n"
     << "| frame | image | translation (mm) | rotation angle (deg) |"
     << (photometric ? " gain | offset |" : "") << (uncertainty ? " predicted TRE (mm) |" : "")
     << "\n|---|---|---|---|" << (photometric ? "---|---|" : "") << (uncertainty ? "---|" : "")
     << "\n";
  for (int i = 0; i < m; ++i) {
    const Eigen::Isometry3d& t = r.frame_from_world[i];
    const double angle = Eigen::AngleAxisd(t.linear()).angle() * 180.0 / M_PI;
    char row[256];
    std::snprintf(row, sizeof(row), "| %d | %s | %.3f, %.3f, %.3f | %.3f |", i,
                  i < static_cast<int>(in.image_names.size()) ? in.image_names[i].c_str() : "",
                  t.translation().x(), t.translation().y(), t.translation().z(), angle);
    md << row;
    if (photometric) {
      std::snprintf(row, sizeof(row), " %.4f | %.3f |", r.photometric[i].gain(),
                    r.photometric[i].offset);
      md << row;
    }
    if (uncertainty) {
      std::snprintf(row, sizeof(row), " %.4f |", r.uncertainty.predicted_tre_mm[i]);
      md << row;
    }
    md << '\n';
  }
  if (photometric) {
    md << "\nGain and offset: frame i's intensities on frame 0's scale are gain * I_i + offset "
          "(photometric=affine); the panorama and the pair picture show them so.\n";
  }
  if (uncertainty || !r.uncertainty_note.empty()) {
    md << "\n" << UncertaintySummary(r.uncertainty, r.uncertainty_note) << ".\n";
  }
  if (in.errors != nullptr) {
    md << "\n## Errors against ground truth (frame-0-relative)\n\n```\n" << in.errors->Table()
       << "```\n";
  }
  return md.str();
}

}  // namespace

PosesFile ResultPoses(const RegistrationResult& result,
                      const std::vector<std::string>& image_names) {
  PosesFile poses;
  poses.images = image_names;
  poses.frame_from_world = result.frame_from_world;
  if (!result.uncertainty.covariance.empty()) {
    poses.covariance = result.uncertainty.covariance;
    poses.predicted_tre_mm = result.uncertainty.predicted_tre_mm;
  }
  // The pipeline's gains and offsets are relative to frame 0, as the file's are.
  PhotometricToPoses(result.photometric, &poses);
  return poses;
}

bool WriteReport(const std::string& dir,
                 const ReportInputs& in,
                 std::string* index_path,
                 std::string* error) {
  namespace fs = std::filesystem;
  std::error_code ec;
  fs::create_directories(fs::path(dir) / "transforms", ec);
  if (ec) {
    *error = "report_dir=" + dir + ": cannot create the folder (" + ec.message() + ")";
    return false;
  }
  const RegistrationResult& r = *in.result;
  const int m = static_cast<int>(in.frames.size());
  auto file = [&](const std::string& name) { return (fs::path(dir) / name).string(); };
  if (!WritePng(RenderPanoramaSlices(in.panorama, in.frames, r.frame_from_world, in.outlined),
                file("panorama_slices.png"), error)) {
    return false;
  }
  const std::vector<std::string> names = ReportFiles(m, in.pair_a, in.pair_b);
  if (!WritePng(RenderPairComparison(in.frames, in.pair_a, in.pair_b, in.initial,
                                     r.frame_from_world, r.grid, r.photometric),
                file(names[1]), error) ||
      !WritePng(RenderConvergence(r.solves), file("convergence.png"), error)) {
    return false;
  }
  if (!WritePoses(ResultPoses(r, in.image_names), file("poses.json"), error)) return false;
  for (int i = 0; i < m; ++i) {
    if (!WriteItkTransform(r.frame_from_world[i], file(names[4 + i]), error)) return false;
  }
  *index_path = file("index.md");
  return WriteFileAtomically(*index_path, ReportIndex(in, names[1]), error);
}

}  // namespace dsr
