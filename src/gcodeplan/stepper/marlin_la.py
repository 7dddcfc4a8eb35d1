"""Marlin 2.1.2's linear advance as its stepper interrupt runs it: the extruder's own interrupt phase.

With ``LIN_ADVANCE`` (K > 0) Marlin 2.1.2 (``stepper.cpp``) does not step the extruder of a print block on
the leading axis's events. The block's E Bresenham still runs there (``pulse_phase_isr``) but only counts
down ``la_advance_steps``; every E pulse comes from a second interrupt phase, ``advance_isr``, that runs on
its own interval ``la_interval`` and steps E by a Bresenham of its own (dividend ``2·e_steps << la_scaling``
over the block's ``2·step_event_count``), each pulse adding ±1 to ``la_advance_steps``:

* accelerating: ``la_interval = TIMER_RATE / (acc_step_rate + la_step_rate) << la_scaling`` where
  ``la_step_rate`` is the block's ``la_advance_rate`` (K · acceleration in steps/s²) while the advance
  built up (``la_advance_steps``) is below ``max_adv_steps``, else 0;
* cruising: from the first cruising event, ``TIMER_RATE / nominal_rate << la_scaling``;
* decelerating: ``la_step_rate`` is ``la_advance_rate`` while the advance is above ``final_adv_steps``; the
  extruder runs at ``|step_rate − la_step_rate|``, backwards when ``la_step_rate`` is the larger (the E
  direction bit is flipped then, and back when it is not), and not at all when the two are equal.

The interrupt (``Stepper::isr``) runs, in one call, the pulse phase if the leading axis is due, then the
advance phase if it is due (or arms it with the current ``la_interval`` when it was idle), then the block
phase; it loops as long as the next event is due before the timer's count plus a 1 µs margin, the count
having run on by each STEP pulse's high time (:data:`ISR_PULSE_HOLD_S`), so every pulse of those events,
X/Y/Z's included, is issued at the call's start. Finishing a block stops the
advance phase (``discard_current_block``: ``la_interval`` and the next advance event become "never");
the next block's ``la_interval`` is set at its pick-up and armed at its first event.

Validated pulse for pulse against the extruder of Marlin 2.1.2.4's linear-advance build
(``tools/compare_marlin.py --reference variants/la``). The block fields come from the planner
(:func:`gcodeplan.planner.marlin.advance_fields`): ``la_advance_rate``, ``la_scaling``, ``max_adv_steps``,
``final_adv_steps``; a block without linear advance has ``la_advance_rate`` 0.
"""
from __future__ import annotations

import numpy as np

from .._jit import njit
from .marlin_isr import (ISR_NOMINAL_RATE, ISR_PHASE, ISR_STEP_RATE, N_ISR, PHASE_ACCEL, PHASE_CRUISE_FIRST,
                         PHASE_DECEL, block_phase_isr, block_pickup)

#: s: Marlin's margin (``STEPPER_TIMER_TICKS_PER_US`` ticks, 1 µs on an ARM board): ``Stepper::isr`` keeps
#: looping while the next event is due before the timer's count plus this margin, and issues that event in the
#: same call, at the call's start
ISR_MARGIN_S = 1e-6
#: s: the timer's count inside a call is not 0 at that test: every STEP pulse the call issued held it for the
#: pulse's high time (``AWAIT_HIGH_PULSE``, once per step event and once per advance pulse). The reference
#: build's hold is not stated; its pulses pin it between 18 and 22 ticks of 25 MHz (all 200,000 stored
#: extruder pulses and all 59,536 per-line end times of both programs agree for any value there, none
#: outside), so the model takes the middle, 20 ticks
ISR_PULSE_HOLD_S = 0.8e-6
#: Marlin's LA_ADV_NEVER (0xFFFFFFFF): the advance phase is idle
LA_ADV_NEVER = 0xFFFFFFFF
_U32 = 0xFFFFFFFF
_E_BIT = 8                       # direction_bits: bit 3 is E (set = negative)

