"""Pictures of a plan: velocity profile, per-axis motion, toolpath coloured by speed, time per layer.

Every curve drawn here is the plan itself: the SEGMENT rows are cubic polynomials in time
(schema.SEGMENT_DTYPE) and are evaluated exactly at the plotted times, never re-derived from
the MOVE/PLAN rows by a second formula. Each segment is sampled at both of its ends (so a
step in acceleration is drawn as a vertical step, not smeared over a grid cell), plus a
uniform grid over the window, plus interior points in the segments whose speed is not linear
in time (S-curve jerk phases, blends).

Figures are built with ``matplotlib.figure.Figure`` directly (never pyplot), so they work
without a display and leave no global state behind; ``save_png`` writes them through Agg.
Default size 16×9 in at 100 dpi = 1600×900 px.
"""
from __future__ import annotations

import io
import math
from dataclasses import dataclass, field

import numpy as np
from matplotlib.collections import LineCollection, PolyCollection
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch
from matplotlib.transforms import blended_transform_factory

from ..errors import GcodeplanError
from ..schema import (
    KIND_PRINT,
    KIND_TRAVEL,
    KIND_WAIT,
    PHASE_BLEND,
    PHASE_NAMES,
)

FIGSIZE_IN = (16.0, 9.0)
DPI = 100
AXES = ("x", "y", "z", "e")

# Phase shading colours, indexed by PHASE_*: accel, cruise, decel, blend, dwell.
PHASE_COLORS = ("#2ca02c", "#1f77b4", "#d62728", "#9467bd", "#7f7f7f")
PHASE_ALPHA = 0.13

UNIFORM_SAMPLES = 4000      # uniform grid points over a window, on top of every segment boundary
# Above DENSE_SAMPLES samples a curve is drawn as its exact min/max over each of DENSE_COLUMNS time
# columns (2 per pixel at 1600 px): same picture, a fraction of the Agg work for 10k-move windows.
DENSE_SAMPLES = 20_000
DENSE_COLUMNS = 3200
CURVED_SAMPLES = 8          # interior points in each segment whose speed is not linear in time
MAX_CURVED_POINTS = 400_000 # cap on those interior points for huge windows (the uniform grid still applies)


@dataclass
class Window:
    """The moves of one plotted window, with their plan and segments.

    ``moves`` and ``plan`` are aligned rows; ``segs['move']`` are *global* move indices and
    ``moves[k]`` is global move ``first_index + k``. ``limits`` is the LIMITS table that
    ``moves['limits']`` indexes.
    """

    moves: np.ndarray
    plan: np.ndarray
    segs: np.ndarray
    first_index: int = 0
    limits: np.ndarray | None = None
    label: str = ""
    feature_names: list = field(default_factory=list)

    def __post_init__(self) -> None:
        if self.moves.shape != self.plan.shape:
            raise ValueError("moves and plan rows must be aligned")

    @property
    def t_range(self) -> tuple[float, float]:
        if self.segs.size:
            return float(self.segs["t0"][0]), float((self.segs["t0"] + self.segs["dt"]).max())
        if self.plan.size:
            return float(self.plan["t_start"][0]), float((self.plan["t_start"] + self.plan["duration"]).max())
        return 0.0, 0.0

    def move_rows(self, seg_move: np.ndarray) -> np.ndarray:
        """Row in ``moves`` of each global move index."""
        return np.asarray(seg_move, dtype=np.int64) - self.first_index


# ----------------------------------------------------------------------------- sampling
def _columns(segs: np.ndarray, prefix: str) -> np.ndarray:
    return np.stack([segs[prefix + a] for a in AXES], axis=1)


def eval_segments(segs: np.ndarray, seg_idx: np.ndarray, tau_t: np.ndarray):
    """Position, velocity, acceleration, jerk of segment ``seg_idx`` at ``tau_t`` s after its start.

    Implements the SEGMENT polynomial (schema.py): q = p + v·τ + a·τ²/2 + j·τ³/6,
    q' = v + a·τ + j·τ²/2, q'' = a + j·τ, q''' = j. Each result has shape (n, 4) for x, y, z, e.
    """
    s = segs[seg_idx]
    tau = np.asarray(tau_t, dtype=np.float64)[:, None]
    p, v, a, j = _columns(s, "p"), _columns(s, "v"), _columns(s, "a"), _columns(s, "j")
    from ..profiles.core import piece_acceleration, piece_position, piece_velocity

    tau = np.ascontiguousarray(np.broadcast_to(tau, p.shape))
    return piece_position(p, v, a, j, tau), piece_velocity(v, a, j, tau), piece_acceleration(a, j, tau), j.copy()


@dataclass
class Samples:
    """A plan sampled for drawing: ``t`` ascending (segment boundaries appear twice, left end
    first), ``seg`` the segment row each sample was taken from, and the (n, 4) kinematics.
    ``gap`` marks samples that start a new stretch after a hole in time (draw a break)."""

    t: np.ndarray
    seg: np.ndarray
    pos: np.ndarray
    vel: np.ndarray
    acc: np.ndarray
    jerk: np.ndarray
    gap: np.ndarray
    side: np.ndarray   # +1 in the first half of its segment, −1 in the second (which way rest is left)


def _curved(segs: np.ndarray) -> np.ndarray:
    """Segments whose toolhead speed is not linear in time: nonzero jerk, or a blend (turning velocity)."""
    j = np.abs(_columns(segs, "j")[:, :3]).sum(axis=1)
    return (j > 0.0) | (segs["phase"] == PHASE_BLEND)


