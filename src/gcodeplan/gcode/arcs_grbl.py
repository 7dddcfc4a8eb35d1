"""G2/G3 arcs cut into chords as grbl 1.1 cuts them (gcode.c's centre rules, motion_control.c ``mc_arc``).

grbl does not bound a chord's sagitta by a search: it takes ``floor(|½·θ·r| / √(tol·(2r − tol)))`` chords
($12 = tol; zero chords → one straight move), rotates the radius vector by a third-order small-angle
approximation of the chord angle, and every ``N_ARC_CORRECTION`` (12) chords puts it back on the circle with
``sin``/``cos``. Everything is single precision with double constants, as grbl's C source evaluates it; the
chord end points are therefore the firmware's to the last bit (docs/design.md, *grbl 1.1*).
"""
from __future__ import annotations

import math

from .._jit import njit
import numpy as np

N_ARC_CORRECTION = 12
ARC_ANGULAR_TRAVEL_EPSILON = 5e-7        # rad
MAX_CHORDS = 65535                       # grbl's segment count is a uint16

# plane → (axis_0, axis_1, axis_linear), gcode.c: G17 X Y Z, G18 Z X Y, G19 Y Z X
PLANE_AXES = {17: (0, 1, 2), 18: (2, 0, 1), 19: (1, 2, 0)}


@njit(cache=True)
def _hypot_f(x, y):
    """nuts_bolts.c hypot_f: √(x² + y²) from single-precision squares."""
    return np.float32(math.sqrt(np.float64(np.float32(np.float32(x * x) + np.float32(y * y)))))


@njit(cache=True)
def grbl_arc_kernel(position, target, offset, radius, use_r, a0, a1, lin, clockwise, arc_tolerance, out):
    """Chord end points of one arc into ``out`` (rows of x, y, z; the last is the target); returns their count,
    or −1 for grbl's arc radius error (R shorter than half the chord), −2 for an end point off the circle
    (error:33 in grbl's rule: |r_end − r| > 0.005 mm and > 0.5 mm or > 0.1 % of r), or −10 − n when ``out``
    cannot hold the n + 1 points (nothing written).
    ``position``, ``target``, ``offset`` are float32[3] in mm (offset = I/J/K from the start); ``radius`` is
    the R word in mm when ``use_r``."""
    pos = position.copy()
    off = offset.copy()
    x = np.float32(target[a0] - pos[a0])
    y = np.float32(target[a1] - pos[a1])
    if use_r:
        if x == 0.0 and y == 0.0:       # gcode.c: an R arc to its own start point (error:33)
            return -2
        r = np.float32(radius)
        h = np.float32(4.0 * np.float64(r) * np.float64(r) - np.float64(np.float32(x * x)) - np.float64(np.float32(y * y)))
        if h < 0:
            return -1
        h = np.float32(-math.sqrt(np.float64(h)) / np.float64(_hypot_f(x, y)))
        if not clockwise:
            h = -h
        if r < 0:
            h = -h
            r = -r
        off[a0] = np.float32(0.5 * np.float64(np.float32(x - np.float32(y * h))))
        off[a1] = np.float32(0.5 * np.float64(np.float32(y + np.float32(x * h))))
    else:
        x = np.float32(x - off[a0])
        y = np.float32(y - off[a1])
        target_r = _hypot_f(x, y)
        r = _hypot_f(off[a0], off[a1])
        delta_r = abs(np.float64(np.float32(target_r - r)))
        if delta_r > 0.005:
            if delta_r > 0.5 or delta_r > 0.001 * np.float64(r):
                return -2
    # motion_control.c mc_arc
    center0 = np.float32(pos[a0] + off[a0])
    center1 = np.float32(pos[a1] + off[a1])
    r0 = np.float32(-off[a0])
    r1 = np.float32(-off[a1])
    rt0 = np.float32(target[a0] - center0)
    rt1 = np.float32(target[a1] - center1)
    travel = np.float32(math.atan2(np.float64(np.float32(np.float32(r0 * rt1) - np.float32(r1 * rt0))),
                                   np.float64(np.float32(np.float32(r0 * rt0) + np.float32(r1 * rt1)))))
    if clockwise:
        if travel >= -ARC_ANGULAR_TRAVEL_EPSILON:
            travel = np.float32(np.float64(travel) - 2 * math.pi)
    else:
        if travel <= ARC_ANGULAR_TRAVEL_EPSILON:
            travel = np.float32(np.float64(travel) + 2 * math.pi)
    tol = np.float32(arc_tolerance)
    denom = math.sqrt(np.float64(np.float32(tol * np.float32(np.float32(np.float32(2) * r) - tol))))
    if not (math.isfinite(np.float64(travel)) and math.isfinite(np.float64(r)) and math.isfinite(center0)
            and math.isfinite(center1)):
        return -2                       # single precision overflowed (an absurd centre or radius): no arc
    segments = 0
    if denom > 0.0:      # a radius under half the tolerance: one straight move (C would divide by NaN)
        segments_f = math.floor(abs(0.5 * np.float64(travel) * np.float64(r)) / denom)
        segments = int(segments_f) if segments_f < 65535.0 else 65535
    if segments + 1 > out.shape[0]:
        return -10 - segments           # out too small: the caller makes room for segments + 1 rows
    n = 0
    if segments:
        theta = np.float32(travel / np.float32(segments))
        linear = np.float32(np.float32(target[lin] - pos[lin]) / np.float32(segments))
        cos_t = np.float32(2.0 - np.float64(np.float32(theta * theta)))
        sin_t = np.float32(np.float64(theta) * 0.16666667 * (np.float64(cos_t) + 4.0))
        cos_t = np.float32(np.float64(cos_t) * 0.5)
        count = 0
        for i in range(1, segments):
            if count < N_ARC_CORRECTION:
                ri = np.float32(np.float32(r0 * sin_t) + np.float32(r1 * cos_t))
                r0 = np.float32(np.float32(r0 * cos_t) - np.float32(r1 * sin_t))
                r1 = ri
                count += 1
            else:
                a = np.float32(np.float32(i) * theta)
                cos_ti = np.float32(math.cos(np.float64(a)))
                sin_ti = np.float32(math.sin(np.float64(a)))
                r0 = np.float32(np.float32(-off[a0] * cos_ti) + np.float32(off[a1] * sin_ti))
                r1 = np.float32(np.float32(-off[a0] * sin_ti) - np.float32(off[a1] * cos_ti))
                count = 0
            pos[a0] = np.float32(center0 + r0)
            pos[a1] = np.float32(center1 + r1)
            pos[lin] = np.float32(pos[lin] + linear)
            for k in range(3):
                out[n, k] = pos[k]
            n += 1
    for k in range(3):
        out[n, k] = target[k]
    return n + 1


