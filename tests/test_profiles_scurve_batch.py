"""The S-curve solver's fast paths: closed forms and Newton start points against forward formulas, the batch
(lockstep Newton, fused argument checks) against the scalar kernel bit for bit."""
from __future__ import annotations

import importlib
import math

import numpy as np
import pytest

from gcodeplan import profiles
# the module, not profiles.scurve (the function of the same name)
sc = importlib.import_module("gcodeplan.profiles.scurve")


def ramp_t(dv, A, J):
    """Fastest change of speed by dv with a = 0 at both ends (the seed's 'perfil S modificado')."""
    dv = np.asarray(dv, dtype=float)
    return np.where(dv * J >= A * A, dv / A + A / J, 2.0 * np.sqrt(np.maximum(dv, 0.0) / J))


def ramp_d(va, vb, A, J):
    """Its distance: the speed is point-symmetric about the ramp's midpoint, so the mean is (va + vb)/2."""
    return 0.5 * (va + vb) * ramp_t(np.abs(vb - va), A, J)


def no_cruise_cases(rng, n, regime):
    """Random (h, V, A, J, v0, v1, vp) with h = R(v0 -> vp) + R(vp -> v1) built forward from a chosen peak vp
    in one regime of the solver: 'pure' (both parts pure S), 'vl_reaches_a' (only the part from/to the lower
    end speed reaches A), 'both_reach_a', 'equal_ends' (v0 = v1, pure S). V is far above vp: no cruise."""
    A = 10 ** rng.uniform(2, 5, n)
    J = 10 ** rng.uniform(3, 8, n)
    c = A * A / J                       # speed change at which A is reached
    vh = c * 10 ** rng.uniform(-3, 2, n) * (rng.uniform(size=n) < 0.9)
    if regime == "equal_ends":
        vl = vh.copy()
        x = c * rng.uniform(0.01, 0.99, n)
    elif regime == "pure":
        vl = np.maximum(vh - c * rng.uniform(0.0, 0.98, n), 0.0)
        dv = vh - vl
        x = (c - dv) * rng.uniform(0.01, 0.99, n)
    elif regime == "vl_reaches_a":
        vl = np.maximum(vh - c * 10 ** rng.uniform(-1.5, 1.5, n), 0.0)
        dv = vh - vl
        x_lo = np.maximum(c - dv, 0.0)
        x = x_lo + (c - x_lo) * rng.uniform(0.01, 0.99, n)
    else:
        vl = np.maximum(vh - c * 10 ** rng.uniform(-2, 2, n), 0.0)
        x = c * 10 ** rng.uniform(0.01, 2, n)
    # keep vp - vh well above rounding of vh: durations depend on sqrt(vp - vh)
    x = np.maximum(x, 1e-6 * (vh + c))
    vp = vh + x
    swap = rng.uniform(size=n) < 0.5
    v0 = np.where(swap, vh, vl)
    v1 = np.where(swap, vl, vh)
    h = ramp_d(v0, vp, A, J) + ramp_d(vp, v1, A, J)
    V = vp * 10 ** rng.uniform(0.5, 1, n)
    return h, V, A, J, v0, v1, vp


@pytest.mark.parametrize("regime", ["pure", "vl_reaches_a", "both_reach_a", "equal_ends"])
def test_no_cruise_peak_is_the_peak_the_distance_was_built_from(regime):
    rng = np.random.default_rng(["pure", "vl_reaches_a", "both_reach_a", "equal_ends"].index(regime))
    h, V, A, J, v0, v1, vp = no_cruise_cases(rng, 3000, regime)
    want_t = ramp_t(vp - v0, A, J) + ramp_t(vp - v1, A, J)
    got_t = profiles.scurve_durations(h, V, A, J, v0, v1)
    np.testing.assert_allclose(got_t, want_t, rtol=1e-11)
    peaks = np.array([sc.scurve_phases_kernel(*args)[2] for args in zip(h[:500], V, A, J, v0, v1)])
    np.testing.assert_allclose(peaks, vp[:500], rtol=1e-13)


def newton_setups(n, seed):
    """Random moves that reach the Newton iteration, with what _newton_setup returns for them."""
    rng = np.random.default_rng(seed)
    rows = []
    while len(rows) < n:
        h, V, A, J, v0, v1, _ = no_cruise_cases(rng, 200, ["pure", "vl_reaches_a"][len(rows) % 2])
        for args in zip(h, V, A, J, v0, v1):
            head = sc._solve_head(*args)
            if head[2] != sc._DONE:
                rows.append((args, head[2:]))
    return rows


