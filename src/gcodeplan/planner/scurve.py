"""S-curve mode: jerk-limited (seven-phase double-S) profiles per move under a junction policy.

Model:

* Junction caps are the trapezoid planner's (``prepare`` with the policy asked for: Klipper, junction
  deviation, classic jerk, exact stop; 'blend' takes junction deviation's caps, as ``prepare`` does).
* Each move's path acceleration is 0 at both of its ends (modelling choice: a move is one double-S profile,
  +J, 0, −J, cruise, −J, 0, +J, from its start speed to its end speed). So acceleration is continuous across
  junctions (0 on both sides) and the jerk limit holds everywhere; the price is that a move cannot carry
  acceleration into the next one, which a path-level S-curve planner could.
* Reachable speeds come from the jerk-limited kernels (``profiles.scurve_max_end_speed_kernel`` forward,
  ``scurve_max_start_speed_kernel`` backward) instead of √(v² + 2·a·d). One backward pass then one forward pass
  give feasible speeds: the forward pass only lowers an end speed to what its start speed reaches (then the
  move accelerates, always feasible), and a lower start never makes the next move's braking harder.
* Every full stop (first move, after dwell/wait rows and exact-stop moves, the end) is at rest; Klipper's
  minimum_cruise_ratio smoothing is not applied (it is a trapezoid-planner rule).
* Streaming (:func:`scurve_window_speeds_kernel`): a move is final once the junction after it is certain to
  sit at its cap whatever follows. The backward reach of a jerk-limited move is not monotone in its end speed
  (a ramp with a = 0 at both ends covers less distance starting from rest than from a low speed), so "assume
  a stop after the window" is not a lower bound as it is for trapezoids; the kernel uses the least reach over
  every possible end speed instead (:func:`least_reach_start_v`).

PLAN rows: start_v, cruise_v (peak), end_v, accel = decel = the move's acceleration limit, jerk = J,
accel_t = t1 + t2 + t3, cruise_t = t4, decel_t = t5 + t6 + t7. SEGMENT rows: one cubic piece per phase of
non-zero duration (phases 1–3 PHASE_ACCEL, 4 PHASE_CRUISE, 5–7 PHASE_DECEL), PHASE_DWELL for dwell/wait rows.
"""
from __future__ import annotations

import math

from .._jit import njit
import numpy as np

from ..errors import ConfigError
from ..profiles.scurve import (ramp_distance_kernel, scurve_max_end_speed_kernel, scurve_max_start_speed_kernel,
                               scurve_phases_kernel)
from ..schema import (KIND_DWELL, KIND_WAIT, LIMIT_ACCEL, LIMIT_JUNCTION, PHASE_ACCEL,
                      PHASE_CRUISE, PHASE_DECEL, PHASE_DWELL, PLAN_DTYPE)
from .passes import fill_idle_row
from .segments import segments_from_table


@njit(cache=True)
def least_reach_start_v(move_d: float, accel: float, jerk: float) -> float:
    """mm/s, the end speed x* at which the backward reach R(x) of a move (the highest start speed that
    can brake to x over move_d) is least.

    A jerk-limited ramp with a = 0 at both ends is slow at low speed, so R is not monotone: from the
    move's end speed x the ramp covers (2x + Δv)/2 · T(Δv) = d. Differentiating: with c = A²/J,
    pure S (Δv < c, T = 2√(Δv/J)): dR/dx ∝ 2x − Δv, so the least R is at x = Δv/2, where
    d = 2Δv·√(Δv/J), Δv = (d·√J/2)^(2/3); with a constant-acceleration phase (Δv ≥ c):
    dR/dx ∝ 2x − c, least at x = c/2. R falls then rises (one minimum), so for any x ≥ x_lo,
    R(x) ≥ R(max(x_lo, x*)).
    """
    c = accel * accel / jerk
    dv_pure = (0.5 * move_d * math.sqrt(jerk)) ** (2.0 / 3.0)
    if dv_pure < c:
        return 0.5 * dv_pure
    return 0.5 * c


