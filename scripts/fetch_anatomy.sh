#!/usr/bin/env bash
# Fetches a real anatomical volume the project did not make, for dsr_simulate --source= and
# the accuracy benchmark: the MNI ICBM152 2009a T1 template at 1 mm (197x233x189,
# skull-stripped; mni_icbm152_t1_tal_nlin_sym_09a), as shipped inside the nilearn wheel on
# PyPI. Writes it, rescaled to the simulator's 0..255 scale (scripts/anatomy_source.py), to
# the git-ignored cache
#   data/cache/mni152_t1.nii.gz
# and prints that path. Idempotent: an existing file whose content checksum matches is kept.
# On failure: one error line on stderr and exit 1.
#
# Licence: the template is "Copyright (C) 1993-2009 Louis Collins, McConnell Brain Imaging
# Centre, Montreal Neurological Institute, McGill University", free to use, copy, modify
# and distribute provided the copyright notice appears in all copies (README.md).
set -euo pipefail
cd "$(dirname "$0")/.."

readonly NILEARN_VERSION=0.14.1
readonly MEMBER=nilearn/datasets/data/mni_icbm152_t1_tal_nlin_sym_09a_converted.nii.gz
# sha256 of MEMBER as extracted from nilearn-0.14.1-py3-none-any.whl.
readonly MEMBER_SHA256=421a10e872fd6cadae7f61d358dffbcc1795a497d61ee76c5dda2503e1a1e9e6
readonly OUT=data/cache/mni152_t1.nii.gz
# sha256 of OUT decompressed (the NIfTI bytes): the gzip stream itself may differ between
# zlib builds, the volume must not.
readonly OUT_CONTENT_SHA256=f89c172e0a9558128043ae621d82327f3296197851a86001bf2a0c0589c52979

fail() {
  echo "fetch_anatomy.sh: error: $*" >&2
  exit 1
}
content_sha256() { gzip -dc "$1" 2>/dev/null | sha256sum | cut -d ' ' -f 1; }

if [ -f "$OUT" ] && [ "$(content_sha256 "$OUT")" = "$OUT_CONTENT_SHA256" ]; then
  echo "$PWD/$OUT"
  exit 0
fi

tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
py=$(bash scripts/python_env.sh 2>"$tmp/env.log") ||
  fail "scripts/python_env.sh could not set up the Python environment: $(tail -n 1 "$tmp/env.log")"
"$py" -m pip download --no-deps --only-binary=:all: --disable-pip-version-check -q \
  -d "$tmp/wheel" "nilearn==$NILEARN_VERSION" >"$tmp/pip.log" 2>&1 ||
  fail "pip download nilearn==$NILEARN_VERSION failed: $(tail -n 1 "$tmp/pip.log")"
wheel=$(find "$tmp/wheel" -name "nilearn-$NILEARN_VERSION-*.whl" | head -n 1)
[ -n "$wheel" ] || fail "pip download nilearn==$NILEARN_VERSION left no wheel"

mkdir -p "$(dirname "$OUT")" || fail "cannot create $(dirname "$OUT")"
partial="$(dirname "$OUT")/.partial_$$_$(basename "$OUT")"
"$py" scripts/anatomy_source.py "$wheel" "$MEMBER" "$MEMBER_SHA256" "$partial" 2>"$tmp/py.log" || {
  rm -f "$partial"
  fail "$( (grep -m 1 '^anatomy_source.py: error: ' "$tmp/py.log" || tail -n 1 "$tmp/py.log") |
    sed 's/^anatomy_source.py: error: //')"
}
got=$(content_sha256 "$partial")
if [ "$got" != "$OUT_CONTENT_SHA256" ]; then
  rm -f "$partial"
  fail "the rescaled volume has content sha256 $got, expected $OUT_CONTENT_SHA256" \
    "(another nibabel or numpy than scripts/python_env.sh installs?)"
fi
mv -f "$partial" "$OUT"
echo "$PWD/$OUT"