# The state that lives across blocks (one int64 array): la_advance_steps, last_direction_bits (the direction
# pins as the interrupt last set them), la_dividend, the tick at which the interrupt call in progress started
# (pulses of the events it handles are issued at that tick) and how long after it an event still joins it
# (the margin plus the pulse holds so far)
LA_ADVANCE_STEPS, LA_DIR_BITS, LA_DIVIDEND, LA_CALL_START, LA_CALL_REACH = range(5)
#: length of the state array
N_LA_STATE = 5


def isr_ticks(timer_hz: int) -> tuple[int, int]:
    """(margin, pulse hold) in ticks of ``timer_hz``: :data:`ISR_MARGIN_S`, :data:`ISR_PULSE_HOLD_S`."""
    return int(round(ISR_MARGIN_S * timer_hz)), int(round(ISR_PULSE_HOLD_S * timer_hz))


def new_state() -> np.ndarray:
    """The interrupt's state at boot: no advance, every direction bit clear, no call in progress."""
    st = np.zeros(N_LA_STATE, np.int64)
    st[LA_CALL_START] = -(1 << 40)
    return st


@njit(cache=True)
def calc_timer_interval(step_rate, timer_hz):
    """``Stepper::calc_timer_interval`` of a 32-bit board: ticks between events at ``step_rate`` steps/s, an
    integer division of the timer rate."""
    return np.int64(timer_hz) // step_rate


@njit(cache=True)
def _scaled(interval, la_scaling):
    """``interval << la_scaling`` as the firmware's uint32 (it wraps). A wrap to 0 would hang Marlin's
    interrupt loop (it needs K · acceleration near 25 MHz · 2^-32 · 2^la_scaling); the model takes 1 tick."""
    v = (interval << la_scaling) & _U32
    return v if v > 0 else np.int64(1)


@njit(cache=True)
def advance_la_interval(isr, st, la_advance_rate, la_scaling, max_adv_steps, final_adv_steps, timer_hz,
                        la_interval):
    """The linear-advance part of ``block_phase_isr`` after the event the block phase just timed (its phase
    and step rate in ``isr``): the new ``la_interval`` (or ``la_interval`` unchanged in cruise after its first
    event), flipping the E direction bit in ``st`` when the deceleration's extruder rate changes sign."""
    phase = isr[ISR_PHASE]
    rate = isr[ISR_STEP_RATE]
    if phase == PHASE_ACCEL:
        extra = la_advance_rate if st[LA_ADVANCE_STEPS] < max_adv_steps else 0
        return _scaled(calc_timer_interval(rate + extra, timer_hz), la_scaling)
    if phase == PHASE_DECEL:
        extra = la_advance_rate if st[LA_ADVANCE_STEPS] > final_adv_steps else 0
        if extra == rate:
            return np.int64(LA_ADV_NEVER)
        reverse = extra > rate
        interval = _scaled(calc_timer_interval(extra - rate if reverse else rate - extra, timer_hz), la_scaling)
        if reverse != ((st[LA_DIR_BITS] & _E_BIT) != 0):
            st[LA_DIR_BITS] ^= _E_BIT
        return interval
    if phase == PHASE_CRUISE_FIRST:
        return _scaled(calc_timer_interval(isr[ISR_NOMINAL_RATE], timer_hz), la_scaling)
    return la_interval


@njit(cache=True)
def _emit(out_t, out_d, n_out, axis, t, d):
    k = n_out[axis]
    if k < out_t.shape[1]:
        out_t[axis, k] = t
        out_d[axis, k] = d
    n_out[axis] = k + 1


