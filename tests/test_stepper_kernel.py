"""Exact step times: closed forms, counts, directions, reversals, re-anchoring, streaming, filter."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gcodeplan.kinematics import Rail
from gcodeplan.machine import Machine
from gcodeplan.schema import SEGMENT_DTYPE
from gcodeplan.stepper import KLIPPER_SDS_FILTER_T, kernel
from gcodeplan.stepper.generate import StepGenerator, generate_steps
from gcodeplan.stepper.synth import (concat_plans, line_segments, polyline_segments, scurve_line_segments,
                                     trapezoid_times)

SPM = 80.0
X_RAIL = [Rail("x", SPM, (1.0, 0.0, 0.0, 0.0))]


def machine(kin="cartesian") -> Machine:
    m = Machine(kinematics=kin)
    for ax, spm in zip("xyze", (80.0, 80.0, 400.0, 95.52)):
        m.axes[ax].steps_per_mm = spm
    return m


def trapezoid_inverse(x: float, v_s: float, v_c: float, v_e: float, a: float, move_d: float) -> float:
    """Time at which a trapezoid along a line reaches distance x (independent closed form per phase)."""
    t_a, t_c, t_d = trapezoid_times(move_d, v_s, v_c, v_e, a)
    d_a = (v_c ** 2 - v_s ** 2) / (2 * a)
    d_c = v_c * t_c
    if x <= d_a:
        return (math.sqrt(v_s ** 2 + 2 * a * x) - v_s) / a
    if x <= d_a + d_c:
        return t_a + (x - d_a) / v_c
    y = x - d_a - d_c          # v_c·τ − a τ²/2 = y
    return t_a + t_c + (v_c - math.sqrt(max(v_c ** 2 - 2 * a * y, 0.0))) / a


@pytest.mark.parametrize("x0,x1,v_s,v_c,v_e,a", [
    (0.0, 200.0, 0.0, 100.0, 0.0, 3000.0),        # Klipper's a_long_x
    (3.01, 41.7, 5.0, 150.0, 20.0, 2500.0),
    (50.0, 12.3, 0.0, 80.0, 0.0, 1000.0),         # negative direction
    (-7.2, -7.0, 0.0, 2.0, 0.0, 500.0),           # a few steps, triangle-free cruise
])
def test_single_trapezoid_steps_are_the_analytic_inverse(x0, x1, v_s, v_c, v_e, a):
    seg = line_segments((x0, 0, 0, 0), (x1, 0, 0, 0), v_s, v_c, v_e, a, t_start=1.25)
    times, dirs = generate_steps(seg, rails=X_RAIL)["x"]
    sign = 1 if x1 > x0 else -1
    # count: change of round(position·steps/mm) (no position here sits on a half step)
    assert len(times) == abs(round(x1 * SPM - x0 * SPM))
    assert np.all(dirs == sign)
    # step k (1-based) at distance (k − ½)/SPM from the start along the move
    k = np.arange(1, len(times) + 1)
    expected = [1.25 + trapezoid_inverse((kk - 0.5) / SPM, v_s, v_c, v_e, a, abs(x1 - x0)) for kk in k]
    assert np.max(np.abs(times - np.array(expected))) < 1e-9
    assert np.all(np.diff(times) > 0)


def test_first_step_matches_klipper_worked_example():
    # klipper-planner.md §8: first step of a 0→200 mm move at a = 3000 is √(2·0.00625/3000) after the start
    seg = line_segments((0, 0, 0, 0), (200, 0, 0, 0), 0.0, 100.0, 0.0, 3000.0)
    times, _ = generate_steps(seg, rails=X_RAIL)["x"]
    assert times[0] == pytest.approx(math.sqrt(2 * 0.00625 / 3000), abs=1e-12)


def test_steps_count_and_direction_per_axis_on_a_diagonal():
    m = machine()
    start, end = (10.0, 90.0, 0.2, 1.0), (35.3, 12.1, 0.45, 3.2)
    seg = line_segments(start, end, 0.0, 120.0, 0.0, 3000.0)
    steps = generate_steps(seg, m)
    for ax, s0, s1, spm in zip("xyze", start, end, (80, 80, 400, 95.52)):
        t, d = steps[ax]
        assert len(t) == abs(round(s1 * spm) - round(s0 * spm)), ax
        assert np.all(d == (1 if s1 > s0 else -1)), ax


@pytest.mark.parametrize("dx,dy", [(30.0, 10.0), (10.0, 30.0), (-25.0, 7.5), (12.0, -40.0)])
def test_corexy_steps_equal_cartesian_steps_of_sum_and_difference(dx, dy):
    """A = X + Y follows the same profile scaled by |r_x ± r_y|: build that move along X alone."""
    x0, y0 = 20.0, 30.0
    v_c, acc = 100.0, 2000.0
    seg = line_segments((x0, y0, 0, 0), (x0 + dx, y0 + dy, 0, 0), 0.0, v_c, 0.0, acc)
    core = generate_steps(seg, machine("corexy"))
    d = math.hypot(dx, dy)
    for name, w in (("a", 1.0), ("b", -1.0)):
        k = abs(dx + w * dy) / d
        ref_seg = line_segments((x0 + w * y0, 0, 0, 0), (x0 + dx + w * (y0 + dy), 0, 0, 0), 0.0, v_c * k, 0.0,
                                acc * k)
        ref_t, ref_d = generate_steps(ref_seg, rails=X_RAIL)["x"]
        t, dd = core[name]
        assert len(t) == len(ref_t) > 0
        assert np.max(np.abs(t - ref_t)) < 1e-9
        assert np.array_equal(dd, ref_d)


def test_scurve_steps_solve_the_cubic():
    seg = scurve_line_segments((0, 0, 0, 0), (30.0, 0, 0, 0), 150.0, 3000.0, 2e5)
    assert np.any(seg["jx"] != 0)
    times, dirs = generate_steps(seg, rails=X_RAIL)["x"]
    assert len(times) == 30 * 80 and np.all(dirs == 1)
    # position at each step time (evaluated independently from the pieces) is the half-step point
    idx = np.searchsorted(seg["t0"], times, side="right") - 1
    tau = times - seg["t0"][idx]
    r = seg[idx]
    pos = r["px"] + r["vx"] * tau + r["ax"] * tau ** 2 / 2 + r["jx"] * tau ** 3 / 6
    expected = (np.arange(len(times)) + 0.5) / SPM
    # |Δx| ≤ v·1 ns: the time is within a nanosecond of the crossing
    vel = r["vx"] + r["ax"] * tau + r["jx"] * tau ** 2 / 2
    assert np.all(np.abs(pos - expected) <= np.maximum(vel, 1e-3) * 1e-9 + 1e-12)


def _piece(t0, dt, p, v, a, j=0.0):
    row = np.zeros(1, SEGMENT_DTYPE)
    row["t0"], row["dt"], row["px"], row["vx"], row["ax"], row["jx"] = t0, dt, p, v, a, j
    return row


def test_reversal_inside_a_parabola():
    # x(τ) = 1 − 2τ + 5τ²/2 over 1 s: minimum at τ = 0.4, x = 0.6, back to 1.5 at τ = 1
    seg = _piece(0.0, 1.0, 1.0, -2.0, 5.0)
    t, d = generate_steps(seg, rails=[Rail("x", 10.0, (1, 0, 0, 0))])["x"]
    # grid anchored at 1.0 (u = 0): down to u = −4 crosses −0.5 … −3.5 (4 steps), up to u = 5 crosses −3.5 … 4.5
    assert list(d) == [-1] * 4 + [1] * 9
    for k, tk in enumerate(t[:4]):
        target = 1.0 - (k + 0.5) / 10
        assert tk == pytest.approx((2 - math.sqrt(4 - 10 * (1 - target))) / 5, abs=1e-12)
    for k, tk in enumerate(t[4:]):
        target = 1.0 + (-3.5 + k) / 10
        assert tk == pytest.approx((2 + math.sqrt(4 - 10 * (1 - target))) / 5, abs=1e-12)


def test_reversals_inside_a_cubic_piece():
    # x(τ) = τ³/6·6 − 3τ²/2·... : v = 3τ² − 6τ + 2 has two roots; check against the sampled position
    p, v, a, j = 0.0, 2.0, -6.0, 6.0          # x = 2τ − 3τ² + τ³ on [0, 3]: up to 0.385, down to −0.385, up to 6
    seg = _piece(0.0, 3.0, p, v, a, j)
    rail = Rail("x", 100.0, (1, 0, 0, 0))
    t, d = generate_steps(seg, rails=[rail])["x"]
    assert np.count_nonzero(np.diff(d)) == 2
    x = lambda tt: 2 * tt - 3 * tt ** 2 + tt ** 3
    n_up1 = round(x(1 - 1 / math.sqrt(3)) * 100)
    assert list(d[:n_up1]) == [1] * n_up1
    # every step time puts the position on its half-step point
    n = np.concatenate(([0], np.cumsum(d)))
    half = (n[:-1] + n[1:]) / 2 / 100
    assert np.max(np.abs(x(t) - half)) < 1e-12
    assert np.sum(d) == round(x(3.0) * 100)


def test_a_stop_exactly_on_a_half_step_point_steps_forward_not_back():
    """The tie rule (kernel docstring): a position that reaches a half-step point exactly and stops there takes
    the forward step (thresholds n + ½ ≤ u) but not the backward one (thresholds n − ½ > u). Binary-exact
    numbers (64 steps/mm, half a step = 1/128 mm reached at τ = 1 s) make the tie exact in floating point."""
    rail = Rail("x", 64.0, (1, 0, 0, 0))
    half = 1.0 / 128.0
    # 0 → +½ step: one forward step, at the very end of the piece
    t, d = generate_steps(_piece(0.0, 1.0, 0.0, half, 0.0), rails=[rail])["x"]
    assert list(d) == [1] and list(t) == [1.0]
    # 0 → −½ step: no step (the grid point below is reached, not passed)
    t, d = generate_steps(_piece(0.0, 1.0, 0.0, -half, 0.0), rails=[rail])["x"]
    assert len(t) == 0
    # the same from a parabola that stops at the tie (v = 0 there): x = ½·(1/64)·τ² on τ ∈ [0, 1] ends at 1/128
    t, d = generate_steps(_piece(0.0, 1.0, 0.0, 0.0, 1.0 / 64.0), rails=[rail])["x"]
    assert list(d) == [1] and list(t) == [1.0]
    t, d = generate_steps(_piece(0.0, 1.0, 0.0, 0.0, -1.0 / 64.0), rails=[rail])["x"]
    assert len(t) == 0
    # and just past the ties both ways: a step each (the rule is about the tie only)
    for sign in (1.0, -1.0):
        t, d = generate_steps(_piece(0.0, 1.0, 0.0, sign * half * (1 + 2 ** -20), 0.0), rails=[rail])["x"]
        assert list(d) == [int(sign)]


def test_jump_between_pieces_reanchors_without_steps():
    rail = Rail("x", 10.0, (1, 0, 0, 0))
    a = _piece(0.0, 1.0, 0.0, 1.03, 0.0)          # 0 → 1.03: steps at 0.05 … 0.95 (10)
    b = _piece(1.0, 1.0, 5.017, 1.0, 0.0)         # set to 5.017, then → 6.017
    t, d = generate_steps(np.concatenate([a, b]), rails=[rail])["x"]
    assert len(t) == 10 + 10
    # after the jump, steps sit on 5.017 + (k + ½)/10, not on the old grid
    assert t[10] == pytest.approx(1.0 + 0.05, abs=1e-12)
    assert np.all(d == 1)


def test_reset_flag_reanchors_even_without_a_jump():
    rail = Rail("x", 10.0, (1, 0, 0, 0))
    a = _piece(0.0, 1.0, 0.0, 0.12, 0.0)          # ends at 0.12, grid at 0: one step (at 0.05)
    b = _piece(1.0, 1.0, 0.12, 0.1, 0.0)          # 0.12 → 0.22
    seg = np.concatenate([a, b])
    plain, _ = generate_steps(seg, rails=[rail])["x"]
    assert plain == pytest.approx([0.05 / 0.12, 1.0 + 0.03 / 0.1])       # 0.15 crossed at τ = 0.3
    reset = np.array([0, 1], np.uint8)
    anchored, _ = generate_steps(seg, rails=[rail], reset=reset)["x"]
    assert anchored == pytest.approx([0.05 / 0.12, 1.0 + 0.5])            # new grid: 0.12 + 0.05


def test_streaming_with_tiny_buffers_is_identical():
    pts = [(0, 0, 0, 0), (30, 5, 0.2, 1), (32, 40, 0.2, 2.5), (-5, 12, 0.4, 4), (0, 0, 0.4, 3)]
    seg = polyline_segments(pts, 150.0, 3000.0, junction_v=8.0)
    m = machine("corexy")
    whole = generate_steps(seg, m)
    parts = {}

    def sink(si, t, d):
        parts.setdefault(si, []).append((t.copy(), d.copy()))

    from gcodeplan.kinematics import rails_for
    gen = StepGenerator(rails_for(m), sink, chunk_steps=7)
    for lo in range(0, len(seg), 2):
        gen.feed(seg[lo:lo + 2])
    gen.finish()
    for si, name in enumerate(["a", "b", "z", "e"]):
        t = np.concatenate([p[0] for p in parts[si]])
        d = np.concatenate([p[1] for p in parts[si]])
        assert np.array_equal(t, whole[name][0]) and np.array_equal(d, whole[name][1])


@settings(max_examples=40, deadline=None)
@given(st.lists(st.tuples(st.floats(-50, 50), st.floats(-50, 50), st.floats(0, 2), st.floats(-3, 10)),
                min_size=2, max_size=8),
       st.floats(5, 200), st.floats(200, 5000), st.floats(0, 20))
def test_round_trip_position_within_half_a_step(points, max_v, accel, junction_v):
    """Counting the steps up to t reproduces the commanded position within ½ step at every sampled t."""
    pts = [(0.0, 0.0, 0.0, 0.0)] + [tuple(p) for p in points]
    seg = polyline_segments(pts, max_v, accel, junction_v=junction_v)
    if len(seg) == 0:
        return
    m = machine("corexy")
    steps = generate_steps(seg, m)
    t_end = seg["t0"][-1] + seg["dt"][-1]
    ts = np.linspace(0.0, t_end, 997)
    idx = np.clip(np.searchsorted(seg["t0"], ts, side="right") - 1, 0, len(seg) - 1)
    tau = ts - seg["t0"][idx]
    r = seg[idx]
    pos = {ax: r["p" + ax] + r["v" + ax] * tau + r["a" + ax] * tau ** 2 / 2 + r["j" + ax] * tau ** 3 / 6
           for ax in "xyze"}
    motor = {"a": pos["x"] + pos["y"], "b": pos["x"] - pos["y"], "z": pos["z"], "e": pos["e"]}
    spm = {"a": 80.0, "b": 80.0, "z": 400.0, "e": 95.52}
    for name, s in motor.items():
        t, d = steps[name]
        n_at = np.concatenate(([0], np.cumsum(d)))[np.searchsorted(t, ts, side="right")]
        assert np.max(np.abs(n_at - s * spm[name])) <= 0.5 + 1e-6, name


def test_sds_filter_drops_step_and_reversal():
    times = np.array([0.0, 0.0100, 0.0105, 0.0110, 0.0300, 0.0310])
    dirs = np.array([1, 1, -1, 1, 1, -1], np.int8)
    state = np.zeros(kernel.SDS_STATE_LEN)
    out_t = np.empty(7)
    out_d = np.empty(7, np.int8)
    m = kernel.sds_filter(times, dirs, 750e-6, state, out_t, out_d)
    tail_t, tail_d = kernel.sds_flush(state)
    got_t = list(out_t[:m]) + list(tail_t)
    got_d = list(out_d[:m]) + list(tail_d)
    # 0.0100(+) and 0.0105(−) cancel; 0.0110(+) stays; 0.0300/0.0310 are 1 ms apart: kept
    assert got_t == [0.0, 0.0110, 0.0300, 0.0310]
    assert got_d == [1, 1, 1, -1]


def test_step_stats():
    st_ = kernel.new_stats()
    kernel.step_stats(np.array([0.0, 0.001, 0.0015, 0.0016, 0.0030]), np.array([1, 1, 1, -1, -1], np.int8), st_)
    assert st_[0] == 5 and st_[1] == 1 and st_[7] == 1
    assert st_[4] == pytest.approx(0.0001)          # shortest interval (the reversal)
    assert st_[5] == pytest.approx(0.0005)          # shortest same-direction interval → 2000 steps/s
    assert st_[6] == pytest.approx(0.0015)


def test_velocity_roots_stable():
    roots = np.empty(2)
    # v = (τ − 1e-9)(τ − 1): tiny root kept to full precision
    n = kernel.velocity_roots(1e-9, -(1 + 1e-9), 2.0, 2.0, roots)
    assert n == 2
    assert roots[0] == pytest.approx(1e-9, rel=1e-12) and roots[1] == pytest.approx(1.0, rel=1e-12)
    assert kernel.velocity_roots(1.0, 0.0, 0.0, 5.0, roots) == 0
    assert kernel.velocity_roots(-2.0, 4.0, 0.0, 5.0, roots) == 1 and roots[0] == 0.5


def test_back_to_back_plans_keep_one_grid():
    a = line_segments((0, 0, 0, 0), (10.01, 0, 0, 0), 0.0, 50.0, 0.0, 1000.0)
    b = line_segments((10.01, 0, 0, 0), (0.02, 0, 0, 0), 0.0, 50.0, 0.0, 1000.0)
    t, d = generate_steps(concat_plans(a, b), rails=X_RAIL)["x"]
    # up 0 → 800.8 steps (801 steps), back to 1.6 (799 steps): one grid anchored at 0 throughout
    assert np.sum(d) == 2 and len(t) == 801 + 799
    assert np.count_nonzero(np.diff(d)) == 1


def test_non_finite_piece_is_reported_not_skipped():
    seg = np.concatenate([_piece(0.0, 1.0, 0.0, 1.0, 0.0), _piece(1.0, 1.0, 1.0, np.nan, 0.0)])
    with pytest.raises(RuntimeError, match="non-finite"):
        generate_steps(seg, rails=X_RAIL)


# ----------------------------------------------------------------- Klipper's own search (itersolve)

STEP = 0.01            # mm
H_BUMP = 0.006         # mm: a bump 1 mm·10⁻³ past the half-step point (0.005)


def _bump_pieces(tc: float, w: float, h: float = H_BUMP):
    """At rest at 0, then p(t) = h·(1 − ((t − tc)/w)²) on [tc − w, tc + w], then at rest again: power-basis pieces.
    Its excursion past the half-step point h/… lasts 2w·√(1 − STEP/2/h)."""
    t0 = np.array([-1.0, tc - w, tc + w])
    dt = np.array([tc - w + 1.0, 2.0 * w, 10.0])
    coef = np.zeros((3, kernel.POLY_NCOEF))
    coef[1, 1] = 2.0 * h / w          # h·(1 − (s/w − 1)²) = h·(2s/w − s²/w²)
    coef[1, 2] = -h / (w * w)
    return t0, dt, coef


def _at_half_step(t, tc, w, h=H_BUMP):
    """Klipper calls a step found once a guess is within 1 nm of the half-step point (or its bracket within
    1 ns): the bump's position at the step times, minus the half-step point (mm)."""
    return h * (1.0 - ((t - tc) / w) ** 2) - 0.5 * STEP


