"""Trapezoid planner: hand-worked cases (closed forms), invariants on random programs, streaming."""
from __future__ import annotations

import math

import numpy as np
import pytest

from gcodeplan.errors import ConfigError, GcodeError
from gcodeplan.planner import StreamPlanner, plan_moves, prepare
from gcodeplan.schema import (KIND_WAIT, LIMIT_ACCEL, LIMIT_AXIS, LIMIT_EXTRUDER, LIMIT_FEED, LIMIT_MCR,
                              LIMIT_NONE)
from conftest import dwell_row, klipper_machine, limits_variants, moves_from_points, random_program

A = 3000.0
POLICIES_TRAP = ("klipper", "junction-deviation", "classic-jerk", "exact-stop")


def jerk_machine(policy="classic-jerk", jerks=(8.0, 8.0, 0.4, 2.5)):
    m = klipper_machine(policy)
    for a, j in zip("xyze", jerks):
        m.axes[a].jerk = j
    return m


def total(plan) -> float:
    return float(plan["t_start"][-1] + plan["duration"][-1])


def plan_of(points, policy="klipper", machine=None, **kw):
    m = machine or klipper_machine(policy)
    mv = moves_from_points(points, **kw)
    return mv, plan_moves(mv, m.limits_row(), m, policy)


# --------------------------------------------------------------------------- hand-worked
def test_single_trapezoid_closed_form():
    _, p = plan_of([(0, 0, 0), (200, 0, 0)], feed_v=100.0)
    # T = d/v + v/a
    assert total(p) == pytest.approx(200 / 100 + 100 / A, rel=1e-14)
    assert p["accel_t"][0] == pytest.approx(100 / A) and p["decel_t"][0] == pytest.approx(100 / A)
    assert p["limit"][0] == LIMIT_FEED and p["t_start"][0] == 0.0


@pytest.mark.parametrize("mcr", [0.0, 0.5])
def test_single_triangle_closed_form(mcr):
    m = klipper_machine(minimum_cruise_ratio=mcr)
    _, p = plan_of([(0, 0, 0), (2, 0, 0)], machine=m, feed_v=100.0)
    d = 2.0
    if mcr == 0.0:
        expected = 2 * math.sqrt(d / A)           # pure triangle, peak √(a·d)
        assert p["cruise_v"][0] == pytest.approx(math.sqrt(A * d))
        assert p["limit"][0] == LIMIT_ACCEL
    else:
        # Klipper's mcr peak: v_c² = d·a·(1 − mcr); a cruise of mcr·d stays
        vc = math.sqrt(d * A * (1 - mcr))
        expected = 2 * vc / A + (d - vc * vc / A) / vc
        assert p["cruise_v"][0] == pytest.approx(vc)
        assert p["limit"][0] == LIMIT_MCR
    assert total(p) == pytest.approx(expected, rel=1e-13)


def test_90_degree_corner_at_square_corner_velocity():
    mv, p = plan_of([(0, 0, 0), (100, 0, 0), (100, 100, 0)], feed_v=100.0)
    assert p["end_v"][0] == pytest.approx(5.0, rel=1e-12)
    assert p["start_v"][1] == pytest.approx(5.0, rel=1e-12)
    one = 100 / A + (100 - 5) / A + (100 - (100**2 / (2 * A)) - (100**2 - 25) / (2 * A)) / 100
    assert total(p) == pytest.approx(2 * one, rel=1e-13)


def test_reversal_stops():
    _, p = plan_of([(0, 0, 0), (10, 0, 0), (0, 0, 0)], feed_v=100.0)
    assert p["end_v"][0] == 0.0 and p["start_v"][1] == 0.0


@pytest.mark.parametrize("policy", ["klipper", "junction-deviation", "classic-jerk"])
def test_collinear_chain_same_as_one_move(policy):
    m = jerk_machine(policy)
    pts = [(20.0 * k, 0.0, 0.0, 0.0) for k in range(11)]
    _, chain = plan_of(pts, machine=m, policy=policy, feed_v=100.0)
    _, one = plan_of([pts[0], pts[-1]], machine=m, policy=policy, feed_v=100.0)
    assert total(chain) == pytest.approx(total(one), rel=1e-12)
    assert np.all(chain["cruise_v"] == pytest.approx(100.0))


