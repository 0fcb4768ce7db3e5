// Small text helpers the readers, the flagfile parser and the file naming share.
#ifndef DSR_UTIL_TEXT_H_
#define DSR_UTIL_TEXT_H_

#include <string>

namespace dsr {

// `text` in lower case (ASCII letters only; other bytes unchanged).
std::string Lower(std::string text);
// Whether `text` ends with `suffix` (case-sensitive; every text ends with "").
bool EndsWith(const std::string& text, const std::string& suffix);
// `text` without leading and trailing spaces, tabs and carriage returns.
std::string Trim(const std::string& text);

}  // namespace dsr

#endif  // DSR_UTIL_TEXT_H_
