"""S-curve mode: jerk-limited (seven-phase double-S) profiles per move under the machine's junction policy.

Model:

* Junction caps are the trapezoid planner's (``prepare`` with the machine's policy: Klipper, junction
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

PLAN rows: start_v, cruise_v (peak), end_v, accel = decel = the move's acceleration limit, jerk = J,
accel_t = t1 + t2 + t3, cruise_t = t4, decel_t = t5 + t6 + t7. SEGMENT rows: one cubic piece per phase of
non-zero duration (phases 1–3 PHASE_ACCEL, 4 PHASE_CRUISE, 5–7 PHASE_DECEL), PHASE_DWELL for dwell/wait rows.
"""
from __future__ import annotations

import math

import numba
import numpy as np

from ..errors import ConfigError
from ..profiles.scurve import (scurve_max_end_speed_kernel, scurve_max_start_speed_kernel,
                               scurve_phases_kernel)
from ..schema import (KIND_DWELL, KIND_WAIT, LIMIT_ACCEL, LIMIT_JUNCTION, LIMIT_NONE, PHASE_ACCEL,
                      PHASE_CRUISE, PHASE_DECEL, PHASE_DWELL, PLAN_DTYPE, SEGMENT_DTYPE)


@numba.njit(cache=True)
def scurve_speeds_kernel(move_d, max_cruise_v, accel, jerk, start_cap_v):
    """Junction speeds (n+1, mm/s) of n moves: start_cap_v[i] caps the start of move i (0 = full stop),
    the end of the last move is at rest. Backward pass with the jerk-limited braking reach, then the
    forward pass with the jerk-limited acceleration reach."""
    n = move_d.shape[0]
    v = np.zeros(n + 1)
    for i in range(n):
        v[i] = min(start_cap_v[i], max_cruise_v[i])
        if i > 0:
            v[i] = min(v[i], max_cruise_v[i - 1])
    v[n] = 0.0
    for i in range(n - 1, -1, -1):
        reach = scurve_max_start_speed_kernel(move_d[i], max_cruise_v[i], accel[i], jerk, v[i + 1])
        if reach < v[i]:
            v[i] = reach
    for i in range(n):
        reach = scurve_max_end_speed_kernel(move_d[i], max_cruise_v[i], accel[i], jerk, v[i])
        if reach < v[i + 1]:
            v[i + 1] = reach
    return v


@numba.njit(cache=True)
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


@numba.njit(cache=True)
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


