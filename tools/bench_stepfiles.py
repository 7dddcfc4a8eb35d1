"""``python tools/bench.py stepfiles [FILE] [--keep DIR]``: plain vs compact step files.

Runs ``gcodeplan steps FILE -q`` twice (``--format plain`` and ``--format compact``) in fresh processes,
then loads both with ``gcodeplan.stepper.export.load_steps``; prints wall time, peak RSS and size of each,
the size ratio, the load times, and whether the times and directions are identical (np.array_equal).
Default FILE: the 50 MB corpus file from ../shared/gcode.
"""
from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DEFAULT = REPO.parent / "shared" / "gcode" / "prusaslicer25_plate150_gyroid_big.gcode"


def _run(argv: list[str]) -> tuple[float, float]:
    """(wall s, peak RSS MB) of one child process."""
    t0 = time.perf_counter()
    before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    subprocess.run(argv, check=True)
    wall = time.perf_counter() - t0
    peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    return wall, max(peak, before) / 1024.0


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="bench.py stepfiles", description=__doc__)
    ap.add_argument("file", nargs="?", default=str(DEFAULT))
    ap.add_argument("--keep", metavar="DIR", help="write the two files here (default: a temporary folder)")
    args = ap.parse_args(argv)
    import numpy as np

    from gcodeplan.stepper.export import load_steps

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(args.keep or tmp)
        written = []
        for fmt in ("plain", "compact"):        # both written before anything is loaded here: a fork of a
            path = out / f"steps_{fmt}.npz"     # big parent would count its pages in the child's peak RSS
            wall, rss = _run([sys.executable, "-m", "gcodeplan.cli", "steps", args.file, "-o", str(path), "-q",
                              "--format", fmt])
            written.append((fmt, path, wall, rss))
        rows = []
        for fmt, path, wall, rss in written:
            t0 = time.perf_counter()
            steps = load_steps(path)
            load = time.perf_counter() - t0
            rows.append((fmt, wall, rss, path.stat().st_size, load, steps))
        n = sum(len(t) for t, _ in rows[0][5].values())
        print(f"{os.path.basename(args.file)}: {n:,} steps")
        print("| form | write wall s | peak RSS MB | size MB | bytes/step | load_steps s |")
        print("|---|---:|---:|---:|---:|---:|")
        for fmt, wall, rss, size, load, _ in rows:
            print(f"| {fmt} | {wall:.1f} | {rss:.0f} | {size / 1e6:.1f} | {size / n:.2f} | {load:.1f} |")
        a, b = rows[0][5], rows[1][5]
        same = all(np.array_equal(a[k][0], b[k][0]) and np.array_equal(a[k][1], b[k][1]) for k in a)
        print(f"size ratio plain/compact {rows[0][3] / rows[1][3]:.1f}×; identical times and directions: {same}")
        print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
