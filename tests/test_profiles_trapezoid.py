"""Trapezoids against the notes' closed forms, a brute-force optimum and hand-worked examples."""
from __future__ import annotations

import math

import numpy as np
import pytest

from gcodeplan import profiles
from gcodeplan.profiles import InfeasibleProfile


def test_rest_to_rest_trapezoid_matches_notes_closed_form():
    # trapezoidal-velocity-profile.it: t_c = V/A, t_f = h/V + V/A when h >= V²/A
    p = profiles.trapezoid(16.0, 4.0, 20.0)
    assert p.duration == pytest.approx(16 / 4 + 4 / 20, rel=1e-15)
    assert p.phases == [(pytest.approx(0.2), 20.0), (pytest.approx(3.8), 0.0), (pytest.approx(0.2), -20.0)]
    assert p.peak_velocity == 4.0
    # the notes' position law: q = A t²/2 (t <= tau); q0 - V²/(2A) + V t (cruise); q1 - A (T - t)²/2 (end)
    t = np.array([0.1, 0.2, 1.0, 4.0, 4.1, 4.2])
    q, v, a, j = p.sample(t)
    T, V, A, tau = 4.2, 4.0, 20.0, 0.2
    expected = np.where(t <= tau, A * t * t / 2, np.where(t <= T - tau, -V * V / (2 * A) + V * t,
                                                          16 - A * (T - t) ** 2 / 2))
    np.testing.assert_allclose(q, expected, rtol=1e-14, atol=1e-14)
    np.testing.assert_array_equal(j, 0.0)


def test_triangular_when_v_max_not_reached():
    # h < V²/A: t_c = sqrt(h/A), t_f = 2 t_c, peak A t_c = sqrt(A h)
    p = profiles.trapezoid(1.0, 100.0, 400.0)
    assert p.duration == pytest.approx(2 * math.sqrt(1 / 400), rel=1e-15)
    assert p.peak_velocity == pytest.approx(math.sqrt(400.0), rel=1e-15)
    assert len(p.phases) == 2            # zero-length cruise merged away


def test_asymmetric_accel_with_end_speeds_hand_worked():
    # v0 = 10, v1 = 20, A_a = 1000, A_d = 500, h = 100, V = 50:
    # vp² = (2·1000·500·100 + 500·100 + 1000·400)/1500 > 2500 -> vp = 50
    # accel (50-10)/1000 = 0.04 s, 1.2 mm; decel (50-20)/500 = 0.06 s, 2.1 mm; cruise 96.7/50 = 1.934 s
    p = profiles.trapezoid(100.0, 50.0, 1000.0, v_start=10.0, v_end=20.0, decel=500.0)
    assert p.duration == pytest.approx(0.04 + 1.934 + 0.06, rel=1e-14)
    q, v, _, _ = p.sample(np.array([0.0, 0.04, 0.04 + 1.934, p.duration]))
    np.testing.assert_allclose(q, [0.0, 1.2, 100 - 2.1, 100.0], rtol=1e-13)
    np.testing.assert_allclose(v, [10.0, 50.0, 50.0, 20.0], rtol=1e-14)


def closed_form_duration(h, V, Aa, Ad, v0, v1):
    """DESIGN.md's form, written independently: peak from (2·Aa·Ad·h + Ad·v0² + Aa·v1²)/(Aa + Ad)."""
    vp = min(V, math.sqrt((2 * Aa * Ad * h + Ad * v0 * v0 + Aa * v1 * v1) / (Aa + Ad)))
    xa = (vp * vp - v0 * v0) / (2 * Aa)
    xd = (vp * vp - v1 * v1) / (2 * Ad)
    return (vp - v0) / Aa + (vp - v1) / Ad + (h - xa - xd) / vp


def test_closed_form_on_random_cases_within_1e12():
    rng = np.random.default_rng(7)
    checked = 0
    for _ in range(3000):
        h = 10 ** rng.uniform(-3, 3)
        V = 10 ** rng.uniform(0, 3)
        Aa, Ad = 10 ** rng.uniform(1, 5, 2)
        v0, v1 = V * rng.uniform(0, 1, 2) * (rng.uniform(size=2) < 0.7)
        feasible = (v1 * v1 - v0 * v0) <= 2 * Aa * h and (v0 * v0 - v1 * v1) <= 2 * Ad * h
        if not feasible:
            with pytest.raises(InfeasibleProfile):
                profiles.trapezoid(h, V, Aa, v0, v1, decel=Ad)
            continue
        p = profiles.trapezoid(h, V, Aa, v0, v1, decel=Ad)
        assert p.duration == pytest.approx(closed_form_duration(h, V, Aa, Ad, v0, v1), rel=1e-12, abs=0)
        checked += 1
    assert checked > 1500


