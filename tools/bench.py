#!/usr/bin/env python3
"""Benchmarks: ``python tools/bench.py NAME [options]`` (``python tools/bench.py`` lists the names).

Each benchmark lives in ``tools/bench_<name>.py`` with a ``main(argv) -> int``; a new file is a new name.
Figures are measured in one run on this machine; compare ratios, not absolute
numbers, across machines.
"""
from __future__ import annotations

import importlib
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
NAMES = tuple(sorted(p.stem[len("bench_"):] for p in HERE.glob("bench_*.py")))


def main(argv: list[str]) -> int:
    if not argv or argv[0] not in NAMES:
        print(__doc__)
        print("names:", ", ".join(NAMES))
        return 2
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    mod = importlib.import_module(f"bench_{argv[0]}")
    return int(mod.main(argv[1:]) or 0)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
