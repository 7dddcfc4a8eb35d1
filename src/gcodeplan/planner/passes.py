"""Look-ahead passes: junction caps (PREP) → start / cruise / end speeds → phase times → clock.

Two flush rules work on the *compact* move arrays (only rows with ``is_move``), over a window
``[lo, hi)`` that ends with a full stop (or, lazily, whose tail may still change):

* ``klipper_flush``: Klipper's LookAheadQueue.flush (docs/design.md §5), with the
  minimum_cruise_ratio "peak" smoothing and the lazy "2nd peak from the end" safe point;
* ``standard_flush``: the plain backward pass (the forward pass is already folded into
  ``max_start_v2``, see prepare.py), cruise at the trapezoid peak; lazy safe point = the last
  move whose start speed is pinned at its junction cap (it cannot rise whatever follows).

Both write speeds for the moves they emit and return the index after the last emitted move.
"""
from __future__ import annotations

import math

from .._jit import njit
import numpy as np

from ..schema import (KIND_DWELL, KIND_WAIT, LIMIT_ACCEL, LIMIT_JUNCTION, LIMIT_MCR, LIMIT_NONE,
                      PLAN_DTYPE)
from .prepare import POLICY_KLIPPER


@njit(cache=True)
def set_junction(start_v2: float, cruise_v2: float, end_v2: float, accel: float,
                 move_d: float) -> tuple[float, float, float]:
    """Phase times (accel_t, cruise_t, decel_t) of a trapezoid, Klipper's Move.set_junction.

    Distances from v² = v0² + 2·a·x: accel_d = (v_c² − v_s²)/(2a), decel_d = (v_c² − v_e²)/(2a),
    cruise_d = d − accel_d − decel_d; each time = distance / mean speed of the phase.
    """
    return trapezoid_phase_times(start_v2, cruise_v2, end_v2, math.sqrt(start_v2), math.sqrt(cruise_v2),
                                 math.sqrt(end_v2), accel, move_d)


@njit(cache=True)
def trapezoid_phase_times(start_v2: float, cruise_v2: float, end_v2: float, start_v: float, cruise_v: float,
                          end_v: float, accel: float, move_d: float) -> tuple[float, float, float]:
    """:func:`set_junction` (s) given the speeds (mm/s) as well as their squares: lay_out stores the speeds
    too, and three square roots per move are a quarter of its time."""
    half_inv_accel = 0.5 / accel
    # Klipper's formulas. Where a phase is absent its distance is rounding noise that can fall below 0 (a cruise
    # or decel time of −5e-19 s, found by tools/fuzz.py; a peak speed equal to the end speed computed as a
    # hair below it): clamped at 0, which moves a time by less than one ulp of any clock value
    accel_d = max((cruise_v2 - start_v2) * half_inv_accel, 0.0)
    decel_d = max((cruise_v2 - end_v2) * half_inv_accel, 0.0)
    cruise_d = max(move_d - accel_d - decel_d, 0.0)
    accel_t = accel_d / ((start_v + cruise_v) * 0.5)
    cruise_t = cruise_d / cruise_v
    decel_t = decel_d / ((end_v + cruise_v) * 0.5)
    return accel_t, cruise_t, decel_t