@njit(cache=True)
def longest_brake_end_v(v_max: float, accel: float, jerk: float) -> float:
    """mm/s, the end speed x in [0, V] whose ramp down from V is the longest in distance.

    The ramp from V down by Δv = V − x covers f(Δv) = (2V − Δv)/2 · T(Δv). With c = A²/J, f is concave
    (pure S: f = (2V − Δv)·√(Δv/J), f' ∝ 2V − 3Δv; with a constant-acceleration phase:
    f = (2V − Δv)/2 · (Δv/A + A/J), f' ∝ 2V − 2Δv − c; C¹ where they meet), so its maximum is at
    Δv = 2V/3 (x = V/3) when V < 1.5c, else at Δv = V − c/2 (x = c/2); over x ≥ x_lo it is at max(x_lo, x).
    """
    c = accel * accel / jerk
    if v_max < 1.5 * c:
        return v_max / 3.0
    return 0.5 * c


# Relative margin on a lower bound of the backward reach: covers the rounding of the reach kernel (its
# error is ~1e-15 relative) and of x* (R is flat at its minimum, so an error δ in x* moves R by ~δ²).
SETTLED_RTOL = 1e-9


@njit(cache=True)
def scurve_window_speeds_kernel(move_d, max_cruise_v, accel, jerk, start_cap_v, start_v, lazy):
    """Junction speeds of a window of n moves whose first start speed ``start_v`` is final.

    Returns (k, v): moves [0, k) are final, with junction speeds v[0..k] (v[k] final too). The caps are
    c[i] = min(start_cap_v[i], V[i], V[i−1]) (0 at a full stop); the backward pass is
    b[i] = min(c[i], R_i(b[i+1])) with R the jerk-limited braking reach, then the forward pass
    v[i+1] = min(b[i+1], F_i(v[i])) with F the acceleration reach. ``lazy`` = False: the window ends the
    program (b[n] = 0), k = n.

    ``lazy`` = True: what follows the window is unknown, so b is bounded from below for every possible
    continuation, from the end backwards: lo[n] = 0, lo[i] = min(c[i], R_i(max(lo[i+1], x*_i))·(1 − SETTLED_RTOL))
    (R is least at x*, :func:`least_reach_start_v`). Where that bound reaches the cap, b[i] = c[i] for certain
    (a full stop, c = 0, always does); the last such junction p starts the exact backward pass. The forward
    pass is then exact up to p, and beyond p as long as F_i(v[i]) ≤ lo[i+1] (then min(b[i+1], F_i) = F_i
    whatever follows: in long runs of short moves the speed is set by how fast it can build up, not by braking).
    k is where it stops; 0 when nothing is final yet.
    """
    n = move_d.shape[0]
    cap = np.empty(n + 1)
    cap[0] = start_v
    for i in range(1, n):
        cap[i] = min(start_cap_v[i], max_cruise_v[i])
        cap[i] = min(cap[i], max_cruise_v[i - 1])
    cap[n] = 0.0
    pin = n
    lo = np.zeros(n + 1)
    if lazy:
        pin = 0
        for i in range(n - 1, 0, -1):
            x = max(lo[i + 1], least_reach_start_v(move_d[i], accel[i], jerk))
            reach_lo = scurve_max_start_speed_kernel(move_d[i], max_cruise_v[i], accel[i], jerk, x)
            reach_lo *= 1.0 - SETTLED_RTOL
            if reach_lo >= cap[i]:
                pin = i
                break
            # the reach saturates at V exactly (cap = V in a cruise): test the braking distance instead
            x = min(max(lo[i + 1], longest_brake_end_v(max_cruise_v[i], accel[i], jerk)), max_cruise_v[i])
            if ramp_distance_kernel(x, max_cruise_v[i], accel[i], jerk) <= move_d[i] * (1.0 - SETTLED_RTOL):
                pin = i
                break
            lo[i] = min(cap[i], reach_lo)
    v = cap.copy()
    for i in range(pin - 1, 0, -1):
        reach = scurve_max_start_speed_kernel(move_d[i], max_cruise_v[i], accel[i], jerk, v[i + 1])
        if reach < v[i]:
            v[i] = reach
    k = 0
    for i in range(n):
        reach = scurve_max_end_speed_kernel(move_d[i], max_cruise_v[i], accel[i], jerk, v[i])
        if i + 1 <= pin:
            if reach < v[i + 1]:
                v[i + 1] = reach
        elif reach <= lo[i + 1]:
            v[i + 1] = reach
        else:
            break
        k = i + 1
    return k, v[:k + 1].copy()


