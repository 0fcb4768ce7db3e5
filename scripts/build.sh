#!/usr/bin/env bash
# Configures and builds dsr (Release, Ninja) into ${DSR_BUILD_DIR:-build}. Installs missing
# Debian packages first. Extra arguments are passed to cmake's configure step.
# DSR_BUILD_TARGETS (space-separated ninja targets, e.g. "dsr_simulate dsr_register"): build
# only those and what they need (scripts/demo.sh); default: everything, the tests too.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install_deps.sh
build_dir="${DSR_BUILD_DIR:-build}"
cmake -S . -B "$build_dir" -G Ninja -DCMAKE_BUILD_TYPE=Release "$@" >/dev/null
read -ra targets <<< "${DSR_BUILD_TARGETS:-}"
ninja -C "$build_dir" -j"$(nproc)" "${targets[@]}" | grep -vE '^\[[0-9]+/[0-9]+\] ' || true
# ninja's exit status is lost in the pipe above: check that the build is complete.
ninja -C "$build_dir" -n "${targets[@]}" | grep -q "no work to do"
