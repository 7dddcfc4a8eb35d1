"""grbl 1.1's planner and stepper as they run: the ``grbl-1.1`` firmware model (docs/design.md, *grbl 1.1*).

grbl (github gnea/grbl, 1.1h) plans and steps in single precision on an 8-bit MCU. This module runs the same
rules on the MOVE rows gcodeplan's reader makes, with the firmware's arithmetic, so that the time of every
step, and so of every line and of the whole program, is the one the firmware gives:

* ``planner.c``: step-rounded targets (``lround(target·steps/mm)``, a move of zero steps is dropped and its
  displacement goes into the next one), per-axis limited acceleration and rapid rate, junction deviation with
  the acceleration the axes allow along the junction vector, the 16-block ring (15 usable) with its
  reverse/forward passes and its *planned* pointer (:func:`_plan_buffer_line`, :func:`_planner_recalculate`);
* ``stepper.c``: the segment generator (``st_prep_buffer``, :func:`_st_prep_buffer`): 10 ms segments of
  constant step rate (``ACCELERATION_TICKS_PER_SECOND`` 100), its ramp state machine, the step-remainder
  time carried from segment to segment, AMASS levels, the 16 MHz Timer1 in CTC mode (a period is
  OCR1A + 1 cycles) and the stepper interrupt (:func:`_isr`): Bresenham across axes, a step pulse written at
  the interrupt *after* the one that decided it;
* the main loop as grbl-sim's lock-step mode runs it: parsing and planning take no time, the planner is
  refilled as soon as a block leaves it (a block leaves when its last segment is *prepared*, not executed),
  the cycle starts when the 15 blocks are full or at a sync (G4, M2/M30, spindle/coolant changes, laser mode's
  syncs: KIND_DWELL / KIND_WAIT rows, gcode/commands_state.py), G4 P is rounded up to 50 ms steps
  (``DWELL_TIME_STEP``);
* a program's ``$`` settings (``$11``, ``$110``-``$122``, accepted only while grbl is idle, gcode/grbl_line.py)
  arrive as a new LIMITS row: the operations of its rows are planned with those settings (the stream mode's
  ``_feed``; :func:`run` takes one set of settings for the whole program).

:func:`run`'s ``buffer_blocks`` sets the planner ring's size (16 by default, grbl's BLOCK_BUFFER_SIZE; the kernels
take it from their arrays), and ``quantised=False`` runs grbl's plan in float64 and continuous time instead
(:mod:`gcodeplan.planner.grbl_ideal` says what stays grbl's and what is turned off).

Floating point follows the C source: ``float`` variables are float32 and ``double`` literals promote an
expression to float64 before it is stored back into a float (the x86 build grbl-sim runs, the reference).
Function boundaries follow grbl's so the code can be diffed against a new release.
"""
from __future__ import annotations

import math

from .._jit import njit
import numpy as np

from ..schema import FLAG_ARC, FLAG_RAPID, KIND_DWELL, KIND_WAIT, LIMIT_ACCEL, LIMIT_AXIS, LIMIT_FEED, LIMIT_NONE
from .grbl_ideal import check_buffer_blocks, run_ideal

f32 = np.float32

# grbl 1.1h config.h / planner.h / stepper.h / cpu_map (ATmega328P, 16 MHz)
F_CPU = 16_000_000                      # Hz, the tick of every time below
BLOCK_BUFFER_SIZE = 16                  # planner ring; one slot always empty: 15 usable blocks (the default:
                                        # GrblState's ``buffer_blocks``, the kernels read it as bf.shape[0])
SEGMENT_BUFFER_SIZE = 6                 # step segment ring; 5 usable segments
ST_BLOCK_BUFFER_SIZE = SEGMENT_BUFFER_SIZE - 1
ACCELERATION_TICKS_PER_SECOND = 100
DT_SEGMENT = 1.0 / (ACCELERATION_TICKS_PER_SECOND * 60.0)   # min per segment (a double in C)
REQ_MM_INCREMENT_SCALAR = 1.25
MAX_AMASS_LEVEL = 3
AMASS_LEVEL1 = F_CPU // 8000            # cycles per step below which AMASS is off
AMASS_LEVEL2 = F_CPU // 4000
AMASS_LEVEL3 = F_CPU // 2000
CYCLES_PER_MINUTE = 16 * 1000000 * 60   # (TICKS_PER_MICROSECOND*1000000*60)
SOME_LARGE_VALUE = 1.0e38
MINIMUM_FEED_RATE = 1.0                 # mm/min
DWELL_TIME_STEP_MS = 50
DWELL_TICKS = F_CPU // 1000 * DWELL_TIME_STEP_MS

RAMP_ACCEL, RAMP_CRUISE, RAMP_DECEL, RAMP_DECEL_OVERRIDE = 0, 1, 2, 3
PREP_FLAG_RECALCULATE = 1
PREP_FLAG_DECEL_OVERRIDE = 8

OP_LINE, OP_SYNC = 0, 1
N_INFO = 6           # op_info columns: entry, peak, exit, nominal speed mm/min, acceleration mm/min², length mm


def read_float(text: str) -> np.float32:
    """A number as grbl's ``read_float`` (nuts_bolts.c) reads it: the digits into a uint32 (at most 8
    significant), then scaled by 0.01 / 0.1 / 10 in single precision with double constants. Not always the
    float nearest to the decimal: grbl's own value is what it plans with."""
    s = text.strip()
    neg = s.startswith("-")
    if s[:1] in "+-":
        s = s[1:]
    intval, exp, ndigit, isdecimal = 0, 0, 0, False
    for ch in s:
        if ch.isdigit():
            ndigit += 1
            if ndigit <= 8:
                if isdecimal:
                    exp -= 1
                intval = intval * 10 + int(ch)
            elif not isdecimal:
                exp += 1
        elif ch == "." and not isdecimal:
            isdecimal = True
        else:
            break
    if not ndigit:
        raise ValueError(f"not a number: {text!r}")
    fval = f32(intval)
    if fval != 0:
        while exp <= -2:
            fval = f32(float(fval) * 0.01)
            exp += 2
        if exp < 0:
            fval = f32(float(fval) * 0.1)
        elif exp > 0:
            while exp > 0:
                fval = f32(float(fval) * 10.0)
                exp -= 1
    return -fval if neg else fval


def grbl_float(x: float) -> np.float32:
    """The float grbl holds for a value gcodeplan read as the float64 ``x``: when ``x`` is a short decimal (at
    most 8 significant digits, what G-code files hold), grbl's :func:`read_float` of that decimal, which can be
    one unit in the last place away from the nearest float; otherwise (a value gcodeplan computed: inch
    conversion, offsets) the nearest float."""
    return grbl_floats(np.array([x], dtype=np.float64))[0]


def grbl_steps_of(target_mm, steps_per_mm: np.ndarray) -> np.ndarray:
    """planner.c plan_buffer_line's target in steps of the X Y Z target ``target_mm`` (mm, as gcodeplan read
    it): ``lround(target·steps/mm)`` on grbl's floats (:func:`grbl_floats`; ``steps_per_mm`` float32, as
    :class:`GrblSettings` holds them). Two targets of equal steps make no block."""
    prod = (grbl_floats(np.asarray(target_mm, dtype=np.float64)) * steps_per_mm).astype(np.float32)
    p = prod.astype(np.float64)
    return (np.sign(p) * np.floor(np.abs(p) + 0.5)).astype(np.int64)      # C lround: half away from zero


def grbl_floats(values: np.ndarray) -> np.ndarray:
    """:func:`grbl_float` of every value (float32 array): the shortest decimal of each value (the fewest
    decimals d ≤ 8 that give it back), then read_float's arithmetic on its digits."""
    return _grbl_floats_kernel(np.asarray(values, dtype=np.float64).ravel()).reshape(np.shape(values))


# 10**d for the decimals grbl_floats tries: exact in float64
_POW10 = np.array([10.0 ** d for d in range(9)], dtype=np.float64)


@njit(cache=True, nogil=True)
def _grbl_float_of(x, pow10):
    """grbl_float of one float64 (see :func:`grbl_floats`)."""
    mag = abs(x)
    if not (math.isfinite(x) and mag < 1e8 and mag > 0):
        return np.float32(x)
    for d in range(9):
        scale = pow10[d]
        iv = np.rint(mag * scale)              # half to even, as np.round
        if iv / scale == mag and iv < 1e8:
            f = np.float32(iv)
            e = -d
            while e <= -2:                     # read_float: scaled by 0.01, then 0.1, each stored in a float
                f = np.float32(np.float64(f) * 0.01)
                e += 2
            if e < 0:
                f = np.float32(np.float64(f) * 0.1)
            return -f if x < 0 else f
    return np.float32(x)


@njit(cache=True, nogil=True)
def _grbl_floats_kernel(x):
    out = np.empty(x.shape[0], np.float32)
    for i in range(x.shape[0]):
        out[i] = _grbl_float_of(x[i], _POW10)
    return out