def _klipper_search(t0, dt, coef, flush, sds_t=0.0):
    """Klipper's steps of one active trapq move [0, 3] (tail sentinel after), windows ending at ``flush``."""
    m_start = np.array([0.0, 3.0])
    m_len = np.array([3.0, kernel.ITS_NEVER_S])
    m_act = np.array([True, False])
    state = kernel.new_itersolve_state()
    out_t = np.empty(10000)
    out_d = np.empty(10000, np.int8)
    done, n = kernel.itersolve_steps(np.asarray(flush, np.float64), m_start, m_len, m_act, 0.0, 0.0, t0, dt, coef,
                                     STEP, sds_t, state, out_t, out_d, 0)
    assert done == len(flush)
    t, d = kernel.itersolve_flush_pending(state)
    return np.concatenate([out_t[:n], t]), np.concatenate([out_d[:n], d])


def test_search_finds_the_exact_crossings_of_monotone_motion():
    """A ramp from rest (p = 50·s², 1 s): every half-step crossing, within 1 ns of √((k + ½)·0.01/50)."""
    t0 = np.array([-1.0, 0.0, 1.0])
    dt = np.array([1.0, 1.0, 10.0])
    coef = np.zeros((3, kernel.POLY_NCOEF))
    coef[1, 2] = 50.0
    coef[2, 0] = 50.0
    t, d = _klipper_search(t0, dt, coef, [10.0])
    want = np.sqrt((np.arange(5000) + 0.5) * STEP / 50.0)
    assert len(t) == 5000 and np.all(d == 1)
    assert np.max(np.abs(t - want)) < 1e-9


