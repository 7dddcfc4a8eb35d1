"""``gcodeplan steps FILE -o steps.npz``: exact per-stepper step times of a G-code file.

Writes, for every stepper, ``<stepper>`` (float64 step times, s from the start
of the first move) and ``<stepper>_dir`` (int8 ±1), the layout of Klipper's
reference files, plus ``steppers``, ``steps_per_mm`` and ``kinematics``. Stepper
names are Klipper's sections (``stepper_x`` … ``extruder``) when the machine
comes from a printer.cfg, otherwise ``x y z e`` (cartesian) / ``a b z e``
(corexy, A = X + Y, B = X − Y). The step convention is documented in
:mod:`gcodeplan.stepper.kernel`.
"""
from __future__ import annotations

import argparse
import math
import sys

import numpy as np

from ..errors import GcodeplanError
from .common import add_machine_arguments, add_plan_arguments, check_plan_arguments, machine_from_args, progress_bar
from ..stepper import DEFAULT_CLOCK_HZ, DEFAULT_MAX_ERROR_S, KLIPPER_SDS_FILTER_T


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("file", help="G-code file")
    add_machine_arguments(p)
    add_plan_arguments(p)
    out = p.add_argument_group("output")
    out.add_argument("-o", "--output", required=True, metavar="steps.npz",
                     help="step times per stepper (.npz, written atomically; '-': standard output, "
                          "never a terminal)")
    out.add_argument("--format", choices=("plain", "compact"), default="plain",
                     help="plain: float64 times and int8 directions, Klipper's reference layout (9 bytes a "
                          "step); compact: the same times bit for bit, deflated (many times smaller; read it "
                          "with gcodeplan.stepper.export.load_steps)")
    out.add_argument("--csv", metavar="DIR",
                     help="also write DIR/<stepper>.csv (time_s,dir per step); DIR is made if missing "
                          "and removed again if the run fails")
    out.add_argument("--compress", action="store_true",
                     help="also store Klipper-style queue_step runs <stepper>_runs (interval, count, add, dir) "
                          "in clock ticks")
    out.add_argument("--clock-hz", type=float, default=DEFAULT_CLOCK_HZ, metavar="HZ",
                     help="MCU clock for --compress (default 50e6, Klipper's Linux MCU)")
    out.add_argument("--max-error", type=float, default=DEFAULT_MAX_ERROR_S, metavar="S",
                     help="--compress: a step may be this much early, never late (default 25e-6 s, "
                          "Klipper's max_stepcompress_error)")
    out.add_argument("--sds-filter", nargs="?", type=float, const=KLIPPER_SDS_FILTER_T, default=None,
                     metavar="S",
                     help="drop a step and its immediate reversal when closer than S "
                          f"(Klipper's step+dir+step filter; default S = {KLIPPER_SDS_FILTER_T * 1e6:g} µs)")
    out.add_argument("--ik-search", choices=("klipper", "exact", "fit"), default="klipper",
                     help="how a plug-in kinematics' motors are stepped: Klipper's own search (default; within "
                          "~10 ns of Klipper's steps), the guarded exact search (about 2x faster, each step within "
                          "1 ns of its half-step point; rotary joints up to ~1.3 µs from Klipper's) or 'fit': the "
                          "exact search's steps from verified polynomial stand-ins of the ik (no ik call per step)")
    out.add_argument("--klipper-batch", action="store_true",
                     help="generate the steps in the windows of Klipper's batch mode (klippy.py -i FILE -o OUT) "
                          "for exactly this file's bytes, as Klipper's reference step files were made; default: "
                          "a window every 0.25 s, as a printer whose host keeps up (Klipper policy only)")
    out.add_argument("--max-step-rate", type=float, metavar="STEPS_PER_S",
                     help="warn when a stepper exceeds this rate (default: the machine's max_step_rate)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar, no summary")


