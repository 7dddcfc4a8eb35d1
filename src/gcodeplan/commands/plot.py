"""``gcodeplan plot``: draw the velocity profile, per-axis motion, toolpath or time per layer of a file.

The whole file is planned from its start (a window's times depend on everything before it), chunk by
chunk through the stream planner; only the selected window's MOVE/PLAN rows are kept, and reading
stops once the window is complete. Segments are made for the window only.
"""
from __future__ import annotations

import argparse
import math
import os
from dataclasses import dataclass

import numpy as np

from .common import add_machine_arguments, add_plan_arguments, check_plan_arguments
from ..errors import GcodeplanError
from ..report import plots

WHATS = ("velocity", "axes", "path", "layers")
MAX_WINDOW_MOVES = 500_000     # beyond this a window is refused: choose a smaller one
FORMATS = {".png": "png", ".svg": "svg", ".pdf": "pdf"}


# ----------------------------------------------------------------------------- selection
@dataclass
class Selection:
    """Which moves to draw: a time range (s), a source line range, or a layer index; none = all."""

    t_from: float | None = None
    t_to: float | None = None
    lines: tuple[int, int] | None = None
    layer: int | None = None

    def describe(self) -> str:
        if self.layer is not None:
            return f"layer {self.layer}"
        if self.lines is not None:
            return f"lines {self.lines[0]}:{self.lines[1]}"
        if self.t_from is not None or self.t_to is not None:
            a = 0.0 if self.t_from is None else self.t_from
            b = "end" if self.t_to is None else f"{self.t_to:g} s"
            return f"t = {a:g} s to {b}"
        return "whole file"

    def hits(self, moves: np.ndarray, plan: np.ndarray) -> np.ndarray:
        """Rows inside the window (a move overlapping a time range counts)."""
        if self.layer is not None:
            return moves["layer"] == self.layer
        if self.lines is not None:
            return (moves["line"] >= self.lines[0]) & (moves["line"] <= self.lines[1])
        hit = np.ones(moves.size, dtype=bool)
        if self.t_from is not None:
            hit &= plan["t_start"] + plan["duration"] > self.t_from
        if self.t_to is not None:
            hit &= plan["t_start"] < self.t_to
        return hit

    def past(self, moves: np.ndarray, plan: np.ndarray) -> bool:
        """True when the last row of this chunk lies after the window. Layer indices, line
        numbers and times only grow through a file, so nothing later can be inside."""
        if moves.size == 0:
            return False
        if self.layer is not None:
            return int(moves["layer"][-1]) > self.layer
        if self.lines is not None:
            return int(moves["line"][-1]) > self.lines[1]
        if self.t_to is not None:
            return float(plan["t_start"][-1]) >= self.t_to
        return False


def parse_lines(text: str) -> tuple[int, int]:
    """``A:B`` (1-based, inclusive) → (A, B)."""
    a, sep, b = text.partition(":")
    try:
        lo, hi = int(a), int(b)
    except ValueError:
        lo = hi = None
    if not sep or lo is None or lo < 1 or hi < lo:
        raise GcodeplanError(f"--lines: expected A:B with 1 ≤ A ≤ B (line numbers), got {text!r}")
    return lo, hi


# ----------------------------------------------------------------------------- planning
def _policy_jerk(machine, policy: str | None, jerk: float | None):
    policy = policy or machine.junction_policy
    if jerk is not None and not (jerk > 0 and math.isfinite(jerk)):
        raise GcodeplanError("--jerk must be a positive number (mm/s³)")
    return policy, jerk


