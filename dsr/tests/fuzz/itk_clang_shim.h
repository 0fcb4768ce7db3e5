// Force-included (clang -include) into the ITK translation units (io/io_itk*.cc) of the
// clang fuzz build. Debian's ITK 5.2 headers were generated for GCC only: their
// itk_compiler_detection.h stops with "Unsupported compiler" under clang. Here that header
// is read once while the compiler presents itself as GCC 12 (the feature macros it sets are
// plain C++11/14 features clang 14 has), then clang's own macros are restored for the rest
// of the translation unit.
#ifndef DSR_TESTS_FUZZ_ITK_CLANG_SHIM_H_
#define DSR_TESTS_FUZZ_ITK_CLANG_SHIM_H_
#if defined(__clang__)
#pragma clang diagnostic push
#pragma clang diagnostic ignored "-Wbuiltin-macro-redefined"
#pragma push_macro("__clang__")
#pragma push_macro("__GNUC__")
#pragma push_macro("__GNUC_MINOR__")
#undef __clang__
#undef __GNUC__
#undef __GNUC_MINOR__
#define __GNUC__ 12
#define __GNUC_MINOR__ 2
#include <itk_compiler_detection.h>
#pragma pop_macro("__GNUC_MINOR__")
#pragma pop_macro("__GNUC__")
#pragma pop_macro("__clang__")
#pragma clang diagnostic pop
#endif
#endif  // DSR_TESTS_FUZZ_ITK_CLANG_SHIM_H_
