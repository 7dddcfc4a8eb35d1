"""Machines with per-axis limits only (grbl): the toolhead has no accel/velocity of its own."""
import math

import pytest

from gcodeplan.config import load_machine
from gcodeplan.errors import GcodeError
from gcodeplan.planner import plan_moves
from conftest import moves_from_points


def test_per_axis_limits_bound_a_move_when_the_toolhead_has_none():
    m = load_machine("grbl")                    # x/y 83.33 mm/s, 500 mm/s²; toolhead inf
    assert m.max_accel == math.inf
    moves = moves_from_points([(0, 0, 0, 0), (100, 0, 0, 0)], feed_v=math.inf, accel=math.inf)
    plan = plan_moves(moves, m.limits_row(), m, "junction-deviation")
    v, a = 5000 / 60, 500.0
    # closed-form trapezoid: T = d/v + v/a
    assert plan["duration"][0] == pytest.approx(100 / v + v / a, rel=1e-12)
    # diagonal XY: each axis at its own limit, the path at √2 times that
    moves = moves_from_points([(0, 0, 0, 0), (100, 100, 0, 0)], feed_v=math.inf, accel=math.inf)
    plan = plan_moves(moves, m.limits_row(), m, "junction-deviation")
    d, v, a = 100 * math.sqrt(2), v * math.sqrt(2), a * math.sqrt(2)
    assert plan["duration"][0] == pytest.approx(d / v + v / a, rel=1e-12)


def test_a_move_no_limit_applies_to_is_an_error_naming_its_line():
    m = load_machine("grbl")                    # the E axis has no limits on a mill
    moves = moves_from_points([(0, 0, 0, 0), (0, 0, 0, 5)], feed_v=math.inf, accel=math.inf, first_line=7)
    with pytest.raises(GcodeError, match=r"line 7: no acceleration limit applies"):
        plan_moves(moves, m.limits_row(), m, "junction-deviation")