def _check_args(args) -> None:
    if not (args.clock_hz > 0 and math.isfinite(args.clock_hz)):
        raise GcodeplanError(f"--clock-hz must be a positive number, got {args.clock_hz:g}")
    if not (args.max_error >= 0 and math.isfinite(args.max_error)):
        raise GcodeplanError(f"--max-error must be ≥ 0 s, got {args.max_error:g}")
    if args.sds_filter is not None and not (args.sds_filter > 0 and math.isfinite(args.sds_filter)):
        raise GcodeplanError(f"--sds-filter must be a positive time in s, got {args.sds_filter:g}")
    check_plan_arguments(args)
    if args.csv is not None and args.csv in ("-", ""):
        raise GcodeplanError("--csv takes a directory (one file per stepper), not standard output")
    if args.max_step_rate is not None and not (args.max_step_rate > 0):
        raise GcodeplanError(f"--max-step-rate must be > 0, got {args.max_step_rate:g}")


def _klipper_batch_windows(args, machine) -> np.ndarray:
    """--klipper-batch: Klipper's batch-mode step-generation windows for the file (stepper.klipper_batch)."""
    from ..stepper.klipper_batch import klipper_batch_flush_times

    if args.file in ("-", ""):
        raise GcodeplanError("--klipper-batch reads the file's bytes: give a file, not standard input")
    if (args.policy or machine.junction_policy) != "klipper" or args.jerk is not None:
        raise GcodeplanError("--klipper-batch: Klipper's windows follow Klipper's plan (policy klipper, no --jerk)")
    try:
        return klipper_batch_flush_times(args.file, machine)
    except OSError as err:
        raise GcodeplanError(f"cannot read {args.file}: {err.strerror or err}") from None


def summary_line(name: str, st: np.ndarray) -> str:
    """One line per stepper from a :func:`kernel.step_stats` vector."""
    count = int(st[0])
    if count == 0:
        return f"{name}: 0 steps"
    peak = 1.0 / st[5] if st[5] > 0 and math.isfinite(st[5]) else 0.0
    shortest = f"{st[4] * 1e6:.3f} µs" if math.isfinite(st[4]) else "-"
    return (f"{name}: {count} steps (net {int(st[7]):+d}), peak {peak:,.0f} steps/s, "
            f"shortest interval {shortest}, {int(st[1])} direction changes")


def _declare_step_arrays(writer, names: list[str], args):
    """Declare the .npz arrays every stepper's steps are appended to (``--format``, ``--compress``); returns
    (per-stepper compact encoders or None, per-stepper compressors or None)."""
    from ..stepper import compress as cmp
    from ..stepper.export import CompactEncoder

    encoders = None
    if args.format == "compact":
        encoders = [CompactEncoder() for _ in names]
        for name in names:
            writer.declare(name + "_times_z", np.uint8)
            writer.declare(name + "_dir_z", np.uint8)
    else:
        for name in names:
            writer.declare(name, np.float64)
            writer.declare(name + "_dir", np.int8)
    compressors = None
    if args.compress:
        compressors = [cmp.Compressor(args.clock_hz, args.max_error, hold_back=True) for _ in names]
        for name in names:
            writer.declare(name + "_runs", cmp.RUN_DTYPE)
    return encoders, compressors


def _finish_step_arrays(writer, rails, machine, args, encoders, compressors) -> None:
    """After the last step: what the encoders and compressors held back, then the file's description arrays
    (steppers, steps/mm, kinematics, filter, clock)."""
    from ..stepper.export import COMPACT_FORMAT

    names = [r.name for r in rails]
    if compressors is not None:             # the runs held back until the last step (compress.Compressor)
        for name, comp in zip(names, compressors):
            writer.append(name + "_runs", comp.finish())

    if encoders is not None:
        for name, enc in zip(names, encoders):
            tz, dz = enc.finish()
            writer.append(name + "_times_z", np.frombuffer(tz, np.uint8))
            writer.append(name + "_dir_z", np.frombuffer(dz, np.uint8))
            writer.put(name + "_blocks", np.array(enc.blocks, np.int64))
            writer.put(name + "_widths", np.array(enc.widths, np.uint8))
        writer.put("format", np.array(COMPACT_FORMAT))
    writer.put("steppers", np.array(names))
    writer.put("steps_per_mm", np.array([r.steps_per_mm for r in rails], np.float64))
    writer.put("kinematics", np.array(machine.kinematics))
    writer.put("sds_filter_s", np.array(args.sds_filter if args.sds_filter is not None else 0.0))
    if args.compress:
        writer.put("clock_hz", np.array(args.clock_hz))
        writer.put("max_error_s", np.array(args.max_error))


