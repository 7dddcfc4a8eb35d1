"""Marlin 2.1.2's stepper interrupt as it times one planner block, in timer ticks, and the pulses it issues.

Marlin (``stepper.cpp``, ``Stepper::block_phase_isr``) does not follow the ideal trapezoid: after each step
of the leading axis it computes the interval to the next one from the phase the block is in, counted in
steps (``accelerate_until`` / ``decelerate_after``), and from the time spent in that phase, counted in timer
ticks:

* picking up a block: the first interval is ``TIMER_RATE / initial_rate``; it counts as acceleration time;
* accelerating (step ``n <= accelerate_until``): ``rate = initial_rate + acceleration_time · acceleration_rate``
  (``STEP_MULTIPLY``: a 32×24-bit fixed-point product, rounded to nearest), capped at ``nominal_rate``;
* cruising: ``TIMER_RATE / nominal_rate`` every step; the deceleration clock starts at 0;
* decelerating (``n > decelerate_after``): ``rate = acc_step_rate − deceleration_time · acceleration_rate``,
  not below ``final_rate``, where ``acc_step_rate`` is the last accelerating rate (``nominal_rate`` after a
  cruise).

With ``S_CURVE_ACCELERATION`` the accelerating and decelerating rates follow a quintic Bézier in time
instead (:func:`_eval_bezier_curve`), between the block's initial, cruise and final rates.

Each rate becomes an interval by integer division of the timer rate; the block lasts the sum of its
intervals and its last step is the end of the block (the next block is picked up in the same interrupt).
``acceleration_rate`` is ``(uint32)(accel_steps_per_s2 · 2^24 / TIMER_RATE)`` in float32, as the planner
stores it. Validated against every block of the shared Marlin reference (docs/design.md, Marlin model).

The pulses (``Stepper::pulse_phase_isr``): every interrupt is one step event of the leading axis; every
axis, X, Y, Z and E, steps on it by Bresenham — its error starts at ``−step_event_count``, grows by
``2·steps`` per event, and the axis steps when it reaches 0 (then it drops by ``2·step_event_count``). The
step directions are the block's ``direction_bits`` (bit set = negative).

All arithmetic is on integers as the firmware's; ``ticks`` are of a ``timer_hz`` clock (25 MHz in the
reference build). One interrupt makes one step: an infinitely fast MCU, on which Marlin's multi-stepping
never engages.
"""
from __future__ import annotations

import numpy as np

from .._jit import njit

#: Hz, the stepper timer of the reference build (STEPPER_TIMER_RATE of a 32-bit board at 25 MHz)
MARLIN_TIMER_HZ = 25_000_000
#: STEP_MULTIPLY's rounding constant: half of 2^24
_HALF_24 = 0x800000

# The interrupt's state while it runs a block (one int64 array, ``isr``): the block's trapezoid as the
# stepper copied it at pick-up, then the Stepper class's running variables (stepper.h names).
(ISR_SEC, ISR_INITIAL_RATE, ISR_NOMINAL_RATE, ISR_FINAL_RATE, ISR_ACCEL_UNTIL, ISR_DECEL_AFTER, ISR_ACC_RATE,
 ISR_CRUISE_RATE, ISR_ACCELERATION_TIME, ISR_DECELERATION_TIME, ISR_DEC_TIME_INV, ISR_S_CURVE,
 ISR_ACC_TIME, ISR_DEC_TIME, ISR_ACC_STEP_RATE, ISR_TICKS_NOMINAL,
 ISR_BEZ_A, ISR_BEZ_B, ISR_BEZ_C, ISR_BEZ_F, ISR_BEZ_AV, ISR_BEZ_2ND, ISR_STEP_RATE, ISR_PHASE) = range(24)
#: length of the ``isr`` state array
N_ISR = 24
#: ``isr[ISR_PHASE]`` after :func:`block_phase_isr`: the phase the event was in (linear advance reads it, with
#: ``isr[ISR_STEP_RATE]``, the step rate that phase computed): accelerating, the first cruising event (its
#: interval computed), a later cruising event, decelerating
PHASE_ACCEL, PHASE_CRUISE_FIRST, PHASE_CRUISE, PHASE_DECEL = 0, 1, 2, 3


