"""Blend mode: parabolic blends at corners under a path tolerance (G64 P).

Model (docs/design.md §7, the course notes' "parabolic fit"):
the toolhead follows each segment along its straight line; around the via point between move j−1 and
move j it leaves the line at speed v_c, changes its velocity vector from V_in = v_c·u_in to
V_out = v_c·u_out under the constant acceleration a = (V_out − V_in)/(2τ) for 2τ seconds, and joins the
next line at speed v_c. The parabola misses the via point by e = |ΔV|·τ/4.

Corner speed. With a toolhead acceleration limit A, per-axis limits A_ax and the tolerance P:

* τ is the least half-time the limits allow: τ = c·v_c with the corner constant
  c = max(k/(2A), max_ax |Δu_ax|/(2·A_ax)) s²/mm, k = |u_out − u_in| (XYZ). A shorter τ both saves time and
  lowers the deviation, so the least τ is the best one.
* deviation: e = |ΔV_xyz|·τ/4 = k·c·v_c²/4 ≤ P  →  v_c² ≤ 4P/(k·c)   (= 8AP/k² when the toolhead limit binds)
* the blend fits in half of each neighbour: v_c·τ = c·v_c² ≤ L/2  →  v_c² ≤ L/(2c)
* v_c ≤ both neighbours' cruise speeds (so every axis speed in the blend, a convex mix of two allowed
  velocities, is allowed too);
* a reversal (u_out = −u_in), a move that is not an XYZ move (extrude-only, dwell, wait), an exact-stop
  move (G61) and the first/last points stop.

Every bound above is linear in w = v_c² (mm²/s²), and so is the distance the blend takes from each
neighbour (c·w). The straight part of move i, between its two blend zones, is
S_i = L_i − c_i·w_i − c_{i+1}·w_{i+1}, and its trapezoid (acceleration A_i) can join the two corner speeds iff
|w_{i+1} − w_i| ≤ 2·A_i·S_i: still linear in (w_i, w_{i+1}). The passes use it in that form (see
:func:`blend_passes_kernel`).

Choice of corner speed: each corner starts at the largest v_c its bounds allow; the passes then lower
corner speeds until every straight part joins its two corners. When a side's straight part may accelerate more
than twice as hard as the blend (α = 2·A_i·c > 2: neighbours with different M204 accelerations, or a per-axis
limit such as a slow Z), a slow blend can lose more time than a stop (:func:`corner_loss`): such corners stop.
Known limit: when α > 1, a higher corner speed shortens the neighbour's straight part more than it helps it,
so the greedy "highest first" choice is not always the fastest; with one acceleration for the whole path and no
per-axis limits a larger tolerance was never slower (100 000 random comparisons), with per-move accelerations
drawn from 100–10 000 mm/s² it was up to 1.5 % slower in 0.15 % of 100 000 random comparisons.

Time attribution: a blend is split at its middle (the instant closest to the via point). Its first half
belongs to the incoming move, its second half to the outgoing move; so a move's PLAN row runs from the middle
of its first blend to the middle of its last one. PLAN.start_v / end_v are the corner speeds (where the
straight part begins and ends), accel_t / cruise_t / decel_t are those of the straight part, and
duration = τ_in + accel_t + cruise_t + decel_t + τ_out. SEGMENT rows of a blend carry PHASE_BLEND.

Streaming (bounded memory): the passes only ever lower corner speeds, and a corner whose cap is below the least
bound the moves after it can impose — a stop, or enough distance ahead to brake from its cap whatever comes
later (:func:`blend_settled_kernel`) — is never lowered from the right. Runs are split at such corners and
planned left to right (:func:`blend_runs_kernel`), in whole-program planning and in the streaming planner
alike, so a window ends at its last settled corner and the next window starts from that corner's final speed:
a run that never stops (a spiral vase) is held for a braking distance, not whole, and the two plans are
bit-identical.

The extruder axis E is part of the velocity vector (E per mm of path times the path speed): inside a blend
its rate moves linearly from the incoming ratio to the outgoing one, under the E acceleration limit if one
is set. With no E limit and collinear XYZ segments whose E ratios differ, E changes rate at once (τ = 0).
"""
from __future__ import annotations

import math

from .._jit import njit
import numpy as np

from ..errors import ConfigError, GcodeError
from ..schema import (
    KIND_DWELL,
    KIND_WAIT,
    LIMIT_ACCEL,
    LIMIT_JUNCTION,
    LIMIT_NONE,
    PHASE_ACCEL,
    PHASE_BLEND,
    PHASE_CRUISE,
    PHASE_DECEL,
    PHASE_DWELL,
    PLAN_DTYPE,
)
from .segments import segments_from_table

