#!/usr/bin/env python3
"""The longest functions of a crate's sources, by lines from `fn` to its closing brace.

    python3 scripts/long-functions.py                       # the runner, functions over 100 lines
    python3 scripts/long-functions.py crates/magcal-core 80 # another crate, another limit

Exits 1 when a function outside `#[cfg(test)]` modules is longer than the limit. Counts braces
outside strings, characters and comments, which is enough for rustfmt-formatted code.
"""
import pathlib
import re
import sys

FN = re.compile(r"^\s*(?:pub(?:\([a-z]+\))?\s+)?(?:const\s+)?(?:async\s+)?(?:unsafe\s+)?fn\s+([A-Za-z0-9_]+)")
STRIP = re.compile(r'//.*$|"(?:\\.|[^"\\])*"|\'(?:\\.|[^\'\\])\'')


def functions(path):
    lines = path.read_text().splitlines()
    test_depth = None
    depth = 0
    open_fns = []  # (name, start line, depth at which its body opened)
    pending_test = False
    for i, line in enumerate(lines, 1):
        code = STRIP.sub("", line)
        if "#[cfg(test)]" in line:
            pending_test = True
        m = FN.match(code)
        if m and not code.rstrip().endswith(";"):
            open_fns.append((m.group(1), i, depth, test_depth is not None))
        for ch in code:
            if ch == "{":
                depth += 1
                if pending_test and test_depth is None:
                    test_depth = depth
                    pending_test = False
            elif ch == "}":
                if open_fns and depth == open_fns[-1][2] + 1:
                    name, start, _, in_test = open_fns.pop()
                    yield name, start, i - start + 1, in_test
                if test_depth is not None and depth == test_depth:
                    test_depth = None
                depth -= 1


def main():
    root = pathlib.Path(sys.argv[1] if len(sys.argv) > 1 else "crates/magcal-runner") / "src"
    limit = int(sys.argv[2]) if len(sys.argv) > 2 else 100
    found = []
    for path in sorted(root.rglob("*.rs")):
        for name, start, length, in_test in functions(path):
            if not in_test:
                found.append((length, f"{path}:{start}", name))
    found.sort(reverse=True)
    for length, where, name in found[:15]:
        print(f"{length:5} {where} {name}")
    over = [f for f in found if f[0] > limit]
    print(f"{len(found)} functions; {len(over)} over {limit} lines")
    return 1 if over else 0


if __name__ == "__main__":
    sys.exit(main())
