// The options table: every option of every front end (the command-line tools, the Python
// package, the docs' option reference) declared once, with its name, type, default, group,
// the front ends that take it, its help, the rule its values must keep and the field it
// sets. The tools register their flags from it (dsr/tools/flags.h), the Python package takes
// it as keyword arguments and lists it in dsr.options(), and `dsr_options --format=json`
// prints it for the docs. A value is checked by its rule when it is set (one line naming
// the option and the rule); rules between options and the library's own rules are checked
// when the options are turned into the libraries' (dsr/app/run_options.h).
//
// Settings holds a value for every option of the table: its default until set. It is a
// plain value (no global state): two registrations in one process each have their own.
#ifndef DSR_APP_OPTIONS_H_
#define DSR_APP_OPTIONS_H_

#include <cstdint>
#include <map>
#include <set>
#include <string>
#include <string_view>
#include <variant>
#include <vector>

namespace dsr {

struct RunConfig;  // dsr/app/run_options.h

enum class OptionType { kBool, kInt32, kUint64, kDouble, kString };
// "bool", "int32", "uint64", "double", "string" (the names gflags gives its types).
const char* OptionTypeName(OptionType type);

// The front ends an option belongs to, as bits.
enum FrontEnd : uint32_t {
  kDsrRegister = 1u << 0,
  kDsrFuse = 1u << 1,
  kDsrSimulate = 1u << 2,
  kDsrCompare = 1u << 3,
  kPyRegister = 1u << 4,  // dsr.register(...)
  kPyFuse = 1u << 5,      // dsr.fuse(...)
  kPySimulate = 1u << 6,  // dsr.simulate(...)
};
// "dsr_register", ..., "python:register", ...: the names of the bits set in `front_ends`.
std::vector<std::string> FrontEndNames(uint32_t front_ends);
// The bit of one name of FrontEndNames; 0 for any other text.
uint32_t FrontEndFromName(const std::string& name);

using OptionValue = std::variant<bool, int32_t, uint64_t, double, std::string>;

struct OptionSpec {
  const char* name;           // the flag's name and the Python keyword
  OptionType type;
  const char* default_text;   // the default, as a command line would give it
  const char* group;          // the section of the option reference and of --help
  uint32_t front_ends;        // FrontEnd bits
  const char* help;
  // The rule a value must keep: "" when it does, else the rule ("must be in [0, 50]").
  // nullptr: every value of the type.
  std::string (*check)(const OptionValue& value);
  // Writes the value into its field of a RunConfig; nullptr for an option a front end reads
  // itself (files, outputs) or that needs others to mean something (run_options.cc).
  void (*apply)(const OptionValue& value, RunConfig* config);
  // For an option that writes one field of a RunConfig: whether `value` written into a
  // default-constructed RunConfig leaves that field as the library's initialiser set it, so
  // that a test holds the table's default to the library's (options_test.cc). nullptr for
  // the others.
  bool (*keeps_library_default)(const OptionValue& value) = nullptr;
};

// Every option, in the order of the option reference (by group).
const std::vector<OptionSpec>& OptionTable();
// The option of that name, or nullptr.
const OptionSpec* FindOption(std::string_view name);

// Where a front end's default differs from the table's: dsr_compare measures every
// method's poses (its start is the identity, its checks are off, its iteration lines too);
// dsr.fuse feathers the panorama. Part of the table: the tools' --help, Python's signatures
// and the option reference show them.
struct FrontEndDefault {
  uint32_t front_end;  // one FrontEnd bit
  const char* name;
  const char* value;
};
const std::vector<FrontEndDefault>& FrontEndDefaults();
// The default of `spec` for `front_end`: the table's, unless FrontEndDefaults names one.
const char* DefaultFor(const OptionSpec& spec, uint32_t front_end);

// A value as a command line would give it ("true", "0.05", "dsr").
std::string OptionValueText(const OptionValue& value);
// Parses `text` as a value of `spec` and checks its rule: false with
// "--name=text: not a valid int32" or "--name=text: <rule>" in `error`.
bool ParseOptionValue(const OptionSpec& spec, const std::string& text, OptionValue* value,
                      std::string* error);

// A named set of defaults for a kind of data (--preset): the options it sets and their
// values. An option given explicitly keeps its value.
struct Preset {
  const char* name;
  std::vector<std::pair<const char*, const char*>> values;
};
const std::vector<Preset>& Presets();

class Settings {
 public:
  // Every option at its table default.
  Settings();
  // Every option at its default for `front_end` (DefaultFor).
  static Settings For(uint32_t front_end);

  // Sets option `name` from text as a command line does (--name=text): false with a
  // one-line `error` naming it ("--name=text: unknown option", "...: not a valid double",
  // "...: must be >= 1").
  bool Set(const std::string& name, const std::string& text, std::string* error);
  // Changes the default of `name` for this front end (dsr_compare's checks are off): the
  // value, unless the option was set; IsDefault stays true. Checked as Set.
  bool SetDefault(const std::string& name, const std::string& text, std::string* error);
  // Reads a flagfile (one --name=value per line, '#' comments and blank lines, nested
  // --flagfile=FILE) with the command line's checks (dsr/app/flagfile.h) and sets its values
  // in order; only options of `front_end` are known. False with one line naming the file.
  bool ReadFlagfile(const std::string& path, uint32_t front_end, std::string* error);

  // Whether `name` kept its default (not set).
  bool IsDefault(const std::string& name) const;
  // The value of `name`, or, when --preset names a preset that sets it and it was not set,
  // the preset's.
  const OptionValue& Value(const std::string& name) const;
  bool Bool(const std::string& name) const;
  int32_t Int(const std::string& name) const;
  uint64_t Uint64(const std::string& name) const;
  double Double(const std::string& name) const;
  const std::string& String(const std::string& name) const;
  // "--a=1 --b=x ...": every option set, in table order (for logs).
  std::string SetOptionsText() const;
  // "preset echo: --photometric=affine ..." (the options the preset set), or "" without one.
  std::string PresetSummary() const;

  // Writes every option with an apply function into `config`.
  void ApplyTo(RunConfig* config) const;

 private:
  std::map<std::string, OptionValue, std::less<>> values_;
  std::set<std::string, std::less<>> set_;
  std::map<std::string, OptionValue, std::less<>> preset_values_;  // of the current --preset
  void UpdatePreset();
};

// `message` (a library's error) with each option field path it names (util/option_fields.h)
// written as the option of the table it is: "--" and the path with '.' as '_'
// (search.rotations -> --search_rotations), its last part (solve.max_iterations ->
// --max_iterations) or its first part (loss.kind -> --loss), the first that is an option of
// `front_ends`. A path with none stays as it is.
std::string FieldPathsAsOptions(const std::string& message, uint32_t front_ends);

}  // namespace dsr

#endif  // DSR_APP_OPTIONS_H_
