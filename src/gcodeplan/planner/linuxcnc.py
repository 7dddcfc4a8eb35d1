"""The 'linuxcnc' junction policy: plan a program as LinuxCNC 2.9's trajectory planner runs it.

MOVE rows → TP segments (:func:`build_segments`), the way LinuxCNC's canon (``emccanon.cc``) hands them to
the planner:

* G1 runs within the naive-CAM tolerance (G64 Q; Q = P when only P is given) merge into one segment tagged
  with the last merged line (at most 101 points, the feed and mode unchanged); an XY arc that deviates less
  than Q from its chord joins such a run as its middle and end point (``ARC_FEED``'s ``chord_deviation``);
* the chords the parser cut an arc into are regrouped into one circular segment (centre, radius and swept
  angle from the chord end points, which lie on the circle; the helix axis is the coordinate axis normal to
  the chords' plane);
* per-segment limits by LinuxCNC's per-axis projection: a line's speed and acceleration are its length over
  the slowest axis' time (``getStraightVelocity``/``getStraightAcceleration``), an arc's those of its circular
  motion under the plane axes' limits and of its straight displacement under every axis' own
  (``ARC_FEED``, :func:`arc_limits`);
* the G-code mode: G61.1 stop, G61 exact path, G64 blend with tolerance P; moves that end where they start
  are dropped; M3/M4/M5/M6/G43, dwells and the program end drain the queue (the next move starts at rest).

Then :mod:`gcodeplan.planner.linuxcnc_tp` queues them (blends, tangent joins, look-ahead) and runs them one
servo cycle at a time. The result: PLAN rows (one per MOVE row; a segment's time is split over its MOVE
rows in proportion to their length, a blend arc's time goes to the line after it as LinuxCNC tags it, and a
line a blend arc swallowed ends with the segment LinuxCNC showed under its number; rows that make no segment
last 0 s), the per-cycle trace, and SEGMENT rows (constant-acceleration pieces fitted to the cycle
positions).

How it differs from the 'blend' policy (:mod:`gcodeplan.planner.blend`): 'blend' is the textbook
parabolic blend (constant acceleration across the corner at full acceleration, deviation |Δv|·τ/4 ≤ P,
exact stop where no P is given, continuous time). 'linuxcnc' rounds corners with tangent circular arcs
sized by the tolerance (no tolerance: up to a quarter of each segment), falls back to parabolic blends at
*half* acceleration on both segments, stops at G61.1, reduces acceleration by the kink ratio at G61 corners,
plans arcs as circles with the normal acceleration limit, looks ahead a bounded number of segments, and is
discrete in 1 ms servo cycles (a segment takes at least one cycle).
"""
from __future__ import annotations

import math

from .._jit import njit
import numpy as np

from ..errors import ConfigError, GcodeError
from ..schema import (FLAG_ARC, FLAG_RAPID, KIND_DWELL, KIND_EXTRUDE_ONLY, KIND_WAIT, LIMIT_ACCEL, LIMIT_FEED,
                      LIMIT_NONE, PHASE_ACCEL, PHASE_CRUISE, PHASE_DECEL, PHASE_DWELL,
                      PLAN_DTYPE, SEGMENT_DTYPE)
from .linuxcnc_tp import (SEG_CIRCLE, SEG_DTYPE, SEG_LINE, TERM_EXACT, TERM_PARABOLIC, TERM_STOP, TP_POS_EPSILON,
                          execute_kernel, queue_kernel)

CHAIN_MAX = 101            # emccanon.cc: a naive-CAM chain holds at most 100 points before it must flush
CART_FUZZ = 1e-8           # mm, posemath.h: emccanon.cc ignores an axis displacement below this


# --------------------------------------------------------------------------- settings
class LinuxcncSettings:
    """The [TRAJ]/[EMCMOT] settings the planner needs (defaults: LinuxCNC 2.9's initraj.cc built-ins)."""

    def __init__(self, cycle: float = 0.001, arc_blend_enable: bool = True, optimization_depth: int = 50,
                 gap_cycles: float = 4.0, ramp_freq: float = 100.0, kink_ratio: float = 0.1):
        self.cycle = float(cycle)                    # s, [EMCMOT]SERVO_PERIOD
        self.arc_blend_enable = bool(arc_blend_enable)
        self.optimization_depth = int(optimization_depth)
        self.gap_cycles = float(gap_cycles)
        self.ramp_freq = float(ramp_freq)            # Hz
        self.kink_ratio = min(max(float(kink_ratio), 0.001), 0.7071)   # tp.c bounds it
        # what the interpreter takes from the .ini (config/linuxcnc.py; gcode/rs274.py)
        self.program_units_mm = 1.0                  # mm per program unit before any G20/G21 ([TRAJ]LINEAR_UNITS)
        self.parameters: dict[int, float] = {}       # the .var parameter file (#5161-5169 G28, #5181-5189 G30)
        self.tool_table: dict[int, float] = {}       # tool number -> length offset Z (mm), [EMCIO]TOOL_TABLE
        self.tool_change_position = None             # (x, y, z) machine mm, [EMCIO]TOOL_CHANGE_POSITION
        self.startup_code = ""                       # [RS274NGC]RS274NGC_STARTUP_CODE


def settings_of(machine) -> LinuxcncSettings:
    """The machine's LinuxCNC settings (``machine.linuxcnc``, set by the .ini reader), else the defaults."""
    s = getattr(machine, "linuxcnc", None)
    return s if isinstance(s, LinuxcncSettings) else LinuxcncSettings()


def _axis_limits(machine, limits) -> tuple[np.ndarray, np.ndarray]:
    lim = limits[0] if len(limits) else None
    v = np.array([float(lim["axis_v_" + a]) if lim is not None else machine.axes[a].max_velocity for a in "xyz"])
    a = np.array([float(lim["axis_a_" + a]) if lim is not None else machine.axes[a].max_accel for a in "xyz"])
    return v, a


# --------------------------------------------------------------------------- building segments
@njit(cache=True)
def _mode(mv):
    if mv.exact_stop == 1:
        return TERM_STOP
    if mv.exact_stop == 2:
        return TERM_EXACT
    return TERM_PARABOLIC


