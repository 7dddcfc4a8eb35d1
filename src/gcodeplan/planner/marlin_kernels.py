"""Marlin 2.1.2's (and bugfix-2.1.x's) planner as it runs, in numba: block buffer, look-ahead passes, trapezoids,
and its stepper.

The functions keep the names and boundaries of Marlin's ``planner.cpp`` (``_populate_block``,
``reverse_pass_kernel``, ``reverse_pass``, ``forward_pass_kernel``, ``forward_pass``,
``recalculate_trapezoids``, ``recalculate``, ``calculate_trapezoid_for_block``, ``get_current_block``) so the
model can be compared with the firmware's next release function by function. Arithmetic is float32 where
the firmware's is ``float`` and integer where it is ``uint32_t``/``int32_t``: the step counts, rates and
step boundaries come out as Marlin's, and so do the step times (:mod:`gcodeplan.stepper.marlin_isr`).

What it models (docs/design.md, "Marlin 2.1.2 model"):

* the ring buffer of ``BLOCK_BUFFER_SIZE`` (16) blocks, 15 usable (another power of 2 by the ring arrays' size,
  :func:`new_state`; unbounded, grown by :func:`grow_ring`); the block the stepper runs is frozen
  (``is_block_busy``); the reverse and forward passes run over the queued blocks from
  ``block_buffer_planned``, Marlin's "already optimal" pointer, so the look-ahead is what the buffer holds;
* the host of the reference runs: Marlin's main loop takes no time, so the buffer is refilled as soon as a
  block leaves; a position change (G92) with blocks queued takes a slot as a sync block;
* ``_populate_block``: targets in whole steps (``lround(mm · steps/mm)``), moves under
  ``MIN_STEPS_PER_SEGMENT`` (6) steps dropped and carried into the next, distance from the step deltas,
  ``SLOWDOWN`` (``MIN_SEGMENT_TIME`` 20 ms when 2..7 blocks are queued), per-axis feed limits, acceleration
  in steps/s² limited per axis (integer or float rule by ``acceleration_long_cutoff``), classic jerk with
  the Průša safe-speed rule and the coasting / reversal jerk, ``MINIMUM_PLANNER_SPEED``;
* ``calculate_trapezoid_for_block``: rates rounded up, the 120 steps/s floor, integer step boundaries.

bugfix-2.1.x as of 2024-07-30 (``VERSION_BUGFIX``, the ``marlin-bugfix`` model) has parallel functions where
its rule changed (``*_bugfix``: ``calculate_trapezoid_for_block_bugfix``, ``reverse_pass_kernel_bugfix``,
``reverse_pass_bugfix``, ``forward_pass_kernel_bugfix``, ``recalculate_trapezoids_bugfix``,
``recalculate_bugfix``, ``_classic_jerk_sqr_bugfix``, and ``block_ticks_kernel_bugfix`` in the stepper) and a
version switch inside ``_populate_block``, ``_pick_and_run`` and ``marlin_run_kernel``:

* a block starts and stops at v² = a / (2 · steps/mm) (``minimum_planner_speed_sqr``, the average speed over one
  step accelerating from rest: √(a/2) steps/s), also the floor of every junction speed and of the forward pass;
* ``calculate_trapezoid_for_block``: rates = speed × steps/mm rounded to nearest, both ramps rounded up, the
  meeting point of a cruise-less block rounded to nearest; no 120 steps/s floor;
* classic jerk: the per-axis speed difference at the lower nominal speed (no Průša safe speed, no
  coasting/reversal cases);
* look-ahead: no nominal-length flag and no ``block_buffer_planned``; the reverse pass stops at the first block
  whose entry cannot rise; the forward pass runs inside ``recalculate_trapezoids``;
* stepper: each rate is read half an interval into its step.

Row kinds handed in (``ROW_*``): a move, a wait (the queue drains first: M400, G4, homing), or nothing.
"""
from __future__ import annotations

import math

import numpy as np

from .._jit import njit
from ..stepper.marlin_isr import block_ticks_kernel, block_ticks_kernel_bugfix, block_ticks_scurve_kernel

BLOCK_BUFFER_SIZE = 16
MIN_STEPS_PER_SEGMENT = 6
MINIMAL_STEP_RATE = 120          # steps/s, planner.cpp (2.1.2): the timer would overflow below it
SLOWDOWN_DIVISOR = 2

ROW_MOVE, ROW_WAIT, ROW_SKIP = 0, 1, 2

# block flag bits (planner.h)
FLAG_RECALCULATE = 1
FLAG_NOMINAL_LENGTH = 2
FLAG_SYNC_POSITION = 8

# float32 block fields (bf[slot, ...])
BF_MM, BF_NOMINAL_SPEED, BF_ENTRY_SQR, BF_MAX_ENTRY_SQR, BF_ACCEL = 0, 1, 2, 3, 4
# bugfix-2.1.x only: the entry speed² the forward pass may not go below, and the block's leading-axis steps per mm
BF_MIN_ENTRY_SQR, BF_STEPS_PER_MM = 5, 6
N_BF = 7
# integer block fields (bi[slot, ...])
(BI_FLAG, BI_SEC, BI_NOMINAL_RATE, BI_INITIAL_RATE, BI_FINAL_RATE, BI_ACCEL_UNTIL, BI_DECEL_AFTER, BI_ACCEL_STEPS,
 BI_ROW, BI_SX, BI_SY, BI_SZ, BI_SE, BI_CRUISE_RATE, BI_ACC_TIME, BI_DEC_TIME, BI_ACC_TIME_INV,
 BI_DEC_TIME_INV, BI_DIR_BITS) = range(19)
N_BI = 19
# integer global state (gi[...])
(GI_HEAD, GI_TAIL, GI_PLANNED, GI_NONBUSY, GI_BUSY, GI_PX, GI_PY, GI_PZ, GI_PE, GI_CLOCK, GI_NEXT_ROW,
 GI_STARTED, GI_RESET_DONE, GI_SETTINGS_ROW, GI_CORE, GI_SLOWDOWN_MAX) = range(16)
N_GI = 16
# the build's kinematics (gi[GI_CORE]): cartesian, COREXY (motors A = X + Y, B = X − Y) or COREXZ (A = X + Z,
# C = X − Z); the planner's position stays the head's, in steps (planner.cpp)
CORE_NONE, CORE_XY, CORE_XZ = 0, 1, 2
# float32 global state (gf[...])
GF_PREV_SPEED, GF_PREV_NOMINAL, GF_PREV_SAFE, GF_PREV_UNIT, GF_POS_FLOAT = 0, 4, 5, 6, 10
N_GF = 14
# junction rule of the build
JUNCTION_CLASSIC_JERK, JUNCTION_DEVIATION = 0, 1
# firmware version whose rules run: Marlin 2.1.2.4, or bugfix-2.1.x of 2024-07-30 (its start/stop speed from the
# acceleration, speed-based trapezoids, one look-ahead pass fewer, its classic jerk and its stepper ISR)
VERSION_2_1_2, VERSION_BUGFIX = 0, 1
#: steps/s, bugfix-2.1.x: no fixed 120 steps/s floor any more (its reference runs go down to 35 steps/s, the
#: start/stop speed keeps rates up); 1 only keeps the interrupt's rate-to-interval division defined
MINIMAL_STEP_RATE_BUGFIX = 1
# planner.h's acos table for JD_HANDLE_SMALL_SEGMENTS (JD_USE_LOOKUP_TABLE, on by default): slope and offset of
# 16 chords of acos(t), entry i covering 1 − t in [2^-(i+1), 2^-i)
JD_LUT_K = np.array([-1.03145837, -1.30760646, -1.75205851, -2.41705704, -3.37769222, -4.74888992, -6.69649887,
                     -9.45661736, -13.3640480, -18.8928222, -26.7136841, -37.7754593, -53.4201813, -75.5458374,
                     -106.836761, -218.532821], dtype=np.float32)
JD_LUT_B = np.array([1.57079637, 1.70887053, 2.04220939, 2.62408352, 3.52467871, 4.85302639, 6.77020454,
                     9.50875854, 13.4009285, 18.9188995, 26.7321243, 37.7885055, 53.4293975, 75.5523529,
                     106.841369, 218.534011], dtype=np.float32)
# per-row outputs
(OI_HAS_BLOCK, OI_T_PICK, OI_T_END, OI_SEC, OI_NOMINAL_RATE, OI_INITIAL_RATE, OI_FINAL_RATE, OI_ACCEL_UNTIL,
 OI_DECEL_AFTER, OI_ACCEL_STEPS, OI_ACC_T, OI_CRUISE_T, OI_DEC_T, OI_FLAG, OI_SX, OI_SY, OI_SZ, OI_SE, OI_DIR_BITS,
 OI_CRUISE_RATE, OI_ACCELERATION_TIME, OI_DECELERATION_TIME, OI_ACC_TIME_INV, OI_DEC_TIME_INV) = range(24)