def test_search_misses_an_excursion_between_its_probes():
    """From the start of its range Klipper probes 100 µs, 200 µs, … 0.8192 s, 1.6384 s after it: a 41 ms
    excursion past the half-step point centred at 1.2 s lies between two probes, and neither of its two
    steps is taken. The exact solver takes both."""
    t0, dt, coef = _bump_pieces(1.2, 0.05)
    t, d = _klipper_search(t0, dt, coef, [10.0])
    assert len(t) == 0
    exact_t = np.empty(10)
    exact_d = np.empty(10, np.int8)
    c = coef
    _, n, _ = kernel.gen_steps(t0, dt, c[:, 0].copy(), c[:, 1].copy(), 2.0 * c[:, 2], 6.0 * c[:, 3],
                               np.zeros(3, np.uint8), STEP, kernel.new_state(), 0, exact_t, exact_d, 0)
    assert n == 2 and list(exact_d[:2]) == [1, -1]
    # the same excursion under a probe (1.6384 s) is seen: both steps, at the exact crossings
    t0, dt, coef = _bump_pieces(1.6384, 0.05)
    t, d = _klipper_search(t0, dt, coef, [10.0])
    half_w = 0.05 * math.sqrt(1.0 - 0.005 / H_BUMP)
    assert list(d) == [1, -1]
    assert np.allclose(t, [1.6384 - half_w, 1.6384 + half_w], rtol=0, atol=1e-7)
    assert np.all(np.abs(_at_half_step(t, 1.6384, 0.05)) <= 1e-9)


