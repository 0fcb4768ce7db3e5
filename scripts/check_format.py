#!/usr/bin/env python3
"""The C++ style checks of scripts/lint.sh: no line of a tracked C++ file over 100 columns,
and every C++ line added or changed since BASE laid out as the repository's .clang-format
says (clang-format on those lines only: the code before BASE was laid out by hand, and
clang-format would re-break some of it). A file moved since BASE counts only its changed
lines (renames are followed). The working tree counts, so uncommitted lines are checked too,
and files git does not track yet count whole.

Usage: check_format.py BASE [CLANG_FORMAT]
       check_format.py --columns-only   (the column rule alone, where no base is known)
Exit 0 when clean; 1 listing each file and line otherwise (fix with `git clang-format BASE`);
2 when BASE is not a commit of this clone.
"""
import re
import subprocess
import sys

COLUMNS = 100
_CPP = re.compile(r"\.(cc|h|inc)$")
_FILE = re.compile(r"^\+\+\+ b/(.+)$")
_HUNK = re.compile(r"^@@ -\d+(?:,\d+)? \+(\d+)(?:,(\d+))? @@")


def changed_lines(patch):
    """{path: [(first, last), ...]} of the lines a `git diff -U0` patch adds or changes, in
    the new files' numbering; hunks that only delete lines add nothing."""
    ranges, path = {}, None
    for line in patch.splitlines():
        file_match = _FILE.match(line)
        if file_match:
            path = file_match.group(1)
            continue
        if line.startswith("+++ /dev/null"):
            path = None
            continue
        hunk = _HUNK.match(line)
        if hunk and path is not None:
            first = int(hunk.group(1))
            count = 1 if hunk.group(2) is None else int(hunk.group(2))
            if count > 0:
                ranges.setdefault(path, []).append((first, first + count - 1))
    return ranges


def long_lines(paths, read=lambda p: open(p, encoding="utf-8", errors="replace").read()):
    """'path:line: N columns' for every line over COLUMNS characters."""
    found = []
    for path in paths:
        for number, line in enumerate(read(path).splitlines(), 1):
            if len(line) > COLUMNS:
                found.append(f"{path}:{number}: {len(line)} columns (at most {COLUMNS})")
    return found


def git(*args):
    return subprocess.run(["git", *args], check=True, capture_output=True, text=True).stdout


def main(argv):
    if len(argv) not in (2, 3):
        sys.exit(__doc__)
    if argv[1] == "--columns-only":
        tracked = [p for p in git("ls-files").splitlines() if _CPP.search(p)]
        problems = long_lines(tracked)
        print("\n".join(problems) or f"check_format.py: {len(tracked)} C++ files within "
              f"{COLUMNS} columns")
        return 1 if problems else 0
    base, clang_format = argv[1], argv[2] if len(argv) == 3 else "clang-format"
    if subprocess.run(["git", "cat-file", "-e", base + "^{commit}"],
                      capture_output=True).returncode != 0:
        print(f"check_format.py: {base} is not a commit of this clone (a shallow clone? "
              "fetch its history, or set DSR_LINT_BASE)", file=sys.stderr)
        return 2
    tracked = [p for p in git("ls-files").splitlines() if _CPP.search(p)]
    # Files git does not track yet (and does not ignore) are new: every line counts.
    untracked = [p for p in git("ls-files", "--others", "--exclude-standard").splitlines()
                 if _CPP.search(p)]
    problems = long_lines(tracked + untracked)
    patch = git("diff", "-M", "-U0", "--no-color", "--diff-filter=AMR", base, "--",
                "*.cc", "*.h", "*.inc")
    changed = changed_lines(patch)
    for path in untracked:
        with open(path, encoding="utf-8", errors="replace") as f:
            changed[path] = [(1, max(1, len(f.read().splitlines())))]
    for path, spans in sorted(changed.items()):
        lines = [f"--lines={first}:{last}" for first, last in spans]
        run = subprocess.run([clang_format, "--dry-run", "-Werror", "--style=file", *lines,
                              path], capture_output=True, text=True)
        if run.returncode != 0:
            places = sorted({m.group(1) for m in re.finditer(
                rf"^{re.escape(path)}:(\d+):\d+: error", run.stderr, re.M)}, key=int)
            problems += [f"{path}:{place}: not laid out as .clang-format says"
                         for place in places or ["?"]]
    if problems:
        print("\n".join(problems))
        print(f"check_format.py: {len(problems)} problem(s); `git clang-format {base}` lays "
              "out the changed lines", file=sys.stderr)
        return 1
    print(f"check_format.py: {len(tracked) + len(untracked)} C++ files within {COLUMNS} "
          f"columns; the lines changed since {base[:12]} in {len(changed)} files as "
          ".clang-format says")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
