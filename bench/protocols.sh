# The simulation protocols of the accuracy benchmarks (sourced by bench/accuracy.sh and
# bench/elastix.sh, so that both register the same sequences). 11 frames of 96x96x80,
# noise sigma 25 unless a protocol says otherwise:
#   paper    +/-12 deg, +/-15 voxels (the paper's draws)
#   wide     +/-25 deg, +/-20 voxels
#   walk     each frame within 6 deg / 6 voxels of the previous one
#   us       walk with ultrasound-like effects: noise sigma 15, speckle of 4 looks of which a
#            fraction 0.8 follows the tissue (frames' speckle correlates by 0.64 at a world
#            point; docs/design.md 6.6), 0.5 dB/cm attenuation, per-frame gain within
#            +/-15 % and offset within +/-10
#   us_flat  the same sequences (same poses, noise and speckle) without the gain, offset
#            and attenuation
#   us_gain  the same sequences with the gain and offset but without the attenuation (which
#            no per-frame gain and offset can undo: it varies with depth)
#   echo     us with the echo-like mapping of the source (--intensity_mapping=echo,
#            docs/design.md 6.6): dark regions (blood, lungs, CSF) black, tissue bright,
#            interfaces brighter, on every source, so large black regions lie inside the
#            fields of view and touch their borders
#   echo_flat  the same sequences (same seed: same poses, noise and speckle) without the
#            gain, offset and attenuation
#   echo_real  echo with what real 3D TEE has besides (docs/design.md 6.7): dropout wedges of
#            20-40 % of the azimuth in about a third of the views, interfaces +-25 % brighter
#            with their angle to the beam, acoustic shadows behind bright reflectors
#            (strength 0.3 above grey level 200) and a lateral blur of 2 mm (standard
#            deviation) at full depth
#   echo_dropout, echo_angle, echo_shadow, echo_psf  echo with one of those four alone
# protocol_flags NAME prints its dsr_simulate flags; an unknown name returns 1.
protocol_names="paper, wide, walk, us, us_flat, us_gain, echo, echo_flat, echo_real, echo_dropout, echo_angle, echo_shadow, echo_psf"
protocol_flags() {
  local walk="--pose_model=walk --step_rotation_deg=6 --step_translation_voxels=6 --max_rotation_deg=12 --max_translation_voxels=15"
  local dropout="--dropout_fraction=0.4 --dropout_view_fraction=0.33" angle="--echogenicity_range=0.25"
  local shadow="--shadow_strength=0.3 --shadow_threshold=200" psf="--psf_lateral_mm=2"
  case "$1" in
    paper) echo "--max_rotation_deg=12 --max_translation_voxels=15" ;;
    wide) echo "--max_rotation_deg=25 --max_translation_voxels=20" ;;
    walk) echo "$walk" ;;
    us) echo "$walk --sigma=15 --speckle_looks=4 --speckle_world_fraction=0.8 --attenuation_db_per_cm=0.5 --gain_range=0.15 --offset_range=10" ;;
    us_flat) echo "$walk --sigma=15 --speckle_looks=4 --speckle_world_fraction=0.8" ;;
    us_gain) echo "$walk --sigma=15 --speckle_looks=4 --speckle_world_fraction=0.8 --gain_range=0.15 --offset_range=10" ;;
    echo) echo "$walk --sigma=15 --speckle_looks=4 --speckle_world_fraction=0.8 --attenuation_db_per_cm=0.5 --gain_range=0.15 --offset_range=10 --intensity_mapping=echo" ;;
    echo_flat) echo "$walk --sigma=15 --speckle_looks=4 --speckle_world_fraction=0.8 --intensity_mapping=echo" ;;
    echo_real) echo "$(protocol_flags echo) $dropout $angle $shadow $psf" ;;
    echo_dropout) echo "$(protocol_flags echo) $dropout" ;;
    echo_angle) echo "$(protocol_flags echo) $angle" ;;
    echo_shadow) echo "$(protocol_flags echo) $shadow" ;;
    echo_psf) echo "$(protocol_flags echo) $psf" ;;
    *) return 1 ;;
  esac
}

# simulate_sequence TOOLS DIR SEED FLAGS... simulates one cached sequence into DIR unless DIR
# already holds it with the same dsr_simulate flags (DIR/simulate_flags.txt), so a changed
# protocol never reuses stale frames: DIR, the script's own cache, is then replaced. The
# log of a failed run is DIR.log. Returns dsr_simulate's status.
simulate_sequence() {
  local tools="$1" dir="$2" seed="$3"
  shift 3
  local want="--seed=$seed --mask_erosion=0 $*"
  if [[ -f "$dir/gt_poses.json" && "$(cat "$dir/simulate_flags.txt" 2>/dev/null)" == "$want" ]]; then
    return 0
  fi
  rm -rf "$dir"
  mkdir -p "$(dirname "$dir")"
  # shellcheck disable=SC2086
  "$tools/dsr_simulate" --out_dir="$dir" $want >/dev/null 2>"$dir.log" || return 1
  echo "$want" > "$dir/simulate_flags.txt"
}

