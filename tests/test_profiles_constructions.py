"""The course notes' worked examples (slips corrected), via points, braking figures, multi-axis moves."""
from __future__ import annotations

import math

import numpy as np
import pytest

from gcodeplan import profiles


# --------------------------------------------------------------------------- timed S-curve
def test_notes_example_position_at_100ms_is_2720_counts_not_2733():
    # s-curve-and-multi-axis.es, ejemplo 1: v_m = 32 counts/ms, t_a = 30 ms. The ramp covers v_m·t_a/2 = 480
    # counts; then 70 ms of cruise at 32 counts/ms: 480 + 2240 = 2720 (the notes print 2733.49 by rounding 64/900
    # to 0.071 and 0.023 in the integrals).
    p = profiles.timed_scurve(32.0, 30.0, total_t=200.0)
    q, v, a, _ = p.sample(np.array([15.0, 30.0, 100.0]))
    assert q[1] == pytest.approx(480.0, rel=1e-14)
    assert q[2] == pytest.approx(2720.0, rel=1e-14)
    # v_A(t) = 2·v_m·t²/t_a² reaches v_m/2 at t_a/2; peak accel 2·v_m/t_a there
    assert v[0] == pytest.approx(16.0, rel=1e-14) and a[0] == pytest.approx(2 * 32 / 30, rel=1e-14)
    t = np.linspace(0, 30, 61)
    _, v, _, j = p.sample(t)
    v_notes = np.where(t < 15, 2 * 32 * t ** 2 / 900, 32 - 2 * 32 * (30 - t) ** 2 / 900)
    np.testing.assert_allclose(v, v_notes, rtol=1e-13, atol=1e-12)
    assert np.abs(j).max() == pytest.approx(4 * 32 / 900, rel=1e-14)
    assert p.info == pytest.approx({"jerk": 4 * 32 / 900, "peak_accel": 64 / 30, "ramp_distance": 480.0})


def test_timed_scurve_rest_to_rest_distance_and_bad_timing():
    p = profiles.timed_scurve(10.0, 4.0, total_t=8.0)            # ejemplo 2 numbers, ramps both ways
    assert p.duration == 8.0 and p.distance == pytest.approx(40.0)
    q, v, _, _ = p.sample(np.array([8.0]))
    assert q[0] == pytest.approx(40.0, rel=1e-14) and v[0] == pytest.approx(0.0, abs=1e-12)
    with pytest.raises(ValueError, match="total_t"):
        profiles.timed_scurve(10.0, 4.0, total_t=7.0)
    with pytest.raises(ValueError, match="t_a"):
        profiles.timed_scurve(10.0, -4.0)


def test_equivalent_scurve_keeps_time_and_distance_and_doubles_peak_accel():
    trap = profiles.trapezoid(100.0, 50.0, 1000.0, v_start=10.0, v_end=5.0, decel=500.0)
    s = profiles.equivalent_scurve(trap)
    assert s.duration == pytest.approx(trap.duration, rel=1e-15)
    t = np.linspace(0, s.duration, 20001)
    q, v, a, _ = s.sample(t)
    assert q[-1] == pytest.approx(100.0, rel=1e-13) and v[-1] == pytest.approx(5.0, rel=1e-12)
    ta, td = trap.phases[0][0], trap.phases[-1][0]
    peaks = s.sample(np.array([ta / 2, s.duration - td / 2]))[2]
    np.testing.assert_allclose(peaks, [2000.0, -1000.0], rtol=1e-12)
    assert a.max() <= 2000.0 * (1 + 1e-12) and a.min() >= -1000.0 * (1 + 1e-12)
    # the S-curve meets the trapezoid in the middle of each ramp ("the crossing point is at mid-interval")
    np.testing.assert_allclose(s.sample(np.array([ta / 2]))[1], trap.sample(np.array([ta / 2]))[1], rtol=1e-13)
    # modified S: a constant-acceleration middle keeps the same time and distance with a lower peak
    m = profiles.equivalent_scurve(trap, jerk_fraction=0.5)
    assert m.duration == pytest.approx(trap.duration, rel=1e-15)
    assert m.sample(np.array([m.duration]))[0][0] == pytest.approx(100.0, rel=1e-13)
    assert 1000.0 < m.pieces["a0"].max() + 1e-9 and np.abs(m.sample(t)[2]).max() < 2000.0
    with pytest.raises(ValueError, match="jerk_fraction"):
        profiles.equivalent_scurve(trap, jerk_fraction=0.0)


