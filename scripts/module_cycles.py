#!/usr/bin/env python3
"""Which top-level modules of a crate use which others through `crate::`, and the cycles.

Usage: scripts/module_cycles.py [SRC_DIR] [--tests] [--edges]

SRC_DIR defaults to crates/pfslam/src. Comments (doc comments and their intra-doc links
included) and string literals are ignored. Test code (files named `tests.rs` or `*_tests.rs`,
`#[cfg(test)]` items) is left out unless `--tests` is given. A path through the crate root's
re-exports (`crate::Config`) counts as a use of the module `lib.rs` re-exports it from.
`--edges` prints, for each edge that is part of a cycle, the places that make it.
Exits 1 when there is a cycle.
"""

import os
import re
import sys
from collections import defaultdict


def strip_comments_and_strings(text):
    """The text with comments and string/char literals blanked (newlines kept, so line
    numbers stay)."""
    out = []
    i, n = 0, len(text)
    while i < n:
        c = text[i]
        if text.startswith("//", i):
            j = text.find("\n", i)
            j = n if j < 0 else j
            out.append(" " * (j - i))
            i = j
        elif text.startswith("/*", i):
            depth, j = 1, i + 2
            while j < n and depth:
                if text.startswith("/*", j):
                    depth, j = depth + 1, j + 2
                elif text.startswith("*/", j):
                    depth, j = depth - 1, j + 2
                else:
                    j += 1
            out.append(re.sub(r"[^\n]", " ", text[i:j]))
            i = j
        elif c == "r" and re.match(r'r#*"', text[i:]) and not re.match(r"\w", text[i - 1 : i] or " "):
            m = re.match(r'r(#*)"', text[i:])
            end = text.find('"' + m.group(1), i + len(m.group(0)))
            j = n if end < 0 else end + 1 + len(m.group(1))
            out.append(re.sub(r"[^\n]", " ", text[i:j]))
            i = j
        elif c == '"':
            j = i + 1
            while j < n and text[j] != '"':
                j += 2 if text[j] == "\\" else 1
            j += 1
            out.append(re.sub(r"[^\n]", " ", text[i:j]))
            i = j
        elif c == "'":
            # A char literal ('a', '\n', '\u{..}'), not a lifetime ('a).
            m = re.match(r"'(\\u\{[0-9a-fA-F]+\}|\\.|[^\\'])'", text[i:])
            if m:
                out.append(" " * len(m.group(0)))
                i += len(m.group(0))
            else:
                out.append(c)
                i += 1
        else:
            out.append(c)
            i += 1
    return "".join(out)


def drop_cfg_test_items(code):
    """Blanks each item that follows `#[cfg(test)]` (a `mod x { .. }` block, a `mod x;`, a
    fn or an impl), keeping newlines."""
    chars = list(code)
    for m in re.finditer(r"#\[cfg\(test\)\]", code):
        j = m.end()
        # The item ends at the first `;` before any `{`, or at the `{`'s matching `}`.
        depth = 0
        while j < len(code):
            ch = code[j]
            if ch == ";" and depth == 0:
                j += 1
                break
            if ch == "{":
                depth += 1
            elif ch == "}":
                depth -= 1
                if depth == 0:
                    j += 1
                    break
            j += 1
        for k in range(m.start(), j):
            if chars[k] != "\n":
                chars[k] = " "
    return "".join(chars)


def top_level_modules(src):
    mods = {}
    for name in sorted(os.listdir(src)):
        path = os.path.join(src, name)
        if name.endswith(".rs") and name not in ("lib.rs", "main.rs"):
            mods.setdefault(name[:-3], []).append(path)
        elif os.path.isdir(path):
            mods.setdefault(name, [])
            for root, _, files in os.walk(path):
                mods[name] += [os.path.join(root, f) for f in files if f.endswith(".rs")]
    return mods