def test_a_window_boundary_restarts_the_probes():
    """A step-generation window ending at 1.19 s restarts the search there: its probes at 1.19 s + 100 µs·2^k
    hit the excursion (1.2028 s) that one long window misses."""
    t0, dt, coef = _bump_pieces(1.2, 0.05)
    t, d = _klipper_search(t0, dt, coef, [1.19, 10.0])
    half_w = 0.05 * math.sqrt(1.0 - 0.005 / H_BUMP)
    assert list(d) == [1, -1]
    assert np.allclose(t, [1.2 - half_w, 1.2 + half_w], rtol=0, atol=1e-7)
    assert np.all(np.abs(_at_half_step(t, 1.2, 0.05)) <= 1e-9)


def test_step_dir_step_inside_750us_is_taken_back():
    """A 0.4 ms excursion seen by the probes: two steps 0.4 ms apart, which Klipper's stepcompress deletes
    together (an opposite step within 750 µs of a held one); without the filter both stay."""
    w = 0.0002 / math.sqrt(1.0 - 0.005 / H_BUMP)          # excursion lasts 2·0.0002 s
    t0, dt, coef = _bump_pieces(1.2, w)
    flush = [1.2 - 0.0001, 10.0]                          # probes restart 100 µs before the peak: inside it
    t, d = _klipper_search(t0, dt, coef, flush, sds_t=0.0)
    assert list(d) == [1, -1] and t[1] - t[0] == pytest.approx(0.0004, abs=1e-9)
    t, d = _klipper_search(t0, dt, coef, flush, sds_t=KLIPPER_SDS_FILTER_T)
    assert len(t) == 0


