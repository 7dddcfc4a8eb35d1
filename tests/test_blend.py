"""Blend mode (parabolic blends under a path tolerance): checked against a hand-worked corner, closed-form
trapezoid times and physical invariants measured on the SEGMENT pieces (sampled independently here)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from gcodeplan.errors import GcodeError
from gcodeplan.machine import Machine
from gcodeplan.planner.blend import corner_geometry, plan_blend
from gcodeplan.schema import (KIND_DWELL, KIND_PRINT, KIND_TRAVEL, MOVE_DTYPE, PHASE_BLEND, PHASE_DWELL,
                              SEGMENT_DTYPE)

AX = "xyze"


def polyline(points, feed=100.0, accel=1000.0, tol=math.nan, e_per_mm=0.0):
    """MOVE rows along a polyline (2-D or 3-D points); E grows by e_per_mm per mm when given."""
    pts = np.asarray(points, dtype=float)
    if pts.shape[1] == 2:
        pts = np.column_stack([pts, np.zeros(len(pts))])
    n = len(pts) - 1
    m = np.zeros(n, MOVE_DTYPE)
    m["line"] = np.arange(1, n + 1)
    m["kind"] = KIND_PRINT if e_per_mm else KIND_TRAVEL
    d = np.linalg.norm(pts[1:] - pts[:-1], axis=1)
    e = np.concatenate([[0.0], np.cumsum(d * e_per_mm)])
    for k, c in enumerate("xyz"):
        m[c + "0"], m[c + "1"] = pts[:-1, k], pts[1:, k]
    m["e0"], m["e1"] = e[:-1], e[1:]
    m["move_d"] = d
    m["feed_v"] = feed
    m["accel"] = accel
    m["blend_p"] = tol
    return m


def machine(tol=0.05, accel=1000.0, **kw):
    return Machine(junction_policy="blend", blend_tolerance=tol, max_accel=accel, max_velocity=1000.0, **kw)


def plan(moves, mach):
    return plan_blend(moves, mach.limits_row(), mach)


def evaluate(segs, t):
    """Position, velocity, acceleration (len(t), 4) from the pieces: an evaluator independent of the planner."""
    t = np.asarray(t, dtype=float)
    k = np.clip(np.searchsorted(segs["t0"], t, side="right") - 1, 0, len(segs) - 1)
    s = segs[k]
    tau = (t - s["t0"])[:, None]
    col = lambda pre: np.stack([s[pre + a] for a in AX], axis=1)  # noqa: E731
    p, v, a, j = col("p"), col("v"), col("a"), col("j")
    return (p + v * tau + a * tau**2 / 2 + j * tau**3 / 6, v + a * tau + j * tau**2 / 2, a + j * tau)


def piece_end(segs):
    """(position, velocity) at the end of every piece, from its own polynomial."""
    tau = segs["dt"][:, None]
    col = lambda pre: np.stack([segs[pre + a] for a in AX], axis=1)  # noqa: E731
    p, v, a, j = col("p"), col("v"), col("a"), col("j")
    return p + v * tau + a * tau**2 / 2 + j * tau**3 / 6, v + a * tau + j * tau**2 / 2


def piece_start(segs):
    col = lambda pre: np.stack([segs[pre + a] for a in AX], axis=1)  # noqa: E731
    return col("p"), col("v")


def random_polyline(rng, n_max=8, dim=2):
    n = int(rng.integers(2, n_max + 1))
    steps = rng.uniform(-1, 1, (n, dim)) * 10 ** rng.uniform(-1.0, 1.7, size=(n, 1))
    return np.vstack([np.zeros(dim), np.cumsum(steps, axis=0)])


def trapezoid_rest_to_rest_t(d, v, a):
    """DESIGN.md: T = d/V + V/A when d >= V²/A, else 2·√(d/A)."""
    return d / v + v / a if d >= v * v / a else 2.0 * math.sqrt(d / a)


# --------------------------------------------------------------------------- the hand-worked corner
def test_single_90_degree_corner_hand_worked():
    # A = 1000, P = 0.05, 90°: |u_out − u_in| = √2, so v_c² = 8·A·P/k² = 200, τ = |ΔV|/(2A) = 20/2000 = 0.01 s,
    # deviation e = |ΔV|·τ/4 = 20·0.01/4 = 0.05 = P. Each blend half covers v_c·τ = 0.1414 mm of a segment.
    moves = polyline([(0, 0), (100, 0), (100, 100)], feed=100.0)
    mach = machine(tol=0.05)
    p, segs = plan(moves, mach)
    v_c = math.sqrt(200.0)
    assert p["end_v"][0] == pytest.approx(v_c, rel=1e-12)
    assert p["start_v"][1] == pytest.approx(v_c, rel=1e-12)
    blend = segs[segs["phase"] == PHASE_BLEND]
    assert len(blend) == 2 and list(blend["move"]) == [0, 1]
    assert blend["dt"] == pytest.approx([0.01, 0.01], rel=1e-12)
    assert blend[0]["px"] == pytest.approx(100 - v_c * 0.01, rel=1e-12)  # leaves the line v_c·τ early
    assert np.hypot(blend["ax"], blend["ay"]) == pytest.approx([1000.0, 1000.0], rel=1e-12)
    # closest approach to the via point, by sampling the blend and refining the sample grid
    t_lo, t_hi = blend[0]["t0"], blend[1]["t0"] + blend[1]["dt"]
    for _ in range(6):
        t = np.linspace(t_lo, t_hi, 2001)
        pos, _, _ = evaluate(segs, t)
        dist = np.hypot(pos[:, 0] - 100.0, pos[:, 1])
        k = int(np.argmin(dist))
        t_lo, t_hi = t[max(k - 2, 0)], t[min(k + 2, len(t) - 1)]
    e = 20.0 * 0.01 / 4
    assert dist[k] == pytest.approx(e, rel=1e-9)
    # straight parts: rest → 100 mm/s at 1000 mm/s² (5 mm), cruise, 100 → v_c (4.9 mm), then the half-blend
    straight = 100.0 - v_c * 0.01
    t_move0 = 0.1 + (100 - v_c) / 1000 + (straight - 5.0 - (100**2 - 200) / 2000) / 100 + 0.01
    assert p["duration"][0] == pytest.approx(t_move0, rel=1e-12)
    assert p["duration"][1] == pytest.approx(t_move0, rel=1e-12)  # mirror image


def test_deviation_scales_with_tolerance_and_a_smaller_tolerance_is_slower():
    moves = polyline([(0, 0), (50, 0), (50, 50)], feed=200.0)
    t = [plan(moves, machine(tol=tol))[0]["duration"].sum() for tol in (0.0, 0.01, 0.1, 1.0)]
    assert t[0] > t[1] > t[2] > t[3]
    for tol in (0.01, 0.1, 1.0):
        _, _, w = corner_geometry(moves, machine(tol=tol).limits_row(), machine(tol=tol))
        assert w[1] == pytest.approx(8 * 1000 * tol / 2, rel=1e-12)  # v² = 8AP/k², k² = 2


# --------------------------------------------------------------------------- invariants on random paths
def _check_invariants(moves, mach, a_max):
    p, segs = plan(moves, mach)
    assert segs.dtype == SEGMENT_DTYPE
    # time line: contiguous pieces; each move's pieces span exactly its PLAN row
    assert np.allclose(segs["t0"][1:], segs["t0"][:-1] + segs["dt"][:-1], rtol=0, atol=1e-12)
    for i in range(len(moves)):
        mine = segs[segs["move"] == i]
        assert mine["t0"][0] == pytest.approx(p["t_start"][i], abs=1e-12)
        assert mine["dt"].sum() == pytest.approx(p["duration"][i], rel=1e-12, abs=1e-15)
    # C0 and C1 across every piece boundary, at rest at both ends, ends at the last point
    pe, ve = piece_end(segs)
    ps, vs = piece_start(segs)
    scale = 1.0 + np.abs(ps).max()
    assert np.abs(pe[:-1] - ps[1:]).max() <= 1e-9 * scale
    assert np.abs(ve[:-1] - vs[1:]).max() <= 1e-9 * (1.0 + np.abs(vs).max())
    assert np.abs(vs[0]).max() == 0.0 and np.abs(ve[-1]).max() <= 1e-9
    end = np.array([moves[-1][a + "1"] for a in AX])
    assert np.abs(pe[-1] - end).max() <= 1e-9 * scale
    # acceleration: analytic per piece, and sampled as second differences of the position (a C1 piecewise
    # quadratic's second difference is a weighted mean of its acceleration, so it is bounded by A as well)
    acc_xyz = np.sqrt(segs["ax"] ** 2 + segs["ay"] ** 2 + segs["az"] ** 2)
    assert acc_xyz.max() <= a_max * (1 + 1e-9)
    total = p["duration"].sum()
    h = 2e-4
    t = np.arange(h, total - h, h / 3.1)
    pos_m, _, _ = evaluate(segs, t - h)
    pos_0, _, _ = evaluate(segs, t)
    pos_p, _, _ = evaluate(segs, t + h)
    acc_fd = np.linalg.norm((pos_p - 2 * pos_0 + pos_m)[:, :3], axis=1) / h**2
    assert acc_fd.max() <= a_max * (1 + 1e-6) + 1e-6 * scale / h**2
    # blends: within half of each neighbour, deviation at the via point ≤ P (= |ΔV|·τ/4, measured)
    rows, corner_c, corner_v2 = corner_geometry(moves, mach.limits_row(), mach)
    tol = np.where(np.isnan(moves["blend_p"]), mach.blend_tolerance, moves["blend_p"])
    for j in range(1, len(moves)):
        first = segs[(segs["phase"] == PHASE_BLEND) & (segs["move"] == j - 1)]
        first = first[first["t0"] >= p["t_start"][j] - first["dt"] - 1e-12] if len(first) else first
        second = segs[(segs["phase"] == PHASE_BLEND) & (segs["move"] == j)]
        second = second[second["t0"] <= p["t_start"][j] + 1e-12] if len(second) else second
        if corner_v2[j] == 0.0 or corner_c[j] == 0.0:
            assert len(first) == 0 and len(second) == 0
            continue
        tau = corner_c[j] * math.sqrt(corner_v2[j])
        assert first["dt"][0] == pytest.approx(tau, rel=1e-12) and second["dt"][0] == pytest.approx(tau, rel=1e-12)
        via = np.array([moves[j - 1][a + "1"] for a in "xyz"])
        start = np.array([first[0]["p" + a] for a in "xyz"])
        end, _ = piece_end(second)
        assert np.linalg.norm(start - via) <= moves["move_d"][j - 1] / 2 * (1 + 1e-12)
        assert np.linalg.norm(end[0, :3] - via) <= moves["move_d"][j] / 2 * (1 + 1e-12)
        ts = np.linspace(first["t0"][0], second["t0"][0] + second["dt"][0], 401)
        pos, _, _ = evaluate(segs, ts)
        dev = np.linalg.norm(pos[:, :3] - via, axis=1).min()
        assert dev <= tol[j - 1] * (1 + 1e-9) + 1e-12
        u_in = (via - np.array([moves[j - 1][a + "0"] for a in "xyz"])) / moves["move_d"][j - 1]
        u_out = (np.array([moves[j][a + "1"] for a in "xyz"]) - via) / moves["move_d"][j]
        dv = math.sqrt(corner_v2[j]) * np.linalg.norm(u_out - u_in)
        assert dev == pytest.approx(dv * tau / 4, rel=1e-4)  # 401 samples: the minimum is found to ~1e-5
    # distance: the straight parts plus the two blend zones are the segment's length
    for i in range(len(moves)):
        d_in = corner_c[i] * corner_v2[i]
        d_out = corner_c[i + 1] * corner_v2[i + 1]
        r = p[i]
        straight = ((r["start_v"] + r["cruise_v"]) / 2 * r["accel_t"] + r["cruise_v"] * r["cruise_t"]
                    + (r["cruise_v"] + r["end_v"]) / 2 * r["decel_t"])
        assert straight + d_in + d_out == pytest.approx(moves["move_d"][i], rel=1e-9)
    return p


@pytest.mark.parametrize("seed", range(6))
def test_random_polylines_keep_tolerance_accel_continuity_and_distance(seed):
    rng = np.random.default_rng(seed)
    for _ in range(4):
        dim = 3 if seed % 2 else 2
        pts = random_polyline(rng, dim=dim)
        a = float(10 ** rng.uniform(2.5, 3.7))
        tol = float(10 ** rng.uniform(-3, 0))
        moves = polyline(pts, feed=float(10 ** rng.uniform(1, 2.5)), accel=a, e_per_mm=0.05 * (seed % 3 == 0))
        _check_invariants(moves, machine(tol=tol, accel=a), a)


@pytest.mark.parametrize("seed", range(4))
def test_a_larger_tolerance_is_never_slower(seed):
    rng = np.random.default_rng(100 + seed)
    for _ in range(25):
        pts = random_polyline(rng, dim=2 + seed % 2)
        a = float(10 ** rng.uniform(2, 4))
        moves = polyline(pts, feed=float(10 ** rng.uniform(1, 2.7)), accel=a)
        prev = math.inf
        for tol in [0.0, 1e-4, 1e-3, 0.01, 0.05, 0.2, 1.0, 10.0]:
            total = plan(moves, machine(tol=tol, accel=a))[0]["duration"].sum()
            assert total <= prev * (1 + 1e-12)
            prev = total


def test_tolerance_zero_gives_the_exact_stop_time():
    rng = np.random.default_rng(7)
    pts = random_polyline(rng, n_max=12)
    moves = polyline(pts, feed=80.0, accel=1500.0)
    p, _ = plan(moves, machine(tol=0.0, accel=1500.0))
    expected = sum(trapezoid_rest_to_rest_t(d, 80.0, 1500.0) for d in moves["move_d"])
    assert p["duration"].sum() == pytest.approx(expected, rel=1e-12)
    assert np.all(p["start_v"] == 0.0) and np.all(p["end_v"] == 0.0)


def test_per_move_tolerance_g64_p_overrides_the_machine_default():
    moves = polyline([(0, 0), (50, 0), (50, 50), (0, 50)], feed=200.0)
    moves["blend_p"] = [0.2, 0.0, math.nan]  # corner 1: min(0.2, 0) = 0 → stop; corner 2: min(0, 0.5)
    p, _ = plan(moves, machine(tol=0.5))
    assert p["end_v"][0] == 0.0 and p["end_v"][1] == 0.0
    moves["blend_p"] = [0.2, 0.2, math.nan]  # corner 2: min(0.2, machine 0.5) = 0.2
    p, _ = plan(moves, machine(tol=0.5))
    assert p["end_v"][1] == pytest.approx(math.sqrt(8 * 1000 * 0.2 / 2), rel=1e-12)


def test_reversal_exact_stop_and_dwell_stop():
    # 180°: the formula would allow a blend, but the path would stop short of the via point: a full stop
    p, segs = plan(polyline([(0, 0), (10, 0), (0, 0)]), machine(tol=1.0))
    assert p["end_v"][0] == 0.0 and not np.any(segs["phase"] == PHASE_BLEND)
    # G61 on the first move: it ends at rest
    moves = polyline([(0, 0), (10, 0), (10, 10)])
    moves["exact_stop"][0] = 1
    assert plan(moves, machine(tol=1.0))[0]["end_v"][0] == 0.0
    # a dwell between two moves: full stop, its time added, one PHASE_DWELL piece at the via point
    a = polyline([(0, 0), (10, 0), (10, 10)])
    moves = np.concatenate([a[:1], np.zeros(1, MOVE_DTYPE), a[1:]])
    moves[1]["kind"], moves[1]["dwell_t"] = KIND_DWELL, 0.5
    moves[1]["x0"] = moves[1]["x1"] = 10.0
    p, segs = plan(moves, machine(tol=1.0))
    assert p["end_v"][0] == 0.0 and p["start_v"][2] == 0.0 and p["duration"][1] == 0.5
    dwell = segs[segs["phase"] == PHASE_DWELL]
    assert len(dwell) == 1 and dwell["move"][0] == 1 and dwell["px"][0] == 10.0 and dwell["dt"][0] == 0.5


def test_zero_length_row_is_transparent():
    a = polyline([(0, 0), (10, 0), (10, 10)])
    z = a[1:2].copy()
    z["x1"], z["y1"], z["move_d"] = z["x0"], z["y0"], 0.0
    with_zero = np.concatenate([a[:1], z, a[1:]])
    p0, _ = plan(a, machine(tol=0.1))
    p1, segs = plan(with_zero, machine(tol=0.1))
    assert p1["duration"][1] == 0.0 and p1["duration"].sum() == pytest.approx(p0["duration"].sum(), rel=1e-14)
    assert not np.any(segs["move"] == 1)


def test_per_axis_accel_limit_holds_in_the_blend():
    mach = machine(tol=1.0, accel=3000.0)
    mach.axes["y"].max_accel = 200.0
    moves = polyline([(0, 0), (40, 0), (40, 40)], feed=150.0, accel=3000.0)
    p, segs = plan(moves, mach)
    assert np.abs(segs["ay"]).max() <= 200.0 * (1 + 1e-12)
    assert np.abs(segs["ax"]).max() <= 3000.0 * (1 + 1e-12)
    assert p["end_v"][0] > 0.0  # still blends


def test_extruder_rate_is_continuous_through_a_blend():
    moves = polyline([(0, 0), (20, 0), (20, 20)], feed=60.0, e_per_mm=0.05)
    p, segs = plan(moves, machine(tol=0.1))
    pe, ve = piece_end(segs)
    ps, vs = piece_start(segs)
    assert np.abs(pe[:-1, 3] - ps[1:, 3]).max() < 1e-12 and np.abs(ve[:-1, 3] - vs[1:, 3]).max() < 1e-12
    assert pe[-1, 3] == pytest.approx(moves["e1"][-1], rel=1e-12)


def test_bad_tolerance_names_the_line():
    moves = polyline([(0, 0), (10, 0), (10, 10)])
    moves["blend_p"][1] = -0.1
    with pytest.raises(GcodeError, match="line 2"):
        plan(moves, machine())


def test_many_moves_are_planned_by_the_compiled_passes():
    # a long zig-zag: the kernels handle it in one go; speeds settle and time adds up
    n = 20000
    x = np.arange(n + 1) * 1.0
    y = np.where(np.arange(n + 1) % 2, 0.3, 0.0)
    moves = polyline(np.column_stack([x, y]), feed=150.0, accel=2000.0)
    p, segs = plan(moves, machine(tol=0.02, accel=2000.0))
    assert np.all(np.isfinite(p["duration"])) and np.all(p["duration"] > 0)
    assert segs["t0"][-1] + segs["dt"][-1] == pytest.approx(p["duration"].sum(), rel=1e-12)