@njit(cache=True)
def klipper_flush(prep, rows, lo, hi, lazy, out_start_v2, out_cruise_v2, out_end_v2, out_limit):
    """Klipper LookAheadQueue.flush over the moves ``prep[rows[lo:hi]]``, stopping after the last.

    Backward pass with the full acceleration (start_v2) and with the mcr pseudo-acceleration
    (mcr_start); a move whose mcr start is below its mcr reach may accelerate, and a "peak" caps
    the cruise of the accelerating moves before it at (mcr_start + reach_mcr)/2. Moves that cannot
    accelerate inherit the previous cruise speed in the forward loop. ``lazy``: emit only up to the
    accelerating move before the 2nd peak from the end (nothing when there is none).
    Speeds go to out_*[k] for compact index k; returns the index after the last emitted move
    (lo = nothing emitted).
    """
    n = hi - lo
    info_start = np.empty(n)
    info_cruise = np.empty(n)   # < 0: cannot accelerate, inherit in the forward loop
    info_next = np.empty(n)
    info_limit = np.empty(n, dtype=np.uint8)
    flush_end = hi
    update_flush_count = lazy
    next_start_v2 = 0.0
    next_mcr_start_v2 = 0.0
    peak_cruise_v2 = 0.0
    pending = 0
    for i in range(hi - 1, lo - 1, -1):
        m = prep[rows[i]]
        reachable_v2 = next_start_v2 + m.delta_v2
        start_v2 = min(m.max_start_v2, reachable_v2)
        cruise_v2 = -1.0
        pending += 1
        reach_mcr_v2 = next_mcr_start_v2 + m.mcr_delta_v2
        mcr_start_v2 = min(m.max_mcr_start_v2, reach_mcr_v2)
        code = m.limit
        if mcr_start_v2 < reach_mcr_v2:
            if mcr_start_v2 + m.mcr_delta_v2 > next_mcr_start_v2 or pending > 1:
                if update_flush_count and peak_cruise_v2 != 0.0:
                    flush_end = i + pending
                    update_flush_count = False
                peak_cruise_v2 = (mcr_start_v2 + reach_mcr_v2) / 2
            half_v2 = (start_v2 + reachable_v2) / 2
            cruise_v2 = min(half_v2, m.max_cruise_v2, peak_cruise_v2)
            if cruise_v2 < m.max_cruise_v2:
                code = LIMIT_MCR if (peak_cruise_v2 < half_v2 and cruise_v2 == peak_cruise_v2) else LIMIT_ACCEL
            pending = 0
        k = i - lo
        info_start[k] = start_v2
        info_cruise[k] = cruise_v2
        info_next[k] = next_start_v2
        info_limit[k] = code
        next_start_v2 = start_v2
        next_mcr_start_v2 = mcr_start_v2
    if update_flush_count or flush_end == lo:
        return lo
    prev_cruise_v2 = 0.0
    for i in range(lo, flush_end):
        k = i - lo
        start_v2 = info_start[k]
        cruise_v2 = info_cruise[k]
        code = info_limit[k]
        if cruise_v2 < 0.0:
            cruise_v2 = min(prev_cruise_v2, start_v2)
            if cruise_v2 < prep[rows[i]].max_cruise_v2:
                code = LIMIT_JUNCTION
        out_start_v2[i] = min(start_v2, cruise_v2)
        out_cruise_v2[i] = cruise_v2
        out_end_v2[i] = min(info_next[k], cruise_v2)
        out_limit[i] = code
        prev_cruise_v2 = cruise_v2
    return flush_end


@njit(cache=True)
def standard_flush(prep, rows, lo, hi, lazy, out_start_v2, out_cruise_v2, out_end_v2, out_limit):
    """Plain look-ahead over the moves ``prep[rows[lo:hi]]``: backward pass
    start_v2[i] = min(max_start_v2[i], start_v2[i+1] + Δv²[i]), cruise at the trapezoid peak
    v_c² = min(V², (v_s² + v_e² + 2·a·d)/2) (docs/design.md §5, look-ahead flush).

    A full flush ends the last move at its stop speed (0, or the classic-jerk safe speed when
    reachable); a lazy one assumes 0 after the window (a lower bound of the truth) and emits the
    moves before the last one whose start is pinned at its cap: later moves cannot change them.
    """
    if lazy:
        next_start_v2 = 0.0
    else:
        last = prep[rows[hi - 1]]
        next_start_v2 = min(last.stop_v2, last.max_start_v2 + last.delta_v2)
    flush_end = hi
    found = not lazy
    for i in range(hi - 1, lo - 1, -1):
        m = prep[rows[i]]
        reachable_v2 = next_start_v2 + m.delta_v2
        start_v2 = min(m.max_start_v2, reachable_v2)
        half_v2 = (start_v2 + reachable_v2) / 2
        cruise_v2 = min(half_v2, m.max_cruise_v2)
        code = m.limit
        if cruise_v2 < m.max_cruise_v2:
            code = LIMIT_JUNCTION if cruise_v2 <= start_v2 else LIMIT_ACCEL
        out_start_v2[i] = start_v2
        out_cruise_v2[i] = cruise_v2
        out_end_v2[i] = next_start_v2
        out_limit[i] = code
        if not found and i > lo and start_v2 == m.max_start_v2:
            flush_end = i
            found = True
        next_start_v2 = start_v2
    if not found:
        return lo
    return flush_end


