// A comparison of registration methods (dsr/app/comparison.h).
#include "dsr/app/comparison.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>

#include "dsr/app/inputs.h"
#include "dsr/app/simulation_run.h"
#include "dsr/io/io_frames.h"
#include "dsr/io/io_image.h"
#include "dsr/pipeline/report.h"
#include "dsr/util/atomic_file.h"

namespace dsr {
namespace {

namespace fs = std::filesystem;

// The folder's own name ("a/seq/" and "a/./seq" -> "seq"; "." -> the working folder's).
std::string SequenceName(const std::string& folder) {
  const fs::path normal = fs::path(folder).lexically_normal();
  std::string name = normal.filename().string();
  if (name.empty()) name = normal.parent_path().filename().string();
  if (name.empty() || name == "." || name == "..") {
    name = fs::path(CanonicalPath(folder)).filename().string();
  }
  return name;
}

// Lists a sequence folder's frame_XX and (with masks) mask_XX images, sorted.
bool ListImages(const std::string& folder, bool with_masks, SequenceFiles* files,
                std::string* error) {
  std::error_code ec;
  for (const auto& entry : fs::directory_iterator(folder, ec)) {
    const std::string name = entry.path().filename().string();
    if (!HasSupportedImageExtension(name)) continue;
    if (name.rfind("frame_", 0) == 0) files->frames.push_back(entry.path().string());
    if (name.rfind("mask_", 0) == 0 && with_masks) files->masks.push_back(entry.path().string());
  }
  if (ec) {
    *error = "--sequences: " + folder + ": cannot list the folder (" + ec.message() + ")";
    return false;
  }
  std::sort(files->frames.begin(), files->frames.end());
  std::sort(files->masks.begin(), files->masks.end());
  return true;
}

// Lists a sequence folder and checks all but the voxels: at least 2 frame_XX images, one
// mask_XX per frame (with masks), and a readable gt_poses.json with one pose per frame.
bool ListSequence(const std::string& folder, bool with_masks, SequenceFiles* out,
                  std::string* error) {
  SequenceFiles files;
  files.folder = folder;
  files.name = SequenceName(folder);
  if (!ListImages(folder, with_masks, &files, error)) return false;
  if (files.frames.size() < 2) {
    *error = "--sequences: " + folder + ": expected at least 2 frame_XX images, found " +
             std::to_string(files.frames.size());
    return false;
  }
  if (with_masks && files.masks.size() != files.frames.size()) {
    *error = "--sequences: " + folder + ": expected one mask_XX image per frame_XX image, found " +
             std::to_string(files.frames.size()) + " frames and " +
             std::to_string(files.masks.size()) + " masks (--sequence_masks=false registers "
             "without them)";
    return false;
  }
  files.gt_poses = (fs::path(folder) / "gt_poses.json").string();
  std::error_code ec;
  if (!fs::is_regular_file(files.gt_poses, ec)) {
    *error = "--sequences: " + folder + ": no gt_poses.json (the ground truth to measure against)";
    return false;
  }
  if (!ReadPoses(files.gt_poses, static_cast<int>(files.frames.size()), &files.ground_truth,
                 error)) {
    *error = "--sequences: " + *error;
    return false;
  }
  *out = std::move(files);
  return true;
}

// --methods: known modes, none twice.
bool MethodsFrom(const Settings& settings, std::vector<std::string>* methods,
                 std::string* error) {
  const std::string& text = settings.String("methods");
  *methods = SplitCommaList(text);
  const std::vector<std::string> known = ModeNames();
  if (methods->empty()) {
    *error = "--methods: empty";
    return false;
  }
  for (size_t i = 0; i < methods->size(); ++i) {
    const std::string& m = (*methods)[i];
    if (std::find(known.begin(), known.end(), m) == known.end()) {
      *error = "--methods: unknown method '" + m + "'";
      return false;
    }
    if (std::find(methods->begin(), methods->begin() + i, m) != methods->begin() + i) {
      *error = "--methods=" + text + ": '" + m + "' is given twice";
      return false;
    }
  }
  return true;
}

// The options every method shares: with recovery, the checks that flag frames are
// dsr_register's unless one is set.
bool BaseOptionsFrom(const Settings& settings, RegistrationOptions* base, std::string* error) {
  std::string init_file;
  if (!RegistrationOptionsFrom(settings, base, &init_file, error)) return false;
  if (!init_file.empty()) {
    *error = "--init=" + settings.String("init") + ": must be identity, pairwise, auto or global";
    return false;
  }
  const std::string& init = settings.String("init");
  const bool recovers = init == "auto" || init == "global";
  for (const char* check : {"max_misfit_ratio", "max_pair_mismatch_ratio", "min_kept_overlap",
                            "max_structure_fraction", "max_pose_error_voxels"}) {
    if (!settings.IsDefault(check)) return true;
  }
  if (recovers) {
    const RegistrationOptions defaults;
    base->min_kept_overlap = defaults.min_kept_overlap;
    base->max_misfit_ratio = defaults.max_misfit_ratio;
    base->max_pair_mismatch_ratio = defaults.max_pair_mismatch_ratio;
    base->max_structure_fraction = defaults.max_structure_fraction;
    base->max_pose_error_voxels = defaults.max_pose_error_voxels;
  }
  return true;
}

// One method's options: the pairwise baseline started from the pairwise baseline is the
// baseline itself; photometric parameters, a robust loss and the pose uncertainty for the
// modes that have them (--gauge is DSR's and DBA's; the baselines hold frame 0 constant).
RegistrationOptions MethodOptions(const Settings& settings, const RegistrationOptions& base,
                                  Mode mode) {
  RegistrationOptions o = base;
  o.mode = mode;
  const std::string& init = settings.String("init");
  SetInitialisation(mode == Mode::kPairwise && init == "pairwise" ? "identity" : init,
                    settings.Int("max_recoveries"), &o);
  o.photometric = ModeEstimatesPhotometric(mode) ? PhotometricFor(settings, mode)
                                                 : PhotometricModel::kNone;
  if (!ModeEstimatesPhotometric(mode)) {
    o.loss = RobustLoss();  // squared
    o.uncertainty = false;  // the baselines' poses are not the estimate's: no figures
  }
  return o;
}

// --sequences: every folder checked before any run (a bad one found after the first
// sequence ran would leave results behind with exit 2).
bool SequencesFrom(const Settings& settings, Comparison* c, std::string* error) {
  const std::vector<std::string> folders = SplitCommaList(settings.String("sequences"));
  c->sequences.resize(folders.size());
  for (size_t s = 0; s < folders.size(); ++s) {
    std::error_code ec;
    if (!fs::is_directory(folders[s], ec)) {
      *error = "--sequences: " + folders[s] + ": not a folder";
      return false;
    }
    for (size_t t = 0; t < s; ++t) {
      if (CanonicalPath(folders[t]) == CanonicalPath(folders[s])) {
        *error = "--sequences: " + folders[s] + " is given twice";
        return false;
      }
      if (SequenceName(folders[t]) == SequenceName(folders[s])) {
        *error = "--sequences: " + folders[t] + " and " + folders[s] + " have the same name '" +
                 SequenceName(folders[s]) + "', which names their rows and poses files; "
                 "rename one";
        return false;
      }
    }
    if (!ListSequence(folders[s], c->sequence_masks, &c->sequences[s], error)) return false;
  }
  if (!folders.empty() && !c->source_path.empty()) {
    *error = "--source=" + c->source_path + ": the source of simulated sequences; with "
             "--sequences nothing is simulated";
    return false;
  }
  return true;
}

}  // namespace

bool ComparisonFrom(const Settings& settings, Comparison* c, std::string* error) {
  if (!MethodsFrom(settings, &c->methods, error)) return false;
  const int32_t num_sequences = settings.Int("num_sequences");
  if (num_sequences < 1 || num_sequences > 100) {
    *error = "--num_sequences=" + std::to_string(num_sequences) + ": must be in [1, 100]";
    return false;
  }
  if (settings.Int("num_frames") > kMaxFrames) {
    *error = "--num_frames=" + std::to_string(settings.Int("num_frames")) + ": must be in [2, 32]";
    return false;
  }
  RegistrationOptions base;
  if (!BaseOptionsFrom(settings, &base, error)) return false;
  c->method_options.clear();
  for (const std::string& method : c->methods) {
    Mode mode;
    StringToMode(method, &mode);  // checked by MethodsFrom
    c->method_options.push_back(MethodOptions(settings, base, mode));
    if (!c->method_options.back().Validate(error)) return false;
  }
  c->sequence_masks = settings.Bool("sequence_masks");
  c->field_of_view = ConfigFrom(settings).field_of_view;
  c->source_path = settings.String("source");
  c->out_dir = settings.String("out_dir");
  if (!SequencesFrom(settings, c, error)) return false;
  c->num_sequences = c->sequences.empty() ? num_sequences : static_cast<int>(c->sequences.size());
  // Simulated sequences differ in their seed only.
  return !c->sequences.empty() ||
         SimulationOptionsFrom(settings, &c->simulation, &c->phantom, error);
}

void PlanComparisonFiles(const Comparison& c, OutputPlan* plan) {
  for (const SequenceFiles& files : c.sequences) {
    for (const std::vector<std::string>* list : {&files.frames, &files.masks}) {
      for (const std::string& file : *list) plan->AddInputImageIn("sequences", files.folder, file);
    }
    plan->AddInputFileIn("sequences", files.folder, files.gt_poses);
  }
  plan->AddInputImage("source", c.source_path);
  plan->AddOutputFolder("out_dir", c.out_dir, c.out_dir);
  plan->AddOutputFolder("out_dir", c.out_dir, (fs::path(c.out_dir) / "poses").string());
  plan->AddDerivedFile("out_dir", c.out_dir, "results.csv");
  plan->AddDerivedFile("out_dir", c.out_dir, "results.md");
  for (int s = 0; s < c.num_sequences; ++s) {
    const std::string name = c.sequences.empty()
                                 ? "seed" + std::to_string(c.simulation.seed + s)
                                 : c.sequences[s].name;
    for (const RegistrationOptions& options : c.method_options) {
      plan->AddDerivedFile("out_dir", c.out_dir,
                           "poses/" + name + "_" + MethodLabel(options) + ".json");
    }
  }
}

bool LoadSequence(const Comparison& c, const SequenceFiles& files, ExperimentSequence* out,
                  std::vector<MaskRule>* mask_rules, std::string* error) {
  out->name = files.name;
  // Without masks, each frame's by the comparison's rule (files.masks is then empty).
  if (!ReadFrames(files.frames, files.masks, c.field_of_view, 0, &out->frames, &out->masks,
                  mask_rules, error)) {
    return false;
  }
  out->ground_truth = files.ground_truth.frame_from_world;
  out->ground_truth_photometric = PhotometricFromPoses(files.ground_truth);
  return true;
}

bool ReadEverySequence(const Comparison& c, std::string* error) {
  std::vector<MaskRule> mask_rules;
  for (const SequenceFiles& files : c.sequences) {
    ExperimentSequence sequence;
    if (!LoadSequence(c, files, &sequence, &mask_rules, error)) return false;
  }
  return true;
}

namespace {

// Sequence s of a simulated comparison.
bool SimulatedSequenceFor(const Comparison& c, const Image& source, int s,
                          ExperimentSequence* sequence, std::string* error) {
  SimulationOptions sim = c.simulation;
  sim.seed = c.simulation.seed + s;
  SimulatedSequence simulated;
  if (!Simulate(source, sim, &simulated, error)) return false;
  sequence->name = "seed" + std::to_string(sim.seed);
  sequence->frames = std::move(simulated.frames);
  sequence->masks = std::move(simulated.masks);
  sequence->ground_truth = std::move(simulated.frame_from_world);
  std::vector<double> gain, offset;
  Frame0IntensityCorrections(simulated.gain, simulated.offset, &gain, &offset);
  for (size_t i = 0; i < gain.size(); ++i) {
    sequence->ground_truth_photometric.push_back({std::log(gain[i]), offset[i]});
  }
  return true;
}

// A usable run's poses into poses/, and the results so far.
bool WriteRow(const Comparison& c, const ComparisonRow& row,
              const std::vector<ComparisonRow>& rows, std::string* error) {
  const fs::path dir(c.out_dir);
  if (row.ok) {
    PosesFile poses;
    poses.frame_from_world = row.frame_from_world;
    PhotometricToPoses(row.photometric, &poses);
    for (size_t i = 0; i < row.frame_from_world.size(); ++i) {
      char name[32];
      std::snprintf(name, sizeof(name), "frame_%02zu", i);
      poses.images.push_back(name);
    }
    const std::string path = (dir / "poses" / (row.sequence + "_" + row.method + ".json")).string();
    if (!WritePoses(poses, path, error)) return false;
  }
  return WriteFileAtomically((dir / "results.csv").string(), ComparisonCsv(rows), error) &&
         WriteFileAtomically((dir / "results.md").string(), ComparisonMarkdown(rows), error);
}

}  // namespace

bool RunComparison(const Comparison& c, const std::function<void(const ComparisonRow&)>& on_row,
                   const std::function<void(const std::string&)>& on_note,
                   std::vector<ComparisonRow>* rows, bool* bad_input, std::string* error) {
  *bad_input = false;
  Image source;
  if (c.sequences.empty() && !LoadSimulationSource(c.simulation, c.phantom, c.source_path,
                                                   &source, error)) {
    *bad_input = true;
    return false;
  }
  for (int s = 0; s < c.num_sequences; ++s) {
    ExperimentSequence sequence;
    std::vector<MaskRule> mask_rules;
    if (!c.sequences.empty()) {
      // Read and checked before: a failure now is a file changed during the run.
      if (!LoadSequence(c, c.sequences[s], &sequence, &mask_rules, error)) return false;
      if (!c.sequence_masks) {
        on_note(sequence.name + " " + FieldOfViewSummary(mask_rules, c.field_of_view.mask_rule));
      }
    } else if (!SimulatedSequenceFor(c, source, s, &sequence, error)) {
      *bad_input = true;
      return false;
    }
    for (const RegistrationOptions& options : c.method_options) {
      ComparisonRow row = RunMethod(sequence, options);
      row.failure = FieldPathsAsOptions(row.failure, c.front_end);  // the CSV's too
      on_row(row);
      rows->push_back(std::move(row));
      // Rewritten after every run, so an interrupted comparison keeps what it measured.
      if (!WriteRow(c, rows->back(), *rows, error)) return false;
    }
  }
  return true;
}

}  // namespace dsr