# --------------------------------------------------------------------------- via points
def test_via_points_hand_worked_two_segments():
    # DESIGN.md: a = (T1(q2-q1) - T2(q1-q0))/(2·T1·T2·tau), e = a·tau²/2.
    # q = 0, 10, 30; T1 = T2 = 2; tau = 0.5: a = (2·20 - 2·10)/(2·2·2·0.5) = 5, e = 5·0.25/2 = 0.625
    p = profiles.via_points([0.0, 10.0, 30.0], [2.0, 2.0], blend_time=1.0)
    assert p.blend_accel[1] == pytest.approx(5.0) and p.deviation[0] == pytest.approx(0.625)
    q, v, _, _ = p.sample(p.via_times)
    assert abs(q[0] - 10.0) == pytest.approx(p.deviation[0], rel=1e-13)
    # starts and ends at rest exactly at the end points; linear between blends
    q, v, _, _ = p.sample(np.array([0.0, p.duration, p.point_times[0] + 1.0]))
    assert (q[0], v[0]) == (0.0, 0.0) and q[1] == pytest.approx(30.0) and v[1] == pytest.approx(0.0, abs=1e-12)
    assert v[2] == pytest.approx(5.0)


def test_via_points_deviation_by_sampling_equals_reported():
    rng = np.random.default_rng(4)
    for _ in range(50):
        q = np.cumsum(rng.uniform(-20, 20, 6))
        T = rng.uniform(1.0, 3.0, 5)
        p = profiles.via_points(q, T, accel=200.0)
        sampled = np.abs(p.sample(p.via_times)[0] - q[1:-1])
        np.testing.assert_allclose(sampled, p.deviation, rtol=1e-9, atol=1e-12)
        # with an acceleration bound every blend uses exactly that accel (or none)
        assert np.all((np.abs(p.blend_accel) == pytest.approx(200.0)) | (p.blend_accel == 0.0))
        # e = |dv|·tau/4 (DESIGN.md), and |a| never exceeds the bound when sampled
        v = np.concatenate(([0.0], np.diff(q) / T, [0.0]))
        np.testing.assert_allclose(p.deviation, np.abs(np.diff(v))[1:-1] * p.tau[1:-1] / 4, rtol=1e-12)
        assert np.abs(p.sample(np.linspace(0, p.duration, 5001))[2]).max() <= 200.0 * (1 + 1e-12)


def test_via_points_rejects_overlapping_blends_and_bad_input():
    with pytest.raises(ValueError, match="overlap"):
        profiles.via_points([0.0, 10.0, 0.0], [1.0, 1.0], blend_time=1.5)
    with pytest.raises(ValueError, match="segment_times"):
        profiles.via_points([0.0, 10.0, 0.0], [1.0])
    with pytest.raises(ValueError, match="exactly one"):
        profiles.via_points([0.0, 10.0], [1.0])
    with pytest.raises(ValueError, match="accel"):
        profiles.via_points([0.0, 10.0], [1.0], accel=-3.0)


# --------------------------------------------------------------------------- braking
def test_braking_figures():
    assert profiles.stopping_distance(100.0, 2000.0) == pytest.approx(2.5)
    assert profiles.stopping_time(100.0, 2000.0) == pytest.approx(0.05)
    np.testing.assert_allclose(profiles.stopping_distance(np.array([0.0, 10.0]), 50.0), [0.0, 1.0])
    assert profiles.safe_spacing(30.0, 5.0) == pytest.approx(90.0)
    with pytest.raises(ValueError, match="decel"):
        profiles.stopping_distance(10.0, 0.0)


def test_braking_point_of_a_trapezoid_is_the_notes_x_if():
    # X_if = h - (vp² - v1²)/(2·A_d)
    p = profiles.trapezoid(100.0, 50.0, 1000.0, v_start=10.0, v_end=20.0, decel=500.0)
    bp = profiles.braking_point(p)
    assert bp.position == pytest.approx(100.0 - (50 ** 2 - 20 ** 2) / 1000.0, rel=1e-14)
    assert bp.speed == pytest.approx(50.0) and bp.time == pytest.approx(0.04 + 1.934)
    # triangle with equal accel from rest: brake at mid-distance (the notes' X_if = X/2)
    assert profiles.braking_point(profiles.trapezoid(8.0, 1e3, 100.0)).position == pytest.approx(4.0)
    # S-curve: the start of phase 5
    s = profiles.scurve(10.0, 100.0, 3000.0, 1e5)
    assert profiles.braking_point(s).time == pytest.approx(0.1, rel=1e-13)


