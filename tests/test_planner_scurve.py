"""S-curve mode: jerk-limited double-S profiles per move. Checked against the 1-D solver (profiles.scurve),
the trapezoid planner's total in the limit J → ∞, and invariants measured on the cubic SEGMENT pieces."""
from __future__ import annotations

import math

import numpy as np
import pytest

from gcodeplan.errors import ConfigError
from gcodeplan.machine import Machine
from gcodeplan.planner.scurve import plan_scurve
from gcodeplan.schema import KIND_DWELL, KIND_TRAVEL, MOVE_DTYPE, PHASE_DWELL

AX = "xyze"


def polyline(points, feed=100.0, accel=1000.0):
    pts = np.asarray(points, dtype=float)
    if pts.shape[1] == 2:
        pts = np.column_stack([pts, np.zeros(len(pts))])
    n = len(pts) - 1
    m = np.zeros(n, MOVE_DTYPE)
    m["line"] = np.arange(1, n + 1)
    m["kind"] = KIND_TRAVEL
    for k, c in enumerate("xyz"):
        m[c + "0"], m[c + "1"] = pts[:-1, k], pts[1:, k]
    m["move_d"] = np.linalg.norm(pts[1:] - pts[:-1], axis=1)
    m["feed_v"] = feed
    m["accel"] = accel
    m["blend_p"] = math.nan
    return m


def machine(policy="junction-deviation", accel=1000.0):
    return Machine(junction_policy=policy, max_accel=accel, max_velocity=1000.0, junction_deviation=0.05)


def random_polyline(rng, n_max=8):
    n = int(rng.integers(1, n_max + 1))
    steps = rng.uniform(-1, 1, (n, 2)) * 10 ** rng.uniform(-1.0, 1.7, size=(n, 1))
    return np.vstack([np.zeros(2), np.cumsum(steps, axis=0)])


def evaluate(segs, t):
    """Position, velocity, acceleration (len(t), 4) from the cubic pieces (independent of the planner)."""
    t = np.asarray(t, dtype=float)
    k = np.clip(np.searchsorted(segs["t0"], t, side="right") - 1, 0, len(segs) - 1)
    s = segs[k]
    tau = (t - s["t0"])[:, None]
    col = lambda pre: np.stack([s[pre + a] for a in AX], axis=1)  # noqa: E731
    p, v, a, j = col("p"), col("v"), col("a"), col("j")
    return p + v * tau + a * tau**2 / 2 + j * tau**3 / 6, v + a * tau + j * tau**2 / 2, a + j * tau


def piece_ends(segs):
    tau = segs["dt"][:, None]
    col = lambda pre: np.stack([segs[pre + a] for a in AX], axis=1)  # noqa: E731
    p, v, a, j = col("p"), col("v"), col("a"), col("j")
    return p + v * tau + a * tau**2 / 2 + j * tau**3 / 6, v + a * tau + j * tau**2 / 2, a + j * tau


def test_single_move_duration_is_the_1d_solver_s():
    from gcodeplan import profiles

    for d, feed, a, j in [(100.0, 100.0, 1000.0, 20000.0), (2.0, 150.0, 3000.0, 1e5), (0.3, 50.0, 500.0, 5000.0)]:
        moves = polyline([(0, 0), (d * 0.6, d * 0.8)], feed=feed, accel=a)
        mach = machine(accel=a)
        plan, segs = plan_scurve(moves, mach.limits_row(), mach, j)
        expected = profiles.scurve(d, feed, a, j).duration
        assert plan["duration"][0] == pytest.approx(expected, rel=1e-12)
        assert plan["jerk"][0] == j
        assert plan["accel_t"][0] + plan["cruise_t"][0] + plan["decel_t"][0] == pytest.approx(expected, rel=1e-12)


def test_hand_worked_rest_to_rest_with_constant_accel_phase():
    # d = 100, V = 100, A = 1000, J = 20000: tj = A/J = 0.05 s, ramp 0→100 has ta = V/A − A/J = 0.05 s, ramp
    # time 0.15 s and distance 100/2·0.15 = 7.5 mm; two ramps 15 mm, cruise 85 mm at 100 → 0.85 s. T = 1.15 s.
    moves = polyline([(0, 0), (100, 0)], feed=100.0, accel=1000.0)
    mach = machine()
    plan, segs = plan_scurve(moves, mach.limits_row(), mach, 20000.0)
    assert plan["duration"][0] == pytest.approx(1.15, rel=1e-12)
    assert plan["accel_t"][0] == pytest.approx(0.15, rel=1e-12) and plan["cruise_t"][0] == pytest.approx(0.85)
    assert len(segs) == 7 and segs["dt"][:3] == pytest.approx([0.05, 0.05, 0.05], rel=1e-12)
    assert np.abs(segs["ax"]).max() == pytest.approx(1000.0, rel=1e-12)