def test_zigzag_centripetal_term_governs():
    # ±10° around X (20° turns) with 0.05 mm segments: Δv²·tan(θ/2)/4 (θ = 160°) is below R_jd·δ·a
    d, half = 0.05, math.radians(10)
    pts = [(0.0, 0.0, 0.0)]
    for k in range(40):
        a = half if k % 2 == 0 else -half
        x, y, _ = pts[-1]
        pts.append((x + d * math.cos(a), y + d * math.sin(a), 0.0))
    m = klipper_machine()
    mv = moves_from_points(pts, feed_v=100.0)
    prep = prepare(mv, m.limits_row(), m)
    cap_v2 = 2 * d * A * 0.25 * math.tan(math.radians(80))
    inner = prep["max_start_v2"][5:35]
    assert inner == pytest.approx(np.full(30, cap_v2), rel=1e-9)
    jd_v2 = math.sin(math.radians(80)) / (1 - math.sin(math.radians(80))) * 25 * (math.sqrt(2) - 1)
    assert cap_v2 < jd_v2
    p = plan_moves(mv, m.limits_row(), m)
    assert np.all(p["start_v"] ** 2 <= prep["max_start_v2"] * (1 + 1e-12))


def test_z_move_limited_by_z_axis():
    _, p = plan_of([(0, 0, 0), (0, 0, 10)], feed_v=100.0)
    assert p["cruise_v"][0] == pytest.approx(15.0) and p["accel"][0] == pytest.approx(100.0)
    assert total(p) == pytest.approx(10 / 15 + 15 / 100, rel=1e-13)
    assert p["limit"][0] == LIMIT_AXIS
    # XY+Z: z_ratio = d/|dz| scales both limits
    _, p = plan_of([(0, 0, 0), (30, 0, 10)], feed_v=100.0)
    zr = math.sqrt(1000) / 10
    assert p["cruise_v"][0] == pytest.approx(15 * zr) and p["accel"][0] == pytest.approx(100 * zr)


def test_extrude_only_between_prints_stops_and_uses_extruder_limits():
    m = klipper_machine()
    pts = [(0, 0, 0, 0), (20, 0, 0, 1), (20, 0, 0, 2), (40, 0, 0, 3)]
    mv = moves_from_points(pts, feed_v=[50.0, 40.0, 50.0])
    p = plan_moves(mv, m.limits_row(), m)
    assert p["end_v"][0] == 0.0 and p["start_v"][1] == 0.0 and p["end_v"][1] == 0.0 and p["start_v"][2] == 0.0
    a_e = m.max_extrude_only_accel
    assert p["accel"][1] == pytest.approx(a_e) and p["limit"][1] == LIMIT_ACCEL   # too short for 40 mm/s
    # 1 mm at 798 mm/s²: v²/a > d, and the mcr pseudo-accel equals a here → pure triangle
    assert p["duration"][1] == pytest.approx(2 * math.sqrt(1.0 / a_e), rel=1e-12)


def test_retraction_with_xy_is_extruder_limited():
    m = klipper_machine()
    _, p = plan_of([(0, 0, 0, 0), (30, 0, 0, -20)], machine=m, feed_v=200.0)
    r_e = 20 / 30
    assert p["cruise_v"][0] == pytest.approx(m.max_extrude_only_velocity / r_e)
    assert p["accel"][0] == pytest.approx(m.max_extrude_only_accel / r_e)
    assert p["limit"][0] == LIMIT_EXTRUDER


