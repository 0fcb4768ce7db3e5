// The options of a call: its (name, value) pairs made into the Settings of one function, with
// the command line's checks and messages (MakeSettings, RegisterSettings, RefuseNonFinite),
// and the options table as Python reads it (OptionsTable).
#include "module_internal.h"

#include <cmath>
#include <cstdint>
#include <string>

#include "dsr/app/options.h"
#include "dsr/app/run_options.h"
#include "dsr/pipeline/registration_options.h"

namespace dsr {
namespace python_internal {
namespace {

// `text` with each NUL character written as \0 (a message holding one would end there).
std::string ShowNul(const std::string& text) {
  std::string out;
  for (const char c : text) out += c == '\0' ? std::string("\\0") : std::string(1, c);
  return out;
}

// A name or value with a NUL character in it: C strings end there, so "50\0junk" would be
// read as 50 and a message that shows it would be cut. Refused, naming the option.
void RefuseNul(const std::string& name, const std::string& value) {
  if (name.find('\0') == std::string::npos && value.find('\0') == std::string::npos) return;
  BadInput("--" + ShowNul(name) + "=" + ShowNul(value) +
           ": contains a NUL character (a string ends there); give it without");
}

}  // namespace

void RefuseNonFinite(const Settings& settings, uint32_t front_end) {
  for (const OptionSpec& spec : OptionTable()) {
    if (spec.type != OptionType::kDouble || (spec.front_ends & front_end) == 0) continue;
    if (std::isfinite(settings.Double(spec.name))) continue;
    BadInput("--" + std::string(spec.name) + "=" + OptionValueText(settings.Value(spec.name)) +
             ": must be a finite number");
  }
}

Settings MakeSettings(const Options& options, uint32_t front_end) {
  Settings settings = Settings::For(front_end);
  std::string error;
  for (const auto& [name, value] : options) {
    RefuseNul(name, value);
    if (name == "flagfile") {
      if (!settings.ReadFlagfile(value, front_end, &error)) BadInput(error);
      continue;
    }
    const OptionSpec* spec = FindOption(name);
    if (spec == nullptr || (spec->front_ends & front_end) == 0) {
      BadInput("--" + name + "=" + value + ": unknown flag");  // the command line's words
    }
    if (!settings.Set(name, value, &error)) BadInput(error);
  }
  return settings;
}

Settings RegisterSettings(const Options& options, uint32_t front_end) {
  Settings settings = MakeSettings(options, front_end);
  RegistrationOptions checked;
  std::string init_file, error;
  if (!RunOptionsFrom(settings, &checked, &init_file, &error)) BadInput(error);
  RefuseNonFinite(settings, front_end);
  return settings;
}

py::list OptionsTable() {
  py::list out;
  for (const OptionSpec& spec : OptionTable()) {
    py::dict defaults;  // where a front end's default differs from the table's
    for (const FrontEndDefault& d : FrontEndDefaults()) {
      if (spec.name != std::string(d.name)) continue;
      defaults[FrontEndNames(d.front_end)[0].c_str()] = d.value;
    }
    out.append(py::make_tuple(spec.name, OptionTypeName(spec.type), spec.default_text, spec.group,
                              FrontEndNames(spec.front_ends), spec.help, defaults));
  }
  return out;
}

}  // namespace python_internal
}  // namespace dsr
