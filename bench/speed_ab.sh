#!/usr/bin/env bash
# The registration's time and memory, this build against another commit's: dsr_register at its
# defaults on the same sequences, the two builds' runs alternating (A B B A A B ...), each
# run's wall time and peak memory taken by the driver (bench/speed_ab.py, os.wait4), and
# this build's own breakdown (load, pyramid, solves, and each check) from its summary line.
# Also, this build alone: --photometric=auto (the default) against --preset=echo on
# ultrasound-like sequences (bench/protocols.sh's us), alternating the same way.
#
#   bash bench/speed_ab.sh [--baseline=e6cb74c] [--runs=3] [--sizes=paper,clinical,us]
#                          [--seeds=101,102] [--out=bench/results/speed_ab]
#
# Sizes: paper = 11 frames of 96x96x80 (the paper's protocol), clinical = 11 frames of
# 176x176x200 at 0.6 mm (the paper's clinical volumes), us = 11 frames of 96x96x80 with
# speckle, attenuation and per-frame gains (--preset=echo's target). Seeds 101 and up are
# not used by the test suite. The baseline is built from `git archive` of the commit into
# OUT/src-COMMIT (targets dsr_register and dsr_simulate only; kept for later runs); this build
# is DSR_TOOLS (default build/tools). Sequences are simulated by this build's dsr_simulate.
# The table, OUT/speed_ab.md, gives per sequence the medians and ranges of both builds' times
# and peak memory, the median of the per-round time ratios (this / baseline), and this
# build's stage times. Long: about 4 minutes per clinical round pair; not part of the suite.
set -euo pipefail
cd "$(dirname "$0")/.."
baseline=e6cb74c runs=3 sizes=paper,clinical,us seeds=101,102 out=bench/results/speed_ab
for arg in "$@"; do
  case "$arg" in
    --baseline=*) baseline=${arg#*=} ;;
    --runs=*) runs=${arg#*=} ;;
    --sizes=*) sizes=${arg#*=} ;;
    --seeds=*) seeds=${arg#*=} ;;
    --out=*) out=${arg#*=} ;;
    *) echo "speed_ab.sh: error: unknown argument $arg" >&2; exit 2 ;;
  esac
done
fail() { echo "speed_ab.sh: error: $*" >&2; exit 2; }
[[ "$runs" =~ ^[1-9][0-9]*$ ]] || fail "--runs=$runs: not a count"
sha=$(git rev-parse --short=12 "$baseline^{commit}" 2>/dev/null) ||
  { echo "speed_ab.sh: error: --baseline=$baseline: not a commit of this repository" >&2; exit 2; }
tools=${DSR_TOOLS:-build/tools}
for t in dsr_register dsr_simulate; do
  [ -x "$tools/$t" ] || fail "$tools/$t missing (bash scripts/build.sh)"
done
mkdir -p "$out"
src="$out/src-$sha"
if [ ! -x "$src/build/tools/dsr_register" ]; then
  echo "speed_ab.sh: building $baseline ($sha) in $src" >&2
  rm -rf "$src"
  mkdir -p "$src"
  git archive "$sha" | tar -x -C "$src"
  cmake -S "$src" -B "$src/build" -G Ninja -DCMAKE_BUILD_TYPE=Release >"$src.log" 2>&1
  ninja -C "$src/build" -j"$(nproc)" dsr_register dsr_simulate >>"$src.log" 2>&1 ||
    { echo "speed_ab.sh: error: the build of $sha failed (see $src.log)" >&2; exit 1; }
fi
# shellcheck source=bench/protocols.sh
source bench/protocols.sh
IFS=, read -ra size_list <<<"$sizes"
IFS=, read -ra seed_list <<<"$seeds"
cases=()
for size in "${size_list[@]}"; do
  case "$size" in
    paper) flags="$(protocol_flags paper)" ;;
    clinical) flags="$(protocol_flags paper) --frame_size=176,176,200 --frame_spacing=0.6" ;;
    us) flags="$(protocol_flags us)" ;;
    *) echo "speed_ab.sh: error: --sizes: unknown size $size (paper, clinical, us)" >&2; exit 2 ;;
  esac
  for seed in "${seed_list[@]}"; do
    dir="$out/sequences/$size-$seed"
    # shellcheck disable=SC2086
    simulate_sequence "$tools" "$dir" "$seed" $flags ||
      { echo "speed_ab.sh: error: simulating $dir failed (see $dir.log)" >&2; exit 1; }
    cases+=("$size:$dir")
  done
done
python3 bench/speed_ab.py --this="$tools/dsr_register" --baseline="$src/build/tools/dsr_register" \
  --baseline_name="$baseline" --runs="$runs" --out="$out" "${cases[@]}"
