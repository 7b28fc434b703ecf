#!/usr/bin/env python3
"""The production functions whose bodies run longer than a limit, longest first.

Usage: scripts/long_functions.py [--limit N] [DIR ...]

DIRs default to every crate's `src/` (and `build.rs`) under crates/ and fuzz/. A body's
lines are those between its braces, blank and comment lines included. Test code is left
out: files named `tests.rs` or `*_tests.rs`, and `#[cfg(test)]` items. Exits 1 when a
function is over the limit (default 100).
"""

import glob
import os
import re
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from module_cycles import drop_cfg_test_items, strip_comments_and_strings  # noqa: E402


def rust_files(dirs):
    for d in dirs:
        if os.path.isfile(d):
            yield d
            continue
        for root, _, files in os.walk(d):
            for f in sorted(files):
                if f.endswith(".rs") and f != "tests.rs" and not f.endswith("_tests.rs"):
                    yield os.path.join(root, f)


def functions(code):
    """(name, first body line, body line count) of every fn with a body in `code`."""
    for m in re.finditer(r"\bfn\s+(\w+)", code):
        j, depth = m.end(), 0
        # The body opens at the first `{` outside the signature's brackets; a `;` first
        # means a declaration without a body.
        while j < len(code):
            ch = code[j]
            if ch in "([":
                depth += 1
            elif ch in ")]":
                depth -= 1
            elif depth == 0 and ch == ";":
                j = -1
                break
            elif depth == 0 and ch == "{":
                break
            j += 1
        if j < 0 or j >= len(code):
            continue
        open_at, depth, k = j, 0, j
        while k < len(code):
            if code[k] == "{":
                depth += 1
            elif code[k] == "}":
                depth -= 1
                if depth == 0:
                    break
            k += 1
        first = code.count("\n", 0, open_at) + 1
        last = code.count("\n", 0, k) + 1
        yield m.group(1), first, max(0, last - first - 1)


def main():
    args = sys.argv[1:]
    limit = 100
    if "--limit" in args:
        i = args.index("--limit")
        limit = int(args[i + 1])
        del args[i : i + 2]
    dirs = args or sorted(glob.glob("crates/*/src") + glob.glob("fuzz/*/src")) + sorted(
        glob.glob("crates/*/build.rs")
    )
    long = []
    for path in rust_files(dirs):
        code = drop_cfg_test_items(strip_comments_and_strings(open(path, encoding="utf-8").read()))
        for name, line, body in functions(code):
            if body > limit:
                long.append((body, f"{path}:{line}", name))
    for body, where, name in sorted(long, key=lambda t: (-t[0], t[1])):
        print(f"{body:5} {where} {name}")
    print(f"{len(long)} functions with bodies over {limit} lines")
    return 1 if long else 0


if __name__ == "__main__":
    sys.exit(main())
