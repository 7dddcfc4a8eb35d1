"""Junction rules against closed forms and hand-worked corners."""
from __future__ import annotations

import math

import pytest

from gcodeplan.planner.junctions import (jd_junction_v2, klipper_centripetal_v2, klipper_extruder_corner_v2,
                                         klipper_junction_deviation, marlin_jerk_junction_v, marlin_safe_v,
                                         marlin_small_segment_v2)


def cos_for_turn(turn_deg: float) -> float:
    """junction cos θ for a direction change of turn_deg (0 = straight on, 180 = reversal)."""
    return -math.cos(math.radians(turn_deg))


def test_klipper_junction_deviation_value():
    # klipper-planner.md §2: scv 5, accel 3000 → 0.0034518 mm
    assert klipper_junction_deviation(5.0, 3000.0) == pytest.approx(0.0034518, abs=5e-8)
    assert klipper_junction_deviation(5.0, 3000.0) == pytest.approx(25 * (math.sqrt(2) - 1) / 3000, rel=1e-15)


def test_klipper_90_degree_corner_is_square_corner_velocity():
    jd = klipper_junction_deviation(5.0, 3000.0)
    big = 1e12  # long moves: the centripetal mid-move terms do not bind
    v2 = klipper_centripetal_v2(cos_for_turn(90), jd, 3000.0, big, jd, 3000.0, big)
    assert math.sqrt(v2) == pytest.approx(5.0, rel=1e-12)
    # scv 10 → 10 mm/s, whatever the accel (δ scales with 1/a)
    jd10 = klipper_junction_deviation(10.0, 1250.0)
    assert math.sqrt(klipper_centripetal_v2(cos_for_turn(90), jd10, 1250.0, big, jd10, 1250.0, big)) == \
        pytest.approx(10.0, rel=1e-12)


def test_klipper_straight_is_uncapped_and_reversal_stops():
    jd = klipper_junction_deviation(5.0, 3000.0)
    assert klipper_centripetal_v2(-1.0, jd, 3000.0, 100.0, jd, 3000.0, 100.0) == math.inf
    assert klipper_centripetal_v2(1.0, jd, 3000.0, 100.0, jd, 3000.0, 100.0) == 0.0


def test_klipper_centripetal_term_for_short_moves():
    # 20° turn, 0.05 mm moves: R_jd·δ·a = 671 mm²/s² but Δv²·tan(θ/2)/4 = 300·tan(80°)/4 = 425 binds
    jd = klipper_junction_deviation(5.0, 3000.0)
    delta_v2 = 2 * 0.05 * 3000.0
    v2 = klipper_centripetal_v2(cos_for_turn(20), jd, 3000.0, delta_v2, jd, 3000.0, delta_v2)
    assert v2 == pytest.approx(delta_v2 * math.tan(math.radians(80)) / 4, rel=1e-12)
    s = math.sin(math.radians(80))
    assert v2 < s / (1 - s) * jd * 3000.0


def test_klipper_extruder_corner():
    # E ratio jumps by 0.05 mm/mm at icv 1 → v ≤ 20 mm/s; same ratio → no cap beyond cruise
    assert klipper_extruder_corner_v2(1.0, 0.08, 0.03, 1e4) == pytest.approx(400.0, rel=1e-12)
    assert klipper_extruder_corner_v2(1.0, 0.03, 0.03, 1e4) == 1e4


def test_jd_rule_closed_form():
    # 90°: v² = a·δ·(√½)/(1−√½) = a·δ·(1+√2)
    assert jd_junction_v2(cos_for_turn(90), 1000.0, 0.013) == pytest.approx(1000 * 0.013 * (1 + math.sqrt(2)))
    assert jd_junction_v2(cos_for_turn(180), 1000.0, 0.013) == 0.0
    assert jd_junction_v2(cos_for_turn(0), 1000.0, 0.013) == math.inf
    # monotone: sharper turns are slower
    vals = [jd_junction_v2(cos_for_turn(t), 1000.0, 0.013) for t in (10, 45, 90, 135, 170)]
    assert vals == sorted(vals, reverse=True)


def test_marlin_small_segment_arc_rule():
    # 0.5 mm chords turning 10°: radius d/φ, v² = a·d/φ
    phi = math.radians(10)
    assert marlin_small_segment_v2(cos_for_turn(10), 0.5, 1000.0) == pytest.approx(1000 * 0.5 / phi, rel=1e-9)
    assert marlin_small_segment_v2(cos_for_turn(10), 1.5, 1000.0) == math.inf   # not short
    assert marlin_small_segment_v2(cos_for_turn(60), 0.5, 1000.0) == math.inf   # sharper than 45°


def test_marlin_safe_speed():
    # X at 100 mm/s with jerk 8 → 8; diagonal at 100 → each axis 70.7 → 100·8/70.7
    assert marlin_safe_v(100.0, 100.0, 0.0, 0.0, 0.0, 8.0, 8.0, 0.4, 2.5) == pytest.approx(8.0)
    c = 100 / math.sqrt(2)
    assert marlin_safe_v(100.0, c, c, 0.0, 0.0, 8.0, 8.0, 0.4, 2.5) == pytest.approx(8 * math.sqrt(2))
    # E is the limiting axis: 10 mm/s of filament with jerk 2.5 → 1/4 of the speed
    assert marlin_safe_v(40.0, 40.0, 0.0, 0.0, 10.0, 8.0, 8.0, 0.4, 2.5) == pytest.approx(8.0)
    assert marlin_safe_v(40.0, 40.0, 0.0, 0.0, 20.0, 8.0, 8.0, 0.4, 2.5) == pytest.approx(5.0)
    assert marlin_safe_v(5.0, 5.0, 0.0, 0.0, 0.0, 8.0, 8.0, 0.4, 2.5) == 5.0


