"""``python tools/bench.py postprocess [FILE] [--runs N]``: post-process and dump-moves, wall time and peak memory.

Each run is a fresh process on a fresh copy of the file (``/usr/bin/time``-style figures from
``resource.getrusage`` of the child): ``gcodeplan estimate --json`` for contrast, ``gcodeplan post-process``
(two passes: plan, then copy with the M73 lines) and ``gcodeplan dump-moves``. Best of N.
"""
from __future__ import annotations

import argparse
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("GCODEPLAN_SHARED", REPO.parent / "shared"))
DEFAULT = SHARED / "gcode" / "prusaslicer25_plate150_gyroid_big.gcode"


def _child(cmd: list[str]) -> tuple[float, float]:
    """(wall s, peak RSS MB) of one child process."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    return wall, max(peak, before) / 1024.0


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="bench.py postprocess")
    ap.add_argument("file", nargs="?", default=str(DEFAULT))
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--dump-moves", action="store_true", help="also time dump-moves (slow on big files)")
    args = ap.parse_args(argv)
    src = Path(args.file)
    lines = sum(1 for _ in open(src, "rb"))
    gp = [sys.executable, "-m", "gcodeplan.cli"]
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp) / src.name
        rows = []
        cases = [("estimate --json", lambda: gp + ["estimate", "-q", "--json", str(work)]),
                 ("post-process", lambda: gp + ["post-process", "-q", str(work)])]
        if args.dump_moves:
            cases.append(("dump-moves", lambda: gp + ["dump-moves", "-q", str(work), "-o", str(Path(tmp) / "m.csv")]))
        for name, cmd in cases:
            best = None
            for _ in range(args.runs):
                shutil.copyfile(src, work)
                wall, rss = _child(cmd())
                best = (wall, rss) if best is None or wall < best[0] else best
            rows.append((name, *best))
    print(f"{src.name}: {lines:,} lines, {src.stat().st_size / 1e6:.1f} MB, best of {args.runs}")
    print("| command | wall s | lines/s | peak RSS MB (of all children so far) |")
    print("|---|---:|---:|---:|")
    for name, wall, rss in rows:
        print(f"| {name} | {wall:.2f} | {lines / wall:,.0f} | {rss:.0f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