@njit(cache=True)
def scurve_phases_all_kernel(move_d, max_cruise_v, accel, jerk, speeds):
    """(n, 7) phase durations and (n,) peak speeds; NaN rows where a profile does not exist."""
    n = move_d.shape[0]
    durations = np.zeros((n, 7))
    peak_v = np.zeros(n)
    for i in range(n):
        t, _, vp = scurve_phases_kernel(move_d[i], max_cruise_v[i], accel[i], jerk, speeds[i], speeds[i + 1])
        for k in range(7):
            durations[i, k] = t[k]
        peak_v[i] = vp
    return durations, peak_v


@njit(cache=True)
def scurve_segments_kernel(p0, axes_r, durations, start_v, jerk, t_start, is_motion, dwell_t, row_index,
                           first_move):
    """Cubic pieces (table t0, dt, p(4), v(4), a(4), j(4)) + move and phase columns.

    Along move i the path coordinate s(t) follows the phases (jerk +J, 0, −J, 0, −J, 0, +J) from s = 0,
    v = start_v, a = 0; each axis is p0 + axes_r·s (so its v, a, j are axes_r times the path's)."""
    n = p0.shape[0]
    count = 0
    for i in range(n):
        if is_motion[i]:
            for k in range(7):
                if durations[i, k] > 0.0:
                    count += 1
        elif dwell_t[i] > 0.0:
            count += 1
    rows = np.zeros((count, 18))
    moves_out = np.zeros(count, np.int64)
    phases_out = np.zeros(count, np.uint8)
    q = 0
    for i in range(n):
        t = t_start[i]
        if not is_motion[i]:
            if dwell_t[i] > 0.0:
                rows[q, 0] = t
                rows[q, 1] = dwell_t[i]
                for ax in range(4):
                    rows[q, 2 + ax] = p0[i, ax]
                moves_out[q] = first_move + row_index[i]
                phases_out[q] = PHASE_DWELL
                q += 1
            continue
        s = 0.0
        v = start_v[i]
        a = 0.0
        for k in range(7):
            dt = durations[i, k]
            if k == 0 or k == 6:
                j = jerk
            elif k == 2 or k == 4:
                j = -jerk
            else:
                j = 0.0
            if dt > 0.0:
                rows[q, 0] = t
                rows[q, 1] = dt
                for ax in range(4):
                    r = axes_r[i, ax]
                    rows[q, 2 + ax] = p0[i, ax] + r * s
                    rows[q, 6 + ax] = r * v
                    rows[q, 10 + ax] = r * a
                    rows[q, 14 + ax] = r * j
                moves_out[q] = first_move + row_index[i]
                phases_out[q] = PHASE_ACCEL if k < 3 else (PHASE_CRUISE if k == 3 else PHASE_DECEL)
                q += 1
            s += dt * (v + dt * (0.5 * a + dt * j / 6.0))
            v += dt * (a + 0.5 * dt * j)
            a += dt * j
            t += dt
    return rows, moves_out, phases_out