def root_reexports(src, mods):
    """`pub use X::...` in lib.rs: the names at the crate root and the module they come from."""
    names = {}
    lib = os.path.join(src, "lib.rs")
    if not os.path.exists(lib):
        return names
    code = strip_comments_and_strings(open(lib, encoding="utf-8").read())
    for m in re.finditer(r"pub\s+use\s+(\w+)::([^;]*);", code):
        module, rest = m.group(1), m.group(2)
        if module not in mods:
            continue
        for ident in re.findall(r"\b(\w+)\b", rest):
            names[ident] = module
    return names


def paths_after_crate(code):
    """(offset, first segment) for every `crate::seg` and every top-level name of a
    `crate::{a, b::c}` group."""
    for m in re.finditer(r"\bcrate\s*::\s*", code):
        j = m.end()
        if j < len(code) and code[j] == "{":
            depth, k, start = 1, j + 1, j + 1
            while k < len(code) and depth:
                if code[k] == "{":
                    depth += 1
                elif code[k] == "}":
                    depth -= 1
                k += 1
            # The top-level entries of the group: split on commas at depth 0.
            body, depth, entry_start = code[start : k - 1], 0, 0
            for idx, ch in enumerate(body + ","):
                if ch == "{":
                    depth += 1
                elif ch == "}":
                    depth -= 1
                elif ch == "," and depth == 0:
                    seg = re.match(r"\s*(\w+)", body[entry_start:idx])
                    if seg:
                        yield m.start(), seg.group(1)
                    entry_start = idx + 1
        else:
            seg = re.match(r"\w+", code[j:])
            if seg:
                yield m.start(), seg.group(0)


def edges(src, with_tests):
    mods = top_level_modules(src)
    reexports = root_reexports(src, mods)
    uses = defaultdict(lambda: defaultdict(list))
    for mod, files in mods.items():
        for path in files:
            base = os.path.basename(path)
            if not with_tests and (base == "tests.rs" or base.endswith("_tests.rs")):
                continue
            code = strip_comments_and_strings(open(path, encoding="utf-8").read())
            if not with_tests:
                code = drop_cfg_test_items(code)
            for offset, seg in paths_after_crate(code):
                target = seg if seg in mods else reexports.get(seg)
                if target and target != mod:
                    line = code.count("\n", 0, offset) + 1
                    uses[mod][target].append(f"{os.path.relpath(path, src)}:{line}")
    return mods, uses


def strongly_connected(nodes, graph):
    index, low, stack, on, out = {}, {}, [], set(), []
    counter = [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            out.append(sorted(comp))

    for v in sorted(nodes):
        if v not in index:
            visit(v)
    return out


def main():
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    src = args[0] if args else "crates/pfslam/src"
    with_tests = "--tests" in sys.argv
    mods, uses = edges(src, with_tests)
    print(f"top-level modules of {src} and the modules each uses through crate::"
          f"{' (tests included)' if with_tests else ' (production code)'}:")
    for mod in sorted(mods):
        targets = sorted(uses[mod])
        print(f"  {mod:10} -> {', '.join(targets) if targets else '(none)'}")
    comps = [c for c in strongly_connected(mods, uses) if len(c) > 1]
    pairs = sorted(
        (a, b) for a in uses for b in uses[a] if a < b and a in uses.get(b, {})
    )
    if not comps:
        print("no cycles")
        return 0
    print("cycles (strongly connected groups):")
    for c in sorted(comps):
        print(f"  {{{', '.join(c)}}}")
    print("mutual pairs:")
    for a, b in pairs:
        print(f"  {a} <-> {b}  ({len(uses[a][b])} uses one way, {len(uses[b][a])} the other)")
    if "--edges" in sys.argv:
        print("edges inside the cycles:")
        for c in comps:
            for a in c:
                for b in sorted(uses[a]):
                    if b in c:
                        print(f"  {a} -> {b}: {', '.join(uses[a][b])}")
    return 1


if __name__ == "__main__":
    sys.exit(main())
