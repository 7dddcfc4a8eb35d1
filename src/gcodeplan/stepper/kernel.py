"""Exact step times of one stepper from its polynomial pieces (numba kernels).

Step convention (Klipper's itersolve, docs/design.md §9):

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

from .._jit import njit
import numpy as np

from ..profiles.core import piece_position, piece_velocity

# A piece whose start differs from the previous piece's end by more than this
# (mm) means the position was set (G28 / SET_KINEMATIC_POSITION): re-anchor the grid.
JUMP_TOL_MM = 1e-6

# reset flags per piece: 0 = re-anchor only on a jump, RESET_ANCHOR = re-anchor at the piece's start
# (G28 / SET_KINEMATIC_POSITION), RESET_CONTINUE = never re-anchor here: a jump (a shaper or smoothing
# change switching streams) is stepped through at the piece's start, as Klipper's itersolve does
RESET_ANCHOR = 1
RESET_CONTINUE = 2

# state vector layout for gen_steps (float64[STATE_LEN])
S_ANCHOR = 0      # mm, position the grid is anchored at
S_N = 1           # steps taken from the anchor (integer-valued)
S_LAST_POS = 2    # mm, position at the end of the last piece processed
S_ANCHORED = 3    # 1 once a first piece has anchored the grid
STATE_LEN = 4


def new_state() -> np.ndarray:
    """A fresh stepper state: the first piece will anchor the grid at its start."""
    return np.zeros(STATE_LEN, dtype=np.float64)


# the package's one piece evaluator (docs/design.md §9)
_pos = piece_position
_vel = piece_velocity


@njit(cache=True)
def velocity_roots(v, a, j, dt, roots):
    """Roots of v + a·τ + j·τ²/2 strictly inside (0, dt), sorted, written to ``roots``; returns their count.

    Quadratic case uses q = −(a + sign(a)·√(a² − 2jv))/2, roots q/(j/2) and v/q
    (Numerical Recipes §5.6), which keeps full precision for both roots.
    """
    return _velocity_roots_at(v, a, j, dt, roots, 0)


@njit(cache=True, inline="always")
def _velocity_roots_at(v, a, j, dt, roots, first):
    """:func:`velocity_roots` written to ``roots[first:]`` (the step engine's cut list, without a view)."""
    count = 0
    if j == 0.0:
        if a != 0.0:
            r = -v / a
            if 0.0 < r < dt:
                roots[first] = r
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
        roots[first + count] = r1
        count += 1
    if 0.0 < r2 < dt and r2 != r1:
        roots[first + count] = r2
        count += 1
    return count


@njit(cache=True, inline="always")
def _newton_in_bracket(tau, f, d, lo, hi, rising):
    """One step of a bracketed Newton search for the root of a function monotone on [lo, hi] (``rising``: it
    increases), with value ``f`` and slope ``d`` at ``tau``: the bracket shrinks to the root's side of tau, then
    the Newton step from tau — or the bracket's middle where that would leave it (or the slope is 0). Returns
    (lo, hi, next tau). The searches below share it (each keeps its own stopping rule)."""
    if (f > 0.0) == rising:
        hi = tau
    else:
        lo = tau
    nxt = tau - f / d if d != 0.0 else 0.5 * (lo + hi)
    if not (lo < nxt < hi):
        nxt = 0.5 * (lo + hi)
    return lo, hi, nxt


@njit(cache=True, inline="always")
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


@njit(cache=True)
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
        d = _vel(v, a, j, tau)
        lo, hi, nxt = _newton_in_bracket(tau, f, d, lo, hi, rising)
        if abs(nxt - tau) <= 1e-15 * (1.0 + abs(tau)) or hi - lo <= 1e-15 * (1.0 + abs(tau)):
            return nxt
        tau = nxt
    return tau


@njit(cache=True, inline="always")
def _forward_count(n, u_end):
    """Forward steps while u rises to u_end from commanded step n: thresholds n+½, n+1½, … ≤ u_end."""
    x = u_end - n - 0.5
    return int(math.floor(x)) + 1 if x >= 0.0 else 0


@njit(cache=True, inline="always")
def _backward_count(n, u_end):
    """Backward steps while u falls to u_end from commanded step n: thresholds n−½, n−1½, … > u_end."""
    x = n - 0.5 - u_end
    return int(math.ceil(x)) if x > 0.0 else 0


@njit(cache=True, inline="always")
def _stretch_steps(n, u_start, u_end, k, sgn, cnt):
    """Steps of monotone stretch ``k`` (u from u_start to u_end, in steps from commanded step n): their count
    into ``cnt[k]``, their direction (+1, -1, 0) into ``sgn[k]``. Returns (count, commanded step after)."""
    c = 0
    if u_end > u_start:
        c = _forward_count(n, u_end)
        n += c
        sgn[k] = 1.0
    elif u_end < u_start:
        c = _backward_count(n, u_end)
        n -= c
        sgn[k] = -1.0
    else:
        sgn[k] = 0.0
    cnt[k] = c
    return c, n


# ------------------------------------------------------------------ the step engine (one skeleton, any motor)
#
# Every exact kernel below runs :func:`step_pieces`: the grid (anchor, reset flags, hysteresis), the
# count-then-solve passes and the output-full protocol are written once; what depends on the kinematics is
# handed to it as five compiled functions, as a junction policy hands the planner its ``cap_v2``:
#
# * ``piece_at(data, i) -> (status, start_mm, piece)``: piece i's own coefficients (``piece``, any tuple the
#   other four read), the motor position at its start (mm) and a PIECE_* status;
# * ``position(piece, s) -> mm``: the motor position at τ = s (s);
# * ``turning_points(piece, span, bnd) -> count``: times in (0, span) that cut the piece into stretches on
#   which the motor is monotone, sorted, into bnd[1..count] (room for ``max_cuts``);
# * ``stretch(piece, lo, hi, sigma) -> ctx``: what the crossing search carries along the monotone stretch
#   [lo, hi] (s) travelled in direction sigma (±1), a tuple of floats;
# * ``crossing(piece, ctx, target, sigma, step_dist) -> (τ, ctx)``: the next τ (s) in the stretch where the
#   motor reaches ``target`` (mm), the crossings of one stretch asked for in order.
#
# The skeleton and its two passes are ``inline="always"``: numba copies them into each thin entry kernel
# (gen_steps, gen_steps_poly, gen_steps_delta) with the functions as module globals there, so each entry
# is compiled once for its kinematics, keeps numba's on-disk cache (no dispatcher in any cached signature)
# and keeps the hand-written kernels' speed. A skeleton compiled on its own and called with the functions as
# arguments would not: numba then refuses to cache the entry kernels ("uses dynamic globals").

# piece_at statuses: the values the entry kernels return as ``need`` when they stop at the piece
PIECE_MOVING = 0
PIECE_STILL = 1           # the motor does not move on this piece: no step, no root search
PIECE_BROKEN = -1         # a non-finite coefficient (a planner bug: the caller reports it)
PIECE_UNREACHABLE = -2    # the motor has no position there (e.g. beyond a delta arm's reach)


@njit(cache=True, inline="always")
def _count_piece_steps(position, piece, bnd, n_str, anchor, n, inv_d, u_start, sgn, cnt):
    """Pass 1 over one piece: the steps of each monotone stretch [bnd[k], bnd[k+1]] (into ``cnt``/``sgn``,
    see :func:`_stretch_steps`) from commanded step ``n``, u_start the piece's start in steps from ``anchor``
    (mm). Returns the piece's step count, or −1 when the motor has no position at a stretch end."""
    total = 0
    u_prev = u_start
    for k in range(n_str):
        end = position(piece, bnd[k + 1])
        if not math.isfinite(end):
            return -1
        u_end = (end - anchor) * inv_d
        c, n = _stretch_steps(n, u_prev, u_end, k, sgn, cnt)
        total += c
        u_prev = u_end
    return total


@njit(cache=True, inline="always")
def _solve_piece_steps(stretch, crossing, piece, bnd, n_str, sgn, cnt, anchor, n, step_dist, base_t,
                       out_t, out_dir, out_n):
    """Pass 2 over one piece: the time of every step counted by :func:`_count_piece_steps`, the crossing of
    its half-step point ``anchor + (n ± ½)·step_dist`` (mm), written to ``out_t`` (s, base_t + τ) and
    ``out_dir`` from ``out_n``. Returns (commanded step after the piece, new out_n)."""
    for k in range(n_str):
        c = cnt[k]
        if c == 0:
            continue
        sigma = sgn[k]
        dirv = np.int8(1) if sigma > 0.0 else np.int8(-1)
        ctx = stretch(piece, bnd[k], bnd[k + 1], sigma)
        for m in range(c):
            target = anchor + (n + 0.5 * sigma) * step_dist
            tau, ctx = crossing(piece, ctx, target, sigma, step_dist)
            out_t[out_n] = base_t + tau
            out_dir[out_n] = dirv
            out_n += 1
            n += sigma
    return n, out_n


@njit(cache=True, inline="always")
def step_pieces(piece_at, position, turning_points, stretch, crossing, data, max_cuts,
                t0, dt, reset, step_dist, state, start, out_t, out_dir, out_n):
    """The step engine: append the step times (s) of pieces ``start..`` of one motor to ``out_t``/``out_dir``
    from index ``out_n``, the motor given by the five functions described above this section over ``data``.

    Piece i lasts τ in [0, dt[i]] from absolute time t0[i] (s). ``reset[i]`` = RESET_ANCHOR re-anchors the
    grid at piece i's start; so does a jump of more than JUMP_TOL_MM from the previous piece's end, unless
    ``reset[i]`` = RESET_CONTINUE. ``state`` (see S_*) carries the grid between calls; ``step_dist`` is mm
    per step. A piece is emitted whole or not at all: when the output is full the call returns early.

    Returns (next piece index, new out_n, need): need is the step count of the piece that did not fit, 0
    when all pieces were done, −1 when piece ``next`` has a non-finite coefficient, −2 when the motor has no
    position on it.
    """
    n_pieces = t0.shape[0]
    cap = out_t.shape[0]
    inv_d = 1.0 / step_dist
    anchor = state[S_ANCHOR]
    n = state[S_N]
    last_pos = state[S_LAST_POS]
    anchored = state[S_ANCHORED] != 0.0
    bnd = np.empty(max_cuts + 2, dtype=np.float64)
    cnt = np.empty(max_cuts + 1, dtype=np.int64)
    sgn = np.empty(max_cuts + 1, dtype=np.float64)
    i = start
    need = 0
    while i < n_pieces:
        span = dt[i]
        status, p, piece = piece_at(data, i)
        if status == PIECE_BROKEN or not math.isfinite(span):
            need = PIECE_BROKEN          # a broken plan: the caller reports it
            break
        if status == PIECE_UNREACHABLE:
            need = PIECE_UNREACHABLE
            break
        if (not anchored) or reset[i] == RESET_ANCHOR or (reset[i] != RESET_CONTINUE
                                                          and abs(p - last_pos) > JUMP_TOL_MM):
            anchor = p
            n = 0.0
            anchored = True
        if status == PIECE_STILL or not (span > 0.0):
            last_pos = position(piece, span) if span > 0.0 else p
            i += 1
            continue
        n_cut = turning_points(piece, span, bnd)
        bnd[0] = 0.0
        bnd[n_cut + 1] = span
        n_str = n_cut + 1
        total = _count_piece_steps(position, piece, bnd, n_str, anchor, n, inv_d, (p - anchor) * inv_d,
                                   sgn, cnt)
        if total < 0:
            need = PIECE_UNREACHABLE
            break
        if out_n + total > cap:
            need = total
            break
        n, out_n = _solve_piece_steps(stretch, crossing, piece, bnd, n_str, sgn, cnt, anchor, n, step_dist,
                                      t0[i], out_t, out_dir, out_n)
        last_pos = position(piece, span)
        i += 1
    state[S_ANCHOR] = anchor
    state[S_N] = n
    state[S_LAST_POS] = last_pos
    state[S_ANCHORED] = 1.0 if anchored else 0.0
    return i, out_n, need


# ------------------------------------------------------------------ linear motors (cubic pieces, exact)

# cuts of a cubic piece: the roots of its quadratic velocity
LINEAR_MAX_CUTS = 2


@njit(cache=True, inline="always")
def _linear_piece(data, i):
    """:func:`step_pieces`'s ``piece_at`` for linear motors: data = (p, v, a, j) columns (mm, mm/s, mm/s²,
    mm/s³); the piece is (p, v, a, j) of row i."""
    pc, vc, ac, jc = data
    p = pc[i]
    v = vc[i]
    a = ac[i]
    j = jc[i]
    status = PIECE_MOVING
    if not (math.isfinite(p) and math.isfinite(v) and math.isfinite(a) and math.isfinite(j)):
        status = PIECE_BROKEN
    elif v == 0.0 and a == 0.0 and j == 0.0:
        status = PIECE_STILL
    return status, p, (p, v, a, j)


@njit(cache=True, inline="always")
def _linear_position(piece, s):
    """Position (mm) of the linear piece at τ = s."""
    p, v, a, j = piece
    return _pos(p, v, a, j, s)


@njit(cache=True, inline="always")
def _linear_turning_points(piece, span, bnd):
    """Where the linear piece reverses: the roots of its velocity in (0, span), into bnd[1..]."""
    p, v, a, j = piece
    return _velocity_roots_at(v, a, j, span, bnd, 1)


@njit(cache=True, inline="always")
def _linear_stretch(piece, lo, hi, sigma):
    """(lo, hi, last crossing, p, v re-based at lo, width) of a monotone stretch: with j = 0 the crossings
    solve the quadratic re-based at the stretch start, where the velocity has sign sigma (or is 0)."""
    p, v, a, j = piece
    p1 = 0.0
    v1 = 0.0
    if j == 0.0:
        p1 = _pos(p, v, a, 0.0, lo)
        v1 = v + a * lo
        if v1 * sigma < 0.0:
            v1 = 0.0
    return (lo, hi, lo, p1, v1, hi - lo)


@njit(cache=True, inline="always")
def _linear_crossing(piece, ctx, target, sigma, step_dist):
    """The next crossing of ``target`` (mm) by the linear piece: closed form for j = 0
    (:func:`quadratic_crossing`), bracketed Newton from the last crossing otherwise (:func:`cubic_crossing`)."""
    p, v, a, j = piece
    lo, hi, left, p1, v1, width = ctx
    if j == 0.0:
        tau = lo + quadratic_crossing(p1, v1, a, target, sigma, width)
    else:
        tau = cubic_crossing(p, v, a, j, target, left, hi)
    return tau, (lo, hi, tau, p1, v1, width)


@njit(cache=True)
def gen_steps(t0, dt, pc, vc, ac, jc, reset, step_dist, state, start, out_t, out_dir, out_n):
    """Append the step times of pieces ``start..`` to ``out_t``/``out_dir`` from index ``out_n``.

    Pieces: s(τ) = pc + vc·τ + ac·τ²/2 + jc·τ³/6 for τ in [0, dt], absolute time
    t0 + τ. ``reset[i]`` = RESET_ANCHOR re-anchors the grid at piece i's start; so
    does a jump of more than JUMP_TOL_MM from the previous piece's end, unless
    ``reset[i]`` = RESET_CONTINUE. ``state`` (see
    S_*) carries the grid between calls. A piece is emitted whole or not at all:
    when the output is full the call returns early.

    Returns (next piece index, new out_n, need): need is the step count of the
    piece that did not fit, 0 when all pieces were done, −1 when piece ``next``
    has a non-finite coefficient. (:func:`step_pieces` with the linear motor's functions.)
    """
    return step_pieces(_linear_piece, _linear_position, _linear_turning_points, _linear_stretch,
                       _linear_crossing, (pc, vc, ac, jc), LINEAR_MAX_CUTS,
                       t0, dt, reset, step_dist, state, start, out_t, out_dir, out_n)


# ------------------------------------------------------------------ filters and statistics

# sds_filter state: [has pending step, pending time, pending dir]
SDS_STATE_LEN = 3


@njit(cache=True)
def monotone_times(times, last_t):
    """Make step times non-decreasing in place, continuing from ``last_t`` (s); returns the new last time.

    A piece's last crossing is t0 + τ and the next piece's first is t0' + τ', with t0' = t0 + dt rounded: the
    two sums can come out one ulp in the wrong order at a piece boundary (found by tools/fuzz.py). Raising the
    later step to the earlier one's time moves it by that ulp and keeps every consumer's order (compression,
    deltas in compact files) true."""
    for i in range(times.shape[0]):
        if times[i] < last_t:
            times[i] = last_t
        last_t = times[i]
    return last_t


@njit(cache=True)
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


@njit(cache=True)
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


@njit(cache=True)
def monotone_stats(times, dirs, last_t, st):
    """:func:`monotone_times` then :func:`step_stats` in one pass over the chunk (the same results: each time is
    raised to ``last_t`` (s) before the statistics read it); returns the new last time (s). One pass instead of
    two keeps a chunk that no longer fits the cache from being read twice."""
    count = st[0]
    changes = st[1]
    prev_t = st[2]
    last_d = st[3]
    min_dt = st[4]
    min_same = st[5]
    min_same_t = st[6]
    net = st[7]
    for k in range(times.shape[0]):
        t = times[k]
        if t < last_t:
            t = last_t
            times[k] = t
        last_t = t
        d = dirs[k]
        if count > 0:
            gap = t - prev_t
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
        prev_t = t
        last_d = d
    st[0] = count
    st[1] = changes
    st[2] = prev_t
    st[3] = last_d
    st[4] = min_dt
    st[5] = min_same
    st[6] = min_same_t
    st[7] = net
    return last_t


# ------------------------------------------------------------------ degree-5 pieces (pressure advance)

POLY_NCOEF = 6


@njit(cache=True, inline="always")
def _horner(c, k, deg, s):
    """Σ c[k, i]·s^i for i ≤ deg."""
    out = c[k, deg]
    for i in range(deg - 1, -1, -1):
        out = out * s + c[k, i]
    return out


@njit(cache=True, inline="always")
def _weighted(arr, i, weights):
    """Σ weights[q]·arr[i, q] over the non-zero weights, a unit weight taken as is (Pieces.rail's sums exactly)."""
    acc = 0.0
    first = True
    for q in range(weights.shape[0]):
        w = weights[q]
        if w == 0.0:
            continue
        term = arr[i, q] if w == 1.0 else w * arr[i, q]
        if first:
            acc = term
            first = False
        else:
            acc = acc + term
    return acc


@njit(cache=True)
def linear_poly(p, v, a, j, weights, out):
    """Power-basis coefficients (``out``, (n, POLY_NCOEF), mm, mm/s, mm/s², mm/s³) of the linear motor
    Σ weights[q]·axis[q] over cubic pieces with (n, 4) x, y, z, e columns ``p v a j`` (mm, mm/s, mm/s², mm/s³):
    p, v, a/2, j/6, 0, 0, in one pass instead of the per-column sums and copies."""
    for i in range(p.shape[0]):
        out[i, 0] = _weighted(p, i, weights)
        out[i, 1] = _weighted(v, i, weights)
        out[i, 2] = 0.5 * _weighted(a, i, weights)
        out[i, 3] = _weighted(j, i, weights) * (1.0 / 6.0)
        out[i, 4] = 0.0
        out[i, 5] = 0.0


@njit(cache=True)
def _poly_root(c, k, deg, lo, hi, f_lo, f_hi):
    """The root of the monotone polynomial Σ c[k,i]·s^i (i ≤ deg) in [lo, hi], f changing sign: bracketed
    secant/bisection (Illinois-free: a bisection every other step keeps it linear-time safe)."""
    for it in range(200):
        if f_lo == f_hi:
            mid = 0.5 * (lo + hi)
        else:
            mid = lo + (hi - lo) * (-f_lo) / (f_hi - f_lo)
        if it % 2 == 1 or not (lo < mid < hi):
            mid = 0.5 * (lo + hi)
        f = _horner(c, k, deg, mid)
        if f == 0.0:
            return mid
        if (f > 0.0) == (f_hi > 0.0):
            hi = mid
            f_hi = f
        else:
            lo = mid
            f_lo = f
        if hi - lo <= 4e-16 * (1.0 + abs(hi)):
            break
    return lo if abs(f_lo) < abs(f_hi) else hi


@njit(cache=True)
def critical_points(c, k, span, deriv, out):
    """Roots in (0, span) of the derivative of piece k (degree ≤ 5), sorted, into ``out``; returns the count.

    Root isolation by the derivative chain: the roots of the (m+1)-th derivative split [0, span] into
    stretches where the m-th is monotone, so each stretch holds at most one root of it, found by
    bracketing. ``deriv`` (POLY_NCOEF × POLY_NCOEF scratch) gets the derivative coefficients.
    """
    # deriv[m, i]: coefficient i of the m-th derivative
    for i in range(POLY_NCOEF):
        deriv[0, i] = c[k, i]
    for m in range(1, POLY_NCOEF):
        for i in range(POLY_NCOEF - m):
            deriv[m, i] = deriv[m - 1, i + 1] * (i + 1)
        for i in range(POLY_NCOEF - m, POLY_NCOEF):
            deriv[m, i] = 0.0
    pts = np.empty(POLY_NCOEF + 1)
    nxt = np.empty(POLY_NCOEF + 1)
    n_pts = 0       # roots of the current derivative found so far (none for the constant 5th)
    for m in range(POLY_NCOEF - 2, 0, -1):
        deg = POLY_NCOEF - 1 - m
        # stretches: 0, pts..., span
        cnt = 0
        lo = 0.0
        f_lo = _horner(deriv, m, deg, lo)
        for q in range(n_pts + 1):
            hi = pts[q] if q < n_pts else span
            f_hi = _horner(deriv, m, deg, hi)
            if f_lo != 0.0 and f_hi != 0.0 and (f_lo > 0.0) != (f_hi > 0.0):
                nxt[cnt] = _poly_root(deriv, m, deg, lo, hi, f_lo, f_hi)
                cnt += 1
            elif f_hi == 0.0 and 0.0 < hi < span:
                nxt[cnt] = hi
                cnt += 1
            lo = hi
            f_lo = f_hi
        for q in range(cnt):
            pts[q] = nxt[q]
        n_pts = cnt
    for q in range(n_pts):
        out[q] = pts[q]
    return n_pts


@njit(cache=True, inline="always")
def _poly_piece(data, i):
    """:func:`step_pieces`'s ``piece_at`` for degree-5 pieces: data = (coef, deriv scratch); the piece is
    (coef, i, deriv scratch)."""
    coef, deriv = data
    p = coef[i, 0]
    finite = True
    moving = False
    for d in range(POLY_NCOEF):
        finite = finite and math.isfinite(coef[i, d])
        if d > 0 and coef[i, d] != 0.0:
            moving = True
    status = PIECE_MOVING
    if not finite:
        status = PIECE_BROKEN
    elif not moving:
        status = PIECE_STILL
    return status, p, (coef, i, deriv)


@njit(cache=True, inline="always")
def _poly_position(piece, s):
    """Position (mm) of the degree-5 piece at τ = s."""
    coef, i, deriv = piece
    return _horner(coef, i, POLY_NCOEF - 1, s)


@njit(cache=True, inline="always")
def _poly_turning_points(piece, span, bnd):
    """Where the degree-5 piece reverses: the roots of its derivative in (0, span) (:func:`critical_points`),
    into bnd[1..]."""
    coef, i, deriv = piece
    return critical_points(coef, i, span, deriv, bnd[1:])


@njit(cache=True, inline="always")
def _poly_stretch(piece, lo, hi, sigma):
    """(last crossing, stretch end) of a monotone stretch of a degree-5 piece."""
    return (lo, hi)


@njit(cache=True, inline="always")
def _poly_crossing(piece, ctx, target, sigma, step_dist):
    """The next crossing of ``target`` (mm) by the degree-5 piece: bracketed Newton (:func:`_poly_newton`)
    between the last crossing and the stretch end."""
    coef, i, deriv = piece
    left, hi = ctx
    deg = POLY_NCOEF - 1
    f_lo = _horner(coef, i, deg, left) - target
    f_hi = _horner(coef, i, deg, hi) - target
    if f_lo == 0.0:
        tau = left
    elif f_hi == 0.0 or (f_lo > 0.0) == (f_hi > 0.0):
        # rounding at the stretch's end: the crossing is at the nearer end
        tau = hi if abs(f_hi) <= abs(f_lo) else left
    else:
        tau = _poly_newton(coef, i, deg, target, left, hi, f_lo, f_hi)
    return tau, (tau, hi)


@njit(cache=True)
def gen_steps_poly(t0, dt, coef, reset, step_dist, state, start, out_t, out_dir, out_n):
    """:func:`gen_steps` for pieces of degree ≤ 5: s(τ) = Σ coef[i, d]·τ^d, τ in [0, dt[i]].

    Same grid, hysteresis, reset flags, state and buffer contract as :func:`gen_steps`. Each piece is
    split at the roots of its derivative (:func:`critical_points`) into monotone stretches; every
    half-step crossing in a stretch is bracketed and solved to full precision.
    """
    deriv = np.empty((POLY_NCOEF, POLY_NCOEF))
    return step_pieces(_poly_piece, _poly_position, _poly_turning_points, _poly_stretch, _poly_crossing,
                       (coef, deriv), POLY_NCOEF, t0, dt, reset, step_dist, state, start, out_t, out_dir, out_n)


@njit(cache=True)
def _poly_newton(c, k, deg, target, lo, hi, f_lo, f_hi):
    """τ in [lo, hi] where piece k equals ``target`` (monotone there, sign change given): bracketed Newton."""
    rising = f_hi > 0.0
    tau = lo + (hi - lo) * (-f_lo) / (f_hi - f_lo)
    for _ in range(100):
        f = _horner(c, k, deg, tau) - target
        if f == 0.0:
            return tau
        d = c[k, deg] * deg
        for q in range(deg - 1, 0, -1):
            d = d * tau + c[k, q] * q
        lo, hi, nxt = _newton_in_bracket(tau, f, d, lo, hi, rising)
        if abs(nxt - tau) <= 1e-15 * (1.0 + abs(tau)) or hi - lo <= 1e-15 * (1.0 + abs(tau)):
            return nxt
        tau = nxt
    return tau


# ------------------------------------------------------------------ delta towers (non-linear)

# coefficients of the polynomials the delta kernel builds: R(τ) = arm² − dx² − dy² has degree ≤ 6 for
# cubic pieces; h = 4·z'²·R − R'² degree ≤ 10
DELTA_NCOEF = 11
# s: a Newton step this small ends the delta crossing search (see _carriage_crossing)
NEWTON_DONE_S = 1e-10


@njit(cache=True, inline="always")
def _carriage(arm2, tx, ty, px, py, pz, vx, vy, vz, ax, ay, az, jx, jy, jz, s):
    """Carriage height (mm) at τ = s: z + √(arm² − (t_x − x)² − (t_y − y)²), Klipper's kin_delta.c."""
    x = px + s * (vx + s * (0.5 * ax + s * jx / 6.0))
    y = py + s * (vy + s * (0.5 * ay + s * jy / 6.0))
    z = pz + s * (vz + s * (0.5 * az + s * jz / 6.0))
    dx = tx - x
    dy = ty - y
    return math.sqrt(arm2 - dx * dx - dy * dy) + z


@njit(cache=True, inline="always")
def _carriage_and_velocity(arm2, tx, ty, px, py, pz, vx, vy, vz, ax, ay, az, jx, jy, jz, s):
    """(carriage height mm, its velocity mm/s) at τ = s, sharing the work of :func:`_carriage` and
    :func:`_carriage_velocity`."""
    x = px + s * (vx + s * (0.5 * ax + s * jx / 6.0))
    y = py + s * (vy + s * (0.5 * ay + s * jy / 6.0))
    z = pz + s * (vz + s * (0.5 * az + s * jz / 6.0))
    dx = tx - x
    dy = ty - y
    root = math.sqrt(arm2 - dx * dx - dy * dy)
    xd = vx + s * (ax + 0.5 * jx * s)
    yd = vy + s * (ay + 0.5 * jy * s)
    zd = vz + s * (az + 0.5 * jz * s)
    return root + z, zd + (dx * xd + dy * yd) / root


@njit(cache=True, inline="always")
def _carriage_velocity(arm2, tx, ty, px, py, vx, vy, vz, ax, ay, az, jx, jy, jz, s):
    """d(carriage height)/dτ (mm/s) at τ = s: z' + ((t_x − x)·x' + (t_y − y)·y') / √R."""
    x = px + s * (vx + s * (0.5 * ax + s * jx / 6.0))
    y = py + s * (vy + s * (0.5 * ay + s * jy / 6.0))
    dx = tx - x
    dy = ty - y
    xd = vx + s * (ax + 0.5 * jx * s)
    yd = vy + s * (ay + 0.5 * jy * s)
    zd = vz + s * (az + 0.5 * jz * s)
    return zd + (dx * xd + dy * yd) / math.sqrt(arm2 - dx * dx - dy * dy)


@njit(cache=True)
def _poly_mul(a, na, b, nb, out):
    """out = a·b (coefficients by power, degrees na and nb); returns the product's degree."""
    for k in range(na + nb + 1):
        out[k] = 0.0
    for i in range(na + 1):
        if a[i] == 0.0:
            continue
        for j in range(nb + 1):
            out[i + j] += a[i] * b[j]
    return na + nb


@njit(cache=True)
def _trim(c, deg):
    """The degree of c once its exactly-zero leading coefficients are dropped (0 for the zero polynomial)."""
    while deg > 0 and c[deg] == 0.0:
        deg -= 1
    return deg


@njit(cache=True)
def poly_roots_and_extrema(c, deg, span, table, roots, crit):
    """Roots in (0, span) of the polynomial Σ c[i]·τ^i (degree ``deg``) and of its derivative, sorted.

    Root isolation by the derivative chain (as :func:`critical_points`): the roots of the (m+1)-th
    derivative cut [0, span] into stretches on which the m-th derivative is monotone, so each holds at
    most one of its roots, found by bracketing. ``table`` is (DELTA_NCOEF, DELTA_NCOEF) scratch.
    Returns (number of roots, number of derivative roots), written to ``roots`` and ``crit``.
    """
    for i in range(deg + 1):
        table[0, i] = c[i]
    for m in range(1, deg + 1):
        for i in range(deg + 1 - m):
            table[m, i] = table[m - 1, i + 1] * (i + 1)
    pts = np.empty(DELTA_NCOEF)
    nxt = np.empty(DELTA_NCOEF)
    n_pts = 0            # roots of derivative m + 1 (none for the constant deg-th derivative)
    n_crit = 0
    for m in range(deg - 1, -1, -1):
        d = deg - m
        cnt = 0
        lo = 0.0
        f_lo = _horner(table, m, d, lo)
        for q in range(n_pts + 1):
            hi = pts[q] if q < n_pts else span
            f_hi = _horner(table, m, d, hi)
            if f_lo != 0.0 and f_hi != 0.0 and (f_lo > 0.0) != (f_hi > 0.0):
                nxt[cnt] = _poly_root(table, m, d, lo, hi, f_lo, f_hi)
                cnt += 1
            elif f_hi == 0.0 and 0.0 < hi < span:
                nxt[cnt] = hi
                cnt += 1
            lo = hi
            f_lo = f_hi
        if m == 1:
            for q in range(cnt):
                crit[q] = nxt[q]
            n_crit = cnt
        for q in range(cnt):
            pts[q] = nxt[q]
        n_pts = cnt
    if deg < 1:
        n_pts = 0
    for q in range(n_pts):
        roots[q] = pts[q]
    return n_pts, n_crit


@njit(cache=True)
def delta_turning_points(arm2, tx, ty, px, py, vx, vy, vz, ax, ay, az, jx, jy, jz, span, out):
    """Times τ in (0, span) that cut a piece into stretches on which the carriage height is monotone,
    sorted, into ``out`` (room for 2·DELTA_NCOEF); returns their count.

    With R(τ) = arm² − (x − t_x)² − (y − t_y)² (a polynomial, degree ≤ 6) the carriage velocity is
    z' + R'/(2√R), of the sign of g = z'·√R + R'/2. Without Z motion its sign changes are the roots of R'.
    With Z motion every root of g is a root of h = 4·z'²·R − R'² = 4·g·(z'·√R − R'/2), a polynomial of
    degree ≤ 10: the roots of h and of h' (where h may touch zero) are the cuts. Extra cuts (roots of the
    other factor) only split a monotone stretch in two.
    """
    dx = np.empty(4)
    dy = np.empty(4)
    dx[0] = px - tx
    dx[1] = vx
    dx[2] = 0.5 * ax
    dx[3] = jx / 6.0
    dy[0] = py - ty
    dy[1] = vy
    dy[2] = 0.5 * ay
    dy[3] = jy / 6.0
    ndx = _trim(dx, 3)
    ndy = _trim(dy, 3)
    sq = np.empty(DELTA_NCOEF)
    rr = np.zeros(DELTA_NCOEF)
    n1 = _poly_mul(dx, ndx, dx, ndx, sq)
    for i in range(n1 + 1):
        rr[i] -= sq[i]
    n2 = _poly_mul(dy, ndy, dy, ndy, sq)
    for i in range(n2 + 1):
        rr[i] -= sq[i]
    rr[0] += arm2
    nr = _trim(rr, max(n1, n2))
    table = np.empty((DELTA_NCOEF, DELTA_NCOEF))
    roots = np.empty(DELTA_NCOEF)
    crit = np.empty(DELTA_NCOEF)
    if vz == 0.0 and az == 0.0 and jz == 0.0:
        if nr < 2:
            return 0
        _, nc = poly_roots_and_extrema(rr, nr, span, table, roots, crit)
        for q in range(nc):
            out[q] = crit[q]
        return nc
    # h = 4·z'²·R − R'²
    zd = np.empty(3)
    zd[0] = vz
    zd[1] = az
    zd[2] = 0.5 * jz
    nzd = _trim(zd, 2)
    zd2 = np.empty(5)
    nzd2 = _poly_mul(zd, nzd, zd, nzd, zd2)
    rd = np.zeros(DELTA_NCOEF)
    nrd = max(nr - 1, 0)
    for i in range(nrd + 1):
        rd[i] = rr[i + 1] * (i + 1) if i + 1 <= nr else 0.0
    h = np.zeros(DELTA_NCOEF)
    tmp = np.empty(DELTA_NCOEF)
    na = _poly_mul(zd2, nzd2, rr, nr, tmp)
    for i in range(na + 1):
        h[i] += 4.0 * tmp[i]
    nb = _poly_mul(rd, nrd, rd, nrd, tmp)
    for i in range(nb + 1):
        h[i] -= tmp[i]
    nh = _trim(h, max(na, nb))
    if nh < 1:
        return 0
    n0, nc = poly_roots_and_extrema(h, nh, span, table, roots, crit)
    # merge the two sorted lists
    i = 0
    j = 0
    m = 0
    while i < n0 or j < nc:
        if j >= nc or (i < n0 and roots[i] <= crit[j]):
            out[m] = roots[i]
            i += 1
        else:
            out[m] = crit[j]
            j += 1
        m += 1
    return m


@njit(cache=True, inline="always")
def _carriage_crossing(arm2, tx, ty, px, py, pz, vx, vy, vz, ax, ay, az, jx, jy, jz, target, lo, hi, f_lo,
                       f_hi, guess):
    """(τ, carriage velocity there) with τ in [lo, hi] where the carriage height equals ``target``: bracketed
    Newton from ``guess`` (inside the bracket, else the secant of the bracket). The height is monotone on
    the bracket; ``f_lo``/``f_hi`` are height − target at its ends, of opposite signs.

    Newton's error after a step of size δ is about (c''/2c')·δ², so a step below NEWTON_DONE_S leaves
    under 1e-12 s wherever |c''/c'| < 1e8 /s: the result is returned then (one step from a good guess)."""
    rising = f_hi > 0.0
    tau = guess
    if not (lo < tau < hi):
        tau = lo + (hi - lo) * (-f_lo) / (f_hi - f_lo)
    d = 0.0
    for _ in range(100):
        c, d = _carriage_and_velocity(arm2, tx, ty, px, py, pz, vx, vy, vz, ax, ay, az, jx, jy, jz, tau)
        f = c - target
        if f == 0.0:
            return tau, d
        lo, hi, nxt = _newton_in_bracket(tau, f, d, lo, hi, rising)
        if abs(nxt - tau) <= NEWTON_DONE_S or hi - lo <= 1e-15 * (1.0 + abs(tau)):
            return nxt, d
        tau = nxt
    return tau, d


@njit(cache=True, inline="always")
def _delta_piece(data, i):
    """:func:`step_pieces`'s ``piece_at`` for a delta tower: data = (p, v, a, j, arm2, tx, ty), (n, ≥3) x, y,
    z columns (mm, mm/s, mm/s², mm/s³) and the tower (mm², mm, mm); the piece is (arm2, tx, ty, px, py, pz,
    vx, vy, vz, ax, ay, az, jx, jy, jz), the arguments of :func:`_carriage` but τ."""
    pc, vc, ac, jc, arm2, tx, ty = data
    px = pc[i, 0]
    py = pc[i, 1]
    pz = pc[i, 2]
    vx = vc[i, 0]
    vy = vc[i, 1]
    vz = vc[i, 2]
    ax = ac[i, 0]
    ay = ac[i, 1]
    az = ac[i, 2]
    jx = jc[i, 0]
    jy = jc[i, 1]
    jz = jc[i, 2]
    piece = (arm2, tx, ty, px, py, pz, vx, vy, vz, ax, ay, az, jx, jy, jz)
    if not (math.isfinite(px) and math.isfinite(py) and math.isfinite(pz) and math.isfinite(vx)
            and math.isfinite(vy) and math.isfinite(vz) and math.isfinite(ax) and math.isfinite(ay)
            and math.isfinite(az) and math.isfinite(jx) and math.isfinite(jy) and math.isfinite(jz)):
        return PIECE_BROKEN, px, piece
    p = _carriage(arm2, tx, ty, px, py, pz, vx, vy, vz, ax, ay, az, jx, jy, jz, 0.0)
    status = PIECE_MOVING
    if not math.isfinite(p):
        status = PIECE_UNREACHABLE
    elif (vx == 0.0 and vy == 0.0 and vz == 0.0 and ax == 0.0 and ay == 0.0 and az == 0.0 and jx == 0.0
          and jy == 0.0 and jz == 0.0):
        status = PIECE_STILL
    return status, p, piece


@njit(cache=True, inline="always")
def _delta_position(piece, s):
    """Carriage height (mm) of the delta piece at τ = s (:func:`_carriage`)."""
    arm2, tx, ty, px, py, pz, vx, vy, vz, ax, ay, az, jx, jy, jz = piece
    return _carriage(arm2, tx, ty, px, py, pz, vx, vy, vz, ax, ay, az, jx, jy, jz, s)


@njit(cache=True, inline="always")
def _delta_turning_points(piece, span, bnd):
    """Where the carriage may turn on the delta piece (:func:`delta_turning_points`), into bnd[1..]."""
    arm2, tx, ty, px, py, pz, vx, vy, vz, ax, ay, az, jx, jy, jz = piece
    return delta_turning_points(arm2, tx, ty, px, py, vx, vy, vz, ax, ay, az, jx, jy, jz, span, bnd[1:])


@njit(cache=True, inline="always")
def _delta_stretch(piece, lo, hi, sigma):
    """(last crossing, stretch end, carriage height at both (mm), Newton's next guess (−1: none), 1/carriage
    velocity at the last crossing (s/mm, 0: none)) of a monotone stretch of a delta piece."""
    return (lo, hi, _delta_position(piece, lo), _delta_position(piece, hi), -1.0, 0.0)


@njit(cache=True, inline="always")
def _delta_crossing(piece, ctx, target, sigma, step_dist):
    """The next crossing of ``target`` (mm) by the carriage: bracketed Newton (:func:`_carriage_crossing`)
    from a guess one step past the last crossing (two-step Adams–Bashforth on dτ/dc = 1/c' with the
    velocities at the last two crossings; Euler after the first)."""
    arm2, tx, ty, px, py, pz, vx, vy, vz, ax, ay, az, jx, jy, jz = piece
    left, hi, c_left, c_hi, guess, inv_v_prev = ctx
    f_lo = c_left - target
    f_hi = c_hi - target
    if f_lo == 0.0:
        tau = left
        guess = -1.0
    elif f_hi == 0.0 or (f_lo > 0.0) == (f_hi > 0.0):
        # rounding at the stretch's end: the crossing is at the nearer end
        tau = hi if abs(f_hi) <= abs(f_lo) else left
        guess = -1.0
    else:
        tau, vel = _carriage_crossing(arm2, tx, ty, px, py, pz, vx, vy, vz, ax, ay, az, jx, jy, jz,
                                      target, left, hi, f_lo, f_hi, guess)
        if vel != 0.0:
            inv_v = 1.0 / vel
            w = inv_v if inv_v_prev == 0.0 else 1.5 * inv_v - 0.5 * inv_v_prev
            guess = tau + sigma * step_dist * w
            inv_v_prev = inv_v
        else:
            guess = -1.0
            inv_v_prev = 0.0
    return tau, (tau, hi, target, c_hi, guess, inv_v_prev)


@njit(cache=True)
def gen_steps_delta(t0, dt, pc, vc, ac, jc, reset, arm2, tx, ty, step_dist, state, start, out_t, out_dir, out_n):
    """:func:`gen_steps` for a delta tower: the stepper position is the carriage height
    z + √(arm2 − (tx − x)² − (ty − y)²) of the pieces' x, y, z (columns 0, 1, 2 of the (n, ≥3) arrays
    ``pc vc ac jc``, the SEGMENT convention: q(τ) = p + v·τ + a·τ²/2 + j·τ³/6).

    Same grid, hysteresis, reset flags, state and buffer contract as :func:`gen_steps`. Each piece is cut
    where the carriage turns (:func:`delta_turning_points`: a carriage can reverse while the head moves
    straight), and every half-step crossing of each monotone stretch is solved by bracketed Newton.
    Returns (next piece index, new out_n, need); need = −1 for a non-finite coefficient, −2 for a
    piece whose start the arm cannot reach.
    """
    return step_pieces(_delta_piece, _delta_position, _delta_turning_points, _delta_stretch, _delta_crossing,
                       (pc, vc, ac, jc, arm2, tx, ty), 2 * DELTA_NCOEF,
                       t0, dt, reset, step_dist, state, start, out_t, out_dir, out_n)


# ------------------------------------------------------------------ Klipper's own step search (itersolve)
#
# Klipper does not solve crossings exactly: its itersolve.c (itersolve_gen_steps_range, Klipper ≥ 2020)
# walks forward from the last step with secant guesses and an exponential search (first probe 100 µs after
# the start of a range, else 1.5 × the last step interval, doubling while nothing is found), and calls a
# step found when a guess lands within 1 nm of the half-step point or the bracket shrinks below 1 ns. A
# reversal counts only once the position is 10 nm past the half-step point behind. Each call covers one
# trapq move clipped to one step-generation window (itersolve_generate_steps: moves where the stepper is
# active, plus the shaper's / pressure advance's reach before and after them), and the search restarts at
# every call. An excursion past a half-step point that falls between two probes is not seen. Its
# stepcompress.c holds the last step back: an opposite step less than 750 µs later deletes both
# (stepcompress_append), unless the search had already seen the position reach the held step's commanded
# position (stepcompress_commit). :func:`itersolve_steps` reproduces this decision for decision, with our
# exact pieces where Klipper calls its position callback (docs/design.md §11).

I_LAST_FLUSH = 0    # s, the previous window's end (sk->last_flush_time)
I_LAST_MOVE = 1     # s, end of the last active move stepped (sk->last_move_time)
I_COMMANDED = 2     # mm, the commanded position (sk->commanded_pos)
I_DIR = 3           # 1.0 forward, 0.0 backward: the direction of the next step (stepcompress next_step_dir)
I_PENDING = 4       # 1.0 while a step is held back (stepcompress next_step_clock != 0)
I_PEND_T = 5        # s, the held step's time
I_MOVE = 6          # index of the first trapq move still to visit
I_PIECE = 7         # piece index hint for the position lookups
I_STARTED = 8       # 1.0 once the commanded position is set
I_START_T = 9       # s, where the commanded position is read when it is not (−inf: the first piece's start)
ITS_LEN = 10

ITS_SEEK_RESET_S = 1e-4     # itersolve.c SEEK_TIME_RESET
ITS_CLOSE_MM = 1e-9         # a guess this close to the half-step point is the step
ITS_CLOSE_S = 1e-9          # a bracket this narrow is the step
ITS_REVERSE_MM = 1e-8       # a reversal needs the position this far past the half-step point behind
ITS_NEVER_S = 1e15          # the trapq's tail sentinel lasts forever


def new_itersolve_state() -> np.ndarray:
    """A fresh :func:`itersolve_steps` state: nothing stepped, the commanded position set by the first piece."""
    st = np.zeros(ITS_LEN, dtype=np.float64)
    st[I_LAST_FLUSH] = -np.inf
    st[I_LAST_MOVE] = -np.inf
    st[I_START_T] = -np.inf
    return st


@njit(cache=True, inline="always")
def _its_position(pt0, pdt, coef, k, t):
    """(position mm, piece index) at absolute time t: Σ coef[k, i]·s^i, s = t − pt0[k] clamped to the piece (at rest
    before the first piece and after the last); ``k`` is the search's starting guess."""
    n = pt0.shape[0]
    while k > 0 and t < pt0[k]:
        k -= 1
    while k + 1 < n and t >= pt0[k + 1]:
        k += 1
    s = t - pt0[k]
    if s < 0.0:
        s = 0.0
    elif s > pdt[k]:
        s = pdt[k]
    return coef[k, 0] + s * (coef[k, 1] + s * (coef[k, 2] + s * (coef[k, 3] + s * (coef[k, 4] + s * coef[k, 5])))), k


IK_NCOEF = 12           # x, y, z pieces for the search's inverse-kinematics callback: p, v, a/2, j/6 per axis
IK_CHECK_SAMPLES = 8    # points per piece where a plug-in motor's position is checked to exist before the search


@njit(cache=True)
def ik_positions(ik, params, x, y, z):
    """``ik(x[i], y[i], z[i], params)`` for every i (motor positions; NaN where the kinematics cannot reach)."""
    out = np.empty(x.shape[0])
    for i in range(x.shape[0]):
        out[i] = ik(x[i], y[i], z[i], params)
    return out


@njit(cache=True, inline="always")
def _its_ik_position(pt0, pdt, coef, ik, params, period, ref, k, base, t):
    """(motor position, piece index) at absolute time base + t through a plug-in's inverse kinematics ``ik`` (Klipper's
    calc_position callback): x, y, z of piece k are coef[k, 4q:4q + 4] (p, v, a/2, j/6 of axis q), clamped to the
    piece as in :func:`_its_position`. ``period`` > 0: a cyclic position taken on the branch within half a period of
    ``ref`` (Klipper's polar bed compares atan2 with the commanded angle). The time into the piece is
    (base − pt0[k]) + t, exactly t on the piece that starts the trapq move at ``base`` (Klipper evaluates a move
    at its own time): the search's secant through two guesses a fraction of a nanometre apart would feel the
    rounding of an absolute time."""
    n = pt0.shape[0]
    ta = base + t
    while k > 0 and ta < pt0[k]:
        k -= 1
    while k + 1 < n and ta >= pt0[k + 1]:
        k += 1
    s = (base - pt0[k]) + t
    if s < 0.0:
        s = 0.0
    elif s > pdt[k]:
        s = pdt[k]
    x = coef[k, 0] + s * (coef[k, 1] + s * (coef[k, 2] + s * coef[k, 3]))
    y = coef[k, 4] + s * (coef[k, 5] + s * (coef[k, 6] + s * coef[k, 7]))
    z = coef[k, 8] + s * (coef[k, 9] + s * (coef[k, 10] + s * coef[k, 11]))
    m = ik(x, y, z, params)
    if period > 0.0:
        if m - ref > 0.5 * period:
            m -= period
        elif m - ref < -0.5 * period:
            m += period
    return m, k


@njit(cache=True, inline="always")
def _its_eval(pt0, pdt, coef, ik, params, period, ref, k, base, t):
    """The search's position callback at time base + t (s): the polynomial pieces (``ik`` None:
    :func:`_its_position`, compiled away) or a plug-in's inverse kinematics of the x, y, z pieces
    (:func:`_its_ik_position`)."""
    if ik is None:
        return _its_position(pt0, pdt, coef, k, base + t)
    return _its_ik_position(pt0, pdt, coef, ik, params, period, ref, k, base, t)


@njit(cache=True, inline="always")
def _its_commit(st, pend_t, out_t, out_dir, out_n):
    """stepcompress_commit: the held step can no longer be taken back, out it goes. Returns the new out_n, −1 when
    ``out_t`` is full."""
    if out_n >= out_t.shape[0]:
        return -1
    out_t[out_n] = pend_t
    out_dir[out_n] = np.int8(1) if st[I_DIR] != 0.0 else np.int8(-1)
    return out_n + 1


@njit(cache=True, inline="always")
def _its_append(sdir, t_step, sds_t, st, pend, pend_t, out_t, out_dir, out_n):
    """stepcompress_append with its step+dir+step filter (``sds_t`` > 0: each step is held back and dropped with the
    opposite step less than sds_t after it; 0: out at once). The held step's direction is st[I_DIR], set here
    to ``sdir``. Returns (out_n, −1 when ``out_t`` is full; pending; held step's time s)."""
    if sds_t > 0.0:
        taken_back = False
        if pend:
            pend_dir = st[I_DIR] != 0.0
            if sdir != pend_dir and t_step - pend_t < sds_t:
                pend = False
                taken_back = True
            else:
                if out_n >= out_t.shape[0]:
                    return -1, pend, pend_t
                out_t[out_n] = pend_t
                out_dir[out_n] = np.int8(1) if pend_dir else np.int8(-1)
                out_n += 1
        if not taken_back:
            pend = True
            pend_t = t_step
    else:
        if out_n >= out_t.shape[0]:
            return -1, pend, pend_t
        out_t[out_n] = t_step
        out_dir[out_n] = np.int8(1) if sdir else np.int8(-1)
        out_n += 1
    st[I_DIR] = 1.0 if sdir else 0.0
    return out_n, pend, pend_t


@njit(cache=True, error_model="numpy", inline="always")
def _its_monotone_end(pt0, pdt, coef, k, t_prev, sdir):
    """(end s of the run of quadratic pieces on which the position keeps moving in direction ``sdir`` from
    ``t_prev`` (at most 32 pieces ahead), index of the piece holding ``t_prev``; ``k`` is the guess)."""
    n_p = pt0.shape[0]
    while k > 0 and t_prev < pt0[k]:
        k -= 1
    while k + 1 < n_p and t_prev >= pt0[k + 1]:
        k += 1
    lim = t_prev
    kk = k
    for _ in range(32):
        if coef[kk, 3] != 0.0 or coef[kk, 4] != 0.0 or coef[kk, 5] != 0.0:
            break
        c1 = coef[kk, 1]
        c2 = coef[kk, 2]
        s_from = t_prev - pt0[kk]
        if s_from < 0.0:
            s_from = 0.0
        v_from = c1 + 2.0 * c2 * s_from
        if (v_from > 0.0) != sdir and v_from != 0.0:
            break
        s_end = pdt[kk]
        if c2 != 0.0:
            s_r = -c1 / (2.0 * c2)
            if s_from < s_r < s_end:
                lim = pt0[kk] + s_r
                break
        lim = pt0[kk] + s_end
        if kk + 1 >= n_p:
            break
        kk += 1
    return lim, k


@njit(cache=True, error_model="numpy", inline="always")
def _its_closed_form_steps(pt0, pdt, coef, k, lim, t_prev, m_start, end, sdir, target, half, seek, g_p, sds_t,
                           st, pend, pend_t, out_t, out_dir, out_n):
    """The steps after the one at ``t_prev`` (s, absolute) that lie on the monotone run of quadratic pieces ending
    at ``lim`` (:func:`_its_monotone_end`) where Klipper's probes for them cannot leave that run — they stay
    below t_prev + 2·max(interval, seek) — so its search finds exactly the crossing: each taken in closed form.
    Returns (out_n or −1 when ``out_t`` is full, pending, held step's time, target, seek, time of the last step
    s, its piece, position of the last step, steps taken)."""
    n_p = pt0.shape[0]
    taken = 0
    kc = k
    base = t_prev
    s_b = t_prev - pt0[kc]
    c2 = coef[kc, 2]
    v_b = coef[kc, 1] + 2.0 * c2 * s_b
    p_b = coef[kc, 0] + s_b * (coef[kc, 1] + s_b * c2)
    p_e = coef[kc, 0] + pdt[kc] * (coef[kc, 1] + pdt[kc] * c2)
    while lim > t_prev and coef[kc, 3] == 0.0 and coef[kc, 4] == 0.0 and coef[kc, 5] == 0.0:
        if (p_e < target) if sdir else (p_e > target):
            # not reached on this piece: the next one of the run
            if kc + 1 >= n_p or pt0[kc + 1] >= lim:
                break
            kc += 1
            base = pt0[kc]
            c2 = coef[kc, 2]
            v_b = coef[kc, 1]
            p_b = coef[kc, 0]
            p_e = p_b + pdt[kc] * (v_b + pdt[kc] * c2)
            continue
        cc = p_b - target
        disc = v_b * v_b - 4.0 * c2 * cc
        if disc < 0.0:
            disc = 0.0
        den = v_b + math.sqrt(disc) if sdir else v_b - math.sqrt(disc)
        if den == 0.0:
            break
        t_step = base - 2.0 * cc / den
        gap = t_step - t_prev
        if not (gap > 0.0):
            break
        reach = gap if gap > seek else seek
        if t_prev + 2.0 * reach >= lim or t_step - m_start >= end:
            break
        out_n, pend, pend_t = _its_append(sdir, t_step, sds_t, st, pend, pend_t, out_t, out_dir, out_n)
        if out_n < 0:
            break
        g_p = target
        target = target + half + half if sdir else target - half - half
        seek = 1.5 * gap
        if seek < ITS_CLOSE_S:
            seek = ITS_CLOSE_S
        t_prev = t_step
        taken += 1
    return out_n, pend, pend_t, target, seek, t_prev, kc, g_p, taken


@njit(cache=True, error_model="numpy", inline="always")
def _its_shortcut(pt0, pdt, coef, k, m_start, end, sdir, target, half, seek, g_p, g_t, og_t, og_p, last_t, low_t,
                  high_t, sds_t, st, pend, pend_t, out_t, out_dir, out_n):
    """After a step at ``last_t`` (s into the move starting at ``m_start``) on polynomial pieces: the steps
    :func:`_its_closed_form_steps` can take, then the search's state as Klipper's would be after the last of
    them (that step as its last guess, a point just before it as the one before). Returns (out_n or −1 when
    ``out_t`` is full, pending, held step's time, target, g_p, g_t, og_t, og_p, last_t, low_t, high_t, k)."""
    lim, k = _its_monotone_end(pt0, pdt, coef, k, m_start + last_t, sdir)
    out_n, pend, pend_t, target, seek, t_prev, kc, g_p, taken = _its_closed_form_steps(
        pt0, pdt, coef, k, lim, m_start + last_t, m_start, end, sdir, target, half, seek, g_p, sds_t, st, pend,
        pend_t, out_t, out_dir, out_n)
    if taken and out_n >= 0:
        last_t = t_prev - m_start
        g_t = last_t
        delta = seek * (1e-3 / 1.5)
        og_t = g_t - delta
        og_p, k = _its_position(pt0, pdt, coef, kc, m_start + og_t)
        low_t = g_t
        high_t = g_t + seek
        if high_t > end:
            high_t = end
    return out_n, pend, pend_t, target, g_p, g_t, og_t, og_p, last_t, low_t, high_t, k


@njit(cache=True, inline="always")
def _its_angle_post_fixup(commanded, period):
    """Klipper's polar_stepper_angle_post_fixup: a cyclic motor's commanded position back within half a period
    of 0 (``period`` 0: unchanged)."""
    if period > 0.0:
        if commanded < -0.5 * period:
            commanded += period
        elif commanded > 0.5 * period:
            commanded -= period
    return commanded


@njit(cache=True, inline="always")
def _its_range_start(m_start, m_len, abs_start, abs_end, half, st):
    """The start of itersolve_gen_steps_range: the range in the move's own time (s), the search state read from
    ``st`` and the first half-step point and search bound. Returns (start, end, commanded position, piece hint,
    pending, held step's time, direction, target, high_t)."""
    start = abs_start - m_start
    if start < 0.0:
        start = 0.0
    end = abs_end - m_start
    if end > m_len:
        end = m_len
    commanded = st[I_COMMANDED]
    sdir = st[I_DIR] != 0.0
    target = commanded + half if sdir else commanded - half
    high_t = start + ITS_SEEK_RESET_S
    if high_t > end:
        high_t = end
    return (start, end, commanded, np.int64(st[I_PIECE]), st[I_PENDING] != 0.0, st[I_PEND_T], sdir, target,
            high_t)


@njit(cache=True, error_model="numpy", inline="always")
def _its_range(m_start, m_len, abs_start, abs_end, pt0, pdt, coef, half, sds_t, st, out_t, out_dir, out_n,
               ik, params, period):
    """itersolve_gen_steps_range: the steps of trapq move [m_start, m_start + m_len] inside [abs_start, abs_end],
    position from :func:`_its_eval` (see there). Updates ``st``; returns the new out_n, −1 when ``out_t`` is full."""
    start, end, commanded, k, pend, pend_t, sdir, target, high_t = _its_range_start(m_start, m_len, abs_start,
                                                                                    abs_end, half, st)
    og_t, og_p, g_t, g_p = start, commanded, start, commanded
    is_dir_change = have_bracket = check_osc = False
    last_t = low_t = start
    while True:
        # secant through the last two guesses
        g_d = g_p - target
        og_d = og_p - target
        nxt = (og_t * g_d - g_t * og_d) / (g_d - og_d)
        if not (nxt > low_t and nxt < high_t):
            if have_bracket:
                nxt = 0.5 * (low_t + high_t)
                check_osc = False
            elif g_t >= end:
                break
            else:
                # exponential search ahead
                nxt = high_t
                high_t = 2.0 * high_t - last_t
                if high_t > end:
                    high_t = end
        og_t, og_p, g_t = g_t, g_p, nxt
        g_p, k = _its_eval(pt0, pdt, coef, ik, params, period, commanded, k, m_start, nxt)
        g_d = g_p - target
        if abs(g_d) > ITS_CLOSE_MM:
            rel = g_d if sdir else -g_d
            if rel > 0.0:
                # past the half-step point: a step lies before this guess
                if have_bracket and og_t <= low_t:
                    if check_osc:
                        # a second time from the same side: forget the older guess (the secant would oscillate)
                        og_t, og_p = g_t, g_p
                    check_osc = True
                high_t, have_bracket = g_t, True
            elif rel < -(half + half + ITS_REVERSE_MM):
                # reversal: the next step is back across the last half-step point
                sdir = not sdir
                target = target + half + half if sdir else target - half - half
                low_t, high_t = last_t, g_t
                is_dir_change = have_bracket = True
                check_osc = False
            else:
                low_t = g_t
            if (not have_bracket) or high_t - low_t > ITS_CLOSE_S:
                if (not is_dir_change) and rel >= -half and pend:
                    # the motor reached the held step's position: it can no longer be taken back
                    out_n = _its_commit(st, pend_t, out_t, out_dir, out_n)
                    if out_n < 0:
                        return -1
                    pend = False
                continue
        # a step at g_t: stepcompress_append as in :func:`_its_append`, written out (measurably faster here)
        t_step = m_start + g_t
        if sds_t > 0.0:
            if pend and sdir != (st[I_DIR] != 0.0) and t_step - pend_t < sds_t:
                pend = False            # taken back with the held step it undoes
            else:
                if pend:
                    if out_n >= out_t.shape[0]:
                        return -1
                    out_t[out_n] = pend_t
                    out_dir[out_n] = np.int8(1) if st[I_DIR] != 0.0 else np.int8(-1)
                    out_n += 1
                pend = True
                pend_t = t_step
        else:
            if out_n >= out_t.shape[0]:
                return -1
            out_t[out_n] = t_step
            out_dir[out_n] = np.int8(1) if sdir else np.int8(-1)
            out_n += 1
        st[I_DIR] = 1.0 if sdir else 0.0
        target = target + half + half if sdir else target - half - half
        seek = 1.5 * (g_t - last_t)
        if seek < ITS_CLOSE_S:
            seek = ITS_CLOSE_S
        if is_dir_change and seek > ITS_SEEK_RESET_S:
            seek = ITS_SEEK_RESET_S
        last_t = low_t = g_t
        high_t = g_t + seek
        if high_t > end:
            high_t = end
        is_dir_change = have_bracket = check_osc = False
        if ik is None:
            # gcodeplan's shortcut on polynomial pieces: the steps Klipper's search cannot miss, in closed form
            out_n, pend, pend_t, target, g_p, g_t, og_t, og_p, last_t, low_t, high_t, k = _its_shortcut(
                pt0, pdt, coef, k, m_start, end, sdir, target, half, seek, g_p, g_t, og_t, og_p, last_t, low_t,
                high_t, sds_t, st, pend, pend_t, out_t, out_dir, out_n)
            if out_n < 0:
                return -1
    st[I_COMMANDED] = _its_angle_post_fixup(target - half if sdir else target + half, period)
    st[I_PIECE] = k
    st[I_PENDING] = 1.0 if pend else 0.0
    st[I_PEND_T] = pend_t
    return out_n


@njit(cache=True, error_model="numpy")
def itersolve_steps(flush_t, m_start, m_len, m_active, pre_t, post_t, pt0, pdt, coef, step_dist, sds_t, state,
                    out_t, out_dir, out_n, ik=None, params=None, period=0.0):
    """Klipper's steps for the step-generation windows ending at ``flush_t`` (s, increasing), itersolve_generate_steps
    call by call.

    Trapq moves: start ``m_start``, duration ``m_len`` (s; the last one is the tail sentinel, ITS_NEVER_S long),
    ``m_active`` (Klipper's check_active: the move has motion on an axis this stepper follows). ``pre_t``/``post_t``:
    how long before/after its active moves the stepper moves (the shaper's or pressure advance's reach; Klipper's
    gen_steps_pre_active / post_active). Position: Σ coef[k, i]·(t − pt0[k])^i on piece k (degree ≤ 5, mm), at rest
    outside the pieces; with ``ik`` (a plug-in's inverse kinematics cfunc, :func:`_its_ik_position`) the motor
    position is ``ik(x, y, z, params)`` of the x, y, z pieces in ``coef`` (12 columns) instead, Klipper's
    calc_position callback (``period`` > 0: a cyclic motor, e.g. polar's bed, rad). ``sds_t`` > 0: hold each step back and drop it with an opposite step less than sds_t later
    (stepcompress.c); 0: no filter. ``state`` (I_*) carries everything between calls; the commanded position
    starts at the position of the first piece.

    Returns (windows done, new out_n). A window is emitted whole: when ``out_t`` fills up the state is restored
    to the window's start and the call returns early (empty the buffer and call again from ``flush_t[done:]``).
    """
    n_moves = m_start.shape[0]
    half = 0.5 * step_dist
    saved = np.empty(ITS_LEN)
    if state[I_STARTED] == 0.0:
        p0, k0 = _its_eval(pt0, pdt, coef, ik, params, period, 0.0, 0, state[I_START_T], 0.0)
        state[I_PIECE] = k0
        state[I_COMMANDED] = p0
        state[I_STARTED] = 1.0
    done = 0
    for w in range(flush_t.shape[0]):
        F = flush_t[w]
        for q in range(ITS_LEN):
            saved[q] = state[q]
        n_before = out_n
        lft = state[I_LAST_FLUSH]
        state[I_LAST_FLUSH] = F
        mi = np.int64(state[I_MOVE])
        while mi < n_moves - 1 and lft >= m_start[mi] + m_len[mi]:
            mi += 1
        state[I_MOVE] = mi
        force = state[I_LAST_MOVE] + post_t
        skip = 0
        full = False
        while mi < n_moves:
            ms = m_start[mi]
            me = ms + m_len[mi]
            if m_active[mi]:
                if skip > 0 and pre_t > 0.0:
                    # steps leading up to the activity (the shaper looks ahead)
                    a0 = ms - pre_t
                    if a0 < lft:
                        a0 = lft
                    if a0 < force:
                        a0 = force
                    pm = mi - 1
                    skip -= 1
                    while skip > 0 and m_start[pm] > a0:
                        pm -= 1
                        skip -= 1
                    while pm != mi:
                        out_n = _its_range(m_start[pm], m_len[pm], a0, F, pt0, pdt, coef, half, sds_t, state,
                                           out_t, out_dir, out_n, ik, params, period)
                        if out_n < 0:
                            break
                        pm += 1
                    if out_n < 0:
                        full = True
                        break
                out_n = _its_range(ms, m_len[mi], lft, F, pt0, pdt, coef, half, sds_t, state, out_t, out_dir, out_n,
                                   ik, params, period)
                if out_n < 0:
                    full = True
                    break
                if me >= F:
                    state[I_LAST_MOVE] = F
                    break
                skip = 0
                state[I_LAST_MOVE] = me
                force = me + post_t
            else:
                if ms < force:
                    # steps just past the activity (the shaper / smoothing lags behind)
                    a1 = force if force < F else F
                    out_n = _its_range(ms, m_len[mi], lft, a1, pt0, pdt, coef, half, sds_t, state, out_t, out_dir,
                                       out_n, ik, params, period)
                    if out_n < 0:
                        full = True
                        break
                    skip = 1
                else:
                    skip += 1
                if F + pre_t <= me:
                    break
            mi += 1
        if full:
            for q in range(ITS_LEN):
                state[q] = saved[q]
            return done, n_before
        done = w + 1
    return done, out_n


def itersolve_flush_pending(state: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The step :func:`itersolve_steps` still holds back (0 or 1 of them), released at the end of the run."""
    if state[I_PENDING] == 0.0:
        return np.empty(0, np.float64), np.empty(0, np.int8)
    state[I_PENDING] = 0.0
    return np.array([state[I_PEND_T]], np.float64), np.array([1 if state[I_DIR] != 0.0 else -1], np.int8)


# ------------------------------------------------------------------ plug-in motors (inverse kinematics, guarded search)
#
# A plug-in motor's position is ``ik(x, y, z)`` (its parameters bound: kinematics.plugin.ik_bound_cfunc) of the
# toolhead's x, y, z pieces: no closed form, so the step engine (:func:`step_pieces`) gets a guarded root search as
# its piece type, exact to < 1 ns (it does not reproduce Klipper's search: see StepGenerator.ik_klipper_search).
# Each piece is sampled at IK_CHECK_SAMPLES + 1 evenly spaced points, plus a probe IK_PROBE of a sample interval in
# from each end: a sample without a motor position makes the piece unreachable (the points the former NumPy check
# looked at), a change of sign between sample differences brackets a turning point, refined by golden-section
# search (Numerical Recipes §10.2) to IK_TURN_S. Each half-step crossing of a monotone stretch starts from a
# prediction: the stretch's crossings two to four steps back extrapolated by a quadratic in the step number (not
# the last one, so that consecutive steps do not wait for each other), one evaluation there and a secant step
# through the last crossing, taken when its estimated error is at most IK_ACCEPT_S. Otherwise, and for the first
# steps of a stretch, a bracketed secant search (Illinois variant, Numerical Recipes §9.2) inside the stretch, to
# IK_DONE_S. A motor that reverses twice between two samples (a wiggle shorter than an eighth of a piece) is not
# seen; Klipper's probes, 1.5 step intervals apart, miss such excursions too.

IK_ACCEPT_S = 1e-9      # s, a predicted crossing's secant correction is taken when its estimated error is this small
IK_DONE_S = 1e-10       # s, the bracketed search stops when its step is this small
IK_TURN_S = 1e-9        # s, width a turning point is narrowed to
IK_PROBE = 1e-3        # of a sample interval: where the direction at a piece's ends is probed
IK_MAX_ITER = 200       # bracketed-search evaluations before the bracket's secant point is taken

@njit(cache=True, inline="always")
def _ik_unwrap(m, ref, period):
    """A cyclic motor position ``m`` (period > 0) taken on the branch nearest ``ref``; ``m`` as is otherwise."""
    if period > 0.0:
        m += period * math.floor((ref - m) / period + 0.5)
    return m


@njit(cache=True, inline="always")
def _ik_at(x0, x1, x2, x3, y0, y1, y2, y3, z0, z1, z2, z3, ik, s):
    """The motor position ik(x, y, z) at τ = s of the x, y, z cubics (power basis: p, v, a/2, j/6)."""
    x = x0 + s * (x1 + s * (x2 + s * x3))
    y = y0 + s * (y1 + s * (y2 + s * y3))
    z = z0 + s * (z1 + s * (z2 + s * z3))
    return ik(x, y, z)


@njit(cache=True, error_model="numpy")
def ik_branch_refs(t0, dt, pc, vc, ac, jc, ik, period, state, start):
    """For a cyclic motor (period > 0, e.g. a turntable's angle in rad): the motor position at the start of each
    piece from ``start`` on, each taken on the branch within half a period of the previous piece's end (the first
    of the state's last position, S_LAST_POS, once anchored): the position followed continuously through the
    wrap-around. Empty for period 0."""
    n = t0.shape[0]
    if not (period > 0.0):
        return np.empty(0, np.float64)
    refs = np.full(n, np.nan)
    prev = state[S_LAST_POS] if state[S_ANCHORED] != 0.0 else np.nan
    for i in range(start, n):
        x0, y0, z0 = pc[i, 0], pc[i, 1], pc[i, 2]
        m0 = ik(x0, y0, z0)
        if math.isfinite(prev):
            m0 = _ik_unwrap(m0, prev, period)
        refs[i] = m0
        s = dt[i]
        if s > 0.0 and math.isfinite(s):
            m1 = _ik_at(x0, vc[i, 0], 0.5 * ac[i, 0], jc[i, 0] * (1.0 / 6.0),
                        y0, vc[i, 1], 0.5 * ac[i, 1], jc[i, 1] * (1.0 / 6.0),
                        z0, vc[i, 2], 0.5 * ac[i, 2], jc[i, 2] * (1.0 / 6.0), ik, s)
            prev = _ik_unwrap(m1, m0, period)
        else:
            prev = m0
    return refs


@njit(cache=True, inline="always")
def _ik_piece(data, i):
    """:func:`step_pieces`'s ``piece_at`` for a plug-in motor: data = (p, v, a, j, ik, period, refs, t0, dt),
    (n, ≥3) x, y, z columns (mm, mm/s, mm/s², mm/s³), the ik with its parameters bound
    (:func:`gcodeplan.kinematics.plugin.ik_bound_cfunc`), the branch references of a cyclic motor
    (:func:`ik_branch_refs`), the pieces' start times and durations (s); the piece is (x, y, z cubics in the
    power basis, ik, period, position at the start (mm), start time (s), duration (s)). It holds no array: every
    array a step's functions receive costs two reference counts per call, more than the ik."""
    pc, vc, ac, jc, ik, period, refs, t0, dt = data
    x0 = pc[i, 0]
    y0 = pc[i, 1]
    z0 = pc[i, 2]
    x1 = vc[i, 0]
    y1 = vc[i, 1]
    z1 = vc[i, 2]
    x2 = 0.5 * ac[i, 0]
    y2 = 0.5 * ac[i, 1]
    z2 = 0.5 * ac[i, 2]
    x3 = jc[i, 0] * (1.0 / 6.0)
    y3 = jc[i, 1] * (1.0 / 6.0)
    z3 = jc[i, 2] * (1.0 / 6.0)
    status = PIECE_MOVING
    p = x0
    if not (math.isfinite(x0) and math.isfinite(y0) and math.isfinite(z0) and math.isfinite(x1)
            and math.isfinite(y1) and math.isfinite(z1) and math.isfinite(x2) and math.isfinite(y2)
            and math.isfinite(z2) and math.isfinite(x3) and math.isfinite(y3) and math.isfinite(z3)):
        status = PIECE_BROKEN
    else:
        p = refs[i] if period > 0.0 else ik(x0, y0, z0)
        if not math.isfinite(p):
            status = PIECE_UNREACHABLE
        elif (x1 == 0.0 and y1 == 0.0 and z1 == 0.0 and x2 == 0.0 and y2 == 0.0 and z2 == 0.0 and x3 == 0.0
              and y3 == 0.0 and z3 == 0.0):
            status = PIECE_STILL
    piece = (x0, x1, x2, x3, y0, y1, y2, y3, z0, z1, z2, z3, ik, period, p, t0[i], dt[i])
    return status, p, piece


@njit(cache=True, inline="always")
def _ik_position(piece, s):
    """Motor position (mm, or rad) of the plug-in piece at τ = s (a cyclic one on the branch of the piece's start).
    Reads the piece's fields one by one: binding its arrays to names would count references at every call."""
    m = _ik_at(piece[0], piece[1], piece[2], piece[3], piece[4], piece[5], piece[6], piece[7], piece[8], piece[9],
               piece[10], piece[11], piece[12], s)
    return _ik_unwrap(m, piece[14], piece[13])


@njit(cache=True, inline="always")
def _ik_turn(piece, lo, hi, sg):
    """Where sg·position (sg ±1) is largest on [lo, hi] (s), which holds one maximum: golden-section search."""
    gr = 0.3819660112501051
    c = lo + gr * (hi - lo)
    d = hi - gr * (hi - lo)
    fc = sg * _ik_position(piece, c)
    fd = sg * _ik_position(piece, d)
    for _ in range(100):
        if hi - lo <= IK_TURN_S:
            break
        if fc >= fd:
            hi = d
            d = c
            fd = fc
            c = lo + gr * (hi - lo)
            fc = sg * _ik_position(piece, c)
        else:
            lo = c
            c = d
            fc = fd
            d = hi - gr * (hi - lo)
            fd = sg * _ik_position(piece, d)
    return c if fc >= fd else d


@njit(cache=True, inline="always")
def _ik_sign(d):
    """+1, −1 or 0 by the sign of ``d``."""
    return 1.0 if d > 0.0 else (-1.0 if d < 0.0 else 0.0)


@njit(cache=True, inline="always")
def _ik_turning_points(piece, span, bnd):
    """Where the plug-in motor may turn on the piece, into bnd[1..] (see the section comment): sample differences
    that change sign bracket a turning point, refined by :func:`_ik_turn`; a probe IK_PROBE of the first and last
    sample interval in from each end gives the direction there (a turn inside an end interval shows no change of
    sign between samples). A sample without a motor position is returned as a cut, where the count pass finds it."""
    n_s = IK_CHECK_SAMPLES
    h = span / n_s
    prev = piece[14]
    probe = IK_PROBE * h
    first = _ik_position(piece, probe)
    if not math.isfinite(first):
        bnd[1] = probe
        return 1
    d_prev = _ik_sign(first - prev)
    run_lo = 0.0           # start of the interval where the motor last moved in direction d_prev
    n_cut = 0
    for q in range(1, n_s + 2):
        if q <= n_s:
            s = span if q == n_s else q * h
            cur = _ik_position(piece, s)
            diff = cur - prev
        else:
            # the direction at the very end, against the last sample interval's
            s = span
            cur = prev
            diff = prev - _ik_position(piece, span - probe)
        if not math.isfinite(cur):
            bnd[1] = s
            return 1
        sd = _ik_sign(diff)
        if sd != 0.0:
            if d_prev != 0.0 and sd != d_prev:
                lo = run_lo if q <= n_s else span - h
                t_turn = _ik_turn(piece, lo, s, d_prev)
                last = bnd[n_cut] if n_cut > 0 else 0.0
                if last < t_turn < span and n_cut < IK_CHECK_SAMPLES:
                    n_cut += 1
                    bnd[n_cut] = t_turn
            d_prev = sd
            run_lo = (q - 1) * h
        prev = cur
    return n_cut


@njit(cache=True, inline="always")
def _ik_stretch(piece, lo, hi, sigma):
    """(last crossing or stretch start (s), stretch end (s), motor position at both (mm), crossings held (0-4),
    the newest four crossings (s)) of a monotone stretch."""
    p_lo = piece[14] if lo == 0.0 else _ik_position(piece, lo)
    p_hi = _ik_position(piece, hi)
    return (lo, hi, p_lo, p_hi, 0.0, 0.0, 0.0, 0.0, 0.0)


@njit(cache=True, inline="always")
def _ik_crossing(piece, ctx, target, sigma, step_dist):
    """The next crossing of ``target`` (mm) by the plug-in motor on a monotone stretch: the predictor from the
    stretch's previous crossings and one Newton correction when it is small enough, else a bracketed secant search
    (section comment)."""
    left, hi, p_left, p_hi, cnt, t1, t2, t3, t4 = ctx
    g_lo = sigma * (p_left - target)
    g_hi = sigma * (p_hi - target)
    tau = -1.0
    if g_lo >= 0.0:
        tau = left              # rounding at the stretch's start
    elif g_hi <= 0.0:
        tau = hi                # rounding at the stretch's end: the crossing is there
    else:
        lo = left
        guess = -1.0
        if cnt >= 2.0:
            d2 = 0.0
            if cnt >= 4.0:
                # from the crossings two to four steps back: the next step's evaluation does not wait for this
                # one's (the processor overlaps them)
                d1 = t2 - t3
                d2 = d1 - (t3 - t4)
                pred = t2 + 2.0 * d1 + 3.0 * d2
            else:
                d1 = t1 - t2
                pred = t1 + d1
            if lo < pred < hi and d1 > 0.0:
                g = sigma * (_ik_position(piece, pred) - target)
                if g == 0.0:
                    tau = pred
                else:
                    # secant through the last crossing and the prediction; its error is
                    # |x''/(2x')|·|τ − left|·|τ − pred| (Numerical Recipes §9.2) with x''/x' ≈ d2/d1² from the history,
                    # or — a change of phase the history cannot see — as large as the prediction's miss implies
                    # (a miss of corr two steps ahead needs a relative change of the interval of corr/(2·d1) per step)
                    cand = pred - g * (pred - lo) / (g - g_lo)
                    corr = abs(cand - pred)
                    curve = abs(d2) if abs(d2) > 0.5 * corr else 0.5 * corr
                    if lo < cand < hi and corr <= 0.25 * d1 and 0.5 * curve * corr <= IK_ACCEPT_S * d1:
                        tau = cand
                    else:
                        if g > 0.0:
                            hi = pred
                            g_hi = g
                        else:
                            lo = pred
                            g_lo = g
                        if lo < cand < hi:
                            guess = cand
        if tau < 0.0:
            tau = _ik_bracketed(piece, target, sigma, lo, hi, g_lo, g_hi, guess)
    if cnt < 4.0:
        cnt += 1.0
    return tau, (tau, ctx[1], target, p_hi, cnt, tau, t1, t2, t3)


@njit(cache=True, inline="always")
def _ik_bracketed(piece, target, sigma, lo, hi, g_lo, g_hi, guess):
    """τ in [lo, hi] where sigma·(position − target) rises through 0 (g_lo < 0 < g_hi at the ends): secant steps
    kept in the bracket (Illinois: the end that stays twice running has its value halved), from ``guess`` when
    it lies inside."""
    t = guess if lo < guess < hi else lo - g_lo * (hi - lo) / (g_hi - g_lo)
    side = 0
    for _ in range(IK_MAX_ITER):
        if not (lo < t < hi):
            t = 0.5 * (lo + hi)
        g = sigma * (_ik_position(piece, t) - target)
        if g == 0.0:
            return t
        if g > 0.0:
            hi = t
            g_hi = g
            if side == 1:
                g_lo *= 0.5
            side = 1
        else:
            lo = t
            g_lo = g
            if side == -1:
                g_hi *= 0.5
            side = -1
        nxt = lo - g_lo * (hi - lo) / (g_hi - g_lo)
        if abs(nxt - t) <= IK_DONE_S or hi - lo <= IK_DONE_S:
            return nxt if lo <= nxt <= hi else t
        t = nxt
    return t


@njit(cache=True, error_model="numpy")
def gen_steps_ik(t0, dt, pc, vc, ac, jc, reset, ik, period, refs, step_dist, state, start, out_t, out_dir, out_n):
    """:func:`gen_steps` for a plug-in motor: the position is ``ik(x, y, z)`` (a compiled function with the plug-in's
    parameters bound, :func:`gcodeplan.kinematics.plugin.ik_bound_cfunc`; mm or rad) of the pieces' x, y, z
    (columns 0, 1, 2 of the (n, ≥3) arrays ``pc vc ac jc``, the SEGMENT convention).
    ``period`` > 0: a cyclic motor, followed continuously from branch references ``refs``
    (:func:`ik_branch_refs`).

    Same grid, hysteresis, reset flags, state and buffer contract as :func:`gen_steps`; each piece is cut where the
    motor turns and each crossing found by the guarded search of the section comment. Returns (next piece index,
    new out_n, need); need = −1 for a non-finite coefficient, −2 for a piece where the kinematics gives no motor
    position (at its start or a sample).
    """
    return step_pieces(_ik_piece, _ik_position, _ik_turning_points, _ik_stretch, _ik_crossing,
                       (pc, vc, ac, jc, ik, period, refs, t0, dt), IK_CHECK_SAMPLES,
                       t0, dt, reset, step_dist, state, start, out_t, out_dir, out_n)


# ------------------------------------------------------------------ plug-in motors by a verified polynomial stand-in
#
# ik_search="fit" (issue 22): no ik call per step. Along a piece the toolhead x, y, z are cubics in time, so the motor
# position m(τ) = ik(x(τ), y(τ), z(τ)) is a smooth function of τ; :func:`ik_fit_pieces` replaces it by a polynomial
# p(τ) of degree ≤ 5 interpolating m at Chebyshev–Lobatto nodes of the span (the ends included, so p starts on the
# exact search's start position), then VERIFIES it at 2·degree further points (two inside each node interval, the
# inner points of the 3·degree Lobatto set). The step engine then steps p (closed-form crossings for degree ≤ 2, the
# linear kernel's functions for a cubic, bracketed Newton for degree 5) and calls no ik at all.
#
# The bound. A crossing of the half-step level L by p at t_p, with |m − p| ≤ e, has |m(t_p) − L| ≤ e, so the true
# crossing is |t_p − t*| ≤ e / |v| away, v the motor speed between the two. A span is accepted when
#   (a) the motor is monotone on it (p' keeps one sign at all 3·degree + 1 samples) and the sampled
#       max |m − p| ≤ ½·IK_FIT_TOL_S·min |p'| (the ½ covers the error and the speed between samples: interpolation
#       error is smooth for a smooth ik), so every step of the span is within IK_FIT_TOL_S of its exact time; or
#   (b) the sampled max |m − p| ≤ IK_FIT_ROUND × the magnitudes the ik computes with: a stand-in as exact as the
#       ik's own floating point (any ik linear in x, y, z on a piece of degree ≤ 3 fits so: cartesian, corexy,
#       hybrid written as plug-ins), whatever the speed.
# Near a turning point (v → 0) no error bound in time holds for (a): such spans fail and are halved (up to
# IK_FIT_SPLITS times, degree 5 each); a piece with a half that still fails is left whole to the exact search
# (:func:`gen_steps_ik`), as is one where the ik gives no position (which reports it). Between samples a motor could
# reverse twice unseen (a wiggle shorter than a sixth of a node interval); the exact search's 8 samples miss
# such wiggles too.

IK_FIT_TOL_S = 1e-9            # s, the step-time error a verified stand-in may add where the motor moves
IK_FIT_ROUND = 64 * 2.220446049250313e-16   # of |m|, |x|, |y|, |z|: a fit error at the ik's own rounding
IK_FIT_SPLITS = 2              # halvings of a piece whose fit fails before the exact search takes it
IK_FIT_DEG = 5                 # the highest degree (the step engine steps degree-5 pieces exactly)
FIT_CUBIC = 0                  # a fitted piece of degree ≤ 3, stepped by the linear kernel's functions
FIT_QUINTIC = 1                # a fitted piece of degree 5, stepped by bracketed Newton
FIT_EXACT = 2                  # the original piece, stepped by the exact search (gen_steps_ik)
FIT_QUINTIC_MONOTONE = 3       # a FIT_QUINTIC piece verified monotone (acceptance (a)): no turning point to find
FIT_REJECTED = 0               # _fit_span's verdicts: rejected, accepted by (b), accepted by (a)
FIT_ROUNDING = 1
FIT_MONOTONE = 2
QUINTIC_DONE_S = 1e-12         # s, a quintic crossing's Newton iteration stops after a step this small


def _fit_tables() -> tuple[np.ndarray, np.ndarray]:
    """(nodes, checks): row d holds the d + 1 Chebyshev–Lobatto nodes of degree d on [0, 1] (0 and 1 exact) and
    the 2·d verification points (the 3·d Lobatto set without the nodes)."""
    nodes = np.zeros((IK_FIT_DEG + 1, IK_FIT_DEG + 1))
    checks = np.zeros((IK_FIT_DEG + 1, 2 * IK_FIT_DEG))
    for d in range(1, IK_FIT_DEG + 1):
        nodes[d, :d + 1] = 0.5 * (1.0 - np.cos(np.pi * np.arange(d + 1) / d))
        q = np.array([k for k in range(1, 3 * d) if k % 3], np.float64)
        checks[d, :2 * d] = 0.5 * (1.0 - np.cos(np.pi * q / (3 * d)))
    return nodes, checks


FIT_NODE_U, FIT_CHECK_U = _fit_tables()


@njit(cache=True, inline="always")
def _fit_cubics(pc, vc, ac, jc, i):
    """Piece i's x, y, z cubics in the power basis (p, v, a/2, j/6 per axis, as :func:`_ik_piece`), as floats: an
    array handed to the fit's helpers would cost two atomic reference counts per call, more than the ik."""
    return (pc[i, 0], vc[i, 0], 0.5 * ac[i, 0], jc[i, 0] * (1.0 / 6.0),
            pc[i, 1], vc[i, 1], 0.5 * ac[i, 1], jc[i, 1] * (1.0 / 6.0),
            pc[i, 2], vc[i, 2], 0.5 * ac[i, 2], jc[i, 2] * (1.0 / 6.0))


@njit(cache=True, inline="always")
def _fit_ik_at(cub, ik, period, ref, s):
    """(motor position on the branch nearest ``ref``, largest |x|, |y|, |z|) at τ = s of the cubics ``cub``
    (:func:`_fit_cubics`; the same arithmetic as :func:`_ik_at`)."""
    x = cub[0] + s * (cub[1] + s * (cub[2] + s * cub[3]))
    y = cub[4] + s * (cub[5] + s * (cub[6] + s * cub[7]))
    z = cub[8] + s * (cub[9] + s * (cub[10] + s * cub[11]))
    return _ik_unwrap(ik(x, y, z), ref, period), max(abs(x), abs(y), abs(z))


@njit(cache=True, inline="always")
def _fit_newton_to_power(m, u, deg, dd, out, row, h):
    """Interpolate values m[0..deg] at nodes u[deg, 0..deg] (u[deg, 0] = 0): Newton divided differences, expanded to the
    power basis in u, then scaled to τ = u·h into out[row, :] (zero above ``deg``). out[row, 0] = m[0] exactly."""
    for k in range(deg + 1):
        dd[k] = m[k]
    for lvl in range(1, deg + 1):
        for k in range(deg, lvl - 1, -1):
            dd[k] = (dd[k] - dd[k - 1]) / (u[deg, k] - u[deg, k - lvl])
    for q in range(POLY_NCOEF):
        out[row, q] = 0.0
    out[row, 0] = dd[deg]
    for k in range(deg - 1, -1, -1):
        uk = u[deg, k]
        for q in range(deg - k, 0, -1):
            out[row, q] = out[row, q - 1] - uk * out[row, q]
        out[row, 0] = dd[k] - uk * out[row, 0]
    inv_h = 1.0 / h
    scale = inv_h
    for q in range(1, deg + 1):
        out[row, q] *= scale
        scale *= inv_h


@njit(cache=True, error_model="numpy", inline="always")
def _fit_span(cub, ik, period, ref, s_lo, h, deg, tol_t, round_rel, m, dd, out, row):
    """Fit the motor position along the cubics ``cub`` (:func:`_fit_cubics`) on τ in [s_lo, s_lo + h] by a polynomial of degree ``deg`` (power basis in
    τ − s_lo, into out[row, :]) and verify it (section comment): FIT_REJECTED, FIT_ROUNDING (accepted by (b)) or
    FIT_MONOTONE (by (a)). ``ref``: the motor position at
    the piece's start (the exact search's, on a cyclic motor's branch)."""
    node_u = FIT_NODE_U
    check_u = FIT_CHECK_U
    mag = 0.0
    for k in range(deg + 1):
        if k == 0 and s_lo == 0.0:
            mk = ref
            g = max(abs(cub[0]), abs(cub[4]), abs(cub[8]))
            m[0] = mk
        else:
            mk, g = _fit_ik_at(cub, ik, period, ref, s_lo + node_u[deg, k] * h)
            m[k] = mk
            m[IK_FIT_DEG + 1] = mk          # the last node's: the span's end (what the next piece may start on)
        if not (math.isfinite(mk) and math.isfinite(g)):
            return FIT_REJECTED
        mag = max(mag, abs(mk), g)
    _fit_newton_to_power(m, node_u, deg, dd, out, row, h)
    c0, c1, c2, c3, c4, c5 = out[row, 0], out[row, 1], out[row, 2], out[row, 3], out[row, 4], out[row, 5]
    err = 0.0
    for q in range(2 * deg):
        s = check_u[deg, q] * h
        mk, g = _fit_ik_at(cub, ik, period, ref, s_lo + s)
        if not (math.isfinite(mk) and math.isfinite(g)):
            return FIT_REJECTED
        mag = max(mag, abs(mk), g)
        err = max(err, abs(mk - (c0 + s * (c1 + s * (c2 + s * (c3 + s * (c4 + s * c5)))))))
    if err <= round_rel * mag:
        return FIT_ROUNDING
    # the speed p' at every node and check point: one sign, and its smallest magnitude
    v_min = math.inf
    sg = 0.0
    for q in range(3 * deg + 1):
        s = (node_u[deg, q] if q <= deg else check_u[deg, q - deg - 1]) * h
        d = c1 + s * (2.0 * c2 + s * (3.0 * c3 + s * (4.0 * c4 + s * 5.0 * c5)))
        if d == 0.0 or (sg != 0.0 and (d > 0.0) != (sg > 0.0)):
            return FIT_REJECTED
        sg = 1.0 if d > 0.0 else -1.0
        v_min = min(v_min, abs(d))
    return FIT_MONOTONE if err <= 0.5 * tol_t * v_min else FIT_REJECTED


@njit(cache=True, inline="always")
def _fit_still(cub):
    """True when the cubics ``cub`` do not move (no derivative term): the motor is still."""
    return (cub[1] == 0.0 and cub[2] == 0.0 and cub[3] == 0.0 and cub[5] == 0.0 and cub[6] == 0.0 and cub[7] == 0.0
            and cub[9] == 0.0 and cub[10] == 0.0 and cub[11] == 0.0)


@njit(cache=True, inline="always")
def _fit_mode(deg, code):
    """The stepping mode of a span fitted with degree ``deg`` and accepted as ``code``."""
    if deg <= 3:
        return FIT_CUBIC
    return FIT_QUINTIC_MONOTONE if code == FIT_MONOTONE else FIT_QUINTIC


@njit(cache=True, inline="always")
def _fit_piece_spans(cub, span, ik, period, ref, tol_t, round_rel, m, dd, out, mode, row):
    """Fit the piece of cubics ``cub`` (duration ``span``) whole, then in 2, 4, … sub-spans (IK_FIT_SPLITS halvings), coefficients and
    modes written from row ``row`` on: the number of accepted sub-spans, 0 when no level passed whole."""
    # the whole piece: first the toolhead's own degree (1 cruising, 2 accelerating, 3 with jerk), at which a
    # linear ik is exact and its steps take the linear kernel's closed forms (a = 0 exactly when cruising), then 5
    deg = 1
    if cub[3] != 0.0 or cub[7] != 0.0 or cub[11] != 0.0:
        deg = 3
    elif cub[2] != 0.0 or cub[6] != 0.0 or cub[10] != 0.0:
        deg = 2
    code = _fit_span(cub, ik, period, ref, 0.0, span, deg, tol_t, round_rel, m, dd, out, row)
    if code == FIT_REJECTED:
        deg = IK_FIT_DEG
        code = _fit_span(cub, ik, period, ref, 0.0, span, deg, tol_t, round_rel, m, dd, out, row)
    if code != FIT_REJECTED:
        mode[row] = _fit_mode(deg, code)
        return 1
    for lvl in range(1, IK_FIT_SPLITS + 1):
        n_sub = 1 << lvl
        ok = True
        for k in range(n_sub):
            s_lo = span * k / n_sub
            s_hi = span if k == n_sub - 1 else span * (k + 1) / n_sub
            code = _fit_span(cub, ik, period, ref, s_lo, s_hi - s_lo, IK_FIT_DEG, tol_t, round_rel,
                             m, dd, out, row + k)
            if code == FIT_REJECTED:
                ok = False
                break
            mode[row + k] = _fit_mode(IK_FIT_DEG, code)
        if ok:
            return n_sub
    return 0


@njit(cache=True, inline="always")
def _fit_same(a, b):
    """a and b the same float, bit for bit but for NaN (±0 told apart: an ik may take atan2 of them)."""
    return a == b and (a != 0.0 or math.copysign(1.0, a) == math.copysign(1.0, b))


@njit(cache=True, inline="always")
def _fit_end(cub, s):
    """x, y, z (mm) of the cubics ``cub`` at τ = s, as :func:`_fit_ik_at` computes them."""
    return (cub[0] + s * (cub[1] + s * (cub[2] + s * cub[3])), cub[4] + s * (cub[5] + s * (cub[6] + s * cub[7])),
            cub[8] + s * (cub[9] + s * (cub[10] + s * cub[11])))


@njit(cache=True, error_model="numpy")
def ik_fit_pieces(t0, dt, pc, vc, ac, jc, reset, ik, period, refs, tol_t, round_rel):
    """The verified polynomial stand-ins of a plug-in motor's pieces (section comment): for pieces with (n, ≥3)
    x, y, z columns ``pc vc ac jc`` (mm, mm/s, mm/s², mm/s³, the SEGMENT convention) from t0 (s) for dt (s), the
    bound ik ``ik(x, y, z)`` (mm or rad), a cyclic motor's ``period`` and branch references ``refs``
    (:func:`ik_branch_refs`), the step-time bound ``tol_t`` (s) and the rounding floor ``round_rel``.

    Returns (t0, dt, coef, mode, src, reset) of the fitted pieces: a piece is one FIT_EXACT row (left to the
    exact search: coef unused), one FIT_CUBIC / FIT_QUINTIC / FIT_QUINTIC_MONOTONE row, or 2^k rows of its sub-spans (the later ones
    with RESET_CONTINUE); coef (m, POLY_NCOEF) is the power basis in time from the row's start (mm, mm/s, …);
    src the original piece's index."""
    n = t0.shape[0]
    cap = n << IK_FIT_SPLITS
    o_t0 = np.empty(cap)
    o_dt = np.empty(cap)
    coef = np.empty((cap, POLY_NCOEF))     # every fitted row is written whole; a FIT_EXACT row's is not read
    mode = np.empty(cap, np.int8)
    src = np.empty(cap, np.int64)
    o_reset = np.empty(cap, np.uint8)
    m = np.empty(IK_FIT_DEG + 2)
    dd = np.empty(IK_FIT_DEG + 1)
    row = 0
    # where the last piece fitted whole ends (x, y, z mm) and the motor there: the next piece's start when it
    # starts there bit for bit (one ik call less; a NaN matches nothing)
    ex = ey = ez = em = math.nan
    for i in range(n):
        span = dt[i]
        fitted = 0
        finite = math.isfinite(span) and math.isfinite(t0[i])
        for q in range(3):
            finite = finite and math.isfinite(pc[i, q]) and math.isfinite(vc[i, q]) and math.isfinite(ac[i, q]) \
                and math.isfinite(jc[i, q])
        ref = math.nan
        if finite:
            cub = _fit_cubics(pc, vc, ac, jc, i)
            if period > 0.0:
                ref = refs[i]
            elif _fit_same(cub[0], ex) and _fit_same(cub[4], ey) and _fit_same(cub[8], ez):
                ref = em
            else:
                ref = ik(cub[0], cub[4], cub[8])
            ex = math.nan
            if not math.isfinite(ref):
                pass
            elif _fit_still(cub) or not (span > 0.0):
                coef[row, 0] = ref          # no motion (or no time): the start position, no step
                for q in range(1, POLY_NCOEF):
                    coef[row, q] = 0.0
                mode[row] = FIT_CUBIC
                fitted = 1
                ex, ey, ez = _fit_end(cub, span)
                em = ref
            else:
                fitted = _fit_piece_spans(cub, span, ik, period, ref, tol_t, round_rel, m, dd, coef, mode, row)
                if fitted == 1:
                    ex, ey, ez = _fit_end(cub, span)
                    em = m[IK_FIT_DEG + 1]
        else:
            ex = math.nan
        if fitted == 0:
            o_t0[row] = t0[i]
            o_dt[row] = span
            mode[row] = FIT_EXACT
            src[row] = i
            o_reset[row] = reset[i]
            row += 1
            continue
        for k in range(fitted):
            s_lo = span * k / fitted
            o_t0[row] = t0[i] + s_lo if k else t0[i]
            o_dt[row] = span - s_lo if k == fitted - 1 else span * (k + 1) / fitted - s_lo
            src[row] = i
            o_reset[row] = reset[i] if k == 0 else RESET_CONTINUE
            row += 1
    return o_t0[:row], o_dt[:row], coef[:row], mode[:row], src[:row], o_reset[:row]


@njit(cache=True, inline="always")
def _fit_piece(data, i):
    """:func:`step_pieces`'s ``piece_at`` for fitted pieces: data = (fitted coef, mode, src, and the exact search's
    data, :func:`_ik_piece`); the piece is (mode, six coefficients — p, v, a, j, 0, 0 of a FIT_CUBIC row for the
    linear kernel's functions, the power basis of a FIT_QUINTIC one — and the exact search's piece, whose fields
    are zero but for ik and period unless the row is FIT_EXACT). Floats only: no array reaches the step's calls."""
    coef, mode, src, ikdata = data
    md = mode[i]
    if md == FIT_EXACT:
        status, p, ikp = _ik_piece(ikdata, src[i])
        return status, p, (md, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, ikp)
    ik = ikdata[4]
    period = ikdata[5]
    ikp = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, ik, period, 0.0, 0.0, 0.0)
    c0 = coef[i, 0]
    c1 = coef[i, 1]
    c2 = coef[i, 2]
    c3 = coef[i, 3]
    c4 = coef[i, 4]
    c5 = coef[i, 5]
    status = PIECE_MOVING
    if c1 == 0.0 and c2 == 0.0 and c3 == 0.0 and c4 == 0.0 and c5 == 0.0:
        status = PIECE_STILL
    if md == FIT_CUBIC:
        return status, c0, (md, c0, c1, 2.0 * c2, 6.0 * c3, 0.0, 0.0, ikp)
    return status, c0, (md, c0, c1, c2, c3, c4, c5, ikp)


@njit(cache=True, inline="always")
def _quintic_at(piece, s):
    """Position of a FIT_QUINTIC piece at τ = s (Horner)."""
    return piece[1] + s * (piece[2] + s * (piece[3] + s * (piece[4] + s * (piece[5] + s * piece[6]))))


@njit(cache=True, inline="always")
def _quintic_speed(piece, s):
    """Derivative of a FIT_QUINTIC piece at τ = s."""
    return piece[2] + s * (2.0 * piece[3] + s * (3.0 * piece[4] + s * (4.0 * piece[5] + s * 5.0 * piece[6])))


@njit(cache=True, inline="always")
def _fit_position(piece, s):
    """Motor position of a fitted (or exact) piece at τ = s."""
    md = piece[0]
    if md == FIT_CUBIC:
        return _pos(piece[1], piece[2], piece[3], piece[4], s)
    if md == FIT_QUINTIC or md == FIT_QUINTIC_MONOTONE:
        return _quintic_at(piece, s)
    return _ik_position(piece[7], s)


@njit(cache=True, inline="always")
def _fit_turning_points(piece, span, bnd):
    """Where a fitted piece reverses: the velocity roots of a cubic, the derivative roots of a quintic
    (:func:`critical_points`), the exact search's for a FIT_EXACT piece."""
    md = piece[0]
    if md == FIT_CUBIC:
        return _velocity_roots_at(piece[2], piece[3], piece[4], span, bnd, 1)
    if md == FIT_QUINTIC_MONOTONE:
        return 0
    if md == FIT_QUINTIC:
        c = np.empty((1, POLY_NCOEF))
        c[0, 0] = piece[1]
        c[0, 1] = piece[2]
        c[0, 2] = piece[3]
        c[0, 3] = piece[4]
        c[0, 4] = piece[5]
        c[0, 5] = piece[6]
        deriv = np.empty((POLY_NCOEF, POLY_NCOEF))
        return critical_points(c, 0, span, deriv, bnd[1:])
    return _ik_turning_points(piece[7], span, bnd)


@njit(cache=True, inline="always")
def _fit_stretch(piece, lo, hi, sigma):
    """The crossing context of a monotone stretch, nine floats whatever the mode: the linear kernel's
    (:func:`_linear_stretch`), (last crossing, end, position at both, speed at the start) of a quintic, the exact search's (:func:`_ik_stretch`)."""
    md = piece[0]
    if md == FIT_CUBIC:
        a, b, c, d, e, f = _linear_stretch((piece[1], piece[2], piece[3], piece[4]), lo, hi, sigma)
        return (a, b, c, d, e, f, 0.0, 0.0, 0.0)
    if md == FIT_QUINTIC or md == FIT_QUINTIC_MONOTONE:
        return (lo, hi, _quintic_at(piece, lo), _quintic_at(piece, hi), _quintic_speed(piece, lo), 0.0, 0.0, 0.0,
                0.0)
    return _ik_stretch(piece[7], lo, hi, sigma)


@njit(cache=True, inline="always")
def _quintic_crossing(piece, ctx, target):
    """(τ, new ctx): where the monotone FIT_QUINTIC piece reaches ``target`` in [last crossing, stretch end].
    ctx = (last crossing, end, position at both, speed near the last crossing, …). Newton's method kept in the
    bracket, from the last crossing's tangent (no evaluation: the position there is its half-step level, the speed
    the last Newton step's), done when a step, or the error it leaves by its curvature, is under QUINTIC_DONE_S
    (quadratic convergence); the nearer end when rounding puts both ends on one side."""
    left = ctx[0]
    hi = ctx[1]
    f_lo = ctx[2] - target
    f_hi = ctx[3] - target
    d = ctx[4]
    if f_lo == 0.0:
        return left, ctx
    if f_hi == 0.0 or (f_lo > 0.0) == (f_hi > 0.0):
        tau = hi if abs(f_hi) <= abs(f_lo) else left
        return tau, (tau, hi, ctx[2], ctx[3], d, 0.0, 0.0, 0.0, 0.0)
    rising = f_hi > 0.0
    lo = left
    tau = left - f_lo / d if d != 0.0 else -1.0
    if not (lo < tau < hi):
        tau = lo + (hi - lo) * (-f_lo) / (f_hi - f_lo)
    t_prev = left
    d_prev = d
    for _ in range(100):
        f = _quintic_at(piece, tau) - target
        d = _quintic_speed(piece, tau)
        if f == 0.0:
            break
        lo, hi, nxt = _newton_in_bracket(tau, f, d, lo, hi, rising)
        step = abs(nxt - tau)
        # a Newton step δ leaves an error of about |p''/(2p')|·δ² (p'' from the last two speeds): taken at once
        # when that is under QUINTIC_DONE_S, as it is from the tangent guess at step rates (one evaluation)
        curve = abs(d - d_prev) / (abs(tau - t_prev) * abs(d)) if tau != t_prev and d != 0.0 else math.inf
        if step <= QUINTIC_DONE_S or 0.5 * curve * step * step <= QUINTIC_DONE_S \
                or hi - lo <= 1e-15 * (1.0 + abs(tau)):
            tau = nxt
            break
        t_prev = tau
        d_prev = d
        tau = nxt
    return tau, (tau, ctx[1], target, ctx[3], d, 0.0, 0.0, 0.0, 0.0)


@njit(cache=True, inline="always")
def _fit_crossing(piece, ctx, target, sigma, step_dist):
    """The next crossing of ``target`` by a fitted (or exact) piece: the linear kernel's for a cubic, bracketed
    Newton from the last crossing for a quintic, the exact search's guarded one for a FIT_EXACT piece."""
    md = piece[0]
    if md == FIT_CUBIC:
        tau, c = _linear_crossing((piece[1], piece[2], piece[3], piece[4]), (ctx[0], ctx[1], ctx[2], ctx[3],
                                                                            ctx[4], ctx[5]), target, sigma, step_dist)
        return tau, (c[0], c[1], c[2], c[3], c[4], c[5], 0.0, 0.0, 0.0)
    if md == FIT_QUINTIC or md == FIT_QUINTIC_MONOTONE:
        return _quintic_crossing(piece, ctx, target)
    return _ik_crossing(piece[7], ctx, target, sigma, step_dist)


@njit(cache=True, error_model="numpy")
def gen_steps_ik_fit(t0, dt, coef, mode, src, reset, pc, vc, ac, jc, ik, period, refs, ik_t0, ik_dt, step_dist,
                     state, start, out_t, out_dir, out_n):
    """:func:`gen_steps_ik` on the verified polynomial stand-ins of :func:`ik_fit_pieces` (its t0, dt, coef, mode,
    src, reset): fitted rows are stepped with no ik call, FIT_EXACT rows by the exact search on the original piece
    ``src`` of ``pc vc ac jc`` (from ``ik_t0`` for ``ik_dt``, s). Same grid, state and buffer contract; the piece
    index returned is a fitted row's."""
    ikdata = (pc, vc, ac, jc, ik, period, refs, ik_t0, ik_dt)
    return step_pieces(_fit_piece, _fit_position, _fit_turning_points, _fit_stretch, _fit_crossing,
                       (coef, mode, src, ikdata), IK_CHECK_SAMPLES, t0, dt, reset, step_dist, state, start, out_t,
                       out_dir, out_n)
