#!/usr/bin/env bash
# elastix groupwise baseline beside the accuracy benchmark: registers the same
# seeded sequences as bench/accuracy.sh with elastix's groupwise rigid registration
# (EulerStackTransform + VarianceOverLastDimensionMetric, bench/elastix_groupwise.py, one
# run per sequence, from identity) and writes, per source, protocol and mask kind,
#   OUT/runs/elastix/SOURCE-PROTOCOL-MASKS/results.csv   (dsr_compare's columns, method elastix)
#   OUT/runs/elastix/SOURCE-PROTOCOL-MASKS/poses/seedN_elastix.json   (dsr poses files)
#   OUT/runs/elastix/SOURCE-PROTOCOL-MASKS/work/seedN/   (parameter file, elastix's logs and
#                                                         TransformParameters.0.txt)
# then the table of success rates (mean TRE below 0.1 mm), median and max TRE and median
# time with bench/accuracy_summary.py, OUT/elastix_summary.md. With --compare_init=auto
# (default; empty to skip) it also summarises dsr's rows for the same sequences from
# OUT/runs/auto/SOURCE-PROTOCOL-MASKS/results.csv (bench/accuracy.sh's output), if present.
#
#   bash bench/elastix.sh [--seeds=10 | --seeds=FIRST-LAST] [--sources=phantom,mni]
#                         [--protocols=paper,wide,walk] [--masks=fov,none]   (bench/protocols.sh)
#                         [--out=bench/results/accuracy] [--compare_init=auto]
#                         [--iterations=1000] [--samples=2048] [--threads=0] [--rerun]
#
# Sequences: the cache bench/accuracy.sh writes, OUT/sequences/SOURCE/PROTOCOL/seedN
# (simulated here with the same flags only when missing). Masks: fov = the sequence's
# mask_XX images, none = each frame's non-zero voxels eroded by one voxel (as dsr without
# --masks). A sequence whose row exists (rows/seedN.csv, written with the same elastix
# settings) is not run again unless --rerun: elastix 5.0.1 is deterministic, so the row
# would be the same; --seeds=20 after --seeds=10 runs only seeds 11..20.
# Needs: elastix (Debian: apt-get install elastix), .venv with numpy and SimpleITK
# (DSR_PYTHON overrides the interpreter), build/tools/dsr_simulate for missing sequences.
# Long: about 35-70 s per sequence on the shared 2-core machine (11 frames of 96x96x80,
# 3 x 1000 iterations), so 10 seeds of one source/protocol/mask kind take 6-12 minutes.
# Not part of the test suite. Exit status: 0 ok (an elastix run that fails is a row with
# ok=0, not an error), 1 a tool failed, 2 bad arguments.
set -euo pipefail
cd "$(dirname "$0")/.."
seeds=10 sources=phantom,mni protocols=paper,wide,walk masks=fov,none
out=bench/results/accuracy compare_init=auto iterations=1000 samples=2048 threads=0 rerun=0
for arg in "$@"; do
  case "$arg" in
    --seeds=*) seeds=${arg#*=} ;;
    --sources=*) sources=${arg#*=} ;;
    --protocols=*) protocols=${arg#*=} ;;
    --masks=*) masks=${arg#*=} ;;
    --out=*) out=${arg#*=} ;;
    --compare_init=*) compare_init=${arg#*=} ;;
    --iterations=*) iterations=${arg#*=} ;;
    --samples=*) samples=${arg#*=} ;;
    --threads=*) threads=${arg#*=} ;;
    --rerun) rerun=1 ;;
    *) echo "elastix.sh: unknown argument '$arg' (see the header of bench/elastix.sh)" >&2; exit 2 ;;
  esac
done
if [[ "$seeds" =~ ^([0-9]+)-([0-9]+)$ ]]; then
  first=${BASH_REMATCH[1]} last=${BASH_REMATCH[2]}
elif [[ "$seeds" =~ ^[0-9]+$ ]]; then
  first=1 last=$seeds
else
  echo "elastix.sh: --seeds=$seeds: expected N (seeds 1..N) or FIRST-LAST" >&2; exit 2
fi
[[ "$first" -ge 1 && "$last" -ge "$first" ]] || {
  echo "elastix.sh: --seeds=$seeds: need 1 <= FIRST <= LAST" >&2; exit 2; }
for n in "$iterations" "$samples" "$threads"; do
  [[ "$n" =~ ^[0-9]+$ ]] || { echo "elastix.sh: --iterations, --samples and --threads take whole numbers" >&2; exit 2; }
done
[[ "$iterations" -ge 1 && "$samples" -ge 1 ]] || {
  echo "elastix.sh: --iterations and --samples must be >= 1" >&2; exit 2; }
command -v elastix >/dev/null || {
  echo "elastix.sh: elastix not found (Debian: apt-get install elastix)" >&2; exit 1; }
python=${DSR_PYTHON:-.venv/bin/python}
"$python" -c "import numpy, SimpleITK" 2>/dev/null || {
  echo "elastix.sh: $python cannot import numpy and SimpleITK (install them into .venv, or set DSR_PYTHON)" >&2; exit 1; }
tools=${DSR_TOOLS:-build/tools}
mni=""

# shellcheck source=bench/protocols.sh
source bench/protocols.sh

