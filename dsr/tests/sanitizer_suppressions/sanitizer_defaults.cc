// Sanitizer defaults for the DSR_SANITIZE build, compiled into every target of that build
// (top CMakeLists.txt), so that `ctest`, the tools and the CLI tests all run with them
// without environment variables. ASAN_OPTIONS / LSAN_OPTIONS / UBSAN_OPTIONS still override.

// Leak detection on. Allocation stacks come from the frame-pointer unwinder (ASan's
// default): the slow DWARF unwinder on every malloc (fast_unwind_on_malloc=0) nearly
// doubled the sanitizer pass of ctest (figures: the commit that chose the fast one), and
// the suppressions below still match: the frame above malloc
// is the third-party library's own (the whole ctest pass runs clean). The libFuzzer build
// (tests/fuzz/CMakeLists.txt defines DSR_SANITIZER_FULL_MALLOC_STACKS) keeps the full
// stacks, with which its MetaIO leak was found.
extern "C" const char* __asan_default_options() {
#ifdef DSR_SANITIZER_FULL_MALLOC_STACKS
  return "detect_leaks=1:abort_on_error=1:fast_unwind_on_malloc=0";
#else
  return "detect_leaks=1:abort_on_error=1";
#endif
}

extern "C" const char* __ubsan_default_options() { return "print_stacktrace=1:halt_on_error=1"; }

// Third-party leaks only. ITK 5.2's bundled NrrdIO does not free its nrrd/biff/gzip state
// when it fails on a truncated or corrupt .nrrd (reached by io_image_test and the bad-input
// catalogue), and its MetaIO leaks a buffer from MetaImage::ReadStream on some malformed
// .mha headers (found by tests/fuzz/fuzz_image): allocations and missing frees are inside
// ITK in both cases.
extern "C" const char* __lsan_default_suppressions() {
  return "leak:libITKNrrdIO\nleak:MetaImage::ReadStream\n";
}
