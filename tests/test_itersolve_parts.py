"""The named parts of Klipper's step search (stepper.kernel: itersolve_gen_steps_range split along
itersolve.c / stepcompress.c), each against a hand-worked case."""
from __future__ import annotations

import math

import numpy as np

from gcodeplan.stepper import kernel


def _buffers(n=8):
    return np.zeros(n), np.zeros(n, np.int8)


def test_append_without_filter_emits_each_step_at_once():
    """sds_t = 0: a step goes out at once with its direction; the direction is remembered in the state."""
    st = kernel.new_itersolve_state()
    out_t, out_d = _buffers()
    n, pend, pend_t = kernel._its_append(False, 0.25, 0.0, st, False, 0.0, out_t, out_d, 0)
    assert (n, pend) == (1, False)
    assert out_t[0] == 0.25 and out_d[0] == -1
    assert st[kernel.I_DIR] == 0.0


def test_append_filter_drops_a_step_and_its_quick_reversal():
    """stepcompress.c's step+dir+step filter (sds_t = 750 µs): a forward step at 1.0000 s held back; a backward
    step 500 µs later cancels it (both vanish); a forward step 1 ms after that is held, and the next forward one
    releases it."""
    sds = 750e-6
    st = kernel.new_itersolve_state()
    out_t, out_d = _buffers()
    n, pend, pend_t = kernel._its_append(True, 1.0, sds, st, False, 0.0, out_t, out_d, 0)
    assert (n, pend, pend_t) == (0, True, 1.0)
    n, pend, pend_t = kernel._its_append(False, 1.0005, sds, st, pend, pend_t, out_t, out_d, n)
    assert (n, pend) == (0, False)          # taken back: nothing out, nothing held
    n, pend, pend_t = kernel._its_append(True, 1.0015, sds, st, pend, pend_t, out_t, out_d, n)
    assert (n, pend, pend_t) == (0, True, 1.0015)
    n, pend, pend_t = kernel._its_append(True, 1.003, sds, st, pend, pend_t, out_t, out_d, n)
    assert (n, pend, pend_t) == (1, True, 1.003)
    assert out_t[0] == 1.0015 and out_d[0] == 1


def test_append_and_commit_report_a_full_buffer():
    """No room: −1 and nothing written (the caller restores the window and empties the buffer)."""
    st = kernel.new_itersolve_state()
    out_t, out_d = _buffers(1)
    out_t[0] = 7.0
    assert kernel._its_append(True, 2.0, 0.0, st, False, 0.0, out_t, out_d, 1)[0] == -1
    assert kernel._its_commit(st, 2.0, out_t, out_d, 1) == -1
    assert out_t[0] == 7.0


def test_commit_releases_the_held_step_with_the_state_direction():
    st = kernel.new_itersolve_state()
    st[kernel.I_DIR] = 0.0
    out_t, out_d = _buffers()
    assert kernel._its_commit(st, 0.5, out_t, out_d, 3) == 4
    assert out_t[3] == 0.5 and out_d[3] == -1


def test_angle_post_fixup_wraps_within_half_a_period():
    """Klipper's polar_stepper_angle_post_fixup: 3.5 rad → 3.5 − 2π, −3.5 rad → −3.5 + 2π, 3 rad kept; no
    period: unchanged."""
    two_pi = 2.0 * math.pi
    assert kernel._its_angle_post_fixup(3.5, two_pi) == 3.5 - two_pi
    assert kernel._its_angle_post_fixup(-3.5, two_pi) == -3.5 + two_pi
    assert kernel._its_angle_post_fixup(3.0, two_pi) == 3.0
    assert kernel._its_angle_post_fixup(1e3, 0.0) == 1e3


def test_monotone_end_stops_at_the_turning_point():
    """p = s − s² on one piece [0, 1] s: moving forward until the velocity 1 − 2s vanishes at s = 0.5; backward
    from s = 0.7 the run lasts to the piece's end (1 s)."""
    pt0 = np.array([0.0])
    pdt = np.array([1.0])
    coef = np.zeros((1, kernel.POLY_NCOEF))
    coef[0, 1] = 1.0
    coef[0, 2] = -1.0
    lim, k = kernel._its_monotone_end(pt0, pdt, coef, 0, 0.1, True)
    assert (lim, k) == (0.5, 0)
    lim, k = kernel._its_monotone_end(pt0, pdt, coef, 0, 0.7, False)
    assert (lim, k) == (1.0, 0)


def test_closed_form_steps_are_the_half_step_crossings_of_a_ramp():
    """p = 50·s² (s ≥ 0) with steps of 0.01 mm after a step at the crossing of 0.005 mm: the next crossings of
    0.015, 0.025, … mm are at √(p/50), each taken while Klipper's probes stay on the run (end 1 s) and before the range ends (0.2 s)."""
    pt0 = np.array([0.0])
    pdt = np.array([1.0])
    coef = np.zeros((1, kernel.POLY_NCOEF))
    coef[0, 2] = 50.0
    half = 0.005
    t_first = math.sqrt(0.005 / 50.0)
    out_t, out_d = _buffers(1024)
    st = kernel.new_itersolve_state()
    st[kernel.I_DIR] = 1.0
    res = kernel._its_closed_form_steps(pt0, pdt, coef, 0, 1.0, t_first, 0.0, 0.2, True, 0.015, half,
                                        1.5 * t_first, 0.005, 0.0, st, False, 0.0, out_t, out_d, 0)
    out_n, taken = res[0], res[8]
    assert out_n == taken > 150
    assert out_t[out_n - 1] < 0.2
    want = np.sqrt((0.015 + 0.01 * np.arange(out_n)) / 50.0)
    assert np.max(np.abs(out_t[:out_n] - want)) < 1e-12
    assert np.all(out_d[:out_n] == 1)
    assert res[5] == out_t[out_n - 1]          # time of the last step taken
