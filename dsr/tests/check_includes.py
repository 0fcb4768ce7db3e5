#!/usr/bin/env python3
"""The Includes.ResolveInTheSourceTree test: every #include "dsr/..." in the sources names a
file that exists under the repository's root, so that grep, editors and code-reading tools
follow every include in a fresh clone, without a build.

Usage: check_includes.py ROOT   (exit 1 listing each include that names no file)
"""
import pathlib
import re
import sys

_INCLUDE = re.compile(r'^\s*#\s*include\s+"(dsr/[^"]+)"', re.M)


def main(argv):
    root = pathlib.Path(argv[1])
    missing, count = [], 0
    for folder in ("dsr", "python", "bench"):
        for path in sorted((root / folder).rglob("*")):
            if path.suffix not in (".cc", ".h", ".inc") or not path.is_file():
                continue
            if path.relative_to(root).parts[:2] == ("bench", "results"):
                continue  # the benchmarks' outputs (bench/speed_ab.sh builds other commits there)
            for included in _INCLUDE.findall(path.read_text(errors="replace")):
                count += 1
                if not (root / included).is_file():
                    missing.append(f"{path.relative_to(root)}: #include \"{included}\"")
    print("\n".join(missing) or f"{count} includes, every one a file under {root}")
    return 1 if missing or count == 0 else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
