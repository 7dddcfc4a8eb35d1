"""The Marlin model without quantisation (``MarlinModel(..., quantised=False)``): Marlin 2.1.2's plan in
continuous time and float64.

What stays Marlin's (the firmware's plan, not its arithmetic): the ring of ``buffer_blocks`` blocks and its host
loop (the buffer fills at once, a block leaves when the stepper picks the next one, waits drain it, a G92 with
blocks queued takes a slot); SLOWDOWN (a finite buffer only: :func:`gcodeplan.planner.marlin_kernels.new_state`);
the feed floors, the per-axis M203 speed and M201 acceleration limits, M204 P/T/R by the move's class and linear
advance's acceleration cap; the junction speed cap by Marlin's own rule, classic jerk or junction deviation (the
functions of :mod:`gcodeplan.planner.marlin_kernels`, in its float32, fed the float64 move rounded to float32);
MINIMUM_PLANNER_SPEED (0.05 mm/s) as the exit of the newest block and the entry of a block queued behind an empty
buffer (planner.cpp: that block is ``block_buffer_planned``, which no pass changes); the block the stepper runs
and the block after it are frozen.

What it turns off: whole-step targets and ``MIN_STEPS_PER_SEGMENT`` (a block is any move whose deltas are not all
0; its length and speeds from the float64 deltas of its MOVE row); float32 and integer arithmetic (rates,
ceil/floor of step counts, uint32 acceleration, M201 as whole mm/s²); the 120 steps/s floor; the stepper
interrupt, its 25 MHz timer and its 1 ms idle poll (a dwell lasts its own time). The look-ahead is the
textbook one over the queued blocks (the two passes of docs/design.md §1, "Data flow"): backward,
v_entry² ≤ v_next² + 2·a·d within the junction cap, then forward, v_entry² ≤ v_prev² + 2·a·d; a block's time is its
trapezoid's, in closed form. Equal to 2.1.2's passes in exact arithmetic: adding blocks only relaxes the stop at
the end of the queue, so the entries Marlin's ``block_buffer_planned`` skips can no longer rise.
"""
from __future__ import annotations

import math

import numpy as np

from .._jit import njit
from ..profiles.trapezoid import block_trapezoid_kernel
from ..schema import KIND_DWELL, KIND_EXTRUDE_ONLY, KIND_WAIT, LIMIT_ACCEL, LIMIT_FEED, LIMIT_NONE
from . import marlin_kernels as mk

F32 = np.float32
#: mm²/s², planner.cpp MINIMUM_PLANNER_SPEED (0.05 mm/s) squared
MIN_PLANNER_SQR = 0.05 * 0.05
# float64 block fields (rf[slot, ...]); integer block fields (ri[slot, ...])
RF_MM, RF_NOMINAL, RF_ACCEL, RF_MAX_ENTRY_SQR, RF_ENTRY_SQR = range(5)
N_RF = 5
RI_FLAG, RI_ROW = 0, 1
N_RI = 2
FLAG_SYNC, FLAG_FROZEN = 1, 2
# float64 global state (gd[...]): the clock (s from the first pick-up), 1 when blocks came since the last passes
GD_CLOCK, GD_DIRTY = 0, 1
N_GD = 2
# per-row outputs (out_t[row, ...]): 1 block / 2 wait, pick-up and end (s), entry, cruise and exit speed (mm/s),
# acceleration (mm/s²), phase times (s), length (mm), junction cap (mm²/s²), nominal speed (mm/s)
(OT_HAS, OT_T_PICK, OT_T_END, OT_V0, OT_VC, OT_V1, OT_ACCEL, OT_TA, OT_TC, OT_TD, OT_MM, OT_MAX_ENTRY_SQR,
 OT_NOMINAL) = range(13)
N_OT = 13
#: the window's extra per-row arrays in this mode (MarlinModel._row_arrays): name, dtype, shape of one row
WINDOW = (("d", np.float64, (4,)), ("fr64", np.float64, ()), ("acc64", np.float64, (3,)),
          ("dwell64", np.float64, ()), ("out_t", np.float64, (N_OT,)))


