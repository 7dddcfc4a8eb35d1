"""``python tools/bench.py blend [--moves N] [--max-mb MB]``: blend mode (G64 P) on a run that never stops.

A synthetic spiral of N moves (default 5 million) without a single full stop — the case that used to hold
the whole run in memory — is generated line by line (never stored), parsed and planned through
:func:`gcodeplan.pipeline.run` with the blend policy, in a fresh process. Prints the wall time, moves per
second, the planned time, the share of corners blended and the peak RSS; exits 1 when the peak RSS is
above ``--max-mb`` (default 400 MB).
"""
from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import time

CHILD = r"""
import json, math, resource, sys, time
import numpy as np
import gcodeplan as gp
from gcodeplan.pipeline import Sink, run
from gcodeplan.schema import PHASE_BLEND

n = int(sys.argv[1])

def spiral(n):
    # a flat spiral around (100, 100) whose radius swings between 20 and 80 mm: ~0.5 mm chords, every corner a
    # few degrees, never a reversal, a dwell or an extrude-only move, so the blend run never stops
    yield "G21\nG90\nM83\nG64 P0.02\nG1 X150 Y100 F6000\n"
    theta = 0.0
    for i in range(n - 1):
        r = 50.0 + 30.0 * math.sin(theta / 400.0)
        theta += 0.5 / r
        r = 50.0 + 30.0 * math.sin(theta / 400.0)
        yield f"G1 X{100.0 + r * math.cos(theta):.4f} Y{100.0 + r * math.sin(theta):.4f} E0.02\n"

class Count(Sink):
    def __init__(self):
        self.moves = 0
        self.end = 0.0
        self.blend_t = 0.0
    def add(self, piece):
        self.moves += len(piece.moves)
        if len(piece.plan):
            self.end = float(piece.plan["t_start"][-1] + piece.plan["duration"][-1])
        s = piece.segments
        self.blend_t += float(s["dt"][s["phase"] == PHASE_BLEND].sum())

machine = gp.load_machine("klipper")
sink = Count()
t0 = time.perf_counter()
res = run(spiral(n), machine, policy="blend", sinks=[sink])
wall = time.perf_counter() - t0
peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
print(json.dumps({"moves": sink.moves, "wall_s": wall, "planned_s": sink.end, "blend_share": sink.blend_t / sink.end,
                  "peak_mb": peak_mb, "mode": res.mode}))
"""


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="bench.py blend", description=__doc__.split("\n")[0])
    ap.add_argument("--moves", type=int, default=5_000_000)
    ap.add_argument("--max-mb", type=float, default=400.0, help="peak RSS limit (MB)")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    out = subprocess.run([sys.executable, "-c", CHILD, str(args.moves)], capture_output=True, text=True)
    if out.returncode != 0:
        print(out.stderr, file=sys.stderr)
        return 1
    r = json.loads(out.stdout.strip().splitlines()[-1])
    total = time.perf_counter() - t0
    ok = r["peak_mb"] < args.max_mb and r["mode"] == "blend" and r["moves"] >= args.moves and math.isfinite(
        r["planned_s"])
    print("| moves | wall s (generate + parse + plan) | moves/s | planned time s | time in blends | peak RSS MB |")
    print("|---:|---:|---:|---:|---:|---:|")
    print(f"| {r['moves']:,} | {r['wall_s']:.1f} | {r['moves'] / r['wall_s']:,.0f} | {r['planned_s']:.1f} | "
          f"{100 * r['blend_share']:.1f} % | {r['peak_mb']:.0f} |")
    print(f"(process {total:.1f} s with start-up; peak RSS limit {args.max_mb:.0f} MB: {'ok' if ok else 'FAILED'})")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