def test_time_optimal_against_brute_force_peak_search():
    # every feasible trapezoid is fixed by its peak vp in [max(v0, v1), V]: scan vp, no profile is faster
    rng = np.random.default_rng(3)
    checked = 0
    for _ in range(200):
        h, V = 10 ** rng.uniform(-1, 2), 10 ** rng.uniform(0.5, 2.5)
        Aa, Ad = 10 ** rng.uniform(2, 4, 2)
        v0, v1 = rng.uniform(0, 0.3 * V, 2)
        if (v1 * v1 - v0 * v0) > 2 * Aa * h or (v0 * v0 - v1 * v1) > 2 * Ad * h:
            # no trapezoid joins these end speeds in h: refused, never faked
            with pytest.raises(InfeasibleProfile):
                profiles.trapezoid(h, V, Aa, v0, v1, decel=Ad)
            continue
        p = profiles.trapezoid(h, V, Aa, v0, v1, decel=Ad)
        checked += 1
        vp = np.linspace(max(v0, v1), V, 20001)
        xa = (vp ** 2 - v0 ** 2) / (2 * Aa)
        xd = (vp ** 2 - v1 ** 2) / (2 * Ad)
        ok = xa + xd <= h
        t = (vp - v0) / Aa + (vp - v1) / Ad + (h - xa - xd) / vp
        assert p.duration <= t[ok].min() * (1 + 1e-12)
    assert checked >= 150, checked      # 186 of the 200 seeded cases are feasible: the search ran on them


def test_end_speed_unreachable_is_infeasible_not_faked():
    with pytest.raises(InfeasibleProfile, match="needs at least 25"):
        profiles.trapezoid(1.0, 100.0, 50.0, v_start=50.0, v_end=0.0)   # 50²/(2·50) = 25 mm to stop
    with pytest.raises(InfeasibleProfile):
        profiles.trapezoid(1.0, 100.0, 50.0, v_start=0.0, v_end=50.0)


def test_edge_cases():
    p = profiles.trapezoid(10.0, 5.0, 100.0, v_start=5.0, v_end=5.0)     # pure cruise
    assert p.duration == pytest.approx(2.0, rel=1e-15) and p.phases == [(pytest.approx(2.0), 0.0)]
    p = profiles.trapezoid(0.0, 5.0, 100.0)
    assert p.duration == 0.0
    # exactly the stopping distance: one deceleration ramp
    p = profiles.trapezoid(0.125, 10.0, 400.0, v_start=10.0, v_end=0.0)
    assert p.duration == pytest.approx(10 / 400, rel=1e-14) and len(p.phases) == 1
    p = profiles.trapezoid(1e3, math.inf, 100.0)     # no velocity limit: triangle
    assert p.duration == pytest.approx(2 * math.sqrt(10.0), rel=1e-15)


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"a_max": -1.0}, "a_max"), ({"a_max": 0.0}, "a_max"), ({"v_max": math.nan}, "v_max"),
        ({"v_start": 200.0}, "v_start"), ({"v_end": -1.0}, "v_end"), ({"distance": math.nan}, "distance"),
        ({"distance": -1.0}, "distance"), ({"decel": 0.0}, "decel"), ({"a_max": "fast"}, "a_max"),
    ],
)
def test_bad_arguments_name_the_argument(kwargs, name):
    args = {"distance": 10.0, "v_max": 100.0, "a_max": 1000.0} | kwargs
    with pytest.raises(ValueError, match=name):
        profiles.trapezoid(**args)


def test_batch_durations_match_scalar_api_and_mark_infeasible_nan():
    rng = np.random.default_rng(11)
    n = 500
    h = 10 ** rng.uniform(-2, 2, n)
    V = rng.uniform(10, 300, n)
    A = 10 ** rng.uniform(2, 4, n)
    v0 = V * rng.uniform(0, 1, n)
    v1 = V * rng.uniform(0, 1, n)
    out = profiles.trapezoid_durations(h, V, A, v0, v1)
    assert out.shape == (n,)
    for i in range(n):
        try:
            want = profiles.trapezoid(h[i], V[i], A[i], v0[i], v1[i]).duration
        except InfeasibleProfile:
            assert math.isnan(out[i])
            continue
        assert out[i] == want
    assert np.isnan(out).any() and not np.isnan(out).all()
    # broadcasting of scalars, and the decel argument
    out2 = profiles.trapezoid_durations(h[:3], 100.0, 1000.0, 0.0, 0.0, decel=500.0)
    assert out2[1] == profiles.trapezoid(h[1], 100.0, 1000.0, decel=500.0).duration
    with pytest.raises(ValueError, match="a_max"):
        profiles.trapezoid_durations(h, V, -A, v0, v1)
    with pytest.raises(ValueError, match="v_start"):
        profiles.trapezoid_durations(h, V, A, v0 + 1000.0, v1)