# Directions closer to opposite than this (cos of the turn > 1 − REVERSAL_COS) are a reversal: full stop.
REVERSAL_COS = 1e-12
# Relative change below which the passes have settled (see blend_passes_kernel).
SETTLE_RTOL = 1e-12


# --------------------------------------------------------------------------- kernels
@njit(cache=True)
def blend_corners_kernel(move_d, axes_r, xyz, stop_after, max_cruise_v2, path_a, toolhead_a, axis_a, tolerance):
    """Corner constants and corner-speed caps for the n+1 junctions of n moves.

    Junction j joins move j−1 to move j (junction 0 is the start, n the end: both at rest).
    Returns (corner_c, max_corner_v2): τ_j = corner_c[j]·v_j (s²/mm → s per mm/s), and the largest
    v_j² the deviation, half-segment and cruise bounds allow (module docstring).
    path_a: per-move acceleration of the straight part (mm/s²); toolhead_a: per-move toolhead accel (M204);
    axis_a: (n, 4) per-axis accel limits (inf = none); tolerance: per-move path tolerance P (mm); the corner
    uses the smaller of its two moves' P. A corner where blending at its cap loses more time than
    stopping (see :func:`corner_loss`) gets cap 0.
    """
    n = move_d.shape[0]
    corner_c = np.zeros(n + 1)
    max_corner_v2 = np.zeros(n + 1)
    for j in range(1, n):
        i_in = j - 1
        i_out = j
        if not xyz[i_in] or not xyz[i_out] or stop_after[i_in]:
            continue
        cos_turn = 0.0
        k2 = 0.0
        for ax in range(3):
            cos_turn += axes_r[i_in, ax] * axes_r[i_out, ax]
            du = axes_r[i_out, ax] - axes_r[i_in, ax]
            k2 += du * du
        if cos_turn < -1.0 + REVERSAL_COS:
            continue
        k = math.sqrt(k2)
        a_tool = min(toolhead_a[i_in], toolhead_a[i_out])
        c = 0.0
        if k > 0.0 and a_tool > 0.0 and a_tool < np.inf:
            c = k / (2.0 * a_tool)
        for ax in range(4):
            a_ax = min(axis_a[i_in, ax], axis_a[i_out, ax])
            du = abs(axes_r[i_out, ax] - axes_r[i_in, ax])
            if du > 0.0 and a_ax < np.inf:
                c = max(c, du / (2.0 * a_ax))
        cap = min(max_cruise_v2[i_in], max_cruise_v2[i_out])
        if c > 0.0:
            cap = min(cap, 0.5 * move_d[i_in] / c, 0.5 * move_d[i_out] / c)
            if k > 0.0:
                p = min(tolerance[i_in], tolerance[i_out])
                cap = min(cap, 4.0 * p / (k * c))
        cap = max(cap, 0.0)
        if cap > 0.0 and corner_loss(cap, c, move_d, max_cruise_v2, path_a, i_in, i_out) > \
                corner_loss(0.0, c, move_d, max_cruise_v2, path_a, i_in, i_out):
            cap = 0.0
        corner_c[j] = c
        max_corner_v2[j] = cap
    return corner_c, max_corner_v2


@njit(cache=True)
def corner_loss(corner_v2, c, move_d, max_cruise_v2, path_a, i_in, i_out):
    """Time lost at a corner taken at v = √corner_v2, against running its neighbours at their speed V (s).

    Per side, with the side's acceleration A and α = 2A·c: braking from V to v costs (V − v)²/(2AV) and the
    half-blend (time c·v over c·v² mm) costs c·v·(V − v)/V; together ((V − v)² + α·v·(V − v))/(2AV).
    This is concave in v for α > 1, so over [0, cap] its least value is at 0 or at the cap; for α ≤ 2 it
    decreases all the way and the cap wins. For α > 2 (the blend's acceleration, toolhead or per-axis, is
    less than half of what the straight part may use) a slow blend can lose more than a stop. V is the
    side's cruise speed, or √(A·L) when the side is too short to reach it (a stand-in for the unknown
    neighbours).
    """
    v = math.sqrt(corner_v2)
    loss = 0.0
    for side in range(2):
        i = i_in if side == 0 else i_out
        a = path_a[i]
        if not (a > 0.0 and a < np.inf):
            continue
        v_side = max(math.sqrt(min(max_cruise_v2[i], a * move_d[i])), v)
        if v_side <= 0.0:
            continue
        alpha = 2.0 * a * c
        loss += ((v_side - v) ** 2 + alpha * v * (v_side - v)) / (2.0 * a * v_side)
    return loss


