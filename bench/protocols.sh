# The simulation protocols of the accuracy benchmarks (sourced by bench/accuracy.sh and
# bench/elastix.sh, so that both register the same sequences). 11 frames of 96x96x80,
# noise sigma 25 unless a protocol says otherwise:
#   paper    +/-12 deg, +/-15 voxels (the paper's draws)
#   wide     +/-25 deg, +/-20 voxels
#   walk     each frame within 6 deg / 6 voxels of the previous one
#   us       walk with ultrasound-like effects (issue 21): noise sigma 15, speckle of 4 looks,
#            0.5 dB/cm attenuation, per-frame gain within +/-15 % and offset within +/-10
#   us_flat  the same sequences (same poses, noise and speckle) without the gain, offset
#            and attenuation
# protocol_flags NAME prints its dsr_simulate flags; an unknown name returns 1.
protocol_names="paper, wide, walk, us, us_flat"
protocol_flags() {
  local walk="--pose_model=walk --step_rotation_deg=6 --step_translation_voxels=6 --max_rotation_deg=12 --max_translation_voxels=15"
  case "$1" in
    paper) echo "--max_rotation_deg=12 --max_translation_voxels=15" ;;
    wide) echo "--max_rotation_deg=25 --max_translation_voxels=20" ;;
    walk) echo "$walk" ;;
    us) echo "$walk --sigma=15 --speckle_looks=4 --attenuation_db_per_cm=0.5 --gain_range=0.15 --offset_range=10" ;;
    us_flat) echo "$walk --sigma=15 --speckle_looks=4" ;;
    *) return 1 ;;
  esac
}