def acceleration_rate(accel_steps_s2, timer_hz: int = MARLIN_TIMER_HZ):
    """The block's ``acceleration_rate``: steps/s² as a 2^24-scaled per-tick increment, computed in float32
    and truncated as ``planner.cpp`` does (an int, or an int64 array for an array of accelerations)."""
    f = np.float32(np.float32(16777216.0) / np.float32(timer_hz))
    if np.ndim(accel_steps_s2):
        return (np.asarray(accel_steps_s2).astype(np.float32) * f).astype(np.float32).astype(np.int64)
    return int(np.float32(np.float32(accel_steps_s2) * f))


@njit(cache=True)
def _eval_bezier_curve(a, b, c, f0, av, curr_step):
    """Marlin's Bézier speed at ``curr_step`` ticks into a ramp (stepper.cpp ``_eval_bezier_curve``, the
    portable integer version): t = av·curr_step as a 32-bit fraction of the ramp, then the quintic
    A·t⁵ + B·t⁴ + C·t³ + F in 64-bit fixed point."""
    m32 = np.uint64(0xFFFFFFFF)
    t = (np.uint64(av) * np.uint64(curr_step)) & m32
    f = t
    f = (f * t) >> np.uint64(32)
    f = (f * t) >> np.uint64(32)
    acc = np.int64(f0) << 31
    acc += np.int64((f & m32) >> np.uint64(1)) * np.int64(c)
    f = (f * t) >> np.uint64(32)
    acc += np.int64((f & m32) >> np.uint64(1)) * np.int64(b)
    f = (f * t) >> np.uint64(32)
    acc += np.int64((f & m32) >> np.uint64(1)) * np.int64(a)
    acc >>= 38
    return np.int64(np.int32(acc))


@njit(cache=True)
def _calc_bezier_curve_coeffs(isr, v0, v1, av):
    """The ramp v0 → v1 over the ramp time whose 32-bit inverse is ``av`` (stepper.cpp
    ``_calc_bezier_curve_coeffs``): A, B, C, F of the quintic into the state."""
    isr[ISR_BEZ_A] = 768 * (v1 - v0)
    isr[ISR_BEZ_B] = 1920 * (v0 - v1)
    isr[ISR_BEZ_C] = 1280 * (v1 - v0)
    isr[ISR_BEZ_F] = 128 * v0
    isr[ISR_BEZ_AV] = av


@njit(cache=True)
def block_pickup(isr, n_steps, initial_rate, nominal_rate, final_rate, accelerate_until, decelerate_after,
                 acc_rate, cruise_rate, acceleration_time, deceleration_time, acceleration_time_inverse,
                 deceleration_time_inverse, s_curve, timer_hz):
    """The pick-up half of ``block_phase_isr``: copy the block into the interrupt's state, reset its phase
    clocks and return the first interval (ticks), ``TIMER_RATE / initial_rate``, which counts as
    acceleration time. ``s_curve``: S_CURVE_ACCELERATION (the Bézier fields are used only then)."""
    isr[ISR_SEC] = n_steps
    isr[ISR_INITIAL_RATE] = initial_rate
    isr[ISR_NOMINAL_RATE] = nominal_rate
    isr[ISR_FINAL_RATE] = final_rate
    isr[ISR_ACCEL_UNTIL] = accelerate_until
    isr[ISR_DECEL_AFTER] = decelerate_after
    isr[ISR_ACC_RATE] = acc_rate
    isr[ISR_CRUISE_RATE] = cruise_rate
    isr[ISR_ACCELERATION_TIME] = acceleration_time
    isr[ISR_DECELERATION_TIME] = deceleration_time
    isr[ISR_DEC_TIME_INV] = deceleration_time_inverse
    isr[ISR_S_CURVE] = 1 if s_curve else 0
    isr[ISR_TICKS_NOMINAL] = -1
    isr[ISR_DEC_TIME] = 0
    if s_curve:
        _calc_bezier_curve_coeffs(isr, np.int64(initial_rate), np.int64(cruise_rate),
                                  np.int64(acceleration_time_inverse))
        isr[ISR_BEZ_2ND] = 0
    else:
        isr[ISR_ACC_STEP_RATE] = initial_rate
    interval = np.int64(timer_hz) // np.int64(initial_rate)
    isr[ISR_ACC_TIME] = interval
    return interval