@njit(cache=True)
def blend_passes_kernel(move_d, accel, corner_c, corner_v2, lo, hi, free_last):
    """Lower the corner speeds² of moves lo … hi−1 (in place) until every straight part can join its two corners.

    Move i joins w_a = corner_v2[i] to w_b = corner_v2[i+1] on S_i = L_i − c_i·w_a − c_{i+1}·w_b, which needs
    |w_b − w_a| ≤ 2·A_i·S_i. With α = 2A_i·c_i, β = 2A_i·c_{i+1}, D = 2A_i·L_i:
      (B) decelerating  w_a ≤ (D + (1 − β)·w_b)/(1 + α)   — the backward pass lowers w_a to this;
      (F) accelerating  w_b ≤ (D + (1 − α)·w_a)/(1 + β)   — the forward pass lowers w_b to this.
    Corner ``lo`` is fixed (a stop, or a corner already final: see :func:`blend_settled_kernel`); corner ``hi``
    is lowered by the forward pass only when ``free_last`` (a settled corner that nothing after it can lower),
    else it is a stop and stays 0.
    Termination: values only decrease and stay ≥ 0. The caps already keep each blend within half of its
    segments (c·w ≤ L/2), so S_i ≥ 0, and at the point where (F) is tight w_b − w_a = 2A_i·S_i ≥ 0, which
    leaves (B) true; lowering w_b never breaks move i+1's (B) (its start gets lower). So after one backward
    and one forward pass every (B) and (F) hold, and a second round changes nothing but rounding: the loop
    stops at the first round that moves no value by more than SETTLE_RTOL (at most a few rounds; bounded
    by 16 in any case).
    """
    for _ in range(16):
        changed = False
        for i in range(hi - 1, lo, -1):
            two_a = 2.0 * accel[i]
            bound = (two_a * move_d[i] + (1.0 - two_a * corner_c[i + 1]) * corner_v2[i + 1]) / (
                1.0 + two_a * corner_c[i])
            if bound < corner_v2[i]:
                if corner_v2[i] - max(bound, 0.0) > SETTLE_RTOL * corner_v2[i]:
                    changed = True
                corner_v2[i] = max(bound, 0.0)
        last = hi if free_last else hi - 1
        for i in range(lo, last):
            two_a = 2.0 * accel[i]
            bound = (two_a * move_d[i] + (1.0 - two_a * corner_c[i]) * corner_v2[i]) / (
                1.0 + two_a * corner_c[i + 1])
            if bound < corner_v2[i + 1]:
                if corner_v2[i + 1] - max(bound, 0.0) > SETTLE_RTOL * corner_v2[i + 1]:
                    changed = True
                corner_v2[i + 1] = max(bound, 0.0)
        if not changed:
            break
    return corner_v2


@njit(cache=True)
def blend_speeds_kernel(move_d, path_a, max_cruise_v2, corner_c, corner_v2, lo, hi, free_last):
    """Passes over moves lo … hi−1, then stop at corners the passes pushed into a losing blend (corner_loss);
    repeat. Corner ``hi`` is checked too when ``free_last`` (move hi must exist then).

    The passes can leave a corner below its cap, where a slow blend may lose more than a stop. Such
    corners are set to 0 and the passes rerun. Speeds only decrease and each corner flips to 0 at most
    once, so this ends after at most hi − lo + 1 rounds (in practice one or two).
    """
    for _ in range(hi - lo + 1):
        blend_passes_kernel(move_d, path_a, corner_c, corner_v2, lo, hi, free_last)
        flipped = False
        end = hi + 1 if free_last else hi
        for j in range(lo + 1, end):
            if corner_v2[j] > 0.0 and corner_c[j] > 0.0 and \
                    corner_loss(corner_v2[j], corner_c[j], move_d, max_cruise_v2, path_a, j - 1, j) > \
                    corner_loss(0.0, corner_c[j], move_d, max_cruise_v2, path_a, j - 1, j):
                corner_v2[j] = 0.0
                flipped = True
        if not flipped:
            break
    return corner_v2


# A settled corner's cap must stay below the least bound the moves after it can impose by this margin, so
# that no rounding of the passes could still lower it.
SETTLED_MARGIN = 1e-9


