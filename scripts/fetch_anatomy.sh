#!/usr/bin/env bash
# Fetches a real anatomical volume the project did not make, for dsr_simulate --source= and
# the accuracy benchmark, and prints its path:
#
#   bash scripts/fetch_anatomy.sh [mni|ct]      (default: mni)
#
# mni: the MNI ICBM152 2009a T1 template at 1 mm (197x233x189, skull-stripped;
#      mni_icbm152_t1_tal_nlin_sym_09a), as shipped inside the nilearn 0.14.1 wheel on PyPI,
#      rescaled to the simulator's 0..255 scale (scripts/anatomy_source.py):
#      data/cache/mni152_t1.nii.gz
# ct:  a chest CT with the heart in view (pyradiomics' test case lung2: 512x512x61 at
#      0.63x0.63x5 mm), as shipped in the pyradiomics 3.1.0 source archive on PyPI, cut to a
#      box on the heart with a soft-tissue window, the lungs dark (scripts/ct_source.py):
#      data/cache/chest_ct.nii.gz. Its slices are 5 mm apart: simulate 1 mm frames from it
#      (dsr_simulate --frame_spacing=1), as bench/accuracy.sh does.
#
# Both downloads and both results are pinned by sha256. Idempotent: an existing file whose
# content checksum matches is kept. On failure: one error line on stderr and exit 1.
#
# Licences: the MNI template is "Copyright (C) 1993-2009 Louis Collins, McConnell Brain
# Imaging Centre, Montreal Neurological Institute, McGill University", free to use, copy,
# modify and distribute provided the copyright notice appears in all copies; pyradiomics and
# its test data are under the BSD 3-clause licence (README.md).
set -euo pipefail
cd "$(dirname "$0")/.."

fail() {
  echo "fetch_anatomy.sh: error: $*" >&2
  exit 1
}
content_sha256() { gzip -dc "$1" 2>/dev/null | sha256sum | cut -d ' ' -f 1; }

source_name=${1:-mni}
case "$source_name" in
  mni)
    readonly NILEARN_VERSION=0.14.1
    readonly MEMBER=nilearn/datasets/data/mni_icbm152_t1_tal_nlin_sym_09a_converted.nii.gz
    # sha256 of MEMBER as extracted from nilearn-0.14.1-py3-none-any.whl.
    readonly MEMBER_SHA256=421a10e872fd6cadae7f61d358dffbcc1795a497d61ee76c5dda2503e1a1e9e6
    readonly OUT=data/cache/mni152_t1.nii.gz
    # sha256 of OUT decompressed (the NIfTI bytes): the gzip stream itself may differ between
    # zlib builds, the volume must not.
    readonly OUT_CONTENT_SHA256=f89c172e0a9558128043ae621d82327f3296197851a86001bf2a0c0589c52979
    readonly CUT=scripts/anatomy_source.py
    ;;
  ct)
    # The source archive is fetched by its address on PyPI's file host (pip would try to
    # build it to read its metadata), so both the archive and the member are pinned.
    readonly SDIST_URL=https://files.pythonhosted.org/packages/03/c1/20fc2c50ab1e3304da36d866042a1905a2b05a1431ece35448ab6b4578f2/pyradiomics-3.1.0.tar.gz
    readonly SDIST_SHA256=24722c962a6bbd09bc39c1c67dbffe92435f9692a421fabaae8a6b4511eb48e4
    readonly MEMBER=pyradiomics-3.1.0/data/lung2_image.nrrd
    readonly MEMBER_SHA256=aa2b94eec79127ed786798ac8dc3c013010e1692d5787bebfae1a1e9685a4651
    readonly OUT=data/cache/chest_ct.nii.gz
    readonly OUT_CONTENT_SHA256=f290e3c49dcce592b6d2e1f0331610a07cb96af7fe8524f370bd1285d0d9be0c
    readonly CUT=scripts/ct_source.py
    ;;
  *) fail "unknown source '$source_name' (mni, ct)" ;;
esac

if [ -f "$OUT" ] && [ "$(content_sha256 "$OUT")" = "$OUT_CONTENT_SHA256" ]; then
  echo "$PWD/$OUT"
  exit 0
fi

tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
py=$(bash scripts/python_env.sh 2>"$tmp/env.log") ||
  fail "scripts/python_env.sh could not set up the Python environment: $(tail -n 1 "$tmp/env.log")"
if [ "$source_name" = mni ]; then
  "$py" -m pip download --no-deps --only-binary=:all: --disable-pip-version-check -q \
    -d "$tmp/wheel" "nilearn==$NILEARN_VERSION" >"$tmp/pip.log" 2>&1 ||
    fail "pip download nilearn==$NILEARN_VERSION failed: $(tail -n 1 "$tmp/pip.log")"
  archive=$(find "$tmp/wheel" -name "nilearn-$NILEARN_VERSION-*.whl" | head -n 1)
  [ -n "$archive" ] || fail "pip download nilearn==$NILEARN_VERSION left no wheel"
else
  archive="$tmp/$(basename "$SDIST_URL")"
  "$py" -c 'import sys, urllib.request; urllib.request.urlretrieve(sys.argv[1], sys.argv[2])' \
    "$SDIST_URL" "$archive" 2>"$tmp/get.log" ||
    fail "cannot download $SDIST_URL: $(tail -n 1 "$tmp/get.log")"
  got=$(sha256sum "$archive" | cut -d ' ' -f 1)
  [ "$got" = "$SDIST_SHA256" ] || fail "$SDIST_URL has sha256 $got, expected $SDIST_SHA256"
fi

mkdir -p "$(dirname "$OUT")" || fail "cannot create $(dirname "$OUT")"
partial="$(dirname "$OUT")/.partial_$$_$(basename "$OUT")"
"$py" "$CUT" "$archive" "$MEMBER" "$MEMBER_SHA256" "$partial" 2>"$tmp/py.log" || {
  rm -f "$partial"
  fail "$( (grep -m 1 ': error: ' "$tmp/py.log" || tail -n 1 "$tmp/py.log") |
    sed 's/^[a-z_]*\.py: error: //')"
}
got=$(content_sha256 "$partial")
if [ "$got" != "$OUT_CONTENT_SHA256" ]; then
  rm -f "$partial"
  fail "the cut volume has content sha256 $got, expected $OUT_CONTENT_SHA256" \
    "(another nibabel or numpy than scripts/python_env.sh installs?)"
fi
mv -f "$partial" "$OUT"
echo "$PWD/$OUT"
