#!/usr/bin/env bash
# Builds the libFuzzer targets (dsr/tests/fuzz: poses-JSON reader, image-loading wrapper, the
# reader of a view's phases) with clang + ASan + UBSan in build-fuzz/ and runs each for a
# bounded time, all at once (one process each; on two cores they share). Usage:
# bash scripts/fuzz.sh [seconds per target, default 600] [target...: poses image phases]
# (the ctest suite replays the same targets on the corpus without clang: FuzzReplay.*)
# The committed seeds (dsr/tests/fuzz/corpus) are copied to build-fuzz/corpus first, so runs
# grow their own corpus; crashes and hangs (an input over 10 s) land in build-fuzz/artifacts/
# and fail the script.
set -euo pipefail
cd "$(dirname "$0")/.."
seconds="${1:-600}"
targets=("${@:2}")
[[ ${#targets[@]} -gt 0 ]] || targets=(poses image phases)
bash scripts/install_deps.sh
if ! dpkg -s libclang-rt-14-dev >/dev/null 2>&1; then
  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libclang-rt-14-dev >/dev/null
fi
build=build-fuzz
CC=clang CXX=clang++ cmake -S . -B "$build" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo \
  -DDSR_BUILD_FUZZERS=ON -DDSR_BUILD_TESTS=OFF >/dev/null
ninja -C "$build" "${targets[@]/#/fuzz_}" | grep -vE '^\[[0-9]+/[0-9]+\] ' || true
mkdir -p "$build/artifacts"
export ASAN_OPTIONS="detect_leaks=1:abort_on_error=1"
export UBSAN_OPTIONS="print_stacktrace=1:halt_on_error=1"
pids=()
for target in "${targets[@]}"; do
  mkdir -p "$build/corpus/$target"
  cp -n dsr/tests/fuzz/corpus/"$target"/* "$build/corpus/$target/"
  "$build/dsr/tests/fuzz/fuzz_$target" "$build/corpus/$target" -max_total_time="$seconds" \
    -artifact_prefix="$build/artifacts/${target}_" -print_final_stats=1 -timeout=10 \
    > "$build/fuzz_$target.log" 2>&1 &
  pids+=($!)
done
status=0
for pid in "${pids[@]}"; do wait "$pid" || status=1; done
for target in "${targets[@]}"; do
  echo "== fuzz_$target ($seconds s)"
  grep -E "stat::number_of_executed_units|stat::peak_rss_mb|cov:|ERROR|SUMMARY" \
    "$build/fuzz_$target.log" | tail -4
done
exit "$status"
