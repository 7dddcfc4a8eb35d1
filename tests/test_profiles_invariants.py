"""Physical invariants of every solved profile, on thousands of random cases (hypothesis)."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gcodeplan import profiles
from gcodeplan.profiles import InfeasibleProfile

SETTINGS = settings(max_examples=1500, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def log_uniform(lo, hi):
    return st.floats(math.log10(lo), math.log10(hi)).map(lambda e: 10.0 ** e)


fraction = st.one_of(st.just(0.0), st.just(1.0), st.floats(0.0, 1.0))


def check_invariants(p, h, v0, v1, V, A, J=None):
    """Simpson's rule is exact for the cubic pieces when no interval straddles a piece boundary, so
    'position integrates velocity' and 'velocity integrates acceleration' can be checked to rounding."""
    T = p.duration
    pcs = p.pieces
    bounds = np.concatenate((pcs["t0"], [T]))
    t = np.unique(np.concatenate((np.linspace(0.0, T, 400), bounds)))
    mid = 0.5 * (t[1:] + t[:-1])
    q, v, a, j = p.sample(t)
    _, vm, am, jm = p.sample(mid)
    dt = np.diff(t)
    scale_q = max(h, 1e-300)
    # Sampling at absolute times: piece start times carry about an ulp of T, which moves a sample by
    # (that time error) x (its derivative): the floor of every tolerance below.
    ulp_t = 4 * np.finfo(float).eps * T
    tol_v = 1e-9 * V + ulp_t * A
    tol_a = 1e-9 * A + ulp_t * (J or 0.0)
    # position integrates velocity, velocity integrates acceleration (Simpson per interval)
    np.testing.assert_allclose(np.diff(q), dt / 6 * (v[:-1] + 4 * vm + v[1:]), rtol=0,
                               atol=1e-10 * scale_q + ulp_t * V)
    np.testing.assert_allclose(np.diff(v), dt * am, rtol=0, atol=tol_v)
    # ends exactly at the distance with the requested speeds
    assert q[0] == 0.0
    assert q[-1] == pytest.approx(h, rel=1e-12, abs=1e-12 * V * T)
    assert v[0] == pytest.approx(v0, abs=1e-12 * V)
    assert v[-1] == pytest.approx(v1, rel=1e-10, abs=tol_v)
    # limits never exceeded beyond 1e-9 relative; forward only
    assert v.min() >= -1e-9 * V and vm.min() >= -1e-9 * V
    assert max(v.max(), vm.max()) <= V * (1 + 1e-9)
    assert max(np.abs(a).max(), np.abs(am).max()) <= A * (1 + 1e-9) + tol_a
    if J is not None:
        assert np.abs(jm).max() <= J * (1 + 1e-12)
        assert a[0] == 0.0 and abs(a[-1]) <= tol_a
        # acceleration continuous: piece k ends where piece k+1 starts
        a_end = pcs["a0"] + pcs["j"] * pcs["dt"]
        np.testing.assert_allclose(a_end[:-1], pcs["a0"][1:], rtol=0, atol=1e-9 * A)
    # position and velocity continuous across pieces
    d = pcs["dt"]
    q_end = pcs["p0"] + pcs["v0"] * d + pcs["a0"] * d * d / 2 + pcs["j"] * d ** 3 / 6
    v_end = pcs["v0"] + pcs["a0"] * d + pcs["j"] * d * d / 2
    np.testing.assert_allclose(q_end[:-1], pcs["p0"][1:], rtol=0, atol=1e-12 * scale_q + 1e-300)
    np.testing.assert_allclose(v_end[:-1], pcs["v0"][1:], rtol=0, atol=1e-10 * V)
    # phases add up to the duration
    assert sum(x for x, _ in p.phases) == pytest.approx(T, rel=1e-12, abs=1e-300)


@SETTINGS
@given(h=log_uniform(1e-4, 1e4), V=log_uniform(1.0, 2e3), A=log_uniform(10.0, 1e5), J=log_uniform(1e2, 1e8),
       f0=fraction, f1=fraction)
def test_scurve_invariants(h, V, A, J, f0, f1):
    v0, v1 = f0 * V, f1 * V
    try:
        p = profiles.scurve(h, V, A, J, v0, v1)
    except InfeasibleProfile:
        # independent check of infeasibility: the one monotone ramp between the speeds is already too long
        dv = abs(v1 - v0)
        t_ramp = dv / A + A / J if dv >= A * A / J else 2 * math.sqrt(dv / J)
        assert (v0 + v1) / 2 * t_ramp > h
        return
    check_invariants(p, h, v0, v1, V, A, J)


@SETTINGS
@given(h=log_uniform(1e-4, 1e4), V=log_uniform(1.0, 2e3), A=log_uniform(10.0, 1e5), D=log_uniform(10.0, 1e5),
       f0=fraction, f1=fraction)
def test_trapezoid_invariants(h, V, A, D, f0, f1):
    v0, v1 = f0 * V, f1 * V
    try:
        p = profiles.trapezoid(h, V, A, v0, v1, decel=D)
    except InfeasibleProfile:
        assert v1 * v1 - v0 * v0 > 2 * A * h or v0 * v0 - v1 * v1 > 2 * D * h
        return
    check_invariants(p, h, v0, v1, V, max(A, D))
    assert (p.pieces["j"] == 0.0).all()
