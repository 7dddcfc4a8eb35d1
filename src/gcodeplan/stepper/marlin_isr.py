"""Marlin 2.1.2's stepper interrupt as it times one planner block, in timer ticks.

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

Each rate becomes an interval by integer division of the timer rate; the block lasts the sum of its
intervals and its last step is the end of the block (the next block is picked up in the same interrupt).
``acceleration_rate`` is ``(uint32)(accel_steps_per_s2 · 2^24 / TIMER_RATE)`` in float32, as the planner
stores it. Validated against every block of the shared Marlin reference (docs/design.md, Marlin model).

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


def acceleration_rate(accel_steps_s2: int, timer_hz: int = MARLIN_TIMER_HZ) -> int:
    """The block's ``acceleration_rate``: steps/s² as a 2^24-scaled per-tick increment, computed in float32
    and truncated as ``planner.cpp`` does."""
    f = np.float32(accel_steps_s2) * (np.float32(16777216.0) / np.float32(timer_hz))
    return int(np.float32(f))


@njit(cache=True)
def block_ticks_kernel(n_steps, initial_rate, nominal_rate, final_rate, accelerate_until, decelerate_after,
                       acc_rate, timer_hz, phase_ticks):
    """Ticks from a block's pick-up to its last step (Marlin 2.1.2 trapezoid ISR, see the module docstring).

    ``phase_ticks`` (3 int64, out): ticks spent before steps of the accelerating, cruising and decelerating
    phases (the first interval counts as accelerating). Returns the total."""
    phase_ticks[0] = 0
    phase_ticks[1] = 0
    phase_ticks[2] = 0
    if n_steps <= 0:
        return np.int64(0)
    interval = np.int64(timer_hz) // np.int64(initial_rate)
    total = interval
    phase_ticks[0] += interval
    acc_time = interval
    dec_time = np.int64(0)
    acc_step_rate = np.int64(initial_rate)
    ticks_nominal = np.int64(-1)
    # the phases are contiguous runs of step numbers: accelerating 1..accelerate_until, cruising up to
    # decelerate_after (every interval the same: counted, not looped), decelerating after it
    last = n_steps - 1
    acc_end = accelerate_until if accelerate_until < last else last
    for n in range(1, acc_end + 1):
        r = ((acc_time * acc_rate + _HALF_24) >> 24) + initial_rate
        if r > nominal_rate:
            r = nominal_rate
        acc_step_rate = r
        interval = np.int64(timer_hz) // r
        acc_time += interval
        phase_ticks[0] += interval
        total += interval
    cruise_lo = accelerate_until + 1 if accelerate_until + 1 > 1 else 1
    cruise_hi = decelerate_after if decelerate_after < last else last
    if cruise_hi >= cruise_lo:
        ticks_nominal = np.int64(timer_hz) // np.int64(nominal_rate)
        acc_step_rate = np.int64(nominal_rate)
        phase_ticks[1] += ticks_nominal * (cruise_hi - cruise_lo + 1)
        total += ticks_nominal * (cruise_hi - cruise_lo + 1)
    dec_lo = decelerate_after + 1 if decelerate_after + 1 > 1 else 1
    for n in range(dec_lo, last + 1):
        s = (dec_time * acc_rate + _HALF_24) >> 24
        if s < acc_step_rate:
            s = acc_step_rate - s
            if s < final_rate:
                s = final_rate
        else:
            s = final_rate
        interval = np.int64(timer_hz) // s
        dec_time += interval
        phase_ticks[2] += interval
        total += interval
    return total


@njit(cache=True)
def block_step_times_kernel(n_steps, initial_rate, nominal_rate, final_rate, accelerate_until, decelerate_after,
                            acc_rate, timer_hz, t_pick, out):
    """Tick of every step of the leading axis (``out[:n_steps]``), from the pick-up tick ``t_pick``: the
    same loop as :func:`block_ticks_kernel`."""
    if n_steps <= 0:
        return
    interval = np.int64(timer_hz) // np.int64(initial_rate)
    t = t_pick + interval
    out[0] = t
    acc_time = interval
    dec_time = np.int64(0)
    acc_step_rate = np.int64(initial_rate)
    ticks_nominal = np.int64(-1)
    for n in range(1, n_steps):
        if n <= accelerate_until:
            r = ((acc_time * acc_rate + _HALF_24) >> 24) + initial_rate
            if r > nominal_rate:
                r = nominal_rate
            acc_step_rate = r
            interval = np.int64(timer_hz) // r
            acc_time += interval
        elif n > decelerate_after:
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
            if ticks_nominal < 0:
                ticks_nominal = np.int64(timer_hz) // np.int64(nominal_rate)
                acc_step_rate = np.int64(nominal_rate)
            interval = ticks_nominal
        t += interval
        out[n] = t


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
def block_ticks_scurve_kernel(n_steps, initial_rate, nominal_rate, final_rate, accelerate_until, decelerate_after,
                              cruise_rate, acceleration_time, deceleration_time, acceleration_time_inverse,
                              deceleration_time_inverse, timer_hz, phase_ticks):
    """Ticks from pick-up to last step with S_CURVE_ACCELERATION: each ramp's rate follows Marlin's quintic
    Bézier in time (initial → cruise over ``acceleration_time`` ticks, cruise → final over
    ``deceleration_time``), read at the start of each step interval; the same phase switching by step count
    as :func:`block_ticks_kernel`."""
    phase_ticks[0] = 0
    phase_ticks[1] = 0
    phase_ticks[2] = 0
    if n_steps <= 0:
        return np.int64(0)
    # _calc_bezier_curve_coeffs(initial, cruise, acceleration_time_inverse)
    v0 = np.int64(initial_rate)
    v1 = np.int64(cruise_rate)
    ba, bb, bc, bf = 768 * (v1 - v0), 1920 * (v0 - v1), 1280 * (v1 - v0), 128 * v0
    bav = np.int64(acceleration_time_inverse)
    second_half = False
    interval = np.int64(timer_hz) // np.int64(initial_rate)
    total = interval
    phase_ticks[0] += interval
    acc_time = interval
    dec_time = np.int64(0)
    ticks_nominal = np.int64(-1)
    for n in range(1, n_steps):
        if n <= accelerate_until:
            if acc_time < acceleration_time:
                r = _eval_bezier_curve(ba, bb, bc, bf, bav, acc_time)
            else:
                r = np.int64(cruise_rate)
            interval = np.int64(timer_hz) // r
            acc_time += interval
            phase_ticks[0] += interval
        elif n > decelerate_after:
            if not second_half:
                v0 = np.int64(cruise_rate)
                v1 = np.int64(final_rate)
                ba, bb, bc, bf = 768 * (v1 - v0), 1920 * (v0 - v1), 1280 * (v1 - v0), 128 * v0
                bav = np.int64(deceleration_time_inverse)
                second_half = True
                s = np.int64(cruise_rate)
            elif dec_time < deceleration_time:
                s = _eval_bezier_curve(ba, bb, bc, bf, bav, dec_time)
            else:
                s = np.int64(final_rate)
            interval = np.int64(timer_hz) // s
            dec_time += interval
            phase_ticks[2] += interval
        else:
            if ticks_nominal < 0:
                ticks_nominal = np.int64(timer_hz) // np.int64(nominal_rate)
            interval = ticks_nominal
            phase_ticks[1] += interval
        total += interval
    return total


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
    # steps 1 .. accelerate_before − 1 accelerate, then cruise up to decelerate_start − 1, then brake
    acc_end = accelerate_before - 1 if accelerate_before - 1 < n_steps - 1 else n_steps - 1
    for n in range(1, acc_end + 1):
        r = ((acc_time * acc_rate + _HALF_24) >> 24) + initial_rate
        if r > nominal_rate:
            r = nominal_rate
        acc_step_rate = r
        interval = np.int64(timer_hz) // r
        acc_time += interval
        dec_time = 0
        phase_ticks[0] += interval
        total += interval
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
    for n in range(dec_lo, n_steps):
        s = (dec_time * acc_rate + _HALF_24) >> 24
        if s < acc_step_rate:
            s = acc_step_rate - s
            if s < final_rate:
                s = final_rate
        else:
            s = final_rate
        interval = np.int64(timer_hz) // s
        dec_time += interval
        phase_ticks[2] += interval
        total += interval
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