@njit(cache=True)
def block_phase_isr(isr, n, timer_hz):
    """The rate half of ``block_phase_isr`` after ``n`` step events of the block (``1 <= n < n_steps``):
    the interval (ticks) to the next event, from the phase ``n`` is in, with that phase's clock advanced
    (see the module docstring)."""
    if n <= isr[ISR_ACCEL_UNTIL]:
        if isr[ISR_S_CURVE] != 0:
            if isr[ISR_ACC_TIME] < isr[ISR_ACCELERATION_TIME]:
                r = _eval_bezier_curve(isr[ISR_BEZ_A], isr[ISR_BEZ_B], isr[ISR_BEZ_C], isr[ISR_BEZ_F],
                                       isr[ISR_BEZ_AV], isr[ISR_ACC_TIME])
            else:
                r = isr[ISR_CRUISE_RATE]
        else:
            # STEP_MULTIPLY(acceleration_time, acceleration_rate): the high 32 bits of a 32×24 product, rounded
            r = ((isr[ISR_ACC_TIME] * isr[ISR_ACC_RATE] + _HALF_24) >> 24) + isr[ISR_INITIAL_RATE]
            if r > isr[ISR_NOMINAL_RATE]:
                r = isr[ISR_NOMINAL_RATE]
            isr[ISR_ACC_STEP_RATE] = r
        isr[ISR_STEP_RATE] = r
        isr[ISR_PHASE] = PHASE_ACCEL
        interval = np.int64(timer_hz) // r
        isr[ISR_ACC_TIME] += interval
        return interval
    if n > isr[ISR_DECEL_AFTER]:
        if isr[ISR_S_CURVE] != 0:
            if isr[ISR_BEZ_2ND] == 0:
                # the first decelerating step runs at the cruise rate; the second ramp's curve starts here
                _calc_bezier_curve_coeffs(isr, isr[ISR_CRUISE_RATE], isr[ISR_FINAL_RATE], isr[ISR_DEC_TIME_INV])
                isr[ISR_BEZ_2ND] = 1
                s = isr[ISR_CRUISE_RATE]
            elif isr[ISR_DEC_TIME] < isr[ISR_DECELERATION_TIME]:
                s = _eval_bezier_curve(isr[ISR_BEZ_A], isr[ISR_BEZ_B], isr[ISR_BEZ_C], isr[ISR_BEZ_F],
                                       isr[ISR_BEZ_AV], isr[ISR_DEC_TIME])
            else:
                s = isr[ISR_FINAL_RATE]
        else:
            s = (isr[ISR_DEC_TIME] * isr[ISR_ACC_RATE] + _HALF_24) >> 24
            if s < isr[ISR_ACC_STEP_RATE]:
                s = isr[ISR_ACC_STEP_RATE] - s
                if s < isr[ISR_FINAL_RATE]:
                    s = isr[ISR_FINAL_RATE]
            else:
                s = isr[ISR_FINAL_RATE]
        isr[ISR_STEP_RATE] = s
        isr[ISR_PHASE] = PHASE_DECEL
        interval = np.int64(timer_hz) // s
        isr[ISR_DEC_TIME] += interval
        return interval
    isr[ISR_STEP_RATE] = isr[ISR_NOMINAL_RATE]
    isr[ISR_PHASE] = PHASE_CRUISE
    if isr[ISR_TICKS_NOMINAL] < 0:
        # the first cruising step: its interval once for the whole cruise; the ramp down starts from nominal
        isr[ISR_TICKS_NOMINAL] = np.int64(timer_hz) // isr[ISR_NOMINAL_RATE]
        if isr[ISR_S_CURVE] == 0:
            isr[ISR_ACC_STEP_RATE] = isr[ISR_NOMINAL_RATE]
        isr[ISR_DEC_TIME] = 0
        isr[ISR_PHASE] = PHASE_CRUISE_FIRST
    return isr[ISR_TICKS_NOMINAL]