def run(args) -> int:
    from .. import pipeline
    from ..report.output import keep_made_dirs, make_dirs, refuse_terminal, remove_made_dirs
    from ..signals import held
    from ..stepper.export import CsvStepWriter, NpzStreamWriter
    from ..stepper.source import StepSink, rails_from

    _check_args(args)
    machine = machine_from_args(args)
    rails = rails_from(machine, klipper_names=bool(getattr(args, "klipper_config", None)))
    names = [r.name for r in rails]
    max_rate = args.max_step_rate if args.max_step_rate is not None else machine.max_step_rate

    writer = None
    csv = None
    bar = None
    made: list[str] = []
    try:
        with held():     # no signal between creating the spool and knowing it (the except below cleans up)
            writer = NpzStreamWriter(args.output)       # fails early on an unwritable place
        # the summary goes to standard error when the .npz itself goes to standard output
        report = sys.stderr if refuse_terminal(args.output, "an .npz file").kind == "stdout" else sys.stdout
        if args.csv:
            try:
                made = make_dirs(args.csv)              # what we make we remove again on failure
            except OSError as err:
                raise GcodeplanError(f"cannot write {args.csv}: {err.strerror or err}") from None
            csv = CsvStepWriter(args.csv, names)
        encoders, compressors = _declare_step_arrays(writer, names, args)

        def sink(si: int, times: np.ndarray, dirs: np.ndarray) -> None:
            name = names[si]
            if encoders is not None:
                tz, dz = encoders[si].feed(times, dirs)
                writer.append(name + "_times_z", np.frombuffer(tz, np.uint8))
                writer.append(name + "_dir_z", np.frombuffer(dz, np.uint8))
            else:
                writer.append(name, times)
                writer.append(name + "_dir", dirs)
            if csv is not None:
                csv.append(si, times, dirs)
            if compressors is not None:
                writer.append(name + "_runs", compressors[si].feed(times, dirs))

        gen = StepSink(rails, sink, sds_filter_t=args.sds_filter, machine=machine, ik_search=args.ik_search)
        if getattr(args, "klipper_batch", False):
            gen.generator.flush_times = _klipper_batch_windows(args, machine)
        bar, progress = progress_bar(args.file, args.quiet)
        pipeline.run(args.file, machine, policy=args.policy, jerk=args.jerk, strict=args.strict, sinks=[gen],
                     progress=progress)
        _finish_step_arrays(writer, rails, machine, args, encoders, compressors)
        writer.commit()
        if csv is not None:
            csv.commit()
        keep_made_dirs(made)
    except BaseException:
        if writer is not None:
            writer.abort()
        if csv is not None:
            csv.abort()
        remove_made_dirs(made)
        raise
    finally:
        if bar is not None:
            bar.close()

    for rail, st in zip(rails, gen.stats):
        if not args.quiet:
            print(summary_line(rail.name, st), file=report)
        if math.isfinite(max_rate) and st[5] > 0 and 1.0 / st[5] > max_rate:
            print(f"gcodeplan: warning: {rail.name} reaches {1.0 / st[5]:,.0f} steps/s at t = {st[6]:.6f} s, "
                  f"above the maximum step rate {max_rate:,.0f} steps/s", file=sys.stderr)
    return 0
