#!/usr/bin/env python3
"""Step generation with input shaping and pressure advance: ``python tools/bench.py steps_features [FILE]``.

Plans FILE (default: the corpus cube) once into memory, then times the step stage alone (one core:
the kernels are single-threaded) three ways on a cartesian Klipper machine (80/80/400/95.5 steps/mm):
plain, shaped (mzv 45 Hz on X, ei 38 Hz on Y: the reference's shaper_cartesian.cfg) and with
pressure advance (K = 0.045 s, smooth time 0.04 s: pa_cartesian.cfg); then on a linear delta
(the reference's delta.cfg: arm 400 mm, radius 196 mm, 80 steps/mm towers), plain and shaped. Prints
steps per second of step-stage time (best of --runs) and the cost ratios per step against plain
cartesian. Target: ≥ 50 M steps/s shaped. Shaped and pressure-advanced motors run Klipper's own step search
(kernel.itersolve_steps: closed-form crossings where its probes cannot leave a monotone run, its probe
sequence near turning points); delta towers keep the exact kernel.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"


def _machine(feature: str):
    from gcodeplan.machine import Machine

    m = Machine(kinematics="cartesian", flavor="klipper")
    for ax, spm in zip("xyze", (80.0, 80.0, 400.0, 3200 / 33.5)):
        m.axes[ax].steps_per_mm = spm
    if feature.startswith("delta"):
        m.kinematics = "delta"
        m.delta_radius, m.print_radius, m.delta_arm_length = 196.0, 202.0, (400.0, 400.0, 400.0)
        m.delta_position_endstop, m.delta_steps_per_mm = (300.0, 300.0, 300.0), (80.0, 80.0, 80.0)
        m.axes["z"].max_velocity, m.axes["z"].max_accel = 15.0, 100.0
    if feature.endswith("shaped"):
        m.shaper_type_x, m.shaper_freq_x = "mzv", 45.0
        m.shaper_type_y, m.shaper_freq_y = "ei", 38.0
    elif feature == "pressure advance":
        m.pressure_advance, m.pressure_advance_smooth_time = 0.045, 0.04
    return m


def _pieces(path: str, machine):
    """Every final piece with its segments, homing resets and the LIMITS table, in memory."""
    from gcodeplan.pipeline import Run
    from gcodeplan.stepper.source import homing_resets

    drive = Run(path, machine)
    out = []
    pending = False
    for piece in drive:
        segs = piece.segments
        reset, pending = homing_resets(piece.moves, segs, piece.first_move, pending)
        out.append((segs, reset, piece.moves, piece.first_move))
    return out, drive.reader.limits


def _time(pieces, limits, machine) -> tuple[int, float]:
    from gcodeplan.kinematics import rails_for
    from gcodeplan.stepper.generate import StepGenerator

    gen = StepGenerator(rails_for(machine), lambda si, t, d: None, settings=machine.limits_row())
    t0 = time.perf_counter()
    for segs, reset, moves, first in pieces:
        gen.feed(segs, reset, moves=moves, limits=limits, first_move=first)
    gen.finish()
    return int(sum(st[0] for st in gen.stats)), time.perf_counter() - t0


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="bench.py steps_features", description=__doc__.splitlines()[0])
    ap.add_argument("file", nargs="?", help="G-code file (default: the corpus cube)")
    ap.add_argument("--runs", type=int, default=3, help="best of N timings (default 3)")
    args = ap.parse_args(argv)
    path = args.file or str(SHARED / "gcode" / "prusaslicer25_cube20_marlin2.gcode")
    if not Path(path).is_file():
        sys.exit(f"no such file: {path}")
    print(f"step stage with shaping / pressure advance: {path}")
    rates = {}
    for feature in ("plain", "shaped", "pressure advance", "delta", "delta shaped"):
        machine = _machine(feature)
        pieces, limits = _pieces(path, machine)
        _time(pieces[:2], limits, machine)            # compile / load the numba cache outside the timing
        best = None
        for _ in range(args.runs):
            steps, dt = _time(pieces, limits, machine)
            best = dt if best is None else min(best, dt)
        rates[feature] = steps / best
        print(f"  {feature:17s}: {steps:,} steps in {best:.3f} s -> {steps / best / 1e6:.1f} M steps/s")
    print("  cost per step vs plain cartesian: " + ", ".join(f"{f} {rates['plain'] / rates[f]:.2f}x"
                                                         for f in rates if f != "plain"))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
