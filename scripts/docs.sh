#!/usr/bin/env bash
# Builds the docs site (MkDocs, mkdocs.yml) from docs/ into build/site/ or the folder given:
#   bash scripts/docs.sh [OUTPUT_DIR]
# The pages are staged: docs/ is copied into build/docs-src/ (mkdocs.yml's docs_dir), and
# the option reference, build/docs-src/options.md, is generated there by docs/gen_options.py
# from the options table that `build/tools/dsr_options --format=json` prints (the C++ build
# makes that tool; this script compiles nothing). Nothing generated lands in docs/. Then
# `mkdocs build --strict`: any warning (a link to a missing page or anchor, a page left out
# of the navigation) fails the script. MkDocs and the rest, pinned in docs/requirements.txt,
# go into .venv-docs; gen_options.py's tests (docs/gen_options_test.py) run first.
# DSR_OPTIONS_JSON=FILE takes the options table from FILE instead of the tool; DSR_BUILD_DIR
# is the build folder the tool is taken from (default build). Called by scripts/test.sh.
set -euo pipefail
out=$(realpath -m "${1:-build/site}")
options_json=${DSR_OPTIONS_JSON:+$(realpath -m "$DSR_OPTIONS_JSON")}
cd "$(dirname "$0")/.."
dsr_options="${DSR_BUILD_DIR:-build}/tools/dsr_options"
if [[ -z "$options_json" && ! -x "$dsr_options" ]]; then
  echo "docs: $dsr_options is missing (bash scripts/build.sh builds it):" \
    "the option reference is generated from its output" >&2
  exit 1
fi
if ! python3 -m venv --help >/dev/null 2>&1 || ! python3 -c "import ensurepip" >/dev/null 2>&1; then
  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq python3-venv >/dev/null
fi
python=.venv-docs/bin/python
if [[ ! -x "$python" ]] || ! cmp -s docs/requirements.txt .venv-docs/requirements.txt; then
  rm -rf .venv-docs
  python3 -m venv .venv-docs
  "$python" -m pip install -q --disable-pip-version-check -r docs/requirements.txt
  cp docs/requirements.txt .venv-docs/requirements.txt
fi
"$python" -m unittest -q docs/gen_options_test.py
stage=build/docs-src
rm -rf "$stage"
mkdir -p build
cp -r docs "$stage"
if [[ -z "$options_json" ]]; then
  options_json=build/docs-options.json
  if ! "$dsr_options" --format=json >"$options_json"; then
    echo "docs: $dsr_options --format=json failed" >&2
    exit 1
  fi
fi
"$python" docs/gen_options.py "$options_json" --out "$stage/options.md"
if ! log=$("$python" -m mkdocs build --strict --site-dir "$out" 2>&1); then
  echo "$log" >&2
  echo "docs: the strict build failed (above)" >&2
  exit 1
fi
echo "docs: site in $out"