N_OI = 24
OF_ENTRY_SQR, OF_NOMINAL_SPEED, OF_MM, OF_ACCEL, OF_EXIT_SQR = 0, 1, 2, 3, 4
N_OF = 5

F32 = np.float32
#: numba's inline option for the planner's per-block functions: inlined into their caller at compile time. As
#: calls, each would take its arrays as one argument per field (over a hundred for _populate_block) and
#: could not be optimised with its caller; inlined, the kernel runs in about two thirds of the time
INLINE = "always"


def new_state(buffer_blocks: int | None = BLOCK_BUFFER_SIZE):
    """(bf, bi, gi, gf): an empty buffer of ``buffer_blocks`` slots (a power of 2, ``buffer_blocks - 1`` usable, as
    Marlin's ring), the stepper idle, position 0 steps. ``None``: an unbounded buffer, a ring of 16 slots to
    start with that :func:`grow_ring` doubles before it fills (SLOWDOWN then never acts: its window of 2 …
    BLOCK_BUFFER_SIZE / 2 − 1 queued blocks is a buffer running low, which an unbounded one never does)."""
    size = BLOCK_BUFFER_SIZE if buffer_blocks is None else int(buffer_blocks)
    bf = np.zeros((size, N_BF), dtype=np.float32)
    bi = np.zeros((size, N_BI), dtype=np.int64)
    gi = np.zeros(N_GI, dtype=np.int64)
    gf = np.zeros(N_GF, dtype=np.float32)
    # planner.cpp SLOWDOWN: WITHIN(moves_queued, 2, (BLOCK_BUFFER_SIZE) / (SLOWDOWN_DIVISOR) - 1)
    gi[GI_SLOWDOWN_MAX] = 1 if buffer_blocks is None else size // SLOWDOWN_DIVISOR - 1
    return bf, bi, gi, gf


def grow_ring(bf, bi, gi, need):
    """The ring (``bf``, ``bi``) with room for ``need`` more blocks: the same arrays when it has it, else new ones of
    a power-of-2 size, the queued blocks moved to slots 0 … in order and ``gi``'s ring pointers (head, tail,
    planned, non-busy) moved with them (an unbounded buffer, :func:`new_state` ``None``)."""
    size = len(bi)
    queued = int((gi[GI_HEAD] - gi[GI_TAIL]) & (size - 1))
    if queued + need < size - 1:
        return bf, bi
    new = size
    while queued + need >= new - 1:
        new *= 2
    order = (int(gi[GI_TAIL]) + np.arange(queued)) & (size - 1)
    bf2 = np.zeros((new, bf.shape[1]), dtype=bf.dtype)
    bi2 = np.zeros((new, bi.shape[1]), dtype=bi.dtype)
    bf2[:queued] = bf[order]
    bi2[:queued] = bi[order]
    tail = int(gi[GI_TAIL])
    for k in (GI_PLANNED, GI_NONBUSY):
        gi[k] = (int(gi[k]) - tail) & (size - 1)
        if gi[k] > queued:           # a pointer outside the queue (not in use) goes to the head
            gi[k] = queued
    gi[GI_TAIL] = 0
    gi[GI_HEAD] = queued
    return bf2, bi2


#: rows of the block-time memo (a power of 2): a sliced plate repeats its objects' blocks; on the 50 MB plate
#: of the benchmark 4096 rows find 89 % of the blocks (76 % of the ramp steps) already timed
MEMO_ROWS = 4096
# a memo row: the stepper mode + 1 (0: empty), the timer rate, the block's twelve trapezoid fields, then the
# interrupt's total and phase ticks
MEMO_KEY = 14
N_MEMO = MEMO_KEY + 4


def new_scratch():
    """(scratch_f, scratch_i, memo): the working rows :func:`marlin_run_kernel` writes into instead of
    allocating (it runs without numba's reference counting): 4×4 float32, 4×4 int64, and the block-time memo
    (MEMO_ROWS rows, empty, and one more that holds the key being looked up; N_MEMO int64 each)."""
    return (np.zeros((4, 4), dtype=np.float32), np.zeros((4, 4), dtype=np.int64),
            np.zeros((MEMO_ROWS + 1, N_MEMO), dtype=np.int64))


@njit(cache=True)
def _next(bi, i):
    """The ring slot after ``i``: the ring's size is ``bi``'s row count, a power of 2 (Marlin's SanityCheck.h
    requires BLOCK_BUFFER_SIZE to be one; planner.h's next_block_index masks with it)."""
    return (i + 1) & (bi.shape[0] - 1)


@njit(cache=True)
def _prev(bi, i):
    """The ring slot before ``i`` (ring size: ``bi``'s row count, a power of 2)."""
    return (i - 1) & (bi.shape[0] - 1)


# ceil and floor as np.ceil / np.floor: numba compiles them to the processor's rounding instruction, where
# math.ceil / math.floor call a C library function through a pointer (the same value: rounding is exact)


@njit(cache=True)
def _ceilf(x):
    return np.int64(np.ceil(x))


@njit(cache=True)
def _floorf(x):
    return np.int64(np.floor(x))


@njit(cache=True)
def _lroundf(x):
    """C lroundf: halves away from zero."""
    if x >= 0:
        return np.int64(np.floor(x + np.float64(0.5)))
    return -np.int64(np.floor(-x + np.float64(0.5)))


@njit(cache=True)
def _is_busy(gi, slot):
    return gi[GI_BUSY] != 0 and slot == gi[GI_TAIL]


@njit(cache=True)
def _max_allowable_speed_sqr(accel, target_velocity_sqr, distance):
    """v² reachable at the start of ``distance`` mm ending at v² = target with −accel (float32, planner.h)."""
    return F32(target_velocity_sqr - F32(F32(F32(2) * accel) * distance))


@njit(cache=True, inline=INLINE)
def calculate_trapezoid_for_block(bf, bi, slot, entry_factor, exit_factor, timer_hz=25000000):
    """Rates and step boundaries of a block from its entry and exit speeds as fractions of nominal."""
    nominal_rate = bi[slot, BI_NOMINAL_RATE]
    initial_rate = _ceilf(F32(F32(nominal_rate) * entry_factor))
    final_rate = _ceilf(F32(F32(nominal_rate) * exit_factor))
    if initial_rate < MINIMAL_STEP_RATE:
        initial_rate = np.int64(MINIMAL_STEP_RATE)
    if final_rate < MINIMAL_STEP_RATE:
        final_rate = np.int64(MINIMAL_STEP_RATE)
    accel = bi[slot, BI_ACCEL_STEPS]
    sec = bi[slot, BI_SEC]
    # steps to accelerate from the initial rate to nominal and to brake from nominal to the final rate,
    # each (rate² difference) / (2·accel), with one inverse of the acceleration (2.1.2's form)
    f_nom_sq = F32(F32(nominal_rate) * F32(nominal_rate))
    half_inverse_accel = F32(F32(0.5) * F32(F32(1) / F32(accel)))
    decelerate_f = F32(half_inverse_accel * F32(f_nom_sq - F32(F32(final_rate) * F32(final_rate))))
    accelerate_f = F32(half_inverse_accel * F32(f_nom_sq - F32(F32(initial_rate) * F32(initial_rate))))
    accelerate_steps = _ceilf(accelerate_f)
    decelerate_steps = _floorf(decelerate_f)
    plateau_steps = sec - accelerate_steps - decelerate_steps
    if plateau_steps < 0:
        # no cruise: accelerate to where the two ramps meet, (steps + accel − decel) / 2
        acc_f = F32(_ceilf(F32(F32(F32(F32(sec) + accelerate_f) - decelerate_f) * F32(0.5))))
        if acc_f < 0:
            acc_f = F32(0)
        accelerate_steps = np.int64(acc_f)
        if accelerate_steps > sec:
            accelerate_steps = sec
        plateau_steps = np.int64(0)
        # S_CURVE_ACCELERATION: the rate reached where the ramps meet, final_speed() = √(v0² + 2·a·d)
        cruise_rate = np.int64(F32(math.sqrt(F32(F32(F32(initial_rate) * F32(initial_rate))
                                                + F32(F32(F32(2) * F32(accel)) * F32(accelerate_steps))))))
    else:
        cruise_rate = nominal_rate
    # S_CURVE_ACCELERATION: each ramp's duration in timer ticks and its 32-bit inverse (get_period_inverse)
    rate_factor = F32(F32(F32(1) / F32(accel)) * F32(timer_hz))
    acc_time = np.int64(F32(rate_factor * F32(cruise_rate - initial_rate)))
    dec_time = np.int64(F32(rate_factor * F32(cruise_rate - final_rate)))
    bi[slot, BI_CRUISE_RATE] = cruise_rate
    bi[slot, BI_ACC_TIME] = acc_time
    bi[slot, BI_DEC_TIME] = dec_time
    bi[slot, BI_ACC_TIME_INV] = 0xFFFFFFFF // acc_time if acc_time > 0 else 0xFFFFFFFF
    bi[slot, BI_DEC_TIME_INV] = 0xFFFFFFFF // dec_time if dec_time > 0 else 0xFFFFFFFF
    bi[slot, BI_ACCEL_UNTIL] = accelerate_steps
    bi[slot, BI_DECEL_AFTER] = accelerate_steps + plateau_steps
    bi[slot, BI_INITIAL_RATE] = initial_rate
    bi[slot, BI_FINAL_RATE] = final_rate


