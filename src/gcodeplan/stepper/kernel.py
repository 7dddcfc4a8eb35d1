"""Exact step times of one stepper from its polynomial pieces (numba kernels).

Step convention (Klipper's itersolve, stated in ../shared/reference/klipper-planner.md §8):

* The stepper's grid is anchored at the position last *set* (the first piece of
  the plan, a G28/SET_KINEMATIC_POSITION, or a jump between pieces). ``n`` counts
  the steps taken from the anchor, so the commanded position is
  ``anchor + n·step_dist``.
* A forward step is taken when the position reaches the half-step point above,
  ``anchor + (n + ½)·step_dist``; a backward step when it passes below
  ``anchor + (n − ½)·step_dist``. After a reversal the next step is therefore due
  at the half-step point on the other side (a hysteresis of one step). Between
  steps n = round(u) where u = (position − anchor)/step_dist, so the count of
  steps up to time t reproduces the position within half a step.
* Ties (a position that stops exactly on a half-step point) step forward and not
  back, which keeps the iteration finite. Klipper's solver settles such ties
  within its own floating-point slack; they do not occur with real coordinates
  (none in the reference files), so this choice is ours, not a measured match.

Root finding inside one piece ``s(τ) = p + v·τ + a·τ²/2 + j·τ³/6``:

* The piece is split at the roots of its velocity ``v + a·τ + j·τ²/2`` so that
  every sub-interval is monotone (direction reversals inside an S-curve phase or
  a blend are found there, not guessed).
* j = 0 (trapezoid phases, blends): the crossing of target s* solves
  a·τ²/2 + v·τ + C = 0 with C = p − s*. With σ the direction of travel the
  root is τ = −2C / (v + σ·√(v² − 2aC)): both terms of the denominator carry the
  sign σ, so nothing cancels (the numerically stable form of the quadratic
  formula, Numerical Recipes §5.6). The polynomial is re-based at the start of
  the sub-interval, where v has sign σ or is zero.
* j ≠ 0 (S-curve phases): Newton's method kept inside a bracket that shrinks
  with every evaluation, falling back to bisection when a Newton step leaves it.
"""
from __future__ import annotations

import math

import numba
import numpy as np

# A piece whose start differs from the previous piece's end by more than this
# (mm) means the position was set (G28 / SET_KINEMATIC_POSITION): re-anchor the grid.
JUMP_TOL_MM = 1e-6

# state vector layout for gen_steps (float64[STATE_LEN])
S_ANCHOR = 0      # mm, position the grid is anchored at
S_N = 1           # steps taken from the anchor (integer-valued)
S_LAST_POS = 2    # mm, position at the end of the last piece processed
S_ANCHORED = 3    # 1 once a first piece has anchored the grid
STATE_LEN = 4


def new_state() -> np.ndarray:
    """A fresh stepper state: the first piece will anchor the grid at its start."""
    return np.zeros(STATE_LEN, dtype=np.float64)


@numba.njit(cache=True, inline="always")
def _pos(p, v, a, j, tau):
    """s(τ) = p + v·τ + a·τ²/2 + j·τ³/6 (Horner form)."""
    return p + tau * (v + tau * (0.5 * a + tau * (j * (1.0 / 6.0))))


@numba.njit(cache=True, inline="always")
def _vel(v, a, j, tau):
    """ds/dτ = v + a·τ + j·τ²/2."""
    return v + tau * (a + 0.5 * j * tau)


@numba.njit(cache=True)
def velocity_roots(v, a, j, dt, roots):
    """Roots of v + a·τ + j·τ²/2 strictly inside (0, dt), sorted, written to ``roots``; returns their count.

    Quadratic case uses q = −(a + sign(a)·√(a² − 2jv))/2, roots q/(j/2) and v/q
    (Numerical Recipes §5.6), which keeps full precision for both roots.
    """
    count = 0
    if j == 0.0:
        if a != 0.0:
            r = -v / a
            if 0.0 < r < dt:
                roots[0] = r
                count = 1
        return count
    half_j = 0.5 * j
    disc = a * a - 4.0 * half_j * v
    if disc < 0.0:
        return 0
    sq = math.sqrt(disc)
    q = -0.5 * (a + (sq if a >= 0.0 else -sq))
    r1 = q / half_j
    r2 = v / q if q != 0.0 else r1
    if r2 < r1:
        r1, r2 = r2, r1
    if 0.0 < r1 < dt:
        roots[count] = r1
        count += 1
    if 0.0 < r2 < dt and r2 != r1:
        roots[count] = r2
        count += 1
    return count


