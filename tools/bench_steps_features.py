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

Then the kinematics plug-ins (issue 22): the generic path for plug-in motors against the exact linear kernel on the
same cartesian plan — a plug-in whose three motors are ik functions x, y, z — (target: generic within 1.5× of
linear per step), both ways a plug-in motor can be stepped: Klipper's search with the compiled inverse kinematics as
its callback (kernel.itersolve_steps, the default: ik_search="klipper"), the step engine's guarded
search (kernel.gen_steps_ik) and the step engine on verified polynomial stand-ins of the ik (ik_search="fit":
kernel.ik_fit_pieces, kernel.gen_steps_ik_fit, no ik call per step); then steps/s per kinematics on Klipper's seven
reference configs, all three ways (../shared/reference/klipper/kinematics/*.cfg; polar on the input shifted by
(+30, +30) mm as the reference is).
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


def _generic_cartesian_ik():
    """A cartesian machine as a plug-in whose X, Y, Z motors are ik functions (the generic engine's path)."""
    import numba

    import gcodeplan as gp

    @numba.njit
    def ik_x(x, y, z, p):
        return x

    @numba.njit
    def ik_y(x, y, z, p):
        return y

    @numba.njit
    def ik_z(x, y, z, p):
        return z

    return gp.kinematics.register("bench_ik_cartesian", gp.kinematics.Plugin(
        {"x": ik_x, "y": ik_y, "z": ik_z},
        {"x": lambda m: m.axes["x"].steps_per_mm, "y": lambda m: m.axes["y"].steps_per_mm,
         "z": lambda m: m.axes["z"].steps_per_mm}, extruder="e"), replace=True)


def _rate(source, machine, runs: int, rails=None, ik_search="klipper") -> tuple[int, float]:
    pieces, limits = _pieces(source, machine)
    _time(pieces[:2], limits, machine, rails, ik_search)
    best = None
    for _ in range(runs):
        steps, dt = _time(pieces, limits, machine, rails, ik_search)
        best = dt if best is None else min(best, dt)
    return steps, best


def bench_kinematics(path: str, runs: int) -> None:
    """The generic path against the linear kernel, then steps/s per plug-in kinematics; each plug-in figure with
    Klipper's search (default), the guarded search and the verified fit."""
    from gcodeplan.kinematics import rails_for

    engines = (("Klipper's search", "klipper"), ("guarded search", "exact"), ("verified fit", "fit"))
    plain = _machine("plain")
    plug = _generic_cartesian_ik()
    pieces, limits = _pieces(path, plain)
    # the linear kernel and the three engines timed in turn, run after run (best of --runs each): on a shared
    # machine the load drifts, and timing one after the other would put the drift into the ratios
    contenders = [("linear", None, "klipper")] + [(label, plug.rails(plain), search) for label, search in engines]
    for _, rails, search in contenders:
        _time(pieces[:2], limits, plain, rails, search)
    best = {}
    for _ in range(runs):
        for label, rails, search in contenders:
            steps, dt = _time(pieces, limits, plain, rails, search)
            best[label] = (steps, min(dt, best.get(label, (0, dt))[1]))
    lin_steps, lin_t = best["linear"]
    print(f"  linear kernel: {lin_steps / lin_t / 1e6:.1f} M steps/s ({len(rails_for(plain))} motors)")
    for label, _ in engines:
        gen_steps, gen_t = best[label]
        print(f"  generic path, {label:16s}: {gen_steps / gen_t / 1e6:.1f} M steps/s -> "
              f"{gen_t / gen_steps / (lin_t / lin_steps):.2f}x linear per step (target <= 1.5x; "
              f"{gen_steps == lin_steps and 'same step count' or 'DIFFERENT count'})")
    kin_dir = SHARED / "reference" / "klipper" / "kinematics"
    if not kin_dir.is_dir():
        print(f"  (no {kin_dir}: per-kinematics figures skipped)")
        return
    sys.path.insert(0, str(REPO / "tools"))
    import compare_kinematics as ck
    from gcodeplan.config import load_klipper_config

    lines = Path(path).read_text().splitlines()
    lines = ["SET_KINEMATIC_POSITION X=0 Y=0 Z=0" if ln.split(";")[0].strip() == "G28" else ln for ln in lines]
    for config in ck.CONFIGS:
        m = load_klipper_config(str(kin_dir / f"{config}.cfg"))
        src = [ck._shift_line(ln) for ln in lines] if config == "polar" else lines
        figures = []
        try:
            for label, search in engines:
                steps, t = _rate(src, m, runs, ik_search=search)
                figures.append(f"{label} {steps / t / 1e6:.1f}")
        except Exception as err:      # a file this machine cannot reach: say so, go on
            print(f"  {config:17s}: {type(err).__name__}: {err}")
            continue
        print(f"  {config:17s}: {steps:,} steps; M steps/s: " + ", ".join(figures))


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


def _time(pieces, limits, machine, rails=None, ik_search="klipper") -> tuple[int, float]:
    from gcodeplan.kinematics import rails_for
    from gcodeplan.stepper.generate import StepGenerator

    gen = StepGenerator(rails or rails_for(machine), lambda si, t, d: None, settings=machine.limits_row(),
                        ik_search=ik_search)
    t0 = time.perf_counter()
    for segs, reset, moves, first in pieces:
        gen.feed(segs, reset, moves=moves, limits=limits, first_move=first)
    gen.finish()
    return int(sum(st[0] for st in gen.stats)), time.perf_counter() - t0


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="bench.py steps_features", description=__doc__.splitlines()[0])
    ap.add_argument("file", nargs="?", help="G-code file (default: the corpus cube)")
    ap.add_argument("--runs", type=int, default=3, help="best of N timings (default 3)")
    ap.add_argument("--kinematics-only", action="store_true", help="only the plug-in kinematics figures")
    args = ap.parse_args(argv)
    path = args.file or str(SHARED / "gcode" / "prusaslicer25_cube20_marlin2.gcode")
    if not Path(path).is_file():
        sys.exit(f"no such file: {path}")
    if args.kinematics_only:
        print(f"step stage of the kinematics plug-ins: {path}")
        bench_kinematics(path, args.runs)
        return 0
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
    bench_kinematics(path, args.runs)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