def test_dwell_and_wait_rows_stop_and_add_time():
    m = klipper_machine()
    a = moves_from_points([(0, 0, 0), (50, 0, 0)], feed_v=100.0)
    b = moves_from_points([(50, 0, 0), (100, 0, 0)], feed_v=100.0)
    mv = np.concatenate([a, dwell_row((50, 0, 0), 0.25), dwell_row((50, 0, 0), 1.5, kind=KIND_WAIT), b])
    p = plan_moves(mv, m.limits_row(), m)
    assert p["end_v"][0] == 0.0 and p["start_v"][3] == 0.0
    one = 50 / 100 + 100 / A
    assert p["t_start"][1] == pytest.approx(one) and p["duration"][1] == 0.25 and p["duration"][2] == 1.5
    assert p["limit"][1] == LIMIT_NONE
    assert total(p) == pytest.approx(2 * one + 1.75, rel=1e-13)


def test_exact_stop_flag_and_policy():
    m = klipper_machine()
    pts = [(0, 0, 0), (50, 0, 0), (100, 0, 0)]
    mv = moves_from_points(pts, feed_v=100.0)
    mv["exact_stop"][0] = 1
    p = plan_moves(mv, m.limits_row(), m)
    assert p["end_v"][0] == 0.0 and p["start_v"][1] == 0.0
    p2 = plan_moves(moves_from_points(pts, feed_v=100.0), m.limits_row(), m, "exact-stop")
    assert total(p2) == pytest.approx(total(p))


def test_zero_length_move_is_dropped_transparently():
    m = klipper_machine()
    mv = moves_from_points([(0, 0, 0), (50, 0, 0), (50, 0, 0), (100, 0, 0)], feed_v=100.0)
    p = plan_moves(mv, m.limits_row(), m)
    assert p["duration"][1] == 0.0 and p["end_v"][0] == pytest.approx(100.0)
    assert total(p) == pytest.approx(1.0 + 100 / A)


def test_classic_jerk_starts_and_ends_at_safe_speed():
    m = jerk_machine()
    _, p = plan_of([(0, 0, 0), (100, 0, 0)], machine=m, policy="classic-jerk", feed_v=100.0)
    assert p["start_v"][0] == pytest.approx(8.0) and p["end_v"][0] == pytest.approx(8.0)
    assert total(p) == pytest.approx(2 * 92 / A + (100 - 2 * (100**2 - 64) / (2 * A)) / 100, rel=1e-13)
    _, p = plan_of([(0, 0, 0), (100, 0, 0), (100, 100, 0)], machine=m, policy="classic-jerk", feed_v=100.0)
    assert p["end_v"][0] == pytest.approx(8.0)   # 90° corner at jerk 8 (see test_junctions)


def test_junction_deviation_corner():
    m = klipper_machine("junction-deviation")
    _, p = plan_of([(0, 0, 0), (100, 0, 0), (100, 100, 0)], machine=m, policy="junction-deviation", feed_v=100.0)
    assert p["end_v"][0] ** 2 == pytest.approx(A * m.junction_deviation * (1 + math.sqrt(2)), rel=1e-12)


# --------------------------------------------------------------------------- bad input
def test_bad_input_names_line_or_key():
    m = klipper_machine()
    mv = moves_from_points([(0, 0, 0), (10, 0, 0), (20, 0, 0)], feed_v=100.0, first_line=7)
    mv["feed_v"][1] = 0.0
    with pytest.raises(GcodeError, match="line 8"):
        plan_moves(mv, m.limits_row(), m)
    mv["feed_v"][1] = 10.0
    mv["x1"][0] = np.nan
    with pytest.raises(GcodeError, match="line 7.*not finite"):
        plan_moves(mv, m.limits_row(), m)
    mv["x1"][0] = 10.0
    with pytest.raises(ConfigError, match="unknown policy"):
        plan_moves(mv, m.limits_row(), m, "nonsense")
    lim = m.limits_row()
    lim["mcr"] = 1.0
    with pytest.raises(ConfigError, match="minimum_cruise_ratio"):
        plan_moves(mv, lim, m)
    with pytest.raises(ConfigError, match="jerk"):
        plan_moves(mv, m.limits_row(), m, "classic-jerk")   # no jerk configured
    mv["limits"][1] = 5
    with pytest.raises(GcodeError, match="line 8.*LIMITS"):
        plan_moves(mv, m.limits_row(), m)