def new_state(buffer_blocks):
    """(rf, ri, gi, gf, gd): an empty ring of ``buffer_blocks`` slots (None: unbounded, grown by
    :func:`gcodeplan.planner.marlin_kernels.grow_ring`), the stepper idle; ``gi``/``gf`` in the layout of
    :func:`gcodeplan.planner.marlin_kernels.new_state` (the junction rules keep their state there)."""
    _, _, gi, gf = mk.new_state(buffer_blocks)
    size = mk.BLOCK_BUFFER_SIZE if buffer_blocks is None else int(buffer_blocks)
    return (np.zeros((size, N_RF)), np.zeros((size, N_RI), np.int64), gi, gf, np.zeros(N_GD))


@njit(cache=True)
def ideal_row_inputs_kernel(kind, x0, y0, z0, e0, x1, y1, z1, e1, feed_v, accel, dwell_t, acc_carry, d, fr, acc,
                            dwell):
    """Per MOVE row, what the continuous model is handed (out): ``d`` the X/Y/Z/E deltas (mm, float64, machine
    E: a G92 E does not break a move), ``fr`` the feed (mm/s; an absurd or infinite F as 1e9 mm/min, as
    :func:`gcodeplan.planner.marlin.row_inputs_kernel`), ``acc`` the M204 P / T / R in force (mm/s², each the
    accel of the last row of its class, ``acc_carry`` (3, in/out) before the batch), ``dwell`` (s, NaN as 0)."""
    for r in range(len(kind)):
        k = kind[r]
        d[r, 0] = x1[r] - x0[r]
        d[r, 1] = y1[r] - y0[r]
        d[r, 2] = z1[r] - z0[r]
        d[r, 3] = e1[r] - e0[r]
        fv = feed_v[r]
        fr[r] = min(fv * 60.0, 1e9) / 60.0 if np.isfinite(fv) else 1e9 / 60.0
        dw = dwell_t[r]
        dwell[r] = dw if dw == dw else 0.0
        if k != KIND_WAIT and k != KIND_DWELL and np.isfinite(accel[r]):
            c = 2 if k == KIND_EXTRUDE_ONLY else (0 if e1[r] != e0[r] else 1)
            acc_carry[c] = accel[r]
        for c in range(3):
            acc[r, c] = acc_carry[c]


@njit(cache=True)
def move_accel(dm, mm, acc, amax, advance_k, e_jerk):
    """A block's acceleration (mm/s²): M204 R for E alone, P with E, T without (``acc``: P, T, R), capped by
    linear advance (E jerk / (K · e/D), planner.cpp ``use_advance_lead``, e/D ≤ 3) and so that no motor's share
    ``|dm[a]| / mm`` exceeds its M201 limit ``amax[a]`` (planner.cpp LIMIT_ACCEL_*, in mm instead of steps)."""
    xyz = math.sqrt(dm[0] * dm[0] + dm[1] * dm[1] + dm[2] * dm[2])
    if dm[0] == 0 and dm[1] == 0 and dm[2] == 0:
        a = acc[2]
    else:
        a = acc[0] if dm[3] != 0 else acc[1]
    if advance_k > 0 and dm[3] > 0 and xyz > 0:
        e_d = dm[3] / xyz
        if not e_d > 3.0:
            a = min(a, e_jerk / (advance_k * e_d))
    for k in range(4):
        if dm[k] != 0:
            a = min(a, amax[k] * mm / abs(dm[k]))
    return a


@njit(cache=True)
def _nominal(dm, mm, fr, moves_queued, slowdown_max, min_segment_time_us, vmax, cs):
    """_populate_block's nominal speed (mm/s) in continuous time: 1 / segment time from the feed, SLOWDOWN (2 …
    ``slowdown_max`` blocks queued: a segment under MIN_SEGMENT_TIME is slowed by twice its shortfall over the
    blocks queued), then every motor within its M203 ``vmax``; ``cs`` (out) the motors' speeds (mm/s)."""
    inverse_secs = fr / mm
    if moves_queued >= 2 and moves_queued <= slowdown_max:
        seg_us = 1e6 / inverse_secs
        if min_segment_time_us > seg_us:
            inverse_secs = 1e6 / (seg_us + 2.0 * (min_segment_time_us - seg_us) / moves_queued)
    factor = 1.0
    for k in range(4):
        cs[k] = dm[k] * inverse_secs
        if abs(cs[k]) > vmax[k]:
            factor = min(factor, vmax[k] / abs(cs[k]))
    for k in range(4):
        cs[k] *= factor
    return mm * inverse_secs * factor


