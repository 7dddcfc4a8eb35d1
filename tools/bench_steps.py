#!/usr/bin/env python3
"""Step generation speed: ``python tools/bench.py steps [FILE] [--kinematics K] [--synthetic N] [--compress-only]``.

Streams FILE (default: the largest corpus file) through the parser and the
planner, and times the step kernel alone (steps per second of kernel time, per
core: the kernel is single-threaded), then with compression. Peak memory is the
process's maximum resident set size. ``--synthetic N`` uses N random
polyline moves built in memory instead of a G-code file.

The compression figure (alone with ``--compress-only``) times the compressor
on Klipper's own exact steps of the corpus cube (../shared/reference/klipper,
corexy, 6.5 M steps fed in 1 M-step chunks as the step generator hands them
over, one core) and compares its queue_step count with Klipper's.
"""
from __future__ import annotations

import argparse
import resource
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"


def _largest_corpus_file() -> Path | None:
    files = sorted((SHARED / "gcode").glob("*.gcode"), key=lambda p: p.stat().st_size)
    return files[-1] if files else None


def _synthetic_batches(n_moves: int, seed: int = 1, batch: int = 20000):
    from gcodeplan.stepper.synth import polyline_segments

    rng = np.random.default_rng(seed)
    t = 0.0
    last = np.zeros(4)
    for lo in range(0, n_moves, batch):
        k = min(batch, n_moves - lo)
        pts = np.cumsum(np.column_stack([rng.uniform(-20, 20, (k, 2)), np.zeros(k), rng.uniform(0, 1, k)]),
                        axis=0) + last
        pts = np.vstack([last, pts])
        seg = polyline_segments(pts, 200.0, 3000.0, junction_v=5.0, t_start=t)
        t = float(seg["t0"][-1] + seg["dt"][-1])
        last = pts[-1]
        yield seg, np.zeros(len(seg), np.uint8)


def _machine(kin: str):
    from gcodeplan.machine import Machine

    m = Machine(kinematics=kin)
    for ax, spm in zip("xyze", (80.0, 80.0, 400.0, 95.52)):
        m.axes[ax].steps_per_mm = spm
    return m


def _run(batches, rails, compress: bool):
    from gcodeplan.stepper.compress import Compressor
    from gcodeplan.stepper.generate import StepGenerator

    comps = [Compressor(hold_back=True) for _ in rails] if compress else None
    n_runs = [0]
    comp_t = [0.0]

    def sink(si, t, d):
        if comps is not None:
            c0 = time.perf_counter()
            n_runs[0] += len(comps[si].feed(t, d))
            comp_t[0] += time.perf_counter() - c0

    gen = StepGenerator(rails, sink)
    kernel_t = 0.0
    for seg, reset in batches:
        k0 = time.perf_counter()
        gen.feed(seg, reset)
        kernel_t += time.perf_counter() - k0
    k0 = time.perf_counter()
    gen.finish()
    kernel_t += time.perf_counter() - k0
    if comps is not None:
        c0 = time.perf_counter()
        n_runs[0] += sum(len(c.finish()) for c in comps)
        comp_t[0] += time.perf_counter() - c0
        kernel_t += time.perf_counter() - c0
    steps = int(sum(st[0] for st in gen.stats))
    return steps, kernel_t - comp_t[0], comp_t[0], n_runs[0]


CUBE = "prusaslicer25_cube20_marlin2"
STEPPERS = ("stepper_x", "stepper_y", "stepper_z", "extruder")