def stream_plan(path: str, machine, policy: str | None, jerk: float | None, strict: bool, on_chunk,
                progress=None):
    """Plan ``path`` from its start and call ``on_chunk(moves, plan, first_index)`` for each planned
    piece in order (``first_index`` = global row of ``moves[0]``); stop early when it returns True.

    ``on_chunk(moves, plan, first_index, segs)``: ``segs`` are the planner's own SEGMENT rows of the
    piece for blend and S-curve plans (they cannot be rebuilt from PLAN rows; global move indices), None
    for trapezoid plans (the caller makes them for what it keeps with ``segments_for``), so a caller
    keeps only the pieces it wants and memory stays bounded. ``progress(bytes_done)``: as
    :func:`gcodeplan.pipeline.run`. Returns the reader.
    """
    from .. import pipeline

    policy, jerk = _policy_jerk(machine, policy, jerk)

    def hand_over(piece):
        # blend / S-curve pieces exist only now; trapezoid pieces the caller makes for what it keeps
        segs = piece.segments if piece.own_segments else None
        return on_chunk(piece.moves, piece.plan, piece.first_move, segs)

    return pipeline.run(path, machine, policy=policy, jerk=jerk, strict=strict,
                        sinks=[pipeline.FunctionSink(hand_over)], progress=progress).reader


def segments_for(moves: np.ndarray, plan: np.ndarray, first_index: int, own_segs: list | None = None):
    """SEGMENT rows of a contiguous run of planned moves: the planner's own pieces when it handed them
    over (blend, S-curves; ``own_segs`` = the list of them, cut to the run), else made by the planner's
    ``to_segments`` (trapezoids)."""
    if own_segs:
        segs = np.concatenate(own_segs)
        lo, hi = first_index, first_index + moves.size
        return segs[(segs["move"] >= lo) & (segs["move"] < hi)]
    from ..planner import to_segments

    if plan.size and np.any(plan["jerk"] != 0.0):
        raise GcodeplanError("S-curve plans are drawn from the S-curve planner's own segments")
    return to_segments(moves, plan, first_index)


class WindowCollector:
    """Keeps the planned rows from the first move in the selection to the last one (a contiguous
    span, so that global move indices stay consecutive)."""

    def __init__(self, sel: Selection, max_moves: int = MAX_WINDOW_MOVES):
        self.sel = sel
        self.max_moves = max_moves
        self.parts: list[tuple[np.ndarray, np.ndarray]] = []
        self.own_segs: list[np.ndarray] = []     # blend / S-curve pieces of the kept parts
        self.first_index: int | None = None
        self.kept = 0
        self.last_hit = -1       # global index of the last selected row
        self.end_t = 0.0
        self.last_line = 0
        self.max_layer = -1

    def __call__(self, moves: np.ndarray, plan: np.ndarray, first: int, segs: np.ndarray | None = None) -> bool:
        if moves.size == 0:
            return False
        self.end_t = float(plan["t_start"][-1] + plan["duration"][-1])
        self.last_line = int(moves["line"][-1])
        self.max_layer = max(self.max_layer, int(moves["layer"].max()))
        hit = np.flatnonzero(self.sel.hits(moves, plan))
        if self.first_index is None:
            if hit.size == 0:
                return self.sel.past(moves, plan)
            self.first_index = first + int(hit[0])
            moves, plan = moves[hit[0]:], plan[hit[0]:]
            hit = hit - hit[0]
        if hit.size:
            self.last_hit = self.first_index + self.kept + int(hit[-1])
        self.parts.append((moves, plan))
        if segs is not None:
            self.own_segs.append(segs[segs["move"] >= self.first_index])
        self.kept += moves.size
        if self.sel.past(moves, plan):
            return True
        if self.last_hit - self.first_index + 1 > self.max_moves:
            raise GcodeplanError(f"the selected window ({self.sel.describe()}) has more than {self.max_moves} "
                                 "moves: choose a smaller one with --from/--to, --lines or --layer")
        return False

    def window(self, limits: np.ndarray, label: str, feature_names=()) -> plots.Window:
        if self.first_index is None:
            raise GcodeplanError(
                f"no moves in the selected window ({self.sel.describe()}): the file's plan ends at "
                f"t = {self.end_t:.3f} s, line {self.last_line}, "
                + (f"layers 0–{self.max_layer}" if self.max_layer >= 0 else "no layer changes"))
        moves = np.concatenate([m for m, _ in self.parts])
        plan = np.concatenate([p for _, p in self.parts])
        n = self.last_hit - self.first_index + 1
        moves, plan = moves[:n], plan[:n]
        segs = segments_for(moves, plan, self.first_index, self.own_segs)
        segs = _clip_segments(segs, self.sel)
        return plots.Window(moves, plan, segs, self.first_index, np.asarray(limits).copy(), label,
                            list(feature_names))