@njit(cache=True)
def reverse_pass_kernel(bf, bi, gi, cur, nxt):
    """Lower a block's entry speed to what it can brake from over its length to the next block's entry."""
    max_entry = bf[cur, BF_MAX_ENTRY_SQR]
    if bf[cur, BF_ENTRY_SQR] != max_entry or (nxt >= 0 and (bi[nxt, BI_FLAG] & FLAG_RECALCULATE) != 0):
        if (bi[cur, BI_FLAG] & FLAG_NOMINAL_LENGTH) != 0:
            new_entry = max_entry
        else:
            nxt_entry = bf[nxt, BF_ENTRY_SQR] if nxt >= 0 else F32(F32(0.05) * F32(0.05))
            new_entry = _max_allowable_speed_sqr(-bf[cur, BF_ACCEL], nxt_entry, bf[cur, BF_MM])
            if max_entry < new_entry:
                new_entry = max_entry
        if bf[cur, BF_ENTRY_SQR] != new_entry:
            if not _is_busy(gi, cur):
                bi[cur, BI_FLAG] |= FLAG_RECALCULATE
                bf[cur, BF_ENTRY_SQR] = new_entry


@njit(cache=True)
def reverse_pass(bf, bi, gi):
    """From the newest block back to (not including) ``block_buffer_planned``; sync blocks are skipped."""
    head = gi[GI_HEAD]
    planned = gi[GI_PLANNED]
    if planned == head:
        return
    idx = _prev(bi, head)
    nxt = -1
    while idx != planned:
        if (bi[idx, BI_FLAG] & FLAG_SYNC_POSITION) == 0:
            reverse_pass_kernel(bf, bi, gi, idx, nxt)
            nxt = idx
        idx = _prev(bi, idx)


@njit(cache=True)
def forward_pass_kernel(bf, bi, gi, prv, cur, idx):
    """Lower a block's entry speed to what the previous block can reach accelerating over its length; move
    ``block_buffer_planned`` to blocks whose entry can no longer change."""
    if prv < 0:
        return
    if (bi[prv, BI_FLAG] & FLAG_NOMINAL_LENGTH) == 0 and bf[prv, BF_ENTRY_SQR] < bf[cur, BF_ENTRY_SQR]:
        new_entry = _max_allowable_speed_sqr(-bf[prv, BF_ACCEL], bf[prv, BF_ENTRY_SQR], bf[prv, BF_MM])
        if new_entry < bf[cur, BF_ENTRY_SQR]:
            if not _is_busy(gi, cur):
                bi[cur, BI_FLAG] |= FLAG_RECALCULATE
                bf[cur, BF_ENTRY_SQR] = new_entry
                gi[GI_PLANNED] = idx
    if bf[cur, BF_ENTRY_SQR] == bf[cur, BF_MAX_ENTRY_SQR]:
        gi[GI_PLANNED] = idx


@njit(cache=True)
def forward_pass(bf, bi, gi):
    """From ``block_buffer_planned`` to the newest block; a busy previous block is not looked through."""
    idx = gi[GI_PLANNED]
    prv = -1
    while idx != gi[GI_HEAD]:
        if (bi[idx, BI_FLAG] & FLAG_SYNC_POSITION) == 0:
            if prv < 0 or not _is_busy(gi, prv):
                forward_pass_kernel(bf, bi, gi, prv, idx, idx)
            prv = idx
        idx = _next(bi, idx)


@njit(cache=True, inline=INLINE)
def recalculate_trapezoids(bf, bi, gi):
    """Trapezoids of the blocks whose entry or exit speed changed; the newest one always (exit at
    MINIMUM_PLANNER_SPEED); the busy block is left as it runs."""
    idx = gi[GI_TAIL]
    head_idx = gi[GI_HEAD]
    while head_idx != idx:
        p = _prev(bi, head_idx)
        if (bi[p, BI_FLAG] & FLAG_SYNC_POSITION) == 0:
            break
        head_idx = p
    block = -1
    nxt = -1
    # the entry speeds (√ of the entry speed², float32) are taken only for the blocks recalculated: nothing
    # changes a block's entry speed² during this sweep, so √ later gives the firmware's value
    while idx != head_idx:
        nxt = idx
        if (bi[nxt, BI_FLAG] & FLAG_SYNC_POSITION) == 0:
            if block >= 0:
                if (bi[block, BI_FLAG] & FLAG_RECALCULATE) != 0 or (bi[nxt, BI_FLAG] & FLAG_RECALCULATE) != 0:
                    if not _is_busy(gi, block):
                        cur_entry = F32(math.sqrt(bf[block, BF_ENTRY_SQR]))
                        nxt_entry = F32(math.sqrt(bf[nxt, BF_ENTRY_SQR]))
                        nomr = F32(F32(1) / bf[block, BF_NOMINAL_SPEED])
                        calculate_trapezoid_for_block(bf, bi, block, F32(cur_entry * nomr), F32(nxt_entry * nomr))
                    bi[block, BI_FLAG] &= ~FLAG_RECALCULATE
            block = nxt
        idx = _next(bi, idx)
    if nxt >= 0 and (bi[nxt, BI_FLAG] & FLAG_SYNC_POSITION) == 0:
        if block < 0 or not _is_busy(gi, block):
            nxt_entry = F32(math.sqrt(bf[nxt, BF_ENTRY_SQR]))
            nomr = F32(F32(1) / bf[nxt, BF_NOMINAL_SPEED])
            calculate_trapezoid_for_block(bf, bi, nxt, F32(nxt_entry * nomr), F32(F32(0.05) * nomr))
        bi[nxt, BI_FLAG] &= ~FLAG_RECALCULATE
    elif block >= 0:
        # trailing sync blocks: the last move block is the newest one
        if not _is_busy(gi, block):
            cur_entry = F32(math.sqrt(bf[block, BF_ENTRY_SQR]))
            nomr = F32(F32(1) / bf[block, BF_NOMINAL_SPEED])
            calculate_trapezoid_for_block(bf, bi, block, F32(cur_entry * nomr), F32(F32(0.05) * nomr))
        bi[block, BI_FLAG] &= ~FLAG_RECALCULATE


@njit(cache=True, inline=INLINE)
def recalculate(bf, bi, gi):
    """Planner::recalculate(): both passes unless the newest block is the planned one, then trapezoids."""
    if _prev(bi, gi[GI_HEAD]) != gi[GI_PLANNED]:
        reverse_pass(bf, bi, gi)
        forward_pass(bf, bi, gi)
    recalculate_trapezoids(bf, bi, gi)


# ---------------------------------------------------------------- bugfix-2.1.x (2024-07-30): the look-ahead
# Marlin's pull requests #27013, #27089 and #27035 (2024) rewrote these functions; the 2.1.2 ones above stay as
# they were, so each version's rule can be read (and diffed) function by function.


