"""Marlin 2.1.2's ARC_SUPPORT segments (gcode/arcs_marlin.py) against arcs worked by hand from plan_arc's rule
(Marlin gcode/motion/G2_G3.cpp): the segment count, the chord lengths, the exact end point, the periodic
correction back onto the circle, equal helical and E steps, and the program-level dispatch for a machine run
by the marlin-2.1.2 model."""
import math

import numpy as np
import pytest

from gcodeplan.config import load_machine
from gcodeplan.errors import GcodeError
from gcodeplan.gcode.arcs_marlin import MarlinArcSettings, arc_settings, marlin_arc_points, marlin_r_offset
from gcodeplan.gcode.reader import read_moves

F32_EPS = float(np.finfo(np.float32).eps)


def _quarter(radius, **kw):
    """A clockwise quarter circle from (0, 0) around (radius, 0) to (radius, radius)."""
    return marlin_arc_points((0, 0, 0, 0), (radius, radius, 0, 0), (radius, 0), True, **kw)


@pytest.mark.parametrize("radius, segments", [
    # flat = r·π/2.  r = 10: 15.71 mm, floor 15 < ceil(72/4) = 18 circle minimum → 18 segments of 0.873 mm
    (10.0, 18),
    # r = 50: 78.54 mm → 78 segments of 1.0069 mm > MAX_ARC_SEGMENT_MM → ceil(78.54 / 1) = 79
    (50.0, 79),
    # r = 1: 1.571 mm → circle minimum 18, 0.0873 mm < MIN_ARC_SEGMENT_MM → floor(1.571 / 0.1) = 15
    (1.0, 15),
    # r = 20: 31.42 mm → 31 segments of 1.0134 mm > 1 → 32
    (20.0, 32),
    # r = 100: 157.08 mm → 157 of 1.0005 mm → 158
    (100.0, 158),
])
def test_segment_count_by_hand(radius, segments):
    pts = _quarter(radius)
    assert len(pts) == segments
    # equal chords (equal angles): 2·r·sin(θ/2), θ = (π/2)/n
    chord = 2 * radius * math.sin(math.pi / 4 / segments)
    start = np.vstack([[0, 0, 0, 0], pts[:-1]])
    lengths = np.hypot(*(pts[:, :2] - start[:, :2]).T)
    assert np.allclose(lengths, chord, rtol=0, atol=2e-5 * max(radius, 1))


def test_full_circle_is_min_circle_segments_and_ends_where_it_started():
    # I5 J5 with no end point: r = 7.07, 44.4 mm → floor 44 < 72 (MIN_CIRCLE_SEGMENTS)
    pts = marlin_arc_points((0, 0, 0, 0), (0, 0, 0, 0), (5, 5), False)
    assert len(pts) == 72
    assert tuple(pts[-1]) == (0, 0, 0, 0)
    r = np.hypot(pts[:, 0] - 5, pts[:, 1] - 5)
    # cos θ ≈ 1 − θ²/2 shrinks the radius a little each segment (θ = 5°: 1.7 µm); i = 25, 50 are put back
    assert np.all(r <= math.hypot(5, 5) + 1e-6) and r.min() > math.hypot(5, 5) - 5e-4
    assert r[24] == pytest.approx(math.hypot(5, 5), abs=2e-6) and r[23] < math.hypot(5, 5) - 3e-4
    # counter-clockwise: the first point turns the radius vector (−5, −5) positively
    a = math.atan2(pts[0, 1] - 5, pts[0, 0] - 5) - math.atan2(-5, -5)
    assert a == pytest.approx(2 * math.pi / 72, abs=1e-5)


def test_end_point_is_the_target_exactly_and_points_are_float32():
    end = (12.345, 6.789, 0.3, 1.234)
    pts = marlin_arc_points((0.1, 0.2, 0.3, 0.0), end, (6.0, 0.1), True)
    assert np.array_equal(pts[-1], np.array(end, dtype=np.float32).astype(np.float64))
    assert np.array_equal(pts, pts.astype(np.float32).astype(np.float64))