def test_search_state_survives_a_full_buffer():
    """Windows are emitted whole: with room for 3 steps per call the ramp still comes out complete and in order."""
    t0 = np.array([-1.0, 0.0, 1.0])
    dt = np.array([1.0, 1.0, 10.0])
    coef = np.zeros((3, kernel.POLY_NCOEF))
    coef[1, 2] = 0.5                                   # 50 steps in 1 s
    coef[2, 0] = 0.5
    flush = np.arange(0.05, 3.0, 0.05)
    m_start, m_len, m_act = np.array([0.0, 3.0]), np.array([3.0, kernel.ITS_NEVER_S]), np.array([True, False])
    state = kernel.new_itersolve_state()
    got = []
    k = 0
    while k < len(flush):
        out_t, out_d = np.empty(8), np.empty(8, np.int8)
        done, n = kernel.itersolve_steps(flush[k:], m_start, m_len, m_act, 0.0, 0.0, t0, dt, coef, STEP, 0.0,
                                         state, out_t, out_d, 0)
        got.append(out_t[:n].copy())
        k += done
        assert done > 0
    t = np.concatenate(got)
    assert len(t) == 50 and np.all(np.diff(t) > 0)
    assert np.allclose(t, np.sqrt((np.arange(50) + 0.5) * STEP / 0.5), rtol=0, atol=1e-9)