@njit(cache=True)
def la_blocks_pulses_kernel(t_pick, n_steps, axis_steps, dir_bits, initial_rate, nominal_rate, final_rate,
                            accelerate_until, decelerate_after, acc_rate, cruise_rate, acceleration_time,
                            deceleration_time, acceleration_time_inverse, deceleration_time_inverse, s_curve,
                            timer_hz, la_advance_rate, la_scaling, max_adv_steps, final_adv_steps, margin_ticks,
                            pulse_ticks, st, out_t, out_d, n_out):
    """Every step pulse of a run of blocks as Marlin's interrupt issues them with linear advance: the block
    events as :func:`gcodeplan.stepper.marlin_isr.blocks_pulses_kernel` times them, X/Y/Z (and E of a block
    without advance) by Bresenham on them, E of an advance block from the advance phase (module
    docstring), each pulse at the start of the interrupt call that issued it: a call goes on to the next
    event while it is due less than ``margin_ticks`` plus ``pulse_ticks`` per STEP pulse issued so far after
    the call's start (:func:`isr_ticks`).

    ``st`` (:func:`new_state`) carries the interrupt across calls. Appends tick and direction per axis to
    ``out_t`` / ``out_d`` (4 × capacity) and counts in ``n_out``; pulses beyond the capacity are counted but
    not stored (the caller retries with more room)."""
    isr = np.empty(N_ISR, np.int64)
    delta_error = np.empty(4, np.int64)
    dividend = np.empty(4, np.int64)
    never = np.int64(LA_ADV_NEVER)
    for i in range(len(t_pick)):
        sec = n_steps[i]
        if sec <= 0:
            continue
        # pick-up (block_phase_isr after discarding the previous block: the advance phase is idle); the
        # direction pins take the block's bits (set_directions when they differ, E's flip included)
        st[LA_DIR_BITS] = dir_bits[i]
        for a in range(4):
            delta_error[a] = -sec
            dividend[a] = 2 * axis_steps[i, a]
        la_delta_error = -sec
        divisor = 2 * sec
        la_active = la_advance_rate[i] != 0
        if la_active:
            st[LA_DIVIDEND] = dividend[3] << la_scaling[i]
        first = block_pickup(isr, sec, initial_rate[i], nominal_rate[i], final_rate[i], accelerate_until[i],
                             decelerate_after[i], acc_rate[i], cruise_rate[i], acceleration_time[i],
                             deceleration_time[i], acceleration_time_inverse[i], deceleration_time_inverse[i],
                             s_curve, timer_hz)
        la_interval = never
        if la_active:
            extra = la_advance_rate[i] if st[LA_ADVANCE_STEPS] < max_adv_steps[i] else 0
            la_interval = _scaled(calc_timer_interval(initial_rate[i] + extra, timer_hz), la_scaling[i])
        main_due = t_pick[i] + first
        adv_due = never                  # a tick, or never
        n = 0
        while True:
            cur = main_due
            if adv_due != never and adv_due < cur:
                cur = adv_due
            if cur - st[LA_CALL_START] >= st[LA_CALL_REACH]:
                # a new interrupt call
                st[LA_CALL_START] = cur
                st[LA_CALL_REACH] = margin_ticks
            stamp = st[LA_CALL_START]
            main = cur == main_due
            if main:
                # pulse_phase_isr: one event of the leading axis, every axis by Bresenham
                n += 1
                st[LA_CALL_REACH] += pulse_ticks        # the leading axis steps at every event
                for a in range(4):
                    delta_error[a] += dividend[a]
                    if delta_error[a] >= 0:
                        delta_error[a] -= divisor
                        if a == 3 and la_active:
                            # the advance phase issues E: this step only lowers the advance count
                            st[LA_ADVANCE_STEPS] -= 1
                        else:
                            _emit(out_t, out_d, n_out, a, stamp, -1 if (st[LA_DIR_BITS] >> a) & 1 else 1)
            if adv_due == cur:
                # advance_isr: the E Bresenham of the advance phase, in the direction E last got
                la_delta_error += st[LA_DIVIDEND]
                if la_delta_error >= 0:
                    d = -1 if st[LA_DIR_BITS] & _E_BIT else 1
                    st[LA_ADVANCE_STEPS] += d
                    la_delta_error -= divisor
                    st[LA_CALL_REACH] += pulse_ticks
                    _emit(out_t, out_d, n_out, 3, stamp, d)
                adv_due = never if la_interval == never else cur + la_interval
            elif adv_due == never and la_interval != never:
                adv_due = cur + la_interval
            if main:
                if n >= sec:
                    break                # discard_current_block: the advance phase stops with the block
                main_due = cur + block_phase_isr(isr, n, timer_hz)
                if la_active:
                    la_interval = advance_la_interval(isr, st, la_advance_rate[i], la_scaling[i], max_adv_steps[i],
                                                      final_adv_steps[i], timer_hz, la_interval)
