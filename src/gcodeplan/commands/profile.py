"""``gcodeplan profile``: solve one 1-D profile, print its phases and total time, optionally plot it."""
from __future__ import annotations

import argparse
import math
import os

import numpy as np

from ..errors import GcodeplanError
from ..profiles.core import Profile
from ..profiles.scurve import scurve
from ..profiles.trapezoid import trapezoid


def _number(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--distance", type=_number, required=True, metavar="D", help="mm to travel (>= 0)")
    p.add_argument("--v-max", type=_number, required=True, metavar="V", help="mm/s velocity limit")
    p.add_argument("--a-max", type=_number, required=True, metavar="A", help="mm/s² acceleration limit")
    p.add_argument("--j-max", type=_number, metavar="J",
                   help="mm/s³ jerk limit: gives a seven-phase S-curve (default: a trapezoid)")
    p.add_argument("--decel", type=_number, metavar="D",
                   help="mm/s² deceleration for trapezoids when it differs from --a-max")
    p.add_argument("--v-start", type=_number, default=0.0, metavar="V0", help="mm/s at the start (default 0)")
    p.add_argument("--v-end", type=_number, default=0.0, metavar="V1", help="mm/s at the end (default 0)")
    p.add_argument("--plot", metavar="out.png",
                   help="draw position, velocity, acceleration and jerk against time (.png, .svg or .pdf; "
                        "'-' or a device/pipe: PNG, never to a terminal)")


def solve(args: argparse.Namespace) -> Profile:
    """The profile the arguments ask for; bad arguments become one-line GcodeplanErrors."""
    try:
        if args.j_max is not None:
            if args.decel is not None:
                raise ValueError("--decel applies to trapezoids only (S-curves use --a-max both ways)")
            return scurve(args.distance, args.v_max, args.a_max, args.j_max, args.v_start, args.v_end)
        return trapezoid(args.distance, args.v_max, args.a_max, args.v_start, args.v_end, args.decel)
    except ValueError as err:   # InfeasibleProfile is a ValueError
        msg = str(err)
        for name in ("distance", "v_max", "a_max", "j_max", "v_start", "v_end", "decel"):
            if msg.startswith(name + " "):    # name the option the user typed
                msg = "--" + name.replace("_", "-") + msg[len(name):]
                break
        raise GcodeplanError(msg) from None


def format_phases(p: Profile) -> str:
    unit = "mm/s³" if p.phase_value == "jerk" else "mm/s²"
    head = f"{'phase':>5} {'start s':>12} {'duration s':>12} {p.phase_value + ' ' + unit:>16} {'v at end mm/s':>14}"
    lines = [f"{p.kind}: distance {p.distance:g} mm, v_start {p.v_start:g} mm/s, v_end {p.v_end:g} mm/s, "
             f"peak {p.peak_velocity:.9g} mm/s", head]
    for k, row in enumerate(p.phase_table(), 1):
        lines.append(f"{k:>5} {row['t_start']:>12.9f} {row['duration']:>12.9f} {row[p.phase_value]:>16.6g} "
                     f"{row['velocity_end']:>14.6f}")
    lines.append(f"total time: {p.duration:.9f} s")
    return "\n".join(lines)


def plot_times(p: Profile, n: int = 1000) -> np.ndarray:
    """Sample times for a plot: an even grid plus both sides of every phase boundary (steps stay steps)."""
    T = p.duration
    grid = np.linspace(0.0, T, n)
    bounds = p.pieces["t0"][1:]
    eps = 1e-9 * max(T, 1e-300)
    t = np.concatenate((grid, bounds, np.clip(bounds - eps, 0.0, T)))
    return np.unique(t)


def plot_profile(p: Profile, path: str, n: int = 1000):
    """Write a PNG with position, velocity, acceleration and jerk against time; return the figure (closed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = plot_times(p, n)
    values = p.sample(t)
    labels = ("position (mm)", "velocity (mm/s)", "acceleration (mm/s²)", "jerk (mm/s³)")
    fig, axes = plt.subplots(4, 1, sharex=True, figsize=(8, 9))
    for ax, y, label in zip(axes, values, labels):
        ax.plot(t, y, lw=1.4)
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
    axes[-1].set_xlabel("time (s)")
    axes[0].set_title(f"{p.kind}: {p.distance:g} mm in {p.duration:.6g} s, peak {p.peak_velocity:.6g} mm/s")
    fig.tight_layout()
    try:
        from ..report.output import atomic_output

        fmt = _plot_format(path)
        with atomic_output(path, "wb", tty_ok=fmt == "svg", what=f"a {fmt.upper()} picture") as fh:
            fig.savefig(fh, format=fmt, dpi=100)      # whole or not at all (report/output.py)
    except OSError as err:
        raise GcodeplanError(f"cannot write plot: {err}", file=path) from None
    finally:
        plt.close(fig)
    return fig


def _plot_format(path: str) -> str:
    """png / svg / pdf from the name; PNG for standard output or a device/pipe without such an ending."""
    from ..report.output import resolve_output

    ext = os.path.splitext(str(path))[1].lower().lstrip(".")
    if ext in ("png", "svg", "pdf"):
        return ext
    if resolve_output(path).is_stream:
        return "png"
    raise GcodeplanError(f"{path}: the picture's name must end in .png, .svg or .pdf")


def run(args: argparse.Namespace) -> int:
    for name in ("distance", "v_max", "a_max", "j_max", "decel", "v_start", "v_end"):
        value = getattr(args, name)
        if value is not None and math.isnan(value):
            raise GcodeplanError(f"--{name.replace('_', '-')} must be a number, got nan")
    if args.plot:       # refuse a bad name, place or a terminal before any work
        from ..report.output import refuse_terminal, resolve_output

        try:
            fmt = _plot_format(args.plot)
            if fmt != "svg":
                refuse_terminal(args.plot, f"a {fmt.upper()} picture")
            to_stdout = resolve_output(args.plot).kind == "stdout"
        except GcodeplanError as err:
            raise GcodeplanError(str(err).replace("cannot write ", "cannot write plot ", 1)) from None
    p = solve(args)
    if not (args.plot and to_stdout):       # the picture alone goes to standard output
        print(format_phases(p))
    if args.plot:
        plot_profile(p, args.plot)
        if not to_stdout:
            print(f"plot written to {args.plot}")
    return 0
