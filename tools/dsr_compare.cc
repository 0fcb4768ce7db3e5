// dsr_compare: the paper's comparison (Fig. 1). Runs registration methods on sequences with
// ground truth (folders written by dsr_simulate, or sequences simulated here from the
// built-in phantom) and writes OUT_DIR/results.csv (one line per method and sequence),
// OUT_DIR/results.md (medians per method) and OUT_DIR/poses/<sequence>_<method>.json.
// scripts/plot_compare.py turns the CSV into the paper's box plots.
#include <filesystem>
#include <cmath>
#include <cstdio>
#include <set>
#include <sstream>

#include <gflags/gflags.h>
#include <glog/logging.h>

#include "dsr/io/io_image.h"
#include "dsr/io/io_poses.h"
#include "dsr/pipeline/experiment.h"
#include "dsr/pipeline/registration.h"
#include "dsr/pipeline/report.h"
#include "dsr/sim/phantom.h"
#include "dsr/sim/simulate.h"
#include "dsr/tools/output_plan.h"
#include "dsr/tools/tool_util.h"
#include "dsr/util/atomic_file.h"

DEFINE_string(methods, "dsr,ape,sequential,lie_normalization,pairwise",
              "Comma-separated methods: dsr, dba, ape, sequential, lie_normalization, pairwise.");
DEFINE_string(sequences, "", "Comma-separated sequence folders written by dsr_simulate "
              "(frame_XX.nii.gz, mask_XX.nii.gz, gt_poses.json). Empty: simulate "
              "--num_sequences sequences from the built-in phantom with the flags below.");
DEFINE_int32(num_sequences, 5, "Sequences to simulate when --sequences is empty, in [1, 100] "
             "(the paper: 5); sequence s uses seed --seed + s.");
DEFINE_uint64(seed, 1, "Seed of the first simulated sequence.");
DEFINE_int32(num_frames, 11, "Frames per simulated sequence, in [2, 32].");
DEFINE_string(frame_size, "96,96,80", "Simulated frame size 'nx,ny,nz', each in [8, 512].");
DEFINE_double(frame_spacing, 0.0, "Simulated isotropic frame spacing in mm, 0 or in [1e-6, "
              "1e6] (0 = the phantom's 1 mm).");
DEFINE_double(sigma, 25.0, "Simulated noise standard deviation, >= 0.");
DEFINE_double(max_rotation_deg, 12.0, "Simulated rotations: each Euler angle within +/- this.");
DEFINE_double(max_translation_voxels, 15.0, "Simulated translations: each world-axis "
              "component within +/- this many voxels.");
DEFINE_int32(phantom_size, 192, "Built-in phantom size (voxels per axis), in [16, 512].");
DEFINE_string(init, "identity", "Initial poses of every method: 'identity' (the paper's "
              "comparison), 'pairwise' (each method other than pairwise starts from the "
              "pairwise baseline's poses), 'auto' (identity, with dsr_register's recovery of "
              "flagged frames) or 'global' (the pair graph's poses, then recovery). With auto "
              "and global, the checks that flag frames default to dsr_register's "
              "(--max_misfit_ratio=2, --max_pair_mismatch_ratio=5, --min_kept_overlap=0.25) unless "
              "set.");
DEFINE_string(out_dir, "", "Output folder (created if missing). Required.");
DEFINE_int32(num_threads, 0, "Threads per run (0 = all cores).");
DEFINE_int32(max_iterations, 100, "Iteration limit of each finest-level solve, >= 1.");
DEFINE_int32(pyramid_levels, 3, "Pyramid levels, in [1, 8].");
DEFINE_double(panorama_spacing, 1.0, "Panorama spacing as a multiple of frame 0's, > 0.");
DEFINE_double(min_kept_overlap, 0.0, "Divergence guard of dsr_register (a frame that slid out "
              "of the overlap fails the run); off by default here, so that every method's "
              "poses are measured, diverged or not. In [0, 1).");
DEFINE_double(max_misfit_ratio, 0.0, "Misfit check of dsr_register (a frame that does not "
              "match the others at the final poses fails the run); off by default here. 0 or > 1.");
DEFINE_double(max_pair_mismatch_ratio, 0.0, "Pair check of dsr_register (two overlapping "
              "frames that do not match each other fail the run); off by default here. 0 or > 1.");
DEFINE_bool(progress, false, "Print one line per solver iteration on stderr.");
DEFINE_bool(uncertainty, false, "dsr and dba: estimate the pose covariance (docs/design.md "
            "section 8.6) and add the mean predicted TRE and the mean normalised squared pose "
            "error (6 when calibrated) to results.csv (predicted_tre_mm, nees).");