# --------------------------------------------------------------------------- invariants
def _machine_for(policy, **kw):
    return jerk_machine(policy) if policy == "classic-jerk" else klipper_machine(policy, **kw)


def check_invariants(mv, lim, plan, prep):
    is_move = prep["is_move"]
    p, pr, m = plan[is_move], prep[is_move], mv[is_move]
    tol = 1e-9
    # phase times non-negative, speeds ordered, speeds consistent with the phases
    for f in ("accel_t", "cruise_t", "decel_t"):
        assert np.all(p[f] >= -1e-12), f
    assert np.all(p["start_v"] <= p["cruise_v"] * (1 + tol) + 1e-9)
    assert np.all(p["end_v"] <= p["cruise_v"] * (1 + tol) + 1e-9)
    assert np.allclose(p["start_v"] + p["accel"] * p["accel_t"], p["cruise_v"], rtol=1e-9, atol=1e-7)
    assert np.allclose(p["cruise_v"] - p["decel"] * p["decel_t"], p["end_v"], rtol=1e-9, atol=1e-7)
    # distance = ∫v dt over the three phases
    dist = ((p["start_v"] + p["cruise_v"]) / 2 * p["accel_t"] + p["cruise_v"] * p["cruise_t"]
            + (p["cruise_v"] + p["end_v"]) / 2 * p["decel_t"])
    assert np.allclose(dist, pr["move_d"], rtol=1e-9, atol=1e-9)
    # no speed above any velocity limit, no accel above the limits in force
    assert np.all(p["cruise_v"] ** 2 <= pr["max_cruise_v2"] * (1 + tol))
    L = lim[m["limits"]]
    kin = pr["kinematic"]
    assert np.all(p["cruise_v"][kin] <= np.minimum(m["feed_v"], L["max_v"])[kin] * (1 + tol) + 1e-9)
    assert np.all(p["accel"][kin] <= m["accel"][kin] * (1 + tol))
    for k, ax in enumerate("xyz"):
        r = np.abs(pr["axes_r_" + ax])
        assert np.all(p["cruise_v"] * r <= L["axis_v_" + ax] * (1 + tol))
        assert np.all(p["accel"] * r <= L["axis_a_" + ax] * (1 + tol))
    # no junction above its cap, speed continuous across junctions (within a run)
    assert np.all(p["start_v"] ** 2 <= np.maximum(pr["max_start_v2"], pr["stop_v2"]) * (1 + tol) + 1e-12)
    joined = ~pr["stop_before"][1:]
    assert np.allclose(p["end_v"][:-1][joined], p["start_v"][1:][joined], rtol=1e-9, atol=1e-9)
    # total = Σ durations, back to back
    assert total(plan) == pytest.approx(plan["duration"].sum(), rel=1e-12)
    assert np.allclose(plan["t_start"][1:], plan["t_start"][:-1] + plan["duration"][:-1], rtol=1e-12, atol=1e-9)


@pytest.mark.parametrize("policy", POLICIES_TRAP)
def test_invariants_on_random_programs(policy):
    rng = np.random.default_rng(abs(hash(policy)) % 2**32)
    m = _machine_for(policy)
    for _ in range(60):
        lim = limits_variants(m, 3, rng)
        mv = random_program(rng, int(rng.integers(20, 400)), n_limits=3, exact_p=0.03)
        plan = plan_moves(mv, lim, m, policy)
        check_invariants(mv, lim, plan, prepare(mv, lim, m, policy))