@njit(cache=True, inline=INLINE)
def calculate_trapezoid_for_block_bugfix(bf, bi, slot, entry_speed, exit_speed, timer_hz=25000000):
    """bugfix-2.1.x: rates and step boundaries of a block from its entry and exit speeds in mm/s.

    Rates are the speeds times the block's steps/mm, rounded to nearest (2.1.2: factors of the nominal rate,
    rounded up, floored at 120 steps/s); an entry speed of 0 keeps the block's initial rate. Both ramps are
    rounded up to whole steps (2.1.2 rounds the braking down); without a cruise the ramps meet at the rounded
    midpoint and the braking takes the remaining steps."""
    spmm = bf[slot, BF_STEPS_PER_MM]
    if entry_speed != 0:
        initial_rate = _lroundf(F32(entry_speed * spmm))
    else:
        initial_rate = bi[slot, BI_INITIAL_RATE]
    final_rate = _lroundf(F32(exit_speed * spmm))
    if initial_rate < MINIMAL_STEP_RATE_BUGFIX:
        initial_rate = np.int64(MINIMAL_STEP_RATE_BUGFIX)
    if final_rate < MINIMAL_STEP_RATE_BUGFIX:
        final_rate = np.int64(MINIMAL_STEP_RATE_BUGFIX)
    nominal_rate = bi[slot, BI_NOMINAL_RATE]
    if nominal_rate < MINIMAL_STEP_RATE_BUGFIX:
        nominal_rate = np.int64(MINIMAL_STEP_RATE_BUGFIX)
        bi[slot, BI_NOMINAL_RATE] = nominal_rate
    cruise_rate = nominal_rate
    sec = bi[slot, BI_SEC]
    accel = bi[slot, BI_ACCEL_STEPS]
    accelerate_steps = np.int64(0)
    decelerate_steps = np.int64(0)
    inverse_accel = F32(0)
    if accel != 0:
        inverse_accel = F32(F32(1) / F32(accel))
        half_inverse_accel = F32(F32(0.5) * inverse_accel)
        f_nom_sq = F32(F32(nominal_rate) * F32(nominal_rate))
        decelerate_f = F32(half_inverse_accel * F32(f_nom_sq - F32(F32(final_rate) * F32(final_rate))))
        accelerate_f = F32(half_inverse_accel * F32(f_nom_sq - F32(F32(initial_rate) * F32(initial_rate))))
        accelerate_steps = _ceilf(accelerate_f)
        decelerate_steps = _ceilf(decelerate_f)
        if sec - accelerate_steps - decelerate_steps < 0:
            # no cruise: the ramps meet at (steps + accel − decel) / 2, rounded to nearest
            accelerate_steps = _lroundf(F32(F32(F32(F32(sec) + accelerate_f) - decelerate_f) * F32(0.5)))
            if accelerate_steps < 0:
                accelerate_steps = np.int64(0)
            if accelerate_steps > sec:
                accelerate_steps = sec
            decelerate_steps = sec - accelerate_steps
            # S_CURVE_ACCELERATION: the rate reached where the ramps meet, final_speed() = √(v0² + 2·a·d)
            peak = np.int64(F32(math.sqrt(F32(F32(F32(initial_rate) * F32(initial_rate))
                                              + F32(F32(F32(2) * F32(accel)) * F32(accelerate_steps))))))
            if peak < cruise_rate:
                cruise_rate = peak
    rate_factor = F32(inverse_accel * F32(timer_hz))
    acc_time = np.int64(F32(rate_factor * F32(cruise_rate - initial_rate)))
    dec_time = np.int64(F32(rate_factor * F32(cruise_rate - final_rate)))
    bi[slot, BI_CRUISE_RATE] = cruise_rate
    bi[slot, BI_ACC_TIME] = acc_time
    bi[slot, BI_DEC_TIME] = dec_time
    bi[slot, BI_ACC_TIME_INV] = 0xFFFFFFFF // acc_time if acc_time > 0 else 0xFFFFFFFF
    bi[slot, BI_DEC_TIME_INV] = 0xFFFFFFFF // dec_time if dec_time > 0 else 0xFFFFFFFF
    # stored as the stepper reads them: accelerate while fewer than accelerate_before steps are done, brake from
    # decelerate_start on (the BI_ACCEL_UNTIL / BI_DECEL_AFTER slots of 2.1.2)
    bi[slot, BI_ACCEL_UNTIL] = accelerate_steps
    bi[slot, BI_DECEL_AFTER] = sec - decelerate_steps
    bi[slot, BI_INITIAL_RATE] = initial_rate
    bi[slot, BI_FINAL_RATE] = final_rate


@njit(cache=True)
def reverse_pass_kernel_bugfix(bf, bi, cur, nxt, safe_exit_speed_sqr):
    """bugfix-2.1.x: raise a block's entry speed² to what it can brake from over its length to the next block's
    entry (the newest block: to the safe exit speed), within its junction limit. True when it rose."""
    if nxt < 0 or (bi[nxt, BI_FLAG] & FLAG_RECALCULATE) != 0:
        if bf[cur, BF_ENTRY_SQR] != bf[cur, BF_MAX_ENTRY_SQR]:
            nxt_entry = bf[nxt, BF_ENTRY_SQR] if nxt >= 0 else safe_exit_speed_sqr
            new_entry = _max_allowable_speed_sqr(-bf[cur, BF_ACCEL], nxt_entry, bf[cur, BF_MM])
            if new_entry > bf[cur, BF_MAX_ENTRY_SQR]:
                new_entry = bf[cur, BF_MAX_ENTRY_SQR]
            if bf[cur, BF_ENTRY_SQR] != new_entry:
                bi[cur, BI_FLAG] |= FLAG_RECALCULATE
                bf[cur, BF_ENTRY_SQR] = new_entry
                return True
    return False


@njit(cache=True)
def reverse_pass_bugfix(bf, bi, gi, safe_exit_speed_sqr):
    """bugfix-2.1.x: from the newest block back to the first non-busy one (whose entry is the busy block's exit,
    not changed), sync blocks skipped; it stops at the first block whose entry speed cannot rise."""
    idx = _prev(bi, gi[GI_HEAD])
    nonbusy = gi[GI_NONBUSY]
    nxt = -1
    while idx != nonbusy:
        if (bi[idx, BI_FLAG] & FLAG_SYNC_POSITION) == 0:
            if not reverse_pass_kernel_bugfix(bf, bi, idx, nxt, safe_exit_speed_sqr):
                return
            nxt = idx
        idx = _prev(bi, idx)


@njit(cache=True)
def forward_pass_kernel_bugfix(bf, bi, prv, cur):
    """bugfix-2.1.x: lower a block's entry speed² to what the previous block reaches accelerating over its length
    (not below the block's minimum); the result becomes the block's new minimum and, when lowered, its maximum."""
    if bf[prv, BF_ENTRY_SQR] < bf[cur, BF_ENTRY_SQR]:
        new_exit = _max_allowable_speed_sqr(-bf[prv, BF_ACCEL], bf[prv, BF_ENTRY_SQR], bf[prv, BF_MM])
        if new_exit < bf[cur, BF_ENTRY_SQR]:
            if new_exit < bf[cur, BF_MIN_ENTRY_SQR]:
                new_exit = bf[cur, BF_MIN_ENTRY_SQR]
            bf[cur, BF_ENTRY_SQR] = new_exit
            bf[cur, BF_MAX_ENTRY_SQR] = new_exit
    bf[cur, BF_MIN_ENTRY_SQR] = bf[cur, BF_ENTRY_SQR]


@njit(cache=True, inline=INLINE)
def recalculate_trapezoids_bugfix(bf, bi, gi, safe_exit_speed_sqr, timer_hz):
    """bugfix-2.1.x: the forward pass and the trapezoids in one sweep from the oldest block. A block whose exit
    changed is recomputed (entry speed 0 = keep its initial rate); the first block enters at its minimum speed;
    behind the busy block the entry cannot change; the newest block exits at the safe exit speed."""
    idx = gi[GI_TAIL]
    head = gi[GI_HEAD]
    block = -1
    next_entry_speed = F32(0)
    while idx != head:
        nxt = idx
        if (bi[nxt, BI_FLAG] & FLAG_SYNC_POSITION) == 0:
            if (bi[nxt, BI_FLAG] & FLAG_RECALCULATE) != 0:
                if block < 0:
                    bf[nxt, BF_ENTRY_SQR] = bf[nxt, BF_MIN_ENTRY_SQR]
                    next_entry_speed = F32(math.sqrt(bf[nxt, BF_MIN_ENTRY_SQR]))
                else:
                    bi[block, BI_FLAG] |= FLAG_RECALCULATE
                    if _is_busy(gi, block):
                        # the running block's exit is fixed: the next one starts at its final rate
                        bf[nxt, BF_ENTRY_SQR] = bf[nxt, BF_MIN_ENTRY_SQR]
                        if bi[nxt, BI_INITIAL_RATE] == 0:
                            bi[nxt, BI_INITIAL_RATE] = bi[block, BI_FINAL_RATE]
                    else:
                        if bf[nxt, BF_ENTRY_SQR] != bf[nxt, BF_MIN_ENTRY_SQR]:
                            forward_pass_kernel_bugfix(bf, bi, block, nxt)
                        current_entry_speed = next_entry_speed
                        next_entry_speed = F32(math.sqrt(bf[nxt, BF_ENTRY_SQR]))
                        calculate_trapezoid_for_block_bugfix(bf, bi, block, current_entry_speed, next_entry_speed,
                                                             timer_hz)
                    bi[block, BI_FLAG] &= ~FLAG_RECALCULATE
            block = nxt
        idx = _next(bi, idx)
    if block >= 0 and (bi[block, BI_FLAG] & FLAG_RECALCULATE) != 0:
        calculate_trapezoid_for_block_bugfix(bf, bi, block, next_entry_speed,
                                             F32(math.sqrt(safe_exit_speed_sqr)), timer_hz)
        bi[block, BI_FLAG] &= ~FLAG_RECALCULATE


@njit(cache=True, inline=INLINE)
def recalculate_bugfix(bf, bi, gi, safe_exit_speed_sqr, timer_hz):
    """bugfix-2.1.x Planner::recalculate(): the reverse pass, then the forward pass with the trapezoids."""
    reverse_pass_bugfix(bf, bi, gi, safe_exit_speed_sqr)
    recalculate_trapezoids_bugfix(bf, bi, gi, safe_exit_speed_sqr, timer_hz)


