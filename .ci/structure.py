#!/usr/bin/env python3
"""The code's shape, checked (fails when it breaks):

- no Rust file holds more than 1,200 lines outside its tests (the lines
  before a trailing `#[cfg(test)] mod tests`; files under tests/, benches/
  and fuzz/, and a module's own `tests.rs`, are tests);
- no import cycle between the files of one crate of the daemon or the lab
  (a file's edges: the `crate::a::b` paths and `use crate::{..}` groups of
  its non-test code, resolved to the longest module path that is a file;
  a child module reaching its parent with `super::` is the module tree,
  not a cycle).

Usage: python3 .ci/structure.py  (from anywhere in the repository)
"""
import os
import re
import subprocess
import sys
from collections import defaultdict

MAX_LINES = 1200
ROOT = subprocess.run(["git", "rev-parse", "--show-toplevel"], capture_output=True,
                      text=True, check=True).stdout.strip()


def non_test(src):
    i = src.find("#[cfg(test)]\nmod tests")
    return src[:i] if i >= 0 else src


def rust_files():
    out = subprocess.run(["git", "ls-files", "*.rs"], cwd=ROOT, capture_output=True,
                         text=True, check=True).stdout.split()
    return [f for f in out
            if not re.search(r"(^|/)(tests|benches|fuzz)/", f) and not f.endswith("/tests.rs")]


def long_files():
    bad = []
    for f in rust_files():
        with open(os.path.join(ROOT, f), encoding="utf-8") as fh:
            n = non_test(fh.read()).count("\n")
        if n > MAX_LINES:
            bad.append((f, n))
    return bad


def crate_srcs():
    """Every src/ directory of the daemon's crates and the lab."""
    dirs = []
    for base in ["daemon", "models/lab"]:
        for d, _, files in os.walk(os.path.join(ROOT, base)):
            if os.path.basename(d) == "src" and ("lib.rs" in files or "main.rs" in files):
                dirs.append(d)
    return sorted(dirs)


def module_path(src_dir, f):
    parts = os.path.relpath(f, src_dir)[:-3].split(os.sep)
    if parts[-1] in ("main", "lib") and len(parts) == 1:
        return ()
    if parts[-1] == "mod":
        parts = parts[:-1]
    return tuple(parts)


def cycles(src_dir):
    files = [os.path.join(d, f) for d, _, fs in os.walk(src_dir) for f in fs
             if f.endswith(".rs") and f != "tests.rs"]
    mods = {module_path(src_dir, f): f for f in files}
    edges = defaultdict(set)
    for m, f in mods.items():
        with open(f, encoding="utf-8") as fh:
            src = re.sub(r"//.*", "", non_test(fh.read()))
        refs = []
        for kind, path in re.findall(r"\b(crate|super)((?:::\w+)+)", src):
            path = path.split("::")[1:]
            if kind == "super":
                base = list(m[:-1])
                while path and path[0] == "super":
                    base, path = base[:-1], path[1:]
                refs.append(base + path)
            else:
                refs.append(path)
        for group in re.findall(r"use crate::\{([^}]*)\}", src, re.S):
            refs += [[name] for name in re.findall(r"(?:^|,)\s*(\w+)", group)]
        for r in refs:
            for k in range(len(r), 0, -1):
                t = tuple(r[:k])
                if t in mods:
                    # the module tree: a child naming its parent, a parent its child
                    if t != m and t != () and t != m[: len(t)] and m != t[: len(m)]:
                        edges[m].add(t)
                    break
    # Tarjan's strongly connected components
    index, low, stack, on, out, n = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = n[0]
        n[0] += 1
        stack.append(v)
        on.add(v)
        for w in edges[v]:
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
                out.append(sorted("::".join(c) for c in comp))

    sys.setrecursionlimit(10000)
    for v in list(mods):
        if v not in index:
            visit(v)
    return out


def main():
    fail = False
    for f, n in long_files():
        print(f"structure: {f} has {n} lines outside its tests (at most {MAX_LINES})")
        fail = True
    for d in crate_srcs():
        for c in cycles(d):
            print(f"structure: import cycle in {os.path.relpath(d, ROOT)}: {' -> '.join(c)}")
            fail = True
    if not fail:
        print(f"structure: no file over {MAX_LINES} lines outside tests; no import cycle "
              f"between the files of {len(crate_srcs())} crates of the daemon and the lab")
    return 1 if fail else 0


if __name__ == "__main__":
    sys.exit(main())