def test_feed_hold_stop_position_and_line_throughput_optimum():
    p = profiles.trapezoid(100.0, 50.0, 1000.0)
    t = 1.0
    q, v, _, _ = p.sample(np.array([t]))
    assert profiles.stop_position(p, t, 1000.0) == pytest.approx(q[0] + v[0] ** 2 / 2000.0)
    # bodies 4 m long, decel 2 m/s²: v* = sqrt(2·2·4) = 4 m/s moves the most bodies per second,
    # 4/(4 + 4) = 0.5 per second; faster and slower both move fewer
    L, d = 4.0, 2.0
    v_star = profiles.optimal_line_speed(L, d)
    assert v_star == pytest.approx(4.0)
    assert profiles.line_throughput(v_star, L, d) == pytest.approx(0.5)
    vs = np.linspace(0.01, 20.0, 2000)
    assert profiles.line_throughput(vs, L, d).max() <= 0.5 + 1e-15
    assert profiles.line_throughput(8.0, L, d) < 0.5 and profiles.line_throughput(2.0, L, d) < 0.5
    assert profiles.optimal_line_speed(L, d, v_max=3.0) == 3.0


# --------------------------------------------------------------------------- multi-axis
def test_notes_multi_axis_example():
    # Lx = 16, Ly = 12, v = 4, t_a = 0.2 (a = v/t_a = 20): slew 4.2 s and 3.2 s; interpolated v_y = 3, both 4.2 s
    slew = profiles.synchronize([16.0, 12.0], 4.0, 20.0, mode="slew")
    assert [p.duration for p in slew] == [pytest.approx(4.2), pytest.approx(3.2)]
    inter = profiles.synchronize([16.0, 12.0], 4.0, 20.0, mode="interpolated")
    assert [p.duration for p in inter] == [pytest.approx(4.2), pytest.approx(4.2)]
    assert inter[1].peak_velocity == pytest.approx(3.0) and inter[0].peak_velocity == pytest.approx(4.0)
    assert inter[1].phases[0][0] == pytest.approx(0.2)        # same t_a on both axes
    # the path stays on the straight line at every time
    q, _, _, _ = inter.sample(np.linspace(0, 4.2, 101))
    np.testing.assert_allclose(q[1], q[0] * 12 / 16, atol=1e-12)
    seq = profiles.synchronize([16.0, -12.0], 4.0, 20.0, mode="sequential")
    np.testing.assert_allclose(seq.start_times, [0.0, 4.2])
    assert seq.duration == pytest.approx(7.4)
    q, _, _, _ = seq.sample(np.array([4.2, 7.4]))
    np.testing.assert_allclose(q, [[16.0, 16.0], [0.0, -12.0]], atol=1e-12)


def test_interpolated_respects_every_axis_limit_with_s_curves():
    rng = np.random.default_rng(8)
    for _ in range(20):
        d = rng.uniform(-50, 50, 3)
        vm, am, jm = rng.uniform(50, 300, 3), rng.uniform(500, 5000, 3), rng.uniform(1e4, 1e6, 3)
        axes = profiles.synchronize(d, vm, am, j_max=jm)
        t = np.linspace(0, axes.duration, 4001)
        q, v, a, j = axes.sample(t)
        np.testing.assert_allclose(q[:, -1], d, rtol=1e-12, atol=1e-12)
        assert (np.abs(v).max(axis=1) <= vm * (1 + 1e-9)).all()
        assert (np.abs(a).max(axis=1) <= am * (1 + 1e-9)).all()
        assert (np.abs(j).max(axis=1) <= jm * (1 + 1e-9)).all()
        # and some axis is at one of its limits (otherwise the move could be faster)
        ratios = np.concatenate((np.abs(v).max(axis=1) / vm, np.abs(a).max(axis=1) / am, np.abs(j).max(axis=1) / jm))
        assert ratios.max() == pytest.approx(1.0, rel=1e-6)
    with pytest.raises(ValueError, match="mode"):
        profiles.synchronize([1.0], 1.0, 1.0, mode="diagonal")
    with pytest.raises(ValueError, match=r"a_max\[1\]"):
        profiles.synchronize([1.0, 2.0], 1.0, [1.0, -1.0])
    assert math.isclose(profiles.synchronize([0.0, 0.0], 1.0, 1.0).duration, 0.0)
