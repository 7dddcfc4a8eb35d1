#!/usr/bin/env python3
"""``gcodeplan.Toolhead`` in a firmware-style loop: ``th.gcode(line)`` then ``th.committed()`` per line.

``python tools/bench.py toolhead [--runs N] [--quick]``: for the cube (and the 20 000-move spiral unless
``--quick``), in every planning mode (klipper trapezoids, junction deviation, blend, S-curves):

* **per-line loop** (the issue-22 figure, target ≤ 10 µs median on the cube): each line timed from
  ``th.gcode(line)`` to the end of ``th.committed()`` (CommittedMove objects made) with the default
  ``block_lines``; median and p90 µs per line, and the mean (the whole run, close() included, over the lines);
* the same loop with ``block_lines=1`` (every call sees every line: the cost before interpretation was
  batched), median µs per line;
* **batch**: every line through ``th.gcode`` and one ``committed_arrays()`` at the end, µs per line;
  and ``gp.plan`` on the file, µs per line;
* the cost of the Toolhead's lock: two uncontended acquire/release pairs (one per call of the loop), µs;
* identical: the per-line loop's moves (line, end position, speeds, times) equal ``gp.plan``'s bit for bit,
  and the ``block_lines=1`` loop's too.

Best of N runs for each figure (``--runs``, default 3). Also checks blend mode stays linear in the length
of a run without a stop: the spiral repeated 1× and 4× must cost ≤ 5× (not 16×).
"""
from __future__ import annotations

import argparse
import threading
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
FILES = ("prusaslicer25_cube20_marlin2.gcode", "e_spiral20k.gcode")
MODES = (("klipper", None, None), ("junction-deviation", "junction-deviation", None),
         ("blend", "blend", None), ("s-curve", None, 100000.0))


def per_line_loop(lines: list[bytes], policy, jerk, block_lines: int | None = None):
    """The firmware loop: (µs per line array, total s incl. close(), CommittedMove list)."""
    from gcodeplan import Toolhead

    th = Toolhead(policy=policy, jerk=jerk) if block_lines is None else \
        Toolhead(policy=policy, jerk=jerk, block_lines=block_lines)
    per = np.empty(len(lines))
    got = []
    clock = time.perf_counter_ns
    t0 = clock()
    for k, line in enumerate(lines):
        a = clock()
        th.gcode(line)
        got.extend(th.committed())
        per[k] = clock() - a
    th.close()
    got.extend(th.committed())
    return per / 1e3, (clock() - t0) / 1e9, got


def batch(lines: list[bytes], policy, jerk):
    """Every line fed, one committed_arrays() at the end: (total s, moves, plan)."""
    from gcodeplan import Toolhead

    th = Toolhead(policy=policy, jerk=jerk)
    t0 = time.perf_counter()
    for line in lines:
        th.gcode(line)
    th.close()
    moves, plan = th.committed_arrays()
    return time.perf_counter() - t0, moves, plan


def same_as_plan(got, ref) -> bool:
    """CommittedMove list equal to gp.plan's rows bit for bit."""
    if len(got) != len(ref.plan):
        return False
    end = ref.plan["t_start"] + ref.plan["duration"]
    cols = {"line": ref.moves["line"], "x": ref.moves["x1"], "y": ref.moves["y1"], "z": ref.moves["z1"],
            "e": ref.moves["e1"], "start_v": ref.plan["start_v"], "cruise_v": ref.plan["cruise_v"],
            "end_v": ref.plan["end_v"], "start_time": ref.plan["t_start"], "end_time": end}
    return all(np.array_equal(np.array([getattr(m, f) for m in got]), v) for f, v in cols.items())


def lock_cost_us(n: int = 20000) -> float:
    """Median µs of two uncontended acquire/release pairs of a threading.Lock (one per Toolhead call)."""
    lock = threading.Lock()
    clock = time.perf_counter_ns
    t = np.empty(n)
    for k in range(n):
        a = clock()
        with lock:
            pass
        with lock:
            pass
        t[k] = clock() - a
    empty = np.empty(n)
    for k in range(n):
        a = clock()
        empty[k] = clock() - a
    return float(np.median(t) - np.median(empty)) / 1e3


def main(argv: list[str]) -> int:
    import gcodeplan as gp

    ap = argparse.ArgumentParser(prog="bench.py toolhead")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--quick", action="store_true", help="the cube only, no blend linearity check")
    args = ap.parse_args(argv)
    print("per-line loop: th.gcode(line); th.committed() per line, default block_lines; batch: gcode() every "
          "line, committed_arrays() once at the end")
    print("| file | mode | lines | moves | loop median µs/line | loop p90 µs/line | loop mean µs/line | "
          "block_lines=1 median µs/line | batch µs/line | gp.plan µs/line | identical |")
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---|")
    for name in FILES[:1] if args.quick else FILES:
        path = REPO / "gcode_samples" / name
        lines = path.read_bytes().split(b"\n")
        if lines and lines[-1] == b"":
            lines.pop()
        n_lines = len(lines)
        for label, policy, jerk in MODES:
            ref = gp.plan(str(path), policy=policy, jerk=jerk)        # also compiles the kernels
            loop = min((per_line_loop(lines, policy, jerk) for _ in range(args.runs)), key=lambda r: r[1])
            one = min((per_line_loop(lines, policy, jerk, 1) for _ in range(max(1, args.runs - 1))),
                      key=lambda r: r[1])
            whole = min(batch(lines, policy, jerk)[0] for _ in range(args.runs))
            plan_s = []
            for _ in range(args.runs):
                t0 = time.perf_counter()
                gp.plan(str(path), policy=policy, jerk=jerk)
                plan_s.append(time.perf_counter() - t0)
            per, total, got = loop
            same = same_as_plan(got, ref) and same_as_plan(one[2], ref)
            print(f"| {name} | {label} | {n_lines} | {len(got)} | {np.median(per):.2f} | "
                  f"{np.percentile(per, 90):.2f} | {total / n_lines * 1e6:.2f} | {np.median(one[0]):.2f} | "
                  f"{whole / n_lines * 1e6:.2f} | {min(plan_s) / n_lines * 1e6:.2f} | {same} |")
    print(f"\nthe Toolhead's lock: {lock_cost_us():.2f} µs per line (two uncontended acquire/release pairs)")
    if args.quick:
        return 0
    # blend mode linear in the length of a run without a stop
    spiral = (REPO / "gcode_samples" / "e_spiral20k.gcode").read_bytes().split(b"\n")
    body = [ln for ln in spiral if ln.startswith(b"G1")]
    head = [ln for ln in spiral if not ln.startswith(b"G1")]
    t = [batch(head + body * k, "blend", None)[0] for k in (1, 4)]
    print(f"blend, spiral ×1 {t[0]:.3f} s, ×4 {t[1]:.3f} s: ratio {t[1] / t[0]:.2f} (linear = 4, quadratic = 16)")
    return 0


if __name__ == "__main__":
    import sys

    sys.exit(main(sys.argv[1:]))