@njit(cache=True)
def populate_ideal(rf, ri, gi, gf, row, d, fr, acc, vmax, amax, amax32, jerk, min_feed, min_travel, jdev,
                   advance_k, min_segment_time_us, junction_mode, scratch_f, scratch32):
    """Queue the move of ``row`` (deltas ``d``, mm) at the ring's head; False (no block) when nothing moves.
    Motor deltas on a Core build (A = X + Y, B = X − Y; or X + Z, X − Z); the length is the head's (E's alone
    without X/Y/Z); the junction cap by the build's rule as Marlin computes it (float32)."""
    dm = scratch_f[0]
    for k in range(4):
        dm[k] = d[k]
    if d[0] == 0 and d[1] == 0 and d[2] == 0 and d[3] == 0:
        return False
    core = gi[mk.GI_CORE]
    if core == mk.CORE_XY:
        dm[0], dm[1] = d[0] + d[1], d[0] - d[1]
    elif core == mk.CORE_XZ:
        dm[0], dm[2] = d[0] + d[2], d[0] - d[2]
    mm = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
    if mm == 0:
        mm = abs(d[3])
    fr_min = min_feed if d[3] != 0 else min_travel
    moves_queued = mk._nonbusy_queued(ri, gi)
    cs = scratch_f[1]
    nominal = _nominal(dm, mm, max(fr, fr_min), moves_queued, gi[mk.GI_SLOWDOWN_MAX], min_segment_time_us, vmax,
                       cs)
    accel = move_accel(dm, mm, acc, amax, advance_k, jerk[3])
    # Marlin's junction rule, its own function in its float32 (its state in gf: the previous move's speeds)
    s32 = scratch32[0]
    v32 = scratch32[1]
    for k in range(4):
        s32[k] = F32(cs[k])
        v32[k] = F32(dm[k])
    if junction_mode == mk.JUNCTION_DEVIATION:
        cap = mk._junction_deviation_sqr(gf, v32, F32(1.0 / mm), 1 if d[3] != 0 else 0, F32(mm), F32(accel),
                                         F32(nominal), moves_queued, amax32, jdev, scratch32[4:], F32(MIN_PLANNER_SQR),
                                         F32(0), core)
    else:
        cap = mk._classic_jerk_sqr(gf, s32, F32(nominal), moves_queued, jerk)
    for k in range(4):
        gf[mk.GF_PREV_SPEED + k] = s32[k]
    gf[mk.GF_PREV_NOMINAL] = F32(nominal)
    h = gi[mk.GI_HEAD]
    rf[h, RF_MM] = mm
    rf[h, RF_NOMINAL] = nominal
    rf[h, RF_ACCEL] = accel
    rf[h, RF_MAX_ENTRY_SQR] = np.float64(cap)
    rf[h, RF_ENTRY_SQR] = MIN_PLANNER_SQR
    # behind an empty buffer the block is block_buffer_planned: no pass changes its entry (planner.cpp)
    ri[h, RI_FLAG] = FLAG_FROZEN if moves_queued == 0 else 0
    ri[h, RI_ROW] = row
    return True


@njit(cache=True)
def lookahead_passes(rf, ri, gi):
    """The textbook look-ahead over the queued blocks after the running one: backward from the newest (exit at
    MINIMUM_PLANNER_SPEED) v² = min(cap, v_next² + 2·a·d), a frozen block kept; then forward from the oldest,
    v² ≤ v_prev² + 2·a·d. Sync blocks are skipped."""
    first = mk._next(ri, gi[mk.GI_TAIL]) if gi[mk.GI_BUSY] != 0 else gi[mk.GI_TAIL]
    head = gi[mk.GI_HEAD]
    if first == head:
        return
    nxt_sqr = MIN_PLANNER_SQR
    idx = head
    while idx != first:
        idx = mk._prev(ri, idx)
        if ri[idx, RI_FLAG] & FLAG_SYNC:
            continue
        if ri[idx, RI_FLAG] & FLAG_FROZEN:
            break
        rf[idx, RF_ENTRY_SQR] = min(rf[idx, RF_MAX_ENTRY_SQR],
                                    nxt_sqr + 2.0 * rf[idx, RF_ACCEL] * rf[idx, RF_MM])
        nxt_sqr = rf[idx, RF_ENTRY_SQR]
    prv = -1
    idx = first
    while idx != head:
        if ri[idx, RI_FLAG] & FLAG_SYNC == 0:
            if prv >= 0 and ri[idx, RI_FLAG] & FLAG_FROZEN == 0:
                reach = rf[prv, RF_ENTRY_SQR] + 2.0 * rf[prv, RF_ACCEL] * rf[prv, RF_MM]
                if reach < rf[idx, RF_ENTRY_SQR]:
                    rf[idx, RF_ENTRY_SQR] = reach
            prv = idx
        idx = mk._next(ri, idx)