def sample_plan(segs: np.ndarray, n_uniform: int = UNIFORM_SAMPLES, n_curved: int = CURVED_SAMPLES) -> Samples:
    """Sample SEGMENT rows (time-ordered) at every segment's two ends, a uniform grid, and
    ``n_curved`` interior points of each curved segment."""
    n = segs.size
    if n == 0:
        z = np.zeros((0, 4))
        return Samples(np.zeros(0), np.zeros(0, np.int64), z, z, z, z, np.zeros(0, bool), np.zeros(0))
    t0 = segs["t0"]
    dt = segs["dt"]
    idx = [np.arange(n), np.arange(n)]
    tau = [np.zeros(n), dt.copy()]
    # uniform grid: each time goes to the segment that contains it
    lo, hi = float(t0[0]), float((t0 + dt).max())
    if n_uniform > 0 and hi > lo:
        grid = np.linspace(lo, hi, n_uniform)
        k = np.clip(np.searchsorted(t0, grid, side="right") - 1, 0, n - 1)
        g_tau = grid - t0[k]
        inside = (g_tau > 0.0) & (g_tau < dt[k])
        idx.append(k[inside])
        tau.append(g_tau[inside])
    curved = np.flatnonzero(_curved(segs))
    if curved.size and n_curved > 0:
        per = max(1, min(n_curved, MAX_CURVED_POINTS // curved.size))
        frac = np.arange(1, per + 1) / (per + 1)
        idx.append(np.repeat(curved, per))
        tau.append((dt[curved][:, None] * frac[None, :]).ravel())
    seg = np.concatenate(idx).astype(np.int64)
    tau_t = np.concatenate(tau)
    order = np.lexsort((tau_t, seg))  # segments are time-ordered, so (segment, τ) order is time order
    seg, tau_t = seg[order], tau_t[order]
    pos, vel, acc, jerk = eval_segments(segs, seg, tau_t)
    # t0 + dt of one piece and t0 of the next can differ by an ulp either way: keep the drawn times monotone
    t = np.maximum.accumulate(t0[seg] + tau_t)
    # A hole in time between consecutive segments (a window made of separate stretches) is a break.
    seg_end = t0 + dt
    new_seg = np.r_[False, seg[1:] != seg[:-1]]
    prev_end = np.r_[seg_end[0], seg_end[seg[:-1]]]
    tol = 1e-9 * max(1.0, abs(hi))
    gap = new_seg & (t0[seg] > prev_end + tol)
    side = np.where(tau_t <= 0.5 * dt[seg], 1.0, -1.0)
    return Samples(t, seg, pos, vel, acc, jerk, gap, side)


def toolhead_kinematics(vel: np.ndarray, acc: np.ndarray, jerk: np.ndarray, side: np.ndarray | None = None):
    """Toolhead speed |v|, its rate d|v|/dt and that rate's derivative, from (n, ≥3) XYZ columns.

    With u = v/|v| and a_t = a·u (tangential acceleration = d|v|/dt),
    d a_t/dt = j·u + (|a|² − a_t²)/|v| (differentiating v·a/|v|; the second term is the
    normal acceleration squared over speed and vanishes on straight moves). At rest u is the
    limit of v/|v|: leaving rest (``side`` +1) v ≈ a·τ so u = a/|a|; coming to rest (``side`` −1)
    v ≈ −a·s so u = −a/|a|; with a = 0 too, v ≈ j·s²/2 either way so u = j/|j|.
    """
    v = vel[:, :3]
    a = acc[:, :3]
    j = jerk[:, :3]
    speed = np.sqrt((v * v).sum(axis=1))
    a_mag = np.sqrt((a * a).sum(axis=1))
    j_mag = np.sqrt((j * j).sum(axis=1))
    eps = 1e-12
    sd = np.ones(speed.size) if side is None else np.asarray(side, dtype=np.float64)
    u = np.where((speed > eps)[:, None], v / np.maximum(speed, eps)[:, None],
                 np.where((a_mag > eps)[:, None], sd[:, None] * a / np.maximum(a_mag, eps)[:, None],
                          j / np.maximum(j_mag, eps)[:, None]))
    a_t = (a * u).sum(axis=1)
    a_n = a - a_t[:, None] * u
    a_n2 = (a_n * a_n).sum(axis=1)
    # a normal component below 1e-9 of |a| is rounding (straight moves), not curvature
    a_n2 = np.where(a_n2 <= (1e-9 * a_mag) ** 2, 0.0, a_n2)
    with np.errstate(divide="ignore", invalid="ignore"):
        curv = np.where(speed > 1e-9, a_n2 / np.maximum(speed, 1e-300), 0.0)
    j_t = (j * u).sum(axis=1) + curv
    return speed, a_t, j_t


def jerk_steps(s: Samples, a_t: np.ndarray, speed: np.ndarray, rest_v: float = 1e-9):
    """Times and sizes (mm/s²) of the steps in tangential acceleration: where one segment
    hands over to the next at the same instant with a different a_t, and at the ends of each
    stretch of motion that starts or ends at rest (the toolhead's acceleration is 0 at rest)."""
    n = s.t.size
    if n == 0:
        return np.zeros(0), np.zeros(0)
    tol = 1e-12 * max(1.0, abs(float(s.t[-1])))
    b = np.flatnonzero((s.seg[1:] != s.seg[:-1]) & (np.abs(s.t[1:] - s.t[:-1]) <= tol))
    t = [s.t[b]]
    da = [a_t[b + 1] - a_t[b]]
    first = np.r_[0, np.flatnonzero(s.gap)]           # first sample of each stretch
    last = np.r_[np.flatnonzero(s.gap) - 1, n - 1]    # last sample of each stretch
    f = first[speed[first] <= rest_v]
    g = last[speed[last] <= rest_v]
    t += [s.t[f], s.t[g]]
    da += [a_t[f], -a_t[g]]
    t_all, da_all = np.concatenate(t), np.concatenate(da)
    order = np.argsort(t_all, kind="stable")
    return t_all[order], da_all[order]


def _with_breaks(t: np.ndarray, ys: list[np.ndarray], gap: np.ndarray):
    """Insert NaN before each gap sample so a line is broken there."""
    if not gap.any():
        return t, ys
    at = np.flatnonzero(gap)
    t2 = np.insert(t, at, np.nan)
    return t2, [np.insert(y, at, np.nan) for y in ys]


def minmax_columns(t: np.ndarray, y: np.ndarray, gap: np.ndarray, n_cols: int = DENSE_COLUMNS):
    """Exact min and max of a time-sorted curve's samples in each of ``n_cols`` equal time columns.

    Returns (centre_t, y_min, y_max) for the non-empty columns, with NaN rows inserted before a
    column where a new stretch starts (``gap``) so that the drawing breaks there."""
    lo, hi = float(t[0]), float(t[-1])
    width = (hi - lo) / n_cols if hi > lo else 1.0
    col = np.minimum(((t - lo) / width).astype(np.int64), n_cols - 1)
    starts = np.flatnonzero(np.r_[True, col[1:] != col[:-1]])
    y_min = np.minimum.reduceat(y, starts)
    y_max = np.maximum.reduceat(y, starts)
    centre = lo + (col[starts] + 0.5) * width
    brk = np.add.reduceat(gap.astype(np.int64), starts) > 0
    if brk.any():
        at = np.flatnonzero(brk)
        centre, y_min, y_max = (np.insert(a, at, np.nan) for a in (centre, y_min, y_max))
    return centre, y_min, y_max


def mean_columns(t: np.ndarray, y: np.ndarray, gap: np.ndarray, n_cols: int = DENSE_COLUMNS):
    """Time-weighted mean of a time-sorted curve in each of ``n_cols`` equal time columns (its integral
    by the trapezoid rule over the samples, exact for curves linear between samples such as trapezoid
    speed profiles, over the time covered). Returns (centre_t, mean) of the non-empty columns, NaN rows
    before a column where a new stretch starts (``gap``)."""
    lo, hi = float(t[0]), float(t[-1])
    width = (hi - lo) / n_cols if hi > lo else 1.0
    dt = np.diff(t)
    area = 0.5 * (y[1:] + y[:-1]) * dt
    keep = ~gap[1:] & (dt > 0)                      # no interval across a hole in time
    mid = 0.5 * (t[1:] + t[:-1])
    col = np.minimum(((mid - lo) / width).astype(np.int64), n_cols - 1)
    a = np.bincount(col[keep], weights=area[keep], minlength=n_cols)
    w = np.bincount(col[keep], weights=dt[keep], minlength=n_cols)
    used = np.flatnonzero(w > 0)
    centre = lo + (used + 0.5) * width
    mean = a[used] / w[used]
    brk = np.zeros(n_cols, bool)
    gcol = np.minimum(((t[gap] - lo) / width).astype(np.int64), n_cols - 1)
    brk[gcol] = True
    at = np.flatnonzero(brk[used])
    if at.size:
        centre, mean = np.insert(centre, at, np.nan), np.insert(mean, at, np.nan)
    return centre, mean


def is_dense(s: "Samples") -> bool:
    """True when a window has more samples than pixels can show apart (:data:`DENSE_SAMPLES`) because it holds
    more pieces than half the pixel columns: its curves are drawn as per-column envelopes
    (:func:`plot_series`). A short window sampled finely (curved pieces, a delta's carriages) stays a line."""
    if s.t.size <= DENSE_SAMPLES:
        return False
    return np.unique(s.seg).size > DENSE_COLUMNS // 2


def plot_series(ax, s: "Samples", y: np.ndarray, gid: str, label: str | None = None, color="black", lw=1.0,
                mean: bool = True):
    """Draw one sampled curve: every sample for ordinary windows (a line with gid ``gid``); for
    dense ones the band between the per-column min and max (``minmax_columns``: gid ``gid``,
    filled, light, so that a whole print is not a solid block) and, with ``mean``, the time-weighted
    mean of each column as a line over it (:func:`mean_columns`: gid ``gid_mean``)."""
    if is_dense(s):
        x, y_min, y_max = minmax_columns(s.t, y, s.gap)
        ax.fill_between(x, y_min, y_max, step="mid", color=color, lw=0, alpha=0.25, gid=gid,
                        label=(label + " (range per pixel column)") if label else None)
        if mean:
            xm, ym = mean_columns(s.t, y, s.gap)
            ax.plot(xm, ym, color=color, lw=lw, gid=gid + "_mean",
                    label=(label + " (mean per pixel column)") if label else "_" + gid + "_mean")
        return
    x, (yy,) = _with_breaks(s.t, [y], s.gap)
    ax.plot(x, yy, gid=gid, label=label if label else "_" + gid, color=color, lw=lw)


# ----------------------------------------------------------------------------- helpers
def new_figure(nrows: int = 1, ncols: int = 1, size_in=FIGSIZE_IN, dpi: int = DPI, **kw):
    fig = Figure(figsize=size_in, dpi=dpi, layout="constrained")
    FigureCanvasAgg(fig)  # headless: the figure renders through Agg whatever backend pyplot may use
    axs = fig.subplots(nrows, ncols, squeeze=False, **kw)
    for ax in axs.flat:
        # whole numbers on the axes: no '+1.87e3' offset to add in one's head (a window late in a print)
        ax.ticklabel_format(axis="both", style="plain", useOffset=False)
    return fig, axs


def save_png(fig: Figure, path) -> None:
    """Write ``fig`` as PNG at its own size (no tight cropping: 16×9 in at 100 dpi stays 1600×900 px)."""
    try:
        fig.savefig(path, format="png", dpi=fig.dpi)
    except OSError as err:
        raise GcodeplanError(f"cannot write {path}: {err.strerror or err}") from None


def png_bytes(fig: Figure) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=fig.dpi)
    return buf.getvalue()


def phase_bands(segs: np.ndarray, max_bands: int = DENSE_COLUMNS):
    """(start_t, end_t, phase) of maximal runs of contiguous same-phase segments. When there are
    more runs than ``max_bands`` (sub-pixel), each of ``max_bands`` equal time columns takes the
    phase in force at its centre, and equal neighbours merge."""
    t0 = segs["t0"]
    t1 = t0 + segs["dt"]
    ph = segs["phase"]
    brk = np.r_[True, (ph[1:] != ph[:-1]) | (t0[1:] > t1[:-1] + 1e-12)]
    starts = np.flatnonzero(brk)
    if starts.size > max_bands:
        lo, hi = float(t0[0]), float(t1.max())
        edges = np.linspace(lo, hi, max_bands + 1)
        centre = 0.5 * (edges[1:] + edges[:-1])
        k = np.clip(np.searchsorted(t0, centre, side="right") - 1, 0, segs.size - 1)
        inside = centre <= t1[k]
        col_ph = np.where(inside, ph[k], 255)  # 255: no segment here (a hole in time)
        run = np.flatnonzero(np.r_[True, col_ph[1:] != col_ph[:-1]])
        run_end = np.r_[run[1:], max_bands]
        keep = col_ph[run] != 255
        return edges[run][keep], edges[run_end][keep], col_ph[run][keep]
    ends = np.r_[starts[1:], ph.size] - 1
    return t0[starts], t1[ends], ph[starts]


def tangential_phases(segs: np.ndarray) -> np.ndarray:
    """``segs`` with the accel / cruise / decel phase of each piece taken from the sign of its tangential
    acceleration v·a/|v| at its middle (blend and dwell pieces keep theirs): a piece that turns at constant
    speed (a LinuxCNC arc's, whose acceleration is normal to the path) is cruising, not decelerating."""
    from ..schema import PHASE_ACCEL, PHASE_CRUISE, PHASE_DECEL

    if segs.size == 0:
        return segs
    mid = 0.5 * segs["dt"]
    _, vel, acc, _ = eval_segments(segs, np.arange(segs.size), mid)
    v, a = vel[:, :3], acc[:, :3]
    speed = np.sqrt((v * v).sum(axis=1))
    a_t = np.where(speed > 1e-12, (v * a).sum(axis=1) / np.maximum(speed, 1e-300), np.sqrt((a * a).sum(axis=1)))
    # mostly normal to the path (an arc at constant speed; a fit's rounding along it) is not a ramp
    tol = np.maximum(0.02 * np.sqrt((a * a).sum(axis=1)), 1e-9 * max(float(np.abs(a).max()), 1.0))
    new = np.where(a_t > tol, PHASE_ACCEL, np.where(a_t < -tol, PHASE_DECEL, PHASE_CRUISE)).astype(segs["phase"].dtype)
    keep = (segs["phase"] != PHASE_ACCEL) & (segs["phase"] != PHASE_CRUISE) & (segs["phase"] != PHASE_DECEL)
    out = segs.copy()
    out["phase"] = np.where(keep, segs["phase"], new)
    return out


def _shade_phases(ax, bands) -> None:
    """Shade each phase band full-height (x in data, y in axes coordinates), one collection."""
    a, b, ph = bands
    if a.size == 0:
        return
    verts = np.empty((a.size, 4, 2))
    verts[:, 0, 0] = verts[:, 1, 0] = a
    verts[:, 2, 0] = verts[:, 3, 0] = b
    verts[:, 0, 1] = verts[:, 3, 1] = 0.0
    verts[:, 1, 1] = verts[:, 2, 1] = 1.0
    colors = np.asarray(PHASE_COLORS)[ph]
    pc = PolyCollection(verts, transform=blended_transform_factory(ax.transData, ax.transAxes),
                        facecolors=colors, edgecolors="none", alpha=PHASE_ALPHA, zorder=0, gid="phases")
    ax.add_collection(pc, autolim=False)


def _phase_legend_handles(segs: np.ndarray):
    present = np.unique(segs["phase"]) if segs.size else []
    return [Patch(facecolor=PHASE_COLORS[p], alpha=0.35, label=PHASE_NAMES[p]) for p in present]


def _step_xy(t_start: np.ndarray, t_end: np.ndarray, y: np.ndarray):
    """Piecewise-constant y over [t_start, t_end] as one line with NaN breaks between pieces."""
    n = t_start.size
    x = np.empty(3 * n)
    yy = np.empty(3 * n)
    x[0::3], x[1::3], x[2::3] = t_start, t_end, np.nan
    yy[0::3], yy[1::3], yy[2::3] = y, y, np.nan
    return x, yy


def _window_title(win: Window, what: str) -> str:
    t0, t1 = win.t_range
    lines = win.moves["line"] if win.moves.size else np.zeros(1, np.int64)
    head = f"{win.label}: " if win.label else ""
    return (f"{head}{what} — {win.moves.size} moves, lines {int(lines.min())}–{int(lines.max())}, "
            f"t = {t0:.3f}–{t1:.3f} s")


def is_cnc_window(win: Window, machine=None) -> bool:
    """True for a CNC program's window: the machine is a CNC flavour (grbl, linuxcnc), or nothing in the
    window extrudes and E never moves. Its feed moves (G1/G2/G3) are the cuts, its rapids (G0) the travel,
    and it has no E row."""
    if machine is not None and getattr(machine, "is_cnc", False):
        return True
    m = win.moves
    if m.size == 0 or np.any(m["kind"] == KIND_PRINT):
        return False
    return not np.any(m["e1"] != m["e0"]) if "e1" in m.dtype.names else True


def _need_segments(win: Window) -> None:
    if win.segs.size == 0:
        raise GcodeplanError("the selected window has no motion to plot")


# ----------------------------------------------------------------------------- velocity
def plot_velocity(win: Window, title: str | None = None, size_in=FIGSIZE_IN, dpi: int = DPI) -> Figure:
    """Toolhead speed, tangential acceleration and, for plans whose acceleration changes continuously
    (S-curves, blends), its jerk against time.

    Phases are shaded; junction speeds (the plan's start_v of each XYZ move) are marked; the
    requested feed rate is drawn as a step line. The jerk of a trapezoid plan is impulsive (zero inside
    phases, a step in acceleration at each phase change): it has no panel, the steps are the
    acceleration curve's own. A window of more moves than pixels (a whole print) is drawn as envelopes:
    per pixel column the range of the speed (light band) and its time-weighted mean (a line), the range
    of the acceleration and the highest requested feed; phases and junctions are not drawn there.
    Lines carry gids ``speed`` (``speed_mean`` dense), ``accel``, ``jerk``, ``feed``, ``junctions``,
    ``jerk_steps_up``, ``jerk_steps_down`` so tests can read them back.
    """
    _need_segments(win)
    segs = win.segs
    s = sample_plan(segs)
    speed, a_t, j_t = toolhead_kinematics(s.vel, s.acc, s.jerk, s.side)
    dense = is_dense(s)
    # a jerk panel for plans whose acceleration changes continuously: S-curves (jerk pieces) and blends
    # (turning velocity); trapezoids and LinuxCNC's constant-acceleration pieces only step it
    has_jerk = bool(np.any(_columns(segs, "j")[:, :3] != 0.0) or np.any(segs["phase"] == PHASE_BLEND))
    fig, axs = new_figure(3 if has_jerk else 2, 1, size_in, dpi, sharex=True)
    ax_v, ax_a = axs[0, 0], axs[1, 0]
    ax_j = axs[2, 0] if has_jerk else None
    panels = [ax for ax in (ax_v, ax_a, ax_j) if ax is not None]
    if not dense:
        bands = phase_bands(tangential_phases(segs))
        for ax in panels:
            _shade_phases(ax, bands)
    for ax in panels:
        ax.grid(True, alpha=0.3)
    plot_series(ax_v, s, speed, "speed", "toolhead speed |v|", color="black" if not dense else "tab:blue",
                lw=1.0, mean=True)
    plot_series(ax_a, s, a_t, "accel", "tangential acceleration d|v|/dt",
                color="black" if not dense else "tab:green", lw=1.0, mean=False)
    if ax_j is not None:
        plot_series(ax_j, s, j_t, "jerk", "jerk d²|v|/dt²", color="black", lw=1.0, mean=False)

    # requested feed rate, for contrast (rapids / unlimited feeds have no finite request: not drawn)
    moves, plan = win.moves, win.plan
    xyz = ((moves["kind"] == KIND_TRAVEL) | (moves["kind"] == KIND_PRINT)) & (moves["move_d"] > 0)
    if xyz.any():
        feed = np.where(np.isfinite(moves["feed_v"][xyz]), moves["feed_v"][xyz], np.nan)
        ts = plan["t_start"][xyz]
        if dense:      # the feed asked for, time-weighted per pixel column: what the mean speed falls short of
            fs = _feed_at_samples(win, s)
            ok = np.isfinite(fs)
            if ok.sum() > 1:
                idx = np.flatnonzero(ok)
                gap = s.gap[idx] | np.r_[False, np.diff(idx) > 1]   # a rapid or E-only stretch between
                x, f_mean = mean_columns(s.t[idx], fs[idx], gap)
                ax_v.plot(x, f_mean, color="tab:orange", lw=1.0, ls="--",
                          label="requested feed rate (mean per pixel column)", gid="feed")
        else:
            fx, fy = _step_xy(ts, ts + plan["duration"][xyz], feed)
            ax_v.plot(fx, fy, color="tab:orange", lw=1.0, ls="--", label="requested feed rate", gid="feed")
            ax_v.plot(ts, plan["start_v"][xyz], ls="none", marker="o", ms=3.5, mfc="none", mec="tab:purple",
                      label="junction speed (plan start_v)", gid="junctions")

    if ax_j is not None:
        # Steps in acceleration = jerk impulses (blends' corners): at boundaries between segments that
        # touch in time, and where motion starts from / ends at rest (acceleration 0 outside).
        step_t, step_da = jerk_steps(s, a_t, speed)
        scale = max(float(np.abs(a_t).max()), 1e-9)
        up, down = step_da > 1e-6 * scale, step_da < -1e-6 * scale
        if up.any() and not dense:
            ax_j.plot(step_t[up], np.zeros(int(up.sum())), ls="none", marker="^", ms=6, color="tab:green",
                      label="jerk impulse (acceleration steps up)", gid="jerk_steps_up")
        if down.any() and not dense:
            ax_j.plot(step_t[down], np.zeros(int(down.sum())), ls="none", marker="v", ms=6, color="tab:red",
                      label="jerk impulse (acceleration steps down)", gid="jerk_steps_down")
        ax_j.set_ylabel("jerk (mm/s³)")

    ax_v.set_ylabel("speed (mm/s)")
    ax_a.set_ylabel("acceleration (mm/s²)")
    panels[-1].set_xlabel("time (s)")
    ax_v.set_ylim(bottom=0.0)
    ax_v.set_xlim(s.t[0], s.t[-1])
    ax_v.legend(handles=ax_v.get_legend_handles_labels()[0] + ([] if dense else _phase_legend_handles(segs)),
                loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=9)
    for ax in panels[1:]:
        ax.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=9)
    fig.suptitle(title or _window_title(win, "velocity profile"))
    return fig


