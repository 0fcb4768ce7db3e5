#!/usr/bin/env bash
# Installs what is missing, builds, and runs the whole test suite (ctest) twice: in the
# Release build (then the Python package's pytest suite against it, scripts/python_test.sh;
# the docs site's strict build, scripts/docs.sh, whose option reference comes from that
# build's tools/dsr_options and which compiles nothing; and the style checks,
# scripts/lint.sh), then in a second build with AddressSanitizer +
# UndefinedBehaviorSanitizer (build-asan/, DSR_SANITIZE=ON; sanitizer options and
# third-party leak suppressions are compiled in, dsr/tests/sanitizer_suppressions/).
# The second build is -O1 with line tables only (-g1), which halves its compile time against
# -O2 -g; tests that solve to machine precision skip themselves there
# (tests/support/sanitizer.h). DSR_SKIP_SANITIZE=1 skips the second pass for quick local
# runs; CI (.ci/run) runs both.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/build.sh
ctest --test-dir "${DSR_BUILD_DIR:-build}" --output-on-failure -j"$(nproc)" --timeout 600
bash scripts/python_test.sh
bash scripts/docs.sh
bash scripts/lint.sh
if [[ "${DSR_SKIP_SANITIZE:-0}" != "1" ]]; then
  DSR_BUILD_DIR="${DSR_ASAN_BUILD_DIR:-build-asan}" bash scripts/build.sh \
    -DCMAKE_BUILD_TYPE=RelWithDebInfo -DCMAKE_CXX_FLAGS_RELWITHDEBINFO="-O1 -g1 -DNDEBUG" \
    -DDSR_SANITIZE=ON
  ctest --test-dir "${DSR_ASAN_BUILD_DIR:-build-asan}" --output-on-failure -j"$(nproc)" \
    --timeout 1200
fi
