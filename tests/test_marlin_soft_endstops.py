"""Marlin's software endstops: a target past them is clamped to them (Marlin's apply_motion_limits, called by
prepare_line_to_destination and by plan_arc for every segment), where Klipper refuses the move.

The truth: the same program with the clamped coordinates written by hand (the `marlin` preset: X 0…255,
Y −4…212.5, Z 0…210), and Marlin's own rule that the position after the move is the clamped one (a relative
move after it starts there)."""
from __future__ import annotations

import numpy as np
import pytest

import gcodeplan as gp
from gcodeplan.errors import GcodeError

HEAD = "G21\nG90\nM82\nG1 X10 Y10 F3000\n"


def _est(tmp_path, text, machine="marlin", name="p.gcode"):
    f = tmp_path / name
    f.write_text(HEAD + text)
    return gp.estimate(str(f), machine=machine)


@pytest.mark.parametrize("machine", ["marlin", "marlin-bugfix", "marlin-generic"])
def test_absolute_and_relative_targets_past_the_endstops_are_clamped(tmp_path, machine):
    m = gp.load_machine("marlin", firmware="generic") if machine == "marlin-generic" else machine
    past = _est(tmp_path, "G1 X300 Y-10 E5\nG1 X100 Y100\nG91\nG1 X200 Z-3\nG1 X-10\nG90\nG1 Y300\n", m, "a.gcode")
    by_hand = _est(tmp_path, "G1 X255 Y-4 E5\nG1 X100 Y100\nG91\nG1 X155 Z0\nG1 X-10\nG90\nG1 Y212.5\n", m, "b.gcode")
    assert past.total_time_s == by_hand.total_time_s > 0
    # line 5: X and Y; line 8: X and Z (one move); line 12: Y
    assert past.parse.soft_clamped_moves == 3
    assert past.parse.soft_clamped_first_line == 5
    assert any("beyond the software endstop (X max 255)" in w for w in past.parse.warnings)


def test_the_clamped_rows_end_at_the_endstops(tmp_path):
    f = tmp_path / "p.gcode"
    f.write_text(HEAD + "G1 X300 Y-10\nG91\nG1 X5\n")
    plan = gp.plan(str(f), machine="marlin")
    rows = plan.moves if hasattr(plan, "moves") else plan
    ends = [(float(r["x1"]), float(r["y1"])) for r in rows if int(r["line"]) >= 5]
    assert ends == [(255.0, -4.0)]          # the relative X5 from the endstop is clamped again: no motion


def test_arc_chords_past_the_endstop_are_clamped_each(tmp_path):
    # a half circle of radius 20 around (20, 10) from (40, 10) to (0, 10) clockwise: it dips to Y −10
    est = _est(tmp_path, "G1 X40 Y10\nG2 X0 Y10 I-20 J0\n")
    arc = [r for r in gp.plan(str(tmp_path / "p.gcode"), machine="marlin").moves if int(r["line"]) == 6]
    ys = np.array([float(r["y1"]) for r in arc])
    assert ys.min() == -4.0 and (ys >= -4.0).all()
    # the chords whose end Marlin's plan_arc computed below Y −4: each clamped (a circle: 2 r sinθ > 14 below 0)
    assert est.parse.soft_clamped_moves == int((ys == -4.0).sum()) > 1


def test_m211_s0_turns_clamping_off_and_the_move_is_an_error_naming_marlin(tmp_path):
    with pytest.raises(GcodeError, match=r"p\.gcode:6: Move out of range.*M211 S0"):
        _est(tmp_path, "M211 S0\nG1 X300\n")
    est = _est(tmp_path, "M211 S0\nM211 S1\nG1 X300\n")
    assert est.parse.soft_clamped_moves == 1


@pytest.mark.parametrize("machine,words", [("klipper", "Klipper refuses this move"),
                                           ("grbl", "ALARM:2"), ("linuxcnc", "LinuxCNC refuses it")])
def test_other_firmware_still_refuse_with_their_own_words(tmp_path, machine, words):
    f = tmp_path / "p.gcode"
    f.write_text("G90\nG1 X10000 F3000\n")
    with pytest.raises(GcodeError, match=words):
        gp.estimate(str(f), machine=machine)


def test_no_bounds_means_no_endstops(tmp_path):
    from gcodeplan.config import without_bounds

    m = without_bounds(gp.load_machine("marlin"))
    est = _est(tmp_path, "G1 X300\n", m)
    assert est.parse.soft_clamped_moves == 0
    assert est.parse.travel_bounds_mm["x"][1] == 300.0