@njit(cache=True)
def _queued(bi, gi):
    return (gi[GI_HEAD] - gi[GI_TAIL]) & (bi.shape[0] - 1)


@njit(cache=True)
def _nonbusy_queued(bi, gi):
    first = _next(bi, gi[GI_TAIL]) if gi[GI_BUSY] != 0 else gi[GI_TAIL]
    return (gi[GI_HEAD] - first) & (bi.shape[0] - 1)


@njit(cache=True)
def buffer_sync_block(bf, bi, gi, row):
    """A position change queued behind the moves (G92 with blocks in the buffer): takes a slot."""
    h = gi[GI_HEAD]
    for k in range(N_BF):
        bf[h, k] = F32(0)
    for k in range(N_BI):
        bi[h, k] = 0
    bi[h, BI_FLAG] = FLAG_SYNC_POSITION
    bi[h, BI_ROW] = row
    gi[GI_HEAD] = _next(bi, h)


@njit(cache=True)
def _normalize_junction_vector(v):
    """v / |v| over its non-zero components (planner.h normalize_junction_vector)."""
    magnitude_sq = F32(0)
    for a in range(4):
        if v[a] != 0:
            magnitude_sq = F32(magnitude_sq + F32(v[a] * v[a]))
    if magnitude_sq == 0:
        return          # a straight continuation: the firmware's NaNs leave the acceleration unlimited
    inv = F32(F32(1) / F32(math.sqrt(magnitude_sq)))
    for a in range(4):
        v[a] = F32(v[a] * inv)


@njit(cache=True)
def _limit_value_by_axis_maximum(max_value, unit_vec, amax_mm):
    """The largest value ≤ max_value whose projection on each axis of unit_vec is within its M201 limit."""
    limit_value = max_value
    for a in range(4):
        if unit_vec[a] != 0:
            if F32(limit_value * F32(abs(unit_vec[a]))) > amax_mm[a]:
                limit_value = F32(abs(F32(amax_mm[a] / unit_vec[a])))
    return limit_value


@njit(cache=True)
def _junction_deviation_sqr(gf, dist, inverse_millimeters, esteps, millimeters, acceleration, nominal_speed,
                            moves_queued, amax_mm, junction_deviation_mm, scratch_f, reversal_sqr, start_sqr,
                            core=CORE_NONE):
    """max_entry_speed² by junction deviation (HAS_JUNCTION_DEVIATION, JD_HANDLE_SMALL_SEGMENTS on): the
    centripetal speed on a circle deviating junction_deviation_mm from the corner, with the acceleration the
    axes allow along the junction; short moves at sharp corners are held to an approximate arc. A reversal
    gets ``reversal_sqr``, a start from rest ``start_sqr`` (mm²/s²; the version's minimum planner speed).
    ``dist`` is per motor: on a Core machine the junction vector is the motors' (A, B), as planner.cpp takes
    steps_dist_mm, and always normalised (its length is not the head's)."""
    unit_vec = scratch_f[2]
    for a in range(4):
        unit_vec[a] = dist[a]
    if esteps > 0 or core != CORE_NONE:
        _normalize_junction_vector(unit_vec)      # with E, or a Core machine: normalise the whole vector
    else:
        for a in range(4):
            unit_vec[a] = F32(unit_vec[a] * inverse_millimeters)
    prev_nominal = gf[GF_PREV_NOMINAL]
    if moves_queued != 0 and not (prev_nominal < F32(0.000001)):
        # cosine of the angle between the previous and this move (E term first, as LOGICAL_AXIS_GANG)
        c = F32(-gf[GF_PREV_UNIT + 3] * unit_vec[3])
        for a in range(3):
            c = F32(c + F32(-gf[GF_PREV_UNIT + a] * unit_vec[a]))
        if c > F32(0.999999):
            vmax_junction_sqr = reversal_sqr     # a reversal: the minimum planner speed
        else:
            if c < F32(-0.999999):
                c = F32(-0.999999)
            junction_unit_vec = scratch_f[3]
            for a in range(4):
                junction_unit_vec[a] = F32(unit_vec[a] - gf[GF_PREV_UNIT + a])
            _normalize_junction_vector(junction_unit_vec)
            junction_acceleration = _limit_value_by_axis_maximum(acceleration, junction_unit_vec, amax_mm)
            sin_theta_d2 = F32(math.sqrt(F32(F32(0.5) * F32(F32(1) - c))))
            vmax_junction_sqr = F32(F32(F32(junction_acceleration * junction_deviation_mm) * sin_theta_d2)
                                    / F32(F32(1) - sin_theta_d2))
            if millimeters < F32(1) and c < F32(-0.7071067812):
                # acos by Marlin's 16-entry table and linear interpolation (planner.h: JD_USE_LOOKUP_TABLE),
                # the entry picked by the leading zeros of (1 − t)·2^15
                neg = F32(-1) if c < 0 else F32(1)
                t = F32(neg * c)
                if t < F32(0.00000003):
                    idx = 0
                else:
                    x = np.int64(F32(F32(F32(1) - t) * F32(32768)))
                    idx = 15 if x <= 0 else 14 - int(math.floor(math.log2(x)))
                    if idx < 0:
                        idx = 0
                junction_theta = F32(F32(t * JD_LUT_K[idx]) + JD_LUT_B[idx])
                if neg > 0:
                    junction_theta = F32(F32(F32(F32(180) * F32(math.pi)) / F32(180)) - junction_theta)
                limit_sqr = F32(F32(millimeters * junction_acceleration) / junction_theta)
                if limit_sqr < vmax_junction_sqr:
                    vmax_junction_sqr = limit_sqr
        nsq = F32(nominal_speed * nominal_speed)
        psq = F32(prev_nominal * prev_nominal)
        if nsq < vmax_junction_sqr:
            vmax_junction_sqr = nsq
        if psq < vmax_junction_sqr:
            vmax_junction_sqr = psq
    else:
        vmax_junction_sqr = start_sqr
    for a in range(4):
        gf[GF_PREV_UNIT + a] = unit_vec[a]
    return vmax_junction_sqr


@njit(cache=True, inline=INLINE)
def _use_advance_lead_accel(accel, tgt, gf, e_jerk, advance_k, steps_per_mm):
    """LIN_ADVANCE's acceleration cap (planner.cpp, where ``use_advance_lead`` is decided for a print move that
    extrudes forward): the acceleration (steps/s²) at which the extruder can jump to the advance speed within its
    jerk, E jerk / (K · e/D), e/D from the float target and ``position_float`` (mm); e/D > 3 is a retract merged
    into a print move and gets no advance (``accel`` unchanged)."""
    dxf = F32(tgt[0] - gf[GF_POS_FLOAT])
    dyf = F32(tgt[1] - gf[GF_POS_FLOAT + 1])
    dzf = F32(tgt[2] - gf[GF_POS_FLOAT + 2])
    e_d_ratio = F32(F32(tgt[3] - gf[GF_POS_FLOAT + 3]) / F32(math.sqrt(
        F32(F32(F32(dxf * dxf) + F32(dyf * dyf)) + F32(dzf * dzf)))))
    if not e_d_ratio > F32(3):
        cap = np.int64(F32(F32(e_jerk / F32(advance_k * e_d_ratio)) * steps_per_mm))
        if cap < accel:
            accel = cap
    return accel


@njit(cache=True, inline=INLINE)
def _limit_accel(accel, steps, sec, cutoff, amax_steps):
    """planner.cpp's LIMIT_ACCEL_LONG / LIMIT_ACCEL_FLOAT over the axes: no axis may accelerate above its M201
    limit (steps/s²), its share of the block's acceleration being its steps / ``sec``; in uint32 arithmetic while
    ``sec`` ≤ ``cutoff`` (the product cannot overflow), in float32 beyond."""
    if sec <= cutoff:
        for a in range(4):
            if steps[a] != 0 and amax_steps[a] < accel:
                max_possible = (amax_steps[a] * sec) // steps[a]
                if max_possible < accel:
                    accel = max_possible
    else:
        for a in range(4):
            if steps[a] != 0 and amax_steps[a] < accel:
                max_possible = F32(F32(F32(amax_steps[a]) * F32(sec)) / F32(steps[a]))
                if max_possible < F32(accel):
                    accel = np.int64(max_possible)
    return accel


@njit(cache=True, inline=INLINE)
def _steps_to_target(gi, tgt, spm, da, target, steps):
    """_populate_block's "number of steps for each axis": the target in whole steps (``lround(mm · steps/mm)``)
    into ``target``, the signed and absolute step deltas from the planner's position into ``da`` and
    ``steps``; returns the block's step_event_count (the most steps of any axis)."""
    sec = np.int64(0)
    for a in range(4):
        target[a] = _lroundf(F32(tgt[a] * spm[a]))
        da[a] = target[a] - gi[GI_PX + a]
        steps[a] = abs(da[a])
        if steps[a] > sec:
            sec = steps[a]
    return sec


