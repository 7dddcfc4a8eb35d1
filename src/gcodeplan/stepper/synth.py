"""Hand-built plans as SEGMENT rows: straight moves with trapezoid or S-curve profiles.

For tests and benchmarks of the step stage without the parser and the planner.
A move from ``start`` to ``end`` (x, y, z, e) follows one path profile s(t)
along the XYZ direction, E scaled by its share (Klipper's ``axes_r``), so every
axis is ``start_i + r_i·s(t)`` with r_i = Δ_i / move_d.
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ..schema import PHASE_ACCEL, PHASE_CRUISE, PHASE_DECEL, SEGMENT_DTYPE

AX = ("x", "y", "z", "e")


def trapezoid_times(move_d: float, start_v: float, cruise_v: float, end_v: float,
                    accel: float, decel: float | None = None) -> tuple[float, float, float]:
    """(accel_t, cruise_t, decel_t) of a trapezoid (Klipper ``set_junction``):
    accel_d = (v_c² − v_s²)/(2a), accel_t = accel_d/((v_s + v_c)/2), likewise for decel,
    cruise_t = (move_d − accel_d − decel_d)/v_c."""
    decel = accel if decel is None else decel
    accel_d = (cruise_v ** 2 - start_v ** 2) / (2.0 * accel)
    decel_d = (cruise_v ** 2 - end_v ** 2) / (2.0 * decel)
    cruise_d = move_d - accel_d - decel_d
    if cruise_d < -1e-9 * max(1.0, move_d):
        raise ValueError(f"trapezoid infeasible: {accel_d} + {decel_d} > {move_d} mm")
    cruise_d = max(cruise_d, 0.0)
    accel_t = accel_d / ((start_v + cruise_v) * 0.5) if accel_d > 0 else 0.0
    decel_t = decel_d / ((end_v + cruise_v) * 0.5) if decel_d > 0 else 0.0
    cruise_t = cruise_d / cruise_v if cruise_d > 0 else 0.0
    return accel_t, cruise_t, decel_t


def _axis_ratios(start, end):
    start = np.asarray(start, np.float64)
    end = np.asarray(end, np.float64)
    delta = end - start
    move_d = float(math.sqrt(float(np.dot(delta[:3], delta[:3]))))
    if move_d < 1e-9:            # extrude-only: the path is E itself (Klipper)
        move_d = abs(float(delta[3]))
        ratios = np.array([0.0, 0.0, 0.0, math.copysign(1.0, delta[3])])
    else:
        ratios = delta / move_d
    return start, move_d, ratios


def _piece(rows, k, t0, dt, start, ratios, s0, v0, a0, j0, move, phase):
    r = rows[k]
    r["t0"] = t0
    r["dt"] = dt
    for i, ax in enumerate(AX):
        r["p" + ax] = start[i] + ratios[i] * s0
        r["v" + ax] = ratios[i] * v0
        r["a" + ax] = ratios[i] * a0
        r["j" + ax] = ratios[i] * j0
    r["move"] = move
    r["phase"] = phase


def line_segments(start: Sequence[float], end: Sequence[float], start_v: float, cruise_v: float, end_v: float,
                  accel: float, *, decel: float | None = None, t_start: float = 0.0, move: int = 0) -> np.ndarray:
    """SEGMENT rows of one straight move with a trapezoid profile (phases of zero length left out)."""
    decel = accel if decel is None else decel
    start, move_d, ratios = _axis_ratios(start, end)
    accel_t, cruise_t, decel_t = trapezoid_times(move_d, start_v, cruise_v, end_v, accel, decel)
    rows = np.zeros(3, dtype=SEGMENT_DTYPE)
    k = 0
    t = t_start
    s = 0.0
    if accel_t > 0:
        _piece(rows, k, t, accel_t, start, ratios, s, start_v, accel, 0.0, move, PHASE_ACCEL)
        k += 1
        s += (start_v + cruise_v) * 0.5 * accel_t
        t += accel_t
    if cruise_t > 0:
        _piece(rows, k, t, cruise_t, start, ratios, s, cruise_v, 0.0, 0.0, move, PHASE_CRUISE)
        k += 1
        s += cruise_v * cruise_t
        t += cruise_t
    if decel_t > 0:
        _piece(rows, k, t, decel_t, start, ratios, s, cruise_v, -decel, 0.0, move, PHASE_DECEL)
        k += 1
    return rows[:k]


def rest_to_rest(move_d: float, max_v: float, accel: float) -> tuple[float, float]:
    """(cruise_v, accel_t) of a rest-to-rest trapezoid: triangle with peak √(a·h) when h < V²/a."""
    cruise_v = min(max_v, math.sqrt(accel * move_d))
    return cruise_v, cruise_v / accel


def polyline_segments(points: Sequence[Sequence[float]], max_v: float, accel: float, *,
                      junction_v: Sequence[float] | float = 0.0, t_start: float = 0.0) -> np.ndarray:
    """A path through ``points`` (x, y, z, e rows) with the given speed at each inner junction.

    Junction speeds are lowered where a move is too short to reach them (a simple
    forward/backward pass), so any input gives a feasible plan.
    """
    pts = np.asarray(points, np.float64)
    n = len(pts) - 1
    dists = np.array([_axis_ratios(pts[i], pts[i + 1])[1] for i in range(n)])
    jv = np.zeros(n + 1)
    jv[1:n] = junction_v if np.isscalar(junction_v) else np.asarray(junction_v, np.float64)
    jv = np.minimum(jv, max_v)
    for i in range(n):                      # forward: reachable from the previous junction
        jv[i + 1] = min(jv[i + 1], math.sqrt(jv[i] ** 2 + 2 * accel * dists[i]))
    for i in range(n - 1, -1, -1):          # backward: able to slow down for the next one
        jv[i] = min(jv[i], math.sqrt(jv[i + 1] ** 2 + 2 * accel * dists[i]))
    out = []
    t = t_start
    for i in range(n):
        peak = math.sqrt((2 * accel * dists[i] + jv[i] ** 2 + jv[i + 1] ** 2) / 2)
        cruise = max(min(max_v, peak), jv[i], jv[i + 1])
        rows = line_segments(pts[i], pts[i + 1], jv[i], cruise, jv[i + 1], accel, t_start=t, move=i)
        out.append(rows)
        if len(rows):
            t = rows["t0"][-1] + rows["dt"][-1]
    return np.concatenate(out) if out else np.zeros(0, SEGMENT_DTYPE)


def scurve_line_segments(start: Sequence[float], end: Sequence[float], max_v: float, accel: float, jerk: float,
                         *, t_start: float = 0.0, move: int = 0) -> np.ndarray:
    """Rest-to-rest jerk-limited (7-phase) straight move: +J, 0, −J, cruise, −J, 0, +J.

    A ramp to speed V takes T1 = A/J jerk time and T2 = V/A − A/J at constant
    acceleration when V ≥ A²/J, else peak acceleration √(V·J) and T2 = 0; its
    distance is V·(2·T1 + T2)/2. The cruise speed is lowered by bisection when
    the move is too short for two ramps.
    """
    start, move_d, ratios = _axis_ratios(start, end)

    def ramp(v):
        if v >= accel * accel / jerk:
            t1, t2, a_p = accel / jerk, v / accel - accel / jerk, accel
        else:
            a_p = math.sqrt(v * jerk)
            t1, t2 = a_p / jerk, 0.0
        return t1, t2, a_p, v * (2 * t1 + t2) / 2

    v = max_v
    if 2 * ramp(v)[3] > move_d:
        lo, hi = 0.0, max_v
        for _ in range(200):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if 2 * ramp(mid)[3] <= move_d else (lo, mid)
        v = lo
    t1, t2, a_p, ramp_d = ramp(v)
    cruise_t = max(move_d - 2 * ramp_d, 0.0) / v
    phases = [(t1, jerk, PHASE_ACCEL), (t2, 0.0, PHASE_ACCEL), (t1, -jerk, PHASE_ACCEL),
              (cruise_t, 0.0, PHASE_CRUISE),
              (t1, -jerk, PHASE_DECEL), (t2, 0.0, PHASE_DECEL), (t1, jerk, PHASE_DECEL)]
    rows = np.zeros(7, dtype=SEGMENT_DTYPE)
    k = 0
    t, s, sv, sa = t_start, 0.0, 0.0, 0.0
    for dur, j, ph in phases:
        if dur <= 0:
            continue
        _piece(rows, k, t, dur, start, ratios, s, sv, sa, j, move, ph)
        k += 1
        s += sv * dur + sa * dur ** 2 / 2 + j * dur ** 3 / 6
        sv += sa * dur + j * dur ** 2 / 2
        sa += j * dur
        t += dur
    return rows[:k]


def concat_plans(*plans: np.ndarray) -> np.ndarray:
    """Back-to-back plans: each starts when the previous one ends (times shifted)."""
    out = []
    t = 0.0
    for p in plans:
        q = p.copy()
        if len(q):
            q["t0"] += t - q["t0"][0]
            t = q["t0"][-1] + q["dt"][-1]
        out.append(q)
    return np.concatenate(out) if out else np.zeros(0, SEGMENT_DTYPE)
