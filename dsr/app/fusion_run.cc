// A fusion run (dsr/app/fusion_run.h).
#include "dsr/app/fusion_run.h"

#include <algorithm>
#include <cstdio>
#include <sstream>

#include "dsr/app/inputs.h"
#include "dsr/app/run_options.h"
#include "dsr/io/io_frames.h"
#include "dsr/io/io_image.h"
#include "dsr/io/io_phases.h"

namespace dsr {

FusionRun::FusionRun(const Settings& settings)
    : config_(ConfigFrom(settings)), blend_(settings.String("blend")) {}

bool FusionRun::PlanFiles(const Settings& settings, const std::string& poses_path,
                          const std::string& out, const std::string& out_count,
                          std::string* error) {
  if (!FrameFilesFrom(settings, 1, &image_paths_, &mask_paths_, error)) return false;
  poses_path_ = poses_path;
  out_ = out;
  out_count_ = out_count;
  for (const auto& [flag, path] : {std::pair<std::string, std::string>{"out", out},
                                   {"out_count", out_count}}) {
    if (!path.empty() && !HasSupportedImageExtension(path)) {
      *error = "--" + flag + "=" + path +
               ": unsupported extension (.nii, .nii.gz, .mha, .mhd, .nrrd, .nhdr)";
      return false;
    }
  }
  plan_ = OutputPlan();
  plan_.AddFrameInputs(image_paths_, mask_paths_, settings.String("images"),
                       settings.String("masks"));
  plan_.AddInputFile("poses", poses_path);
  plan_.AddOutputImage("out", out);
  plan_.AddOutputImage("out_count", out_count);
  return plan_.Check(error);
}

bool FusionRun::ReadFiles(std::string* error) {
  const int m = static_cast<int>(image_paths_.size());
  if (!ReadPoses(poses_path_, m, &poses_, error)) {
    *error = "--poses: " + *error;
    return false;
  }
  // Only the phases --phases selects are read.
  if (!ReadViewPhases(config_.phases, image_paths_, mask_paths_, config_.field_of_view,
                      config_.num_threads, &images_, &masks_, &mask_rules_, &later_phases_,
                      error)) {
    return false;
  }
  names_ = image_paths_;
  // After the frames, so that a broken frame is reported as such first.
  return MatchPosesToImages("poses", poses_path_, image_paths_, &poses_, error);
}

bool FusionRun::SetFrames(std::vector<Image> images, std::vector<Mask> masks,
                          std::vector<MaskRule> mask_rules, std::vector<std::string> names,
                          PosesFile poses, const std::string& poses_name, std::string* error,
                          std::vector<std::vector<Image>> later_phases, bool phases_selected) {
  images_ = std::move(images);
  later_phases_ = std::move(later_phases);
  const std::vector<int> selected = phases_selected ? std::vector<int>() : config_.phases;
  if (!UseViewPhases(selected, names, &images_, &later_phases_, error)) return false;
  masks_ = std::move(masks);
  mask_rules_ = std::move(mask_rules);
  names_ = std::move(names);
  poses_ = std::move(poses);
  if (poses_.frame_from_world.size() != images_.size()) {
    *error = poses_name + ": " + std::to_string(poses_.frame_from_world.size()) +
             " poses for " + std::to_string(images_.size()) + " images";
    return false;
  }
  return MatchPosesToImages("poses", poses_name, names_, &poses_, error);
}

bool FusionRun::Prepare(std::string* error) {
  if (!PrepareFusion(images_, masks_, names_, poses_.frame_from_world, config_.panorama_spacing,
                     config_.num_threads, &frames_, &frame_from_world_, &grid_, error)) {
    return false;
  }
  // The mean (float) and k_j (uint8); writing adds a float copy and ITK's image of each
  // output, one at a time, and --out_count a float image of k_j.
  // Every later phase's mean, float, and one more frame set while it is fused.
  const double bytes_per_voxel = 5.0 + 8.0 + (out_count_.empty() ? 0.0 : 4.0) +
                                 4.0 * (later_phases_.empty() ? 0 : later_phases_[0].size());
  std::ostringstream spacing;
  spacing << "--panorama_spacing=" << config_.panorama_spacing;
  // The file's gains and offsets (re-gauged to frame 0 by MatchPosesToImages), if any.
  photometric_ = PhotometricFromPoses(poses_);
  const double bytes = bytes_per_voxel * static_cast<double>(grid_.NumVoxels());
  return CheckMemoryEstimate(spacing.str(), bytes,
                             "a panorama of " + std::to_string(grid_.size[0]) + "x" +
                                 std::to_string(grid_.size[1]) + "x" +
                                 std::to_string(grid_.size[2]) + " voxels",
                             error);
}

void FusionRun::Fuse() {
  fused_ = FusePanorama(frames_, frame_from_world_, grid_, config_.feather,
                        config_.feather_voxels, config_.num_threads, photometric_);
  later_means_.clear();
  const int later = later_phases_.empty() ? 0 : static_cast<int>(later_phases_[0].size());
  for (int p = 0; p < later; ++p) {  // phase by phase: one more set of frames at a time
    std::vector<Frame> frames(frames_.size());
    ParallelFor(0, static_cast<int64_t>(frames.size()), config_.num_threads, [&](int64_t i) {
      frames[i] = Frame::Borrowing(later_phases_[i][p], {}, masks_[i]);
    });
    later_means_.push_back(FusePanorama(frames, frame_from_world_, grid_, config_.feather,
                                        config_.feather_voxels, config_.num_threads,
                                        photometric_).mean);
  }
}

bool FusionRun::Write(std::string* error) const {
  std::vector<const float*> phases(1, fused_.mean.voxels.data());
  for (const Image& mean : later_means_) phases.push_back(mean.voxels.data());
  // One phase: a 3D image as WriteImage writes it; more: 4D (io/io_phases.h).
  if (!out_.empty() && !WritePhases(grid_, phases, out_, error)) return false;
  if (out_count_.empty()) return true;
  Image count(grid_, 0.0f);
  std::copy(fused_.count.voxels.begin(), fused_.count.voxels.end(), count.voxels.begin());
  return WriteImage(count, out_count_, error);
}

std::vector<std::string> FusionRun::SummaryLines() const {
  char line[512];
  std::snprintf(line, sizeof(line),
                "%zu frames%s, %s blend%s, panorama %dx%dx%d voxels of %.3gx%.3gx%.3g mm; "
                "field-of-view enlargement %.3f (%lld voxels seen / %lld in frame 0's field of "
                "view); wrote %s",
                images_.size(),
                later_means_.empty()
                    ? ""
                    : (" x " + std::to_string(1 + later_means_.size()) + " phases").c_str(),
                blend_.c_str(),
                photometric_.empty() ? "" : " of intensities corrected by --poses' gain and offset",
                grid_.size[0], grid_.size[1], grid_.size[2], grid_.spacing_mm[0],
                grid_.spacing_mm[1], grid_.spacing_mm[2], fused_.EnlargementRatio(),
                static_cast<long long>(fused_.seen_voxels),
                static_cast<long long>(fused_.frame0_voxels), out_.c_str());
  return {line, FieldOfViewSummary(mask_rules_, config_.field_of_view.mask_rule)};
}

}  // namespace dsr
