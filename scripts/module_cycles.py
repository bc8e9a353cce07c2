#!/usr/bin/env python3
"""Finds cycles between the modules of a Rust crate, from its `use crate::…` and `crate::…`
paths (and `super::` in a module's own files).

Usage: module_cycles.py SRC_DIR [SRC_DIR ...]   (each a crate's src/ folder)

A module is a top-level file or folder of SRC_DIR (`link.rs`, `bench/`); an edge A → B is a
path `crate::B` written in A's code, comments and doc links aside (tests included: a test
module that needs another module is an edge too, so test-only cycles are caught). Prints each crate's modules with their
edges and every cycle found (strongly connected components with more than one module); exit 1
when there is one. Nothing is compiled: it reads the text.
"""

import os
import re
import sys

PATH = re.compile(r"\bcrate::([a-z_][a-z0-9_]*)")


def modules(src):
    mods = {}
    for name in sorted(os.listdir(src)):
        path = os.path.join(src, name)
        if name in ("lib.rs", "main.rs"):
            continue
        if name.endswith(".rs"):
            mods.setdefault(name[:-3], []).append(path)
        elif os.path.isdir(path):
            for d, _, files in os.walk(path):
                for f in files:
                    if f.endswith(".rs"):
                        mods.setdefault(name, []).append(os.path.join(d, f))
    # `#[path = "x.rs"]` children (e.g. stack_mpc_tests.rs) belong to the module that names them.
    owners = {}
    for m, files in mods.items():
        for f in files:
            with open(f, encoding="utf-8") as fh:
                for p in re.findall(r'#\[path\s*=\s*"([^"]+)"\]', fh.read()):
                    owners[os.path.splitext(os.path.basename(p))[0]] = m
    for child, owner in owners.items():
        if child in mods and child != owner:
            mods[owner].extend(mods.pop(child))
    return mods


def edges(mods):
    out = {m: set() for m in mods}
    for m, files in mods.items():
        for f in files:
            with open(f, encoding="utf-8") as fh:
                # Comments (and doc links) are not dependencies.
                text = "\n".join(line.split("//", 1)[0] for line in fh)
            # `use crate::{a, b::c}` groups
            for group in re.findall(r"crate::\{([^}]*)\}", text):
                for name in re.findall(r"(?:^|,)\s*([a-z_][a-z0-9_]*)", group):
                    if name in mods and name != m:
                        out[m].add(name)
            for name in PATH.findall(text):
                if name in mods and name != m:
                    out[m].add(name)
    return out


def cycles(graph):
    index, low, stack, on, comps = {}, {}, [], set(), []
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
                comps.append(sorted(comp))

    for v in graph:
        if v not in index:
            visit(v)
    return comps


def main():
    if len(sys.argv) < 2:
        print(__doc__, file=sys.stderr)
        sys.exit(2)
    found = False
    for src in sys.argv[1:]:
        graph = edges(modules(src))
        comps = cycles(graph)
        print(f"{src}: {len(graph)} modules, {sum(len(e) for e in graph.values())} edges, "
              f"{len(comps)} cycle(s)")
        for comp in comps:
            found = True
            inner = {m: sorted(graph[m] & set(comp)) for m in comp}
            print("  cycle: " + "; ".join(f"{m} -> {', '.join(t)}" for m, t in inner.items()))
    sys.exit(1 if found else 0)


if __name__ == "__main__":
    main()
