#!/usr/bin/env bash
# Installs what is missing, builds, and runs the whole test suite (ctest).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/build.sh
ctest --test-dir "${DSR_BUILD_DIR:-build}" --output-on-failure -j"$(nproc)" --timeout 600