def test_more_permissive_corners_never_slower():
    rng = np.random.default_rng(7)
    for _ in range(40):
        mv = random_program(rng, 300, exact_p=0.02)
        times = {}
        for scv in (1.0, 5.0, 20.0):
            m = klipper_machine(square_corner_velocity=scv)
            times[scv] = total(plan_moves(mv, m.limits_row(), m))
        assert times[1.0] >= times[5.0] * (1 - 1e-12) and times[5.0] >= times[20.0] * (1 - 1e-12)
        jd = [total(plan_moves(mv, klipper_machine(junction_deviation=d).limits_row(), klipper_machine(),
                               "junction-deviation")) for d in (0.002, 0.013, 0.1)]
        assert jd[0] >= jd[1] * (1 - 1e-12) and jd[1] >= jd[2] * (1 - 1e-12)
        jk = []
        for j in (2.0, 8.0, 20.0):
            mj = jerk_machine(jerks=(j, j, j / 20, j / 3))
            jk.append(total(plan_moves(mv, mj.limits_row(), mj, "classic-jerk")))
        assert jk[0] >= jk[1] * (1 - 1e-9) and jk[1] >= jk[2] * (1 - 1e-9)


def test_exact_stop_never_faster():
    rng = np.random.default_rng(11)
    for _ in range(40):
        mv = random_program(rng, 300)
        m = jerk_machine()
        stop = total(plan_moves(mv, m.limits_row(), m, "exact-stop"))
        for policy in ("klipper", "junction-deviation", "classic-jerk"):
            if policy == "classic-jerk":
                continue   # starts/ends at the safe speed, not at rest: may beat exact stop at stops
            assert total(plan_moves(mv, m.limits_row(), m, policy)) <= stop * (1 + 1e-12)


# --------------------------------------------------------------------------- streaming
def _stream(mv, lim, m, policy, chunk):
    sp = StreamPlanner(m, policy)
    outs, window = [], 0
    for i in range(0, len(mv), chunk):
        outs.extend(sp.feed(mv[i:i + chunk], lim))
        window = max(window, sp.pending)
    outs.extend(sp.finish())
    return np.concatenate([o[0] for o in outs]), np.concatenate([o[1] for o in outs]), window


@pytest.mark.parametrize("policy", POLICIES_TRAP)
def test_stream_is_bit_identical_to_whole_plan(policy):
    rng = np.random.default_rng(3)
    m = _machine_for(policy)
    for trial in range(5):
        lim = limits_variants(m, 3, rng)
        mv = random_program(rng, 1500, n_limits=3, dwell_p=0.002 * trial, exact_p=0.005 * (trial % 2))
        whole = plan_moves(mv, lim, m, policy)
        for chunk in ((1, 3, 17, 256, 5000) if trial == 0 else (5, 41, 256)):
            mv_out, plan_out, window = _stream(mv, lim, m, policy, chunk)
            assert len(plan_out) == len(mv)
            for f in mv.dtype.names:
                assert np.array_equal(mv_out[f], mv[f]), f
            for f in whole.dtype.names:
                assert np.array_equal(plan_out[f], whole[f]), (f, chunk)
            if chunk <= 17:
                assert window < 200   # bounded look-ahead, not the whole program


def test_stream_emits_before_finish_on_long_program():
    m = klipper_machine()
    rng = np.random.default_rng(5)
    mv = random_program(rng, 5000, dwell_p=0.0)
    sp = StreamPlanner(m)
    emitted = sum(len(o[0]) for i in range(0, 5000, 100) for o in sp.feed(mv[i:i + 100], m.limits_row()))
    assert emitted > 4000
    rest = sum(len(o[0]) for o in sp.finish())
    assert emitted + rest == 5000


def test_dispatch_to_blend_and_scurve():
    m = klipper_machine()
    mv = moves_from_points([(0, 0, 0), (50, 0, 0), (50, 50, 0)], feed_v=100.0)
    trap = plan_moves(mv, m.limits_row(), m)
    s = plan_moves(mv, m.limits_row(), m, jerk=1e5)
    assert len(s) == 2 and np.all(s["jerk"] > 0) and total(s) > total(trap)   # jerk-limited: slower
    lim = m.limits_row()
    lim["max_jerk"] = 1e5
    assert np.array_equal(plan_moves(mv, lim, m)["duration"], s["duration"])
    b = plan_moves(mv, m.limits_row(), m, "blend")
    assert len(b) == 2 and np.all(b["duration"] > 0)
