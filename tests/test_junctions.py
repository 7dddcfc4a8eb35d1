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