@njit(cache=True, inline=INLINE)
def _core_motor_steps(core, da, steps):
    """_populate_block's "number of steps for each axis" on a Core machine (planner.cpp, CORE_IS_XY /
    CORE_IS_XZ): the head's step deltas in ``da`` become the motors' (A = X + Y, B = X − Y; or A = X + Z,
    C = X − Z), their absolute values into ``steps``; returns the block's step_event_count."""
    if core == CORE_XY:
        a = da[0] + da[1]
        da[1] = da[0] - da[1]
        da[0] = a
    else:
        a = da[0] + da[2]
        da[2] = da[0] - da[2]
        da[0] = a
    sec = np.int64(0)
    for k in range(4):
        steps[k] = abs(da[k])
        if steps[k] > sec:
            sec = steps[k]
    return sec


@njit(cache=True, inline=INLINE)
def _head_millimeters(da, mm_per_step):
    """The block length (mm) from the head's step deltas (on a Core build X_HEAD, Y_HEAD, Z), planner.cpp's
    SQRT of the squared distances in float32."""
    hx = F32(F32(da[0]) * mm_per_step[0])
    hy = F32(F32(da[1]) * mm_per_step[1])
    hz = F32(F32(da[2]) * mm_per_step[2])
    return F32(math.sqrt(F32(F32(F32(hx * hx) + F32(hy * hy)) + F32(hz * hz))))


@njit(cache=True, inline=INLINE)
def _slowdown(inverse_secs, moves_queued, min_segment_time_us, slowdown_max):
    """_populate_block's SLOWDOWN: with 2 to ``slowdown_max`` blocks queued (BLOCK_BUFFER_SIZE / 2 − 1: 7 in a
    16-block buffer), a segment shorter than MIN_SEGMENT_TIME (µs) is slowed towards it, by twice the shortfall
    over the blocks queued; returns 1 / segment time (1/s)."""
    segment_time_us = _lroundf(F32(F32(1000000) / inverse_secs))
    if moves_queued >= 2 and moves_queued <= slowdown_max:
        time_diff = min_segment_time_us - segment_time_us
        if time_diff > 0:
            # int32 division, as the firmware's LROUND(2 * time_diff / moves_queued)
            nst = segment_time_us + (2 * time_diff) // moves_queued
            inverse_secs = F32(F32(1000000) / F32(nst))
    return inverse_secs


@njit(cache=True, inline=INLINE)
def _limit_speed(dist, inverse_secs, vmax, current_speed):
    """_populate_block's "calculate and limit speed in mm/sec": each axis' speed (mm/s, into
    ``current_speed``) from its distance (mm) and 1 / segment time; returns the factor (≤ 1) that keeps every
    axis within its M203 limit ``vmax`` (mm/s)."""
    speed_factor = F32(1)
    for a in range(4):
        current_speed[a] = F32(dist[a] * inverse_secs)
        cs = F32(abs(current_speed[a]))
        if cs > vmax[a]:
            q = F32(vmax[a] / cs)
            if q < speed_factor:
                speed_factor = q
    return speed_factor


@njit(cache=True, inline=INLINE)
def _acceleration_steps(steps, da, sec, steps_per_mm, acc_p, acc_t, acc_r, tgt, gf, jerk, advance_k, cutoff,
                        amax_steps):
    """_populate_block's "compute and limit the acceleration rate for the trapezoid generator" (steps/s²): M204
    R for a move of E alone, P for a print move, T for a travel (mm/s² × the block's steps/mm, rounded up),
    capped by linear advance's rule (:func:`_use_advance_lead_accel`) and by each axis' M201 limit
    (:func:`_limit_accel`)."""
    if steps[0] == 0 and steps[1] == 0 and steps[2] == 0:
        return _ceilf(F32(acc_r * steps_per_mm))
    esteps = steps[3]
    accel = _ceilf(F32((acc_p if esteps != 0 else acc_t) * steps_per_mm))
    if advance_k > 0 and esteps != 0 and da[3] > 0:
        accel = _use_advance_lead_accel(accel, tgt, gf, jerk[3], advance_k, steps_per_mm)
    return _limit_accel(accel, steps, sec, cutoff, amax_steps)


@njit(cache=True, inline=INLINE)
def _populate_block(bf, bi, gi, gf, row, tgt, fr_mm_s, acc_p, acc_t, acc_r, vmax, amax_steps, cutoff, jerk,
                    min_feed, min_travel, spm, mm_per_step, min_segment_time_us, junction_mode, amax_mm, jdev,
                    advance_k, scratch_f, scratch_i, version=VERSION_2_1_2):
    """Fill the head slot from a move; False (nothing queued, position kept) when under 6 steps.

    ``version``: VERSION_2_1_2 or VERSION_BUGFIX (the start/stop speed and the classic jerk differ)."""
    h = gi[GI_HEAD]
    # scratch rows (no allocation per block): steps, targets and deltas; distances, speeds, unit vectors
    da = scratch_i[0]
    target = scratch_i[1]
    steps = scratch_i[2]
    sec = _steps_to_target(gi, tgt, spm, da, target, steps)
    core = gi[GI_CORE]
    # the length from the head's deltas; on a Core build the block is then in motor steps (da, steps, dist)
    millimeters = _head_millimeters(da, mm_per_step)
    if core != CORE_NONE:
        sec = _core_motor_steps(core, da, steps)
    if sec < MIN_STEPS_PER_SEGMENT:
        return False
    dist = scratch_f[0]
    for a in range(4):
        dist[a] = F32(F32(da[a]) * mm_per_step[a])
    if steps[0] < MIN_STEPS_PER_SEGMENT and steps[1] < MIN_STEPS_PER_SEGMENT and steps[2] < MIN_STEPS_PER_SEGMENT:
        millimeters = F32(abs(dist[3]))
    esteps = steps[3]
    fr_min = min_feed if esteps != 0 else min_travel        # NOLESS(fr_mm_s, min feed / min travel feed)
    fr = fr_min if fr_mm_s < fr_min else fr_mm_s
    inverse_millimeters = F32(F32(1) / millimeters)
    inverse_secs = F32(fr * inverse_millimeters)
    moves_queued = _nonbusy_queued(bi, gi)
    inverse_secs = _slowdown(inverse_secs, moves_queued, min_segment_time_us, gi[GI_SLOWDOWN_MAX])
    nominal_speed = F32(millimeters * inverse_secs)
    nominal_rate = _ceilf(F32(F32(sec) * inverse_secs))
    current_speed = scratch_f[1]
    speed_factor = _limit_speed(dist, inverse_secs, vmax, current_speed)
    if speed_factor < F32(1):
        for a in range(4):
            current_speed[a] = F32(current_speed[a] * speed_factor)
        nominal_rate = np.int64(F32(F32(nominal_rate) * speed_factor))
        nominal_speed = F32(nominal_speed * speed_factor)
    steps_per_mm = F32(F32(sec) * inverse_millimeters)
    accel = _acceleration_steps(steps, da, sec, steps_per_mm, acc_p, acc_t, acc_r, tgt, gf, jerk, advance_k, cutoff,
                                amax_steps)
    acceleration = F32(F32(accel) / steps_per_mm)
    if version == VERSION_BUGFIX:
        # bugfix-2.1.x: the average speed over one step accelerating from rest, v² = a / (2 · steps/mm), is the
        # slowest a block starts or ends (2.1.2: MINIMUM_PLANNER_SPEED 0.05 mm/s)
        min_sqr = F32(F32(F32(0.5) * acceleration) / steps_per_mm)
        start_sqr = min_sqr
    else:
        min_sqr = F32(F32(0.05) * F32(0.05))
        start_sqr = F32(0)
    if junction_mode == JUNCTION_DEVIATION:
        max_entry_sqr = _junction_deviation_sqr(gf, dist, inverse_millimeters, esteps, millimeters, acceleration,
                                                nominal_speed, moves_queued, amax_mm, jdev, scratch_f, min_sqr,
                                                start_sqr, core)
    elif version == VERSION_BUGFIX:
        max_entry_sqr = _classic_jerk_sqr_bugfix(gf, current_speed, nominal_speed, moves_queued, jerk, scratch_f)
    else:
        max_entry_sqr = _classic_jerk_sqr(gf, current_speed, nominal_speed, moves_queued, jerk)
    if version == VERSION_BUGFIX and max_entry_sqr < min_sqr:
        max_entry_sqr = min_sqr           # a high acceleration overrides a low jerk / junction limit
    # the block
    for k in range(N_BF):
        bf[h, k] = F32(0)
    for k in range(N_BI):
        bi[h, k] = 0
    bf[h, BF_MM] = millimeters
    bf[h, BF_NOMINAL_SPEED] = nominal_speed
    bf[h, BF_ACCEL] = acceleration
    bf[h, BF_MAX_ENTRY_SQR] = max_entry_sqr
    bf[h, BF_ENTRY_SQR] = min_sqr
    flag = FLAG_RECALCULATE
    if version == VERSION_BUGFIX:
        # no nominal-length flag in bugfix; the forward pass keeps the entry at or above this minimum, and the
        # trapezoid's rates come from speeds times the block's steps/mm
        bf[h, BF_MIN_ENTRY_SQR] = min_sqr
        bf[h, BF_STEPS_PER_MM] = steps_per_mm
    else:
        v_allowable_sqr = _max_allowable_speed_sqr(-acceleration, min_sqr, millimeters)
        if F32(nominal_speed * nominal_speed) <= v_allowable_sqr:
            flag |= FLAG_NOMINAL_LENGTH
    bi[h, BI_FLAG] = flag
    bi[h, BI_SEC] = sec
    bi[h, BI_NOMINAL_RATE] = nominal_rate
    bi[h, BI_ACCEL_STEPS] = accel
    bi[h, BI_ROW] = row
    dir_bits = np.int64(0)
    for a in range(4):
        bi[h, BI_SX + a] = steps[a]
        if da[a] < 0:
            dir_bits |= 1 << a                 # block->direction_bits: bit set = the axis runs negative
        gf[GF_PREV_SPEED + a] = current_speed[a]
        gi[GI_PX + a] = target[a]
    bi[h, BI_DIR_BITS] = dir_bits
    gf[GF_PREV_NOMINAL] = nominal_speed
    for a in range(4):
        gf[GF_POS_FLOAT + a] = tgt[a]
    return True