def _feed_at_samples(win: Window, s: Samples) -> np.ndarray:
    """Requested feed (mm/s) of the XYZ move each sample belongs to, NaN for others (rapids, E-only)."""
    rows = win.move_rows(win.segs["move"][s.seg])
    ok = (rows >= 0) & (rows < win.moves.size)
    out = np.full(s.t.size, np.nan)
    m = win.moves
    r = rows[ok]
    xyz = ((m["kind"][r] == KIND_TRAVEL) | (m["kind"][r] == KIND_PRINT)) & (m["move_d"][r] > 0)
    f = np.where(xyz & np.isfinite(m["feed_v"][r]), m["feed_v"][r], np.nan)
    out[ok] = f
    return out


# ----------------------------------------------------------------------------- axes
def _limit_steps(win: Window, column: str):
    """Per-move step line of a LIMITS column (inf → not drawn), or None when nowhere finite."""
    if win.limits is None or win.moves.size == 0 or column not in win.limits.dtype.names:
        return None
    rows = np.clip(win.moves["limits"], 0, win.limits.size - 1)
    val = win.limits[column][rows].astype(np.float64)
    val = np.where(np.isfinite(val) & (val > 0), val, np.nan)
    if np.all(np.isnan(val)):
        return None
    ts = win.plan["t_start"]
    return _step_xy(ts, ts + win.plan["duration"], val)


