#!/usr/bin/env python3
"""File-level import cycles in the workspace's crates.

Each `.rs` file under a crate's `src/` is a node; a file depends on another when it names it by
path (`crate::a::b`, `super::b`, `self::b`, including inside `use` groups). Re-exports are
followed to the file that defines the module, not the name. Prints every strongly connected
component with more than one file; exits 1 when there is one.

    scripts/import-cycles.py [crates/nrc-render ...]
"""
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def module_path(src: Path, f: Path):
    rel = f.relative_to(src).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] in ("lib", "main"):
        parts = parts[:-1]
    elif parts[-1] == "mod":
        parts = parts[:-1]
    return tuple(parts)


def strip_comments(text: str) -> str:
    """Comments and visibility paths (`pub(in crate::a)` names a scope, not a dependency)."""
    text = re.sub(r"//[^\n]*", "", text)
    text = re.sub(r"\bpub\(in [\w:]+\)", "pub", text)
    return re.sub(r"/\*.*?\*/", "", text, flags=re.S)


def paths_in(text: str):
    """Module paths named in `text`: `crate::a::b::{c, d::e}` expanded."""
    out = []
    for m in re.finditer(r"\b(crate|super|self)((?:::\w+)+)(::\{)?", text):
        head = [m.group(1)] + m.group(2).split("::")[1:]
        if m.group(3):
            depth, i, start = 1, m.end(), m.end()
            while depth and i < len(text):
                depth += {"{": 1, "}": -1}.get(text[i], 0)
                i += 1
            for item in re.split(r",", text[start : i - 1]):
                item = item.strip().split(" as ")[0]
                if item and not item.startswith("{"):
                    out.append(head + item.split("::"))
        out.append(head)
    return out


def crate_graph(crate: Path):
    src = crate / "src"
    files = {module_path(src, f): f for f in src.rglob("*.rs")}
    graph = {}
    for mod, f in files.items():
        text = strip_comments(f.read_text())
        deps = set()
        for p in paths_in(text):
            if p[0] == "crate":
                base, rest = (), p[1:]
            elif p[0] == "super":
                base, rest = mod[:-1], p[1:]
                while rest and rest[0] == "super":
                    base, rest = base[:-1], rest[1:]
            else:
                base, rest = mod, p[1:]
            # The longest prefix that is a file of the crate.
            target = None
            for k in range(len(rest), -1, -1):
                cand = base + tuple(rest[:k])
                if cand in files:
                    target = cand
                    break
            if target is not None and target != mod and target != ():
                deps.add(target)
        # `use child::...` (a path relative to this module).
        for m in re.finditer(r"\buse\s+(\w+)::", text):
            child = mod + (m.group(1),)
            if child in files:
                deps.add(child)
        graph[mod] = deps
    return graph


def cycles(graph):
    index, low, stack, on, out = {}, {}, [], set(), []
    counter = [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph[v]:
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
            if len(comp) > 1:
                out.append(sorted(comp))

    sys.setrecursionlimit(10000)
    for v in graph:
        if v not in index:
            visit(v)
    return out


def main():
    crates = [ROOT / a for a in sys.argv[1:]] or [ROOT] + sorted((ROOT / "crates").iterdir())
    found = False
    for c in crates:
        for comp in cycles(crate_graph(c)):
            found = True
            names = ", ".join("/".join(m) or "lib" for m in comp)
            where = c.relative_to(ROOT) if c.is_relative_to(ROOT) and c != ROOT else c
            print(f"{where if c != ROOT else '.'}: {names}")
    sys.exit(1 if found else 0)


if __name__ == "__main__":
    main()
