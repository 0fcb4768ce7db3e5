// dsr_options: prints the options table (dsr/app/options.h), the one list every front end's
// options come from: as JSON for the docs' option reference (scripts/docs.sh), or as text.
#include <cstdio>
#include <cstdlib>
#include <string>

#include <nlohmann/json.hpp>

#include "dsr/app/options.h"

namespace {

int Usage() {
  std::fprintf(stderr, "dsr_options: error: usage: dsr_options [--format=json|text]\n");
  return 2;
}

}  // namespace

int main(int argc, char** argv) {
  std::string format = "text";
  for (int a = 1; a < argc; ++a) {
    const std::string arg = argv[a];
    if (arg.rfind("--format=", 0) != 0) return Usage();
    format = arg.substr(9);
  }
  if (format != "json" && format != "text") return Usage();
  nlohmann::json table = nlohmann::json::array();
  for (const dsr::OptionSpec& spec : dsr::OptionTable()) {
    if (format == "text") {
      std::printf("--%s (%s, default \"%s\"; %s)\n    %s\n", spec.name,
                  dsr::OptionTypeName(spec.type), spec.default_text, spec.group, spec.help);
      continue;
    }
    nlohmann::json defaults = nlohmann::json::object();  // a front end's own, where it differs
    for (const dsr::FrontEndDefault& d : dsr::FrontEndDefaults()) {
      if (std::string(d.name) == spec.name) defaults[dsr::FrontEndNames(d.front_end)[0]] = d.value;
    }
    table.push_back({{"name", spec.name},
                     {"front_end_defaults", defaults},
                     {"type", dsr::OptionTypeName(spec.type)},
                     {"default", spec.default_text},
                     {"help", spec.help},
                     {"group", spec.group},
                     {"front_ends", dsr::FrontEndNames(spec.front_ends)}});
  }
  if (format == "json") std::printf("%s\n", table.dump(1).c_str());
  return EXIT_SUCCESS;
}
