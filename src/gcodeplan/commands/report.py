"""``gcodeplan report``: one self-contained HTML page with the estimate tables and the plots.

One pass over the file: the plan is folded into the time summary and the per-layer/feature table
while the moves of the slowest layers seen so far are kept (a layer is a contiguous run of moves
with the same layer index; at most ``--slowest`` of them plus the current one are held). Files
without layer changes get one window: their first ``MAX_KEEP_MOVES`` moves.
"""
from __future__ import annotations

import argparse
import io
import os
from dataclasses import dataclass, field

import numpy as np

from .. import __version__
from .common import add_machine_arguments, add_plan_arguments, check_plan_arguments
from ..errors import GcodeplanError
from ..schema import KIND_WAIT
from ..report import html, plots
from .plot import parse_size, segments_for, stream_plan

MAX_KEEP_MOVES = 200_000   # moves kept for one drawn layer (a longer layer is drawn from its start)


@dataclass
class LayerRun:
    layer: int
    first_index: int
    time_s: float
    parts: list
    kept: int = 0
    truncated: bool = False
    own_segs: list = field(default_factory=list)

    def add(self, moves: np.ndarray, plan: np.ndarray, time_s: float, segs: np.ndarray | None = None) -> None:
        """``segs``: the planner's own pieces of these moves (blend, S-curves), or None (trapezoids)."""
        self.time_s += time_s
        room = MAX_KEEP_MOVES - self.kept
        if room <= 0:
            self.truncated = True
            return
        if moves.size > room:
            moves, plan, self.truncated = moves[:room], plan[:room], True
        self.parts.append((moves, plan))
        if segs is not None:
            self.own_segs.append(segs[segs["move"] < self.first_index + self.kept + moves.size])
        self.kept += moves.size


class SlowestLayers:
    """Keeps the ``k`` slowest layer runs (by planned time, waits excluded from the choice)."""

    def __init__(self, k: int):
        self.k = k
        self.best: list[LayerRun] = []
        self.current: LayerRun | None = None

    def _close(self) -> None:
        run = self.current
        self.current = None
        if run is None or self.k <= 0:
            return
        self.best.append(run)
        self.best.sort(key=lambda r: -r.time_s)
        del self.best[self.k:]

    def __call__(self, moves: np.ndarray, plan: np.ndarray, first: int, segs: np.ndarray | None = None) -> bool:
        if moves.size == 0:
            return False
        layer = moves["layer"]
        # a heat-up is not a slow layer: waits count for the tables, not for choosing what to draw
        motion_t = np.where(moves["kind"] == KIND_WAIT, 0.0, plan["duration"])
        cuts = np.flatnonzero(layer[1:] != layer[:-1]) + 1
        for a, b in zip(np.r_[0, cuts], np.r_[cuts, moves.size]):
            lay = int(layer[a])
            if self.current is None or self.current.layer != lay:
                self._close()
                self.current = LayerRun(lay, first + int(a), 0.0, [])
            run_segs = None
            if segs is not None:
                run_segs = segs[(segs["move"] >= first + a) & (segs["move"] < first + b)]
            self.current.add(moves[a:b], plan[a:b], float(motion_t[a:b].sum()), run_segs)
        return False

    def finish(self) -> list[LayerRun]:
        self._close()
        return self.best


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("file", metavar="FILE", help="G-code file")
    add_machine_arguments(p)
    p.add_argument("-o", "--output", metavar="REPORT.html",
                   help="page to write ('-': standard output); default FILE.html beside the input, "
                        "stdin.html in the current directory when FILE is standard input")
    add_plan_arguments(p)
    p.add_argument("--slowest", type=int, default=2, metavar="N",
                   help="draw the velocity, axes and path plots of the N slowest layers (default 2)")
    p.add_argument("--size", default="1600x900", metavar="WxH", help="plot size in pixels (default 1600x900)")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress bar")


def _fmt_s(seconds: float) -> str:
    from ..report.summary import hms

    return f"{hms(seconds)} ({seconds:.1f} s)"


def _tables(est, d: dict) -> list[str]:
    t = est.time
    rows = [("total time", _fmt_s(t.total_time_s)),
            ("naive time (length / feed, for contrast)", _fmt_s(d.get("naive_time_s", 0.0)))]
    if d.get("slicer_estimate_s"):
        rows.append(("slicer's own estimate", _fmt_s(d["slicer_estimate_s"])))
    rows += [("printing", _fmt_s(t.print_time_s)), ("travel", _fmt_s(t.travel_time_s)),
             ("extrude-only", _fmt_s(t.extrude_only_time_s)), ("dwell", _fmt_s(t.dwell_s)),
             ("waits (heating, homing)", _fmt_s(t.waits_s))]
    motion = max(t.accel_t + t.cruise_t + t.decel_t, 1e-300)
    rows += [("accelerating / cruising / decelerating",
              f"{100 * t.accel_t / motion:.1f} % / {100 * t.cruise_t / motion:.1f} % / {100 * t.decel_t / motion:.1f} %"),
             ("moves", d.get("moves", 0)), ("full stops", t.stops),
             ("peak speed", f"{t.peak_v:.1f} mm/s (line {t.peak_v_line})")]
    out = [html.section("Time", html.table(("", "value"), rows))]
    lim = t.limits()
    if lim:
        tot = sum(lim.values())
        out.append(html.section("What limited the speed (share of time)", html.table(
            ("limit", "time", "share"),
            [(k, _fmt_s(v), f"{100 * v / tot:.1f} %") for k, v in sorted(lim.items(), key=lambda kv: -kv[1])])))
    feats = t.features(est.features)
    if feats:
        total = max(t.total_time_s, 1e-300)
        out.append(html.section("Time per feature", html.table(
            ("feature", "time", "share"),
            [(k, _fmt_s(v), f"{100 * v / total:.1f} %") for k, v in sorted(feats.items(), key=lambda kv: -kv[1])])))
    layers = t.layers(est.layer_z)
    if layers:
        slow = sorted(layers, key=lambda L: -L["time_s"])[:10]
        out.append(html.section(f"Slowest layers (of {len(layers)})", html.table(
            ("layer", "z (mm)", "time"),
            [(L["index"], "-" if L["z"] is None or not np.isfinite(L["z"]) else f"{L['z']:.3f}", _fmt_s(L["time_s"]))
             for L in slow])))
    unknown = d.get("unknown_commands") or {}
    if unknown:
        out.append(html.section("Not modelled (counted)", html.table(
            ("command", "count"), sorted(unknown.items(), key=lambda kv: -kv[1]))))
    return out