class GrblSettings:
    """The ``$`` settings the planner and stepper use, in grbl's units and precision: steps/mm ($100-$102),
    max rate mm/min ($110-$112), acceleration mm/min² ($120-$122 × 60 × 60, as settings.c stores it),
    junction deviation mm ($11), arc tolerance mm ($12)."""

    def __init__(self, steps_per_mm, max_rate_mm_min, accel_mm_s2, junction_deviation_mm, arc_tolerance_mm):
        self.steps_per_mm = np.array([f32(v) for v in steps_per_mm], dtype=np.float32)
        self.max_rate = np.array([f32(v) for v in max_rate_mm_min], dtype=np.float32)
        acc = []
        for v in accel_mm_s2:
            a = f32(v)
            a = f32(a * f32(60))
            acc.append(f32(a * f32(60)))
        self.acceleration = np.array(acc, dtype=np.float32)
        self.junction_deviation = f32(junction_deviation_mm)
        self.arc_tolerance = f32(arc_tolerance_mm)
        self.idle_lock_ticks = 0
        # the values as given, float64 in mm/s, mm/s², mm (the plan without quantisation, grbl_ideal)
        self.exact_max_v = np.array(max_rate_mm_min, dtype=np.float64) / 60.0
        self.exact_max_a = np.array(accel_mm_s2, dtype=np.float64)
        self.exact_junction_deviation = float(junction_deviation_mm)

    @classmethod
    def from_machine(cls, m) -> "GrblSettings":
        """From a :class:`~gcodeplan.machine.Machine` (mm/s, mm/s²): each value is the float grbl would hold
        for the ``$`` line that sets it (a rate of 83.333… mm/s is $110 = 5000)."""
        def rate(v):
            return read_float(_decimal(v * 60.0))

        axes = [m.axes[a] for a in "xyz"]
        s = cls([read_float(_decimal(a.steps_per_mm)) for a in axes],
                [rate(a.max_velocity) for a in axes],
                [read_float(_decimal(a.max_accel)) for a in axes],
                read_float(_decimal(m.junction_deviation)), read_float(_decimal(m.arc_tolerance)))
        s.exact_max_v = np.array([float(a.max_velocity) for a in axes])
        s.exact_max_a = np.array([float(a.max_accel) for a in axes])
        s.exact_junction_deviation = float(m.junction_deviation)
        # $1 (stepper idle delay): st_go_idle busy-waits that long inside the stepper interrupt at every stop,
        # unless it is 255 (keep the motors enabled)
        idle_ms = int(getattr(m, "grbl_idle_lock_ms", 255))
        s.idle_lock_ticks = 0 if idle_ms == 255 else idle_ms * (F_CPU // 1000)
        return s


def steps_per_mm_of(machine) -> np.ndarray:
    """grbl's steps/mm ($100-$102) of ``machine``'s X Y Z as the firmware holds them (float32), as
    :meth:`GrblSettings.from_machine` reads them."""
    return np.array([read_float(_decimal(machine.axes[a].steps_per_mm)) for a in "xyz"], dtype=np.float32)


def settings_of_limits(machine, limits_row) -> "GrblSettings":
    """The settings of ``machine`` with the max rates ($110-$112), accelerations ($120-$122) and junction
    deviation ($11) of a LIMITS row (mm/s, mm/s², mm): a program's ``$`` lines change those
    (gcode/grbl_line.py); each value is the float grbl holds for its ``$`` line, as in :meth:`from_machine`."""
    from dataclasses import replace

    axes = dict(machine.axes)
    for a in "xyz":
        axes[a] = replace(axes[a], max_velocity=float(limits_row["axis_v_" + a]),
                          max_accel=float(limits_row["axis_a_" + a]))
    return GrblSettings.from_machine(replace(machine, axes=axes,
                                             junction_deviation=float(limits_row["junction_dev"])))


def _decimal(v: float) -> str:
    """``$`` value text for v: grbl prints settings with 3 decimals; a value read back from such a report (or
    typed by a user) has few digits, so the shortest repr rounded to 6 decimals is what the firmware got."""
    if not math.isfinite(v):
        raise ValueError(f"grbl setting must be finite, got {v}")
    return f"{round(v, 6):.6f}"


# --------------------------------------------------------------------------- the simulation
# State lives in small arrays so one numba function can run the whole program (grbl's globals). The functions
# run once per segment or per block (_prep_then_wait, _st_prep_buffer and its steps _prep_*, _isr,
# _rest_of_segment, _plan_buffer_line) are inlined into the feed kernel (inline="always"): a call of a compiled numba function
# with its ~20 array arguments costs more than the work of a segment (measured: the kernel 2.5× faster).
# planner ring, per block
B_MM, B_ACC, B_RAPID, B_PROG, B_ENTRY2, B_MAXENTRY2, B_MAXJUNC2 = range(7)
N_BF = 7


@njit(cache=True)
def _limit_value_by_axis_maximum(max_value, unit_vec):
    limit = np.float32(SOME_LARGE_VALUE)
    for i in range(3):
        if unit_vec[i] != 0:
            v = abs(np.float64(max_value[i] / unit_vec[i]))
            if v < limit:
                limit = np.float32(v)
    return limit


@njit(cache=True)
def _convert_delta_vector_to_unit_vector(vec):
    mag = np.float32(0.0)
    for i in range(3):
        if vec[i] != 0.0:
            mag = np.float32(mag + np.float32(vec[i] * vec[i]))
    mag = np.float32(math.sqrt(np.float64(mag)))
    inv = np.float32(1.0 / np.float64(mag))
    for i in range(3):
        vec[i] = np.float32(vec[i] * inv)
    return mag


@njit(cache=True)
def _nominal_speed(bf, b, rapid):
    """plan_compute_profile_nominal_speed, overrides at 100 %."""
    v = bf[b, B_PROG]
    if not rapid[b]:
        if v > bf[b, B_RAPID]:
            v = bf[b, B_RAPID]
    if v > np.float32(MINIMUM_FEED_RATE):
        return v
    return np.float32(MINIMUM_FEED_RATE)


@njit(cache=True)
def _next(i, n):
    i += 1
    return 0 if i == n else i


@njit(cache=True)
def _prev(i, n):
    return n - 1 if i == 0 else i - 1


class _State:
    """Names of the integer (``si``) and float32 (``sf``) state slots of the simulation, grbl's globals."""


# integer state slots
I_HEAD, I_TAIL, I_NEXT_HEAD, I_PLANNED = 0, 1, 2, 3
I_PL_BLOCK, I_ST_BLOCK_INDEX, I_RAMP, I_RECALC = 4, 5, 6, 7
I_SEG_HEAD, I_SEG_TAIL, I_SEG_NEXT_HEAD = 8, 9, 10
I_EXEC_SEG, I_EXEC_BLOCK, I_STEP_COUNT, I_OUTBITS, I_DIRBITS = 11, 12, 13, 14, 15
I_RUNNING, I_OCR, I_CYCLE, I_NSTEPS_OUT = 16, 17, 18, 19
I_CX, I_CY, I_CZ, I_SX, I_SY, I_SZ = 20, 21, 22, 23, 24, 25
I_TICK, I_NEXT_ISR, I_LAST_MATCH, I_POS_X, I_POS_Y, I_POS_Z = 26, 27, 28, 29, 30, 31
I_PHASE = 32          # TCNT1 at the interrupt that fired at once at a cycle start; -1 after a compare match
I_STARTED, I_T0, I_NEXT_OP, I_IDLE_LOCK, I_LAST_PULSE = 33, 34, 35, 36, 37
N_SI = 38
# float32 state slots: prep (st_prep_t) and pl.previous_*
F_STEPS_REM, F_STEP_PER_MM, F_REQ_MM, F_DT_REM, F_CUR_V, F_EXIT_V, F_MM_COMPLETE = 0, 1, 2, 3, 4, 5, 6
F_ACC_UNTIL, F_DEC_AFTER, F_MAX_V, F_PREV_NOMINAL, F_PUX, F_PUY, F_PUZ = 7, 8, 9, 10, 11, 12, 13
N_SF = 14


@njit(cache=True)
def _planner_recalculate(si, sf, bf):
    """planner.c planner_recalculate: reverse pass from the newest block back to the planned pointer, then the
    forward pass that moves the planned pointer past every block that can no longer change."""
    n = bf.shape[0]
    head = si[I_HEAD]
    block_index = _prev(head, n)
    if block_index == si[I_PLANNED]:
        return
    cur = block_index
    bf[cur, B_ENTRY2] = min(bf[cur, B_MAXENTRY2], np.float32(np.float32(2) * bf[cur, B_ACC] * bf[cur, B_MM]))
    block_index = _prev(block_index, n)
    if block_index == si[I_PLANNED]:
        if block_index == si[I_TAIL]:
            _st_update_plan_block_parameters(si, sf, bf)
    else:
        while block_index != si[I_PLANNED]:
            nxt = cur
            cur = block_index
            block_index = _prev(block_index, n)
            if block_index == si[I_TAIL]:
                _st_update_plan_block_parameters(si, sf, bf)
            if bf[cur, B_ENTRY2] != bf[cur, B_MAXENTRY2]:
                e2 = np.float32(bf[nxt, B_ENTRY2] + np.float32(np.float32(2) * bf[cur, B_ACC]) * bf[cur, B_MM])
                if e2 < bf[cur, B_MAXENTRY2]:
                    bf[cur, B_ENTRY2] = e2
                else:
                    bf[cur, B_ENTRY2] = bf[cur, B_MAXENTRY2]
    nxt = si[I_PLANNED]
    block_index = _next(si[I_PLANNED], n)
    while block_index != head:
        cur = nxt
        nxt = block_index
        if bf[cur, B_ENTRY2] < bf[nxt, B_ENTRY2]:
            e2 = np.float32(bf[cur, B_ENTRY2] + np.float32(np.float32(2) * bf[cur, B_ACC]) * bf[cur, B_MM])
            if e2 < bf[nxt, B_ENTRY2]:
                bf[nxt, B_ENTRY2] = e2
                si[I_PLANNED] = block_index
        if bf[nxt, B_ENTRY2] == bf[nxt, B_MAXENTRY2]:
            si[I_PLANNED] = block_index
        block_index = _next(block_index, n)


@njit(cache=True)
def _st_update_plan_block_parameters(si, sf, bf):
    """stepper.c: the block being prepared was re-planned: restart its profile from the current speed."""
    if si[I_PL_BLOCK] >= 0:
        si[I_RECALC] |= PREP_FLAG_RECALCULATE
        bf[si[I_PL_BLOCK], B_ENTRY2] = np.float32(sf[F_CUR_V] * sf[F_CUR_V])
        si[I_PL_BLOCK] = -1


@njit(cache=True, inline="always")
def _plan_buffer_line(si, sf, bf, bsteps, bdir, bop, brapid, target, rate, rapid, op, steps_per_mm, max_rate,
                      acceleration, junction_deviation, target_steps, unit_vecs):
    """planner.c plan_buffer_line. Returns False for a block of zero steps (dropped; the position stays).
    ``target_steps`` (3 int64) and ``unit_vecs`` (2×3 float32): scratch, the C function's local arrays."""
    b = si[I_HEAD]
    unit_vec = unit_vecs[0]
    sec = 0
    dirb = 0
    pos = (si[I_POS_X], si[I_POS_Y], si[I_POS_Z])
    for i in range(3):
        target_steps[i] = _lround(np.float32(target[i] * steps_per_mm[i]))
        d = target_steps[i] - pos[i]
        bsteps[b, i] = abs(d)
        if bsteps[b, i] > sec:
            sec = bsteps[b, i]
        delta_mm = np.float32(np.float32(d) / steps_per_mm[i])
        unit_vec[i] = delta_mm
        if delta_mm < 0.0:
            dirb |= 1 << i
    if sec == 0:
        return False
    bdir[b] = dirb
    bop[b] = op
    brapid[b] = rapid
    bf[b, B_MM] = _convert_delta_vector_to_unit_vector(unit_vec)
    bf[b, B_ACC] = _limit_value_by_axis_maximum(acceleration, unit_vec)
    bf[b, B_RAPID] = _limit_value_by_axis_maximum(max_rate, unit_vec)
    if rapid:
        bf[b, B_PROG] = bf[b, B_RAPID]
    else:
        bf[b, B_PROG] = rate
    if si[I_HEAD] == si[I_TAIL]:
        bf[b, B_ENTRY2] = 0.0
        bf[b, B_MAXJUNC2] = 0.0
    else:
        cos_theta = np.float32(0.0)
        junction_unit_vec = unit_vecs[1]
        for i in range(3):
            cos_theta = np.float32(cos_theta - np.float32(sf[F_PUX + i] * unit_vec[i]))
            junction_unit_vec[i] = np.float32(unit_vec[i] - sf[F_PUX + i])
        if cos_theta > 0.999999:
            bf[b, B_MAXJUNC2] = 0.0
        elif cos_theta < -0.999999:
            bf[b, B_MAXJUNC2] = np.float32(SOME_LARGE_VALUE)
        else:
            _convert_delta_vector_to_unit_vector(junction_unit_vec)
            junction_acc = _limit_value_by_axis_maximum(acceleration, junction_unit_vec)
            sin_theta_d2 = np.float32(math.sqrt(0.5 * (1.0 - np.float64(cos_theta))))
            v2 = np.float64(np.float32(junction_acc * junction_deviation) * sin_theta_d2) / (1.0 - np.float64(sin_theta_d2))
            bf[b, B_MAXJUNC2] = np.float32(max(0.0, v2))
    nominal = _nominal_speed(bf, b, brapid)
    prev_nominal = sf[F_PREV_NOMINAL]
    if nominal > prev_nominal:
        bf[b, B_MAXENTRY2] = np.float32(prev_nominal * prev_nominal)
    else:
        bf[b, B_MAXENTRY2] = np.float32(nominal * nominal)
    if bf[b, B_MAXENTRY2] > bf[b, B_MAXJUNC2]:
        bf[b, B_MAXENTRY2] = bf[b, B_MAXJUNC2]
    sf[F_PREV_NOMINAL] = nominal
    for i in range(3):
        sf[F_PUX + i] = unit_vec[i]
    si[I_POS_X] = target_steps[0]
    si[I_POS_Y] = target_steps[1]
    si[I_POS_Z] = target_steps[2]
    si[I_HEAD] = si[I_NEXT_HEAD]
    si[I_NEXT_HEAD] = _next(si[I_HEAD], bf.shape[0])
    _planner_recalculate(si, sf, bf)
    return True


@njit(cache=True)
def _lround(x):
    """C lround: half away from zero."""
    v = np.float64(x)
    if v >= 0.0:
        return np.int64(math.floor(v + 0.5))
    return -np.int64(math.floor(-v + 0.5))


@njit(cache=True, inline="always")
def _st_prep_buffer(si, sf, bf, bsteps, bdir, bop, brapid, st_steps, st_sec, st_dir, st_op, seg_n, seg_cycles,
                    seg_block, seg_amass, window_base, op_info):
    """stepper.c st_prep_buffer, normal operation (no feed hold, parking or overrides): fill the segment ring
    with 10 ms segments of the block at the planner's tail. Its steps in grbl's order, one function each: take
    the tail block (:func:`_prep_load_block`) and compute its velocity profile (:func:`_prep_velocity_profile`),
    then per segment the distance covered in its time (:func:`_prep_segment_distance`) and its steps and step
    rate (:func:`_prep_segment_step_rate`); a block whose last segment is made leaves the planner."""
    while si[I_SEG_TAIL] != si[I_SEG_NEXT_HEAD]:
        if si[I_PL_BLOCK] < 0:
            if si[I_HEAD] == si[I_TAIL]:
                return
            pb = si[I_TAIL]
            si[I_PL_BLOCK] = pb
            loaded = _prep_load_block(si, sf, bf, bsteps, bdir, bop, st_steps, st_sec, st_dir, st_op, pb)
            nominal = _prep_velocity_profile(si, sf, bf, brapid, pb)
            if loaded:
                _record_profile(si, sf, bf, bop, pb, nominal, window_base, op_info)
        pb = si[I_PL_BLOCK]
        seg = si[I_SEG_HEAD]
        seg_block[seg] = si[I_ST_BLOCK_INDEX]
        dt, mm_remaining = _prep_segment_distance(si, sf, bf, pb)
        _prep_segment_step_rate(sf, seg, dt, mm_remaining, seg_n, seg_cycles, seg_amass)
        si[I_SEG_HEAD] = si[I_SEG_NEXT_HEAD]
        si[I_SEG_NEXT_HEAD] = _next(si[I_SEG_NEXT_HEAD], SEGMENT_BUFFER_SIZE)
        bf[pb, B_MM] = mm_remaining
        if mm_remaining == sf[F_MM_COMPLETE]:
            if mm_remaining > 0.0:
                return
            si[I_PL_BLOCK] = -1
            # plan_discard_current_block
            if si[I_HEAD] != si[I_TAIL]:
                bi = _next(si[I_TAIL], bf.shape[0])
                if si[I_TAIL] == si[I_PLANNED]:
                    si[I_PLANNED] = bi
                si[I_TAIL] = bi


@njit(cache=True, inline="always")
def _prep_load_block(si, sf, bf, bsteps, bdir, bop, st_steps, st_sec, st_dir, st_op, pb):
    """st_prep_buffer, a new planner block ``pb``: after a re-plan of the block being prepared only its profile
    is recomputed (returns False); otherwise its steps (AMASS-scaled) go to the stepper's block ring and the
    prep state starts at the block's entry speed (returns True)."""
    if si[I_RECALC] & PREP_FLAG_RECALCULATE:
        si[I_RECALC] = 0
        return False
    sbi = _next(si[I_ST_BLOCK_INDEX], ST_BLOCK_BUFFER_SIZE)
    si[I_ST_BLOCK_INDEX] = sbi
    st_dir[sbi] = bdir[pb]
    sec = 0
    for i in range(3):
        st_steps[sbi, i] = bsteps[pb, i] << MAX_AMASS_LEVEL
        if bsteps[pb, i] > sec:
            sec = bsteps[pb, i]
    st_sec[sbi] = sec << MAX_AMASS_LEVEL
    st_op[sbi] = bop[pb]
    sf[F_STEPS_REM] = np.float32(sec)
    sf[F_STEP_PER_MM] = np.float32(sf[F_STEPS_REM] / bf[pb, B_MM])
    sf[F_REQ_MM] = np.float32(REQ_MM_INCREMENT_SCALAR / np.float64(sf[F_STEP_PER_MM]))
    sf[F_DT_REM] = 0.0
    sf[F_CUR_V] = np.float32(math.sqrt(np.float64(bf[pb, B_ENTRY2])))
    return True


@njit(cache=True, inline="always")
def _prep_velocity_profile(si, sf, bf, brapid, pb):
    """st_prep_buffer, the velocity profile of block ``pb`` (or of what is left of it) from its entry and exit
    speeds: the ramp it starts in, where acceleration ends and deceleration starts (mm left), its top speed.
    Returns the block's nominal speed (mm/min)."""
    sf[F_MM_COMPLETE] = 0.0
    acc = bf[pb, B_ACC]
    mm = bf[pb, B_MM]
    entry2 = bf[pb, B_ENTRY2]
    inv_2_accel = np.float32(0.5 / np.float64(acc))
    si[I_RAMP] = RAMP_ACCEL
    sf[F_ACC_UNTIL] = mm
    nb = _next(pb, bf.shape[0])
    exit2 = np.float32(0.0) if nb == si[I_HEAD] else bf[nb, B_ENTRY2]
    sf[F_EXIT_V] = np.float32(math.sqrt(np.float64(exit2)))
    nominal = _nominal_speed(bf, pb, brapid)
    nominal2 = np.float32(nominal * nominal)
    intersect = np.float32(0.5 * np.float64(np.float32(mm + np.float32(inv_2_accel * np.float32(entry2 - exit2)))))
    if entry2 > nominal2:
        sf[F_ACC_UNTIL] = np.float32(mm - np.float32(inv_2_accel * np.float32(entry2 - nominal2)))
        if sf[F_ACC_UNTIL] <= 0.0:
            si[I_RAMP] = RAMP_DECEL
            sf[F_EXIT_V] = np.float32(math.sqrt(np.float64(np.float32(entry2 - np.float32(np.float32(2) * acc) * mm))))
            si[I_RECALC] |= PREP_FLAG_DECEL_OVERRIDE
        else:
            sf[F_DEC_AFTER] = np.float32(inv_2_accel * np.float32(nominal2 - exit2))
            sf[F_MAX_V] = nominal
            si[I_RAMP] = RAMP_DECEL_OVERRIDE
    elif intersect > 0.0:
        if intersect < mm:
            sf[F_DEC_AFTER] = np.float32(inv_2_accel * np.float32(nominal2 - exit2))
            if sf[F_DEC_AFTER] < intersect:
                sf[F_MAX_V] = nominal
                if entry2 == nominal2:
                    si[I_RAMP] = RAMP_CRUISE
                else:
                    sf[F_ACC_UNTIL] = np.float32(sf[F_ACC_UNTIL] - np.float32(inv_2_accel * np.float32(nominal2 - entry2)))
            else:
                sf[F_ACC_UNTIL] = intersect
                sf[F_DEC_AFTER] = intersect
                sf[F_MAX_V] = np.float32(math.sqrt(2.0 * np.float64(acc) * np.float64(intersect) + np.float64(exit2)))
        else:
            si[I_RAMP] = RAMP_DECEL
    else:
        sf[F_ACC_UNTIL] = 0.0
        sf[F_MAX_V] = sf[F_EXIT_V]
    return nominal


@njit(cache=True, inline="always")
def _record_profile(si, sf, bf, bop, pb, nominal, window_base, op_info):
    """op_info of block ``pb`` as first profiled (gcodeplan's, not grbl's): entry, peak, exit and nominal speed
    (mm/min), acceleration (mm/min²), length (mm)."""
    row = bop[pb] - window_base
    op_info[row, 0] = sf[F_CUR_V]
    if si[I_RAMP] == RAMP_DECEL or si[I_RAMP] == RAMP_DECEL_OVERRIDE:
        op_info[row, 1] = sf[F_CUR_V]     # deceleration only: the peak is the entry
    else:
        # A block the planner made one deceleration from its entry (entry² = exit² + 2·a·mm) has its
        # accelerate/decelerate intersection at its length to rounding; when it falls just inside, the top
        # speed, √(2·a·intersect + exit²) in single precision, can come out one float below the entry, and
        # the firmware's "acceleration" lowers the speed by that float over a fraction of a step. The
        # profile's peak is then its entry (a peak below the entry is a phase of negative time).
        op_info[row, 1] = sf[F_MAX_V] if sf[F_MAX_V] >= sf[F_CUR_V] else sf[F_CUR_V]
    op_info[row, 2] = sf[F_EXIT_V]
    op_info[row, 3] = nominal
    op_info[row, 4] = bf[pb, B_ACC]
    op_info[row, 5] = bf[pb, B_MM]


@njit(cache=True, inline="always")
def _prep_segment_distance(si, sf, bf, pb):
    """st_prep_buffer, one segment of block ``pb``: run the ramp state machine (acceleration, cruise,
    deceleration, deceleration override) over the segment time DT_SEGMENT, extended by whole DT_SEGMENTs until
    it covers at least REQ_MM_INCREMENT_SCALAR steps or ends the block. Returns (segment time min, mm of the
    block left after it)."""
    acc = bf[pb, B_ACC]
    dt_max = np.float32(DT_SEGMENT)
    dt = np.float32(0.0)
    time_var = dt_max
    mm_remaining = bf[pb, B_MM]
    minimum_mm = np.float32(mm_remaining - sf[F_REQ_MM])
    if minimum_mm < 0.0:
        minimum_mm = np.float32(0.0)
    while True:
        ramp = si[I_RAMP]
        if ramp == RAMP_DECEL_OVERRIDE:
            speed_var = np.float32(acc * time_var)
            if np.float32(sf[F_CUR_V] - sf[F_MAX_V]) <= speed_var:
                mm_remaining = sf[F_ACC_UNTIL]
                time_var = np.float32(2.0 * np.float64(np.float32(bf[pb, B_MM] - mm_remaining))
                                      / np.float64(np.float32(sf[F_CUR_V] + sf[F_MAX_V])))
                si[I_RAMP] = RAMP_CRUISE
                sf[F_CUR_V] = sf[F_MAX_V]
            else:
                mm_remaining = np.float32(np.float64(mm_remaining) - np.float64(time_var) * (
                    np.float64(sf[F_CUR_V]) - 0.5 * np.float64(speed_var)))
                sf[F_CUR_V] = np.float32(sf[F_CUR_V] - speed_var)
        elif ramp == RAMP_ACCEL:
            speed_var = np.float32(acc * time_var)
            mm_remaining = np.float32(np.float64(mm_remaining) - np.float64(time_var) * (
                np.float64(sf[F_CUR_V]) + 0.5 * np.float64(speed_var)))
            if mm_remaining < sf[F_ACC_UNTIL]:
                mm_remaining = sf[F_ACC_UNTIL]
                time_var = np.float32(2.0 * np.float64(np.float32(bf[pb, B_MM] - mm_remaining))
                                      / np.float64(np.float32(sf[F_CUR_V] + sf[F_MAX_V])))
                if mm_remaining == sf[F_DEC_AFTER]:
                    si[I_RAMP] = RAMP_DECEL
                else:
                    si[I_RAMP] = RAMP_CRUISE
                sf[F_CUR_V] = sf[F_MAX_V]
            else:
                sf[F_CUR_V] = np.float32(sf[F_CUR_V] + speed_var)
        elif ramp == RAMP_CRUISE:
            mm_var = np.float32(mm_remaining - np.float32(sf[F_MAX_V] * time_var))
            if mm_var < sf[F_DEC_AFTER]:
                time_var = np.float32(np.float32(mm_remaining - sf[F_DEC_AFTER]) / sf[F_MAX_V])
                mm_remaining = sf[F_DEC_AFTER]
                si[I_RAMP] = RAMP_DECEL
            else:
                mm_remaining = mm_var
        else:
            speed_var = np.float32(acc * time_var)
            done = False
            if sf[F_CUR_V] > speed_var:
                mm_var = np.float32(np.float64(mm_remaining) - np.float64(time_var) * (
                    np.float64(sf[F_CUR_V]) - 0.5 * np.float64(speed_var)))
                if mm_var > sf[F_MM_COMPLETE]:
                    mm_remaining = mm_var
                    sf[F_CUR_V] = np.float32(sf[F_CUR_V] - speed_var)
                    done = True
            if not done:
                time_var = np.float32(2.0 * np.float64(np.float32(mm_remaining - sf[F_MM_COMPLETE]))
                                      / np.float64(np.float32(sf[F_CUR_V] + sf[F_EXIT_V])))
                mm_remaining = sf[F_MM_COMPLETE]
                sf[F_CUR_V] = sf[F_EXIT_V]
        dt = np.float32(dt + time_var)
        if dt < dt_max:
            time_var = np.float32(dt_max - dt)
        else:
            if mm_remaining > minimum_mm:
                dt_max = np.float32(np.float64(dt_max) + DT_SEGMENT)
                time_var = np.float32(dt_max - dt)
            else:
                break
        if not (mm_remaining > sf[F_MM_COMPLETE]):
            break
    return dt, mm_remaining


@njit(cache=True, inline="always")
def _prep_segment_step_rate(sf, seg, dt, mm_remaining, seg_n, seg_cycles, seg_amass):
    """st_prep_buffer, segment ``seg`` of ``dt`` min ending ``mm_remaining`` mm before the block's end: its
    whole steps, its step period in Timer1 cycles from the time since the last step (the step-remainder time
    carried from the previous segment included), its AMASS level; the carried step and time remainders."""
    step_dist_remaining = np.float32(sf[F_STEP_PER_MM] * mm_remaining)
    n_steps_remaining = np.float32(math.ceil(np.float64(step_dist_remaining)))
    last_n_steps_remaining = np.float32(math.ceil(np.float64(sf[F_STEPS_REM])))
    n_step = np.int64(np.float32(last_n_steps_remaining - n_steps_remaining))
    dt = np.float32(dt + sf[F_DT_REM])
    inv_rate = np.float32(dt / np.float32(last_n_steps_remaining - step_dist_remaining))
    cycles = np.int64(math.ceil(np.float64(np.float32(np.float32(CYCLES_PER_MINUTE) * inv_rate))))
    amass = 0
    if cycles >= AMASS_LEVEL1:
        if cycles < AMASS_LEVEL2:
            amass = 1
        elif cycles < AMASS_LEVEL3:
            amass = 2
        else:
            amass = 3
        cycles >>= amass
        n_step = (n_step << amass) & 0xFFFF
    seg_cycles[seg] = cycles if cycles < 65536 else 0xFFFF
    seg_n[seg] = n_step
    seg_amass[seg] = amass
    sf[F_STEPS_REM] = n_steps_remaining
    sf[F_DT_REM] = np.float32(np.float32(n_steps_remaining - step_dist_remaining) * inv_rate)


@njit(cache=True, inline="always")
def _pulse(si, out, tick, step_t, step_dir, n_out):
    """The step pins written at ``tick`` (bits of ``out``), each pulse kept while step_t has room; n_out counts all."""
    for ax in range(3):
        if out & (1 << ax):
            k = n_out[ax]
            if k < step_t.shape[1]:
                step_t[ax, k] = tick
                step_dir[ax, k] = -1 if (si[I_DIRBITS] >> ax) & 1 else 1
            n_out[ax] = k + 1


@njit(cache=True, inline="always")
def _isr(si, st_steps, st_sec, st_dir, st_op, seg_n, seg_cycles, seg_block, seg_amass, window_base, op_end_tick,
         step_t, step_dir, n_out):
    """stepper.c ISR(TIMER1_COMPA_vect) at tick si[I_TICK]: pulse the bits decided last time, load a segment
    when none is running (or go idle when there is none), then decide the next pulse by Bresenham."""
    tick = si[I_TICK]
    out = si[I_OUTBITS]
    if out:
        op_end_tick[st_op[si[I_EXEC_BLOCK]] - window_base] = tick
        si[I_LAST_PULSE] = tick
        _pulse(si, out, tick, step_t, step_dir, n_out)
    si[I_OUTBITS] = 0
    if si[I_EXEC_SEG] < 0:
        if si[I_SEG_HEAD] != si[I_SEG_TAIL]:
            seg = si[I_SEG_TAIL]
            si[I_EXEC_SEG] = seg
            si[I_OCR] = seg_cycles[seg]
            si[I_STEP_COUNT] = seg_n[seg]
            if si[I_EXEC_BLOCK] != seg_block[seg]:
                si[I_EXEC_BLOCK] = seg_block[seg]
                half = st_sec[seg_block[seg]] >> 1
                si[I_CX] = half
                si[I_CY] = half
                si[I_CZ] = half
            eb = si[I_EXEC_BLOCK]
            si[I_DIRBITS] = st_dir[eb]
            a = seg_amass[seg]
            si[I_SX] = st_steps[eb, 0] >> a
            si[I_SY] = st_steps[eb, 1] >> a
            si[I_SZ] = st_steps[eb, 2] >> a
        else:
            si[I_RUNNING] = 0          # st_go_idle; Timer1 keeps counting with the last OCR1A
            si[I_LAST_MATCH] = tick
            si[I_TICK] = tick + si[I_IDLE_LOCK]    # $1: delay_ms inside the interrupt
            return
    eb = si[I_EXEC_BLOCK]
    sec = st_sec[eb]
    bits = 0
    si[I_CX] += si[I_SX]
    if si[I_CX] > sec:
        bits |= 1
        si[I_CX] -= sec
    si[I_CY] += si[I_SY]
    if si[I_CY] > sec:
        bits |= 2
        si[I_CY] -= sec
    si[I_CZ] += si[I_SZ]
    if si[I_CZ] > sec:
        bits |= 4
        si[I_CZ] -= sec
    si[I_OUTBITS] = bits
    si[I_STEP_COUNT] = (si[I_STEP_COUNT] - 1) & 0xFFFF
    if si[I_STEP_COUNT] == 0:
        si[I_EXEC_SEG] = -1
        si[I_SEG_TAIL] = _next(si[I_SEG_TAIL], SEGMENT_BUFFER_SIZE)
    si[I_LAST_MATCH] = tick
    phase = si[I_PHASE]
    if phase < 0:                      # fired by a compare match: TCNT1 restarts from 0
        si[I_NEXT_ISR] = tick + si[I_OCR] + 1
    elif phase <= si[I_OCR]:           # fired at once by a pending flag, TCNT1 = phase
        si[I_NEXT_ISR] = tick + si[I_OCR] - phase
    else:                              # TCNT1 above the new OCR1A: up to 0xFFFF, over, and up again
        si[I_NEXT_ISR] = tick + 65536 - phase + si[I_OCR]
    si[I_PHASE] = -1


@njit(cache=True, inline="always")
def _rest_of_segment(si, st_sec, st_op, window_base, op_end_tick, step_t, step_dir, n_out):
    """The interrupts of the running segment after the one that loaded it, in closed form: they come every
    OCR1A + 1 ticks, and each axis' Bresenham counter c (1 ≤ c ≤ sec) makes its i-th step at the
    m_i = ⌈(i·sec + 1 − c)/s⌉-th increment (an increment adds s, a step takes sec off once the counter exceeds
    sec). A step decided at an interrupt is pulsed at the next one; the last interrupt's pulses wait for the
    next segment's first interrupt. Equal, interrupt for interrupt, to running :func:`_isr` that many times."""
    r = si[I_STEP_COUNT]               # increments left, the first at si[I_NEXT_ISR]
    period = si[I_OCR] + 1
    t1 = si[I_NEXT_ISR]
    eb = si[I_EXEC_BLOCK]
    sec = st_sec[eb]
    row = st_op[eb] - window_base
    last = -1
    out = si[I_OUTBITS]                # decided at the loading interrupt: pulsed at t1
    if out:
        last = t1
        _pulse(si, out, t1, step_t, step_dir, n_out)
    pending = 0
    for ax in range(3):
        s = si[I_SX + ax]
        c = si[I_CX + ax]
        if s == 0:
            continue
        n_steps = (c + r * s - 1) // sec
        if n_steps >= 1:
            sign = -1 if (si[I_DIRBITS] >> ax) & 1 else 1
            if step_t.shape[1] > 0:
                for i in range(1, n_steps + 1):
                    m = (i * sec + 1 - c + s - 1) // s
                    if m < r:
                        k = n_out[ax]
                        if k < step_t.shape[1]:
                            step_t[ax, k] = t1 + m * period
                            step_dir[ax, k] = sign
                        n_out[ax] = k + 1
            m_last = (n_steps * sec + 1 - c + s - 1) // s
            if m_last < r:
                if step_t.shape[1] == 0:
                    n_out[ax] += n_steps
                t = t1 + m_last * period
                if t > last:
                    last = t
            else:
                pending |= 1 << ax
                if step_t.shape[1] == 0:
                    n_out[ax] += n_steps - 1
        si[I_CX + ax] = c + r * s - n_steps * sec
    if last >= 0:
        op_end_tick[row] = last
        si[I_LAST_PULSE] = last
    t_end = t1 + (r - 1) * period      # the segment's last interrupt
    si[I_OUTBITS] = pending
    si[I_STEP_COUNT] = 0
    si[I_EXEC_SEG] = -1
    si[I_SEG_TAIL] = _next(si[I_SEG_TAIL], SEGMENT_BUFFER_SIZE)
    si[I_TICK] = t_end
    si[I_LAST_MATCH] = t_end
    si[I_NEXT_ISR] = t_end + period
    si[I_PHASE] = -1


# _nrt=False: the kernel allocates nothing (its scratch is GrblState's), and without numba's reference counting
# the ~60 array arguments of the functions inlined per segment are not counted up and down (an atomic operation
# each): measured, 40 % of the kernel's time went to those counts
@njit(cache=True, nogil=True, _nrt=False)
def grbl_feed_kernel(si, sf, bf, bsteps, bdir, bop, brapid, st_steps, st_sec, st_dir, st_op, seg_n, seg_cycles,
                     seg_block, seg_amass, op_kind, op_target, op_rate, op_rapid, op_dwell_ticks, op_base, final,
                     steps_per_mm, max_rate, acceleration, junction_deviation, window_base, op_end_tick, op_info,
                     step_t, step_dir, n_out, target_steps, unit_vecs):
    """Run grbl's main loop over a batch of operations (global indices op_base …), resuming from the state in
    the arrays (grbl's globals, :class:`GrblState`); with ``final`` the program then ends (auto cycle start,
    the motion runs out). An OP_LINE op is a straight move to op_target at op_rate mm/min (or a rapid); an
    OP_SYNC op waits for the motion to stop, then dwells op_dwell_ticks.
    Outputs, indexed by global op − window_base: op_end_tick (absolute tick of the op's last step pulse, or
    of the end of a sync; −1 none) and op_info (entry, peak, exit speed mm/min, acceleration mm/min²,
    length mm of the block as the segment generator first profiled it); step pulses into step_t / step_dir
    (absolute ticks, per axis up to their width; n_out counts every pulse). ``target_steps`` (3 int64) and
    ``unit_vecs`` (2×3 float32): _plan_buffer_line's scratch."""
    nops = op_kind.shape[0]
    for j in range(nops + (1 if final else 0)):
        k = op_base + j
        if j < nops and op_kind[j] == OP_LINE:
            # mc_line: wait for room, starting the cycle when the buffer is full
            while si[I_TAIL] == si[I_NEXT_HEAD]:
                if si[I_CYCLE] == 0:
                    _cycle_start(si, sf, bf, bsteps, bdir, bop, brapid, st_steps, st_sec, st_dir, st_op, seg_n,
                                 seg_cycles, seg_block, seg_amass, window_base, op_info)
                _prep_then_wait(si, sf, bf, bsteps, bdir, bop, brapid, st_steps, st_sec, st_dir, st_op, seg_n,
                                seg_cycles, seg_block, seg_amass, window_base, op_end_tick, op_info, step_t,
                                step_dir, n_out, True)
            _plan_buffer_line(si, sf, bf, bsteps, bdir, bop, brapid, op_target[j], op_rate[j], op_rapid[j], k,
                              steps_per_mm, max_rate, acceleration, junction_deviation, target_steps, unit_vecs)
            if si[I_CYCLE]:
                _st_prep_buffer(si, sf, bf, bsteps, bdir, bop, brapid, st_steps, st_sec, st_dir, st_op, seg_n,
                                seg_cycles, seg_block, seg_amass, window_base, op_info)
        else:
            # protocol_buffer_synchronize (a sync, or the end of the program)
            if si[I_HEAD] != si[I_TAIL] and si[I_CYCLE] == 0:
                _cycle_start(si, sf, bf, bsteps, bdir, bop, brapid, st_steps, st_sec, st_dir, st_op, seg_n,
                             seg_cycles, seg_block, seg_amass, window_base, op_info)
            while si[I_CYCLE]:
                _prep_then_wait(si, sf, bf, bsteps, bdir, bop, brapid, st_steps, st_sec, st_dir, st_op, seg_n,
                                seg_cycles, seg_block, seg_amass, window_base, op_end_tick, op_info, step_t,
                                step_dir, n_out, False)
                if si[I_RUNNING] == 0:
                    si[I_CYCLE] = 0
            if j < nops:
                # a sync without dwell ends with the last step (the few empty interrupts of the last segment
                # after it count to the next motion); a dwell ends where it ends
                if op_dwell_ticks[j] > 0:
                    si[I_TICK] += op_dwell_ticks[j]
                    op_end_tick[k - window_base] = si[I_TICK]
                else:
                    op_end_tick[k - window_base] = si[I_LAST_PULSE]
        si[I_NEXT_OP] = k + 1 if j < nops else k


@njit(cache=True)
def _cycle_start(si, sf, bf, bsteps, bdir, bop, brapid, st_steps, st_sec, st_dir, st_op, seg_n, seg_cycles,
                 seg_block, seg_amass, window_base, op_info):
    """protocol_exec_rt_system on EXEC_CYCLE_START: prepare segments, then st_wake_up (enable the interrupt of
    the free-running Timer1)."""
    si[I_CYCLE] = 1
    _st_prep_buffer(si, sf, bf, bsteps, bdir, bop, brapid, st_steps, st_sec, st_dir, st_op, seg_n, seg_cycles,
                    seg_block, seg_amass, window_base, op_info)
    tick = si[I_TICK]
    if not si[I_STARTED]:
        si[I_STARTED] = 1
        si[I_T0] = tick
    si[I_RUNNING] = 1
    si[I_OUTBITS] = 0
    last = si[I_LAST_MATCH]
    period = si[I_OCR] + 1
    if last < 0:
        si[I_NEXT_ISR] = tick        # after reset OCR1A = 0: a match every tick, TCNT1 = 0
        si[I_PHASE] = 0
    else:
        # Timer1 ran on from the last interrupt with the last OCR1A: the first interrupt of the cycle is its
        # next compare match (measured on the reference: up to one old period, 4 ms, after the start)
        si[I_NEXT_ISR] = last + period * ((tick - last) // period + 1)
        si[I_PHASE] = -1


@njit(cache=True, inline="always")
def _prep_then_wait(si, sf, bf, bsteps, bdir, bop, brapid, st_steps, st_sec, st_dir, st_op, seg_n, seg_cycles,
                    seg_block, seg_amass, window_base, op_end_tick, op_info, step_t, step_dir, n_out, need_full):
    """grbl-sim's lock-step st_prep_buffer: grbl's own, then, while the stepper runs and grbl waits (planner
    full, or a sync), the clock runs to the next stepper interrupt."""
    _st_prep_buffer(si, sf, bf, bsteps, bdir, bop, brapid, st_steps, st_sec, st_dir, st_op, seg_n, seg_cycles,
                    seg_block, seg_amass, window_base, op_info)
    if si[I_RUNNING] and (not need_full or si[I_TAIL] == si[I_NEXT_HEAD]):
        # Until a segment completes nothing changes for the main loop (the segment ring stays as full as it
        # was, so st_prep_buffer has nothing to do and no block leaves the planner): run the interrupts of
        # the current segment in one go, exactly as one interrupt per main-loop pass would.
        si[I_TICK] = si[I_NEXT_ISR]
        _isr(si, st_steps, st_sec, st_dir, st_op, seg_n, seg_cycles, seg_block, seg_amass, window_base,
             op_end_tick, step_t, step_dir, n_out)
        if si[I_RUNNING] and si[I_EXEC_SEG] >= 0:
            _rest_of_segment(si, st_sec, st_op, window_base, op_end_tick, step_t, step_dir, n_out)


# --------------------------------------------------------------------------- MOVE rows in, times out
class GrblState:
    """grbl's globals between two batches of a stream: the planner ring, the segment generator, the segment
    and stepper-block rings, the stepper interrupt and Timer1, the clock (ticks of 62.5 ns)."""

    def __init__(self, settings: "GrblSettings", buffer_blocks: int = BLOCK_BUFFER_SIZE):
        n = check_buffer_blocks(buffer_blocks)
        self.settings = settings
        self.si = np.zeros(N_SI, np.int64)
        self.sf = np.zeros(N_SF, np.float32)
        self.bf = np.zeros((n, N_BF), np.float32)      # the ring's size is its row count (bf.shape[0])
        self.bsteps = np.zeros((n, 3), np.int64)
        self.bdir = np.zeros(n, np.int64)
        self.bop = np.zeros(n, np.int64)
        self.brapid = np.zeros(n, np.bool_)
        self.st_steps = np.zeros((ST_BLOCK_BUFFER_SIZE, 3), np.int64)
        self.st_sec = np.zeros(ST_BLOCK_BUFFER_SIZE, np.int64)
        self.st_dir = np.zeros(ST_BLOCK_BUFFER_SIZE, np.int64)
        self.st_op = np.zeros(ST_BLOCK_BUFFER_SIZE, np.int64)
        self.seg = np.zeros((4, SEGMENT_BUFFER_SIZE), np.int64)     # n_step, cycles_per_tick, st block, amass
        self.target_steps = np.zeros(3, np.int64)      # _plan_buffer_line's scratch (the kernel allocates nothing)
        self.unit_vecs = np.zeros((2, 3), np.float32)
        si = self.si
        si[I_NEXT_HEAD] = 1
        si[I_PL_BLOCK] = -1
        si[I_EXEC_SEG] = -1
        si[I_SEG_NEXT_HEAD] = 1
        si[I_LAST_MATCH] = -1
        si[I_IDLE_LOCK] = settings.idle_lock_ticks

    def feed(self, op_kind, op_target, op_rate, op_rapid, op_dwell_ticks, final, window_base, op_end_tick, op_info,
             step_t, step_dir, n_out) -> None:
        """Run the next operations (their global indices continue from the last call)."""
        s, g = self.settings, self.seg
        grbl_feed_kernel(self.si, self.sf, self.bf, self.bsteps, self.bdir, self.bop, self.brapid, self.st_steps,
                         self.st_sec, self.st_dir, self.st_op, g[0], g[1], g[2], g[3], op_kind, op_target, op_rate,
                         op_rapid, op_dwell_ticks, int(self.si[I_NEXT_OP]), final, s.steps_per_mm, s.max_rate,
                         s.acceleration, s.junction_deviation, window_base, op_end_tick, op_info, step_t, step_dir,
                         n_out, self.target_steps, self.unit_vecs)

    def first_open_op(self) -> int:
        """The first operation whose last step pulse has not been issued yet (all before it are final)."""
        si = self.si
        cands = [int(si[I_NEXT_OP])]
        if si[I_HEAD] != si[I_TAIL]:
            cands.append(int(self.bop[si[I_TAIL]]))
        if si[I_SEG_HEAD] != si[I_SEG_TAIL]:
            cands.append(int(self.st_op[self.seg[2, si[I_SEG_TAIL]]]))
        if si[I_EXEC_SEG] >= 0 or si[I_OUTBITS]:
            cands.append(int(self.st_op[si[I_EXEC_BLOCK]]))
        return min(cands)

    @property
    def t0(self) -> int:
        """Tick of the first cycle start (time zero), 0 before it."""
        return int(self.si[I_T0]) if self.si[I_STARTED] else int(self.si[I_TICK])


class GrblRun:
    """What :func:`run` returns: per MOVE row, the time of its last step pulse (s from the first cycle start;
    nan for a row that made no step: a dropped sub-step move, a wait before any motion), the program's total
    (the last step, s) and, when asked for, every step pulse per axis (s, direction ±1)."""

    def __init__(self, row_end_s, total_s, steps):
        self.row_end_s = row_end_s
        self.total_s = total_s
        self.steps = steps


def operations(moves: np.ndarray):
    """MOVE rows → grbl's operations: (kind, target mm float32 (n, 3), rate mm/min float32, rapid, dwell ticks,
    MOVE row of each op). Motion rows are lines (arcs arrive as chords); dwells and waits are syncs; E-only
    rows have no grbl meaning and are skipped."""
    return _operations_kernel(moves["kind"], moves["flags"], moves["x1"], moves["y1"], moves["z1"],
                              moves["feed_v"], moves["dwell_t"], _POW10)


@njit(cache=True, nogil=False)     # main thread, once a batch: see _first_beyond_reach
def _operations_kernel(kind, flags, x1, y1, z1, feed_v, dwell_t, pow10):
    """:func:`operations` on the MOVE columns, one pass."""
    n_rows = kind.shape[0]
    keep = np.empty(n_rows, np.int64)
    n = 0
    for r in range(n_rows):
        if kind[r] <= 1 or kind[r] == KIND_DWELL or kind[r] == KIND_WAIT:
            keep[n] = r
            n += 1
    keep = keep[:n].copy()
    op_kind = np.empty(n, np.int64)
    target = np.empty((n, 3), np.float32)
    rate = np.empty(n, np.float32)
    rapid = np.empty(n, np.bool_)
    dwell_ticks = np.zeros(n, np.int64)
    px = py = pz = np.nan                  # the last coordinates read, and grbl's floats of them
    fx = fy = fz = np.float32(0.0)
    for j in range(n):
        r = keep[j]
        k = kind[r]
        op_kind[j] = OP_SYNC if (k == KIND_DWELL or k == KIND_WAIT) else OP_LINE
        # arc chords are grbl's floats already (arcs_grbl.py); a line's target is the number in the file as
        # grbl reads it
        if flags[r] & FLAG_ARC:
            target[j, 0] = np.float32(x1[r])
            target[j, 1] = np.float32(y1[r])
            target[j, 2] = np.float32(z1[r])
        else:
            # a coordinate the line repeats (Z on most lines) is read once; ±0 always (its sign is its own)
            if x1[r] != px or x1[r] == 0.0:
                px, fx = x1[r], _grbl_float_of(x1[r], pow10)
            if y1[r] != py or y1[r] == 0.0:
                py, fy = y1[r], _grbl_float_of(y1[r], pow10)
            if z1[r] != pz or z1[r] == 0.0:
                pz, fz = z1[r], _grbl_float_of(z1[r], pow10)
            target[j, 0] = fx
            target[j, 1] = fy
            target[j, 2] = fz
        feed = feed_v[r]
        rapid[j] = (flags[r] & FLAG_RAPID) != 0 or not math.isfinite(feed)
        rate[j] = np.float32(0.0) if rapid[j] else np.float32(feed * 60.0)
        if k == KIND_DWELL:
            # mc_dwell: ceil(1000/DWELL_TIME_STEP × P) steps of DWELL_TIME_STEP ms (protocol.c delay_sec)
            p = np.float64(np.float32(1000 // DWELL_TIME_STEP_MS) * np.float32(dwell_t[r]))
            dwell_ticks[j] = np.int64(math.ceil(p)) * DWELL_TICKS
    return op_kind, target, rate, rapid, dwell_ticks, keep


def check_reach(moves: np.ndarray, settings: GrblSettings) -> None:
    """grbl keeps positions as int32 steps (sys_position, pl.position): a target beyond ±2³¹ steps (or not a
    number) has no meaning on the machine; an error naming the line rather than a wrapped position."""
    k, i = _first_beyond_reach(moves["x1"], moves["y1"], moves["z1"], reach_mm(settings))
    if k >= 0:
        raise _reach_error(moves, settings, k, i)


def reach_mm(settings: GrblSettings) -> np.ndarray:
    """mm, the reach of grbl's int32 step positions per axis X, Y, Z (±2³¹ steps)."""
    return np.array([2.0 ** 31 / float(v) for v in settings.steps_per_mm])


def _reach_error(moves: np.ndarray, settings: GrblSettings, k: int, i: int):
    """The error of row ``i``'s target on axis ``k`` (0..2) beyond grbl's reach (:func:`check_reach`)."""
    from ..errors import GcodeError

    axis = "xyz"[k]
    return GcodeError(f"{axis.upper()} {moves[axis + '1'][i]:g} mm is beyond grbl's reach "
                      f"(±2³¹ steps at {float(settings.steps_per_mm[k]):g} steps/mm)", line=int(moves["line"][i]))


@njit(cache=True, nogil=False)     # main thread, once a batch: see _first_beyond_reach
def _first_refused_kernel(e0, e1, x1, y1, z1, reach):
    """The stream mode's two checks of a batch in one pass: (the first row that moves E, the axis and row
    :func:`_first_beyond_reach` gives), −1 for none."""
    e_row = -1
    bad = np.full(3, -1, np.int64)
    for i in range(e0.shape[0]):
        if e_row < 0 and e1[i] != e0[i]:
            e_row = i
        if bad[0] < 0 and not (abs(x1[i]) < reach[0]):
            bad[0] = i
        if bad[1] < 0 and not (abs(y1[i]) < reach[1]):
            bad[1] = i
        if bad[2] < 0 and not (abs(z1[i]) < reach[2]):
            bad[2] = i
    for k in range(3):
        if bad[k] >= 0:
            return e_row, k, bad[k]
    return e_row, -1, -1


# nogil=False for the small kernels the grbl mode runs in the main thread once a batch (well under a
# millisecond each): releasing the GIL for them hands it to the reader thread, which then keeps it for its
# Python work up to the interpreter's switch interval (5 ms); measured on the 50 MB file, 1.4 s of such waits
# around 0.05 s of work in one of them
@njit(cache=True, nogil=False)
def _first_beyond_reach(x1, y1, z1, reach):
    """(axis, row) of the first target not within ±reach[axis] mm (or not a number), axes in order X, Y, Z;
    (−1, −1) when all are."""
    for k in range(3):
        v = x1 if k == 0 else (y1 if k == 1 else z1)
        for i in range(v.shape[0]):
            if not (abs(v[i]) < reach[k]):
                return k, i
    return -1, -1


def run(moves: np.ndarray, settings: GrblSettings, steps_capacity: int = 0,
        buffer_blocks: int | None = BLOCK_BUFFER_SIZE, quantised: bool = True):
    """Run grbl 1.1 on MOVE rows (a whole program; see the module docstring for what is modelled).
    ``steps_capacity``: how many step pulses per axis to keep (0: none). ``buffer_blocks``: the planner ring,
    BLOCK_BUFFER_SIZE (16 by default, 15 usable blocks). ``quantised=False``: the plan in float64 and continuous
    time, :func:`gcodeplan.planner.grbl_ideal.run_ideal` (there ``buffer_blocks=None`` is unbounded; its result
    has the per-op block outputs too)."""
    if not quantised:
        from ..errors import ConfigError

        if steps_capacity:
            raise ConfigError("grbl model: quantised=False has no step pulses (no stepper is simulated)")
        return run_ideal(moves, settings, buffer_blocks)
    check_reach(moves, settings)
    op_kind, target, rate, rapid, dwell_ticks, rows = operations(moves)
    op_end = np.full(len(op_kind), -1, np.int64)
    op_info = np.zeros((len(op_kind), N_INFO), np.float32)
    step_t = np.zeros((3, steps_capacity), np.int64)
    step_dir = np.zeros((3, steps_capacity), np.int8)
    n_out = np.zeros(3, np.int64)
    state = GrblState(settings, buffer_blocks)
    state.feed(op_kind, target, rate, rapid, dwell_ticks, True, 0, op_end, op_info, step_t, step_dir, n_out)
    t0 = state.t0
    row_end = np.full(len(moves), np.nan)
    lines = (op_end >= 0) & (op_kind == OP_LINE)
    row_end[rows[lines]] = (op_end[lines] - t0) / F_CPU
    last = int(op_end[lines].max()) - t0 if lines.any() else 0
    steps = None
    if steps_capacity:
        steps = {}
        for ax, name in enumerate("xyz"):
            k = min(int(n_out[ax]), steps_capacity)
            steps[f"stepper_{name}"] = ((step_t[ax, :k] - t0) / F_CPU, step_dir[ax, :k].copy())
    return GrblRun(row_end, last / F_CPU, steps)


# --------------------------------------------------------------------------- the StreamPlanner mode
def _plan_rows(moves, op_of_row, op_kind, op_end, op_info, op_rapid, clock_s, t0):
    """PLAN rows of complete MOVE rows. A row ends at its last step pulse (a sync at the end of its dwell);
    rows without a step end where the previous one did. Speeds and phases are the block's profile as grbl's
    segment generator planned it, laid on the row's own length and stretched in time to the firmware's
    duration (its timer rounds every step period up: +0.004 … +0.12 %), so that the pieces are continuous
    in position and their times are the firmware's. Returns (plan, end of the last row s)."""
    from ..schema import PLAN_DTYPE

    plan = np.zeros(len(moves), dtype=PLAN_DTYPE)
    t_end = _plan_rows_kernel(moves["move_d"], moves["feed_v"], op_of_row, op_kind, op_end, op_info, op_rapid,
                              float(clock_s), int(t0), plan["t_start"], plan["duration"], plan["start_v"],
                              plan["cruise_v"], plan["end_v"], plan["accel"], plan["decel"], plan["accel_t"],
                              plan["cruise_t"], plan["decel_t"], plan["limit"])
    return plan, t_end


@njit(cache=True)
def _max_nan(a, b):
    """np.maximum of two floats: the larger, nan if either is nan."""
    return a if (a >= b or a != a) else b


@njit(cache=True, nogil=False)     # main thread, once a batch: see _first_beyond_reach
def _plan_rows_kernel(move_d, feed_v, op_of_row, op_kind, op_end, op_info, op_rapid, clock_s, t0, t_start,
                      duration, start_v, cruise_v, end_v, accel, decel, accel_t, cruise_t, decel_t, limit):
    """:func:`_plan_rows` row by row into the PLAN columns (zeros on entry); returns the last row's end (s).
    Speeds mm/s from op_info's mm/min, acceleration mm/s² from its mm/min²."""
    n = move_d.shape[0]
    prev_end = clock_s
    for r in range(n):
        j = op_of_row[r]
        end_s = -np.inf
        if j >= 0 and op_end[j] >= 0:
            end_s = (op_end[j] - t0) / F_CPU
        end_s = _max_nan(prev_end, _max_nan(end_s, clock_s))       # rows end in order, none before the clock
        dur = end_s - prev_end
        t_start[r] = prev_end
        duration[r] = dur
        prev_end = end_s
        limit[r] = LIMIT_NONE
        if not (j >= 0 and op_kind[j] == OP_LINE and dur > 0 and move_d[r] > 0):
            continue
        v0 = np.float64(op_info[j, 0]) / 60.0
        vp = np.float64(op_info[j, 1]) / 60.0
        v1 = np.float64(op_info[j, 2]) / 60.0
        nominal = np.float64(op_info[j, 3]) / 60.0
        a = np.float64(op_info[j, 4]) / 3600.0
        d = move_d[r]
        da = _max_nan(vp * vp - v0 * v0, 0.0) / (2 * a)
        dd = _max_nan(vp * vp - v1 * v1, 0.0) / (2 * a)
        if da + dd > d:             # the step-rounded length differs from the row's: the peak on the row
            vp = _max_nan(_max_nan(v0, v1), math.sqrt(_max_nan((2 * a * d + v0 * v0 + v1 * v1) / 2, 0.0)))
            da = _max_nan(vp * vp - v0 * v0, 0.0) / (2 * a)
            dd = _max_nan(d - da, 0.0)
            v1 = math.sqrt(_max_nan(vp * vp - 2 * a * dd, 0.0))
        ta = (vp - v0) / a
        td = (vp - v1) / a
        tc = _max_nan(d - da - dd, 0.0) / vp if vp > 0 else 0.0
        t_plan = ta + tc + td
        f = dur / t_plan if t_plan > 0 else 1.0
        start_v[r] = v0 / f
        cruise_v[r] = vp / f
        end_v[r] = v1 / f
        accel[r] = a / (f * f)
        decel[r] = a / (f * f)
        accel_t[r] = ta * f
        cruise_t[r] = tc * f
        decel_t[r] = td * f
        feed = feed_v[r]
        if vp >= nominal * (1 - 1e-6):
            capped = op_rapid[j] or (math.isfinite(feed) and nominal < feed * (1 - 1e-6))
            limit[r] = LIMIT_AXIS if capped else LIMIT_FEED
        else:
            limit[r] = LIMIT_ACCEL
    return prev_end


@njit(cache=True, nogil=False)     # main thread, once a batch: see _first_beyond_reach
def _append_ops_kernel(row_op, op_kind, op_rapid, op_end, op_info, n_rows, rows, kind, rapid, first):
    """The stream mode's pending arrays with a batch appended (new arrays; the old ones are left as they were):
    ``row_op`` with the batch's ``n_rows`` rows (each its op's global index from ``first`` on, −1 for a row
    without one; ``rows``: the row of each new op), ``op_kind`` and ``op_rapid`` with the new ops' ``kind`` and
    ``rapid``, ``op_end`` with −1 (not ended) and ``op_info`` with zero rows for them. One pass instead of seven
    array operations a batch, none of which hands the GIL to the reader thread."""
    n_old, m_old, m = row_op.shape[0], op_kind.shape[0], kind.shape[0]
    row_op2 = np.empty(n_old + n_rows, np.int64)
    row_op2[:n_old] = row_op
    row_op2[n_old:] = -1
    for j in range(m):
        row_op2[n_old + rows[j]] = first + j
    kind2 = np.empty(m_old + m, np.int64)
    kind2[:m_old] = op_kind
    kind2[m_old:] = kind
    rapid2 = np.empty(m_old + m, np.bool_)
    rapid2[:m_old] = op_rapid
    rapid2[m_old:] = rapid
    end2 = np.empty(m_old + m, np.int64)
    end2[:m_old] = op_end
    end2[m_old:] = -1
    info2 = np.zeros((m_old + m, op_info.shape[1]), np.float32)
    info2[:m_old] = op_info
    return row_op2, kind2, rapid2, end2, info2


def make_stream_mode(base_cls):
    """The StreamPlanner mode of machines with ``firmware = "grbl-1.1"`` (``base_cls``: planner.stream._Mode):
    every batch runs grbl on, and the rows whose last step pulse is out are final (:class:`_GrblStreamMode`)."""
    return type("GrblMode", (_GrblStreamMode, base_cls), {"__doc__": _GrblStreamMode.__doc__})


class _GrblStreamMode:
    """The grbl-1.1 planning mode (mixed in before planner.stream._Mode by :func:`make_stream_mode`): grbl's
    state carries over from batch to batch; a batch's MOVE rows become operations with global indices, and
    the op arrays keep those of the rows still pending (from op ``op_base`` on)."""

    name = "grbl-1.1"
    own_prepare = True

    def __init__(self, sp):
        super().__init__(sp)
        from ..errors import ConfigError

        if sp.machine.kinematics != "cartesian":
            raise ConfigError(f"the grbl-1.1 firmware model steps a cartesian machine, not "
                              f"{sp.machine.kinematics!r} (grbl's COREXY build is not modelled)")
        self.settings = GrblSettings.from_machine(sp.machine)
        self.limits_idx = 0                            # the LIMITS row the settings in force come from
        self.limits = None                             # the LIMITS table (prepare's)
        self.settings_of = {0: self.settings}          # LIMITS row → its settings
        self.reach = reach_mm(self.settings)            # mm, check_reach's
        self.state = GrblState(self.settings)
        self.want_steps = bool(getattr(sp, "want_firmware_steps", False))
        self.pos_steps = np.zeros(3, np.int64)         # where the last fed line ends, in steps (for sizing)
        self.bound_steps = np.zeros(3, np.int64)       # pulses the lines fed so far can make, at most
        self.taken_steps = np.zeros(3, np.int64)       # pulses handed on
        self.last_steps = None                         # the pulses of the rows of the last emission
        self.fed = 0                                   # pending rows already given to grbl
        self.row_op = np.zeros(0, np.int64)            # per pending row: its op (global index), −1 none
        self.op_base = 0                               # global index of the first op kept below
        self.op_kind = np.zeros(0, np.int64)
        self.op_rapid = np.zeros(0, np.bool_)
        self.op_end = np.zeros(0, np.int64)
        self.op_info = np.zeros((0, N_INFO), np.float32)
        self.n_out = np.zeros(3, np.int64)
        self.no_steps = np.zeros((3, 0), np.int64)
        self.no_dirs = np.zeros((3, 0), np.int8)

    def prepare(self, moves_chunk, limits):
        """The checks grbl's parser makes on a chunk (E words, int32 step positions); PREP rows it does not use.

        An E move stays an error that stops the run, not one rejected line among others (as grbl's other block
        errors are, gcode/rs274.py): E is no grbl word (error:20 on every line that has one), so a file with E
        moves is a printer's file, not a program for this machine; timing it without its extrusions would be
        a silent wrong answer for the printer it was made for."""
        from ..errors import GcodeError

        e_move, k, i = _first_refused_kernel(moves_chunk["e0"], moves_chunk["e1"], moves_chunk["x1"],
                                             moves_chunk["y1"], moves_chunk["z1"], self.reach)
        if e_move >= 0:      # gcode.c: E is no grbl word (error:20), the whole line is rejected
            line = int(moves_chunk["line"][e_move])
            raise GcodeError("grbl 1.1 has no E axis: it rejects this line (error:20, unsupported command)",
                             line=line)
        if k >= 0:           # check_reach
            raise _reach_error(moves_chunk, self.settings, k, i)
        from .prepare import unread_prep

        self.limits = limits
        return unread_prep(len(moves_chunk))

    def window_prep(self, moves_chunk, limits):
        """The grbl model plans from the MOVE rows alone: the window's PREP rows (the stream keeps them 1:1
        with its MOVE rows) are one zero row repeated, a read-only view of no memory (zeroing and copying
        128 bytes a row cost more than a tenth of the model's time)."""
        from .prepare import unread_prep

        self.prepare(moves_chunk, limits)
        return unread_prep(len(self.sp.pending_prep) + len(moves_chunk))

    def plan(self, final: bool):
        """Run grbl on the rows not fed yet; emit the rows before the first whose last pulse is not out."""
        sp = self.sp
        new = sp.pending_moves[self.fed:]
        kind, target, rate, rapid, dwell, rows = self._add_ops(new)
        if self.want_steps:
            self._make_room(kind, target)
        self._feed(kind, target, rate, rapid, dwell, new["limits"][rows], final)
        self.fed = len(sp.pending_moves)
        if final:
            n_rows = len(sp.pending_moves)
        else:
            open_op = self.state.first_open_op()
            later = np.nonzero(self.row_op >= open_op)[0]
            n_rows = int(later[0]) if later.size else len(sp.pending_moves)
        if n_rows == 0:
            return 0, None, sp.clock, None
        local = np.where(self.row_op[:n_rows] >= 0, self.row_op[:n_rows] - self.op_base, -1)
        plan, t_end = _plan_rows(sp.pending_moves[:n_rows], local, self.op_kind, self.op_end, self.op_info,
                                 self.op_rapid, sp.clock, 0)
        if self.want_steps:
            self.last_steps = self._take_steps(None if final else int(round(t_end * F_CPU)))
        return n_rows, plan, t_end, None

    def _add_ops(self, new):
        """grbl's operations of the new MOVE rows, appended to the pending ones (global indices go on);
        returns what the feed kernel takes: (kind, target, rate, rapid, dwell ticks), and the row of each."""
        kind, target, rate, rapid, dwell, rows = operations(new)
        self.row_op, self.op_kind, self.op_rapid, self.op_end, self.op_info = _append_ops_kernel(
            self.row_op, self.op_kind, self.op_rapid, self.op_end, self.op_info, len(new), rows, kind, rapid,
            self.op_base + len(self.op_kind))
        return kind, target, rate, rapid, dwell, rows

    def _feed(self, kind, target, rate, rapid, dwell, limits_idx, final):
        """Run grbl on the new operations, with the settings of the LIMITS row of each: a program's ``$`` line
        changes them only when grbl is idle (gcode/grbl_line.py), where its planner is empty, so the ops of
        one row run on its settings (system.c: the next block is planned with the stored values)."""
        n = len(kind)
        start = 0
        while True:
            if start < n and limits_idx[start] != self.limits_idx:
                self._use_limits(int(limits_idx[start]))
            other = np.flatnonzero(limits_idx[start:] != self.limits_idx)
            end = start + int(other[0]) if other.size else n
            self.state.feed(kind[start:end], target[start:end], rate[start:end], rapid[start:end],
                            dwell[start:end], final and end == n, self.op_base, self.op_end, self.op_info,
                            self.no_steps, self.no_dirs, self.n_out)
            if end == n:
                return
            start = end

    def _use_limits(self, idx: int) -> None:
        """The settings of LIMITS row ``idx`` from now on (:func:`settings_of_limits`)."""
        s = self.settings_of.get(idx)
        if s is None:
            s = self.settings_of[idx] = settings_of_limits(self.sp.machine, self.limits[idx])
        self.limits_idx = idx
        self.settings = self.state.settings = s

    def _make_room(self, kind, target):
        """Room in the pulse buffers for every step the new lines can make (their step-rounded lengths)."""
        spm = self.settings.steps_per_mm
        lines = target[kind == OP_LINE]
        pos = np.rint((lines * spm).astype(np.float32).astype(np.float64)).astype(np.int64)
        path = np.concatenate([self.pos_steps[None, :], pos]) if len(pos) else self.pos_steps[None, :]
        if len(pos):
            self.pos_steps = pos[-1]
        # every pulse still to come is of a line fed so far: at most their step-rounded lengths
        self.bound_steps = self.bound_steps + np.abs(np.diff(path, axis=0)).sum(axis=0) + len(pos)
        need = self.bound_steps - self.taken_steps + 8
        width = self.no_steps.shape[1]
        if need.max() > width:
            size = int(max(need.max(), 2 * width, 1024))
            t = np.zeros((3, size), np.int64)
            d = np.zeros((3, size), np.int8)
            t[:, :width], d[:, :width] = self.no_steps, self.no_dirs
            self.no_steps, self.no_dirs = t, d

    def _take_steps(self, until_tick):
        """The pulses issued up to ``until_tick`` (all with None): {axis index: (times s, dirs)}; the rest
        stays for the next emission."""
        out = {}
        for ax in range(3):
            n = int(self.n_out[ax])
            if n > self.no_steps.shape[1]:
                raise RuntimeError("grbl model: step buffer overrun (a sizing bug)")
            t = self.no_steps[ax, :n]
            k = n if until_tick is None else int(np.searchsorted(t, until_tick, side="right"))
            out[ax] = (t[:k] / F_CPU, self.no_dirs[ax, :k].copy())
            rest = n - k
            self.taken_steps[ax] += k
            self.no_steps[ax, :rest] = self.no_steps[ax, k:n].copy()
            self.no_dirs[ax, :rest] = self.no_dirs[ax, k:n].copy()
            self.n_out[ax] = rest
        return out

    def drop(self, n_rows: int) -> None:
        self.fed -= n_rows
        gone = self.row_op[:n_rows]
        self.row_op = self.row_op[n_rows:].copy()
        used = gone[gone >= 0]
        if used.size:
            k = int(used.max()) + 1 - self.op_base
            self.op_base += k
            self.op_kind = self.op_kind[k:].copy()
            self.op_rapid = self.op_rapid[k:].copy()
            self.op_end = self.op_end[k:].copy()
            self.op_info = self.op_info[k:].copy()

    def reset(self) -> None:
        pass