DEFINE_string(loss, "squared",
              "Loss of the intensity differences (modes dsr and dba; docs/design.md 4.7): "
              "squared, or huber / cauchy with --loss_scale (grey levels of the input) for "
              "outliers such as shadows and reverberation. DBA applies it through Ceres, DSR "
              "by iteratively reweighted solves. --uncertainty is then not estimated.");
DEFINE_double(loss_scale, 0.0, "Scale of --loss=huber or cauchy, in grey levels of the input "
              "(residuals larger than about this are down-weighted); > 0.");
DEFINE_string(photometric, dsr::PhotometricModelToString(dsr::kDefaultPhotometricModel),
              "Photometric model of the methods dsr and dba (docs/design.md section 2.8): "
              "none, or affine (each frame's gain and offset against frame 0 estimated with "
              "the poses; their rows are named METHOD+affine). The baselines have no "
              "photometric parameters and always run without. With affine, "
              "poses/<sequence>_<method>.json carries each frame's \"gain\" and \"offset\", "
              "and results.csv the mean absolute gain and offset errors over frames 1..m-1 "
              "(mae_gain, mae_offset) when the ground truth has them (gt_poses.json's "
              "\"gain\"/\"offset\"; 1 and 0 for the sequences simulated here).");
namespace {
bool ValidatePhotometric(const char* flag, const std::string& v) {
  dsr::PhotometricModel model;
  return dsr::CheckFlag(dsr::StringToPhotometricModel(v, &model), flag, v,
                        "must be none or affine");
}
}  // namespace
DEFINE_validator(photometric, &ValidatePhotometric);
DEFINE_bool(sequence_masks, true, "--sequences: register with each folder's mask_XX images; "
            "false: with each frame's non-zero voxels eroded by one voxel, as dsr_register "
            "does without --masks.");

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
    if (name.rfind("mask_", 0) == 0 && FLAGS_sequence_masks) {
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
  if (FLAGS_sequence_masks && files.masks.size() != files.frames.size()) {
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
// non-zero voxels eroded by one voxel).
bool LoadSequence(const SequenceFiles& files, dsr::ExperimentSequence* out, std::string* error) {
  out->name = files.name;
  out->frames.resize(files.frames.size());
  out->masks.resize(files.frames.size());
  for (size_t i = 0; i < files.frames.size(); ++i) {
    if (!dsr::ReadImage(files.frames[i], &out->frames[i], error)) return false;
    if (!FLAGS_sequence_masks) {
      out->masks[i] = dsr::MaskFromNonZero(out->frames[i], 1);
    } else if (!dsr::ReadMask(files.masks[i], out->frames[i].geometry, &out->masks[i], error)) {
      return false;
    }
  }
  out->ground_truth = files.ground_truth.frame_from_world;
  out->ground_truth_photometric = dsr::PhotometricFromPoses(files.ground_truth);
  return true;
}

int Main(int argc, char** argv) {
  dsr::InitTool(
      "compares registration methods on sequences with ground truth (the paper's Fig. 1).\n"
      "  dsr_compare --out_dir=DIR [--methods=dsr,ape,...] [--sequences=DIR1,DIR2 | "
      "--num_sequences=5 ...]\n"
      "  dsr_compare --flagfile=configs/paper_simulated.flags\n"
      "Exit status: 0 ok (a method that fails on a sequence is a row, not an error), 2 bad "
      "input.",
      {"out_dir"}, &argc, &argv);
  std::string error;
  const std::vector<std::string> methods = dsr::SplitCommaList(FLAGS_methods);
  const std::vector<std::string> known = dsr::ModeNames();
  if (methods.empty()) return Fail("--methods: empty");
  for (size_t i = 0; i < methods.size(); ++i) {
    const std::string& m = methods[i];
    if (std::find(known.begin(), known.end(), m) == known.end()) {
      return Fail("--methods: unknown method '" + m + "'");
    }
    if (std::find(methods.begin(), methods.begin() + i, m) != methods.begin() + i) {
      return Fail("--methods=" + FLAGS_methods + ": '" + m + "' is given twice");
    }
  }
  {
    dsr::RegistrationOptions probe;
    if (!dsr::SetInitialisation(FLAGS_init, 0, &probe)) {
      return Fail("--init=" + FLAGS_init + ": must be identity, pairwise, auto or global");
    }
  }
  if (FLAGS_num_sequences < 1 || FLAGS_num_sequences > 100) {
    return Fail("--num_sequences=" + std::to_string(FLAGS_num_sequences) + ": must be in [1, 100]");
  }
  if (FLAGS_num_frames < 2 || FLAGS_num_frames > dsr::kMaxFrames) {
    return Fail("--num_frames=" + std::to_string(FLAGS_num_frames) + ": must be in [2, 32]");
  }
  if (FLAGS_phantom_size < 16 || FLAGS_phantom_size > 512) {
    return Fail("--phantom_size=" + std::to_string(FLAGS_phantom_size) + ": must be in [16, 512]");
  }
  Eigen::Vector3i frame_size;
  if (!dsr::ParseSize3(FLAGS_frame_size, &frame_size, 8, 512)) {
    return Fail("--frame_size=" + FLAGS_frame_size + ": must be three integers in [8, 512]");
  }
  if (FLAGS_num_threads < 0) return Fail("--num_threads: must be >= 0");
  if (FLAGS_frame_spacing != 0.0 && !(FLAGS_frame_spacing >= dsr::kMinFrameSpacingMm &&
                                      FLAGS_frame_spacing <= dsr::kMaxFrameSpacingMm)) {
    std::ostringstream value;
    value << FLAGS_frame_spacing;
    return Fail("--frame_spacing=" + value.str() +
                ": must be 0 (the phantom's 1 mm) or in [1e-06, 1e+06] mm");
  }

  dsr::RegistrationOptions base;
  base.solve.num_threads = FLAGS_num_threads;
  base.solve.max_iterations = FLAGS_max_iterations;
  base.solve.log_progress = FLAGS_progress;
  base.estimate_uncertainty = FLAGS_uncertainty;
  base.pyramid_levels = FLAGS_pyramid_levels;
  base.panorama_spacing = FLAGS_panorama_spacing;
  base.min_kept_overlap = FLAGS_min_kept_overlap;
  base.max_misfit_ratio = FLAGS_max_misfit_ratio;
  base.max_pair_mismatch_ratio = FLAGS_max_pair_mismatch_ratio;
  base.search.num_threads = FLAGS_num_threads;
  base.search.refine.log_progress = false;
  const bool recovers = FLAGS_init == "auto" || FLAGS_init == "global";
  if (recovers && gflags::GetCommandLineFlagInfoOrDie("max_misfit_ratio").is_default &&
      gflags::GetCommandLineFlagInfoOrDie("max_pair_mismatch_ratio").is_default &&
      gflags::GetCommandLineFlagInfoOrDie("min_kept_overlap").is_default) {
    const dsr::RegistrationOptions defaults;
    base.min_kept_overlap = defaults.min_kept_overlap;
    base.max_misfit_ratio = defaults.max_misfit_ratio;
    base.max_pair_mismatch_ratio = defaults.max_pair_mismatch_ratio;
  }
  dsr::PhotometricModel photometric = dsr::PhotometricModel::kNone;
  dsr::StringToPhotometricModel(FLAGS_photometric, &photometric);  // validated
  dsr::RobustLoss loss;
  if (!dsr::MakeRobustLoss(FLAGS_loss, FLAGS_loss_scale, &loss, &error)) return Fail(error);
  // Each method's options: the pairwise baseline started from the pairwise baseline is the
  // baseline itself; photometric parameters for the modes that have them.
  const auto options_for = [&](const std::string& method) {
    dsr::RegistrationOptions o = base;
    CHECK(dsr::StringToMode(method, &o.mode)) << method;  // checked against ModeNames
    dsr::SetInitialisation(
        method == "pairwise" && FLAGS_init == "pairwise" ? std::string("identity") : FLAGS_init,
        dsr::kDefaultMaxRecoveries, &o);
    o.photometric =
        dsr::ModeEstimatesPhotometric(o.mode) ? photometric : dsr::PhotometricModel::kNone;
    if (dsr::ModeEstimatesPhotometric(o.mode)) o.loss = loss;  // the baselines: squared
    return o;
  };
  for (const std::string& m : methods) {
    if (!options_for(m).Validate(&error)) return Fail(error);
  }
  namespace fs = std::filesystem;
  const std::vector<std::string> folders = dsr::SplitCommaList(FLAGS_sequences);
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
  const auto simulation_for = [&](int s) {
    dsr::SimulationOptions sim;
    sim.num_frames = FLAGS_num_frames;
    sim.frame_size = frame_size;
    sim.noise_sigma = FLAGS_sigma;
    sim.max_rotation_deg = FLAGS_max_rotation_deg;
    sim.max_translation_voxels = FLAGS_max_translation_voxels;
    sim.seed = FLAGS_seed + s;
    sim.frame_spacing_mm = FLAGS_frame_spacing;
    return sim;
  };
  if (folders.empty() && !simulation_for(0).Validate(&error)) return Fail(error);
  // Every file this run reads and writes.
  const int num_sequences =
      folders.empty() ? FLAGS_num_sequences : static_cast<int>(folders.size());
  dsr::OutputPlan plan;
  for (const SequenceFiles& files : sequence_files) {
    for (const std::vector<std::string>* list : {&files.frames, &files.masks}) {
      for (const std::string& file : *list) plan.AddInputImageIn("sequences", files.folder, file);
    }
    plan.AddInputFileIn("sequences", files.folder, files.gt_poses);
  }
  const std::string poses_dir = (fs::path(FLAGS_out_dir) / "poses").string();
  plan.AddOutputFolder("out_dir", FLAGS_out_dir, FLAGS_out_dir);
  plan.AddOutputFolder("out_dir", FLAGS_out_dir, poses_dir);
  plan.AddDerivedFile("out_dir", FLAGS_out_dir, "results.csv");
  plan.AddDerivedFile("out_dir", FLAGS_out_dir, "results.md");
  for (int s = 0; s < num_sequences; ++s) {
    const std::string name = folders.empty() ? "seed" + std::to_string(FLAGS_seed + s)
                                             : sequence_files[s].name;
    for (const std::string& m : methods) {
      plan.AddDerivedFile("out_dir", FLAGS_out_dir,
                          "poses/" + name + "_" + dsr::MethodLabel(options_for(m)) + ".json");
    }
  }
  if (!plan.Check(&error)) return Fail(error);
  // The voxels last (every frame and mask is read once here and again for its run, so
  // that only one sequence is held in memory).
  for (const SequenceFiles& files : sequence_files) {
    dsr::ExperimentSequence sequence;
    if (!LoadSequence(files, &sequence, &error)) return Fail(error);
  }
  if (!plan.CreateFolders(&error)) return Fail(error);

  // Sequences: loaded (checked up front) or simulated one at a time below.
  dsr::Image phantom;
  if (folders.empty()) {
    dsr::PhantomOptions p;
    p.size = FLAGS_phantom_size;
    phantom = dsr::MakePhantom(p);
  }
  std::vector<dsr::ComparisonRow> rows;
  for (int s = 0; s < num_sequences; ++s) {
    dsr::ExperimentSequence sequence;
    if (!folders.empty()) {
      // Read and checked above: a failure now is a file changed during the run.
      if (!LoadSequence(sequence_files[s], &sequence, &error)) return Fail(error, dsr::kExitFailed);
    } else {
      const dsr::SimulationOptions sim = simulation_for(s);
      dsr::SimulatedSequence simulated;
      if (!dsr::Simulate(phantom, sim, &simulated, &error)) return Fail(error);
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
      std::fprintf(stderr, "dsr_compare: %-28s %-10s %s MAE %.4f voxels, %.3g rad, %d iterations, %.2f s\n",
                   row.method.c_str(), row.sequence.c_str(), row.ok ? "ok    " : "FAILED",
                   row.mae_translation_voxels, row.mae_rotation_rad, row.iterations, row.seconds);
      if (!row.ok) std::fprintf(stderr, "dsr_compare:   %s\n", row.failure.c_str());
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
            (fs::path(FLAGS_out_dir) / "poses" / (row.sequence + "_" + row.method + ".json")).string();
        if (!dsr::WritePoses(poses, path, &error)) return Fail(error, dsr::kExitFailed);
      }
      rows.push_back(std::move(row));
      // Rewritten after every run, so an interrupted comparison keeps what it measured.
      if (!dsr::WriteFileAtomically((fs::path(FLAGS_out_dir) / "results.csv").string(),
                                    dsr::ComparisonCsv(rows), &error) ||
          !dsr::WriteFileAtomically((fs::path(FLAGS_out_dir) / "results.md").string(),
                                    dsr::ComparisonMarkdown(rows), &error)) {
        return Fail(error, dsr::kExitFailed);
      }
    }
  }
  std::printf("%s", dsr::ComparisonMarkdown(rows).c_str());
  std::printf("dsr_compare: wrote %s/results.csv and results.md\n", FLAGS_out_dir.c_str());
  return EXIT_SUCCESS;
}

}  // namespace

int main(int argc, char** argv) { return dsr::RunToolMain(argc, argv, &Main); }
