#!/usr/bin/env bash
# Cardiac sequences: every phase against one phase (docs/design.md section 12). For each
# source, protocol and seed, dsr_simulate writes 11 views x T phases of a beating source (a
# 20 mm ball contracting by up to 4 mm over the cycle, its own noise in every phase; each
# view a 4D NIfTI), and dsr_register registers it from identity twice: with every phase
# (--phases=all) and with phase 0 alone (--phases=0), against the ground truth. A run
# succeeds when it exits 0 with a mean TRE below 0.1 mm (bench/accuracy.sh's rule).
# Writes OUT/phases.csv (one row per run) and prints OUT/phases.md: per source and
# protocol, the success rates, the median and largest mean TRE of each, and the median of
# the per-sequence TRE ratios (every phase / phase 0; about 1/sqrt(T) where the anatomy is
# still and the noise independent).
#
#   bash bench/phases.sh [--seeds=20] [--phases=8] [--sources=phantom,mni,ct]
#                        [--protocols=paper,wide] [--out=bench/results/phases]
#
# Long: about 30 s per sequence on 2 cores (8 phases); not part of the test suite.
set -euo pipefail
cd "$(dirname "$0")/.."
seeds=20 phases=8 sources=phantom,mni,ct protocols=paper,wide out=bench/results/phases
for arg in "$@"; do
  case "$arg" in
    --seeds=*) seeds=${arg#*=} ;;
    --phases=*) phases=${arg#*=} ;;
    --sources=*) sources=${arg#*=} ;;
    --protocols=*) protocols=${arg#*=} ;;
    --out=*) out=${arg#*=} ;;
    *) echo "phases.sh: error: unknown argument $arg" >&2; exit 2 ;;
  esac
done
tools=${DSR_TOOLS:-build/tools}
# shellcheck source=bench/protocols.sh
source bench/protocols.sh
mkdir -p "$out/sequences"
csv="$out/phases.csv"
[ -f "$csv" ] || echo "source,protocol,seed,phases,exit,tre_mean_mm,tre_max_mm,seconds" > "$csv"
for source in ${sources//,/ }; do
  case "$source" in
    phantom) source_flag="" ;;
    mni) source_flag="--source=$(bash scripts/fetch_anatomy.sh mni | tail -n 1)" ;;
    ct) source_flag="--source=$(bash scripts/fetch_anatomy.sh ct | tail -n 1) --frame_spacing=1" ;;
    *) echo "phases.sh: error: unknown source $source" >&2; exit 2 ;;
  esac
  for protocol in ${protocols//,/ }; do
    flags=$(protocol_flags "$protocol") || { echo "phases.sh: error: unknown protocol $protocol" >&2; exit 2; }
    for seed in $(seq 1 "$seeds"); do
      dir="$out/sequences/$source-$protocol-$phases-$seed"
      if [ ! -f "$dir/gt_poses.json" ]; then
        # shellcheck disable=SC2086
        "$tools/dsr_simulate" --out_dir="$dir" --seed="$seed" --num_phases="$phases" \
          $source_flag $flags >/dev/null 2>"$dir.log" || { echo "simulation failed: $dir.log" >&2; exit 1; }
      fi
      images=$(ls "$dir"/frame_*.nii.gz | paste -sd, -)
      masks=$(ls "$dir"/mask_*.nii.gz | paste -sd, -)
      for which in all 0; do
        key="$source,$protocol,$seed,$which,"
        grep -q "^$key" "$csv" && continue  # done before (the CSV is the cache)
        start=$(date +%s.%N)
        code=0
        "$tools/dsr_register" --images="$images" --masks="$masks" --phases="$which" \
          --out_poses="$dir/poses_$which.json" --gt_poses="$dir/gt_poses.json" \
          --progress=false >"$dir/register_$which.txt" 2>&1 || code=$?
        seconds=$(echo "$(date +%s.%N) - $start" | bc)
        line=$(grep -o "TRE mean [0-9.e+-]* mm, max [0-9.e+-]* mm" "$dir/register_$which.txt" || true)
        mean=$(echo "$line" | awk '{print $3}')
        max=$(echo "$line" | awk '{print $6}')
        echo "$key$code,${mean:-},${max:-},$seconds" >> "$csv"
        echo "$source $protocol seed $seed phases $which: exit $code, TRE mean ${mean:-none} mm (${seconds} s)"
      done
    done
  done
done
python3 bench/phases_summary.py "$csv" | tee "$out/phases.md"
