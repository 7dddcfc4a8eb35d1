#!/usr/bin/env python3
"""Functions of src/gcodeplan longer than a limit (default 100 lines), longest first.

``python tools/long_functions.py [--limit N]`` prints ``lines  file:line  qualified name``. A function's length is
from its ``def`` (decorators left out) to its last line, nested functions included in their parent's length
and listed on their own when they are long themselves.
"""
from __future__ import annotations

import argparse
import ast
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src" / "gcodeplan"


def long_functions(limit: int = 100, src: Path = SRC) -> list[tuple[int, str, int, str]]:
    """(lines, file relative to src/gcodeplan, def line, qualified name) of every function over ``limit``."""
    out = []
    for path in sorted(src.rglob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"), str(path))

        def visit(node, prefix):
            for child in ast.iter_child_nodes(node):
                if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    name = prefix + child.name
                    n = child.end_lineno - child.lineno + 1
                    if n > limit:
                        out.append((n, str(path.relative_to(src)), child.lineno, name))
                    visit(child, name + ".")
                elif isinstance(child, ast.ClassDef):
                    visit(child, prefix + child.name + ".")

        visit(tree, "")
    return sorted(out, key=lambda r: (-r[0], r[1], r[2]))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--limit", type=int, default=100, help="list functions longer than this many lines")
    args = ap.parse_args(argv)
    rows = long_functions(args.limit)
    for n, f, line, name in rows:
        print(f"{n:5d}  {f}:{line}  {name}")
    print(f"{len(rows)} functions over {args.limit} lines")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