@njit(cache=True)
def pick_and_run_ideal(rf, ri, gi, gd, out_t, row_base, ph):
    """The stepper: finish the running block, skip sync blocks, take the next one and run its trapezoid from its
    entry to the next block's (the newest: MINIMUM_PLANNER_SPEED), after the look-ahead passes when blocks came
    since the last; the next block is then frozen (its entry is this one's exit). False when the buffer is
    empty."""
    if gi[mk.GI_BUSY] != 0:
        gi[mk.GI_TAIL] = mk._next(ri, gi[mk.GI_TAIL])
        gi[mk.GI_BUSY] = 0
    while mk._queued(ri, gi) > 0:
        t = gi[mk.GI_TAIL]
        if ri[t, RI_FLAG] & FLAG_SYNC:
            gi[mk.GI_TAIL] = mk._next(ri, t)
            continue
        if gd[GD_DIRTY] != 0:
            lookahead_passes(rf, ri, gi)
            gd[GD_DIRTY] = 0
        gi[mk.GI_BUSY] = 1
        gi[mk.GI_STARTED] = 1
        exit_sqr = MIN_PLANNER_SQR
        idx = mk._next(ri, t)
        while idx != gi[mk.GI_HEAD]:
            if ri[idx, RI_FLAG] & FLAG_SYNC == 0:
                exit_sqr = rf[idx, RF_ENTRY_SQR]
                ri[idx, RI_FLAG] |= FLAG_FROZEN
                break
            idx = mk._next(ri, idx)
        block_trapezoid_kernel(rf[t, RF_ENTRY_SQR], exit_sqr, rf[t, RF_NOMINAL], rf[t, RF_ACCEL], rf[t, RF_MM], ph)
        r = ri[t, RI_ROW] - row_base
        out_t[r, OT_HAS] = 1
        out_t[r, OT_T_PICK] = gd[GD_CLOCK]
        gd[GD_CLOCK] += ph[3] + ph[4] + ph[5]
        out_t[r, OT_T_END] = gd[GD_CLOCK]
        for k in range(6):
            out_t[r, OT_V0 + (k if k < 3 else k + 1)] = ph[k]
        out_t[r, OT_ACCEL] = rf[t, RF_ACCEL]
        out_t[r, OT_MM] = rf[t, RF_MM]
        out_t[r, OT_MAX_ENTRY_SQR] = rf[t, RF_MAX_ENTRY_SQR]
        out_t[r, OT_NOMINAL] = rf[t, RF_NOMINAL]
        return True
    return False


