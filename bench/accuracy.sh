#!/usr/bin/env bash
# Accuracy benchmark: registers N seeded simulated sequences per source,
# protocol and mask kind with dsr_compare and writes one table of success rates (mean TRE
# below 0.1 mm), median and max TRE and median time.
#
#   bash bench/accuracy.sh [--seeds=20] [--sources=phantom,mni] [--protocols=paper,wide,walk]
#                          [--masks=fov,none] [--init=auto] [--methods=dsr]
#                          [--uncertainty] [--out=bench/results/accuracy]
#
# Sources: the built-in phantom and the MNI152 T1 template (scripts/fetch_anatomy.sh, a
# real anatomical volume the project did not make). Protocols (11 frames of 96x96x80,
# noise sigma 25): paper (+/-12 deg, +/-15 voxels), wide (+/-25 deg, +/-20 voxels), walk
# (each frame within 6 deg / 6 voxels of the previous one); us: walk with ultrasound-like
# effects (issue 21: noise sigma 15, speckle of 4 looks, 0.5 dB/cm attenuation, per-frame
# gain within +/-15 % and offset within +/-10), us_flat: the same sequences (same poses,
# noise and speckle) without the gain, offset and attenuation. Masks: fov = the exact field of
# view (dsr_simulate --mask_erosion=0), none = each frame's non-zero voxels eroded by one
# voxel (what dsr_register uses without --masks). Sequences are cached under OUT/sequences.
# --uncertainty: also the pose covariance (dsr_compare --uncertainty) and a table of the
# predicted against the measured error (runs go to OUT/runs/INIT-uncertainty).
# Long: about 2-4 s per run on 2 cores (20 seeds x 2 sources x 3 protocols x 2 mask kinds =
# 240 runs per initialiser); not part of the test suite.
set -euo pipefail
cd "$(dirname "$0")/.."
seeds=20 sources=phantom,mni protocols=paper,wide,walk masks=fov,none init=auto methods=dsr
uncertainty=""
out=bench/results/accuracy
for arg in "$@"; do
  case "$arg" in
    --seeds=*) seeds=${arg#*=} ;;
    --sources=*) sources=${arg#*=} ;;
    --protocols=*) protocols=${arg#*=} ;;
    --masks=*) masks=${arg#*=} ;;
    --init=*) init=${arg#*=} ;;
    --methods=*) methods=${arg#*=} ;;
    --out=*) out=${arg#*=} ;;
    --uncertainty) uncertainty=--uncertainty ;;
    *) echo "accuracy.sh: unknown argument '$arg' (see the header of bench/accuracy.sh)" >&2; exit 2 ;;
  esac
done
[[ "$seeds" =~ ^[0-9]+$ && "$seeds" -ge 1 ]] || { echo "accuracy.sh: --seeds=$seeds: must be >= 1" >&2; exit 2; }
tools=${DSR_TOOLS:-build/tools}
if [[ ! -x "$tools/dsr_compare" ]]; then bash scripts/build.sh; fi
mni=""
if [[ ",$sources," == *",mni,"* ]]; then mni=$(bash scripts/fetch_anatomy.sh | tail -n 1); fi

protocol_flags() {
  case "$1" in
    paper) echo "--max_rotation_deg=12 --max_translation_voxels=15" ;;
    wide) echo "--max_rotation_deg=25 --max_translation_voxels=20" ;;
    walk) echo "--pose_model=walk --step_rotation_deg=6 --step_translation_voxels=6 --max_rotation_deg=12 --max_translation_voxels=15" ;;
    us) echo "--pose_model=walk --step_rotation_deg=6 --step_translation_voxels=6 --max_rotation_deg=12 --max_translation_voxels=15 --sigma=15 --speckle_looks=4 --attenuation_db_per_cm=0.5 --gain_range=0.15 --offset_range=10" ;;
    us_flat) echo "--pose_model=walk --step_rotation_deg=6 --step_translation_voxels=6 --max_rotation_deg=12 --max_translation_voxels=15 --sigma=15 --speckle_looks=4" ;;
    *) echo "accuracy.sh: unknown protocol '$1' (paper, wide, walk, us, us_flat)" >&2; exit 2 ;;
  esac
}

mkdir -p "$out"
csvs=()
IFS=, read -ra source_list <<< "$sources"
IFS=, read -ra protocol_list <<< "$protocols"
IFS=, read -ra mask_list <<< "$masks"
for source in "${source_list[@]}"; do
  case "$source" in
    phantom) source_flag="" ;;
    mni) source_flag="--source=$mni" ;;
    *) echo "accuracy.sh: unknown source '$source' (phantom, mni)" >&2; exit 2 ;;
  esac
  for protocol in "${protocol_list[@]}"; do
    flags=$(protocol_flags "$protocol")
    folders=()
    for ((seed = 1; seed <= seeds; ++seed)); do
      dir="$out/sequences/$source/$protocol/seed$seed"
      if [[ ! -f "$dir/gt_poses.json" ]]; then
        # shellcheck disable=SC2086
        "$tools/dsr_simulate" --out_dir="$dir" --seed="$seed" --mask_erosion=0 $source_flag $flags \
          >/dev/null 2>"$out/simulate.log" || {
          echo "accuracy.sh: dsr_simulate failed for $dir: $(tail -n 1 "$out/simulate.log")" >&2; exit 1; }
      fi
      folders+=("$dir")
    done
    list=$(IFS=,; echo "${folders[*]}")
    for mask in "${mask_list[@]}"; do
      case "$mask" in fov) use=true ;; none) use=false ;;
        *) echo "accuracy.sh: unknown mask kind '$mask' (fov, none)" >&2; exit 2 ;; esac
      run="$out/runs/$init${uncertainty:+-uncertainty}/$source-$protocol-$mask"
      mkdir -p "$run"
      echo "accuracy.sh: $source $protocol masks=$mask init=$init ($seeds sequences)" >&2
      "$tools/dsr_compare" --out_dir="$run" --methods="$methods" --sequences="$list" \
        --sequence_masks="$use" --init="$init" $uncertainty 2>"$run.log" >/dev/null || {
        echo "accuracy.sh: dsr_compare failed, see $run.log" >&2; exit 1; }
      csvs+=("$source,$protocol,$mask,$run/results.csv")
    done
  done
done
summary="$out/accuracy_$init${uncertainty:+_uncertainty}.md"
python3 bench/accuracy_summary.py --init="$init" "${csvs[@]}" > "$summary"
cat "$summary"
echo "accuracy.sh: wrote $summary" >&2