def plot_axes(win: Window, machine=None, title: str | None = None, size_in=FIGSIZE_IN, dpi: int = DPI) -> Figure:
    """Per-axis position and velocity against time (and per motor for corexy, corexz and other linear
    machines, asked of the kinematics), with limits.

    Velocity limits drawn: the per-axis limit in force (LIMITS axis_v_*, a step line since the
    G-code may change it), the extrude-only limit on E, and, when the machine has a finite
    ``max_step_rate``, the speed at which a stepper reaches it (max_step_rate / steps_per_mm).
    Motors that combine axes (corexy a = x + y, b = x − y: docs/design.md §9) get rows of their own, and so does
    each motor of a plug-in kinematics given by its inverse kinematics (polar's bed angle in rad and arm in mm:
    :func:`ik_motion`). Lines carry gids ``pos_<axis or motor>``/``vel_<axis or motor>``.

    A delta, or a machine with input shaping, gets one row per motor that moves with X/Y: the position
    and velocity it is driven to (X/Y shaped first, then the kinematics: gids ``motor_<name>``,
    ``motor_vel_<name>``) against the commanded one (the planned path through the kinematics:
    ``cmd_<name>``, ``cmd_vel_<name>``); see :func:`motor_motion`.
    """
    _need_segments(win)
    s = sample_plan(win.segs)
    # a CNC program has no extruder: no E row
    rows = [a for a in AXES if a != "e" or not is_cnc_window(win, machine)]
    pos = {a: s.pos[:, i] for i, a in enumerate(AXES)}
    vel = {a: s.vel[:, i] for i, a in enumerate(AXES)}
    kin = getattr(machine, "kinematics", "cartesian") if machine is not None else "cartesian"
    shaped = machine is not None and (getattr(machine, "shaper_freq_x", 0.0) > 0
                                      or getattr(machine, "shaper_freq_y", 0.0) > 0)
    motors = {}
    motor_labels: dict[str, str] = {}
    motor_spm: dict[str, float] = {}
    motor_units: dict[str, str] = {}       # a plug-in motor's position unit (its ik's: mm, rad)
    if kin == "delta" or shaped:
        from ..kinematics import rails_for

        for name, cp, cv, mp, mv in motor_motion(win.segs, machine, s.t):
            motors[name] = (cp, cv, mp, mv)
            pos[name], vel[name] = mp, mv
        motor_units.update((r.name, ik_unit(r)) for r in rails_for(machine) if r.ik is not None)
    elif machine is not None and kin != "cartesian":
        names, motor_labels, motor_units, motor_spm = _motor_rows(machine, s, pos, vel)
        rows += names
    rows += list(motors)
    fig, axs = new_figure(len(rows), 2, size_in, dpi, sharex=True)
    for r, name in enumerate(rows):
        ax_p, ax_v = axs[r]
        if name in motors:                 # a motor row (delta tower, shaped axis), after the axes
            cp, cv, mp, mv = motors[name]
            label = f"motor {name}"
            plot_series(ax_p, s, cp, f"cmd_{name}", color="0.55", lw=1.6)
            plot_series(ax_p, s, mp, f"motor_{name}", color="tab:blue", lw=1.0)
            plot_series(ax_v, s, cv, f"cmd_vel_{name}", "commanded", color="0.55", lw=1.6)
            plot_series(ax_v, s, mv, f"motor_vel_{name}", "driven (shaped)" if shaped else "driven",
                        color="tab:blue", lw=1.0)
            unit = motor_units.get(name, "mm")
            ax_p.set_ylabel(f"{label} ({unit})", fontsize=9)
            ax_v.set_ylabel(f"{label} ({unit}/s)", fontsize=9)
            for ax in (ax_p, ax_v):
                ax.grid(True, alpha=0.3)
                ax.tick_params(labelsize=8)
            ax_v.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=8)
            continue
        label = motor_labels.get(name, name)
        unit = motor_units.get(name, "mm")
        plot_series(ax_p, s, pos[name], f"pos_{name}", color="tab:blue", lw=1.0)
        plot_series(ax_v, s, vel[name], f"vel_{name}", f"{name} velocity", color="tab:blue", lw=1.0)
        ax_p.set_ylabel(f"{label} ({unit})", fontsize=9)
        ax_v.set_ylabel(f"{label} ({unit}/s)", fontsize=9)
        for ax in (ax_p, ax_v):
            ax.grid(True, alpha=0.3)
            ax.tick_params(labelsize=8)
        limit_lines = []
        if name in AXES:
            limit_lines.append((f"axis_v_{name}", f"{name} max velocity", "tab:red"))
        if name == "e":
            limit_lines.append(("extrude_only_v", "extrude-only max velocity", "tab:orange"))
        for col, lab, color in limit_lines:
            st = _limit_steps(win, col)
            if st is not None:
                ax_v.plot(st[0], st[1], color=color, ls="--", lw=0.9, label=lab, gid=f"limit_{col}")
                ax_v.plot(st[0], -st[1], color=color, ls="--", lw=0.9, gid=f"limit_{col}_neg")
        if machine is not None and math.isfinite(getattr(machine, "max_step_rate", math.inf)):
            spm = motor_spm[name] if name in motor_spm else machine.axes[name].steps_per_mm
            if spm > 0:
                vmax = machine.max_step_rate / spm
                ax_v.axhline(vmax, color="tab:purple", ls=":", lw=0.9, label="step-rate limit", gid=f"steprate_{name}")
                ax_v.axhline(-vmax, color="tab:purple", ls=":", lw=0.9)
        if len(ax_v.get_lines()) > 1:
            ax_v.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=8)
    axs[-1, 0].set_xlabel("time (s)")
    axs[-1, 1].set_xlabel("time (s)")
    axs[0, 0].set_title("position" + (f" (motors {', '.join(motor_labels)}: {kin})" if motor_labels else ""),
                        fontsize=10)
    axs[0, 1].set_title("velocity", fontsize=10)
    axs[0, 0].set_xlim(s.t[0], s.t[-1])
    fig.suptitle(title or _window_title(win, f"axes ({kin})"))
    return fig