def build_report(path: str, machine, policy: str | None = None, jerk: float | None = None, strict: bool = False,
                 slowest: int = 2, size_in=plots.FIGSIZE_IN, progress=None) -> str:
    """Plan ``path`` once and return the HTML page (the viewer reads the lines' texts again: ``path`` must be
    readable twice, a regular file or :func:`gcodeplan.gcode.sources.spooled`'s copy)."""
    from ..machine import planned_by
    from ..report.estimate import planned_by_text
    from .estimate import Estimate, print_text
    from ..report.summary import TimeSummary
    from ..report.viewer import ViewerSink, thin_for, viewer_data, viewer_fragment

    policy = policy or machine.junction_policy
    time = TimeSummary()
    per_layer = plots.LayerFeatureTimes()
    keep = SlowestLayers(slowest)
    view = ViewerSink(thin_for(path))   # the interactive viewer, embedded above the tables (bounded)

    def fold(m, p, first, segs):
        time.add(m, p)
        per_layer.add(m, p)
        keep(m, p, first, segs)
        view.add_rows(m, p, first, None, segs)
        return False

    reader = stream_plan(path, machine, policy, jerk, strict, fold, progress)
    view.finish(reader, policy)
    est = Estimate(reader.path, reader.summary, time, list(reader.layer_z), list(reader.features), policy,
                   machine.name, firmware=planned_by(machine, policy, jerk))
    d = est.to_json()
    name = os.path.basename(reader.path)
    parts = _tables(est, d)
    if view.moves:
        parts.insert(0, html.section("Explore the plan", viewer_fragment(viewer_data(view, path, machine.name, policy))))
    parts.append(html.details("the estimate as `gcodeplan estimate` prints it", html.pre(_text(est, print_text))))
    imgs = []
    if per_layer.t_s.shape[0] > 1:
        fig = plots.plot_layers(per_layer, list(reader.features), list(reader.layer_z), title=f"{name}: time per layer",
                                size_in=size_in)
        imgs.append(html.figure(plots.png_bytes(fig), "time per layer", "time per layer, split by feature"))
    if imgs:
        parts.append(html.section("Time per layer", *imgs))
    for run in keep.finish():
        moves = np.concatenate([m for m, _ in run.parts])
        plan = np.concatenate([p for _, p in run.parts])
        segs = segments_for(moves, plan, run.first_index, run.own_segs)
        what = f"layer {run.layer}" if run.layer >= 0 else "before the first layer change"
        note = f" (first {run.kept} moves drawn)" if run.truncated else ""
        win = plots.Window(moves, plan, segs, run.first_index, np.asarray(reader.limits), f"{name} ({what})",
                           list(reader.features))
        if segs.size == 0:
            continue
        figs = [(plots.plot_velocity(win, size_in=size_in), "velocity profile"),
                (plots.plot_axes(win, machine, size_in=size_in), "axes"),
                (plots.plot_path(win, size_in=size_in, machine=machine), "toolpath coloured by speed")]
        parts.append(html.section(
            f"{what.capitalize()}: {_fmt_s(run.time_s)} of motion{note}",
            *(html.figure(plots.png_bytes(f), f"{what}: {cap}", f"{what}: {cap}") for f, cap in figs)))
    title = f"gcodeplan report: {name}"
    footer = html.pre(f"gcodeplan {__version__}; machine {machine.name}, {planned_by_text(est)}; "
                      "times are the plan's (docs/design.md), curves sampled from the plan's segments.")
    return html.page(title, *parts, footer)


def _text(est, print_text) -> str:
    buf = io.StringIO()
    print_text(est, buf)
    return buf.getvalue()


def run(args) -> int:
    from .common import machine_from_args

    check_plan_arguments(args)
    if args.slowest < 0:
        raise GcodeplanError(f"--slowest must be 0 or more, got {args.slowest}")
    machine = machine_from_args(args)
    size_in = parse_size(args.size)
    from ..gcode.sources import spooled
    from ..report.output import atomic_output, default_output, resolve_output
    from .common import progress_bar

    out = args.output or default_output(args.file, ".html")
    target = resolve_output(out)      # refuse an unwritable place before planning, not after
    bar, progress = progress_bar(args.file, getattr(args, "quiet", False))
    try:
        with spooled(args.file) as src:   # read twice (the plan, then the viewer's line texts): '-', FIFOs copied
            page = build_report(src, machine, args.policy, args.jerk, args.strict, args.slowest, size_in, progress)
    finally:
        if bar is not None:
            bar.close()

    try:
        with atomic_output(out, "w") as fh:       # whole or not at all, even on SIGTERM
            fh.write(page)
    except OSError as err:
        raise GcodeplanError(f"cannot write {out}: {err.strerror or err}") from None
    if target.kind != "stdout":       # the page itself went to standard output
        print(out)
    return 0