@njit(cache=True)
def plan_runs(policy, prep, rows, lo, hi, out_start_v2, out_cruise_v2, out_end_v2, out_limit):
    """Full flushes over the runs of moves rows[lo:hi] between full stops (``stop_before``);
    a run also starts at lo."""
    start = lo
    while start < hi:
        end = start + 1
        while end < hi and not prep[rows[end]].stop_before:
            end += 1
        if policy == POLICY_KLIPPER:
            klipper_flush(prep, rows, start, end, False, out_start_v2, out_cruise_v2, out_end_v2, out_limit)
        else:
            standard_flush(prep, rows, start, end, False, out_start_v2, out_cruise_v2, out_end_v2, out_limit)
        start = end


@njit(cache=True)
def lay_out(moves, prep, n_rows, start_v2, cruise_v2, end_v2, limit, t_clock, plan):
    """Phase times and the clock for rows [0, n_rows) of ``moves`` (MOVE rows): moves back to back from
    ``t_clock`` (Klipper adds the phase times one by one: t += accel_t; t += cruise_t; t += decel_t),
    dwell/wait rows add dwell_t, dropped rows take no time. Speeds come in compact order (k-th real move).
    Returns the final clock."""
    k = 0
    for i in range(n_rows):
        out = plan[i]
        out.t_start = t_clock
        out.jerk = 0.0
        m = prep[i]
        if m.is_move:
            start_v = math.sqrt(start_v2[k])
            cruise_v = math.sqrt(cruise_v2[k])
            end_v = math.sqrt(end_v2[k])
            a_t, c_t, d_t = trapezoid_phase_times(start_v2[k], cruise_v2[k], end_v2[k], start_v, cruise_v, end_v,
                                                  m.accel, m.move_d)
            out.start_v = start_v
            out.cruise_v = cruise_v
            out.end_v = end_v
            out.accel = m.accel
            out.decel = m.accel
            out.accel_t = a_t
            out.cruise_t = c_t
            out.decel_t = d_t
            out.duration = a_t + c_t + d_t
            out.limit = limit[k]
            t_clock = t_clock + a_t + c_t + d_t
            k += 1
        else:
            t_clock = t_clock + fill_idle_row(out, moves[i].kind, moves[i].dwell_t)
    return t_clock


@njit(cache=True)
def fill_idle_row(out, kind, dwell_t) -> float:
    """A PLAN row that is not a move (dwell, wait, or a dropped zero-length row): no motion; returns the
    time it takes (dwell_t for dwell/wait rows, else 0)."""
    out.start_v = 0.0
    out.cruise_v = 0.0
    out.end_v = 0.0
    out.accel = 0.0
    out.decel = 0.0
    out.jerk = 0.0
    out.accel_t = 0.0
    out.cruise_t = 0.0
    out.decel_t = 0.0
    out.limit = LIMIT_NONE
    if kind == KIND_DWELL or kind == KIND_WAIT:
        out.duration = dwell_t
        return dwell_t
    out.duration = 0.0
    return 0.0


# --------------------------------------------------------------------------- Python layer
def speed_buffers(m: int):
    """Compact start/cruise/end speed² and limit-code arrays for m moves."""
    return np.zeros(m), np.zeros(m), np.zeros(m), np.zeros(m, dtype=np.uint8)


def layout_rows(moves: np.ndarray, prep: np.ndarray, n_rows: int, start_v2, cruise_v2, end_v2, limit,
                t_clock: float) -> tuple[np.ndarray, float]:
    """PLAN rows for the first n_rows rows (speeds in compact order): (plan, clock at the end)."""
    plan = np.empty(n_rows, dtype=PLAN_DTYPE)
    t_end = lay_out(np.ascontiguousarray(moves[:n_rows]), prep, n_rows, start_v2, cruise_v2, end_v2, limit,
                    float(t_clock), plan)
    return plan, float(t_end)


def plan_from_prep(moves: np.ndarray, prep: np.ndarray, pcode: int, t_clock: float = 0.0) -> tuple[np.ndarray, float]:
    """Full flushes over prepared rows (trapezoid policies): (PLAN rows, clock at the end)."""
    rows = np.flatnonzero(prep["is_move"])
    bufs = speed_buffers(len(rows))
    plan_runs(pcode, prep, rows, 0, len(rows), *bufs)
    return layout_rows(moves, prep, len(moves), *bufs, t_clock)
