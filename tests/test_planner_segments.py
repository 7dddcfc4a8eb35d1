"""PLAN → SEGMENT pieces and sampling: the pieces reproduce each move's geometry and profile."""
from __future__ import annotations

import numpy as np
import pytest

from gcodeplan.planner import plan_moves, sample_segments, to_segments
from gcodeplan.schema import PHASE_ACCEL, PHASE_CRUISE, PHASE_DECEL, PHASE_DWELL
from conftest import dwell_row, klipper_machine, moves_from_points, random_program


def test_single_move_three_pieces_hand_worked():
    m = klipper_machine()
    mv = moves_from_points([(0, 0, 0, 0), (60, 80, 0, 5)], feed_v=100.0)   # 100 mm, u = (0.6, 0.8), r_e = 0.05
    plan = plan_moves(mv, m.limits_row(), m)
    segs = to_segments(mv, plan, first_index=10)
    assert list(segs["phase"]) == [PHASE_ACCEL, PHASE_CRUISE, PHASE_DECEL]
    assert np.all(segs["move"] == 10)
    assert segs["ax"][0] == pytest.approx(0.6 * 3000) and segs["ay"][2] == pytest.approx(-0.8 * 3000)
    assert segs["ve"][1] == pytest.approx(0.05 * 100)
    # cruise starts after v²/(2a) = 5/3 mm of path
    assert segs["px"][1] == pytest.approx(0.6 * 10000 / 6000) and segs["pe"][1] == pytest.approx(0.05 * 10000 / 6000)
    pos, vel, acc, jerk = sample_segments(segs, [0.0, plan["duration"][0] / 2, plan["duration"][0]])
    assert pos[2] == pytest.approx([60, 80, 0, 5], abs=1e-9)
    assert vel[1] == pytest.approx([60, 80, 0, 5])
    assert np.all(acc[1] == 0.0) and np.all(jerk == 0.0)


def test_extrude_only_and_dwell_pieces():
    m = klipper_machine()
    a = moves_from_points([(0, 0, 0, 0), (0, 0, 0, -1)], feed_v=30.0)
    mv = np.concatenate([a, dwell_row((0, 0, 0, -1), 0.5)])
    plan = plan_moves(mv, m.limits_row(), m)
    segs = to_segments(mv, plan)
    assert segs["phase"][-1] == PHASE_DWELL and segs["dt"][-1] == 0.5 and segs["move"][-1] == 1
    assert np.all(segs["vx"] == 0) and np.all(segs["vy"] == 0)
    assert np.all(segs["ve"][:-1] <= 0.0) and np.all(segs[:-1]["ae"][[0]] < 0)
    pos, vel, _, _ = sample_segments(segs, [plan["t_start"][1] + 0.25])
    assert pos[0] == pytest.approx([0, 0, 0, -1]) and np.all(vel == 0.0)


def test_sampled_motion_matches_every_move():
    rng = np.random.default_rng(2)
    m = klipper_machine()
    mv = random_program(rng, 300)
    plan = plan_moves(mv, m.limits_row(), m)
    segs = to_segments(mv, plan)
    assert np.all(segs["dt"] > 0) and np.all(np.diff(segs["t0"]) >= 0)
    # every move ends where the G-code says
    motion = plan["duration"] > 0
    ends = (plan["t_start"] + plan["duration"])[motion]
    pos, _, _, _ = sample_segments(segs, ends)
    want = np.stack([mv[a + "1"] for a in "xyze"], axis=1)[motion]
    assert np.allclose(pos, want, atol=1e-7)
    # distance along the path = ∫|v| dt, numerically (fine grid, trapezoid rule) vs Σ move_d
    t = np.linspace(0.0, ends[-1], 400001)
    _, vel, acc, _ = sample_segments(segs, t)
    speed = np.sqrt((vel[:, :3] ** 2).sum(axis=1))
    xyz_len = np.sqrt(sum((mv[a + "1"] - mv[a + "0"]) ** 2 for a in "xyz")).sum()
    assert np.trapezoid(speed, t) == pytest.approx(xyz_len, rel=1e-4)
    # path speed continuous (axis velocities may turn at a corner): no change above a·dt between samples
    assert np.max(np.abs(np.diff(speed))) <= 3000 * (t[1] - t[0]) * (1 + 1e-6) + 1e-9


def test_sampling_rejects_unsorted_times():
    m = klipper_machine()
    mv = moves_from_points([(0, 0, 0), (10, 0, 0)])
    segs = to_segments(mv, plan_moves(mv, m.limits_row(), m))
    with pytest.raises(ValueError):
        sample_segments(segs, [0.1, 0.0])