def plan_scurve(moves: np.ndarray, limits: np.ndarray, machine, jerk: float, first_move: int = 0):
    """Plan ``moves`` with jerk-limited S-curves (``jerk`` mm/s³ along the path).

    Returns (PLAN rows aligned with ``moves``, SEGMENT rows with cubic pieces). Junction caps follow
    ``machine.junction_policy``; see the module docstring for the model.
    """
    from .prepare import prepare

    try:
        jerk = float(jerk)
    except (TypeError, ValueError):
        raise ConfigError(f"max_jerk: must be a number, got {jerk!r}") from None
    if not (jerk > 0.0 and math.isfinite(jerk)):
        raise ConfigError(f"max_jerk: must be finite and > 0 for S-curves, got {jerk!r}")
    moves = np.asarray(moves)
    limits = np.asarray(limits)
    n = len(moves)
    prep_all = prepare(moves, limits, machine, machine.junction_policy)
    kind = moves["kind"]
    still = (kind == KIND_DWELL) | (kind == KIND_WAIT)
    rows = np.flatnonzero(prep_all["is_move"] | still)
    prep = prep_all[rows]
    sub = moves[rows]
    m = len(rows)
    is_motion = np.ascontiguousarray(prep["is_move"])

    # the moves alone, in order; stops come from stop_before (set after dwell/wait rows and exact stops)
    mv = np.flatnonzero(is_motion)
    move_d = np.ascontiguousarray(prep["move_d"][mv], dtype=np.float64)
    max_cruise_v = np.sqrt(np.ascontiguousarray(prep["max_cruise_v2"][mv], dtype=np.float64))
    accel = np.ascontiguousarray(prep["accel"][mv], dtype=np.float64)
    start_cap_v = np.where(prep["stop_before"][mv], 0.0, np.sqrt(prep["max_start_v2"][mv]))
    speeds = scurve_speeds_kernel(move_d, max_cruise_v, accel, jerk, np.ascontiguousarray(start_cap_v))
    durations, peak_v = scurve_phases_all_kernel(move_d, max_cruise_v, accel, jerk, speeds)
    bad = np.flatnonzero(np.isnan(peak_v))
    if bad.size:  # the passes make every profile feasible; reaching here is a bug, not bad input
        i = int(mv[bad[0]])
        raise RuntimeError(f"S-curve planner: no profile for the move on line {int(sub['line'][i])} "
                           f"(d={move_d[bad[0]]!r}, v0={speeds[bad[0]]!r}, v1={speeds[bad[0] + 1]!r})")

    dur_rows = np.zeros((m, 7))
    dur_rows[mv] = durations
    start_v = np.zeros(m)
    end_v = np.zeros(m)
    cruise_v = np.zeros(m)
    start_v[mv], end_v[mv], cruise_v[mv] = speeds[:-1], speeds[1:], peak_v
    dwell_t = np.where(is_motion, 0.0, sub["dwell_t"]).astype(np.float64)
    duration_rows = dur_rows.sum(axis=1) + dwell_t

    plan = np.zeros(n, dtype=PLAN_DTYPE)
    duration = np.zeros(n)
    duration[rows] = duration_rows
    t_start = np.zeros(n)
    if n:
        np.cumsum(duration[:-1], out=t_start[1:])
    plan["t_start"] = t_start
    plan["duration"] = duration
    for name, col in (("start_v", start_v), ("cruise_v", cruise_v), ("end_v", end_v)):
        plan[name][rows] = col
    a_rows = np.zeros(m)
    a_rows[mv] = accel
    plan["accel"][rows] = a_rows
    plan["decel"][rows] = a_rows
    plan["jerk"][rows] = np.where(is_motion, jerk, 0.0)
    plan["accel_t"][rows] = dur_rows[:, 0:3].sum(axis=1)
    plan["cruise_t"][rows] = dur_rows[:, 3]
    plan["decel_t"][rows] = dur_rows[:, 4:7].sum(axis=1)
    limit = np.full(n, LIMIT_NONE, dtype=np.uint8)
    vmax_rows = np.sqrt(prep["max_cruise_v2"])
    reached = cruise_v >= vmax_rows * (1.0 - 1e-9)
    pinned = cruise_v <= np.maximum(start_v, end_v) * (1.0 + 1e-12)
    limit[rows] = np.where(~is_motion, LIMIT_NONE,
                           np.where(reached, prep["limit"], np.where(pinned, LIMIT_JUNCTION, LIMIT_ACCEL)))
    plan["limit"] = limit

    p0 = np.zeros((m, 4))
    axes_r = np.zeros((m, 4))
    for col, ax in enumerate("xyze"):
        p0[:, col] = sub[ax + "0"]
        axes_r[:, col] = prep["axes_r_" + ax]
    seg_rows, seg_move, seg_phase = scurve_segments_kernel(
        p0, axes_r, dur_rows, start_v, jerk, np.ascontiguousarray(t_start[rows]), is_motion,
        np.ascontiguousarray(dwell_t), np.ascontiguousarray(rows.astype(np.int64)), int(first_move))
    segs = np.zeros(len(seg_rows), dtype=SEGMENT_DTYPE)
    segs["t0"], segs["dt"] = seg_rows[:, 0], seg_rows[:, 1]
    for col, ax in enumerate("xyze"):
        segs["p" + ax] = seg_rows[:, 2 + col]
        segs["v" + ax] = seg_rows[:, 6 + col]
        segs["a" + ax] = seg_rows[:, 10 + col]
        segs["j" + ax] = seg_rows[:, 14 + col]
    segs["move"] = seg_move
    segs["phase"] = seg_phase
    return plan, segs