def _motor_rows(machine, s: "Samples", pos: dict, vel: dict) -> tuple[list, dict, dict, dict]:
    """The rows of the motors the kinematics makes of the axes, unshaped: a linear machine's motors (corexy,
    corexz, ...) each a weighted sum of axes; a plug-in's non-linear motors (polar's bed and arm, a winch's
    cables) its inverse kinematics (:func:`ik_motion`). Adds their positions and velocities to ``pos``/``vel``;
    returns (row names in order, labels, position units, steps per unit) by row name."""
    from ..kinematics import rails_for

    names, labels, units, spm = [], {}, {}, {}
    for rail in rails_for(machine):
        if rail.ik is not None:
            key = rail.name if rail.name not in AXES else f"{rail.name} motor"
            pos[key], vel[key] = ik_motion(rail, s.pos, s.vel)
            labels[key], units[key], spm[key] = key, ik_unit(rail), rail.steps_per_mm
            names.append(key)
            continue
        w = rail.weights
        if w is None or sum(1 for x in w if x != 0.0) < 2:
            continue                   # a motor that is one axis is that axis's own row
        pos[rail.name] = sum(wi * pos[a] for wi, a in zip(w, AXES) if wi != 0.0)
        vel[rail.name] = sum(wi * vel[a] for wi, a in zip(w, AXES) if wi != 0.0)
        terms = " ".join(f"{'+' if wi > 0 else '−'} {'' if abs(wi) == 1 else f'{abs(wi):g}·'}{a}"
                         for wi, a in zip(w, AXES) if wi != 0.0)
        labels[rail.name] = f"{rail.name} = {terms.lstrip('+ ')}"
        spm[rail.name] = rail.steps_per_mm
        names.append(rail.name)
    return names, labels, units, spm