@njit(cache=True)
def block_ticks_per_event(isr, first_interval, timer_hz, phase_ticks):
    """Ticks from pick-up to the last step of the block picked up into ``isr`` (first interval given),
    summed interrupt by interrupt through :func:`block_phase_isr` (a cruise is counted, not looped), split
    into ``phase_ticks`` (accelerating, cruising, decelerating). The reference the ramp sums of
    :func:`block_ticks_kernel` / :func:`block_ticks_scurve_kernel` are held to (tests/test_marlin_isr_sums.py)."""
    n_steps = isr[ISR_SEC]
    phase_ticks[0] = first_interval
    phase_ticks[1] = 0
    phase_ticks[2] = 0
    total = first_interval
    n = np.int64(1)
    while n < n_steps:
        interval = block_phase_isr(isr, n, timer_hz)
        if n <= isr[ISR_ACCEL_UNTIL]:
            phase_ticks[0] += interval
        elif n > isr[ISR_DECEL_AFTER]:
            phase_ticks[2] += interval
        else:
            # every cruising step has the interval of the first: the rest of the cruise at once
            k = isr[ISR_DECEL_AFTER]
            if k > n_steps - 1:
                k = n_steps - 1
            interval *= k - n + 1
            phase_ticks[1] += interval
            n = k
        total += interval
        n += 1
    return total


@njit(cache=True)
def _phase_counts(n_steps, accelerate_until, decelerate_after):
    """How many of the events 1 .. n_steps − 1 after pick-up :func:`block_phase_isr` times as accelerating
    (``n <= accelerate_until``), cruising and decelerating (``n > decelerate_after``, tested after the first)."""
    last = n_steps - 1
    n_acc = accelerate_until if accelerate_until < last else last
    if n_acc < 0:
        n_acc = 0
    cruise_end = decelerate_after if decelerate_after < last else last
    n_cruise = cruise_end - n_acc
    if n_cruise < 0:
        n_cruise = 0
    n_dec = last - n_acc - n_cruise
    return n_acc, n_cruise, n_dec


