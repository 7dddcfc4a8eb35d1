"""``python tools/bench.py stages [--file F] [--runs N]``: where ``gcodeplan estimate`` spends its time after start-up.

In one process, numba's kernels loaded first (a warm-up estimate of a small file), best of N runs each on the
50 MB corpus file (``../shared/gcode/prusaslicer25_plate150_gyroid_big.gcode``, or ``--file``):

* a bare Python loop over the file's lines (text mode), the yardstick of the start-up target (issue 13);
* parse: the reader's MOVE batches (scanner, interpreter, per-batch checks and summary);
* parse + plan: the pipeline without sinks (the streaming planner added);
* parse + plan + account: ``gcodeplan.estimate`` without per-line times, what ``gcodeplan estimate`` runs.

Each stage's own cost is the difference between two rows, given per MOVE row as well. Start-up (imports, numba's
cache) is not in these figures: ``python tools/bench.py startup`` measures whole processes.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("GCODEPLAN_SHARED", REPO.parent / "shared"))
BIG = SHARED / "gcode" / "prusaslicer25_plate150_gyroid_big.gcode"
WARM = REPO / "gcode_samples" / "prusaslicer25_cube20_marlin2.gcode"


def best_of(fn, runs: int) -> float:
    """Least wall time (s) of ``runs`` calls of ``fn()`` (the machine is shared: the least disturbed run)."""
    best = float("inf")
    for _ in range(runs):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="bench.py stages", description=__doc__.split("\n")[0])
    ap.add_argument("--file", type=Path, default=BIG, help="G-code file (default: the 50 MB corpus file)")
    ap.add_argument("--runs", type=int, default=3, help="runs per figure (best is kept)")
    args = ap.parse_args(argv)
    if not args.file.is_file():
        print(f"{args.file} not found: nothing to measure", file=sys.stderr)
        return 2
    import gcodeplan as gp
    from gcodeplan.gcode import GcodeReader
    from gcodeplan.pipeline import run

    machine = gp.load_machine()
    gp.estimate(str(WARM), machine, line_times=False)        # every kernel loaded (or compiled) before timing
    path = str(args.file)
    rows = []

    def loop():
        with open(path) as f:
            for _ in f:
                pass

    def parse():
        reader = GcodeReader(path, machine)
        for moves in reader.batches():
            rows.append(len(moves))

    loop_s = best_of(loop, args.runs)
    parse_s = best_of(parse, args.runs)
    n = sum(rows) // args.runs
    plan_s = best_of(lambda: run(path, machine), args.runs)
    est_s = best_of(lambda: gp.estimate(path, machine, line_times=False), args.runs)
    print(f"| {args.file.name} ({args.file.stat().st_size / 1e6:.0f} MB, {n} MOVE rows), best of {args.runs} "
          f"| s | stage s | ns per row | × bare loop |")
    print("|---|---:|---:|---:|---:|")
    print(f"| bare Python line loop (text) | {loop_s:.3f} | | | 1.00 |")
    for name, total, prev in (("parse", parse_s, 0.0), ("parse + plan", plan_s, parse_s),
                              ("parse + plan + account (estimate)", est_s, plan_s)):
        stage = total - prev
        print(f"| {name} | {total:.3f} | {stage:.3f} | {stage / n * 1e9:.0f} | {total / loop_s:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