def _path_at(segs: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Position and velocity (n, 4) of the SEGMENT path at times ``t`` (s), at rest before and after it."""
    k = np.clip(np.searchsorted(segs["t0"], t, side="right") - 1, 0, len(segs) - 1)
    tau = np.clip(t - segs["t0"][k], 0.0, segs["dt"][k])
    p, v, _, _ = eval_segments(segs, k, tau)
    v[(t < segs["t0"][0]) | (t > segs["t0"][-1] + segs["dt"][-1])] = 0.0
    return p, v


def motor_motion(segs: np.ndarray, machine, t: np.ndarray) -> list[tuple]:
    """Per motor that moves with X or Y: (name, commanded position mm, commanded velocity mm/s, driven
    position, driven velocity) at times ``t`` (s).

    Commanded: the planned path through the kinematics. Driven: X and Y first input-shaped as Klipper's
    kin_shaper.c does (:mod:`gcodeplan.stepper.shaping`; the same pieces the step generator steps), then
    the kinematics: a linear motor Σ w·axis, a delta tower its carriage height z + √(L² − (x − t_x)² −
    (y − t_y)²) and that height's time derivative. The window is taken at rest outside its own pieces, so
    within the shaper's reach (≤ 20 ms at usual frequencies) of the window's ends the driven curve is what
    a machine starting and stopping there would do.
    """
    from ..kinematics import rails_for
    from ..stepper.shaping import ShapedStream, as_segments, shaper_pulses

    t = np.asarray(t, np.float64)
    driven_path = segs
    fx, fy = float(getattr(machine, "shaper_freq_x", 0.0)), float(getattr(machine, "shaper_freq_y", 0.0))
    if (fx > 0 or fy > 0) and segs.size:
        none = (np.zeros(0), np.zeros(0))
        px = shaper_pulses(machine.shaper_type_x, fx, machine.damping_ratio_x) if fx > 0 else none
        py = shaper_pulses(machine.shaper_type_y, fy, machine.damping_ratio_y) if fy > 0 else none
        stream = ShapedStream(px, py)
        driven_path = np.concatenate([as_segments(stream.feed(segs)), as_segments(stream.finish())])
    cp, cv = _path_at(segs, t)
    dp, dv = _path_at(driven_path, t)
    out = []
    for rail in rails_for(machine):
        if rail.tower is not None:
            arm2, tx, ty = rail.tower
            motion = []
            for p, v in ((cp, cv), (dp, dv)):
                dx, dy = tx - p[:, 0], ty - p[:, 1]
                with np.errstate(invalid="ignore"):
                    root = np.sqrt(arm2 - dx * dx - dy * dy)
                motion += [p[:, 2] + root, v[:, 2] + (dx * v[:, 0] + dy * v[:, 1]) / root]
            out.append((rail.name, *motion))
        elif rail.weights is not None and (rail.weights[0] or rail.weights[1]):
            w = np.asarray(rail.weights, np.float64)
            out.append((rail.name, cp @ w, cv @ w, dp @ w, dv @ w))
        elif rail.ik is not None:
            out.append((rail.name, *ik_motion(rail, cp, cv), *ik_motion(rail, dp, dv)))
    return out


# s: the half-interval of the central difference a plug-in motor's velocity is taken over: at 1000 mm/s the
# toolhead moves 0.01 mm, so the difference's truncation error (∝ dt²) and its rounding error (∝ 1/dt) both stay
# below 1e-8 of the velocity on machines of metres and millimetres
IK_DT = 1e-5


def ik_motion(rail, p: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A plug-in motor's position (its inverse kinematics' unit: mm, rad) and velocity (unit/s) for toolhead
    positions ``p`` (n, ≥3, mm) moving at ``v`` (n, ≥3, mm/s): ``rail.ik`` at each point, a cyclic motor (a
    turntable: ``rail.period``) followed continuously as the step engine follows it, and the velocity the ik's
    derivative along ``v`` (a central difference over ±:data:`IK_DT` s). Where the ik has no derivative (polar's
    bed angle at the centre) the velocity is NaN (a gap), not the difference across the jump: there the
    one-sided differences' disagreement does not shrink as dt² when dt halves (:func:`_ik_kink`)."""
    params = np.asarray(rail.ik_params if len(rail.ik_params) else (0.0,), np.float64)
    p3 = np.asarray(p, np.float64)[:, :3]
    v3 = np.asarray(v, np.float64)[:, :3]
    pos = _ik_at(rail.ik, p3, params)
    diffs = []       # one-sided differences ahead and behind over dt and 2·dt
    for k in (1.0, -1.0, 2.0, -2.0):
        d = (_ik_at(rail.ik, p3 + v3 * (k * IK_DT), params) - pos) * np.sign(k)
        if rail.period > 0:
            d -= rail.period * np.round(d / rail.period)        # a difference taken across the wrap
        diffs.append(d)
    ahead, behind, ahead2, behind2 = diffs
    if rail.period > 0 and pos.size:
        pos = np.unwrap(pos, period=rail.period)
    kink = _ik_kink(ahead - behind, ahead2 - behind2, pos)
    return pos, np.where(kink, np.nan, (ahead + behind) / (2.0 * IK_DT))


def _ik_kink(d1: np.ndarray, d2: np.ndarray, pos: np.ndarray) -> np.ndarray:
    """True where a motor's position has no derivative: ``d1``, ``d2`` = ahead − behind one-sided differences over
    dt and 2·dt. A smooth position gives d2 = 4·d1 (both ∝ the second derivative · dt²), a kink 2·d1, a jump
    d1 (the jump itself); a d1 at the level of the position's rounding is smooth."""
    noise = 64.0 * np.finfo(np.float64).eps * (1.0 + np.abs(pos))
    return (np.abs(d1) > noise) & (np.abs(d2) < 3.0 * np.abs(d1))


def _ik_at(ik, p3: np.ndarray, params: np.ndarray) -> np.ndarray:
    """``ik(x, y, z, params)`` at each row of ``p3`` (the plug-in's own function, compiled or not)."""
    return np.fromiter((ik(x, y, z, params) for x, y, z in p3.tolist()), np.float64, count=len(p3))


def ik_unit(rail) -> str:
    """The position unit a plug-in motor's row is labelled in: rad for a turntable (period 2π), else the
    plug-in's own ("units": mm for a carriage or cable, rad for an arm's angle)."""
    return "rad" if rail.period and abs(rail.period - 2.0 * math.pi) < 1e-12 else "units"


# ----------------------------------------------------------------------------- path
def plot_path(win: Window, title: str | None = None, size_in=FIGSIZE_IN, dpi: int = DPI,
              pieces_per_segment: int = 4, machine=None) -> Figure:
    """XY toolpath coloured by actual toolhead speed; travel moves dashed; a colour bar.

    Each segment is cut into ``pieces_per_segment`` pieces at its own times (a cruise keeps one)
    and each piece takes the speed at its middle time, evaluated from the segment polynomial.
    Collections carry gids ``path_print`` / ``path_travel``; their ``get_array()`` is the speed.
    """
    _need_segments(win)
    segs = win.segs
    n = segs.size
    kind = np.full(n, KIND_PRINT, dtype=np.int64)
    rows = win.move_rows(segs["move"])
    ok = (rows >= 0) & (rows < win.moves.size)
    kind[ok] = win.moves["kind"][rows[ok]]
    cnc = is_cnc_window(win, machine)
    if cnc:      # the cuts are the feed moves (travel kind, not G0): drawn solid, the rapids dashed
        from ..schema import FLAG_RAPID

        rapid = np.zeros(n, bool)
        rapid[ok] = (win.moves["flags"][rows[ok]] & FLAG_RAPID) != 0
        kind = np.where((kind == KIND_TRAVEL) & ~rapid, KIND_PRINT, kind)
    # cruise phases of straight moves have constant speed: one piece is exact
    const_v = (np.abs(_columns(segs, "a")[:, :3]).sum(axis=1) == 0) & (np.abs(_columns(segs, "j")[:, :3]).sum(axis=1) == 0)
    per = np.where(const_v, 1, max(1, pieces_per_segment))
    seg = np.repeat(np.arange(n), per)
    start = np.r_[0, np.cumsum(per)[:-1]]
    k = np.arange(seg.size) - np.repeat(start, per)
    frac0 = k / per[seg]
    frac1 = (k + 1) / per[seg]
    dt = segs["dt"][seg]
    p0, _, _, _ = eval_segments(segs, seg, frac0 * dt)
    p1, _, _, _ = eval_segments(segs, seg, frac1 * dt)
    _, vm, _, _ = eval_segments(segs, seg, 0.5 * (frac0 + frac1) * dt)
    speed = np.sqrt((vm[:, :3] ** 2).sum(axis=1))
    moved = np.hypot(p1[:, 0] - p0[:, 0], p1[:, 1] - p0[:, 1]) > 0
    kseg = kind[seg]
    fig, axs = new_figure(1, 1, size_in, dpi)
    ax = axs[0, 0]
    vmax = float(speed[moved].max()) if moved.any() else 1.0
    norm_kw = dict(cmap="viridis", clim=(0.0, max(vmax, 1e-9)))
    cols = {}
    names = {"print": "cutting (feed) moves" if cnc else "print moves",
             "travel": "rapids (G0, dashed)" if cnc else "travel moves (dashed)"}
    for name, sel, style, lw in (("print", kseg != KIND_TRAVEL, "solid", 1.2),
                                 ("travel", kseg == KIND_TRAVEL, (0, (3, 2)), 0.9)):
        m = sel & moved
        lc = LineCollection(np.stack([p0[m, :2], p1[m, :2]], axis=1), linestyles=style, linewidths=lw,
                            gid=f"path_{name}", label=names[name])
        lc.set_array(speed[m])
        lc.set_cmap(norm_kw["cmap"])
        lc.set_clim(*norm_kw["clim"])
        ax.add_collection(lc)
        cols[name] = lc
    ax.autoscale_view()
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.grid(True, alpha=0.3)
    handles = [Line2D([], [], color="0.3", lw=1.2, label=names["print"]),
               Line2D([], [], color="0.3", lw=0.9, ls=(0, (3, 2)), label=names["travel"])]
    ax.legend(handles=handles, loc="lower left", bbox_to_anchor=(0.0, 1.0), ncols=2, fontsize=9, frameon=False)
    fig.colorbar(cols["print"], ax=ax, label="toolhead speed (mm/s)", pad=0.01)
    fig.suptitle(title or _window_title(win, "toolpath coloured by speed"))
    return fig


# ----------------------------------------------------------------------------- layers
WAITS_NAME = "(waits)"
UNTAGGED_NAME = "(untagged)"


class LayerFeatureTimes:
    """Running time per (layer, feature), folded chunk by chunk with bincount.

    Slot [0, :] holds moves before the first layer change, slot [:, 0] moves with no feature
    tag, and the last column the waits (KIND_WAIT rows: heating, homing), kept apart so that a
    heat-up does not pass for a slow layer.
    """

    def __init__(self) -> None:
        self.t_s = np.zeros((1, 2))   # rows: layer + 1; columns: feature + 1, then waits

    def add(self, moves: np.ndarray, plan: np.ndarray) -> None:
        if moves.size == 0:
            return
        layer = np.maximum(moves["layer"], -1).astype(np.int64) + 1
        feat = np.maximum(moves["feature"], -1).astype(np.int64) + 1
        n_l = max(self.t_s.shape[0], int(layer.max()) + 1)
        n_f = max(self.t_s.shape[1] - 1, int(feat.max()) + 1)
        if (n_l, n_f + 1) != self.t_s.shape:
            grown = np.zeros((n_l, n_f + 1))
            grown[: self.t_s.shape[0], : self.t_s.shape[1] - 1] = self.t_s[:, :-1]
            grown[: self.t_s.shape[0], -1] = self.t_s[:, -1]
            self.t_s = grown
        col = np.where(moves["kind"] == KIND_WAIT, n_f, feat)
        flat = np.bincount(layer * (n_f + 1) + col, weights=plan["duration"], minlength=n_l * (n_f + 1))
        self.t_s += flat.reshape(n_l, n_f + 1)

    def column_names(self, feature_names: list) -> list[str]:
        n_f = self.t_s.shape[1] - 1
        return [UNTAGGED_NAME] + [str(feature_names[i]) if i < len(feature_names) else f"feature {i}"
                                  for i in range(n_f - 1)] + [WAITS_NAME]

    def layer_times(self) -> np.ndarray:
        """Seconds per layer 0..N−1 (without the pre-layer slot)."""
        return self.t_s[1:].sum(axis=1)


def plot_layers(times: LayerFeatureTimes, feature_names: list, layer_z: list | None = None,
                title: str = "time per layer", size_in=FIGSIZE_IN, dpi: int = DPI, max_features: int = 10) -> Figure:
    """Time per layer as stacked bars split by feature type (the largest ``max_features``
    features by total time; the rest as "other"). Time before the first layer change is given
    in the title, not as a bar. Bar containers are labelled with the feature name and their
    rectangles carry gids ``layer_bars:<feature>``."""
    t = times.t_s
    n_layers = t.shape[0] - 1
    if n_layers <= 0:
        raise GcodeplanError("the file has no layer changes: nothing to draw per layer")
    names = times.column_names(feature_names)
    body = t[1:]
    # merge duplicate names (a feature list may repeat a name under two indices)
    uniq: dict[str, np.ndarray] = {}
    for i, nm in enumerate(names):
        uniq[nm] = uniq.get(nm, 0.0) + body[:, i]
    order = sorted((nm for nm in uniq if uniq[nm].sum() > 0), key=lambda nm: -uniq[nm].sum())
    if len(order) > max_features:
        keep, rest = order[: max_features - 1], order[max_features - 1:]
        other = sum(uniq[nm] for nm in rest)
        uniq = {nm: uniq[nm] for nm in keep}
        uniq["other"] = other
        order = keep + ["other"]
    fig, axs = new_figure(1, 1, size_in, dpi)
    ax = axs[0, 0]
    x = np.arange(n_layers)
    bottom = np.zeros(n_layers)
    # the viewer page's colours (report/palette.py): a feature looks the same in both
    from .palette import NO_FEATURE_COLOR, OTHER_COLOR, WAITS_COLOR, feature_colors

    colors = dict(zip(names[1:-1], feature_colors(names[1:-1])))
    colors.update({WAITS_NAME: WAITS_COLOR, UNTAGGED_NAME: NO_FEATURE_COLOR, "other": OTHER_COLOR})
    width = 0.85 if n_layers < 200 else 1.0
    for i, nm in enumerate(order):
        h = np.asarray(uniq[nm], dtype=np.float64)
        color = colors.get(nm, OTHER_COLOR)
        bars = ax.bar(x, h, bottom=bottom, width=width, color=color, label=nm, linewidth=0)
        for r in bars:
            r.set_gid(f"layer_bars:{nm}")
        bottom += h
    ax.set_xlabel("layer index")
    ax.set_ylabel("time (s)")
    ax.set_xlim(-0.5 if n_layers < 200 else -1, n_layers - 0.5)
    ax.grid(True, axis="y", alpha=0.3)
    ax.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=9, title="feature")
    z = np.asarray(layer_z[:n_layers] if layer_z is not None else [], dtype=np.float64)
    if z.size == n_layers > 1 and np.all(np.isfinite(z)) and np.all(np.diff(z) > 0):
        # a z scale on top only when it is a plain function of the index (not a vase's or a z-hop's)
        sec = ax.secondary_xaxis("top", functions=(lambda i: np.interp(i, x, z), lambda zz: np.interp(zz, z, x)))
        sec.set_xlabel("z (mm)")
    pre = float(t[0].sum())
    slow = int(np.argmax(bottom))
    fig.suptitle(f"{title} — {n_layers} layers, total {bottom.sum() + pre:.1f} s, slowest layer {slow} "
                 f"({bottom[slow]:.1f} s), before the first layer {pre:.1f} s")
    return fig


