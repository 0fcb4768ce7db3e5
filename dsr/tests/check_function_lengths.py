#!/usr/bin/env python3
"""The Style.NoFunctionOver80Lines test: no function in the given folders' sources (tests
left out) is longer than the limit, counted from the first line of its signature to its
closing brace. A definition at namespace scope starts at column 0 (Google style, namespaces
not indented); its body is found by matching braces, outside comments, strings and
character literals. Class bodies, namespaces, enums and data tables (an initializer
ending in '};') are not functions; member functions defined inside a class are counted with
the class's own rules only when they are defined outside it.

Usage: check_function_lengths.py LIMIT FOLDER...   (exit 1 listing each function over it)
"""
import pathlib
import re
import sys

_NOT_A_FUNCTION = re.compile(r"(namespace|struct|class|enum|union|extern|typedef|"
                             r"template\s*<[^>]*>\s*(struct|class)|#|//|\}|using)")
_CODE = re.compile(r'//.*|"(?:\\.|[^"\\])*"|\'(?:\\.|[^\'\\])*\'')


def code_only(line):
    """The line without comments and the contents of string and character literals."""
    return _CODE.sub(lambda m: "" if m.group(0).startswith("//") else '""', line)


def long_functions(path, limit):
    lines = [code_only(line) for line in path.read_text().split("\n")]
    found, i = [], 0
    while i < len(lines):
        line = lines[i]
        if not line or line[0].isspace() or _NOT_A_FUNCTION.match(line) or "(" not in line:
            i += 1
            continue
        # A signature: scan to its body's '{' (or a ';' or '=': a declaration or data).
        j, opening = i, None
        while j < len(lines) and j < i + 20:
            text = lines[j]
            k = min([p for p in (text.find("{"), text.find(";")) if p >= 0], default=-1)
            if k >= 0:
                opening = (j, k) if text[k] == "{" else None
                break
            j += 1
        if opening is None or "=" in lines[i].split("(")[0]:
            i = j + 1
            continue
        depth, end = 0, None
        for n in range(opening[0], len(lines)):
            start_col = opening[1] if n == opening[0] else 0
            for c in lines[n][start_col:]:
                depth += c == "{"
                depth -= c == "}"
                if depth == 0:
                    end = n
                    break
            if end is not None:
                break
        if end is None:
            break
        length = end - i + 1
        if length > limit and not lines[end].lstrip().startswith("};"):
            found.append((length, f"{path}:{i + 1}", path.read_text().split("\n")[i].strip()[:90]))
        i = end + 1
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