def _clip_segments(segs: np.ndarray, sel: Selection) -> np.ndarray:
    """For a time window, cut the pieces at its ends (the polynomial is re-based at the new start)."""
    if segs.size == 0 or (sel.t_from is None and sel.t_to is None) or sel.layer is not None or sel.lines is not None:
        return segs
    lo = -math.inf if sel.t_from is None else sel.t_from
    hi = math.inf if sel.t_to is None else sel.t_to
    t1 = segs["t0"] + segs["dt"]
    segs = segs[(t1 > lo) & (segs["t0"] < hi)].copy()
    if segs.size == 0:
        return segs
    shift = np.maximum(lo - segs["t0"], 0.0)
    cut = shift > 0
    if cut.any():
        s = segs[cut]
        idx = np.flatnonzero(cut)
        pos, vel, acc, _ = plots.eval_segments(segs, idx, shift[cut])
        for k, a in enumerate(plots.AXES):
            s["p" + a], s["v" + a], s["a" + a] = pos[:, k], vel[:, k], acc[:, k]
        s["t0"] = s["t0"] + shift[cut]
        s["dt"] = s["dt"] - shift[cut]
        segs[cut] = s
    end = segs["t0"] + segs["dt"]
    segs["dt"] = np.where(end > hi, hi - segs["t0"], segs["dt"])
    return segs[segs["dt"] > 0]


def load_window(path: str, machine, sel: Selection, policy: str | None = None, jerk: float | None = None,
                strict: bool = False, progress=None) -> tuple[plots.Window, object]:
    """Plan ``path`` from its start and return the selected window (with its segments) and the reader."""
    collect = WindowCollector(sel)
    reader = stream_plan(path, machine, policy, jerk, strict, collect, progress)
    label = f"{os.path.basename(path)} ({sel.describe()})"
    return collect.window(reader.limits, label, reader.features), reader


def load_layer_times(path: str, machine, policy: str | None = None, jerk: float | None = None,
                     strict: bool = False, progress=None) -> tuple[plots.LayerFeatureTimes, object]:
    """Plan the whole file and return its time per (layer, feature) and the reader."""
    times = plots.LayerFeatureTimes()

    def fold(m, p, first, segs):
        times.add(m, p)
        return False

    reader = stream_plan(path, machine, policy, jerk, strict, fold, progress)
    return times, reader


# ----------------------------------------------------------------------------- command
def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("file", metavar="FILE", help="G-code file")
    add_machine_arguments(p)
    p.add_argument("-o", "--output", metavar="OUT.png",
                   help="picture to write (.png, .svg or .pdf; '-' or a device/pipe without one of these "
                        "endings: PNG, never to a terminal); default FILE_<what>.png beside the input, "
                        "stdin_<what>.png in the current directory when FILE is standard input")
    p.add_argument("--what", choices=WHATS, default="velocity",
                   help="velocity: speed/acceleration/jerk against time; axes: per-axis position and velocity; "
                        "path: XY toolpath coloured by speed; layers: time per layer by feature (default velocity)")
    win = p.add_argument_group("window (velocity, axes, path; default: the whole file)")
    win.add_argument("--from", dest="t_from", type=float, metavar="T0", help="start time (s)")
    win.add_argument("--to", dest="t_to", type=float, metavar="T1", help="end time (s)")
    win.add_argument("--lines", metavar="A:B", help="source lines A to B (inclusive)")
    win.add_argument("--layer", type=int, metavar="N", help="layer index N (0 = first layer)")
    add_plan_arguments(p)
    p.add_argument("--size", default="1600x900", metavar="WxH", help="picture size in pixels (default 1600x900)")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress bar")


