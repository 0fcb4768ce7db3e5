// The check every option enum's names share: each value's name parses back to the value,
// and a name that is not one leaves the target untouched.
#ifndef DSR_TESTS_SUPPORT_ENUM_NAMES_H_
#define DSR_TESTS_SUPPORT_ENUM_NAMES_H_

#include <initializer_list>
#include <string>

#include <gtest/gtest.h>

namespace dsr {
namespace testing_enums {

// `values` must hold at least two values (the parse starts from another one than its
// target). to_string(E) names a value; from_string(name, &value) parses one.
template <typename E, typename ToString, typename FromString>
void ExpectNamesRoundTrip(std::initializer_list<E> values, ToString to_string,
                          FromString from_string, std::initializer_list<const char*> not_names) {
  ASSERT_GE(values.size(), 2u);
  const E first = *values.begin();
  const E second = *(values.begin() + 1);
  for (E value : values) {
    E parsed = value == first ? second : first;
    ASSERT_TRUE(from_string(std::string(to_string(value)), &parsed)) << to_string(value);
    EXPECT_EQ(parsed, value) << to_string(value);
  }
  for (const char* name : not_names) {
    E untouched = second;
    EXPECT_FALSE(from_string(std::string(name), &untouched)) << name;
    EXPECT_EQ(untouched, second) << name;
  }
}

}  // namespace testing_enums
}  // namespace dsr

#endif  // DSR_TESTS_SUPPORT_ENUM_NAMES_H_