# Settings that change a row: a cached row written with other settings is run again.
settings="elastix $(elastix --version 2>/dev/null | tr -d '\n'); $(md5sum < bench/elastix_groupwise.py | cut -c1-12); iterations=$iterations samples=$samples"
header="method,sequence,ok,mae_translation_voxels,mae_translation_mm,mae_rotation_rad,tre_mean_mm,tre_max_mm,iterations,seconds_per_iteration,intensity_differences_per_iteration,seconds,peak_memory_mb,added_memory_mb,failure"
mkdir -p "$out"
csvs=() dsr_csvs=()
IFS=, read -ra source_list <<< "$sources"
IFS=, read -ra protocol_list <<< "$protocols"
IFS=, read -ra mask_list <<< "$masks"
for mask in "${mask_list[@]}"; do
  [[ "$mask" == fov || "$mask" == none ]] || {
    echo "elastix.sh: unknown mask kind '$mask' (fov, none)" >&2; exit 2; }
done
for source in "${source_list[@]}"; do
  [[ "$source" == phantom || "$source" == mni ]] || {
    echo "elastix.sh: unknown source '$source' (phantom, mni)" >&2; exit 2; }
  for protocol in "${protocol_list[@]}"; do
    flags=$(protocol_flags "$protocol") || {
      echo "elastix.sh: unknown protocol '$protocol' ($protocol_names)" >&2; exit 2; }
    for ((seed = first; seed <= last; ++seed)); do
      dir="$out/sequences/$source/$protocol/seed$seed"
      if [[ ! -x "$tools/dsr_simulate" ]]; then
        echo "elastix.sh: $tools/dsr_simulate is not built (bash scripts/build.sh)" >&2; exit 1
      fi
      source_flag=""
      if [[ "$source" == mni ]]; then
        [[ -n "$mni" ]] || mni=$(bash scripts/fetch_anatomy.sh | tail -n 1)
        source_flag="--source=$mni"
      fi
      # shellcheck disable=SC2086
      simulate_sequence "$tools" "$dir" "$seed" $source_flag $flags || {
        echo "elastix.sh: dsr_simulate failed for $dir: $(tail -n 1 "$dir.log")" >&2; exit 1; }
    done
    for mask in "${mask_list[@]}"; do
      run="$out/runs/elastix/$source-$protocol-$mask"
      mkdir -p "$run/rows" "$run/poses" "$run/work"
      echo "elastix.sh: $source $protocol masks=$mask seeds $first..$last" >&2
      for ((seed = first; seed <= last; ++seed)); do
        row="$run/rows/seed$seed.csv"
        # The row holds for these elastix settings on this very sequence.
        row_settings="$settings $(cat "$out/sequences/$source/$protocol/seed$seed/simulate_flags.txt")"
        if [[ $rerun == 0 && -f "$row" && -f "$row.settings" && "$(cat "$row.settings")" == "$row_settings" ]]; then
          continue
        fi
        rm -rf "$run/work/seed$seed"
        status=0
        "$python" bench/elastix_groupwise.py "$out/sequences/$source/$protocol/seed$seed" \
          --masks="$mask" --work_dir="$run/work/seed$seed" \
          --out_poses="$run/poses/seed${seed}_elastix.json" --iterations="$iterations" \
          --samples="$samples" --threads="$threads" >"$row.tmp" 2>"$run/work/seed$seed.err" || status=$?
        if [[ $status -ge 2 || ! -s "$row.tmp" ]]; then
          echo "elastix.sh: elastix_groupwise.py failed on seed $seed: $(tail -n 1 "$run/work/seed$seed.err")" >&2
          rm -f "$row.tmp"; exit 1
        fi
        mv "$row.tmp" "$row"
        echo "$row_settings" > "$row.settings"
        echo "elastix.sh:   seed$seed: $(cut -d, -f3,7,12 "$row" | awk -F, '{printf "ok=%s mean TRE %s mm, %s s", $1, $2, $3}')" >&2
      done
      {
        echo "$header"
        for ((seed = first; seed <= last; ++seed)); do cat "$run/rows/seed$seed.csv"; done
      } > "$run/results.csv.tmp"
      mv "$run/results.csv.tmp" "$run/results.csv"
      csvs+=("$source,$protocol,$mask,$run/results.csv")
      dsr="$out/runs/$compare_init/$source-$protocol-$mask/results.csv"
      if [[ -n "$compare_init" && -f "$dsr" ]]; then
        # dsr's rows for the same sequences (seedFIRST..seedLAST), in a snapshot: the file
        # may be rewritten by a running bench/accuracy.sh.
        awk -F, -v first="$first" -v last="$last" \
          'NR == 1 { print; next } { s = $2; sub(/^seed/, "", s) } s + 0 >= first && s + 0 <= last' \
          "$dsr" > "$run/dsr_$compare_init.csv"
        dsr_csvs+=("$source,$protocol,$mask,$run/dsr_$compare_init.csv")
      fi
    done
  done
done
summary="$out/elastix_summary.md"
{
  echo "elastix groupwise (EulerStackTransform + VarianceOverLastDimensionMetric), seeds $first..$last, from identity; bench/elastix.sh."
  echo
  python3 bench/accuracy_summary.py --init=identity "${csvs[@]}"
  if [[ ${#dsr_csvs[@]} -gt 0 ]]; then
    echo
    echo "dsr on the same sequences (rows of OUT/runs/$compare_init, read at the end of this run):"
    echo
    python3 bench/accuracy_summary.py --init="$compare_init" "${dsr_csvs[@]}"
  fi
} > "$summary.tmp"
mv "$summary.tmp" "$summary"
cat "$summary"
echo "elastix.sh: wrote $summary" >&2