@njit(cache=True, inline=INLINE)
def _classic_jerk_sqr(gf, current_speed, nominal_speed, moves_queued, jerk):
    """max_entry_speed² by classic jerk (Průša's rule, planner.cpp): a safe speed to start from / stop at,
    and the junction speed at which no axis changes speed by more than its jerk (coasting or reversing)."""
    safe_speed = nominal_speed
    limited = 0
    for a in range(4):
        j = F32(abs(current_speed[a]))
        maxj = jerk[a]
        if j > maxj:
            if limited:
                mjerk = F32(nominal_speed * maxj)
                if F32(j * safe_speed) > mjerk:
                    safe_speed = F32(mjerk / j)
            else:
                safe_speed = F32(safe_speed * F32(maxj / j))
                limited += 1
    prev_nominal = gf[GF_PREV_NOMINAL]
    if moves_queued != 0 and not (prev_nominal < F32(0.000001)):
        v_factor = F32(1)
        limited = 0
        vmax_junction = nominal_speed if nominal_speed < prev_nominal else prev_nominal
        smaller_speed_factor = F32(vmax_junction / prev_nominal)
        for a in range(4):
            v_exit = F32(gf[GF_PREV_SPEED + a] * smaller_speed_factor)
            v_entry = current_speed[a]
            if limited:
                v_exit = F32(v_exit * v_factor)
                v_entry = F32(v_entry * v_factor)
            if v_exit > v_entry:
                if v_entry > 0 or v_exit < 0:
                    j = F32(v_exit - v_entry)       # coasting
                else:
                    j = v_exit if v_exit > -v_entry else -v_entry   # reversal
            else:
                if v_entry < 0 or v_exit > 0:
                    j = F32(v_entry - v_exit)
                else:
                    j = -v_exit if -v_exit > v_entry else v_entry
            if j > jerk[a]:
                v_factor = F32(v_factor * F32(jerk[a] / j))
                limited += 1
        if limited:
            vmax_junction = F32(vmax_junction * v_factor)
        threshold = F32(vmax_junction * F32(0.99))
        if gf[GF_PREV_SAFE] > threshold and safe_speed > threshold:
            vmax_junction = safe_speed
    else:
        vmax_junction = safe_speed
    gf[GF_PREV_SAFE] = safe_speed
    return F32(vmax_junction * vmax_junction)


@njit(cache=True, inline=INLINE)
def _classic_jerk_sqr_bugfix(gf, current_speed, nominal_speed, moves_queued, jerk, scratch_f):
    """bugfix-2.1.x max_entry_speed² by classic jerk: the junction speed is the lower nominal speed, the other
    move's per-axis speeds scaled to it; each axis' speed difference (from rest for a first move) within its
    jerk scales the junction down. No Průša safe-speed rule and no coasting/reversal cases (2.1.2's)."""
    speed_diff = scratch_f[2]
    for a in range(4):
        speed_diff[a] = current_speed[a]
    prev_nominal = gf[GF_PREV_NOMINAL]
    if moves_queued == 0 or prev_nominal < F32(0.000001):
        vmax_junction = nominal_speed            # a jerk from or to a full halt
    elif nominal_speed < prev_nominal:
        vmax_junction = nominal_speed
        previous_scale = F32(vmax_junction / prev_nominal)
        for a in range(4):
            speed_diff[a] = F32(speed_diff[a] - F32(gf[GF_PREV_SPEED + a] * previous_scale))
    else:
        vmax_junction = prev_nominal
        current_scale = F32(vmax_junction / nominal_speed)
        for a in range(4):
            speed_diff[a] = F32(F32(speed_diff[a] * current_scale) - gf[GF_PREV_SPEED + a])
    v_factor = F32(1)
    for a in range(4):
        j = F32(abs(speed_diff[a]))
        if F32(j * v_factor) > jerk[a]:
            v_factor = F32(jerk[a] / j)
    v = F32(vmax_junction * v_factor)
    return F32(v * v)


@njit(cache=True, inline=INLINE)
def _block_ticks_memo(memo, mode, key, timer_hz, ph):
    """The interrupt's ticks for the block whose trapezoid fields are ``key`` (12 int64: steps, initial,
    nominal and final rate, accelerate_until, decelerate_after, acceleration_rate, cruise rate, acceleration
    and deceleration time and their inverses), ``ph`` its phase ticks, in stepper ``mode`` (0: 2.1.2,
    1: bugfix-2.1.x, 2: S-curve). The time is a function of these integers alone, so a block seen before (a
    repeated object of a plate) is looked up in ``memo`` (direct-mapped by a hash of the key) instead of
    being summed again: the same integers either way."""
    h = np.uint64(timer_hz) ^ (np.uint64(mode) << np.uint64(56))
    for j in range(12):
        h = (h ^ np.uint64(key[j])) * np.uint64(0x100000001B3)
    h ^= h >> np.uint64(29)
    row = np.int64(h & np.uint64(MEMO_ROWS - 1))
    hit = memo[row, 0] == mode + 1 and memo[row, 1] == timer_hz
    j = 0
    while hit and j < 12:
        hit = memo[row, 2 + j] == key[j]
        j += 1
    if hit:
        ph[0] = memo[row, MEMO_KEY + 1]
        ph[1] = memo[row, MEMO_KEY + 2]
        ph[2] = memo[row, MEMO_KEY + 3]
        return memo[row, MEMO_KEY]
    if mode == 2:
        ticks = block_ticks_scurve_kernel(key[0], key[1], key[2], key[3], key[4], key[5], key[7], key[8], key[9],
                                          key[10], key[11], timer_hz, ph)
    elif mode == 1:
        ticks = block_ticks_kernel_bugfix(key[0], key[1], key[2], key[3], key[4], key[5], key[6], timer_hz, ph)
    else:
        ticks = block_ticks_kernel(key[0], key[1], key[2], key[3], key[4], key[5], key[6], timer_hz, ph)
    memo[row, 0] = mode + 1
    memo[row, 1] = timer_hz
    for j in range(12):
        memo[row, 2 + j] = key[j]
    memo[row, MEMO_KEY] = ticks
    memo[row, MEMO_KEY + 1] = ph[0]
    memo[row, MEMO_KEY + 2] = ph[1]
    memo[row, MEMO_KEY + 3] = ph[2]
    return ticks