def test_marlin_jerk_corner_hand_worked():
    # 90° X→Y at 100 mm/s, jerk 8: X drops 100 → 0 (jump 100) → factor 0.08, Y then jumps 8 = jerk → 8 mm/s
    j = (8.0, 8.0, 0.4, 2.5)
    v = marlin_jerk_junction_v(100.0, 100.0, 1, 0, 0, 0, 0, 1, 0, 0, *j, 8.0, 8.0)
    assert v == pytest.approx(8.0)
    # straight on, 100 → 60 mm/s: coasting at 60, X jump 0 → 60
    assert marlin_jerk_junction_v(100.0, 60.0, 1, 0, 0, 0, 1, 0, 0, 0, *j, 8.0, 8.0) == pytest.approx(60.0)
    # reversal at 20 mm/s: jump max(20, 20) = 20 → 20·8/20 = 8 → then both safe speeds (8) > 0.99·8 → safe
    assert marlin_jerk_junction_v(20.0, 20.0, 1, 0, 0, 0, -1, 0, 0, 0, *j, 8.0, 8.0) == pytest.approx(8.0)
    # small turn, 30°, 50 mm/s: Δvx = 50(1−cos30) = 6.7, Δvy = 25 → scale 8/25 → 16 mm/s
    c, s = math.cos(math.radians(30)), math.sin(math.radians(30))
    v = marlin_jerk_junction_v(50.0, 50.0, 1, 0, 0, 0, c, s, 0, 0, *j, 8.0, 8.0)
    assert v == pytest.approx(50 * 8 / 25, rel=1e-9)


# A V-turn where X reverses and Y carries on, with safe speeds below the junction speed so that Marlin's
# safe-speed override (both safe speeds > 0.99·v_j → v_j = the next safe speed) cannot decide: the
# reversal rule alone sets the speed. Jerk 10 mm/s on X and Y, 100 mm/s both moves, unit directions
# (±0.6, 0.8) and (∓0.28, 0.96) (0.28² + 0.96² = 1).
#   X: 60 → −28 mm/s passes through rest, so Marlin counts max(60, 28) = 60 (not the 88 of the difference):
#      factor 10/60, v_j = 100/6 = 16.667 mm/s;
#   Y: then 80/6 = 13.33 → 96/6 = 16 mm/s, a coasting jump of 2.67 < 10: no further limit;
#   safe speeds: 100·min(10/60, 10/80) = 12.5 and 100·min(10/28, 10/96) = 10.417, both < 0.99·16.667.
# (Counting the difference, 88, would give 100·10/88 = 11.36 mm/s; the smaller magnitude, 28, 35.7 mm/s.)
JERKS_10 = (10.0, 10.0, 0.4, 2.5)
V_TURN = [((0.6, 0.8), (-0.28, 0.96)), ((-0.6, 0.8), (0.28, 0.96)),      # the larger speed before the turn
          ((0.28, 0.96), (-0.6, 0.8)), ((-0.28, 0.96), (0.6, 0.8))]      # the larger speed after it


@pytest.mark.parametrize("u_prev, u", V_TURN)
def test_marlin_jerk_reversal_counts_the_larger_speed_only(u_prev, u):
    safe_prev = marlin_safe_v(100.0, 100 * u_prev[0], 100 * u_prev[1], 0.0, 0.0, *JERKS_10)
    safe = marlin_safe_v(100.0, 100 * u[0], 100 * u[1], 0.0, 0.0, *JERKS_10)
    assert sorted((safe_prev, safe)) == pytest.approx([100 * 10 / 96, 12.5], rel=1e-12)
    v = marlin_jerk_junction_v(100.0, 100.0, u_prev[0], u_prev[1], 0, 0, u[0], u[1], 0, 0, *JERKS_10,
                               safe_prev, safe)
    assert max(safe_prev, safe) < 0.99 * v              # the override does not apply: the rule decides
    assert v == pytest.approx(100 / 6, rel=1e-12)


def test_marlin_jerk_reversal_in_a_plan():
    """The same V-turn through the classic-jerk planner: the junction runs at 100/6 mm/s."""
    from conftest import klipper_machine, moves_from_points
    from gcodeplan.planner import plan_moves

    m = klipper_machine("classic-jerk")
    for a, j in zip("xyze", JERKS_10):
        m.axes[a].jerk = j
    mv = moves_from_points([(0, 0, 0), (60, 80, 0), (32, 176, 0)], feed_v=100.0)
    p = plan_moves(mv, m.limits_row(), m, "classic-jerk")
    assert p["start_v"][0] == pytest.approx(12.5, rel=1e-12)       # from rest: the first move's safe speed
    assert p["end_v"][0] == pytest.approx(100 / 6, rel=1e-12) and p["start_v"][1] == p["end_v"][0]
    assert p["end_v"][1] == pytest.approx(100 * 10 / 96, rel=1e-12)
