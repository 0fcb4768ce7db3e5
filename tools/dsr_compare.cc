// dsr_compare: the paper's comparison (Fig. 1). Runs registration methods on sequences with
// ground truth (folders written by dsr_simulate, or sequences simulated here from the
// built-in phantom) and writes OUT_DIR/results.csv (one line per method and sequence),
// OUT_DIR/results.md (medians per method) and OUT_DIR/poses/<sequence>_<method>.json.
// scripts/plot_compare.py turns the CSV into the paper's box plots.
#include <filesystem>
#include <cmath>
#include <cstdio>
#include <set>

#include <gflags/gflags.h>
#include <glog/logging.h>

#include "core/atomic_file.h"
#include "core/io_image.h"
#include "core/io_poses.h"
#include "pipeline/experiment.h"
#include "pipeline/registration.h"
#include "sim/phantom.h"
#include "sim/simulate.h"
#include "tools/tool_util.h"

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
DEFINE_double(frame_spacing, 0.0, "Simulated isotropic frame spacing in mm, >= 0 (0 = the "
              "phantom's 1 mm).");
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
DEFINE_bool(sequence_masks, true, "--sequences: register with each folder's mask_XX images; "
            "false: with each frame's non-zero voxels eroded by one voxel, as dsr_register "
            "does without --masks.");

namespace {

using dsr::Fail;

bool LoadSequence(const std::string& folder, dsr::ExperimentSequence* out, std::string* error) {
  namespace fs = std::filesystem;
  std::vector<std::string> frames, masks;
  std::error_code ec;
  for (const auto& entry : fs::directory_iterator(folder, ec)) {
    const std::string name = entry.path().filename().string();
    if (name.rfind("frame_", 0) == 0 && dsr::HasSupportedImageExtension(name)) frames.push_back(entry.path().string());
    if (name.rfind("mask_", 0) == 0 && dsr::HasSupportedImageExtension(name)) masks.push_back(entry.path().string());
  }
  if (ec) {
    *error = "--sequences: " + folder + ": cannot list the folder (" + ec.message() + ")";
    return false;
  }
  std::sort(frames.begin(), frames.end());
  std::sort(masks.begin(), masks.end());
  if (frames.size() < 2 || masks.size() != frames.size()) {
    *error = "--sequences: " + folder + ": expected frame_XX and mask_XX images of the same "
             "number (at least 2), found " + std::to_string(frames.size()) + " and " +
             std::to_string(masks.size());
    return false;
  }
  out->name = fs::path(folder).lexically_normal().filename().string();
  if (out->name.empty()) out->name = fs::path(folder).lexically_normal().parent_path().filename().string();
  out->frames.resize(frames.size());
  out->masks.resize(frames.size());
  for (size_t i = 0; i < frames.size(); ++i) {
    if (!dsr::ReadImage(frames[i], &out->frames[i], error) ||
        !dsr::ReadMask(masks[i], out->frames[i].geometry, &out->masks[i], error)) {
      return false;
    }
    if (!FLAGS_sequence_masks) out->masks[i] = dsr::MaskFromNonZero(out->frames[i], 1);
  }
  dsr::PosesFile gt;
  if (!dsr::ReadPoses((fs::path(folder) / "gt_poses.json").string(),
                      static_cast<int>(frames.size()), &gt, error)) {
    return false;
  }
  out->ground_truth = gt.frame_from_world;
  return true;
}

}  // namespace

int main(int argc, char** argv) {
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
  for (const std::string& m : methods) {
    if (std::find(known.begin(), known.end(), m) == known.end()) {
      return Fail("--methods: unknown method '" + m + "'");
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
  if (!(FLAGS_frame_spacing >= 0.0) || !std::isfinite(FLAGS_frame_spacing)) {
    return Fail("--frame_spacing: must be >= 0");
  }

  dsr::RegistrationOptions base;
  base.solve.num_threads = FLAGS_num_threads;
  base.solve.max_iterations = FLAGS_max_iterations;
  base.solve.log_progress = FLAGS_progress;
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
  // The pairwise baseline started from the pairwise baseline is the baseline itself.
  const auto init_for = [](const std::string& method) {
    return method == "pairwise" && FLAGS_init == "pairwise" ? std::string("identity") : FLAGS_init;
  };
  for (const std::string& m : methods) {
    dsr::RegistrationOptions o = base;
    o.mode = m;
    dsr::SetInitialisation(init_for(m), dsr::kDefaultMaxRecoveries, &o);
    if (!o.Validate(&error)) return Fail(error);
  }
  namespace fs = std::filesystem;
  const std::vector<std::string> folders = dsr::SplitCommaList(FLAGS_sequences);
  for (const std::string& folder : folders) {
    std::error_code dir_ec;
    if (!fs::is_directory(folder, dir_ec)) return Fail("--sequences: " + folder + ": not a folder");
  }
  std::error_code ec;
  fs::create_directories(fs::path(FLAGS_out_dir) / "poses", ec);
  if (ec) return Fail("--out_dir=" + FLAGS_out_dir + ": cannot create (" + ec.message() + ")");
  for (const char* name : {"results.csv", "results.md"}) {
    if (!dsr::CheckOutputFile("out_dir", (fs::path(FLAGS_out_dir) / name).string(), {}, &error)) {
      return Fail(error);
    }
  }

  // Sequences: loaded (checked up front) or simulated one at a time below.
  const int num_sequences = folders.empty() ? FLAGS_num_sequences : static_cast<int>(folders.size());
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
      if (!LoadSequence(folders[s], &sequence, &error)) return Fail(error);
    } else {
      dsr::SimulationOptions sim;
      sim.num_frames = FLAGS_num_frames;
      sim.frame_size = frame_size;
      sim.noise_sigma = FLAGS_sigma;
      sim.max_rotation_deg = FLAGS_max_rotation_deg;
      sim.max_translation_voxels = FLAGS_max_translation_voxels;
      sim.seed = FLAGS_seed + s;
      sim.frame_spacing_mm = FLAGS_frame_spacing;
      std::string why;
      if (!sim.Validate(&why)) return Fail(why);
      dsr::SimulatedSequence simulated;
      if (!dsr::Simulate(phantom, sim, &simulated, &error)) return Fail(error);
      sequence.name = "seed" + std::to_string(sim.seed);
      sequence.frames = std::move(simulated.frames);
      sequence.masks = std::move(simulated.masks);
      sequence.ground_truth = std::move(simulated.frame_from_world);
    }
    for (const std::string& m : methods) {
      dsr::RegistrationOptions o = base;
      o.mode = m;
      dsr::SetInitialisation(init_for(m), dsr::kDefaultMaxRecoveries, &o);
      dsr::ComparisonRow row = dsr::RunMethod(sequence, o);
      std::fprintf(stderr, "dsr_compare: %-28s %-10s %s MAE %.4f voxels, %.3g rad, %d iterations, %.2f s\n",
                   row.method.c_str(), row.sequence.c_str(), row.ok ? "ok    " : "FAILED",
                   row.mae_translation_voxels, row.mae_rotation_rad, row.iterations, row.seconds);
      if (!row.ok) std::fprintf(stderr, "dsr_compare:   %s\n", row.failure.c_str());
      if (row.ok) {
        dsr::PosesFile poses;
        poses.frame_from_world = row.frame_from_world;
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