@njit(cache=True)
def blend_settled_kernel(move_d, path_a, corner_c, corner_v2, end_open):
    """Corners whose speed nothing after them can lower: the blend planner's look-ahead horizon.

    ``corner_v2`` holds the caps of corners 0 … m (before the passes). Corner m ends the program (speed 0)
    unless ``end_open``: then the window is part of a longer program and neither corner m's speed w nor its
    constant c is known; only c·w ≤ L/2 (the blend fits in half of the last move), so the last move's (B)
    bound is at least (2A·L − A·L)/(1 + α) whatever follows. Going backwards, [lo_j, hi_j] bounds what the passes
    from the right can leave at corner j: hi_j = cap_j and lo_j = min(cap_j, least (B) bound of move j over
    corner j+1's interval) — (B) is linear in w_{j+1}, so its least value is at an end of the interval.
    A corner whose cap stays below that least bound (SETTLED_MARGIN) is *settled*: the passes coming from
    the right never lower it, only the moves before it (forward pass) and its own loss test can, so the run
    can be split there and the part before it planned for good. A stop (cap 0) is settled too. A corner
    where the loss test may fire (a side with α = 2A·c > 2, :func:`corner_loss`) can become 0 whatever its
    bounds, so the corner before it sees [0, hi].

    The bounds only widen when less is known after the window (a wider interval at corner m), so a corner
    settled in a window is settled in the whole program, and every corner before a settled one gets the
    same bounds in both: the streaming planner and whole-program planning split runs at the same corners.
    Returns a bool array over the corners (0 and m False).
    """
    m = move_d.shape[0]
    settled = np.zeros(m + 1, np.bool_)
    lo = 0.0
    hi = 0.0
    for j in range(m - 1, 0, -1):
        cap = corner_v2[j]
        if not (cap > 0.0):
            settled[j] = True
            lo = 0.0
            hi = 0.0
            continue
        lo_next = lo
        c_next = corner_c[j + 1]
        if j + 1 < m and c_next > 0.0 and corner_v2[j + 1] > 0.0:
            for side in range(2):
                a_side = path_a[j + side]
                if a_side > 0.0 and a_side < np.inf and 2.0 * a_side * c_next > 2.0 - 1e-9:
                    lo_next = 0.0
        two_a = 2.0 * path_a[j]
        b_lo = (two_a * move_d[j] + (1.0 - two_a * c_next) * lo_next) / (1.0 + two_a * corner_c[j])
        b_hi = (two_a * move_d[j] + (1.0 - two_a * c_next) * hi) / (1.0 + two_a * corner_c[j])
        b_min = min(b_lo, b_hi)
        if end_open and j == m - 1:
            # D + (1 − β)·w ≥ D − A·L for any w ≥ 0 with c·w ≤ L/2; shaded by 1e-12 so that the bound the
            # whole program computes from the actual corner (another rounding of a larger number) is never below
            b_min = (0.5 * two_a * move_d[j]) / (1.0 + two_a * corner_c[j]) * (1.0 - 1e-12)
        if b_min >= cap * (1.0 + SETTLED_MARGIN):     # False for nan (an infinite acceleration)
            settled[j] = True
            lo = cap
        elif b_min > 0.0:
            lo = min(cap, b_min)
        else:
            lo = 0.0
        hi = cap
    return settled


@njit(cache=True)
def blend_runs_kernel(move_d, path_a, max_cruise_v2, corner_c, corner_v2, settled, j_end):
    """:func:`blend_speeds_kernel` on each run of moves between two settled corners before corner ``j_end``
    (stops — the ends, reversals, dwell/wait rows, extrude-only neighbours, exact stops, losing corners — and
    corners nothing after them can lower: :func:`blend_settled_kernel`), one run at a time, left to right.

    Corner 0 is fixed (0 at the start of the program, or the final speed of a settled corner before the
    window). Each run starts from the final speed of the corner that closed the run before it and ends at a
    stop or at a settled corner, which its own passes and loss test may still lower. Speeds only decrease
    and a settled corner is never lowered from the right, so the runs never reach back: planning them in
    turn is the same plan as planning the whole, and it is what lets the streaming planner emit a run as
    soon as the corner after it is settled, with the same rounding as the whole program.
    """
    m = move_d.shape[0]
    a = 0
    for j in range(1, j_end + 1):
        if j == j_end or settled[j]:
            free_last = j < m and corner_v2[j] > 0.0
            blend_speeds_kernel(move_d, path_a, max_cruise_v2, corner_c, corner_v2, a, j, free_last)
            a = j
    return corner_v2