def parse_size(text: str) -> tuple[float, float]:
    w, sep, h = text.lower().partition("x")
    try:
        wi, hi = int(w), int(h)
    except ValueError:
        wi = hi = 0
    if not sep or not (200 <= wi <= 10000 and 200 <= hi <= 10000):
        raise GcodeplanError(f"--size: expected WxH in pixels, each 200..10000, got {text!r}")
    return wi / plots.DPI, hi / plots.DPI


def selection_from_args(args) -> Selection:
    chosen = [name for name, val in (("--from/--to", args.t_from is not None or args.t_to is not None),
                                     ("--lines", args.lines is not None), ("--layer", args.layer is not None)) if val]
    if len(chosen) > 1:
        raise GcodeplanError(f"choose one window: {' and '.join(chosen)} were both given")
    for name, val in (("--from", args.t_from), ("--to", args.t_to)):
        if val is not None and not math.isfinite(val):
            raise GcodeplanError(f"{name} must be a finite time in seconds, got {val}")
    if args.t_from is not None and args.t_to is not None and args.t_to <= args.t_from:
        raise GcodeplanError(f"--to ({args.t_to:g} s) must be after --from ({args.t_from:g} s)")
    if args.layer is not None and args.layer < 0:
        raise GcodeplanError(f"--layer must be 0 or more, got {args.layer}")
    return Selection(args.t_from, args.t_to, parse_lines(args.lines) if args.lines else None, args.layer)


def output_path(args) -> tuple[str, str]:
    """(path, format) of the picture; refuses a bad name or place before any planning."""
    from ..report.output import default_output, refuse_terminal, resolve_output

    out = args.output or default_output(args.file, f"_{args.what}.png")
    ext = os.path.splitext(out)[1].lower()
    target = resolve_output(out)
    if ext not in FORMATS:
        if not target.is_stream:
            raise GcodeplanError(f"{out}: the picture's name must end in .png, .svg or .pdf")
        ext = ".png"          # standard output, /dev/null, a pipe: PNG
    if FORMATS[ext] != "svg":
        refuse_terminal(out, f"a {FORMATS[ext].upper()} picture")
    return out, FORMATS[ext]


def draw(what: str, win: plots.Window | None, machine, size_in, layer_times=None, reader=None):
    if what == "velocity":
        return plots.plot_velocity(win, size_in=size_in)
    if what == "axes":
        return plots.plot_axes(win, machine, size_in=size_in)
    if what == "path":
        return plots.plot_path(win, size_in=size_in, machine=machine)
    return plots.plot_layers(layer_times, list(reader.features), list(reader.layer_z),
                             title=f"{os.path.basename(reader.path)}: time per layer", size_in=size_in)


def run(args) -> int:
    from .common import machine_from_args

    check_plan_arguments(args)
    machine = machine_from_args(args)
    size_in = parse_size(args.size)
    out, fmt = output_path(args)
    from .common import progress_bar

    if args.what == "layers" and any(v is not None for v in (args.t_from, args.t_to, args.lines, args.layer)):
        raise GcodeplanError("--what layers draws every layer: drop --from/--to, --lines and --layer")
    sel = selection_from_args(args) if args.what != "layers" else None
    bar, progress = progress_bar(args.file, getattr(args, "quiet", False))
    try:
        if args.what == "layers":
            times, reader = load_layer_times(args.file, machine, args.policy, args.jerk, args.strict, progress)
            fig = draw("layers", None, machine, size_in, times, reader)
        else:
            win, _ = load_window(args.file, machine, sel, args.policy, args.jerk, args.strict, progress)
            fig = draw(args.what, win, machine, size_in)
    finally:
        if bar is not None:
            bar.close()
    from ..report.output import atomic_output

    try:
        with atomic_output(out, "wb", tty_ok=fmt == "svg", what=f"a {fmt.upper()} picture") as fh:
            fig.savefig(fh, format=fmt, dpi=fig.dpi)  # whole or not at all, even on SIGTERM
    except OSError as err:
        raise GcodeplanError(f"cannot write {out}: {err.strerror or err}") from None
    from ..report.output import resolve_output

    if resolve_output(out).kind != "stdout":     # else the picture itself went to standard output
        print(out)
    return 0