def _kernel_args(start, end, ijk, r, plane: int, clockwise: bool, arc_tolerance: float):
    """grbl_arc_kernel's arguments (all but ``out``) for one arc, in grbl's floats, and the arc's radius (mm)."""
    from ..planner.grbl import grbl_floats

    a0, a1, lin = PLANE_AXES[plane]
    # every number in one call of the rounding kernel (each value rounded on its own, as grbl_float does)
    vals = grbl_floats(np.array([*start, *end, *(ijk if ijk is not None else (0.0, 0.0, 0.0)),
                                 0.0 if r is None else r], dtype=np.float64))
    pos = vals[0:3].copy()
    tgt = vals[3:6].copy()
    off = np.zeros(3, np.float32) if ijk is None else vals[6:9].copy()
    if r is not None:
        r = vals[9]
    use_r = ijk is None
    radius = abs(float(r)) if use_r else math.hypot(float(off[a0]), float(off[a1]))
    args = (pos, tgt, off, np.float32(0.0 if r is None else r), use_r, a0, a1, lin, clockwise,
            np.float32(arc_tolerance))
    return args, radius


def grbl_arc_error(start, end, ijk, r, plane: int, clockwise: bool, arc_tolerance: float) -> int:
    """grbl's error number for one G2/G3 (arguments as :func:`grbl_arc_chords`), found as gcode.c's block
    check finds it, before anything of the line runs: 0 (none), 34 (arc radius error: R shorter than half the
    chord) or 33 (invalid target: an R arc to its own start, an end point off the circle)."""
    args, _ = _kernel_args(start, end, ijk, r, plane, clockwise, arc_tolerance)
    n = grbl_arc_kernel(*args, np.empty((0, 3), np.float32))    # no room: the checks run, nothing is cut
    return 34 if n == -1 else 33 if n == -2 else 0


def grbl_arc_chords(start, end, ijk, r, plane: int, clockwise: bool, arc_tolerance: float) -> np.ndarray:
    """The chord end points (n, 3) grbl makes for one G2/G3, the last one the target. ``start``/``end`` mm;
    ``ijk`` the centre offset from the start (mm) or None with ``r`` the R word (mm). Raises ValueError with
    grbl's error for an impossible arc (the grbl interpreter rejects such a line first: gcode/rs274.py)."""
    args, radius = _kernel_args(start, end, ijk, r, plane, clockwise, arc_tolerance)
    q = arc_tolerance * (2 * radius - arc_tolerance)
    bound = MAX_CHORDS if not q > 0 else int(min(MAX_CHORDS, math.pi * radius * 1.001 / math.sqrt(q) + 2))
    out = np.empty((bound + 2, 3), np.float32)
    n = grbl_arc_kernel(*args, out)
    if n <= -10:                        # the estimate above was short (single precision): exactly what it needs
        out = np.empty((-n - 10 + 1, 3), np.float32)
        n = grbl_arc_kernel(*args, out)
    if n == -1:
        raise ValueError("arc radius error: R is shorter than half the chord (grbl error:34)")
    if n == -2:
        raise ValueError("invalid arc target: the end point is off the circle (grbl error:33)")
    return out[:n].astype(np.float64)