@njit(cache=True)
def blend_timing_kernel(move_d, accel, max_cruise_v2, corner_c, corner_v2, dwell_t):
    """Per-move trapezoid on the straight part and the blend half-times around it.

    Returns an (n, 9) array: start_v, cruise_v, end_v, accel_t, cruise_t, decel_t, tau_in, tau_out, duration.
    Peak of the straight part (equal accel and decel, docs/design.md §3, trapezoid with v0, v1):
    v_p² = min(V², (w_a + w_b)/2 + A·S).
    """
    n = move_d.shape[0]
    out = np.zeros((n, 9))
    for i in range(n):
        if move_d[i] <= 0.0:
            out[i, 8] = dwell_t[i]
            continue
        a = accel[i]
        w_a = corner_v2[i]
        w_b = corner_v2[i + 1]
        v_a = math.sqrt(w_a)
        v_b = math.sqrt(w_b)
        tau_in = corner_c[i] * v_a
        tau_out = corner_c[i + 1] * v_b
        straight_d = max(move_d[i] - corner_c[i] * w_a - corner_c[i + 1] * w_b, 0.0)
        peak_v2 = min(max_cruise_v2[i], 0.5 * (w_a + w_b) + a * straight_d)
        peak_v2 = max(peak_v2, w_a, w_b)  # rounding only: the passes made both ends reachable
        v_p = math.sqrt(peak_v2)
        accel_t = (v_p - v_a) / a
        decel_t = (v_p - v_b) / a
        accel_d = (peak_v2 - w_a) / (2.0 * a)
        decel_d = (peak_v2 - w_b) / (2.0 * a)
        cruise_d = max(straight_d - accel_d - decel_d, 0.0)
        cruise_t = cruise_d / v_p if v_p > 0.0 else 0.0
        out[i, 0] = v_a
        out[i, 1] = v_p
        out[i, 2] = v_b
        out[i, 3] = accel_t
        out[i, 4] = cruise_t
        out[i, 5] = decel_t
        out[i, 6] = tau_in
        out[i, 7] = tau_out
        out[i, 8] = tau_in + accel_t + cruise_t + decel_t + tau_out
    return out


@njit(cache=True)
def _put(rows, k, t0, dt, p, v, a, move, phase, moves_out, phases_out):
    rows[k, 0] = t0
    rows[k, 1] = dt
    for ax in range(4):
        rows[k, 2 + ax] = p[ax]
        rows[k, 6 + ax] = v[ax]
        rows[k, 10 + ax] = a[ax]
    moves_out[k] = move
    phases_out[k] = phase


@njit(cache=True)
def blend_segments_kernel(p0, p1, move_d, axes_r, axes_before, accel, corner_c, timing, t_start, row_index,
                          first_move):
    """SEGMENT pieces (as a float table + move and phase columns) for the planned moves.

    p0, p1: (n, 4) start/end points (x, y, z, e); axes_r: (n + 1, 4) unit directions, the last one that of the
    move after the last (for its blend; any row when that corner is a stop); axes_before: (4,) the direction
    of the move before the first (a window that starts inside a run). Per move: second half of its first blend, accel,
    cruise, decel, first half of its last blend; pieces of zero duration are left out. A dwell/wait row
    (move_d = 0) gives one PHASE_DWELL piece at rest. Columns of the table: t0, dt, p(4), v(4), a(4).
    """
    n = p0.shape[0]
    count = 0
    for i in range(n):
        if move_d[i] <= 0.0:
            if timing[i, 8] > 0.0:
                count += 1
            continue
        for col in range(3, 8):
            if timing[i, col] > 0.0:
                count += 1
    rows = np.zeros((count, 14))
    moves_out = np.zeros(count, np.int64)
    phases_out = np.zeros(count, np.uint8)
    zero = np.zeros(4)
    p = np.zeros(4)
    v = np.zeros(4)
    acc = np.zeros(4)
    k = 0
    for i in range(n):
        t = t_start[i]
        move = first_move + row_index[i]
        v_a = timing[i, 0]
        v_p = timing[i, 1]
        v_b = timing[i, 2]
        accel_t = timing[i, 3]
        cruise_t = timing[i, 4]
        decel_t = timing[i, 5]
        tau_in = timing[i, 6]
        tau_out = timing[i, 7]
        if move_d[i] <= 0.0:
            if timing[i, 8] > 0.0:
                _put(rows, k, t, timing[i, 8], p0[i], zero, zero, move, PHASE_DWELL, moves_out, phases_out)
                k += 1
            continue
        if tau_in > 0.0:
            # second half of the blend around p0[i]: from its middle to the line of move i
            for ax in range(4):
                u_before = axes_before[ax] if i == 0 else axes_r[i - 1, ax]
                v_in = v_a * u_before
                v_out = v_a * axes_r[i, ax]
                # v·Δu, not v_out − v_in: on nearly collinear moves Δu is rounding noise and the difference
                # of the two products would carry v·u·ε into a τ of ~1e-19 s (accelerations above the limits)
                acc[ax] = v_a * (axes_r[i, ax] - u_before) / (2.0 * tau_in)
                p[ax] = p0[i, ax] + 0.5 * acc[ax] * tau_in * tau_in
                v[ax] = 0.5 * (v_in + v_out)
            _put(rows, k, t, tau_in, p, v, acc, move, PHASE_BLEND, moves_out, phases_out)
            k += 1
            t += tau_in
        d = corner_c[i] * v_a * v_a  # distance of the straight part's start from p0
        a = accel[i]
        for ax in range(4):
            p[ax] = p0[i, ax] + axes_r[i, ax] * d
        if accel_t > 0.0:
            for ax in range(4):
                v[ax] = v_a * axes_r[i, ax]
                acc[ax] = a * axes_r[i, ax]
            _put(rows, k, t, accel_t, p, v, acc, move, PHASE_ACCEL, moves_out, phases_out)
            k += 1
            t += accel_t
            d += 0.5 * (v_a + v_p) * accel_t
            for ax in range(4):
                p[ax] = p0[i, ax] + axes_r[i, ax] * d
        if cruise_t > 0.0:
            for ax in range(4):
                v[ax] = v_p * axes_r[i, ax]
            _put(rows, k, t, cruise_t, p, v, zero, move, PHASE_CRUISE, moves_out, phases_out)
            k += 1
            t += cruise_t
            d += v_p * cruise_t
            for ax in range(4):
                p[ax] = p0[i, ax] + axes_r[i, ax] * d
        if decel_t > 0.0:
            for ax in range(4):
                v[ax] = v_p * axes_r[i, ax]
                acc[ax] = -a * axes_r[i, ax]
            _put(rows, k, t, decel_t, p, v, acc, move, PHASE_DECEL, moves_out, phases_out)
            k += 1
            t += decel_t
        if tau_out > 0.0:
            # first half of the blend around p1[i]: from the line of move i to the blend's middle
            for ax in range(4):
                v_in = v_b * axes_r[i, ax]
                acc[ax] = v_b * (axes_r[i + 1, ax] - axes_r[i, ax]) / (2.0 * tau_out)
                p[ax] = p1[i, ax] - v_in * tau_out
                v[ax] = v_in
            _put(rows, k, t, tau_out, p, v, acc, move, PHASE_BLEND, moves_out, phases_out)
            k += 1
    return rows, moves_out, phases_out