@numba.njit(cache=True, inline="always")
def quadratic_crossing(p, v, a, target, sigma, span):
    """τ in [0, span] where p + v·τ + a·τ²/2 = target, travelling in direction sigma (±1).

    τ = −2C / (v + σ·√(v² − 2aC)), C = p − target (stable form, no cancellation).
    Requires v·σ ≥ 0 (the piece is re-based at the start of its monotone stretch).
    """
    c = p - target
    if a == 0.0:
        tau = -c / v
    else:
        disc = v * v - 2.0 * a * c
        if disc < 0.0:
            disc = 0.0
        den = v + sigma * math.sqrt(disc)
        tau = -2.0 * c / den if den != 0.0 else 0.0
    if tau < 0.0:
        tau = 0.0
    elif tau > span:
        tau = span
    return tau


@numba.njit(cache=True)
def cubic_crossing(p, v, a, j, target, lo, hi):
    """τ in [lo, hi] where s(τ) = target, s monotone on the bracket: bracketed Newton.

    The bracket always holds the sign change; a Newton step that leaves it, or
    a vanishing derivative, is replaced by bisection.
    """
    f_lo = _pos(p, v, a, j, lo) - target
    f_hi = _pos(p, v, a, j, hi) - target
    if f_lo == 0.0:
        return lo
    if f_hi == 0.0:
        return hi
    if (f_lo > 0.0) == (f_hi > 0.0):
        # rounding at the stretch's end: the crossing is at the nearer end
        return lo if abs(f_lo) < abs(f_hi) else hi
    rising = f_hi > 0.0
    # first guess: secant through the bracket ends
    tau = lo + (hi - lo) * (-f_lo) / (f_hi - f_lo)
    for _ in range(100):
        f = _pos(p, v, a, j, tau) - target
        if f == 0.0:
            return tau
        if (f > 0.0) == rising:
            hi = tau
        else:
            lo = tau
        d = _vel(v, a, j, tau)
        nxt = tau - f / d if d != 0.0 else 0.5 * (lo + hi)
        if not (lo < nxt < hi):
            nxt = 0.5 * (lo + hi)
        if abs(nxt - tau) <= 1e-15 * (1.0 + abs(tau)) or hi - lo <= 1e-15 * (1.0 + abs(tau)):
            return nxt
        tau = nxt
    return tau


@numba.njit(cache=True, inline="always")
def _forward_count(n, u_end):
    """Forward steps while u rises to u_end from commanded step n: thresholds n+½, n+1½, … ≤ u_end."""
    x = u_end - n - 0.5
    return int(math.floor(x)) + 1 if x >= 0.0 else 0


@numba.njit(cache=True, inline="always")
def _backward_count(n, u_end):
    """Backward steps while u falls to u_end from commanded step n: thresholds n−½, n−1½, … > u_end."""
    x = n - 0.5 - u_end
    return int(math.ceil(x)) if x > 0.0 else 0


@numba.njit(cache=True)
def gen_steps(t0, dt, pc, vc, ac, jc, reset, step_dist, state, start, out_t, out_dir, out_n):
    """Append the step times of pieces ``start..`` to ``out_t``/``out_dir`` from index ``out_n``.

    Pieces: s(τ) = pc + vc·τ + ac·τ²/2 + jc·τ³/6 for τ in [0, dt], absolute time
    t0 + τ. ``reset[i]`` ≠ 0 re-anchors the grid at piece i's start; so does a
    jump of more than JUMP_TOL_MM from the previous piece's end. ``state`` (see
    S_*) carries the grid between calls. A piece is emitted whole or not at all:
    when the output is full the call returns early.

    Returns (next piece index, new out_n, need): need is the step count of the
    piece that did not fit, 0 when all pieces were done, −1 when piece ``next``
    has a non-finite coefficient.
    """
    n_pieces = t0.shape[0]
    cap = out_t.shape[0]
    inv_d = 1.0 / step_dist
    anchor = state[S_ANCHOR]
    n = state[S_N]
    last_pos = state[S_LAST_POS]
    anchored = state[S_ANCHORED] != 0.0
    roots = np.empty(2, dtype=np.float64)
    bnd = np.empty(4, dtype=np.float64)
    cnt = np.empty(3, dtype=np.int64)
    sgn = np.empty(3, dtype=np.float64)
    i = start
    need = 0
    while i < n_pieces:
        p = pc[i]
        v = vc[i]
        a = ac[i]
        j = jc[i]
        span = dt[i]
        if (not anchored) or reset[i] != 0 or abs(p - last_pos) > JUMP_TOL_MM:
            anchor = p
            n = 0.0
            anchored = True
        if not (math.isfinite(p) and math.isfinite(v) and math.isfinite(a) and math.isfinite(j)
                and math.isfinite(span)):
            need = -1          # a broken plan: the caller reports it
            break
        if (v == 0.0 and a == 0.0 and j == 0.0) or not (span > 0.0):
            last_pos = _pos(p, v, a, j, span) if span > 0.0 else p
            i += 1
            continue
        # monotone stretches [bnd[k], bnd[k+1]]
        nr = velocity_roots(v, a, j, span, roots)
        bnd[0] = 0.0
        for k in range(nr):
            bnd[k + 1] = roots[k]
        bnd[nr + 1] = span
        n_str = nr + 1
        # pass 1: how many steps, per stretch (no root solving)
        nn = n
        total = 0
        u_prev = (p - anchor) * inv_d
        for k in range(n_str):
            u_end = (_pos(p, v, a, j, bnd[k + 1]) - anchor) * inv_d
            c = 0
            if u_end > u_prev:
                c = _forward_count(nn, u_end)
                nn += c
                sgn[k] = 1.0
            elif u_end < u_prev:
                c = _backward_count(nn, u_end)
                nn -= c
                sgn[k] = -1.0
            else:
                sgn[k] = 0.0
            cnt[k] = c
            total += c
            u_prev = u_end
        if out_n + total > cap:
            need = total
            break
        # pass 2: solve each crossing
        base_t = t0[i]
        for k in range(n_str):
            c = cnt[k]
            if c == 0:
                continue
            sigma = sgn[k]
            lo = bnd[k]
            hi = bnd[k + 1]
            dirv = np.int8(1) if sigma > 0.0 else np.int8(-1)
            if j == 0.0:
                # re-base at the stretch start, where the velocity has sign sigma (or is 0)
                p1 = _pos(p, v, a, 0.0, lo)
                v1 = v + a * lo
                if v1 * sigma < 0.0:
                    v1 = 0.0
                width = hi - lo
                for m in range(c):
                    target = anchor + (n + 0.5 * sigma) * step_dist
                    tau = quadratic_crossing(p1, v1, a, target, sigma, width)
                    out_t[out_n] = base_t + (lo + tau)
                    out_dir[out_n] = dirv
                    out_n += 1
                    n += sigma
            else:
                left = lo
                for m in range(c):
                    target = anchor + (n + 0.5 * sigma) * step_dist
                    tau = cubic_crossing(p, v, a, j, target, left, hi)
                    out_t[out_n] = base_t + tau
                    out_dir[out_n] = dirv
                    out_n += 1
                    n += sigma
                    left = tau
        last_pos = _pos(p, v, a, j, span)
        i += 1
    state[S_ANCHOR] = anchor
    state[S_N] = n
    state[S_LAST_POS] = last_pos
    state[S_ANCHORED] = 1.0 if anchored else 0.0
    return i, out_n, need


