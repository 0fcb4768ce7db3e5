// simulate: dsr_simulate's sequence (frames, masks, ground truth, later phases, intensity
// corrections) made in memory and returned as arrays.
#include "module_internal.h"

#include <string>
#include <vector>

#include "dsr/app/options.h"
#include "dsr/app/run_options.h"
#include "dsr/app/simulation_run.h"
#include "dsr/sim/phantom.h"
#include "dsr/sim/simulate.h"

namespace dsr {
namespace python_internal {

py::dict SimulateSequence(const Options& options_in) {
  SimulationOptions options;
  PhantomOptions phantom;
  std::string error;
  const Settings settings = MakeSettings(options_in, kPySimulate);
  if (!SimulationOptionsFrom(settings, &options, &phantom, &error)) BadInput(error);
  RefuseNonFinite(settings, kPySimulate);
  // As dsr_simulate: what would not fit in memory is refused before any of it is allocated.
  Image source;
  if (!LoadSimulationSource(options, phantom, settings.String("source"), &source, &error)) {
    BadInput(error);
  }
  SimulatedSequence sequence;
  bool ok = false;
  {
    py::gil_scoped_release release;
    ok = Simulate(source, options, &sequence, &error);
  }
  if (!ok) BadInput(error);
  py::list frames, masks, truth;
  for (size_t f = 0; f < sequence.frames.size(); ++f) {
    frames.append(
        py::make_tuple(ToArray(sequence.frames[f]), FromGeometry(sequence.frames[f].geometry)));
    masks.append(
        py::make_tuple(ToArray(sequence.masks[f]), FromGeometry(sequence.masks[f].geometry)));
    truth.append(ToArray(sequence.frame_from_world[f]));
  }
  py::dict out;
  out["frames"] = frames;
  out["masks"] = masks;
  out["frame_from_world"] = truth;
  if (sequence.num_phases() > 1) {  // a beating source: later_phases[i][p - 1], p >= 1
    py::list later_phases;
    for (const std::vector<Image>& view : sequence.later_phases) {
      py::list phases;
      for (const Image& phase : view) {
        phases.append(py::make_tuple(ToArray(phase), FromGeometry(phase.geometry)));
      }
      later_phases.append(phases);
    }
    out["later_phases"] = later_phases;
  }
  if (options.gain_range > 0.0 || options.offset_range > 0.0) {
    std::vector<double> gain, offset;
    Frame0IntensityCorrections(sequence.gain, sequence.offset, &gain, &offset);
    out["gain"] = gain;
    out["offset"] = offset;
  }
  return out;
}

}  // namespace python_internal
}  // namespace dsr
