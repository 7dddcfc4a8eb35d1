"""The block durations the estimate path sums phase by phase (stepper.marlin_isr: ``block_ticks_kernel``,
``block_ticks_scurve_kernel``, ``block_ticks_kernel_bugfix``) against Marlin's interrupt run one event at a time
(``block_pickup`` + ``block_phase_isr``, and bugfix-2.1.x's ``block_step_times_kernel_bugfix``): the same integer
ticks, in total and per phase, on hand-chosen blocks (ramps that reach the cap or the floor, no cruise,
one step, rates of 1 and of millions of steps/s) and on random ones, for the trapezoid, S-curve and bugfix's
half-interval clock.
"""
import numpy as np
import pytest

from gcodeplan.stepper.marlin_isr import (MARLIN_TIMER_HZ, N_ISR, acceleration_rate, block_phase_isr, block_pickup,
                                          block_step_times_kernel_bugfix, block_ticks_kernel, block_ticks_kernel_bugfix,
                                          block_ticks_scurve_kernel)

HZ = MARLIN_TIMER_HZ


def _event_by_event(b, s_curve):
    """Ticks per phase (accelerating incl. the first interval, cruising, decelerating) of the 2.1.2 interrupt
    run one event at a time, and the total."""
    sec, init, nom, fin, au, da, ar, cruise, at, dt, ati, dti = b
    isr = np.zeros(N_ISR, np.int64)
    ph = [block_pickup(isr, sec, init, nom, fin, au, da, ar, cruise, at, dt, ati, dti, s_curve, HZ), 0, 0]
    for n in range(1, sec):
        k = 0 if n <= au else (2 if n > da else 1)
        ph[k] += block_phase_isr(isr, n, HZ)
    return ph, sum(ph)


def _bugfix_event_by_event(b):
    sec, init, nom, fin, ab, ds, ar = b[:7]
    out = np.zeros(sec, np.int64)
    block_step_times_kernel_bugfix(sec, init, nom, fin, ab, ds, ar, HZ, 0, out)
    dt = np.diff(np.concatenate([[0], out]))
    n = np.arange(sec)
    acc = (n == 0) | (n < ab)
    dec = ~acc & (n >= ds)
    return [int(dt[acc].sum()), int(dt[~acc & ~dec].sum()), int(dt[dec].sum())], int(out[-1])


def _scurve_times(init, cruise, accel):
    """acceleration_time (ticks) and its 32-bit inverse as Marlin's planner derives them for a ramp."""
    t = max(1, int((cruise - init) / accel * HZ))
    return t, 0xFFFFFFFF // t


def _random_blocks(seed, n):
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        sec = int(rng.choice([1, 2, 3, int(rng.integers(4, 60)), int(rng.integers(60, 3000))]))
        nom = int(rng.choice([int(rng.integers(120, 2000)), int(rng.integers(2000, 60000)),
                              int(rng.integers(60000, 3_000_000))]))
        init = int(rng.integers(1, nom + 1))
        fin = int(rng.integers(1, nom + 1))
        accel = float(rng.choice([rng.uniform(10, 2000), rng.uniform(2000, 200_000), rng.uniform(2e5, 5e7)]))
        au = int(rng.integers(-1, sec + 2))
        da = int(rng.integers(au, sec + 2))
        at, ati = _scurve_times(init, nom, accel)
        dt, dti = _scurve_times(fin, nom, accel)
        out.append((sec, init, nom, fin, au, da, acceleration_rate(accel), nom, at, dt, ati, dti))
    return out


# (steps, initial, nominal, final, accelerate_until, decelerate_after, steps/s²)
HAND = [
    (1, 200, 4800, 200, 0, 1, 20000),              # one step: the pick-up interval only
    (2, 200, 4800, 200, 1, 1, 20000),              # up one event, nothing else
    (400, 300, 8000, 300, 150, 250, 80000),        # a trapezoid with a cruise
    (400, 300, 8000, 300, 200, 200, 80000),        # a triangle: decelerates from the last accelerating rate
    (5000, 300, 1000, 300, 4000, 4500, 400000),    # reaches nominal long before accelerate_until: capped ramp
    (5000, 1000, 1000, 120, 0, 10, 500000),        # brakes to the final rate early: the floor holds
    (50, 1, 3, 1, 20, 30, 1),                      # rate 1 step/s: 25 M ticks an interval
    (20000, 2_000_000, 6_000_000, 2_000_000, 5000, 15000, 10 ** 9),  # millions of steps/s: 4- and 12-tick intervals
    (30, 5000, 4000, 3000, 10, 20, 20000),         # initial above nominal: capped from the first event
    (30, 100, 4000, 5000, 10, 20, 20000),          # final above the braking rate
    (600, 250, 9000, 250, 600, 600, 0),            # zero acceleration rate
    (700, 250, 9000, 250, -1, 800, 30000),         # all cruise
]


def _hand_blocks():
    out = []
    for sec, init, nom, fin, au, da, accel in HAND:
        at, ati = _scurve_times(init, nom, max(accel, 1))
        dt, dti = _scurve_times(fin, nom, max(accel, 1))
        out.append((sec, init, nom, fin, au, da, acceleration_rate(accel), nom, at, dt, ati, dti))
    return out