# ------------------------------------------------------------------ filters and statistics

# sds_filter state: [has pending step, pending time, pending dir]
SDS_STATE_LEN = 3


@numba.njit(cache=True)
def sds_filter(times, dirs, window_t, state, out_t, out_dir):
    """Klipper's step+dir+step filter, streaming.

    A step followed by an opposite-direction step less than ``window_t`` later is
    dropped together with it (Klipper stepcompress SDS_FILTER_TIME = 750 µs). One
    step is held back as pending between calls (``state``); flush it with
    :func:`sds_flush`. Returns the number of steps written to out_t/out_dir
    (which must hold len(times) + 1).
    """
    m = 0
    has = state[0] != 0.0
    pt = state[1]
    pd = np.int8(state[2])
    for k in range(times.shape[0]):
        t = times[k]
        d = dirs[k]
        if has:
            if d != pd and t - pt < window_t:
                has = False
                continue
            out_t[m] = pt
            out_dir[m] = pd
            m += 1
        pt = t
        pd = d
        has = True
    state[0] = 1.0 if has else 0.0
    state[1] = pt
    state[2] = pd
    return m


def sds_flush(state: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The step still pending in the filter (0 or 1 of them)."""
    if state[0] == 0.0:
        return np.empty(0, np.float64), np.empty(0, np.int8)
    state[0] = 0.0
    return np.array([state[1]], np.float64), np.array([int(state[2])], np.int8)


# step_stats state: [count, direction changes, last time, last dir, shortest interval,
#                    shortest same-direction interval, its time, net steps]
STATS_LEN = 8


def new_stats() -> np.ndarray:
    st = np.zeros(STATS_LEN, dtype=np.float64)
    st[4] = np.inf
    st[5] = np.inf
    st[6] = np.nan
    return st


@numba.njit(cache=True)
def step_stats(times, dirs, st):
    """Accumulate count, direction changes, shortest interval, shortest same-direction
    interval (→ peak step rate) and its time, and net steps over a chunk of steps."""
    count = st[0]
    changes = st[1]
    last_t = st[2]
    last_d = st[3]
    min_dt = st[4]
    min_same = st[5]
    min_same_t = st[6]
    net = st[7]
    for k in range(times.shape[0]):
        t = times[k]
        d = dirs[k]
        if count > 0:
            gap = t - last_t
            if gap < min_dt:
                min_dt = gap
            if d == last_d:
                if gap < min_same:
                    min_same = gap
                    min_same_t = t
            else:
                changes += 1
        count += 1
        net += d
        last_t = t
        last_d = d
    st[0] = count
    st[1] = changes
    st[2] = last_t
    st[3] = last_d
    st[4] = min_dt
    st[5] = min_same
    st[6] = min_same_t
    st[7] = net
