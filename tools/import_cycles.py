#!/usr/bin/env python3
"""Import cycles between the modules of src/gcodeplan, found statically with ``ast``.

``python tools/import_cycles.py [--module-level]`` prints every cycle (one strongly connected component of the
import graph per line, with one concrete cycle through it) and exits 1 when there is one.

Every ``import``/``from ... import`` counts, at module level and inside functions alike: a function-level
import hides a cycle from the interpreter's start-up but not from the design (the two modules still need
each other), so both are edges. ``--module-level`` keeps only the imports run when the module is loaded.
Imports under ``if TYPE_CHECKING:`` are left out (they never run). ``from . import name`` is an edge to the
submodule ``name`` when one exists, otherwise to the package. A package's ``__init__`` imported only because
a submodule is imported (Python runs ``pkg/__init__`` before ``pkg.sub``) is not an edge: that is the import
system, not a dependency the code chose.
"""
from __future__ import annotations

import argparse
import ast
import sys
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src"
PACKAGE = "gcodeplan"


def module_names(src: Path = SRC, package: str = PACKAGE) -> dict[str, Path]:
    """Every module of the package: dotted name → file (a package is named by its ``__init__``)."""
    out = {}
    for path in sorted((src / package).rglob("*.py")):
        parts = list(path.relative_to(src).with_suffix("").parts)
        is_pkg = parts[-1] == "__init__"
        if is_pkg:
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _imports(tree: ast.Module, module_level: bool):
    """(node, at_module_level) of every import statement, skipping ``if TYPE_CHECKING:`` bodies."""
    def walk(node, in_function):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and _is_type_checking(child.test):
                for sub in child.orelse:
                    yield from walk_one(sub, in_function)
                continue
            yield from walk_one(child, in_function)

    def walk_one(child, in_function):
        if isinstance(child, (ast.Import, ast.ImportFrom)):
            yield child, not in_function
        inner = in_function or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
        yield from walk(child, inner)

    for node, at_top in walk(tree, False):
        if at_top or not module_level:
            yield node, at_top


def import_graph(module_level: bool = False, src: Path = SRC,
                 package: str = PACKAGE) -> dict[str, dict[str, int]]:
    """module → {imported module of the package: line of the first import statement}."""
    mods = module_names(src, package)
    graph: dict[str, dict[str, int]] = {m: {} for m in mods}
    for mod, path in mods.items():
        is_pkg = path.name == "__init__.py"
        tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
        for node, _ in _imports(tree, module_level):
            targets = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            else:
                if node.level:
                    base = mod.split(".") if is_pkg else mod.split(".")[:-1]
                    base = base[:len(base) - (node.level - 1)]
                    prefix = ".".join(base + ([node.module] if node.module else []))
                else:
                    prefix = node.module or ""
                for a in node.names:
                    sub = f"{prefix}.{a.name}"
                    targets.append(sub if sub in mods else prefix)
            for t in targets:
                # `import gcodeplan.x.y` names the deepest module of the package it reaches
                while t and t not in mods:
                    t = t.rpartition(".")[0]
                if t and t != mod:
                    graph[mod].setdefault(t, node.lineno)
    return graph


def cycles(graph: dict[str, dict[str, int]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    sys.setrecursionlimit(max(10000, sys.getrecursionlimit()))

    def visit(v):
        index[v] = low[v] = len(index)
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

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return sorted(out)


def one_cycle(graph: dict[str, dict[str, int]], comp: list[str]) -> list[str]:
    """A shortest cycle through the first module of a component: [a, b, ..., a]."""
    members = set(comp)
    start = comp[0]
    prev = {start: None}
    frontier = [start]
    while frontier:
        nxt = []
        for v in frontier:
            for w in sorted(graph[v]):
                if w == start:
                    path = [v]
                    while prev[path[-1]] is not None:
                        path.append(prev[path[-1]])
                    return path[::-1] + [start]
                if w in members and w not in prev:
                    prev[w] = v
                    nxt.append(w)
        frontier = nxt
    return comp


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--module-level", action="store_true",
                    help="only imports run at module load (leave out function-level imports)")
    args = ap.parse_args(argv)
    graph = import_graph(module_level=args.module_level)
    found = cycles(graph)
    for comp in found:
        cyc = one_cycle(graph, comp)
        steps = " -> ".join(f"{a} (line {graph[a][b]})" for a, b in zip(cyc, cyc[1:]))
        print(f"cycle among {', '.join(comp)}: {steps} -> {cyc[-1]}")
    if not found:
        print(f"no import cycles among {len(graph)} modules")
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main())