def test_correction_every_n_arc_correction_segments():
    """Points 25, 50 … (N_ARC_CORRECTION = 25) are the start vector turned by i·θ with cos/sin (in float); the
    ones between come from the small-angle rotation. N_ARC_CORRECTION = 1 makes every point exact."""
    r = 100.0
    # a half circle counter-clockwise around (0, 100): 314.16 mm → 314 of 1.0005 mm → ceil = 315 segments
    pts = marlin_arc_points((0, 0, 0, 0), (0, 2 * r, 0, 0), (0, r), False)
    ptsx = marlin_arc_points((0, 0, 0, 0), (0, 2 * r, 0, 0), (0, r), False,
                             settings=MarlinArcSettings(n_arc_correction=1))
    n = len(pts)
    assert n == len(ptsx) == 315
    theta = np.float32(np.float32(np.float32(360.0) * np.float32(math.pi)) / np.float32(180.0)) / np.float32(2)
    theta = np.float32(theta / np.float32(n))
    for i in (25, 50, 75, 300):
        a = float(np.float32(np.float32(i) * theta))
        # the radius vector (0, −r) turned by a: (r·sin a, −r·cos a), about the centre (0, r)
        x = np.float32(np.float32(-0.0 * np.float32(math.cos(a))) + np.float32(r * np.float32(math.sin(a))))
        y = np.float32(np.float32(r) + np.float32(np.float32(-0.0 * np.float32(math.sin(a)))
                                                  - np.float32(r * np.float32(math.cos(a)))))
        assert (pts[i - 1, 0], pts[i - 1, 1]) == (x, y) == (ptsx[i - 1, 0], ptsx[i - 1, 1])
    drift = np.abs(np.hypot(pts[:, 0], pts[:, 1] - r) - r)
    assert drift.max() < 1e-3
    assert not np.array_equal(pts[:24], ptsx[:24])      # the approximation is used between corrections


def test_helix_z_and_e_advance_by_equal_float_steps():
    pts = marlin_arc_points((0, 0, 0, 10.0), (10, 10, 2.0, 12.0), (10, 0), True)
    n = len(pts)
    per_z = np.float32(np.float32(2.0) / np.float32(n))
    per_e = np.float32(np.float32(2.0) / np.float32(n))
    z = np.float32(0.0)
    e = np.float32(10.0)
    for i in range(n - 1):
        z = np.float32(z + per_z)
        e = np.float32(e + per_e)
        assert pts[i, 2] == z and pts[i, 3] == e
    assert pts[-1, 2] == np.float32(2.0) and pts[-1, 3] == np.float32(12.0)


def test_segments_per_second_rule():
    """ARC_SEGMENTS_PER_SEC 50: the nominal length is feed/50 clamped to [0.1, 1] mm."""
    s = MarlinArcSettings(segments_per_sec=50)
    assert len(_quarter(50.0, feed_mm_s=10.0, settings=s)) == 392     # 0.2 mm: floor(78.54/0.2) = 392
    assert len(_quarter(50.0, feed_mm_s=100.0, settings=s)) == 79     # 2 mm clamped to 1 mm
    assert len(_quarter(50.0, feed_mm_s=1.0, settings=s)) == 785      # 0.02 mm clamped to 0.1 mm


def test_r_form_centre_and_short_radius():
    # R10 from (0, 0) to (10, 10) clockwise: the centre (10, 0) (the short way round)
    a, b = marlin_r_offset((0, 0), (10, 10), 10.0, True)
    assert (float(a), float(b)) == pytest.approx((10.0, 0.0), abs=1e-5)
    # |R| under half the chord: Marlin pivots on the chord's midpoint (a half circle), no error
    a, b = marlin_r_offset((0, 0), (10, 0), 2.0, False)
    assert (float(a), float(b)) == (5.0, 0.0)
    assert marlin_r_offset((3, 3), (3, 3), 5.0, True) is None
    assert marlin_r_offset((0, 0), (1, 0), 0.0, True) is None


def test_p_circles_share_helix_and_e_by_angle():
    # a quarter arc plus one full circle (ARC_P_CIRCLES): 72 + 18 segments, E shared 4/5 and 1/5
    pts = marlin_arc_points((0, 0, 0, 0), (10, 10, 0, 5.0), (10, 0), True, circles=1)
    assert len(pts) == 72 + 18
    assert pts[71, 0] == 0 and pts[71, 1] == 0
    assert pts[71, 3] == pytest.approx(4.0, abs=1e-5)
    assert pts[-1, 3] == np.float32(5.0)


def test_uint16_count_is_refused():
    with pytest.raises(ValueError, match="16 bits"):
        _quarter(60000.0)


def test_arc_settings_of_machines():
    m = load_machine("marlin")
    assert arc_settings(m) == MarlinArcSettings(min_segment_mm=0.1, max_segment_mm=1.0)


def _rows(tmp_path, text, machine="marlin"):
    p = tmp_path / "a.gcode"
    p.write_text(text)
    moves, _ = read_moves(str(p), load_machine(machine))
    return moves


def test_program_on_the_marlin_model_uses_marlins_segments(tmp_path):
    moves = _rows(tmp_path, "G21\nG90\nM83\nG1 X50 Y50 F3000\nG2 X60 Y60 I10 J0 E2\nG2 I5 J5\nG1 X0 Y0\n")
    arc = moves[moves["line"] == 5]
    assert len(arc) == 18
    assert np.allclose(np.diff(arc["e1"] - arc["e0"]), 0, atol=1e-6)        # equal E per segment
    assert arc["e1"][-1] == 2.0 and arc["x1"][-1] == 60.0 and arc["y1"][-1] == 60.0
    assert len(moves[moves["line"] == 6]) == 72                              # a full circle without X/Y
    # the same machine on the generic planner keeps its own chord rule (Klipper's resolution rule)
    generic = _rows(tmp_path, "G21\nG90\nG1 X50 Y50 F3000\nG2 X60 Y60 I10 J0\n", "klipper")
    assert len(generic[generic["line"] == 4]) != 18