# --------------------------------------------------------------------------- public API
def _tolerance(moves: np.ndarray, machine) -> np.ndarray:
    p = np.asarray(moves["blend_p"], dtype=np.float64)
    p = np.where(np.isnan(p), float(machine.blend_tolerance), p)
    bad = np.flatnonzero(~(p >= 0.0))
    if bad.size:
        row = int(bad[0])
        if np.isnan(moves["blend_p"][row]):
            raise ConfigError(f"blend_tolerance: must be >= 0 mm, got {machine.blend_tolerance!r}")
        line = int(moves["line"][row])
        raise GcodeError(f"G64 P (path tolerance) must be >= 0, got {float(p[row])!r}", line=line)
    return p


def blend_row_limits(moves: np.ndarray, limits: np.ndarray, machine):
    """(PREP rows, (n, 5) float array): per-row limits of the blend planner for MOVE rows, row by row (so that
    chunks of a program give the same values as the whole): the trapezoid planner's per-move limits and input
    checks, and per row the path tolerance P (mm) then the axis accelerations x, y, z, e (mm/s²)."""
    from .prepare import prepare

    moves = np.asarray(moves)
    limits = np.asarray(limits)
    tol = _tolerance(moves, machine)
    prep = prepare(moves, limits, machine, "exact-stop")     # refuses accelerations too small to plan with
    aux = np.empty((len(moves), 5))
    aux[:, 0] = tol
    lim_row = moves["limits"]
    for col, ax in enumerate("xyze"):
        aux[:, 1 + col] = limits["axis_a_" + ax][lim_row]
    return prep, aux


def _window_rows(moves, prep, aux):
    """The rows that take part and their per-row arrays (zero-length rows do not take part: prepare drops
    them, so the corner is taken between their neighbours; dwell and wait rows stay, as full stops)."""
    kind = moves["kind"]
    rows = np.flatnonzero(prep["is_move"] | (kind == KIND_DWELL) | (kind == KIND_WAIT))
    every = len(rows) == len(moves)
    sub = moves if every else moves[rows]
    prep = prep if every else prep[rows]
    aux = aux if every else aux[rows]
    axes_r = np.zeros((len(rows), 4))
    for col, ax in enumerate("xyze"):
        axes_r[:, col] = prep["axes_r_" + ax]
    return {
        "rows": rows,
        "move_d": np.ascontiguousarray(prep["move_d"], dtype=np.float64),
        "axes_r": axes_r,
        "max_cruise_v2": np.ascontiguousarray(prep["max_cruise_v2"], dtype=np.float64),
        "accel": np.ascontiguousarray(prep["accel"], dtype=np.float64),
        "cruise_limit": np.ascontiguousarray(prep["limit"]),
        "xyz": np.ascontiguousarray(prep["kinematic"] & prep["is_move"]),
        "exact_stop": np.ascontiguousarray(sub["exact_stop"].astype(np.bool_)),
        "toolhead_a": np.ascontiguousarray(sub["accel"], dtype=np.float64),
        "axis_a": np.ascontiguousarray(aux[:, 1:5]),
        "tolerance": np.ascontiguousarray(aux[:, 0]),
    }