@njit(cache=True)
def ideal_run_kernel(kind, d, fr, acc, dwell, reset_bits, lim, vmax, amax, amax32, jerk, min_feed, min_travel, jdev,
                     advance_k, min_segment_time_us, junction_mode, final, row_base, rf, ri, gi, gf, gd, out_t,
                     scratch_f, scratch32):
    """:func:`gcodeplan.planner.marlin_kernels.marlin_run_kernel`'s host loop and stepper over the continuous
    blocks: rows ``gi[GI_NEXT_ROW] - row_base ..`` until the input runs out (``final``: until the buffer is
    empty); ``lim`` indexes the per-LIMITS-row tables ``vmax`` … ``advance_k`` (float64; ``amax32``, ``jerk``,
    ``jdev`` float32 for Marlin's junction rules). Times are s from the first pick-up in ``out_t``. Returns the
    absolute number of the first row whose block has not run yet."""
    n = len(kind)
    end_row = row_base + n
    ph = np.zeros(6)
    while True:
        while gi[mk.GI_NEXT_ROW] < end_row and mk._queued(ri, gi) < len(ri) - 1:
            r = gi[mk.GI_NEXT_ROW] - row_base
            k = kind[r]
            if k == mk.ROW_WAIT:
                if mk._queued(ri, gi) > 0 or gi[mk.GI_BUSY] != 0:
                    break                      # M400 / G4 / G28: wait for the buffer to drain
                out_t[r, OT_HAS] = 2
                out_t[r, OT_T_PICK] = gd[GD_CLOCK]
                if gi[mk.GI_STARTED] != 0:
                    gd[GD_CLOCK] += dwell[r]   # no 1 ms idle poll: the dwell's own time
                out_t[r, OT_T_END] = gd[GD_CLOCK]
                gi[mk.GI_NEXT_ROW] += 1
                continue
            if k == mk.ROW_SKIP:
                gi[mk.GI_NEXT_ROW] += 1
                continue
            if reset_bits[r] != 0 and gi[mk.GI_RESET_DONE] == 0:
                gi[mk.GI_RESET_DONE] = 1
                if mk._queued(ri, gi) > 0 or gi[mk.GI_BUSY] != 0:
                    h = gi[mk.GI_HEAD]         # G92 behind queued blocks: a sync block takes a slot
                    ri[h, RI_FLAG] = FLAG_SYNC
                    ri[h, RI_ROW] = gi[mk.GI_NEXT_ROW]
                    gi[mk.GI_HEAD] = mk._next(ri, h)
                    continue
            gi[mk.GI_RESET_DONE] = 0
            L = lim[r]
            if populate_ideal(rf, ri, gi, gf, gi[mk.GI_NEXT_ROW], d[r], fr[r], acc[r], vmax[L], amax[L], amax32[L],
                              jerk[L], min_feed[L], min_travel[L], jdev[L], advance_k[L], min_segment_time_us,
                              junction_mode, scratch_f, scratch32):
                gi[mk.GI_HEAD] = mk._next(ri, gi[mk.GI_HEAD])
                gd[GD_DIRTY] = 1
            gi[mk.GI_NEXT_ROW] += 1
        if not final and gi[mk.GI_NEXT_ROW] >= end_row and mk._queued(ri, gi) < len(ri) - 1:
            break                              # the host would queue more: wait for the next rows
        if not pick_and_run_ideal(rf, ri, gi, gd, out_t, row_base, ph):
            if gi[mk.GI_NEXT_ROW] >= end_row:
                break
    first = gi[mk.GI_NEXT_ROW]
    t = gi[mk.GI_TAIL]
    if gi[mk.GI_BUSY] != 0:
        t = mk._next(ri, t)
    while t != gi[mk.GI_HEAD]:
        if ri[t, RI_ROW] < first:
            first = ri[t, RI_ROW]
        t = mk._next(ri, t)
    return first


@njit(cache=True)
def ideal_plan_rows_kernel(out_t, move_d, kind, last, t_start, duration, start_v, cruise_v, end_v, accel, decel,
                           accel_t, cruise_t, decel_t, limit):
    """PLAN fields of settled rows from ``out_t``: a block's pick-up, duration and trapezoid, the cruise speed
    refitted so the row's ``move_d`` (mm) is covered in its phase times (the head's length; E's alone for an
    E-only move, as the block's). A row without a block lasts 0 s at the end of the last timed row at the exit
    speed of the block before it (``last``: that end (s) and speed (mm/s), in/out; at rest after a wait)."""
    for r in range(len(move_d)):
        hb = out_t[r, OT_HAS]
        wait = kind[r] == KIND_WAIT or kind[r] == KIND_DWELL
        if hb != 0:
            t_start[r] = out_t[r, OT_T_PICK]
            duration[r] = out_t[r, OT_T_END] - out_t[r, OT_T_PICK]
            last[0] = out_t[r, OT_T_END]
        else:
            t_start[r] = last[0]
            duration[r] = 0.0
        if hb == 1:
            v0, v1 = out_t[r, OT_V0], out_t[r, OT_V1]
            ta, tc, td = out_t[r, OT_TA], out_t[r, OT_TC], out_t[r, OT_TD]
            den = ta / 2 + tc + td / 2
            vc = max((move_d[r] - v0 * ta / 2 - v1 * td / 2) / den, 0.0) if den > 0 else 0.0
            start_v[r], cruise_v[r], end_v[r] = v0, vc, v1
            accel_t[r], cruise_t[r], decel_t[r] = ta, tc, td
            accel[r] = (vc - v0) / ta if ta > 0 else 0.0
            decel[r] = (vc - v1) / td if td > 0 else 0.0
            last[1] = v1
        elif wait:
            last[1] = 0.0
        else:
            start_v[r] = cruise_v[r] = end_v[r] = last[1]
        limit[r] = LIMIT_NONE if wait else (LIMIT_ACCEL if out_t[r, OT_TA] > 0 else LIMIT_FEED)
