// Field paths in error messages (util/option_fields.h).
#include "dsr/util/option_fields.h"

namespace dsr {
namespace {

bool PathChar(char c) {
  return (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') || c == '_' || c == '.';
}

bool StartsPath(const std::string& s, size_t i) {
  if (!(s[i] >= 'a' && s[i] <= 'z')) return false;
  if (i == 0) return true;
  const char before = s[i - 1];
  return before == ' ' || before == '(' || before == ',' || before == ';';
}

}  // namespace

std::string RewriteFieldPaths(const std::string& message,
                              const std::function<std::string(const std::string&)>& rewrite) {
  std::string out;
  size_t i = 0;
  while (i < message.size()) {
    if (StartsPath(message, i)) {
      size_t end = i;
      while (end < message.size() && PathChar(message[end])) ++end;
      const bool valued = end < message.size() && message[end] == '=';
      const bool bracketed = i > 0 && message[i - 1] == '(' && end < message.size() &&
                             message[end] == ')';
      if ((valued || bracketed) && message[end - 1] != '.') {
        out += rewrite(message.substr(i, end - i));
      } else {
        out.append(message, i, end - i);
      }
      i = end;
      continue;
    }
    out += message[i++];
  }
  return out;
}

std::string PrefixFieldPaths(const std::string& prefix, const std::string& message) {
  return RewriteFieldPaths(message, [&](const std::string& path) { return prefix + "." + path; });
}

}  // namespace dsr