@njit(cache=True)
def accel_ramp_ticks(acc_time, n_events, initial_rate, nominal_rate, acc_rate, timer_hz):
    """``n_events`` accelerating events of the trapezoid interrupt from the acceleration clock ``acc_time``
    (ticks): returns the clock after them and the last rate (steps/s; ``initial_rate`` if none), exactly as
    :func:`block_phase_isr` steps them. The rate only grows with the clock, so once it reaches
    ``nominal_rate`` every further event is ``timer_hz // nominal_rate`` ticks: the rest is one product."""
    T = np.int64(timer_hz)
    r = np.int64(initial_rate)
    k = np.int64(0)
    while k < n_events:
        r = ((acc_time * acc_rate + _HALF_24) >> 24) + initial_rate
        if r >= nominal_rate:
            r = np.int64(nominal_rate)
            return acc_time + (T // r) * (n_events - k), r
        acc_time += T // r
        k += 1
    return acc_time, r


@njit(cache=True)
def decel_ramp_ticks(dec_time, n_events, acc_step_rate, final_rate, acc_rate, timer_hz):
    """``n_events`` decelerating events of the trapezoid interrupt from the deceleration clock ``dec_time``
    (ticks), down from ``acc_step_rate``: returns the clock after them, exactly as :func:`block_phase_isr`
    steps them. The rate only falls as the clock grows, so once it is held at ``final_rate`` every further
    event is ``timer_hz // final_rate`` ticks: the rest is one product."""
    T = np.int64(timer_hz)
    k = np.int64(0)
    while k < n_events:
        s = (dec_time * acc_rate + _HALF_24) >> 24
        if s < acc_step_rate and acc_step_rate - s > final_rate:
            dec_time += T // (acc_step_rate - s)
            k += 1
        else:
            return dec_time + (T // np.int64(final_rate)) * (n_events - k)
    return dec_time


@njit(cache=True)
def _bezier_ramp_ticks(t, n_events, v0, v1, av, ramp_ticks, timer_hz):
    """``n_events`` events of an S-curve ramp v0 → v1 from its clock ``t`` (ticks): each reads the Bézier at
    its start while ``t < ramp_ticks`` and ``v1`` after, as :func:`block_phase_isr`; returns the clock after
    them. Past the ramp time the rate stays ``v1``: the rest is one product."""
    T = np.int64(timer_hz)
    a = 768 * (v1 - v0)
    b = 1920 * (v0 - v1)
    c = 1280 * (v1 - v0)
    f = 128 * v0
    k = np.int64(0)
    while k < n_events:
        if t >= ramp_ticks:
            return t + (T // v1) * (n_events - k)
        t += T // _eval_bezier_curve(a, b, c, f, av, t)
        k += 1
    return t


@njit(cache=True)
def block_ticks_kernel(n_steps, initial_rate, nominal_rate, final_rate, accelerate_until, decelerate_after,
                       acc_rate, timer_hz, phase_ticks):
    """Ticks from a block's pick-up to its last step (Marlin 2.1.2 trapezoid ISR, see the module docstring).

    ``phase_ticks`` (3 int64, out): ticks spent before steps of the accelerating, cruising and decelerating
    phases (the first interval counts as accelerating). Returns the total. Allocates nothing, so a planner
    kernel compiled without numba's reference counting can call it per block."""
    if n_steps <= 0:
        phase_ticks[0] = 0
        phase_ticks[1] = 0
        phase_ticks[2] = 0
        return np.int64(0)
    # the interrupt's sum phase by phase (what block_ticks_per_event adds event by event, the same integers)
    T = np.int64(timer_hz)
    n_acc, n_cruise, n_dec = _phase_counts(n_steps, accelerate_until, decelerate_after)
    first = T // np.int64(initial_rate)
    acc_end, acc_step_rate = accel_ramp_ticks(first, n_acc, initial_rate, nominal_rate, acc_rate, timer_hz)
    cruise_t = np.int64(0)
    if n_cruise > 0:
        # the first cruising event restarts the braking clock and brakes from nominal
        cruise_t = (T // np.int64(nominal_rate)) * n_cruise
        acc_step_rate = np.int64(nominal_rate)
    dec_t = decel_ramp_ticks(np.int64(0), n_dec, acc_step_rate, final_rate, acc_rate, timer_hz)
    phase_ticks[0] = acc_end
    phase_ticks[1] = cruise_t
    phase_ticks[2] = dec_t
    return acc_end + cruise_t + dec_t


@njit(cache=True)
def block_ticks_scurve_kernel(n_steps, initial_rate, nominal_rate, final_rate, accelerate_until, decelerate_after,
                              cruise_rate, acceleration_time, deceleration_time, acceleration_time_inverse,
                              deceleration_time_inverse, timer_hz, phase_ticks):
    """Ticks from pick-up to last step with S_CURVE_ACCELERATION: each ramp's rate follows Marlin's quintic
    Bézier in time (initial → cruise over ``acceleration_time`` ticks, cruise → final over
    ``deceleration_time``), read at the start of each step interval; the same phase switching by step count
    as :func:`block_ticks_kernel`; allocates nothing either."""
    if n_steps <= 0:
        phase_ticks[0] = 0
        phase_ticks[1] = 0
        phase_ticks[2] = 0
        return np.int64(0)
    # the interrupt's sum phase by phase (what block_ticks_per_event adds event by event, the same integers)
    T = np.int64(timer_hz)
    n_acc, n_cruise, n_dec = _phase_counts(n_steps, accelerate_until, decelerate_after)
    first = T // np.int64(initial_rate)
    acc_end = _bezier_ramp_ticks(first, n_acc, np.int64(initial_rate), np.int64(cruise_rate),
                                 np.int64(acceleration_time_inverse), acceleration_time, timer_hz)
    cruise_t = (T // np.int64(nominal_rate)) * n_cruise
    dec_t = np.int64(0)
    if n_dec > 0:
        # the first braking event runs at the cruise rate, then the second ramp's curve from clock 0
        dec_t = _bezier_ramp_ticks(T // np.int64(cruise_rate), n_dec - 1, np.int64(cruise_rate),
                                   np.int64(final_rate), np.int64(deceleration_time_inverse), deceleration_time,
                                   timer_hz)
    phase_ticks[0] = acc_end
    phase_ticks[1] = cruise_t
    phase_ticks[2] = dec_t
    return acc_end + cruise_t + dec_t


@njit(cache=True)
def block_step_times_kernel(n_steps, initial_rate, nominal_rate, final_rate, accelerate_until, decelerate_after,
                            acc_rate, timer_hz, t_pick, out):
    """Tick of every step of the leading axis (``out[:n_steps]``), from the pick-up tick ``t_pick``: the
    same interrupt as :func:`block_ticks_kernel`, step by step."""
    if n_steps <= 0:
        return
    isr = np.empty(N_ISR, np.int64)
    t = t_pick + block_pickup(isr, n_steps, initial_rate, nominal_rate, final_rate, accelerate_until,
                              decelerate_after, acc_rate, nominal_rate, 0, 0, 0, 0, False, timer_hz)
    out[0] = t
    for n in range(1, n_steps):
        t += block_phase_isr(isr, n, timer_hz)
        out[n] = t


@njit(cache=True)
def pulse_phase_isr(delta_error, advance_dividend, advance_divisor, dir_bits, t, out_t, out_d, n_out):
    """One step event (``Stepper::pulse_phase_isr``): each axis's Bresenham error grows by its dividend;
    an axis whose error reached 0 steps at tick ``t`` (appended to ``out_t[axis]`` / ``out_d[axis]``, +1 or
    −1 from ``dir_bits``) and its error drops by the divisor."""
    for a in range(4):
        delta_error[a] += advance_dividend[a]
        if delta_error[a] >= 0:
            delta_error[a] -= advance_divisor
            k = n_out[a]
            out_t[a, k] = t
            out_d[a, k] = -1 if (dir_bits >> a) & 1 else 1
            n_out[a] = k + 1


@njit(cache=True)
def blocks_pulses_kernel(t_pick, n_steps, axis_steps, dir_bits, initial_rate, nominal_rate, final_rate,
                         accelerate_until, decelerate_after, acc_rate, cruise_rate, acceleration_time,
                         deceleration_time, acceleration_time_inverse, deceleration_time_inverse, s_curve, timer_hz,
                         out_t, out_d, n_out, bugfix=False):
    """Every step pulse of a run of blocks as Marlin's interrupt issues them: block ``i`` picked up at tick
    ``t_pick[i]``, its ``n_steps[i]`` step events timed by :func:`block_phase_isr`, each axis (X, Y, Z, E)
    stepping on them by Bresenham (:func:`pulse_phase_isr`; ``axis_steps[i]``: 4 step counts).

    Appends tick and direction per axis to ``out_t`` / ``out_d`` (4 × capacity; ``n_out``: 4 fill counts,
    updated); each axis needs room for the sum of its steps. ``bugfix``: the step events are timed by
    bugfix-2.1.x's interrupt (:func:`block_step_times_kernel_bugfix`; its ``accelerate_before`` /
    ``decelerate_start`` are in the ``accelerate_until`` / ``decelerate_after`` columns); Bresenham is the same."""
    isr = np.empty(N_ISR, np.int64)
    ticks = np.empty(0, np.int64)
    delta_error = np.empty(4, np.int64)
    advance_dividend = np.empty(4, np.int64)
    for i in range(len(t_pick)):
        sec = n_steps[i]
        if sec <= 0:
            continue
        # pick-up: Bresenham errors at −step_event_count ("1/2" of the doubled divisor), dividends 2·steps
        for a in range(4):
            delta_error[a] = -sec
            advance_dividend[a] = 2 * axis_steps[i, a]
        advance_divisor = 2 * sec
        if bugfix:
            if ticks.size < sec:
                ticks = np.empty(2 * sec, np.int64)
            block_step_times_kernel_bugfix(sec, initial_rate[i], nominal_rate[i], final_rate[i], accelerate_until[i],
                                           decelerate_after[i], acc_rate[i], timer_hz, t_pick[i], ticks)
            for n in range(sec):
                pulse_phase_isr(delta_error, advance_dividend, advance_divisor, dir_bits[i], ticks[n], out_t, out_d,
                                n_out)
            continue
        t = t_pick[i] + block_pickup(isr, sec, initial_rate[i], nominal_rate[i], final_rate[i], accelerate_until[i],
                                     decelerate_after[i], acc_rate[i], cruise_rate[i], acceleration_time[i],
                                     deceleration_time[i], acceleration_time_inverse[i],
                                     deceleration_time_inverse[i], s_curve, timer_hz)
        for n in range(1, sec + 1):
            pulse_phase_isr(delta_error, advance_dividend, advance_divisor, dir_bits[i], t, out_t, out_d, n_out)
            if n < sec:
                t += block_phase_isr(isr, n, timer_hz)


@njit(cache=True)
def block_ticks_kernel_bugfix(n_steps, initial_rate, nominal_rate, final_rate, accelerate_before, decelerate_start,
                              acc_rate, timer_hz, phase_ticks):
    """Ticks from a block's pick-up to its last step in Marlin bugfix-2.1.x (2024-07-30, stepper.cpp
    ``block_phase_isr`` after Marlin's pull request #27013), ``phase_ticks`` as :func:`block_ticks_kernel`.

    What changed against 2.1.2: the acceleration and deceleration clocks start half an interval in (at pick-up
    half the first interval, at the first cruising step half the cruise interval), so each rate is read near
    the middle of its step rather than at its start, and every accelerating step resets the braking clock; the
    phases are by step count, accelerating while fewer than
    ``accelerate_before`` steps are done and braking from ``decelerate_start`` on."""
    phase_ticks[0] = 0
    phase_ticks[1] = 0
    phase_ticks[2] = 0
    if n_steps <= 0:
        return np.int64(0)
    interval = np.int64(timer_hz) // np.int64(initial_rate)
    total = interval
    phase_ticks[0] += interval
    acc_time = interval // 2
    dec_time = interval // 2
    acc_step_rate = np.int64(initial_rate)
    # steps 1 .. accelerate_before − 1 accelerate (each restarting the braking clock), then cruise up to
    # decelerate_start − 1, then brake; each ramp summed as the interrupt steps it (accel_ramp_ticks,
    # decel_ramp_ticks: the same integers)
    acc_end = accelerate_before - 1 if accelerate_before - 1 < n_steps - 1 else n_steps - 1
    if acc_end > 0:
        acc_clock, acc_step_rate = accel_ramp_ticks(acc_time, acc_end, initial_rate, nominal_rate, acc_rate,
                                                    timer_hz)
        phase_ticks[0] += acc_clock - acc_time
        total += acc_clock - acc_time
        dec_time = 0
    cruise_lo = accelerate_before if accelerate_before > 1 else 1
    cruise_hi = decelerate_start if decelerate_start < n_steps else n_steps
    if cruise_hi > cruise_lo:
        ticks_nominal = np.int64(timer_hz) // np.int64(nominal_rate)
        acc_step_rate = np.int64(nominal_rate)
        dec_time = ticks_nominal // 2
        phase_ticks[1] += ticks_nominal * (cruise_hi - cruise_lo)
        total += ticks_nominal * (cruise_hi - cruise_lo)
    dec_lo = decelerate_start if decelerate_start > 1 else 1
    if accelerate_before > dec_lo:
        dec_lo = accelerate_before
    if n_steps > dec_lo:
        dec_ticks = decel_ramp_ticks(dec_time, n_steps - dec_lo, acc_step_rate, final_rate, acc_rate,
                                     timer_hz) - dec_time
        phase_ticks[2] += dec_ticks
        total += dec_ticks
    return total


@njit(cache=True)
def block_step_times_kernel_bugfix(n_steps, initial_rate, nominal_rate, final_rate, accelerate_before,
                                   decelerate_start, acc_rate, timer_hz, t_pick, out):
    """Tick of every step of the leading axis (``out[:n_steps]``) in bugfix-2.1.x, from the pick-up tick
    ``t_pick``: the same rules as :func:`block_ticks_kernel_bugfix`, one step at the end of each interval."""
    if n_steps <= 0:
        return
    interval = np.int64(timer_hz) // np.int64(initial_rate)
    t = t_pick + interval
    out[0] = t
    acc_time = interval // 2
    dec_time = interval // 2
    acc_step_rate = np.int64(initial_rate)
    ticks_nominal = np.int64(0)
    for n in range(1, n_steps):
        if n < accelerate_before:
            r = ((acc_time * acc_rate + _HALF_24) >> 24) + initial_rate
            if r > nominal_rate:
                r = nominal_rate
            acc_step_rate = r
            interval = np.int64(timer_hz) // r
            acc_time += interval
            dec_time = 0
        elif n >= decelerate_start:
            s = (dec_time * acc_rate + _HALF_24) >> 24
            if s < acc_step_rate:
                s = acc_step_rate - s
                if s < final_rate:
                    s = final_rate
            else:
                s = final_rate
            interval = np.int64(timer_hz) // s
            dec_time += interval
        else:
            if ticks_nominal == 0:
                ticks_nominal = np.int64(timer_hz) // np.int64(nominal_rate)
                acc_step_rate = np.int64(nominal_rate)
                dec_time = ticks_nominal // 2
            interval = ticks_nominal
        t += interval
        out[n] = t