def _check(moves, mach, jerk):
    plan, segs = plan_scurve(moves, mach.limits_row(), mach, jerk)
    total = plan["duration"].sum()
    assert np.allclose(segs["t0"][1:], segs["t0"][:-1] + segs["dt"][:-1], rtol=0, atol=1e-12)
    assert segs["t0"][-1] + segs["dt"][-1] == pytest.approx(total, rel=1e-12)
    # analytic: jerk ≤ J per piece (path jerk = |axes_r|·J = J), acceleration ≤ the move's limit
    jn = np.sqrt(segs["jx"] ** 2 + segs["jy"] ** 2 + segs["jz"] ** 2)
    assert jn.max() <= jerk * (1 + 1e-12)
    pe, ve, ae = piece_ends(segs)
    col = lambda pre: np.stack([segs[pre + a] for a in AX], axis=1)  # noqa: E731
    ps, vs, as_ = col("p"), col("v"), col("a")
    scale = 1 + np.abs(ps).max()
    # position and acceleration continuous everywhere (a = 0 at every junction); speed continuous
    assert np.abs(pe[:-1] - ps[1:]).max() <= 1e-9 * scale
    assert np.abs(ae[:-1] - as_[1:]).max() <= 1e-6 * (1 + np.abs(as_).max())
    speed_end = np.linalg.norm(ve[:-1, :3], axis=1)
    speed_start = np.linalg.norm(vs[1:, :3], axis=1)
    assert np.abs(speed_end - speed_start).max() <= 1e-9 * (1 + speed_start.max())
    same_move = segs["move"][:-1] == segs["move"][1:]
    assert np.abs(ve[:-1][same_move] - vs[1:][same_move]).max(initial=0) <= 1e-9 * (1 + speed_start.max())
    # at rest at both ends and a = 0 at each move's ends
    assert np.abs(vs[0]).max() == 0 and np.abs(ve[-1]).max() <= 1e-9 * (1 + speed_start.max())
    for i in range(len(moves)):
        mine = np.flatnonzero(segs["move"] == i)
        assert np.abs(as_[mine[0]]).max() == 0.0
        assert np.abs(ae[mine[-1]]).max() <= 1e-6 * (1 + np.abs(as_).max())
        # distance: the move's pieces cover exactly its length
        moved = np.linalg.norm(pe[mine[-1], :3] - ps[mine[0], :3])
        assert moved == pytest.approx(moves["move_d"][i], rel=1e-9, abs=1e-12)
    end = np.array([moves[-1][a + "1"] for a in AX])
    assert np.abs(pe[-1] - end).max() <= 1e-9 * scale
    # sampled: finite differences of the acceleration stay within J (a is continuous and piecewise linear)
    h = min(1e-4, total / 50)
    t = np.arange(0.0, total - h, h / 2.7)
    _, _, a0 = evaluate(segs, t)
    _, _, a1 = evaluate(segs, t + h)
    assert (np.linalg.norm((a1 - a0)[:, :3], axis=1) / h).max() <= jerk * (1 + 1e-6)
    # and the speed along the path never exceeds each move's cruise cap
    return plan, segs


@pytest.mark.parametrize("seed", range(5))
def test_random_paths_respect_jerk_and_stay_continuous(seed):
    rng = np.random.default_rng(seed)
    for _ in range(4):
        pts = random_polyline(rng)
        a = float(10 ** rng.uniform(2.5, 3.7))
        j = float(10 ** rng.uniform(3.5, 6))
        moves = polyline(pts, feed=float(10 ** rng.uniform(1, 2.5)), accel=a)
        policy = ("junction-deviation", "klipper", "exact-stop")[seed % 3]
        _check(moves, machine(policy, accel=a), j)


@pytest.mark.parametrize("seed", range(3))
def test_a_larger_jerk_is_never_slower(seed):
    rng = np.random.default_rng(50 + seed)
    for _ in range(10):
        pts = random_polyline(rng)
        a = float(10 ** rng.uniform(2.5, 3.7))
        moves = polyline(pts, feed=float(10 ** rng.uniform(1, 2.5)), accel=a)
        mach = machine(("junction-deviation", "klipper", "exact-stop")[seed], accel=a)
        prev = math.inf
        for j in (1e3, 1e4, 5e4, 2e5, 1e6, 1e7):
            total = plan_scurve(moves, mach.limits_row(), mach, j)[0]["duration"].sum()
            assert total <= prev * (1 + 1e-12)
            prev = total


def test_huge_jerk_approaches_the_trapezoid_plan():
    from gcodeplan.planner import plan_moves

    rng = np.random.default_rng(3)
    pts = random_polyline(rng, n_max=12)
    moves = polyline(pts, feed=120.0, accel=2000.0)
    mach = machine("junction-deviation", accel=2000.0)
    trap = plan_moves(moves, mach.limits_row(), mach)["duration"].sum()
    t1 = plan_scurve(moves, mach.limits_row(), mach, 1e7)[0]["duration"].sum()
    t2 = plan_scurve(moves, mach.limits_row(), mach, 1e10)[0]["duration"].sum()
    assert t1 > t2 > trap
    assert t2 == pytest.approx(trap, rel=1e-4)
    assert abs(t2 - trap) < abs(t1 - trap) / 10


def test_dwell_stops_and_adds_its_time():
    a = polyline([(0, 0), (10, 0), (20, 0)])
    moves = np.concatenate([a[:1], np.zeros(1, MOVE_DTYPE), a[1:]])
    moves[1]["kind"], moves[1]["dwell_t"], moves[1]["x0"], moves[1]["x1"] = KIND_DWELL, 0.25, 10.0, 10.0
    mach = machine()
    plan, segs = plan_scurve(moves, mach.limits_row(), mach, 1e5)
    assert plan["end_v"][0] == 0.0 and plan["start_v"][2] == 0.0 and plan["duration"][1] == 0.25
    assert plan["duration"][0] == pytest.approx(plan["duration"][2], rel=1e-12)
    assert np.sum(segs["phase"] == PHASE_DWELL) == 1


def test_bad_jerk_is_a_config_error():
    moves = polyline([(0, 0), (10, 0)])
    mach = machine()
    for bad in (0.0, -1.0, math.inf, math.nan, "x"):
        with pytest.raises(ConfigError, match="max_jerk"):
            plan_scurve(moves, mach.limits_row(), mach, bad)