_CORNER_INPUTS = ("move_d", "axes_r", "xyz", "exact_stop", "max_cruise_v2", "accel", "toolhead_a", "axis_a",
                  "tolerance")


def blend_window_corners(moves: np.ndarray, prep: np.ndarray, aux: np.ndarray, lazy: bool, head=None):
    """The rows that take part, their per-move arrays, the corner constants and corner speeds² of a window.

    ``head``: None when the window starts the program (or follows a stop); else what the previous window left
    (``ctx["head"]`` of :func:`blend_plan_window`): the taking-part row before this window's first one and
    the final speed² of the corner between them, which this window starts from. Returns
    (ml, corner_c, corner_v2, j_end, head): corners [0, j_end] are final and the rows before taking-part row
    j_end are final; ``lazy`` = False: the window ends the program, j_end = len(rows). Lazy: j_end is the
    last corner of the window that nothing after the window can lower (:func:`blend_settled_kernel`), 0 when
    there is none; ``head`` is what the next window needs (None when the program ends).
    """
    ml = _window_rows(moves, prep, aux)
    m = len(ml["rows"])
    if head is not None:
        # the corner between the previous window and this one: the same two rows, so the same constants
        ext = [np.concatenate([head[k], ml[k]]) for k in _CORNER_INPUTS]
        corner_c, corner_v2 = blend_corners_kernel(*ext)
        corner_c, corner_v2 = corner_c[1:], corner_v2[1:]
        corner_v2[0] = head["w"]
    else:
        corner_c, corner_v2 = blend_corners_kernel(*(ml[k] for k in _CORNER_INPUTS))
    settled = blend_settled_kernel(ml["move_d"], ml["accel"], corner_c, corner_v2, bool(lazy))
    if lazy:
        ends = np.flatnonzero(settled[1:m])
        j_end = int(ends[-1]) + 1 if ends.size else 0
    else:
        j_end = m
    blend_runs_kernel(ml["move_d"], ml["accel"], ml["max_cruise_v2"], corner_c, corner_v2, settled, j_end)
    new_head = head
    if lazy and j_end > 0:
        k = j_end - 1
        new_head = {key: ml[key][k:k + 1].copy() for key in _CORNER_INPUTS}
        new_head["w"] = float(corner_v2[j_end])
    elif not lazy:
        new_head = None
    return ml, corner_c, corner_v2, j_end, new_head


def _corners(moves: np.ndarray, limits: np.ndarray, machine):
    """Whole program: (ml, corner_c, corner_v2) with every corner settled."""
    prep, aux = blend_row_limits(moves, limits, machine)
    ml, corner_c, corner_v2, _, _ = blend_window_corners(np.asarray(moves), prep, aux, lazy=False)
    return ml, corner_c, corner_v2


def corner_geometry(moves: np.ndarray, limits: np.ndarray, machine):
    """(rows, corner_c, corner_v2): the rows that take part (zero-length rows do not) and, for the
    junctions between them, the corner constant and settled corner speed² after the passes.

    Junction j is the end of taking-part row j−1 (0 and len(rows) are the ends of the path); the blend
    there lasts 2·corner_c[j]·√corner_v2[j] s. Exposed for tests and plots.
    """
    ml, corner_c, corner_v2 = _corners(moves, limits, machine)
    return ml["rows"], corner_c, corner_v2


