// From Settings (dsr/app/options.h) to the libraries' options: what a registration, a
// fusion and a simulation run with, and the rules between options that no single option's
// rule can check. Every front end (the command-line tools, the Python package) calls these,
// so a run from Python is the run dsr_register makes, with its messages.
#ifndef DSR_APP_RUN_OPTIONS_H_
#define DSR_APP_RUN_OPTIONS_H_

#include <string>
#include <vector>

#include "dsr/app/options.h"
#include "dsr/geometry/field_of_view.h"
#include "dsr/pipeline/registration.h"
#include "dsr/sim/phantom.h"
#include "dsr/sim/simulate.h"

namespace dsr {

// What the options table's fields are (OptionSpec::apply writes them).
struct RunConfig {
  RegistrationOptions registration;
  FieldOfViewOptions field_of_view;  // of frames given without masks
  double panorama_spacing = 1.0;     // multiple of frame 0's spacing
  int num_threads = 0;               // 0: every hardware thread
  bool feather = false;              // the fused panorama's blend
  double feather_voxels = 8.0;
  // --phases: the phases of 4D views that are registered, in this order (empty: all).
  std::vector<int> phases;
  int report_phase = 0;  // --report_phase: a position in the registered phases
  SimulationOptions simulation;
  PhantomOptions phantom;
};

// --phases' value: "all" (empty `phases`) or comma-separated phase indices without a
// repeat, in the order given, each of decimal digits only (no sign, no space, no empty item:
// "0,1," and " 1" are refused). False for anything else (`phases` may be null: a check).
bool ParsePhaseList(const std::string& text, std::vector<int>* phases);

// Every field of the table from `settings`.
RunConfig ConfigFrom(const Settings& settings);

// The registration's options, but for the mode (--mode is one run's; dsr_compare has
// --methods) and the photometric model (its default depends on the mode: PhotometricFor).
// --init: a name sets the start and recovery (SetInitialisation); any other text is a
// poses file, returned in *init_file (the start is then the file's poses, with recovery).
// False with a one-line `error` naming the option.
bool RegistrationOptionsFrom(const Settings& settings, RegistrationOptions* options,
                             std::string* init_file, std::string* error);

// --photometric as the model of `mode`: its value (or --preset's), except that the default
// applies only to the modes that estimate photometric parameters (a baseline runs without
// them unless --photometric is given; then RegistrationOptions::Validate refuses it).
PhotometricModel PhotometricFor(const Settings& settings, Mode mode);

// One registration run's options (dsr_register, dsr.register): --mode, the options above,
// the photometric model for that mode, the rule between options that needs to know what
// was given (an explicit --gauge=mean needs a mode that takes a gauge), and the library's
// own rules (RegistrationOptions::Validate: uncertainty, photometric parameters and robust
// losses need dsr or dba, ...). False with a one-line `error` naming the option (or a
// field, from Validate: FieldPathsAsOptions names its option).
bool RunOptionsFrom(const Settings& settings, RegistrationOptions* options,
                    std::string* init_file, std::string* error);

// The simulation's options and the built-in phantom's (checked as a whole). False with a
// one-line `error`.
bool SimulationOptionsFrom(const Settings& settings, SimulationOptions* options,
                           PhantomOptions* phantom, std::string* error);

// Every file of the views `views` (--images: io/io_phases.h ViewFiles, so each phase file
// of a view joined by ';') is another file, by CanonicalPath: a file given as two frames,
// two phases of one view or phases of two views is refused, "--images: <file> is given
// twice" (with the two places when a phase file is one of them).
bool CheckEachFileOnce(const std::vector<std::string>& views, std::string* error);

// The files of --images and --masks: parsed (ParseInputList), between min_frames and
// kMaxFrames images, one mask per image or none, no file given twice (CheckEachFileOnce).
// False with a one-line `error` naming the option.
bool FrameFilesFrom(const Settings& settings, int min_frames,
                    std::vector<std::string>* image_paths,
                    std::vector<std::string>* mask_paths, std::string* error);

}  // namespace dsr

#endif  // DSR_APP_RUN_OPTIONS_H_