def test_invalid_arc_args_name_the_line(tmp_path):
    with pytest.raises(GcodeError) as err:
        _rows(tmp_path, "G1 X10 Y10 F3000\nG2 X10 Y10 R5\n")
    assert err.value.line == 2 and "Invalid arc args" in str(err.value)


# ---------------------------------------------------------------- relative moves in Marlin's floats

def _m83_spiral(tmp_path, n=8000):
    lines = ["G21", "G90", "M83", "G1 Z0.2 F600"]
    for i in range(n):
        a = i * 0.05
        lines.append(f"G1 X{100 + 40 * math.cos(a):.3f} Y{100 + 40 * math.sin(a):.3f} E0.07 F1800")
    p = tmp_path / "m83.gcode"
    p.write_text("\n".join(lines) + "\n")
    return p


def test_relative_e_sums_in_float_as_marlin_and_changes_the_step_count(tmp_path):
    """M83 without G92 E0: Marlin's E is current_position.e + 0.07 in float, 8000 times: 560.0447 mm, not 560;
    at 280 steps/mm the extruder makes 156813 steps, 13 more than a double sum would give."""
    from gcodeplan.planner import marlin_kernels as mk
    from gcodeplan.planner.marlin import run_marlin

    chain = np.float32(0.0)
    for _ in range(8000):
        chain = np.float32(chain + np.float32(0.07))
    assert float(chain) == pytest.approx(560.0447, abs=1e-4)
    m = load_machine("marlin")
    moves, reader = read_moves(str(_m83_spiral(tmp_path)), m)
    assert moves["e1"][-1] == float(chain)
    slow, _ = read_moves(str(tmp_path / "m83.gcode"), m, force_python=True)
    assert np.array_equal(moves["e1"], slow["e1"])
    _, model = run_marlin(moves, reader.limits, m, keep_blocks=True, e_position_sets=reader.interp.e_position_sets)
    oi = np.concatenate([x[0] for x in model.blocks])
    e_steps = int(oi[oi[:, mk.OI_HAS_BLOCK] == 1, mk.OI_SE].sum())
    assert e_steps == round(float(chain) * 280) == 156813          # round(560.0 × 280) would be 156800
    # the generic planner (and Klipper) keep the double sum: their results do not change
    generic, _ = read_moves(str(tmp_path / "m83.gcode"), load_machine("klipper"))
    assert generic["e1"][-1] == pytest.approx(560.0, abs=1e-9)


def test_relative_xyz_sums_in_float(tmp_path):
    p = tmp_path / "g91.gcode"
    p.write_text("G21\nG90\nG1 X10.1 Y0 F3000\nG91\n" + "G1 X0.1\n" * 1000)
    moves, _ = read_moves(str(p), load_machine("marlin"))
    slow, _ = read_moves(str(p), load_machine("marlin"), force_python=True)    # the Python interpreter's sum
    assert np.array_equal(moves["x1"], slow["x1"])
    x = np.float32(10.1)
    for _ in range(1000):
        x = np.float32(x + np.float32(0.1))
    assert moves["x1"][-1] == float(x) != pytest.approx(110.1, abs=1e-6)


def test_p_word_follows_arc_p_circles(tmp_path):
    """Marlin's default build (the marlin preset's) has ARC_P_CIRCLES off: P is ignored, and gcodeplan says so;
    a build with it on draws the circles first (18 + 72 segments for a quarter arc and one circle)."""
    from dataclasses import replace

    p = tmp_path / "p.gcode"
    p.write_text("G21\nG90\nG1 X50 Y50 F3000\nG2 X60 Y60 I10 J0 P1\n")
    m = load_machine("marlin")
    moves, reader = read_moves(str(p), m)
    assert len(moves[moves["line"] == 4]) == 18
    assert any("ARC_P_CIRCLES off" in w for w in reader.summary.warnings)
    m2 = replace(m, marlin_arcs=MarlinArcSettings(p_circles=True))
    moves, _ = read_moves(str(p), m2)
    assert len(moves[moves["line"] == 4]) == 18 + 72


def test_absurd_arcs_are_errors_without_numpy_warnings(tmp_path):
    import warnings

    huge = "1" + "0" * 60
    for line in (f"G2 X10 Y10 I{huge} J0", f"G2 X{huge} Y10 R5", f"G2 X10 Y10 R{huge}"):
        p = tmp_path / "a.gcode"
        p.write_text("G1 X0 Y0 F3000\n" + line + "\n")
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            with pytest.raises(GcodeError) as err:
                read_moves(str(p), load_machine("marlin"))
        assert err.value.line == 2
