// How library errors name options. A library refuses an option by its field path in the
// options struct it was given, "field=value: rule" (e.g. "solve.max_iterations=0: must be
// >= 1"), and names other fields in the same form ("needs mode=dsr or dba"). A struct that
// validates a member struct prefixes the member's name to the paths of its error
// (PrefixFieldPaths). Tools rewrite the paths into their flags (tools/tool_util.h), so a
// library caller reads field names and a command-line user reads flags.
//
// A field path is a word of [a-z0-9_.] starting with a letter, directly followed by '='
// (at the start of the message or after a space, '(', ',' or ';': so "--flag=" and
// "/path/file=" are not paths), or alone in parentheses ("poses (init) place").
#ifndef DSR_UTIL_OPTION_FIELDS_H_
#define DSR_UTIL_OPTION_FIELDS_H_

#include <functional>
#include <initializer_list>
#include <sstream>
#include <string>

namespace dsr {

// "field=value: rule", the value as an ostream prints it.
template <typename T>
std::string FieldError(const std::string& field, const T& value, const std::string& rule) {
  std::ostringstream s;
  s << field << "=" << value << ": " << rule;
  return s.str();
}

// For Validate functions: *error = FieldError(field, value, rule); returns false.
template <typename T>
bool RefuseField(std::string* error, const std::string& field, const T& value,
                 const std::string& rule) {
  *error = FieldError(field, value, rule);
  return false;
}

// The value among `values` whose name to_string(value) is `name`: true with *value set, or
// false with *value untouched. How the options' enum names (the tools' flag values) parse.
template <typename E, typename Values, typename ToString>
bool FindNamed(const std::string& name, const Values& values, ToString to_string, E* value) {
  for (const E& candidate : values) {
    if (name == to_string(candidate)) {
      *value = candidate;
      return true;
    }
  }
  return false;
}
template <typename E, typename ToString>
bool FindNamed(const std::string& name, std::initializer_list<E> values, ToString to_string,
               E* value) {
  return FindNamed<E, std::initializer_list<E>, ToString>(name, values, to_string, value);
}

// `message` with every field path replaced by rewrite(path).
std::string RewriteFieldPaths(const std::string& message,
                              const std::function<std::string(const std::string&)>& rewrite);

// `message` with "prefix." before every field path.
std::string PrefixFieldPaths(const std::string& prefix, const std::string& message);

}  // namespace dsr

#endif  // DSR_UTIL_OPTION_FIELDS_H_