@njit(cache=True)
def _init_seg(sg, line, row0, row1, term, tol, feed, traverse):
    sg.line = line
    sg.row0 = row0
    sg.row1 = row1
    sg.term = term
    sg.tolerance = tol
    sg.reqvel = feed
    sg.traverse = traverse
    sg.blend_prev = 0
    sg.kink_vel = -1.0
    sg.kink_red = 0.0
    sg.kink_red_prev = 0.0
    sg.acc_ratio_tan = 0.5
    sg.finalized = 0
    sg.finalvel = 0.0
    sg.at_max = 0
    sg.sync_after = 0
    sg.dwell_after = 0.0
    sg.lline = 0.0
    sg.radius = 0.0
    sg.angle = 0.0
    for a in range(3):
        sg.c[a] = 0.0
        sg.rt[a] = 0.0
        sg.rp[a] = 0.0
        sg.h[a] = 0.0


@njit(cache=True)
def _emit_line(out, n, x0, y0, z0, x1, y1, z1, line, row0, row1, term, tol, feed, traverse, vmax, amax,
               vlimit_tool, amax_tool, cycle):
    """emccanon.cc STRAIGHT_FEED/TRAVERSE + tp.c tpAddLine: one line segment (dropped when zero-length)."""
    d = (x1 - x0, y1 - y0, z1 - z0)
    L = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
    if L < TP_POS_EPSILON:
        return n
    tv = 0.0
    ta = 0.0
    for a in range(3):
        da = abs(d[a])
        if da < 1e-10:
            continue
        tv = max(tv, da / vmax[a])
        ta = max(ta, da / amax[a])
    ini_v = L / tv if tv > 0.0 else vlimit_tool
    acc = L / ta if ta > 0.0 else amax_tool
    acc = min(acc, amax_tool)
    sg = out[n]
    _init_seg(sg, line, row0, row1, term, tol, ini_v if traverse else min(feed, ini_v), traverse)
    sg.kind = SEG_LINE
    sg.p0[0], sg.p0[1], sg.p0[2] = x0, y0, z0
    sg.p1[0], sg.p1[1], sg.p1[2] = x1, y1, z1
    for a in range(3):
        sg.u[a] = d[a] / L
    sg.target = L
    sg.nominal = L
    sg.inivel = ini_v
    sg.maxvel = min(ini_v, L / cycle)           # tcClampVelocityByLength
    sg.maxaccel = acc
    return n + 1


@njit(cache=True)
def arc_limits(r0, dr, angle, p0, p1, i, j, vmax, amax):
    """emccanon.cc ARC_FEED: (max speed mm/s, max acceleration mm/s²) of a circle or helix of start radius
    ``r0`` (mm), radius change ``dr`` (mm) over ``angle`` (rad) from ``p0`` to ``p1`` in the plane of axes
    i, j. The circular motion is held by the plane axes (speed, and √3/2 of their acceleration as normal
    acceleration on the effective radius), the straight displacement p0 → p1 (the helix axis' travel) by
    every axis' own limits (getStraightVelocity/Acceleration, displacements under CART_FUZZ ignored); the
    least time of the two, spread over the whole helical length, gives the limits."""
    v_axes = min(vmax[i], vmax[j])
    a_axes = min(amax[i], amax[j])
    r_min = min(r0, r0 + dr)
    spiral_per_rad = dr / angle if angle > 0.0 else 0.0
    eff_r = math.sqrt(spiral_per_rad * spiral_per_rad + r_min * r_min)
    v_planar = min(math.sqrt(a_axes * math.sqrt(3.0) / 2.0 * eff_r), v_axes)
    spiral_len = math.hypot(r_min * angle, dr)
    t_motion = 0.0
    ta_motion = 0.0
    axial2 = 0.0
    for a in range(3):
        d = abs(p1[a] - p0[a])
        if a != i and a != j:
            axial2 += d * d
        if d < CART_FUZZ:
            continue
        t_motion = max(t_motion, d / vmax[a])
        ta_motion = max(ta_motion, d / amax[a])
    total = math.hypot(spiral_len, math.sqrt(axial2))
    t_max = max(t_motion, spiral_len / v_planar)
    tt_max = max(ta_motion, spiral_len / a_axes)
    return total / t_max, total / tt_max


