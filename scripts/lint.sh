#!/usr/bin/env bash
# The style checks CI runs (scripts/test.sh), each quick:
#  - C++: no line of a tracked file over 100 columns, and every line added or changed since
#    the base laid out as .clang-format says (scripts/check_format.py; clang-format from
#    Debian). The code before the base was laid out by hand and stays as it is.
#  - Python: ruff (pinned, from PyPI, in .venv) with ruff.toml over the whole tree.
#  - Commits: each subject since the base under 72 characters (the detail goes in the body).
# The base: $DSR_LINT_BASE, or the commit .ci/lint_base names (the commit before these checks
# began: its hash on the first line, its subject on the second, by which it is found where
# the history was rewritten since). Where neither is in this clone's history (a shallow or
# squashed clone), the checks that need a base are skipped with a notice. Install steps run
# here, so a fresh Debian machine needs nothing else.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install_deps.sh clang-format git
python=$(bash scripts/python_env.sh)
if ! "$python" -m ruff --version 2>/dev/null | grep -qx "ruff 0.8.4"; then
  "$python" -m pip install -q --disable-pip-version-check "ruff==0.8.4" >&2
fi
base=${DSR_LINT_BASE:-}
if [[ -z "$base" ]]; then
  base=$(sed -n 1p .ci/lint_base)
  if ! git cat-file -e "$base^{commit}" 2>/dev/null; then
    subject=$(sed -n 2p .ci/lint_base)
    base=$(git log --format='%H %s' |
           awk -v s="$subject" '!found && substr($0, 42) == s { print $1; found = 1 }')
  fi
fi
python3 scripts/check_format_test.py
"$python" -m ruff check --quiet .
echo "lint: ruff finds nothing"
if [[ -z "$base" ]] || ! git cat-file -e "$base^{commit}" 2>/dev/null; then
  echo "lint: the base commit of .ci/lint_base is not in this clone's history: the C++" \
       "layout of changed lines and the commit subjects are not checked" >&2
  python3 scripts/check_format.py --columns-only
  exit 0
fi
python3 scripts/check_format.py "$base"
long=$(git log --format=%s "$base..HEAD" | awk 'length >= 72')
if [[ -n "$long" ]]; then
  echo "lint: commit subjects of 72 characters or more since ${base:0:12} (keep the subject" \
       "short, the detail in the body):" >&2
  echo "$long" >&2
  exit 1
fi
echo "lint: $(git rev-list --count "$base..HEAD") commit subjects since ${base:0:12} under 72" \
     "characters"