@njit(cache=True)
def scurve_layout_kernel(kind, dwell_t, prep, speeds, durations, peak_v, jerk, t_clock, plan):
    """PLAN rows for every row of ``prep`` (speeds and phase times in compact order: k-th real move), moves
    back to back from ``t_clock``; dwell/wait rows add dwell_t, dropped rows take no time. Returns the clock
    at the end. accel_t = t1 + t2 + t3, cruise_t = t4, decel_t = t5 + t6 + t7; duration adds t1..t7 in order.
    limit: the move's own cruise limit when its peak reaches it, else LIMIT_JUNCTION when the peak is one of
    its end speeds (it cannot speed up), else LIMIT_ACCEL."""
    k = 0
    for i in range(prep.shape[0]):
        out = plan[i]
        m = prep[i]
        out.t_start = t_clock
        if m.is_move:
            d = durations[k]
            start_v = speeds[k]
            end_v = speeds[k + 1]
            cruise_v = peak_v[k]
            out.start_v = start_v
            out.cruise_v = cruise_v
            out.end_v = end_v
            out.accel = m.accel
            out.decel = m.accel
            out.jerk = jerk
            out.accel_t = d[0] + d[1] + d[2]
            out.cruise_t = d[3]
            out.decel_t = d[4] + d[5] + d[6]
            duration = d[0] + d[1] + d[2] + d[3] + d[4] + d[5] + d[6]
            out.duration = duration
            if cruise_v >= math.sqrt(m.max_cruise_v2) * (1.0 - 1e-9):
                out.limit = m.limit
            elif cruise_v <= max(start_v, end_v) * (1.0 + 1e-12):
                out.limit = LIMIT_JUNCTION
            else:
                out.limit = LIMIT_ACCEL
            t_clock = t_clock + duration
            k += 1
        else:
            t_clock = t_clock + fill_idle_row(out, kind[i], dwell_t[i])
    return t_clock


def scurve_jerk(moves: np.ndarray, limits: np.ndarray, jerk: float | None) -> float | None:
    """The S-curve jerk asked for (argument, else the limits in force), or None for trapezoids."""
    if jerk is not None:
        if not (jerk > 0.0 and np.isfinite(jerk)):
            raise ConfigError(f"max_jerk: must be finite and > 0 for S-curves, got {jerk!r}")
        return float(jerk)
    if len(moves) == 0:
        return None
    all_mj = limits["max_jerk"]
    if not np.any(np.isfinite(all_mj) & (all_mj > 0.0)):  # the common case: no jerk limit anywhere
        return None
    used = np.unique(moves["limits"])
    used = used[(used >= 0) & (used < len(limits))]
    mj = limits["max_jerk"][used]
    on = np.isfinite(mj) & (mj > 0.0)
    return float(mj[on].min()) if np.any(on) else None


def check_jerk(jerk) -> float:
    """The S-curve jerk as a float; ConfigError unless finite and > 0."""
    try:
        jerk = float(jerk)
    except (TypeError, ValueError):
        raise ConfigError(f"max_jerk: must be a number, got {jerk!r}") from None
    if not (jerk > 0.0 and math.isfinite(jerk)):
        raise ConfigError(f"max_jerk: must be finite and > 0 for S-curves, got {jerk!r}")
    return jerk