@njit(cache=True)
def _chords_circumcircle(pts, m, i, j):
    """The circle through the first, middle and last of the ``m + 1`` chord points ``pts`` in the (i, j) plane
    (another point for the last when the chords close a full circle). Returns (ok, centre i, centre j,
    radius), mm."""
    A = pts[0]
    B = pts[(m + 1) // 2]
    C = pts[m]
    if (m + 1) // 2 == m or (m + 1) // 2 == 0:
        B = pts[1]
    ax_, ay_ = A[i], A[j]
    bx_, by_ = B[i], B[j]
    cx_, cy_ = C[i], C[j]
    if abs(ax_ - cx_) + abs(ay_ - cy_) < 1e-12:
        C = pts[m - 1]   # a full circle: use another point
        cx_, cy_ = C[i], C[j]
    den = 2.0 * (ax_ * (by_ - cy_) + bx_ * (cy_ - ay_) + cx_ * (ay_ - by_))
    if den == 0.0:
        return False, 0.0, 0.0, 0.0
    a2 = ax_ * ax_ + ay_ * ay_
    b2 = bx_ * bx_ + by_ * by_
    c2_ = cx_ * cx_ + cy_ * cy_
    ux = (a2 * (by_ - cy_) + b2 * (cy_ - ay_) + c2_ * (ay_ - by_)) / den
    uy = (a2 * (cx_ - bx_) + b2 * (ax_ - cx_) + c2_ * (bx_ - ax_)) / den
    return True, ux, uy, math.hypot(ax_ - ux, ay_ - uy)


@njit(cache=True)
def _chords_sweep(pts, m, i, j, ux, uy):
    """The signed angle (rad) the ``m`` chords sweep around the centre (ux, uy) of the (i, j) plane."""
    sweep = 0.0
    for k in range(m):
        p = pts[k]
        q = pts[k + 1]
        vx0, vy0 = p[i] - ux, p[j] - uy
        vx1, vy1 = q[i] - ux, q[j] - uy
        sweep += math.atan2(vx0 * vy1 - vy0 * vx1, vx0 * vx1 + vy0 * vy1)
    return sweep


@njit(cache=True)
def _emit_arc(out, n, moves, r0, r1, term, tol, feed, vmax, amax, amax_tool, cycle):
    """The chords r0..r1 of one arc as one circular segment; returns (n, ok)."""
    m = r1 - r0 + 1
    if m < 2:
        return n, False
    pts = np.empty((m + 1, 3))
    pts[0, 0], pts[0, 1], pts[0, 2] = moves[r0].x0, moves[r0].y0, moves[r0].z0
    for k in range(m):
        mv = moves[r0 + k]
        pts[k + 1, 0], pts[k + 1, 1], pts[k + 1, 2] = mv.x1, mv.y1, mv.z1
    # the helix axis: the coordinate axis most normal to the first two chords
    c1 = pts[1] - pts[0]
    c2 = pts[2] - pts[1]
    cr = (c1[1] * c2[2] - c1[2] * c2[1], c1[2] * c2[0] - c1[0] * c2[2], c1[0] * c2[1] - c1[1] * c2[0])
    ax = 0
    for a in range(3):
        if abs(cr[a]) > abs(cr[ax]):
            ax = a
    if cr[ax] == 0.0:
        return n, False
    i = (ax + 1) % 3
    j = (ax + 2) % 3
    ok, ux, uy, R = _chords_circumcircle(pts, m, i, j)
    if not ok:
        return n, False
    sweep = _chords_sweep(pts, m, i, j, ux, uy)
    # The parser places the chord ends as LinuxCNC's arc does: equal angle steps, the radius changing
    # linearly from start to end (a "spiral" when the G-code's end point is slightly off the circle of its
    # I/J centre). Fit that exactly (Gauss-Newton from the circle through three points) so that the
    # tangents at the ends, which decide tangent joins, are LinuxCNC's.
    ux, uy, R, dr, th0, sweep = _fit_spiral(pts, m, i, j, ux, uy, R, sweep)
    angle = abs(sweep)
    sgn = 1.0 if sweep > 0.0 else -1.0
    ax_ = pts[0, i]
    ay_ = pts[0, j]
    h = pts[m, ax] - pts[0, ax]
    sg = out[n]
    _init_seg(sg, moves[r1].line, r0, r1, term, tol, feed, 0)
    sg.kind = SEG_CIRCLE
    for a in range(3):
        sg.p0[a] = pts[0, a]
        sg.p1[a] = pts[m, a]
        sg.c[a] = pts[0, a]
        sg.h[a] = 0.0
        sg.u[a] = 0.0
    sg.c[i] = ux
    sg.c[j] = uy
    sg.rt[i] = ax_ - ux
    sg.rt[j] = ay_ - uy
    sg.rt[ax] = 0.0
    # rp = n × rt with n = sgn·e_ax
    sg.rp[ax] = 0.0
    sg.rp[i] = -sgn * sg.rt[j]
    sg.rp[j] = sgn * sg.rt[i]
    sg.h[ax] = h
    sg.radius = R
    sg.spiral = dr
    sg.angle = angle
    # check the reconstruction reaches the end point
    ce = math.cos(angle)
    se = math.sin(angle)
    rf = (R + dr) / R if R > 0.0 else 1.0
    err = 0.0
    for a in range(3):
        e = sg.c[a] + (sg.rt[a] * ce + sg.rp[a] * se) * rf + sg.h[a] - pts[m, a]
        err = max(err, abs(e))
    if err > 1e-6 * max(1.0, R) or not R > 0.0:
        return n, False
    L = math.sqrt(((R + 0.5 * dr) * angle) ** 2 + h * h)
    if L < TP_POS_EPSILON:
        return n, False
    ini_v, acc = arc_limits(R, dr, angle, pts[0], pts[m], i, j, vmax, amax)
    acc = min(acc, amax_tool)
    sg.reqvel = min(feed, ini_v)
    sg.target = L
    sg.nominal = L
    sg.inivel = ini_v
    sg.maxvel = min(ini_v, L / cycle)
    sg.maxaccel = acc
    # the normal-acceleration limit is applied when the segment is finalised (tc.c tcFinalizeLength), once
    # its neighbours and so its acceleration are known, as LinuxCNC does
    return n + 1, True


@njit(cache=True)
def _gauss_newton_step(J, res):
    """(ok, step) solving (JᵀJ)·step = Jᵀ·res by Gaussian elimination with partial pivoting, in loops: numba's
    matrix product and np.linalg need SciPy's BLAS/LAPACK, which gcodeplan does not depend on."""
    n = J.shape[1]
    A = np.zeros((n, n))
    g = np.zeros(n)
    for r in range(J.shape[0]):
        for a in range(n):
            g[a] += J[r, a] * res[r]
            for b in range(n):
                A[a, b] += J[r, a] * J[r, b]
    step = np.zeros(n)
    for d in range(n):
        if not A[d, d] > 0.0:
            return False, step
    for col in range(n):
        piv = col
        for r in range(col + 1, n):
            if abs(A[r, col]) > abs(A[piv, col]):
                piv = r
        if A[piv, col] == 0.0:
            return False, step
        if piv != col:
            for c in range(n):
                A[col, c], A[piv, c] = A[piv, c], A[col, c]
            g[col], g[piv] = g[piv], g[col]
        for r in range(col + 1, n):
            f = A[r, col] / A[col, col]
            if f != 0.0:
                for c in range(col, n):
                    A[r, c] -= f * A[col, c]
                g[r] -= f * g[col]
    for r in range(n - 1, -1, -1):
        acc = g[r]
        for c in range(r + 1, n):
            acc -= A[r, c] * step[c]
        step[r] = acc / A[r, r]
    return True, step


@njit(cache=True)
def _fit_spiral(pts, m, i, j, cx, cy, r0, sweep):
    """Least squares of p_k = c + (r0 + dr·k/m)·(cos, sin)(θ0 + sweep·k/m) over the chord ends (plane axes
    i, j). Returns (cx, cy, r0, dr, θ0, sweep)."""
    th0 = math.atan2(pts[0, j] - cy, pts[0, i] - cx)
    dr = math.hypot(pts[m, i] - cx, pts[m, j] - cy) - r0
    x = np.array([cx, cy, r0, dr, th0, sweep])
    J = np.empty((2 * (m + 1), 6))
    res = np.empty(2 * (m + 1))
    for _ in range(8):
        for k in range(m + 1):
            f = k / m
            ang = x[4] + x[5] * f
            r = x[2] + x[3] * f
            ca = math.cos(ang)
            sa = math.sin(ang)
            res[2 * k] = x[0] + r * ca - pts[k, i]
            res[2 * k + 1] = x[1] + r * sa - pts[k, j]
            J[2 * k, 0] = 1.0
            J[2 * k, 1] = 0.0
            J[2 * k, 2] = ca
            J[2 * k, 3] = ca * f
            J[2 * k, 4] = -r * sa
            J[2 * k, 5] = -r * sa * f
            J[2 * k + 1, 0] = 0.0
            J[2 * k + 1, 1] = 1.0
            J[2 * k + 1, 2] = sa
            J[2 * k + 1, 3] = sa * f
            J[2 * k + 1, 4] = r * ca
            J[2 * k + 1, 5] = r * ca * f
        ok, step = _gauss_newton_step(J, res)
        if not ok:
            break
        for d in range(6):
            x[d] -= step[d]
        if np.max(np.abs(step)) < 1e-13 * max(1.0, abs(x[2])):
            break
    return x[0], x[1], x[2], x[3], x[4], x[5]


@njit(cache=True)
def _point_dist_to_seg(px, py, pz, bx, by, bz, ex, ey, ez):
    mx, my, mz = ex - bx, ey - by, ez - bz
    mm = mx * mx + my * my + mz * mz
    t0 = 0.0
    if mm > 0.0:
        t0 = (mx * (px - bx) + my * (py - by) + mz * (pz - bz)) / mm
    t0 = min(1.0, max(0.0, t0))
    dx = px - (bx + t0 * mx)
    dy = py - (by + t0 * my)
    dz = pz - (bz + t0 * mz)
    return math.sqrt(dx * dx + dy * dy + dz * dz)


@njit(cache=True)
def _naive_arc_points(moves, r0, r1):
    """emccanon.cc ARC_FEED/chord_deviation for the chords r0..r1 of one arc: (ok, deviation of the arc
    from its chord (mm), the arc's middle point). ``ok`` is False unless the arc lies in the XY plane —
    LinuxCNC's canon only lets XY arcs join a naive-CAM chain."""
    m = r1 - r0 + 1
    sx, sy, sz = moves[r0].x0, moves[r0].y0, moves[r0].z0
    ex, ey, ez = moves[r1].x1, moves[r1].y1, moves[r1].z1
    if m < 2:
        # one chord: the parser found the arc within its chord tolerance of a line, so its deviation is
        # below that (taken as 0); the chord's middle stands for the arc's, the plane is XY when Z stays
        return sz == ez, 0.0, (sx + ex) / 2.0, (sy + ey) / 2.0, sz
    # the plane: the chords turn about Z only when the arc is in XY
    c1x, c1y, c1z = moves[r0].x1 - sx, moves[r0].y1 - sy, moves[r0].z1 - sz
    c2x, c2y, c2z = (moves[r0 + 1].x1 - moves[r0 + 1].x0, moves[r0 + 1].y1 - moves[r0 + 1].y0,
                     moves[r0 + 1].z1 - moves[r0 + 1].z0)
    crx, cry, crz = c1y * c2z - c1z * c2y, c1z * c2x - c1x * c2z, c1x * c2y - c1y * c2x
    if not (abs(crz) > abs(crx) and abs(crz) > abs(cry)):
        return False, 0.0, 0.0, 0.0, 0.0
    # centre: circumcircle of start, middle chord end and end (XY)
    k = (m + 1) // 2
    mxp, myp = moves[r0 + k - 1].x1, moves[r0 + k - 1].y1
    if abs(sx - ex) + abs(sy - ey) < 1e-12:
        ex2, ey2 = moves[r1 - 1].x1, moves[r1 - 1].y1
    else:
        ex2, ey2 = ex, ey
    den = 2.0 * (sx * (myp - ey2) + mxp * (ey2 - sy) + ex2 * (sy - myp))
    if den == 0.0:
        return False, 0.0, 0.0, 0.0, 0.0
    a2 = sx * sx + sy * sy
    b2 = mxp * mxp + myp * myp
    c2 = ex2 * ex2 + ey2 * ey2
    ux = (a2 * (myp - ey2) + b2 * (ey2 - sy) + c2 * (sy - myp)) / den
    uy = (a2 * (ex2 - mxp) + b2 * (sx - ex2) + c2 * (mxp - sx)) / den
    sweep = 0.0
    for t in range(m):
        mv = moves[r0 + t]
        vx0, vy0 = mv.x0 - ux, mv.y0 - uy
        vx1, vy1 = mv.x1 - ux, mv.y1 - uy
        sweep += math.atan2(vx0 * vy1 - vy0 * vx1, vx0 * vx1 + vy0 * vy1)
    rad = math.hypot(sx - ux, sy - uy)
    th1 = math.atan2(sy - uy, sx - ux)
    mid = th1 + sweep / 2.0
    dev = rad * (1.0 - math.cos(abs(sweep) / 2.0))
    return True, dev, ux + rad * math.cos(mid), uy + rad * math.sin(mid), (sz + ez) / 2.0


@njit(cache=True)
def _linkable(pts, nc, bx, by, bz, px, py, pz, q_tol):
    """emccanon.cc linkable: the point P may extend the chain from B when every chained point stays within
    the naive-CAM tolerance of the segment B→P."""
    if px == bx and py == by and pz == bz:
        return False
    for t in range(nc):
        if _point_dist_to_seg(pts[t, 0], pts[t, 1], pts[t, 2], bx, by, bz, px, py, pz) > q_tol:
            return False
    return True


@njit(cache=True)
def _flush_segments(out, n, bx, by, bz, pts, pt_line, nc, ch_row0, ch_row1, ch_p, ch_feed, vmax, amax, vlimit_tool,
                    amax_tool, cycle):
    """emccanon.cc flush_segments: the naive-CAM chain (its ``nc`` points ``pts`` after the start (bx, by, bz))
    sent as one blended line to its last point, tagged with that point's line and the MOVE rows
    ch_row0..ch_row1 (none when empty). Returns the new segment count."""
    return _emit_line(out, n, bx, by, bz, pts[nc - 1, 0], pts[nc - 1, 1], pts[nc - 1, 2], pt_line[nc - 1],
                      ch_row0 if ch_row0 <= ch_row1 else -1, ch_row1, TERM_PARABOLIC, ch_p, ch_feed, 0, vmax, amax,
                      vlimit_tool, amax_tool, cycle)


@njit(cache=True)
def _arc_chords_end(moves, r):
    """The last MOVE row of the arc whose first chord is row ``r``: the chords of one G2/G3 line, each starting
    where the one before ends."""
    nm = moves.shape[0]
    r1 = r
    while (r1 + 1 < nm and (moves[r1 + 1].flags & FLAG_ARC) != 0 and moves[r1 + 1].line == moves[r].line
           and moves[r1 + 1].x0 == moves[r1].x1 and moves[r1 + 1].y0 == moves[r1].y1
           and moves[r1 + 1].z0 == moves[r1].z1):
        r1 += 1
    return r1


@njit(cache=True)
def _emit_arc_or_chords(out, n, moves, r, r1, term, tol, vmax, amax, vlimit_tool, amax_tool, cycle):
    """The arc of chords r..r1 as one circular segment (as LinuxCNC's tpAddCircle gets it), or, when no circle
    fits them, each chord as a line. Returns the new segment count."""
    n2, ok = _emit_arc(out, n, moves, r, r1, term, tol, moves[r].feed_v, vmax, amax, amax_tool, cycle)
    if ok:
        return n2
    for rr in range(r, r1 + 1):
        m2 = moves[rr]
        n = _emit_line(out, n, m2.x0, m2.y0, m2.z0, m2.x1, m2.y1, m2.z1, m2.line, rr, rr, term, tol,
                       m2.feed_v, 0, vmax, amax, vlimit_tool, amax_tool, cycle)
    return n


@njit(cache=True)
def _naive_cam_points(moves, r, r1, arc, q_tol, p_mid):
    """How many points a chainable row offers the naive-CAM chain (emccanon.cc see_segment): a line its end
    point (1); an XY arc within ``q_tol`` (mm) of its chord its middle point (written to ``p_mid``) and its end
    (2); another arc none (0)."""
    if not arc:
        return 1
    ok, dev, mx, my, mz = _naive_arc_points(moves, r, r1)
    if ok and dev < q_tol:
        p_mid[0], p_mid[1], p_mid[2] = mx, my, mz
        return 2
    return 0


@njit(cache=True)
def _queue_wait(out, n, mv, lead_dwell):
    """A dwell or wait row: the queue drains after the last segment queued (``sync_after``), a dwell adds its
    time (s) there, or before the first segment when none is queued yet. Returns that leading dwell (s)."""
    if n > 0:
        out[n - 1].sync_after = 1
        out[n - 1].dwell_after += mv.dwell_t if mv.kind == KIND_DWELL else 0.0
    elif mv.kind == KIND_DWELL:
        lead_dwell += mv.dwell_t
    return lead_dwell


@njit(cache=True)
def build_kernel(moves, vmax, amax, vlimit_tool, amax_tool, cycle, out):
    """MOVE rows → input TP segments in ``out``. Returns (n segments, dwell before the first segment).

    The naive-CAM chain follows emccanon.cc's see_segment/flush_segments: G1 end points (and the middle
    and end point of an XY arc that deviates less than Q from its chord) accumulate while every point stays
    within Q of the line from the chain's start to the newest point; the chain is sent as one line tagged
    with its last point's line number."""
    n = 0
    lead_dwell = 0.0
    nm = moves.shape[0]
    pts = np.empty((CHAIN_MAX + 2, 3))
    pt_line = np.empty(CHAIN_MAX + 2, dtype=np.int64)
    nc = 0
    bx = 0.0
    by = 0.0
    bz = 0.0
    ch_row0 = 0
    ch_row1 = -1
    ch_feed = 0.0
    ch_p = 0.0
    ch_q = 0.0
    last_row = -1                      # last MOVE row given to an emitted chain
    r = 0
    while r < nm:
        mv = moves[r]
        k = mv.kind
        is_wait = k == KIND_WAIT or k == KIND_DWELL
        is_motion = (not is_wait) and k != KIND_EXTRUDE_ONLY
        rapid = (mv.flags & FLAG_RAPID) != 0 or not (mv.feed_v < math.inf)
        arc = (mv.flags & FLAG_ARC) != 0
        term = _mode(mv)
        tol = mv.blend_p if mv.blend_p == mv.blend_p else 0.0
        q_tol = mv.blend_q if mv.blend_q == mv.blend_q else 0.0
        r1 = _arc_chords_end(moves, r) if arc else r
        # the points this row offers to the naive-CAM chain (none: it is not chainable)
        p_mid = np.empty(3)
        chainable = is_motion and not rapid and term == TERM_PARABOLIC and q_tol > 0.0
        npt = _naive_cam_points(moves, r, r1, arc, q_tol, p_mid) if chainable else 0
        # a chain cannot absorb a move with other settings, or one that does not start where it ends
        if nc > 0 and not (npt > 0 and mv.feed_v == ch_feed and tol == ch_p and q_tol == ch_q
                           and mv.x0 == pts[nc - 1, 0] and mv.y0 == pts[nc - 1, 1] and mv.z0 == pts[nc - 1, 2]):
            n = _flush_segments(out, n, bx, by, bz, pts, pt_line, nc, ch_row0, ch_row1, ch_p, ch_feed, vmax, amax,
                                vlimit_tool, amax_tool, cycle)
            last_row = max(last_row, ch_row1)
            bx, by, bz = pts[nc - 1, 0], pts[nc - 1, 1], pts[nc - 1, 2]
            nc = 0
        if npt > 0:
            for t in range(npt):
                if t == 0 and npt == 2:
                    px, py, pz = p_mid[0], p_mid[1], p_mid[2]
                    prow = r - 1 if r1 > r else r       # the middle point ends no whole row of its own
                else:
                    px, py, pz = moves[r1].x1, moves[r1].y1, moves[r1].z1
                    prow = r1
                if nc > 0 and not (nc <= CHAIN_MAX - 1 and _linkable(pts, nc, bx, by, bz, px, py, pz, q_tol)):
                    n = _flush_segments(out, n, bx, by, bz, pts, pt_line, nc, ch_row0, ch_row1, ch_p, ch_feed, vmax,
                                        amax, vlimit_tool, amax_tool, cycle)
                    last_row = max(last_row, ch_row1)
                    bx, by, bz = pts[nc - 1, 0], pts[nc - 1, 1], pts[nc - 1, 2]
                    nc = 0
                if nc == 0:
                    if t == 0:
                        bx, by, bz = mv.x0, mv.y0, mv.z0
                    ch_row0 = max(r, last_row + 1)
                    ch_row1 = ch_row0 - 1
                    ch_feed = mv.feed_v
                    ch_p = tol
                    ch_q = q_tol
                pts[nc, 0], pts[nc, 1], pts[nc, 2] = px, py, pz
                pt_line[nc] = mv.line
                nc += 1
                ch_row1 = max(ch_row1, prow)
            r = r1 + 1
            continue
        if is_wait:
            lead_dwell = _queue_wait(out, n, mv, lead_dwell)
            r += 1
            continue
        if not is_motion:
            r += 1
            continue
        if arc:
            n = _emit_arc_or_chords(out, n, moves, r, r1, term, tol, vmax, amax, vlimit_tool, amax_tool, cycle)
            r = r1 + 1
            continue
        if rapid:
            n = _emit_line(out, n, mv.x0, mv.y0, mv.z0, mv.x1, mv.y1, mv.z1, mv.line, r, r, term, tol, math.inf, 1,
                           vmax, amax, vlimit_tool, amax_tool, cycle)
            r += 1
            continue
        n = _emit_line(out, n, mv.x0, mv.y0, mv.z0, mv.x1, mv.y1, mv.z1, mv.line, r, r, term, tol, mv.feed_v, 0,
                       vmax, amax, vlimit_tool, amax_tool, cycle)
        r += 1
    if nc > 0:
        n = _flush_segments(out, n, bx, by, bz, pts, pt_line, nc, ch_row0, ch_row1, ch_p, ch_feed, vmax, amax,
                            vlimit_tool, amax_tool, cycle)
    return n, lead_dwell


# --------------------------------------------------------------------------- results
@njit(cache=True)
def _segment_times(exec_seg, n_cycles, n_q, cycle):
    """End time of each queue segment: the end of the last cycle it was the executing segment (LinuxCNC's
    per-line rule), made non-decreasing in queue order."""
    end = np.full(n_q, -1.0)
    for k in range(n_cycles):
        end[exec_seg[k]] = (k + 1) * cycle
    run = 0.0
    for j in range(n_q):
        if end[j] < run:
            end[j] = run
        run = end[j]
    return end


@njit(cache=True)
def _row_times(n_rows, q, n_q, seg_end, lead, move_d, t_start, dur, kind, dwell_t, cycle):
    """Spread each row-bearing segment's interval (from the previous row-bearing segment's end, so that a
    blend arc counts with the line after it) over its MOVE rows by length; other rows take 0 s."""
    covered = np.zeros(n_rows, dtype=np.bool_)
    prev_end = lead
    for j in range(n_q):
        sg = q[j]
        if sg.row0 < 0:
            continue
        t0 = prev_end
        t1 = seg_end[j]
        if sg.dwell_after > 0.0:      # the dwell's cycles at rest belong to the dwell row
            t1 -= np.ceil(sg.dwell_after / cycle - 1e-9) * cycle   # float: no int64 overflow
        tot = 0.0
        for r in range(sg.row0, sg.row1 + 1):
            tot += move_d[r]
        acc = 0.0
        for r in range(sg.row0, sg.row1 + 1):
            f0 = acc / tot if tot > 0.0 else 0.0
            acc += move_d[r]
            f1 = acc / tot if tot > 0.0 else 1.0
            t_start[r] = t0 + (t1 - t0) * f0
            dur[r] = (t1 - t0) * (f1 - f0)
            covered[r] = True
        prev_end = seg_end[j]
    clock = 0.0
    for r in range(n_rows):
        if covered[r]:
            clock = t_start[r] + dur[r]
        else:
            t_start[r] = clock
            dur[r] = 0.0
            if kind[r] == KIND_DWELL:
                dur[r] = np.ceil(dwell_t[r] / cycle - 1e-9) * cycle
                clock += dur[r]


@njit(cache=True)
def _pieces_kernel(pos, n_cycles, start_pos, cycle, exec_seg, seg_rows, t0_lead, count_only,
                   o_t0, o_dt, o_p, o_v, o_a, o_move, o_phase):
    """Constant-acceleration pieces through the cycle-end positions: a piece grows while the second
    difference of the positions stays the same (lines under constant acceleration or cruise)."""
    k = 0
    c = 0
    prev = np.empty(3)
    for a in range(3):
        prev[a] = start_pos[a]
    while c < n_cycles:
        # velocity over the first cycle and acceleration from the next one
        v0 = np.empty(3)
        acc = np.zeros(3)
        p_start = prev.copy()
        for a in range(3):
            v0[a] = (pos[c, a] - p_start[a]) / cycle
        end = c + 1
        if c + 1 < n_cycles:
            for a in range(3):
                d1 = pos[c, a] - p_start[a]
                d2 = pos[c + 1, a] - pos[c, a]
                acc[a] = (d2 - d1) / (cycle * cycle)
            # fit p(τ) = p_start + v τ + a τ²/2 through cycle ends: v = d1/dt − a·dt/2
            for a in range(3):
                v0[a] = (pos[c, a] - p_start[a]) / cycle - acc[a] * cycle / 2.0
            end = c + 2
            while end < n_cycles and exec_seg[end] == exec_seg[c]:
                tt = (end + 1 - c) * cycle
                ok = True
                for a in range(3):
                    pred = p_start[a] + v0[a] * tt + 0.5 * acc[a] * tt * tt
                    if abs(pred - pos[end, a]) > 1e-9:
                        ok = False
                        break
                if not ok:
                    break
                end += 1
        if not count_only:
            o_t0[k] = t0_lead + c * cycle
            o_dt[k] = (end - c) * cycle
            sp = 0.0
            sa = 0.0
            for a in range(3):
                o_p[k, a] = p_start[a]
                o_v[k, a] = v0[a]
                o_a[k, a] = acc[a]
                sp += v0[a] * v0[a]
                sa += v0[a] * acc[a]
            o_p[k, 3] = 0.0
            o_v[k, 3] = 0.0
            o_a[k, 3] = 0.0
            o_move[k] = seg_rows[exec_seg[c]]
            moving = sp > 1e-18 or sa != 0.0
            o_phase[k] = (PHASE_ACCEL if sa > 1e-12 else PHASE_DECEL if sa < -1e-12 else
                          PHASE_CRUISE if moving else PHASE_DWELL)
        k += 1
        for a in range(3):
            prev[a] = pos[end - 1, a]
        c = end
    return k


class LinuxcncRun:
    """One program planned as LinuxCNC runs it: the queue, the per-cycle trace, per-row times."""

    def __init__(self, moves, queue, n_cycles, exec_seg, pos, dist, cycle, lead, start_pos):
        self.moves = moves
        self.queue = queue                   # SEG_DTYPE rows as queued (blends included)
        self.n_cycles = n_cycles
        self.exec_seg = exec_seg             # per cycle: executing queue segment
        self.pos = pos                       # per cycle: commanded position at its end (mm)
        self.dist = dist                     # per cycle: path distance covered (mm)
        self.cycle = cycle                   # s
        self.lead = lead                     # s of dwell before the first motion
        self.start_pos = start_pos

    @property
    def total_time(self) -> float:
        """s, from the first cycle to the end of the last cycle in which the position changed."""
        moving = np.flatnonzero(self.dist[:self.n_cycles] > 0.0)
        last = int(moving[-1]) + 1 if moving.size else 0
        return self.lead + last * self.cycle

    def times(self) -> np.ndarray:
        """Cycle end times (s)."""
        return self.lead + (np.arange(self.n_cycles) + 1) * self.cycle

    def speed(self) -> np.ndarray:
        """Path speed over each cycle (mm/s), from the commanded-position difference (as the reference's ``v``)."""
        p = np.vstack([self.start_pos[None, :], self.pos[:self.n_cycles]])
        return np.sqrt((np.diff(p, axis=0) ** 2).sum(axis=1)) / self.cycle

    def line_end_times(self) -> dict[int, float]:
        """LinuxCNC's per-line end time: the end of the last cycle in which the line's segment executed."""
        lines = self.queue["line"]
        out: dict[int, float] = {}
        ex = self.exec_seg[:self.n_cycles]
        ends = self.lead + (np.arange(self.n_cycles) + 1) * self.cycle
        for ln, t in zip(lines[ex], ends):
            out[int(ln)] = float(t)
        return out


def _checked_limits(machine, limits):
    vmax, amax = _axis_limits(machine, limits)
    if not (np.all(vmax > 0) and np.all(amax > 0)):
        raise ConfigError("linuxcnc policy: every axis needs max_velocity and max_accel > 0")
    if not np.all(np.isfinite(amax)):
        raise ConfigError("linuxcnc policy: every axis needs a finite max_accel (LinuxCNC plans by axis limits)")
    vmax = np.where(np.isfinite(vmax), vmax, 1e300)
    return vmax, amax


def run_linuxcnc(moves: np.ndarray, limits: np.ndarray, machine) -> LinuxcncRun:
    """Plan and execute ``moves`` (whole program or a window that starts and ends at rest)."""
    moves = np.ascontiguousarray(moves)
    st = settings_of(machine)
    vmax, amax = _checked_limits(machine, limits)
    vlimit = float(machine.max_velocity) if np.isfinite(machine.max_velocity) else 1e300
    amax_tool = float(machine.max_accel) if np.isfinite(machine.max_accel) else 1e300
    bad = np.flatnonzero(~np.isfinite(moves["x1"]) | ~np.isfinite(moves["y1"]) | ~np.isfinite(moves["z1"]))
    if bad.size:
        raise GcodeError("a coordinate is not finite", line=int(moves["line"][bad[0]]))
    feeding = (moves["kind"] <= 1) & ((moves["flags"] & FLAG_RAPID) == 0)
    badf = np.flatnonzero(feeding & ~(moves["feed_v"] > 0))
    if badf.size:
        raise GcodeError("feed rate must be > 0 (F0 or no F given?)", line=int(moves["line"][badf[0]]))
    segs = np.zeros(max(len(moves), 1), dtype=SEG_DTYPE)
    n_in, lead = build_kernel(moves, vmax, amax, vlimit, amax_tool, st.cycle, segs)
    q = np.zeros(2 * n_in + 2, dtype=SEG_DTYPE)
    n_q = queue_kernel(segs, n_in, q, amax.astype(np.float64), vmax.astype(np.float64), vlimit, st.cycle,
                       st.kink_ratio, st.optimization_depth, st.gap_cycles, st.arc_blend_enable)
    q = q[:n_q].copy()
    start = q[0]["p0"].copy() if n_q else np.zeros(3)
    # a generous cycle budget: the time at a tenth of every segment's speed limit, plus dwells
    est = 0.0
    if n_q:
        v = np.maximum(np.minimum(q["reqvel"], q["maxvel"]), 1e-6)
        est = float(np.sum(q["target"] / v) * 4.0 + np.sum(q["dwell_after"]))
    budget = int(est / st.cycle) + 4 * n_q + 1000
    while True:
        exec_seg = np.zeros(budget, dtype=np.int64)
        pos = np.zeros((budget, 3))
        dist = np.zeros(budget)
        n_cycles = execute_kernel(q, n_q, vlimit, st.cycle, st.ramp_freq, budget, exec_seg, pos, dist)
        if n_cycles >= 0:
            break
        budget *= 2
    return LinuxcncRun(moves, q, n_cycles, exec_seg[:n_cycles], pos[:n_cycles], dist[:n_cycles], st.cycle,
                       lead, start)


def plan_rows(run: LinuxcncRun, t_clock: float = 0.0) -> np.ndarray:
    """PLAN rows for the run's MOVE rows (module docstring), times offset by ``t_clock``."""
    moves = run.moves
    n = len(moves)
    plan = np.zeros(n, dtype=PLAN_DTYPE)
    n_q = len(run.queue)
    seg_end = _segment_times(run.exec_seg, run.n_cycles, n_q, run.cycle) + run.lead if n_q else np.zeros(0)
    t_start = np.zeros(n)
    dur = np.zeros(n)
    move_d = np.sqrt((moves["x1"] - moves["x0"]) ** 2 + (moves["y1"] - moves["y0"]) ** 2
                     + (moves["z1"] - moves["z0"]) ** 2)
    _row_times(n, run.queue, n_q, seg_end, run.lead, move_d, t_start, dur, moves["kind"], moves["dwell_t"],
               run.cycle)
    plan["t_start"] = t_clock + t_start
    plan["duration"] = dur
    # speeds at the row boundaries from the trace
    times = run.times()
    speed = run.speed()
    if run.n_cycles:
        def v_at(t):
            k = np.clip(np.searchsorted(times, t - 1e-12), 0, run.n_cycles - 1)
            return speed[k]
        plan["start_v"] = np.where(dur > 0, v_at(t_start + 1e-9), 0.0)
        plan["end_v"] = np.where(dur > 0, v_at(t_start + dur - 1e-9), 0.0)
        # peak speed per row: max over the cycles of its interval
        k0 = np.searchsorted(times, t_start + 1e-12)
        k1 = np.searchsorted(times, t_start + dur - 1e-12, side="right")
        plan["cruise_v"] = _interval_max(speed, k0, k1, np.maximum(plan["start_v"], plan["end_v"]))
    is_motion = (moves["kind"] <= 1)
    # the phases and accelerations each row's interval saw in the trace (linuxcnc_phases.py)
    from .linuxcnc_phases import fill_phases

    fill_phases(plan, times, speed, run.cycle, run.lead, t_start, dur, is_motion)
    feed = moves["feed_v"]
    lim = np.where(plan["cruise_v"] >= 0.999 * np.minimum(feed, machine_vlimit(run)), LIMIT_FEED, LIMIT_ACCEL)
    plan["limit"] = np.where(is_motion & (dur > 0), lim, LIMIT_NONE)
    waits = (moves["kind"] == KIND_WAIT) | (moves["kind"] == KIND_DWELL)
    plan["limit"][waits] = LIMIT_NONE
    return plan


@njit(cache=True)
def _interval_max(speed, k0, k1, default):
    out = default.copy()
    for r in range(k0.shape[0]):
        for k in range(k0[r], min(k1[r], speed.shape[0])):
            if speed[k] > out[r]:
                out[r] = speed[k]
    return out


def machine_vlimit(run: LinuxcncRun) -> float:
    q = run.queue
    return float(np.max(q["reqvel"])) if len(q) else math.inf


def segment_rows(run: LinuxcncRun, first_move: int = 0, t_clock: float = 0.0) -> np.ndarray:
    """SEGMENT rows (constant-acceleration pieces through the cycle positions); SEGMENT.move is the first
    MOVE row of the executing segment (of the following line for a blend arc), offset by ``first_move``."""
    n_q = len(run.queue)
    if run.n_cycles == 0 or n_q == 0:
        return np.zeros(0, dtype=SEGMENT_DTYPE)
    rows = run.queue["row0"].copy()
    for j in range(n_q - 2, -1, -1):        # a blend arc's pieces belong to the row after it
        if rows[j] < 0:
            rows[j] = rows[j + 1]
    rows = np.where(rows < 0, 0, rows) + first_move
    args = (run.pos, run.n_cycles, run.start_pos.astype(np.float64), run.cycle, run.exec_seg, rows,
            t_clock + run.lead)
    z1 = np.zeros(1)
    z2 = np.zeros((1, 4))
    zi = np.zeros(1, dtype=np.int64)
    zu = np.zeros(1, dtype=np.uint8)
    m = _pieces_kernel(*args, True, z1, z1, z2, z2, z2, zi, zu)
    o_t0 = np.empty(m)
    o_dt = np.empty(m)
    o_p = np.empty((m, 4))
    o_v = np.empty((m, 4))
    o_a = np.empty((m, 4))
    o_move = np.empty(m, dtype=np.int64)
    o_phase = np.empty(m, dtype=np.uint8)
    _pieces_kernel(*args, False, o_t0, o_dt, o_p, o_v, o_a, o_move, o_phase)
    out = np.zeros(m, dtype=SEGMENT_DTYPE)
    out["t0"] = o_t0
    out["dt"] = o_dt
    for a, ax in enumerate("xyze"):
        out["p" + ax] = o_p[:, a]
        out["v" + ax] = o_v[:, a]
        out["a" + ax] = o_a[:, a]
    out["move"] = o_move
    out["phase"] = o_phase
    return out


def plan_linuxcnc(moves: np.ndarray, limits: np.ndarray, machine, first_move: int = 0, t_clock: float = 0.0):
    """(PLAN rows, SEGMENT rows) of ``moves`` planned as LinuxCNC 2.9 runs them (module docstring)."""
    run = run_linuxcnc(moves, limits, machine)
    return plan_rows(run, t_clock), segment_rows(run, first_move, t_clock)


# --------------------------------------------------------------------------- streaming
def window_end(moves: np.ndarray, final: bool) -> int:
    """Rows of a window LinuxCNC plans independently of what follows: up to the last queue drain (a wait or
    dwell row: M3/M5/M6/G43/G4...), everything at the end of the program."""
    if final:
        return len(moves)
    k = moves["kind"]
    sync = np.flatnonzero((k == KIND_WAIT) | (k == KIND_DWELL))
    return int(sync[-1]) + 1 if sync.size else 0


def make_stream_mode(base_cls):
    """The StreamPlanner mode for this policy (``base_cls``: planner.stream._Mode): windows from one queue
    drain to the next, each planned and run on its own (LinuxCNC's queue is empty there)."""

    class LinuxcncMode(base_cls):
        name = "linuxcnc"
        own_segments = True
        own_prepare = True

        def __init__(self, sp):
            super().__init__(sp)
            self.limits = None

        def prepare(self, moves_chunk, limits):
            from .prepare import PREP_DTYPE

            self.limits = np.asarray(limits)
            return np.zeros(len(moves_chunk), dtype=PREP_DTYPE)

        def plan(self, final: bool):
            sp = self.sp
            n_rows = window_end(sp.pending_moves, final)
            if n_rows == 0:
                return 0, None, sp.clock, None
            window = sp.pending_moves[:n_rows]
            run = run_linuxcnc(window, self.limits, sp.machine)
            plan = plan_rows(run, sp.clock)
            t_end = sp.clock + run.lead + run.n_cycles * run.cycle
            return n_rows, plan, t_end, (run, sp.clock)

        def segments(self, moves, plan, prep, ctx, first_index):
            run, clock = ctx
            return segment_rows(run, first_index, clock)

    return LinuxcncMode