def compress_figure(chunk: int = 1 << 20, repeat: int = 5) -> int:
    """Compressor speed and queue_step counts on Klipper's exact steps of the cube, against Klipper's commands."""
    from gcodeplan.stepper.compress import Compressor

    ref = SHARED / "reference" / "klipper"
    exact_f = ref / "steps" / f"{CUBE}_corexy_exact_steps.npz"
    cmds_f = ref / "compression" / f"{CUBE}_corexy_queue_step.npz"
    if not (exact_f.exists() and cmds_f.exists()):
        print(f"  compression: skipped ({exact_f.parent.parent} not available)")
        return 0
    exact = np.load(exact_f)
    cmds = np.load(cmds_f)
    start = -round(float(cmds["first_move_print_time_s"]) * float(cmds["clock_hz"]))
    streams = [(np.ascontiguousarray(exact[s]), np.ascontiguousarray(exact[s + "_dir"], np.int8)) for s in STEPPERS]
    n_steps = sum(len(t) for t, _ in streams)

    def one_pass():
        counts = []
        for t, d in streams:
            comp = Compressor(start_clock=start, hold_back=True)
            k = sum(len(comp.feed(t[i:i + chunk], d[i:i + chunk])) for i in range(0, len(t), chunk))
            counts.append(k + len(comp.finish()))
        return counts

    one_pass()                                   # compile (numba cache) outside the timings
    best = float("inf")
    for _ in range(repeat):
        c0 = time.thread_time()                  # CPU time of this thread: the figure is per core
        counts = one_pass()
        best = min(best, time.thread_time() - c0)
    klipper = [len(cmds[s + "_count"]) for s in STEPPERS]
    print(f"  compression (Klipper's cube exact steps, corexy, 25 us, {chunk:,}-step chunks): "
          f"{n_steps:,} steps in {best * 1e3:.0f} ms CPU -> {n_steps / best / 1e6:.1f} M steps/s per core "
          f"(best of {repeat})")
    print(f"    queue_step commands x/y/z/e: ours {'/'.join(map(str, counts))} = {sum(counts):,}; "
          f"Klipper {'/'.join(map(str, klipper))} = {sum(klipper):,} "
          f"(ours / Klipper = {sum(counts) / sum(klipper):.3f}; Klipper's batch flushes cut runs every 0.25 s, "
          f"without them its algorithm gives 43831/42171/6009/30373 = 122,384)")
    return 0


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="bench.py steps", description=__doc__.splitlines()[0])
    ap.add_argument("file", nargs="?", help="G-code file (default: the largest file of ../shared/gcode)")
    ap.add_argument("--kinematics", default="cartesian", choices=("cartesian", "corexy"))
    ap.add_argument("--synthetic", type=int, metavar="N", help="N random moves instead of a file")
    ap.add_argument("--no-compress", action="store_true", help="skip the run with compression")
    ap.add_argument("--compress-only", action="store_true",
                    help="only the compression figure on Klipper's exact steps of the cube")
    args = ap.parse_args(argv)
    if args.compress_only:
        print("steps benchmark: compression")
        return compress_figure()

    from gcodeplan.kinematics import rails_for
    from gcodeplan.stepper.synth import line_segments

    machine = _machine(args.kinematics)
    rails = rails_for(machine)
    # compile (numba cache) outside the timings
    _run([(line_segments((0, 0, 0, 0), (5, 3, 1, 1), 0, 50, 0, 1000), np.zeros(3, np.uint8))], rails, True)

    def batches():
        if args.synthetic:
            return _synthetic_batches(args.synthetic)
        from gcodeplan.stepper.source import segment_batches

        path = args.file or _largest_corpus_file()
        if path is None:
            sys.exit("no G-code file given and ../shared/gcode is empty")
        return segment_batches(str(path), machine)

    # the plan is cached in memory only for synthetic runs; files are re-planned for each run
    what = f"{args.synthetic} random moves" if args.synthetic else str(args.file or _largest_corpus_file())
    print(f"steps benchmark: {what}, {args.kinematics}")
    w0 = time.perf_counter()
    steps, kern_t, _, _ = _run(batches(), rails, compress=False)
    wall = time.perf_counter() - w0
    print(f"  exact steps     : {steps:,} steps, kernel {kern_t:.2f} s -> {steps / kern_t / 1e6:.1f} M steps/s "
          f"(wall incl. parse+plan {wall:.1f} s)")
    if not args.no_compress:
        w0 = time.perf_counter()
        steps, kern_t, comp_t, n_runs = _run(batches(), rails, compress=True)
        wall = time.perf_counter() - w0
        print(f"  with compression: {steps:,} steps in {n_runs:,} runs ({steps / max(n_runs, 1):.1f} steps/run), "
              f"kernel+compress {kern_t + comp_t:.2f} s -> {steps / (kern_t + comp_t) / 1e6:.1f} M steps/s "
              f"(wall {wall:.1f} s)")
    if not args.no_compress:
        compress_figure()
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"  peak memory (max RSS): {peak_mb:.0f} MB")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
