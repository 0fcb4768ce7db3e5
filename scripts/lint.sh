#!/usr/bin/env bash
# The style checks CI runs (scripts/test.sh), each quick:
#  - C++: no line of a tracked file over 100 columns, and every line added or changed since
#    the base laid out as .clang-format says (scripts/check_format.py; clang-format from
#    Debian). The code before the base was laid out by hand and stays as it is.
#  - Python: ruff (pinned, from PyPI, in .venv) with ruff.toml over the whole tree.
#  - Commits: each subject since the base under 72 characters (the detail goes in the body).
# The base: $DSR_LINT_BASE, or the commit .ci/lint_base names (the commit before these checks
# began). Install steps run here, so a fresh Debian machine needs nothing else.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install_deps.sh clang-format git
python=$(bash scripts/python_env.sh)
if ! "$python" -m ruff --version 2>/dev/null | grep -qx "ruff 0.8.4"; then
  "$python" -m pip install -q --disable-pip-version-check "ruff==0.8.4" >&2
fi
base=${DSR_LINT_BASE:-$(tr -d '[:space:]' < .ci/lint_base)}
python3 scripts/check_format_test.py
python3 scripts/check_format.py "$base"
"$python" -m ruff check --quiet .
echo "lint: ruff finds nothing"
long=$(git log --format=%s "$base..HEAD" | awk 'length >= 72')
if [[ -n "$long" ]]; then
  echo "lint: commit subjects of 72 characters or more since ${base:0:12} (keep the subject" \
       "short, the detail in the body):" >&2
  echo "$long" >&2
  exit 1
fi
echo "lint: $(git rev-list --count "$base..HEAD") commit subjects since ${base:0:12} under 72" \
     "characters"
