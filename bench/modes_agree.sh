#!/usr/bin/env bash
# The paper's theorem at pipeline level: --mode=dsr and --mode=dba with default flags register
# the same simulated sequences (6 frames of 32^3 voxels at 2 mm, +/-5 deg, +/-3 voxels) and
# end at the same poses. For each seed, DBA's poses are compared with DSR's as if DSR's were
# the ground truth (dsr_register --gt_poses): the mean TRE between the two, in mm, and DSR's
# TRE against the simulated truth. Target: under 0.01 mm between the modes.
#
#   bash bench/modes_agree.sh [--seeds=5] [--out=bench/results/modes_agree]
set -euo pipefail
cd "$(dirname "$0")/.."
seeds=5 out=bench/results/modes_agree
for arg in "$@"; do
  case "$arg" in
    --seeds=*) seeds=${arg#*=} ;;
    --out=*) out=${arg#*=} ;;
    *) echo "modes_agree.sh: unknown argument '$arg' (see its header)" >&2; exit 2 ;;
  esac
done
[[ "$seeds" =~ ^[0-9]+$ && "$seeds" -ge 1 ]] || { echo "modes_agree.sh: --seeds=$seeds: must be >= 1" >&2; exit 2; }
tools=${DSR_TOOLS:-build/tools}
if [[ ! -x "$tools/dsr_register" ]]; then bash scripts/build.sh; fi
mkdir -p "$out"
tre() { grep -oE "TRE mean [0-9.]+(e[+-]?[0-9]+)? mm" "$1" | head -n 1 | cut -d" " -f3; }
echo "| seed | DBA vs DSR, mean TRE (mm) | DSR vs the truth, mean TRE (mm) |"
echo "|---|---|---|"
for ((seed = 1; seed <= seeds; ++seed)); do
  dir="$out/seed$seed"
  if [[ ! -f "$dir/gt_poses.json" ]]; then
    "$tools/dsr_simulate" --out_dir="$dir" --num_frames=6 --frame_size=32,32,32 --frame_spacing=2 \
      --seed="$seed" --max_rotation_deg=5 --max_translation_voxels=3 > "$dir.log" 2>&1 || {
      echo "modes_agree.sh: dsr_simulate failed, see $dir.log" >&2; exit 1; }
  fi
  images=$(ls "$dir"/frame_*.nii.gz | paste -sd,)
  masks=$(ls "$dir"/mask_*.nii.gz | paste -sd,)
  "$tools/dsr_register" --images="$images" --masks="$masks" --mode=dsr --progress=false \
    --out_poses="$out/seed${seed}_dsr.json" --gt_poses="$dir/gt_poses.json" \
    > "$out/seed${seed}_dsr.log" 2>&1 || {
    echo "modes_agree.sh: dsr_register --mode=dsr failed, see $out/seed${seed}_dsr.log" >&2; exit 1; }
  # DBA's poses measured against DSR's (as if they were the truth).
  "$tools/dsr_register" --images="$images" --masks="$masks" --mode=dba --progress=false \
    --out_poses="$out/seed${seed}_dba.json" --gt_poses="$out/seed${seed}_dsr.json" \
    > "$out/seed${seed}_dba.log" 2>&1 || {
    echo "modes_agree.sh: dsr_register --mode=dba failed, see $out/seed${seed}_dba.log" >&2; exit 1; }
  echo "| $seed | $(tre "$out/seed${seed}_dba.log") | $(tre "$out/seed${seed}_dsr.log") |"
done
