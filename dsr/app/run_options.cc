// From Settings to the libraries' options (dsr/app/run_options.h).
#include "dsr/app/run_options.h"

#include <algorithm>
#include <map>

#include "dsr/app/inputs.h"
#include "dsr/io/io_phases.h"
#include "dsr/model/robust_loss.h"
#include "dsr/util/option_fields.h"

namespace dsr {

bool ParsePhaseList(const std::string& text, std::vector<int>* phases) {
  std::vector<int> list;
  if (text != "all") {
    // Items of decimal digits only, split at every comma: no sign, no space and no empty
    // item (" 1", "+1", "0,1," and "0,,1" are refused alike).
    for (size_t begin = 0;;) {
      const size_t comma = text.find(',', begin);
      const size_t end = comma == std::string::npos ? text.size() : comma;
      const std::string item = text.substr(begin, end - begin);
      if (item.empty() || item.size() > 9 ||
          item.find_first_not_of("0123456789") != std::string::npos) {
        return false;
      }
      const int phase = std::stoi(item);
      if (phase > 4096 || std::find(list.begin(), list.end(), phase) != list.end()) return false;
      list.push_back(phase);
      if (comma == std::string::npos) break;
      begin = comma + 1;
    }
  }
  if (phases != nullptr) *phases = std::move(list);
  return true;
}

RunConfig ConfigFrom(const Settings& settings) {
  RunConfig config;
  settings.ApplyTo(&config);
  config.registration.search.refine.progress = false;
  return config;
}

PhotometricModel PhotometricFor(const Settings& settings, Mode mode) {
  if (settings.IsDefault("photometric") && !ModeEstimatesPhotometric(mode)) {
    return PhotometricModel::kNone;
  }
  PhotometricModel model = PhotometricModel::kNone;
  StringToPhotometricModel(settings.String("photometric"), &model);  // checked when set
  return model;
}

bool RegistrationOptionsFrom(const Settings& settings, RegistrationOptions* options,
                             std::string* init_file, std::string* error) {
  *options = ConfigFrom(settings).registration;
  if (!MakeRobustLoss(settings.String("loss"), settings.Double("loss_scale"), &options->loss,
                      error)) {
    return false;
  }
  init_file->clear();
  if (!SetInitialisation(settings.String("init"), settings.Int("max_recoveries"), options)) {
    *init_file = settings.String("init");
  }
  return true;
}

bool RunOptionsFrom(const Settings& settings, RegistrationOptions* options,
                    std::string* init_file, std::string* error) {
  const std::string& mode = settings.String("mode");
  if (!StringToMode(mode, &options->mode)) {
    std::string names;
    for (const std::string& name : ModeNames()) names += (names.empty() ? "" : "|") + name;
    *error = "--mode=" + mode + ": unknown mode (one of " + names + ")";
    return false;
  }
  const Mode chosen = options->mode;
  if (!RegistrationOptionsFrom(settings, options, init_file, error)) return false;
  options->mode = chosen;
  options->photometric = PhotometricFor(settings, chosen);
  if (!settings.IsDefault("gauge") && options->gauge != Gauge::kFrame0 &&
      !ModeTakesGauge(chosen)) {
    *error = "--gauge=" + settings.String("gauge") + ": needs --mode=dsr or dba (--mode=" +
             mode + " holds frame 0 constant)";
    return false;
  }
  return options->Validate(error);
}

bool SimulationOptionsFrom(const Settings& settings, SimulationOptions* options,
                           PhantomOptions* phantom, std::string* error) {
  const RunConfig config = ConfigFrom(settings);
  *options = config.simulation;
  *phantom = config.phantom;
  if (!options->Validate(error)) return false;
  if (!phantom->Validate(error)) {
    *error = PrefixFieldPaths("phantom", *error);
    return false;
  }
  return true;
}

namespace {

// Where a file of --images is: "image 2", or "phase 1 of image 0" for a view given as its
// phases' files joined by ';'.
std::string PlaceOf(int image, int phase, size_t phases) {
  const std::string name = "image " + std::to_string(image);
  return phases > 1 ? "phase " + std::to_string(phase) + " of " + name : name;
}

}  // namespace

bool CheckEachFileOnce(const std::vector<std::string>& views, std::string* error) {
  std::map<std::string, std::string> place_of;  // CanonicalPath -> PlaceOf
  for (size_t i = 0; i < views.size(); ++i) {
    const std::vector<std::string> files = ViewFiles(views[i]);
    for (size_t p = 0; p < files.size(); ++p) {
      const std::string place = PlaceOf(static_cast<int>(i), static_cast<int>(p), files.size());
      const auto [first, inserted] = place_of.emplace(CanonicalPath(files[p]), place);
      if (inserted) continue;
      *error = "--images: " + files[p] + " is given twice";
      if (files.size() > 1 || first->second.rfind("phase", 0) == 0) {
        *error += " (" + first->second + " and " + place + "; each frame and phase is a file "
                  "of its own)";
      }
      return false;
    }
  }
  return true;
}

bool FrameFilesFrom(const Settings& settings, int min_frames,
                    std::vector<std::string>* image_paths,
                    std::vector<std::string>* mask_paths, std::string* error) {
  if (!ParseInputList("images", settings.String("images"), image_paths, error) ||
      !ParseInputList("masks", settings.String("masks"), mask_paths, error)) {
    return false;
  }
  const int m = static_cast<int>(image_paths->size());
  if (m < min_frames) {
    *error = m == 0 && min_frames == 1 ? "--images: no image given"
                                       : "--images: need at least " + std::to_string(min_frames) +
                                             " images, got " + std::to_string(m);
    return false;
  }
  if (m > kMaxFrames) {
    *error = "--images: at most " + std::to_string(kMaxFrames) + " frames, got " +
             std::to_string(m);
    return false;
  }
  if (!mask_paths->empty() && static_cast<int>(mask_paths->size()) != m) {
    *error = "--masks: " + std::to_string(mask_paths->size()) + " masks for " +
             std::to_string(m) + " images";
    return false;
  }
  return CheckEachFileOnce(*image_paths, error);
}

}  // namespace dsr