def blend_plan_window(moves: np.ndarray, prep: np.ndarray, aux: np.ndarray, t_clock: float, lazy: bool,
                      head=None):
    """Plan the final part of a window of rows (MOVE rows, their PREP and aux rows from
    :func:`blend_row_limits`) that starts at time ``t_clock``: at rest (``head`` None) or at the corner the
    previous window ended at (``head``: that window's ``ctx["head"]``).

    Returns (n_rows, plan, t_end, ctx): the first n_rows rows are final (all of them when ``lazy`` is False),
    their PLAN rows, the clock after them, and what :func:`blend_segments` needs to make their pieces;
    ``ctx["head"]`` is what the next window starts from (None after the end of the program).
    """
    n = len(moves)
    ml, corner_c, corner_v2, j_end, new_head = blend_window_corners(moves, prep, aux, lazy, head)
    rows = ml["rows"]
    m = len(rows)
    n_rows = n if j_end == m else int(rows[j_end])
    rows = rows[:j_end]
    move_d = ml["move_d"][:j_end]
    accel_m = ml["accel"][:j_end]
    max_cruise_v2 = ml["max_cruise_v2"][:j_end]
    corner_c = corner_c[:j_end + 1]
    corner_v2 = corner_v2[:j_end + 1]
    dwell_t = np.where(move_d > 0, 0.0, moves["dwell_t"][rows]).astype(np.float64)
    timing = blend_timing_kernel(move_d, accel_m, max_cruise_v2, corner_c, corner_v2, dwell_t)

    full = np.zeros((n_rows, 9))
    full[rows] = timing
    plan = np.zeros(n_rows, dtype=PLAN_DTYPE)
    duration = full[:, 8]
    clock = np.empty(n_rows + 1)
    clock[0] = t_clock
    clock[1:] = duration
    np.cumsum(clock, out=clock)  # sequential: every row starts where the previous one ends
    plan["t_start"] = clock[:-1]
    plan["start_v"], plan["cruise_v"], plan["end_v"] = full[:, 0], full[:, 1], full[:, 2]
    accel = np.zeros(n_rows)
    accel[rows] = np.where(move_d > 0, accel_m, 0.0)
    plan["accel"] = accel
    plan["decel"] = accel
    plan["accel_t"], plan["cruise_t"], plan["decel_t"] = full[:, 3], full[:, 4], full[:, 5]
    plan["duration"] = duration
    reached = timing[:, 1] >= np.sqrt(max_cruise_v2) * (1.0 - 1e-9)
    pinned = timing[:, 1] <= np.maximum(timing[:, 0], timing[:, 2]) * (1.0 + 1e-12)
    limit = np.full(n_rows, LIMIT_NONE, dtype=np.uint8)
    limit[rows] = np.where(move_d <= 0, LIMIT_NONE,
                           np.where(reached, ml["cruise_limit"][:j_end],
                                    np.where(pinned, LIMIT_JUNCTION, LIMIT_ACCEL)))
    plan["limit"] = limit
    plan["jerk"] = 0.0
    axes_before = head["axes_r"][0] if head is not None else np.zeros(4)
    ctx = {"rows": rows, "move_d": move_d, "axes_r": ml["axes_r"][:j_end + 1], "axes_before": axes_before,
           "accel": accel_m, "corner_c": corner_c, "timing": timing, "head": new_head}
    return n_rows, plan, float(clock[-1]), ctx


def blend_segments(moves: np.ndarray, plan: np.ndarray, ctx: dict, first_move: int = 0) -> np.ndarray:
    """SEGMENT rows of rows planned by :func:`blend_plan_window` (``ctx`` is its last result); SEGMENT.move =
    first_move + row index."""
    rows = ctx["rows"]
    sub = moves[rows]
    p0 = np.zeros((len(rows), 4))
    p1 = np.zeros((len(rows), 4))
    for col, ax in enumerate("xyze"):
        p0[:, col] = sub[ax + "0"]
        p1[:, col] = sub[ax + "1"]
    axes_r = ctx["axes_r"]
    if len(axes_r) == len(rows):      # the window ends the program: the corner after the last move is a stop
        axes_r = np.concatenate([axes_r, np.zeros((1, 4))])
    seg_rows, seg_move, seg_phase = blend_segments_kernel(
        p0, p1, ctx["move_d"], np.ascontiguousarray(axes_r), np.ascontiguousarray(ctx["axes_before"], np.float64),
        ctx["accel"], ctx["corner_c"], ctx["timing"],
        np.ascontiguousarray(plan["t_start"][rows]), np.ascontiguousarray(rows.astype(np.int64)),
        int(first_move))
    return segments_from_table(seg_rows, seg_move, seg_phase)


def plan_blend(moves: np.ndarray, limits: np.ndarray, machine, first_move: int = 0):
    """Plan ``moves`` with parabolic corner blends under the path tolerance (G64 P).

    Returns (PLAN rows aligned with ``moves``, SEGMENT rows). t_start counts from the start of the first
    move; SEGMENT.move is ``first_move`` + the row index. The path starts and ends at rest; so does every
    dwell/wait row and every exact-stop (G61) move. Bad input raises GcodeError / ConfigError. The streaming
    planner (:class:`gcodeplan.planner.stream.StreamPlanner`) gives the same rows bit for bit.
    """
    moves = np.asarray(moves)
    prep, aux = blend_row_limits(moves, limits, machine)
    n_rows, plan, _, ctx = blend_plan_window(moves, prep, aux, 0.0, lazy=False)
    assert n_rows == len(moves)
    return plan, blend_segments(moves, plan, ctx, first_move)