@njit(cache=True, inline=INLINE)
def _pick_and_run(bf, bi, gi, out_i, out_f, timer_hz, acc_rate_scale, row_base, s_curve, scratch_i, memo,
                  version=VERSION_2_1_2):
    """The stepper: finish the busy block, skip sync blocks, pick up the next move block and time it
    (get_current_block + block_phase_isr). Returns False when the buffer is empty."""
    if gi[GI_BUSY] != 0:
        gi[GI_TAIL] = _next(bi, gi[GI_TAIL])
        gi[GI_BUSY] = 0
    while _queued(bi, gi) > 0:
        t = gi[GI_TAIL]
        # get_current_block(): the block becomes busy, the planned pointer is pushed past it
        gi[GI_NONBUSY] = _next(bi, t)
        if gi[GI_PLANNED] == t:
            gi[GI_PLANNED] = gi[GI_NONBUSY]
        if (bi[t, BI_FLAG] & FLAG_SYNC_POSITION) != 0:
            gi[GI_TAIL] = _next(bi, t)
            continue
        gi[GI_BUSY] = 1
        gi[GI_STARTED] = 1
        r = bi[t, BI_ROW] - row_base
        acc_steps = bi[t, BI_ACCEL_STEPS]
        acc_rate = np.int64(F32(F32(acc_steps) * acc_rate_scale))
        ph = scratch_i[3]
        # the trapezoid as the stepper copies it at pick-up: the key of the block-time memo
        key = memo[MEMO_ROWS]
        key[0] = bi[t, BI_SEC]
        key[1] = bi[t, BI_INITIAL_RATE]
        key[2] = bi[t, BI_NOMINAL_RATE]
        key[3] = bi[t, BI_FINAL_RATE]
        key[4] = bi[t, BI_ACCEL_UNTIL]
        key[5] = bi[t, BI_DECEL_AFTER]
        key[6] = acc_rate
        if s_curve:
            mode = 2
            key[7] = bi[t, BI_CRUISE_RATE]
            key[8] = bi[t, BI_ACC_TIME]
            key[9] = bi[t, BI_DEC_TIME]
            key[10] = bi[t, BI_ACC_TIME_INV]
            key[11] = bi[t, BI_DEC_TIME_INV]
        else:
            mode = 1 if version == VERSION_BUGFIX else 0
            for j in range(7, 12):
                key[j] = 0
        ticks = _block_ticks_memo(memo, mode, key, timer_hz, ph)
        out_i[r, OI_HAS_BLOCK] = 1
        out_i[r, OI_T_PICK] = gi[GI_CLOCK]
        gi[GI_CLOCK] += ticks
        out_i[r, OI_T_END] = gi[GI_CLOCK]
        out_i[r, OI_SEC] = bi[t, BI_SEC]
        out_i[r, OI_NOMINAL_RATE] = bi[t, BI_NOMINAL_RATE]
        out_i[r, OI_INITIAL_RATE] = bi[t, BI_INITIAL_RATE]
        out_i[r, OI_FINAL_RATE] = bi[t, BI_FINAL_RATE]
        out_i[r, OI_ACCEL_UNTIL] = bi[t, BI_ACCEL_UNTIL]
        out_i[r, OI_DECEL_AFTER] = bi[t, BI_DECEL_AFTER]
        out_i[r, OI_ACCEL_STEPS] = acc_steps
        out_i[r, OI_ACC_T] = ph[0]
        out_i[r, OI_CRUISE_T] = ph[1]
        out_i[r, OI_DEC_T] = ph[2]
        out_i[r, OI_FLAG] = bi[t, BI_FLAG]
        for a in range(4):
            out_i[r, OI_SX + a] = bi[t, BI_SX + a]
        # what the interrupt needs to issue the block's pulses (stepper.marlin_isr.blocks_pulses_kernel)
        out_i[r, OI_DIR_BITS] = bi[t, BI_DIR_BITS]
        out_i[r, OI_CRUISE_RATE] = bi[t, BI_CRUISE_RATE]
        out_i[r, OI_ACCELERATION_TIME] = bi[t, BI_ACC_TIME]
        out_i[r, OI_DECELERATION_TIME] = bi[t, BI_DEC_TIME]
        out_i[r, OI_ACC_TIME_INV] = bi[t, BI_ACC_TIME_INV]
        out_i[r, OI_DEC_TIME_INV] = bi[t, BI_DEC_TIME_INV]
        out_f[r, OF_ENTRY_SQR] = bf[t, BF_ENTRY_SQR]
        out_f[r, OF_NOMINAL_SPEED] = bf[t, BF_NOMINAL_SPEED]
        out_f[r, OF_MM] = bf[t, BF_MM]
        out_f[r, OF_ACCEL] = bf[t, BF_ACCEL]
        # exit speed as executed: final_rate / nominal_rate of nominal speed
        fr = F32(F32(bi[t, BI_FINAL_RATE]) / F32(bi[t, BI_NOMINAL_RATE]) * bf[t, BF_NOMINAL_SPEED])
        out_f[r, OF_EXIT_SQR] = F32(fr * fr)
        return True
    return False


@njit(cache=True, _nrt=False)
def marlin_run_kernel(kind, tgt, reset_bits, reset_pos, fr, acc_p, acc_t, acc_r, lim, vmax, amax_steps, cutoff,
                      jerk, min_feed, min_travel, wait_ticks, spm, mm_per_step, min_segment_time_us, timer_hz,
                      acc_rate_scale, final, row_base, bf, bi, gi, gf, out_i, out_f, junction_mode, amax_mm, jdev,
                      advance_k, s_curve, scratch_f, scratch_i, memo, version=VERSION_2_1_2):
    """Run rows ``gi[GI_NEXT_ROW] - row_base ..`` of this window through Marlin's host loop, planner and
    stepper until the input runs out (``final``: then until the buffer is empty).

    Row arrays are indexed from ``row_base`` (``bi[., BI_ROW]`` and ``gi[GI_NEXT_ROW]`` are absolute row
    numbers); times are ticks of ``timer_hz`` from the first pick-up. ``lim``: each row's LIMITS row, which
    indexes the settings tables ``vmax`` … ``min_travel``, ``amax_mm``, ``jdev``, ``advance_k``. Returns the
    absolute number of the first row whose block has not run yet (rows before it are final). ``version``: whose rules run
    (VERSION_2_1_2, VERSION_BUGFIX). ``scratch_f``, ``scratch_i``, ``memo``: working rows and the block-time
    memo (:func:`new_scratch`, one per run: it is keyed by the stepper mode, not by the machine's settings);
    compiled without numba's reference counting, so nothing it calls allocates."""
    n = len(kind)
    end_row = row_base + n
    while True:
        # the host: Marlin's main loop fills the buffer (15 usable slots) in no time
        while gi[GI_NEXT_ROW] < end_row and _queued(bi, gi) < len(bi) - 1:
            r = gi[GI_NEXT_ROW] - row_base
            k = kind[r]
            if k == ROW_WAIT:
                if _queued(bi, gi) > 0 or gi[GI_BUSY] != 0:
                    break                      # M400 / G4 / G28: wait for the buffer to drain
                out_i[r, OI_HAS_BLOCK] = 2
                out_i[r, OI_T_PICK] = gi[GI_CLOCK]
                if gi[GI_STARTED] != 0:
                    # idle: the ISR polls every ms; the next block is picked up at the first poll after
                    per_ms = timer_hz // 1000
                    nms = (wait_ticks[r] + per_ms - 1) // per_ms
                    if nms < 1:
                        nms = 1
                    gi[GI_CLOCK] += nms * per_ms
                out_i[r, OI_T_END] = gi[GI_CLOCK]
                gi[GI_NEXT_ROW] += 1
                continue
            if k == ROW_SKIP:
                gi[GI_NEXT_ROW] += 1
                continue
            if reset_bits[r] != 0 and gi[GI_RESET_DONE] == 0:
                # G92: a new position in steps; with blocks queued it travels as a sync block
                for a in range(4):
                    if (reset_bits[r] >> a) & 1:
                        gi[GI_PX + a] = _lroundf(F32(reset_pos[r, a] * spm[a]))
                        gf[GF_POS_FLOAT + a] = reset_pos[r, a]
                gi[GI_RESET_DONE] = 1
                if _queued(bi, gi) > 0 or gi[GI_BUSY] != 0:
                    buffer_sync_block(bf, bi, gi, gi[GI_NEXT_ROW])
                    continue                   # the move needs a slot of its own
            gi[GI_RESET_DONE] = 0
            L = lim[r]
            if _populate_block(bf, bi, gi, gf, gi[GI_NEXT_ROW], tgt[r], fr[r], acc_p[r], acc_t[r], acc_r[r], vmax[L],
                               amax_steps[L], cutoff[L], jerk[L], min_feed[L], min_travel[L], spm, mm_per_step,
                               min_segment_time_us, junction_mode, amax_mm[L], jdev[L], advance_k[L], scratch_f,
                               scratch_i, version):
                h = gi[GI_HEAD]
                gi[GI_HEAD] = _next(bi, h)
                if version == VERSION_BUGFIX:
                    # the newest block must be able to stop at its own minimum speed (no arc hint here)
                    recalculate_bugfix(bf, bi, gi, bf[h, BF_MIN_ENTRY_SQR], timer_hz)
                else:
                    recalculate(bf, bi, gi)
            gi[GI_NEXT_ROW] += 1
        if not final and gi[GI_NEXT_ROW] >= end_row and _queued(bi, gi) < len(bi) - 1:
            break                              # the host would queue more: wait for the next rows
        if not _pick_and_run(bf, bi, gi, out_i, out_f, timer_hz, acc_rate_scale, row_base, s_curve, scratch_i, memo,
                             version):
            if gi[GI_NEXT_ROW] >= end_row:
                break
    # rows before the oldest block not yet run (or the next row to read) are final
    first = gi[GI_NEXT_ROW]
    t = gi[GI_TAIL]
    if gi[GI_BUSY] != 0:
        t = _next(bi, t)
    while t != gi[GI_HEAD]:
        if bi[t, BI_ROW] < first:
            first = bi[t, BI_ROW]
        t = _next(bi, t)
    return first
