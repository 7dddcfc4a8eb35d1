"""PLAN rows → SEGMENT pieces: per-axis polynomials in time, up to three per move.

Along a trapezoid move the path distance is s(τ) = v0·τ + a·τ²/2 in each phase (accel: a > 0,
cruise: a = 0, decel: a < 0), and every axis follows q_i = q_i,start + r_i·s with r_i = d_i/move_d
(Klipper's trapq; E rides the same profile scaled by its ratio, an extrude-only move has r_e = ±1
and x/y/z still). Zero-duration phases are skipped; a dwell/wait row with dwell_t > 0 is one
PHASE_DWELL piece at rest.
"""
from __future__ import annotations

import math

from .._jit import njit
import numpy as np

from ..schema import KIND_DWELL, KIND_WAIT, PHASE_ACCEL, PHASE_CRUISE, PHASE_DECEL, PHASE_DWELL, SEGMENT_DTYPE

_MIN_MOVE_D = 1e-9  # Klipper: below this XYZ length the move is extrude-only


@njit(cache=True)
def _segments_kernel(kind, start, end, t_start, start_v, cruise_v, accel, decel, accel_t, cruise_t, decel_t,
                     duration, first_index, count_only, o_t0, o_dt, o_p, o_v, o_a, o_move, o_phase):
    n = kind.shape[0]
    k = 0
    r = np.zeros(4)
    for i in range(n):
        if kind[i] == KIND_DWELL or kind[i] == KIND_WAIT:
            if duration[i] > 0.0:
                if not count_only:
                    o_t0[k] = t_start[i]
                    o_dt[k] = duration[i]
                    for a in range(4):
                        o_p[k, a] = start[i, a]
                        o_v[k, a] = 0.0
                        o_a[k, a] = 0.0
                    o_move[k] = first_index + i
                    o_phase[k] = PHASE_DWELL
                k += 1
            continue
        if duration[i] <= 0.0:
            continue
        dx = end[i, 0] - start[i, 0]
        dy = end[i, 1] - start[i, 1]
        dz = end[i, 2] - start[i, 2]
        move_d = math.sqrt(dx * dx + dy * dy + dz * dz)
        if move_d >= _MIN_MOVE_D:
            for a in range(4):
                r[a] = (end[i, a] - start[i, a]) / move_d
        else:
            r[0] = 0.0
            r[1] = 0.0
            r[2] = 0.0
            r[3] = 1.0 if end[i, 3] >= start[i, 3] else -1.0
        # distance at the start of each phase
        s_cruise = (start_v[i] + 0.5 * accel[i] * accel_t[i]) * accel_t[i]
        s_decel = s_cruise + cruise_v[i] * cruise_t[i]
        t0s = (t_start[i], t_start[i] + accel_t[i], t_start[i] + accel_t[i] + cruise_t[i])
        dts = (accel_t[i], cruise_t[i], decel_t[i])
        s0s = (0.0, s_cruise, s_decel)
        v0s = (start_v[i], cruise_v[i], cruise_v[i])
        a0s = (accel[i], 0.0, -decel[i])
        phases = (PHASE_ACCEL, PHASE_CRUISE, PHASE_DECEL)
        for ph in range(3):
            if dts[ph] <= 0.0:
                continue
            if not count_only:
                o_t0[k] = t0s[ph]
                o_dt[k] = dts[ph]
                for a in range(4):
                    o_p[k, a] = start[i, a] + r[a] * s0s[ph]
                    o_v[k, a] = r[a] * v0s[ph]
                    o_a[k, a] = r[a] * a0s[ph]
                o_move[k] = first_index + i
                o_phase[k] = phases[ph]
            k += 1
    return k


def to_segments(moves: np.ndarray, plan: np.ndarray, first_index: int = 0) -> np.ndarray:
    """SEGMENT_DTYPE pieces of trapezoid plans; ``move`` = first_index + row."""
    moves = np.asarray(moves)
    plan = np.asarray(plan)
    if len(moves) != len(plan):
        raise ValueError(f"moves ({len(moves)}) and plan ({len(plan)}) rows differ")
    if len(plan) and np.any(plan["jerk"] != 0.0):
        raise NotImplementedError("to_segments handles trapezoid plans (jerk = 0); S-curve plans have their own")
    c = np.ascontiguousarray
    start = np.stack([moves["x0"], moves["y0"], moves["z0"], moves["e0"]], axis=1)
    end = np.stack([moves["x1"], moves["y1"], moves["z1"], moves["e1"]], axis=1)
    args = (c(moves["kind"]), start, end) + tuple(c(plan[f]) for f in (
        "t_start", "start_v", "cruise_v", "accel", "decel", "accel_t", "cruise_t", "decel_t", "duration"))
    z1, z2 = np.zeros(0), np.zeros((0, 4))
    count = _segments_kernel(*args, int(first_index), True, z1, z1, z2, z2, z2,
                             np.zeros(0, np.int64), np.zeros(0, np.uint8))
    t0, dt = np.empty(count), np.empty(count)
    p, v, a = np.empty((count, 4)), np.empty((count, 4)), np.empty((count, 4))
    move, phase = np.empty(count, np.int64), np.empty(count, np.uint8)
    _segments_kernel(*args, int(first_index), False, t0, dt, p, v, a, move, phase)
    segs = np.zeros(count, dtype=SEGMENT_DTYPE)
    segs["t0"], segs["dt"], segs["move"], segs["phase"] = t0, dt, move, phase
    for k, ax in enumerate("xyze"):
        segs["p" + ax] = p[:, k]
        segs["v" + ax] = v[:, k]
        segs["a" + ax] = a[:, k]
    return segs


def segments_from_table(seg_rows: np.ndarray, seg_move: np.ndarray, seg_phase: np.ndarray) -> np.ndarray:
    """SEGMENT rows from the (n, 18) float table the blend / S-curve kernels fill
    (t0, dt, then p, v, a, j for x, y, z, e; a table with 14 columns has no jerk)."""
    segs = np.zeros(len(seg_rows), dtype=SEGMENT_DTYPE)
    segs["t0"], segs["dt"] = seg_rows[:, 0], seg_rows[:, 1]
    with_jerk = seg_rows.shape[1] >= 18
    for col, ax in enumerate("xyze"):
        segs["p" + ax] = seg_rows[:, 2 + col]
        segs["v" + ax] = seg_rows[:, 6 + col]
        segs["a" + ax] = seg_rows[:, 10 + col]
        if with_jerk:
            segs["j" + ax] = seg_rows[:, 14 + col]
    segs["move"] = seg_move
    segs["phase"] = seg_phase
    return segs