# ----------------------------------------------------------------------------- profiles
def plot_profile_1d(t, q, v, a, j, title: str = "", size_in=FIGSIZE_IN, dpi: int = DPI) -> Figure:
    """One 1-D motion profile: position, velocity, acceleration and jerk against time
    (for ``gcodeplan profile --plot``). The arrays are drawn as given (already sampled from the
    profile); lines carry gids ``q``, ``v``, ``a``, ``j``."""
    t = np.asarray(t, dtype=np.float64)
    fig, axs = new_figure(4, 1, size_in, dpi, sharex=True)
    for ax, y, gid, lab in zip(axs[:, 0], (q, v, a, j), "qvaj",
                               ("position (mm)", "velocity (mm/s)", "acceleration (mm/s²)", "jerk (mm/s³)")):
        ax.plot(t, np.asarray(y, dtype=np.float64), color="black", lw=1.2, gid=gid)
        ax.set_ylabel(lab)
        ax.grid(True, alpha=0.3)
    axs[-1, 0].set_xlabel("time (s)")
    if t.size:
        axs[0, 0].set_xlim(t[0], t[-1])
    if title:
        fig.suptitle(title)
    return fig


__all__ = [
    "Window", "Samples", "LayerFeatureTimes", "eval_segments", "sample_plan", "toolhead_kinematics", "motor_motion",
    "plot_velocity", "plot_axes", "plot_path", "plot_layers", "plot_profile_1d", "save_png", "png_bytes",
    "new_figure", "FIGSIZE_IN", "DPI",
]
