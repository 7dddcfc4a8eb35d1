#!/usr/bin/env python3
"""Per-move cost of ``gcodeplan.Toolhead`` fed one line at a time (issue: flat cost, ≤ 10 µs per move).

``python tools/bench.py toolhead [--runs N]``: for the cube and the 20 000-move spiral, in every
planning mode (klipper trapezoids, junction deviation, blend, S-curves), feeds the file line by line
and reports the median cost of a ``gcode()`` call, the mean cost per line and per move over the
whole run (interpretation and planning included), and the same file planned whole by ``gp.plan``
for contrast. Checks the Toolhead's plan equals ``gp.plan``'s bit for bit. Best of N runs.
Also checks blend mode stays linear: the spiral repeated 1× and 4× must cost ≤ 5× (not 16×).
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
FILES = ("prusaslicer25_cube20_marlin2.gcode", "e_spiral20k.gcode")
MODES = (("klipper", None, None), ("junction-deviation", "junction-deviation", None),
         ("blend", "blend", None), ("s-curve", None, 100000.0))


def feed_singly(lines: list[bytes], policy, jerk):
    from gcodeplan import Toolhead

    th = Toolhead(policy=policy, jerk=jerk)
    calls = np.empty(len(lines))
    clock = time.perf_counter
    t0 = clock()
    for k, line in enumerate(lines):
        a = clock()
        th.gcode(line)
        calls[k] = clock() - a
    th.close()
    total = clock() - t0
    moves, plan = th.committed_arrays()
    return total, calls, moves, plan


def main(argv: list[str]) -> int:
    import gcodeplan as gp

    ap = argparse.ArgumentParser(prog="bench.py toolhead")
    ap.add_argument("--runs", type=int, default=3)
    args = ap.parse_args(argv)
    print("| file | mode | moves | median µs per call | mean µs per line | mean µs per move | gp.plan µs per move | identical |")
    print("|---|---|---:|---:|---:|---:|---:|---|")
    for name in FILES:
        path = REPO / "gcode_samples" / name
        lines = path.read_bytes().split(b"\n")
        if lines and lines[-1] == b"":
            lines.pop()
        for label, policy, jerk in MODES:
            ref = gp.plan(str(path), policy=policy, jerk=jerk)        # also compiles the kernels
            best = None
            for _ in range(args.runs):
                total, calls, moves, plan = feed_singly(lines, policy, jerk)
                if best is None or total < best[0]:
                    best = (total, calls, moves, plan)
            total, calls, moves, plan = best
            t0 = time.perf_counter()
            gp.plan(str(path), policy=policy, jerk=jerk)
            whole = time.perf_counter() - t0
            n = max(len(moves), 1)
            same = all(np.array_equal(plan[f], ref.plan[f]) for f in ("t_start", "start_v", "cruise_v", "end_v",
                                                                      "duration"))
            print(f"| {name} | {label} | {len(moves)} | {np.median(calls) * 1e6:.2f} | "
                  f"{total / len(lines) * 1e6:.2f} | {total / n * 1e6:.2f} | {whole / n * 1e6:.2f} | {same} |")
    # blend mode linear in the length of a run without a stop
    spiral = (REPO / "gcode_samples" / "e_spiral20k.gcode").read_bytes().split(b"\n")
    body = [ln for ln in spiral if ln.startswith(b"G1")]
    head = [ln for ln in spiral if not ln.startswith(b"G1")]
    t = []
    for k in (1, 4):
        t.append(feed_singly(head + body * k, "blend", None)[0])
    print(f"\nblend, spiral ×1 {t[0]:.3f} s, ×4 {t[1]:.3f} s: ratio {t[1] / t[0]:.2f} (linear = 4, quadratic = 16)")
    return 0


if __name__ == "__main__":
    import sys

    sys.exit(main(sys.argv[1:]))
