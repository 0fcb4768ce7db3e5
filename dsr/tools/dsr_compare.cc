// dsr_compare: the paper's comparison (Fig. 1). Runs registration methods on sequences with
// ground truth (folders written by dsr_simulate, or sequences simulated here from the
// built-in phantom or --source) and writes OUT_DIR/results.csv (one line per method and sequence),
// OUT_DIR/results.md (medians per method) and OUT_DIR/poses/<sequence>_<method>.json.
// scripts/plot_compare.py turns the CSV into the paper's box plots.
#include <filesystem>
#include <cmath>
#include <cstdio>
#include <set>
#include <sstream>

#include <gflags/gflags.h>
#include <glog/logging.h>

#include "dsr/io/io_frames.h"
#include "dsr/io/io_image.h"
#include "dsr/io/io_poses.h"
#include "dsr/pipeline/experiment.h"
#include "dsr/pipeline/registration.h"
#include "dsr/pipeline/report.h"
#include "dsr/sim/phantom.h"
#include "dsr/sim/simulate.h"
#include "dsr/tools/flags.h"
#include "dsr/app/output_plan.h"
#include "dsr/tools/tool_util.h"
#include "dsr/util/atomic_file.h"



namespace {

using dsr::Fail;

// The files of one --sequences folder (written by dsr_simulate).
struct SequenceFiles {
  std::string folder;
  std::string name;  // the folder's name: names its rows and poses files
  std::vector<std::string> frames, masks;  // sorted; masks empty with --sequence_masks=false
  std::string gt_poses;
  dsr::PosesFile ground_truth;
};

// The folder's own name ("a/seq/" and "a/./seq" -> "seq"; "." -> the working folder's).
std::string SequenceName(const std::string& folder) {
  namespace fs = std::filesystem;
  const fs::path normal = fs::path(folder).lexically_normal();
  std::string name = normal.filename().string();
  if (name.empty()) name = normal.parent_path().filename().string();
  if (name.empty() || name == "." || name == "..") {
    name = fs::path(dsr::CanonicalPath(folder)).filename().string();
  }
  return name;
}

// Lists a sequence folder and checks all but the voxels: at least 2 frame_XX images, one
// mask_XX per frame (with --sequence_masks), and a readable gt_poses.json with one pose per
// frame.
bool ListSequence(const std::string& folder, SequenceFiles* out, std::string* error) {
  namespace fs = std::filesystem;
  SequenceFiles files;
  files.folder = folder;
  files.name = SequenceName(folder);
  std::error_code ec;
  for (const auto& entry : fs::directory_iterator(folder, ec)) {
    const std::string name = entry.path().filename().string();
    if (!dsr::HasSupportedImageExtension(name)) continue;
    if (name.rfind("frame_", 0) == 0) files.frames.push_back(entry.path().string());
    if (name.rfind("mask_", 0) == 0 && dsr::BoolFlag("sequence_masks")) {
      files.masks.push_back(entry.path().string());
    }
  }
  if (ec) {
    *error = "--sequences: " + folder + ": cannot list the folder (" + ec.message() + ")";
    return false;
  }
  std::sort(files.frames.begin(), files.frames.end());
  std::sort(files.masks.begin(), files.masks.end());
  if (files.frames.size() < 2) {
    *error = "--sequences: " + folder + ": expected at least 2 frame_XX images, found " +
             std::to_string(files.frames.size());
    return false;
  }
  if (dsr::BoolFlag("sequence_masks") && files.masks.size() != files.frames.size()) {
    *error = "--sequences: " + folder + ": expected one mask_XX image per frame_XX image, found " +
             std::to_string(files.frames.size()) + " frames and " +
             std::to_string(files.masks.size()) + " masks (--sequence_masks=false registers "
             "without them)";
    return false;
  }
  files.gt_poses = (fs::path(folder) / "gt_poses.json").string();
  if (!fs::is_regular_file(files.gt_poses, ec)) {
    *error = "--sequences: " + folder + ": no gt_poses.json (the ground truth to measure against)";
    return false;
  }
  if (!dsr::ReadPoses(files.gt_poses, static_cast<int>(files.frames.size()), &files.ground_truth,
                      error)) {
    *error = "--sequences: " + *error;
    return false;
  }
  *out = std::move(files);
  return true;
}

// Reads the frames and masks of a listed sequence (without --sequence_masks, each frame's
// field of view by --mask_rule eroded by --mask_erosion voxels, as dsr_register makes it;
// `mask_rules` then says which rule built each).
bool LoadSequence(const SequenceFiles& files,
                  dsr::ExperimentSequence* out,
                  std::vector<dsr::MaskRule>* mask_rules,
                  std::string* error) {
  out->name = files.name;
  out->frames.resize(files.frames.size());
  out->masks.resize(files.frames.size());
  mask_rules->assign(dsr::BoolFlag("sequence_masks") ? 0 : files.frames.size(), dsr::MaskRule::kHull);
  for (size_t i = 0; i < files.frames.size(); ++i) {
    if (!dsr::ReadImage(files.frames[i], &out->frames[i], error)) return false;
    if (!dsr::BoolFlag("sequence_masks")) {
      if (!dsr::MaskFromImage(out->frames[i], dsr::ToolConfig().field_of_view, files.frames[i],
                              &out->masks[i], &(*mask_rules)[i], error)) {
        return false;
      }
    } else if (!dsr::ReadMask(files.masks[i], out->frames[i].geometry, &out->masks[i], error)) {
      return false;
    }
  }
  out->ground_truth = files.ground_truth.frame_from_world;
  out->ground_truth_photometric = dsr::PhotometricFromPoses(files.ground_truth);
  return true;
}

int Main(int argc, char** argv) {
  // Every method's poses are measured, diverged or not, from the paper's start.
  dsr::SetFlagDefault("init", "identity");
  dsr::SetFlagDefault("min_kept_overlap", "0");
  dsr::SetFlagDefault("max_misfit_ratio", "0");
  dsr::SetFlagDefault("max_pair_mismatch_ratio", "0");
  dsr::SetFlagDefault("max_structure_fraction", "0");
  dsr::SetFlagDefault("max_pose_error_voxels", "0");
  dsr::SetFlagDefault("progress", "false");
  dsr::InitTool(
      "compares registration methods on sequences with ground truth (the paper's Fig. 1).\n"
      "  dsr_compare --out_dir=DIR [--methods=dsr,ape,...] [--sequences=DIR1,DIR2 | "
      "--num_sequences=5 ...]\n"
      "  dsr_compare --flagfile=configs/paper_simulated.flags\n"
      "Exit status: 0 ok (a method that fails on a sequence is a row, not an error), 2 bad "
      "input.",
      dsr::kDsrCompare, {"out_dir"}, &argc, &argv);
  std::string error;
  const std::vector<std::string> methods = dsr::SplitCommaList(dsr::StringFlag("methods"));
  const std::vector<std::string> known = dsr::ModeNames();
  if (methods.empty()) return Fail("--methods: empty");
  for (size_t i = 0; i < methods.size(); ++i) {
    const std::string& m = methods[i];
    if (std::find(known.begin(), known.end(), m) == known.end()) {
      return Fail("--methods: unknown method '" + m + "'");
    }
    if (std::find(methods.begin(), methods.begin() + i, m) != methods.begin() + i) {
      return Fail("--methods=" + dsr::StringFlag("methods") + ": '" + m + "' is given twice");
    }
  }
  if (dsr::IntFlag("num_sequences") < 1 || dsr::IntFlag("num_sequences") > 100) {
    return Fail("--num_sequences=" + std::to_string(dsr::IntFlag("num_sequences")) + ": must be in [1, 100]");
  }
  if (dsr::IntFlag("num_frames") > dsr::kMaxFrames) {
    return Fail("--num_frames=" + std::to_string(dsr::IntFlag("num_frames")) + ": must be in [2, 32]");
  }
  dsr::RegistrationOptions base;
  std::string init_file;
  if (!dsr::RegistrationOptionsFrom(dsr::ToolSettings(), &base, &init_file, &error)) return Fail(error);
  if (!init_file.empty()) {
    return Fail("--init=" + dsr::StringFlag("init") + ": must be identity, pairwise, auto or global");
  }
  // With recovery, the checks that flag frames are dsr_register's unless one is set.
  const bool recovers = dsr::StringFlag("init") == "auto" || dsr::StringFlag("init") == "global";
  if (recovers && dsr::ToolSettings().IsDefault("max_misfit_ratio") &&
      dsr::ToolSettings().IsDefault("max_pair_mismatch_ratio") && dsr::ToolSettings().IsDefault("min_kept_overlap") &&
      dsr::ToolSettings().IsDefault("max_structure_fraction") &&
      dsr::ToolSettings().IsDefault("max_pose_error_voxels")) {
    const dsr::RegistrationOptions defaults;
    base.min_kept_overlap = defaults.min_kept_overlap;
    base.max_misfit_ratio = defaults.max_misfit_ratio;
    base.max_pair_mismatch_ratio = defaults.max_pair_mismatch_ratio;
    base.max_structure_fraction = defaults.max_structure_fraction;
    base.max_pose_error_voxels = defaults.max_pose_error_voxels;
  }
  // Each method's options: the pairwise baseline started from the pairwise baseline is the
  // baseline itself; photometric parameters for the modes that have them (--gauge is DSR's
  // and DBA's; the baselines hold frame 0 constant).
  const auto options_for = [&](const std::string& method) {
    dsr::RegistrationOptions o = base;
    CHECK(dsr::StringToMode(method, &o.mode)) << method;  // checked against ModeNames
    dsr::SetInitialisation(
        method == "pairwise" && dsr::StringFlag("init") == "pairwise" ? std::string("identity") : dsr::StringFlag("init"),
        dsr::IntFlag("max_recoveries"), &o);
    o.photometric = dsr::ModeEstimatesPhotometric(o.mode) ? dsr::PhotometricFor(dsr::ToolSettings(), o.mode)
                                                          : dsr::PhotometricModel::kNone;
    if (!dsr::ModeEstimatesPhotometric(o.mode)) o.loss = dsr::RobustLoss();  // squared
    return o;
  };
  for (const std::string& m : methods) {
    if (!options_for(m).Validate(&error)) return Fail(error);
  }
  namespace fs = std::filesystem;
  const std::vector<std::string> folders = dsr::SplitCommaList(dsr::StringFlag("sequences"));
  // Every sequence folder is checked before any run: a bad one found after the first
  // sequence ran would leave results behind with exit 2.
  std::vector<SequenceFiles> sequence_files(folders.size());
  for (size_t s = 0; s < folders.size(); ++s) {
    std::error_code dir_ec;
    if (!fs::is_directory(folders[s], dir_ec)) {
      return Fail("--sequences: " + folders[s] + ": not a folder");
    }
    for (size_t t = 0; t < s; ++t) {
      if (dsr::CanonicalPath(folders[t]) == dsr::CanonicalPath(folders[s])) {
        return Fail("--sequences: " + folders[s] + " is given twice");
      }
      if (SequenceName(folders[t]) == SequenceName(folders[s])) {
        return Fail("--sequences: " + folders[t] + " and " + folders[s] + " have the same name '" +
                    SequenceName(folders[s]) + "', which names their rows and poses files; "
                    "rename one");
      }
    }
    if (!ListSequence(folders[s], &sequence_files[s], &error)) return Fail(error);
  }
  // Simulated sequences differ in their seed only.
  dsr::SimulationOptions simulation;
  dsr::PhantomOptions phantom_options;
  if (folders.empty() &&
      !dsr::SimulationOptionsFrom(dsr::ToolSettings(), &simulation, &phantom_options, &error)) {
    return Fail(error);
  }
  const auto simulation_for = [&](int s) {
    dsr::SimulationOptions sim = simulation;
    sim.seed = dsr::Uint64Flag("seed") + s;
    return sim;
  };
  // Every file this run reads and writes.
  const int num_sequences =
      folders.empty() ? dsr::IntFlag("num_sequences") : static_cast<int>(folders.size());
  dsr::OutputPlan plan;
  for (const SequenceFiles& files : sequence_files) {
    for (const std::vector<std::string>* list : {&files.frames, &files.masks}) {
      for (const std::string& file : *list) plan.AddInputImageIn("sequences", files.folder, file);
    }
    plan.AddInputFileIn("sequences", files.folder, files.gt_poses);
  }
  const std::string poses_dir = (fs::path(dsr::StringFlag("out_dir")) / "poses").string();
  if (!folders.empty() && !dsr::StringFlag("source").empty()) {
    return Fail("--source=" + dsr::StringFlag("source") + ": the source of simulated sequences; with "
                "--sequences nothing is simulated");
  }
  plan.AddInputImage("source", dsr::StringFlag("source"));
  plan.AddOutputFolder("out_dir", dsr::StringFlag("out_dir"), dsr::StringFlag("out_dir"));
  plan.AddOutputFolder("out_dir", dsr::StringFlag("out_dir"), poses_dir);
  plan.AddDerivedFile("out_dir", dsr::StringFlag("out_dir"), "results.csv");
  plan.AddDerivedFile("out_dir", dsr::StringFlag("out_dir"), "results.md");
  for (int s = 0; s < num_sequences; ++s) {
    const std::string name = folders.empty() ? "seed" + std::to_string(dsr::Uint64Flag("seed") + s)
                                             : sequence_files[s].name;
    for (const std::string& m : methods) {
      plan.AddDerivedFile("out_dir", dsr::StringFlag("out_dir"),
                          "poses/" + name + "_" + dsr::MethodLabel(options_for(m)) + ".json");
    }
  }
  if (!plan.Check(&error)) return Fail(error);
  // The voxels last (every frame and mask is read once here and again for its run, so
  // that only one sequence is held in memory).
  std::vector<dsr::MaskRule> mask_rules;
  for (const SequenceFiles& files : sequence_files) {
    dsr::ExperimentSequence sequence;
    if (!LoadSequence(files, &sequence, &mask_rules, &error)) return Fail(error);
  }
  if (!plan.CreateFolders(&error)) return Fail(error);

  // Sequences: loaded (checked up front) or simulated one at a time below.
  dsr::Image source;
  if (folders.empty() && dsr::StringFlag("source").empty()) {
    source = dsr::MakePhantom(phantom_options);
  } else if (folders.empty() && !dsr::ReadImage(dsr::StringFlag("source"), &source, &error)) {
    return Fail("--source: " + error);
  }
  std::vector<dsr::ComparisonRow> rows;
  for (int s = 0; s < num_sequences; ++s) {
    dsr::ExperimentSequence sequence;
    if (!folders.empty()) {
      // Read and checked above: a failure now is a file changed during the run.
      if (!LoadSequence(sequence_files[s], &sequence, &mask_rules, &error)) {
        return Fail(error, dsr::kExitFailed);
      }
      if (!dsr::BoolFlag("sequence_masks")) {
        std::fprintf(stderr, "dsr_compare: %s %s\n", sequence.name.c_str(),
                     dsr::FieldOfViewSummary(mask_rules, dsr::ToolConfig().field_of_view.mask_rule)
                         .c_str());
      }
    } else {
      const dsr::SimulationOptions sim = simulation_for(s);
      dsr::SimulatedSequence simulated;
      if (!dsr::Simulate(source, sim, &simulated, &error)) return Fail(error);
      sequence.name = "seed" + std::to_string(sim.seed);
      sequence.frames = std::move(simulated.frames);
      sequence.masks = std::move(simulated.masks);
      sequence.ground_truth = std::move(simulated.frame_from_world);
      std::vector<double> gain, offset;
      dsr::Frame0IntensityCorrections(simulated.gain, simulated.offset, &gain, &offset);
      for (size_t i = 0; i < gain.size(); ++i) {
        sequence.ground_truth_photometric.push_back({std::log(gain[i]), offset[i]});
      }
    }
    for (const std::string& m : methods) {
      dsr::ComparisonRow row = dsr::RunMethod(sequence, options_for(m));
      row.failure = dsr::FieldPathsAsFlags(row.failure);  // the CSV's too: in flags
      std::fprintf(stderr, "dsr_compare: %-28s %-10s %s MAE %.4f voxels, %.3g rad, %d iterations, %.2f s\n",
                   row.method.c_str(), row.sequence.c_str(), row.ok ? "ok    " : "FAILED",
                   row.mae_translation_voxels, row.mae_rotation_rad, row.iterations, row.seconds);
      if (!row.ok) {
        std::fprintf(stderr, "dsr_compare:   %s\n", row.failure.c_str());
      }
      if (row.ok) {
        dsr::PosesFile poses;
        poses.frame_from_world = row.frame_from_world;
        dsr::PhotometricToPoses(row.photometric, &poses);
        for (size_t i = 0; i < row.frame_from_world.size(); ++i) {
          char name[32];
          std::snprintf(name, sizeof(name), "frame_%02zu", i);
          poses.images.push_back(name);
        }
        const std::string path =
            (fs::path(dsr::StringFlag("out_dir")) / "poses" / (row.sequence + "_" + row.method + ".json")).string();
        if (!dsr::WritePoses(poses, path, &error)) return Fail(error, dsr::kExitFailed);
      }
      rows.push_back(std::move(row));
      // Rewritten after every run, so an interrupted comparison keeps what it measured.
      if (!dsr::WriteFileAtomically((fs::path(dsr::StringFlag("out_dir")) / "results.csv").string(),
                                    dsr::ComparisonCsv(rows), &error) ||
          !dsr::WriteFileAtomically((fs::path(dsr::StringFlag("out_dir")) / "results.md").string(),
                                    dsr::ComparisonMarkdown(rows), &error)) {
        return Fail(error, dsr::kExitFailed);
      }
    }
  }
  std::printf("%s", dsr::ComparisonMarkdown(rows).c_str());
  std::printf("dsr_compare: wrote %s/results.csv and results.md\n", dsr::StringFlag("out_dir").c_str());
  return EXIT_SUCCESS;
}

}  // namespace

int main(int argc, char** argv) { return dsr::RunToolMain(argc, argv, &Main); }
