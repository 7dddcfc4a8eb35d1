"""Accelerating / cruising / decelerating shares of LinuxCNC PLAN rows, from the servo-cycle trace.

LinuxCNC's planner (planner/linuxcnc.py) gives each MOVE row a time interval, not a trapezoid: a row's
speed is what the trajectory planner's cycles make it, with blends and several ramps in one row. The
PLAN row still tells what happened in it, read off the trace:

* ``accel_t`` / ``decel_t``: the time in the row's interval during which the path speed rose / fell
  from one cycle to the next (a cycle's speed is its commanded-position difference over the cycle,
  as LinuxCNC's own ``v`` trace); ``cruise_t`` the rest, so that ``accel_t + cruise_t + decel_t`` is
  the row's duration (the durations, and so every total, are not touched);
* ``accel`` / ``decel``: the largest rise / fall of speed per second between two cycles of the row
  (mm/s²): what the row's acceleration reached.

Rows that are not motion (dwells, waits) have no phases, as in the other planners.
"""
from __future__ import annotations

import numpy as np

# a speed change slower than this (mm/s²) is cruising: the cycle speeds of a blend arc's chords or of a
# line's rounded positions wander by far less than any acceleration LinuxCNC plans
ACCEL_TOL = 1.0


def fill_phases(plan: np.ndarray, times: np.ndarray, speed: np.ndarray, cycle: float, lead: float,
                t_start: np.ndarray, dur: np.ndarray, motion: np.ndarray) -> None:
    """Set ``accel_t``, ``cruise_t``, ``decel_t``, ``accel``, ``decel`` of ``plan`` in place.

    ``times``/``speed``: cycle end times (s, from the window's start) and path speed per cycle (mm/s);
    ``cycle``: s; ``lead``: s before the first cycle; ``t_start``/``dur``: each row's interval on the
    same clock; ``motion``: rows that are feed or rapid moves."""
    n = len(plan)
    plan["accel_t"] = 0.0
    plan["cruise_t"] = 0.0
    plan["decel_t"] = 0.0
    plan["accel"] = 0.0
    plan["decel"] = 0.0
    m = len(speed)
    if n == 0:
        return
    if m == 0:
        plan["cruise_t"] = np.where(motion, dur, 0.0)
        return
    dv = np.diff(speed, prepend=0.0)                   # each cycle's speed change (rest before the first)
    up = dv > ACCEL_TOL * cycle
    down = dv < -ACCEL_TOL * cycle
    # cumulative rising / falling time at the cycle boundaries lead + k·cycle (k = 0..m): linear inside
    grid = np.r_[lead, times]
    cum_up = np.r_[0.0, np.cumsum(np.where(up, cycle, 0.0))]
    cum_down = np.r_[0.0, np.cumsum(np.where(down, cycle, 0.0))]
    t1 = t_start + dur
    acc_t = np.interp(t1, grid, cum_up) - np.interp(t_start, grid, cum_up)
    dec_t = np.interp(t1, grid, cum_down) - np.interp(t_start, grid, cum_down)
    acc_t = np.clip(acc_t, 0.0, dur)
    dec_t = np.clip(dec_t, 0.0, dur - acc_t)
    cru_t = np.maximum(dur - acc_t - dec_t, 0.0)
    plan["accel_t"] = np.where(motion, acc_t, 0.0)
    plan["decel_t"] = np.where(motion, dec_t, 0.0)
    plan["cruise_t"] = np.where(motion, cru_t, 0.0)
    # the largest rise / fall per second over the cycles that end inside each row
    k0 = np.searchsorted(times, t_start + 1e-12)
    k1 = np.searchsorted(times, t1 - 1e-12, side="right")
    rate_up = np.where(up, dv, 0.0) / cycle
    rate_down = np.where(down, -dv, 0.0) / cycle
    plan["accel"] = np.where(motion, _interval_max(rate_up, k0, k1), 0.0)
    plan["decel"] = np.where(motion, _interval_max(rate_down, k0, k1), 0.0)


def _interval_max(a: np.ndarray, k0: np.ndarray, k1: np.ndarray) -> np.ndarray:
    """max(a[k0[r]:k1[r]]) per row (0 for an empty range), vectorised with a running-max table."""
    out = np.zeros(len(k0))
    if a.size == 0:
        return out
    k1 = np.minimum(k1, a.size)
    ok = k1 > k0
    if not ok.any():
        return out
    # sparse table: level j holds max over [i, i + 2^j)
    levels = [a]
    span = 1
    while 2 * span <= a.size:
        prev = levels[-1]
        levels.append(np.maximum(prev[:-span], prev[span:]))
        span *= 2
    length = (k1 - k0)[ok]
    j = np.floor(np.log2(length)).astype(np.int64)
    lo = k0[ok]
    hi = k1[ok] - (1 << j)
    res = np.empty(lo.size)
    for level in np.unique(j):
        sel = j == level
        tab = levels[level]
        res[sel] = np.maximum(tab[lo[sel]], tab[hi[sel]])
    out[ok] = res
    return out