def test_newton_starts_right_of_the_root_and_converges_in_a_few_steps():
    # the start point inverts a lower bound of D(s) - D(0), so D(start) >= h (the docstring's claim that
    # makes Newton monotone); measured with the forward formulas, not the solver's
    setups = newton_setups(1000, 3)
    kinds = set()
    for (h, V, A, J, v0, v1), (what, s, p1, p2, p3, p4, p5) in setups:
        kinds.add(what)
        vh = max(v0, v1)
        d_start = float(ramp_d(v0, vh + s * s, A, J) + ramp_d(vh + s * s, v1, A, J))
        assert d_start >= h * (1 - 1e-12), (h, V, A, J, v0, v1)
        step = sc._quartic_step if what == sc._NEWTON_QUARTIC else sc._pure_s_step
        s0 = s
        for k in range(1, 100):
            s_next, more = step(s, p1, p2, p3, p4, p5)
            assert s_next <= s            # monotone from the right
            s = s_next
            if not more:
                break
        assert k <= 7, (h, V, A, J, v0, v1)
        assert s == sc._newton_solve(what, s0, p1, p2, p3, p4, p5)
    assert kinds == {sc._NEWTON_QUARTIC, sc._NEWTON_PURE_S}


def broad_cases(n, seed):
    """Every branch: cruise, end speed at V, closed forms, both Newton formulas, infeasible, and end speeds at the
    edge of feasibility (from the max-end-speed kernel, which the feasibility slack must accept)."""
    rng = np.random.default_rng(seed)
    V = 10 ** rng.uniform(0, 3, n)
    A = 10 ** rng.uniform(1, 5, n)
    J = 10 ** rng.uniform(2, 8, n)
    h = 10 ** rng.uniform(-5, 4, n)
    pick = lambda: V * np.choose(rng.integers(0, 4, n), [np.zeros(n), rng.uniform(size=n), np.ones(n),
                                                         rng.uniform(0.95, 1.0, n)])
    v0, v1 = pick(), pick()
    same = rng.uniform(size=n) < 0.1
    v1[same] = v0[same]
    edge = rng.uniform(size=n) < 0.1
    for i in np.nonzero(edge)[0]:
        v1[i] = sc.scurve_max_end_speed_kernel(h[i], V[i], A[i], J[i], v0[i])
    return h, V, A, J, v0, v1


def test_batch_is_the_scalar_kernel_bit_for_bit():
    # the batch sets Newton cases aside per block and iterates them in lockstep: same arithmetic, same bits
    args = broad_cases(20_000, 11)          # many blocks of sc._BATCH_BLOCK
    got = profiles.scurve_durations(*args)
    want = np.array([sc.scurve_duration_kernel(*row) for row in zip(*args)])
    np.testing.assert_array_equal(got, want)
    whats = np.array([sc._solve_head(*row)[2] for row in zip(*args)])
    # every path is exercised: closed forms/cruise, both Newton formulas, infeasible
    assert {sc._DONE, sc._NEWTON_QUARTIC, sc._NEWTON_PURE_S} <= set(whats.tolist())
    assert np.isnan(got).sum() > 100 and np.isfinite(got).sum() > 10_000
    # the edge cases (end speed = the highest reachable) are feasible
    edge_v1 = np.array([sc.scurve_max_end_speed_kernel(h, V, A, J, v0) for h, V, A, J, v0, _ in
                        zip(*(a[:300] for a in args))])
    assert np.isfinite(profiles.scurve_durations(*(a[:300] for a in args[:5]), edge_v1)).all()


def test_batch_broadcasts_and_keeps_the_shape():
    h = np.linspace(0.1, 20.0, 12).reshape(3, 4)
    got = profiles.scurve_durations(h, 100.0, 2000.0, 1e5, 0.0, 0.0)
    assert got.shape == (3, 4)
    want = [[sc.scurve_duration_kernel(x, 100.0, 2000.0, 1e5, 0.0, 0.0) for x in row] for row in h]
    np.testing.assert_array_equal(got, want)
    assert profiles.scurve_durations([], [], [], [], [], []).shape == (0,)


@pytest.mark.parametrize(
    ("name", "value", "message"),
    [("distance", -1.0, "distance must be >= 0"), ("distance", math.inf, "distance must be finite"),
     ("v_max", 0.0, "v_max must be > 0"), ("a_max", math.nan, "a_max contains NaN"),
     ("j_max", math.inf, "j_max must be finite"), ("v_start", -0.5, "v_start must be >= 0"),
     ("v_end", 1e9, "v_end exceeds v_max"), ("v_start", math.nan, "v_start contains NaN")],
)
def test_one_bad_element_deep_in_a_batch_is_named(name, value, message):
    args = dict(zip(("distance", "v_max", "a_max", "j_max", "v_start", "v_end"),
                    (np.array(a) for a in broad_cases(3000, 5))))
    args[name][1777] = value
    with pytest.raises(ValueError, match=message):
        profiles.scurve_durations(**args)


def test_infinite_speed_limit_is_allowed_but_not_infinite_end_speeds():
    got = profiles.scurve_durations([1.0, 2.0], math.inf, 1000.0, 1e5, 0.0, 0.0)
    assert got.tolist() == [sc.scurve_duration_kernel(d, math.inf, 1000.0, 1e5, 0.0, 0.0) for d in (1.0, 2.0)]
    with pytest.raises(ValueError, match="v_start must be finite"):
        profiles.scurve_durations(1.0, math.inf, 1000.0, 1e5, math.inf, 0.0)
    with pytest.raises(ValueError, match="v_end must be finite"):
        profiles.scurve_durations([1.0, 2.0], math.inf, 1000.0, 1e5, 0.0, [0.0, math.inf])