def scurve_plan_window(moves: np.ndarray, prep: np.ndarray, jerk: float, start_v: float, t_clock: float,
                       lazy: bool):
    """Plan the final part of a window of rows (MOVE + their PREP rows) whose first move starts at the final
    speed ``start_v`` (mm/s) at time ``t_clock``.

    Returns (n_rows, plan, t_end, v_end, durations): the first n_rows rows are final (``lazy`` = False: all of
    them, the program ends at rest), their PLAN rows, the clock and the start speed of the next move after
    them, and the (k, 7) phase durations of their k moves (for :func:`scurve_segments`).
    """
    is_move = prep["is_move"]
    mv = np.flatnonzero(is_move)
    move_d = np.ascontiguousarray(prep["move_d"][mv], dtype=np.float64)
    max_cruise_v = np.sqrt(np.ascontiguousarray(prep["max_cruise_v2"][mv], dtype=np.float64))
    accel = np.ascontiguousarray(prep["accel"][mv], dtype=np.float64)
    start_cap_v = np.where(prep["stop_before"][mv], 0.0, np.sqrt(prep["max_start_v2"][mv]))
    k, speeds = scurve_window_speeds_kernel(move_d, max_cruise_v, accel, jerk, start_cap_v, float(start_v),
                                            bool(lazy))
    # every row before the first move still open (dwell / wait / dropped rows included)
    n_rows = len(moves) if k == len(mv) else int(mv[k])
    durations, peak_v = scurve_phases_all_kernel(move_d[:k], max_cruise_v[:k], accel[:k], jerk, speeds)
    bad = np.flatnonzero(np.isnan(peak_v))
    if bad.size:  # the passes make every profile feasible; reaching here is a bug, not bad input
        i = int(mv[bad[0]])
        raise RuntimeError(f"S-curve planner: no profile for the move on line {int(moves['line'][i])} "
                           f"(d={move_d[bad[0]]!r}, v0={speeds[bad[0]]!r}, v1={speeds[bad[0] + 1]!r})")
    plan = np.empty(n_rows, dtype=PLAN_DTYPE)
    t_end = scurve_layout_kernel(np.ascontiguousarray(moves["kind"][:n_rows]),
                                 np.ascontiguousarray(moves["dwell_t"][:n_rows], dtype=np.float64),
                                 prep[:n_rows], speeds, durations, peak_v, jerk, float(t_clock), plan)
    return n_rows, plan, float(t_end), float(speeds[k]), durations


def scurve_segments(moves: np.ndarray, prep: np.ndarray, plan: np.ndarray, durations: np.ndarray, jerk: float,
                    first_move: int = 0) -> np.ndarray:
    """SEGMENT rows (one cubic piece per phase of non-zero duration, PHASE_DWELL for dwell/wait rows) of rows
    planned by :func:`scurve_plan_window`; SEGMENT.move = first_move + row index."""
    kind = moves["kind"]
    still = (kind == KIND_DWELL) | (kind == KIND_WAIT)
    is_move = prep["is_move"]
    rows = np.flatnonzero(is_move | still)
    is_motion = np.ascontiguousarray(is_move[rows])
    dur_rows = np.zeros((len(rows), 7))
    dur_rows[is_motion] = durations
    sub = moves[rows]
    dwell_t = np.where(is_motion, 0.0, sub["dwell_t"]).astype(np.float64)
    p0 = np.zeros((len(rows), 4))
    axes_r = np.zeros((len(rows), 4))
    for col, ax in enumerate("xyze"):
        p0[:, col] = sub[ax + "0"]
        axes_r[:, col] = prep["axes_r_" + ax][rows]
    seg_rows, seg_move, seg_phase = scurve_segments_kernel(
        p0, axes_r, dur_rows, np.ascontiguousarray(plan["start_v"][rows]), float(jerk),
        np.ascontiguousarray(plan["t_start"][rows]), is_motion, np.ascontiguousarray(dwell_t),
        np.ascontiguousarray(rows.astype(np.int64)), int(first_move))
    return segments_from_table(seg_rows, seg_move, seg_phase)


def plan_scurve(moves: np.ndarray, limits: np.ndarray, machine, jerk: float, first_move: int = 0,
                policy: str | None = None):
    """Plan ``moves`` with jerk-limited S-curves (``jerk`` mm/s³ along the path).

    Returns (PLAN rows aligned with ``moves``, SEGMENT rows with cubic pieces). Junction caps follow
    ``policy`` (None = ``machine.junction_policy``); see the module docstring for the model. The streaming planner
    (:class:`gcodeplan.planner.stream.StreamPlanner`) gives the same rows bit for bit.
    """
    from .prepare import prepare

    jerk = check_jerk(jerk)
    moves = np.asarray(moves)
    limits = np.asarray(limits)
    prep = prepare(moves, limits, machine, policy or machine.junction_policy)
    n_rows, plan, _, _, durations = scurve_plan_window(moves, prep, jerk, 0.0, 0.0, lazy=False)
    assert n_rows == len(moves)
    return plan, scurve_segments(moves, prep, plan, durations, jerk, first_move)
