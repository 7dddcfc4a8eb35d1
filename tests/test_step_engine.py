"""The one step engine (stepper.kernel.step_pieces) against hand-worked crossings, for each kinematics it runs.

gen_steps (linear motors), gen_steps_poly (degree-5 pieces) and gen_steps_delta (a delta tower) are the engine
with their own motor functions; a kinematics written in this file through the same five functions proves the
interface is all the engine needs.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from gcodeplan import _jit
from gcodeplan.stepper import kernel

# the hand-worked move: motor m(t) = 10·t − 9.6·t² mm over 1 s, step_dist 1 mm. It peaks at t = 10/19.2 s,
# m = 100/38.4 = 2.604 mm, and ends at m(1) = 0.4 mm: forward steps at the half-step points 0.5, 1.5, 2.5 mm,
# then (hysteresis: the commanded position is 3 mm) backward steps at 2.5, 1.5, 0.5 mm on the way down.
V0, A0 = 10.0, -19.2


def _hand_worked_times(t_start=0.0):
    """Times (s) of the six steps of the hand-worked move: 9.6·t² − 10·t + c = 0, rising root then falling."""
    rise = [(10.0 - math.sqrt(100.0 - 38.4 * c)) / 19.2 for c in (0.5, 1.5, 2.5)]
    fall = [(10.0 + math.sqrt(100.0 - 38.4 * c)) / 19.2 for c in (2.5, 1.5, 0.5)]
    return t_start + np.array(rise + fall), np.array([1, 1, 1, -1, -1, -1], np.int8)


def _buffers(cap=64):
    return np.empty(cap), np.empty(cap, np.int8)


def _linear(t0, dt, p, v, a, j, step_dist, cap=64, reset=None):
    out_t, out_d = _buffers(cap)
    reset = np.zeros(len(t0), np.uint8) if reset is None else reset
    st = kernel.new_state()
    ret = kernel.gen_steps(np.asarray(t0, float), np.asarray(dt, float), np.asarray(p, float), np.asarray(v, float),
                           np.asarray(a, float), np.asarray(j, float), reset, step_dist, st, 0, out_t, out_d, 0)
    return ret, out_t[:ret[1]], out_d[:ret[1]]


def test_linear_motor_steps_at_the_hand_worked_crossings_both_ways():
    ret, t, d = _linear([2.0], [1.0], [0.0], [V0], [A0], [0.0], 1.0)
    want_t, want_d = _hand_worked_times(2.0)
    assert ret == (1, 6, 0)
    assert np.array_equal(d, want_d)
    assert np.max(np.abs(t - want_t)) < 1e-14


def test_poly_motor_steps_at_the_hand_worked_crossings_both_ways():
    coef = np.zeros((1, kernel.POLY_NCOEF))
    coef[0, 1], coef[0, 2] = V0, 0.5 * A0
    out_t, out_d = _buffers()
    ret = kernel.gen_steps_poly(np.array([2.0]), np.array([1.0]), coef, np.zeros(1, np.uint8), 1.0,
                                kernel.new_state(), 0, out_t, out_d, 0)
    want_t, want_d = _hand_worked_times(2.0)
    assert ret == (1, 6, 0)
    assert np.array_equal(out_d[:6], want_d)
    assert np.max(np.abs(out_t[:6] - want_t)) < 1e-14


def test_cubic_piece_steps_at_the_cube_roots():
    # s = t³ (j = 6 mm/s³) over 2 s reaches 8 mm: steps at t = ∛(k + ½), k = 0..7
    ret, t, d = _linear([0.0], [2.0], [0.0], [0.0], [0.0], [6.0], 1.0)
    assert ret == (1, 8, 0)
    assert np.all(d == 1)
    assert np.max(np.abs(t - np.cbrt(np.arange(8) + 0.5))) < 1e-14


def test_delta_carriage_rises_and_falls_while_the_head_moves_straight():
    # the head crosses under the tower along x at 60 mm/s (x from −30 to +30 mm, y = z = 0): the carriage
    # height is h = √(L² − x²), highest at x = 0. Inverting, height h is crossed at x = ∓√(L² − h²).
    arm, v, step_dist = 250.0, 60.0, 0.1
    z = np.zeros((1, 3))
    p = np.array([[-30.0, 0.0, 0.0]])
    vel = np.array([[v, 0.0, 0.0]])
    out_t, out_d = _buffers(1000)
    ret = kernel.gen_steps_delta(np.array([0.5]), np.array([1.0]), p, vel, z, z, np.zeros(1, np.uint8), arm * arm,
                                 0.0, 0.0, step_dist, kernel.new_state(), 0, out_t, out_d, 0)
    anchor = math.sqrt(arm * arm - 900.0)
    k_up = math.floor((arm - anchor) / step_dist - 0.5) + 1       # half-step points below the top
    rise = [anchor + (k + 0.5) * step_dist for k in range(k_up)]
    fall = [anchor + (k - 0.5) * step_dist for k in range(k_up, 0, -1)]    # it ends at the anchor height again
    want = ([0.5 + (-math.sqrt(arm * arm - h * h) + 30.0) / v for h in rise]
            + [0.5 + (math.sqrt(arm * arm - h * h) + 30.0) / v for h in fall])
    assert k_up == 18
    assert ret == (1, 2 * k_up, 0)
    assert np.array_equal(out_d[:ret[1]], np.array([1] * k_up + [-1] * k_up, np.int8))
    # the inverse loses precision near the top (dh/dx → 0): 1e-9 s there, far below a step's timing
    assert np.max(np.abs(out_t[:ret[1]] - np.array(want))) < 1e-9


def _three_motors(cap, step_dist=0.5):
    """The same motor, 5 mm at 10 mm/s twice (10 steps a piece), through the three entry kernels with a
    ``cap``-step buffer: a linear motor, a degree-5 piece, a delta carriage over a head moving in z right
    under its tower (height z + L). Returns [(next, out_n, need), times] per kernel."""
    t0, dt = np.array([0.0, 0.5]), np.array([0.5, 0.5])
    reset = np.zeros(2, np.uint8)
    out = []
    out_t, out_d = _buffers(cap)
    ret = kernel.gen_steps(t0, dt, np.array([0.0, 5.0]), np.full(2, 10.0), np.zeros(2), np.zeros(2), reset,
                           step_dist, kernel.new_state(), 0, out_t, out_d, 0)
    out.append((ret, out_t[:ret[1]].copy()))
    coef = np.zeros((2, kernel.POLY_NCOEF))
    coef[:, 0], coef[:, 1] = (0.0, 5.0), 10.0
    out_t, out_d = _buffers(cap)
    ret = kernel.gen_steps_poly(t0, dt, coef, reset, step_dist, kernel.new_state(), 0, out_t, out_d, 0)
    out.append((ret, out_t[:ret[1]].copy()))
    p = np.array([[7.0, -3.0, 0.0], [7.0, -3.0, 5.0]])
    v = np.array([[0.0, 0.0, 10.0], [0.0, 0.0, 10.0]])
    z = np.zeros((2, 3))
    out_t, out_d = _buffers(cap)
    ret = kernel.gen_steps_delta(t0, dt, p, v, z, z, reset, 300.0 ** 2, 7.0, -3.0, step_dist, kernel.new_state(),
                                 0, out_t, out_d, 0)
    out.append((ret, out_t[:ret[1]].copy()))
    return out


@pytest.mark.parametrize("cap,want", [
    (5, (0, 0, 10)),       # not even the first piece fits: nothing written, its count asked for
    (15, (1, 10, 10)),     # the first piece whole, the second's count asked for
    (20, (2, 20, 0)),      # everything
])
def test_output_full_protocol_is_the_same_for_every_kinematics(cap, want):
    for ret, times in _three_motors(cap):
        assert ret == want
        # forward steps at the half-step points 0.25, 0.75, … mm: t = (k + ½)·0.05 s
        assert np.max(np.abs(times - (np.arange(ret[1]) + 0.5) * 0.05), initial=0.0) < 1e-13


def test_broken_and_unreachable_pieces_stop_the_engine_with_their_code():
    out_t, out_d = _buffers()
    t0, dt, reset = np.array([0.0, 1.0]), np.array([1.0, 1.0]), np.zeros(2, np.uint8)
    ret = kernel.gen_steps(t0, dt, np.array([0.0, np.nan]), np.array([1.0, 1.0]), np.zeros(2), np.zeros(2), reset,
                           0.5, kernel.new_state(), 0, out_t, out_d, 0)
    assert ret == (1, 2, kernel.PIECE_BROKEN)         # the first piece's two steps, then the NaN piece
    p = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    v = np.array([[0.0, 0.0, 1.0], [400.0, 0.0, 0.0]])  # the second piece leaves the 300 mm arm's reach
    z = np.zeros((2, 3))
    ret = kernel.gen_steps_delta(t0, dt, p, v, z, z, reset, 300.0 ** 2, 0.0, 0.0, 0.5, kernel.new_state(), 0,
                                 out_t, out_d, 0)
    assert ret == (1, 2, kernel.PIECE_UNREACHABLE)


def test_a_kinematics_written_outside_the_package_runs_on_the_engine():
    """A motor m = 2·x − 3 (x a parabola piece) given to step_pieces as five functions of its own, its
    crossings found by plain bisection: the engine steps it at the hand-worked times."""
    numba = _jit.numba_module()
    step_pieces = _jit.compiled(kernel.step_pieces)

    @numba.njit
    def piece_at(data, i):
        p, v, a = data
        m = 2.0 * p[i] - 3.0
        status = kernel.PIECE_STILL if v[i] == 0.0 and a[i] == 0.0 else kernel.PIECE_MOVING
        return status, m, (m, 2.0 * v[i], 2.0 * a[i])

    @numba.njit
    def position(piece, s):
        m, v, a = piece
        return m + v * s + 0.5 * a * s * s

    @numba.njit
    def turning_points(piece, span, bnd):
        m, v, a = piece
        if a != 0.0 and 0.0 < -v / a < span:
            bnd[1] = -v / a
            return 1
        return 0

    @numba.njit
    def stretch(piece, lo, hi, sigma):
        return (lo, hi)

    @numba.njit
    def crossing(piece, ctx, target, sigma, step_dist):
        lo, hi = ctx
        for _ in range(200):
            mid = 0.5 * (lo + hi)
            if (position(piece, mid) - target) * sigma < 0.0:
                lo = mid
            else:
                hi = mid
        return hi, (hi, ctx[1])

    @numba.njit
    def scaled_steps(t0, dt, p, v, a, state, out_t, out_d):
        return step_pieces(piece_at, position, turning_points, stretch, crossing, (p, v, a), 1,
                           t0, dt, np.zeros(t0.shape[0], np.uint8), 1.0, state, 0, out_t, out_d, 0)

    out_t, out_d = _buffers()
    # x = 1.5 + 5·t − 4.8·t²  ->  m = 10·t − 9.6·t², the hand-worked move
    ret = scaled_steps(np.array([2.0]), np.array([1.0]), np.array([1.5]), np.array([V0 / 2]), np.array([A0 / 2]),
                       kernel.new_state(), out_t, out_d)
    want_t, want_d = _hand_worked_times(2.0)
    assert ret == (1, 6, 0)
    assert np.array_equal(out_d[:6], want_d)
    assert np.max(np.abs(out_t[:6] - want_t)) < 1e-14
