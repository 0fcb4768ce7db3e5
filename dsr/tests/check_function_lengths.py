#!/usr/bin/env python3
"""The Style.NoFunctionOver80Lines test: no function in the given folders' sources (tests
left out) is longer than the limit, counted from the first line of its signature to its
closing brace. Functions at namespace scope only, as the code is laid out (Google style: a
definition starts at column 0 and ends with a '}' at column 0); data tables (an initializer
ending in '};') are not functions.

Usage: check_function_lengths.py LIMIT FOLDER...   (exit 1 listing each function over it)
"""
import pathlib
import re
import sys

_NOT_A_FUNCTION = re.compile(r"(namespace|struct|class|enum|union|extern|typedef|#|//)")


def long_functions(path, limit):
    lines = path.read_text().split("\n")
    found, start = [], None
    for i, line in enumerate(lines):
        if start is None:
            if (line and not line[0].isspace() and line.rstrip().endswith("{")
                    and not _NOT_A_FUNCTION.match(line) and "=" not in line.split("(")[0]):
                start = i
                # The signature's first line: back over its wrapped lines.
                while (start > 0 and lines[start - 1] and not lines[start - 1][0].isspace()
                       and not lines[start - 1].rstrip().endswith((";", "}", "{"))
                       and not _NOT_A_FUNCTION.match(lines[start - 1])):
                    start -= 1
        elif line.startswith("}"):
            length = i - start + 1
            if length > limit and not line.startswith("};"):
                found.append((length, f"{path}:{start + 1}", lines[start].strip()[:90]))
            start = None
    return found


def main(argv):
    limit, folders = int(argv[1]), argv[2:]
    found = []
    for folder in folders:
        for path in sorted(pathlib.Path(folder).rglob("*.cc")):
            if not path.name.endswith("_test.cc"):
                found += long_functions(path, limit)
    for length, where, signature in sorted(found, reverse=True):
        print(f"{where}: {length} lines (limit {limit}): {signature}")
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