@pytest.mark.parametrize("blocks", [_hand_blocks(), _random_blocks(1, 400), _random_blocks(2, 400)],
                         ids=["hand", "random1", "random2"])
def test_trapezoid_sum_equals_the_interrupt_event_by_event(blocks):
    ph = np.zeros(3, np.int64)
    for b in blocks:
        sec, init, nom, fin, au, da, ar = b[:7]
        want_ph, want = _event_by_event(b, False)
        assert block_ticks_kernel(sec, init, nom, fin, au, da, ar, HZ, ph) == want, b
        assert list(ph) == want_ph, b


@pytest.mark.parametrize("blocks", [_hand_blocks(), _random_blocks(3, 400), _random_blocks(4, 400)],
                         ids=["hand", "random3", "random4"])
def test_scurve_sum_equals_the_interrupt_event_by_event(blocks):
    ph = np.zeros(3, np.int64)
    for b in blocks:
        sec, init, nom, fin, au, da, ar, cruise, at, dt, ati, dti = b
        want_ph, want = _event_by_event(b, True)
        assert block_ticks_scurve_kernel(sec, init, nom, fin, au, da, cruise, at, dt, ati, dti, HZ, ph) == want, b
        assert list(ph) == want_ph, b


@pytest.mark.parametrize("blocks", [_hand_blocks(), _random_blocks(5, 400), _random_blocks(6, 400)],
                         ids=["hand", "random5", "random6"])
def test_bugfix_sum_equals_its_interrupt_event_by_event(blocks):
    """bugfix-2.1.x (clocks starting half an interval in): accelerate_before / decelerate_start in the
    accelerate_until / decelerate_after places."""
    ph = np.zeros(3, np.int64)
    for b in blocks:
        sec, init, nom, fin, ab, ds, ar = b[:7]
        want_ph, want = _bugfix_event_by_event(b)
        assert block_ticks_kernel_bugfix(sec, init, nom, fin, ab, ds, ar, HZ, ph) == want, b
        assert list(ph) == want_ph, b


def test_the_hand_blocks_exercise_the_closed_forms():
    """The hand-chosen ramps reach the cap and the floor (so the one-product shortcuts are what is checked):
    the capped ramp's events after reaching nominal are all ``HZ // nominal`` ticks, the floored ramp's
    after reaching the final rate all ``HZ // final``."""
    isr = np.zeros(N_ISR, np.int64)
    sec, init, nom, fin, au, da, accel = HAND[4]
    block_pickup(isr, sec, init, nom, fin, au, da, acceleration_rate(accel), nom, 0, 0, 0, 0, False, HZ)
    iv = [block_phase_isr(isr, n, HZ) for n in range(1, au + 1)]
    assert iv[-3000:] == [HZ // nom] * 3000
    sec, init, nom, fin, au, da, accel = HAND[5]
    block_pickup(isr, sec, init, nom, fin, au, da, acceleration_rate(accel), nom, 0, 0, 0, 0, False, HZ)
    iv = [block_phase_isr(isr, n, HZ) for n in range(1, sec)]
    assert iv[-4000:] == [HZ // fin] * 4000


def test_the_run_kernels_memo_gives_each_block_its_own_sum():
    """The Marlin run kernel's block-time memo (planner.marlin_kernels): blocks met again, in another order,
    under another stepper mode (2.1.2, bugfix, S-curve: the same fields, other times) or another timer rate,
    get the time their own sum gives, never a neighbour's."""
    from gcodeplan.planner import marlin_kernels as mk

    memo = mk.new_scratch()[2]
    key = memo[mk.MEMO_ROWS]
    ph = np.zeros(3, np.int64)
    blocks = _random_blocks(7, 300) + _hand_blocks()
    order = np.random.default_rng(8).permutation(np.tile(np.arange(len(blocks)), 3))
    seen_hit = False
    for i in order:
        b = blocks[i]
        sec, init, nom, fin, au, da, ar, cruise, at, dt, ati, dti = b
        for mode, hz in ((0, HZ), (1, HZ), (2, HZ), (0, HZ // 2)):
            key[:12] = b
            if mode == 2:
                want = block_ticks_scurve_kernel(sec, init, nom, fin, au, da, cruise, at, dt, ati, dti, hz, ph)
            elif mode == 1:
                want = block_ticks_kernel_bugfix(sec, init, nom, fin, au, da, ar, hz, ph)
            else:
                want = block_ticks_kernel(sec, init, nom, fin, au, da, ar, hz, ph)
            want_ph = list(ph)
            filled = np.count_nonzero(memo[:mk.MEMO_ROWS, 0])
            assert mk._block_ticks_memo(memo, mode, key, hz, ph) == want, (mode, hz, b)
            assert list(ph) == want_ph
            seen_hit |= np.count_nonzero(memo[:mk.MEMO_ROWS, 0]) == filled and filled > 0
    assert seen_hit
