"""Travel limits (Klipper's check_move), absurd numbers, bounding boxes and speed caps in the summaries.

Truth: Klipper's kinematics/cartesian.py ``_check_endstops`` (an axis that moves must end inside
[position_min, position_max]; error text ``Move out of range: x y z [e]`` with 3 decimals, from
toolhead.py ``move_error``), hand-worked boxes and speed caps of small programs.
"""
from __future__ import annotations

import dataclasses

import json
import math

import numpy as np
import pytest

from conftest import shared_path
from gcodeplan.cli import main
from gcodeplan.config import load_klipper_config, load_machine
from gcodeplan.errors import ConfigError, GcodeError
from gcodeplan.gcode import bounds
from gcodeplan.gcode.reader import GcodeReader, read_moves
from gcodeplan.machine import Machine

CFG = """\
[printer]
kinematics: {kin}
max_velocity: 300
max_accel: 3000
max_z_velocity: 15
max_z_accel: 100
[stepper_x]
rotation_distance: 40
microsteps: 16
position_endstop: 0
position_max: 200
[stepper_y]
rotation_distance: 40
microsteps: 16
position_min: -5
position_max: 210
position_endstop: 0
[stepper_z]
rotation_distance: 8
microsteps: 16
position_endstop: 0
position_max: 100
"""


def cfg(tmp_path, kin="cartesian"):
    p = tmp_path / "printer.cfg"
    p.write_text(CFG.format(kin=kin))
    return load_klipper_config(str(p))


def gfile(tmp_path, text, name="p.gcode"):
    p = tmp_path / name
    p.write_text(text)
    return str(p)


def parse(path, machine):
    return read_moves(path, machine)


@pytest.mark.parametrize("kin", ["cartesian", "corexy", "corexz"])
def test_klipper_limits_are_read(tmp_path, kin):
    m = cfg(tmp_path, kin)
    assert [(m.axes[a].position_min, m.axes[a].position_max) for a in "xyz"] == [(0, 200), (-5, 210), (0, 100)]
    assert (m.axes["e"].position_min, m.axes["e"].position_max) == (-math.inf, math.inf)


def test_moves_to_the_limits_pass_and_beyond_fail_with_klippers_text(tmp_path):
    m = cfg(tmp_path)
    ok = gfile(tmp_path, "G90\nG1 X200 Y-5 Z100 F3000\nG1 X0 Y210 Z0\n")
    parse(ok, m)
    bad = gfile(tmp_path, "G90\nG1 X10 F3000\nM83\nG1 X200.0004 E1.25\n", "bad.gcode")
    with pytest.raises(GcodeError) as err:
        parse(bad, m)
    msg = str(err.value)
    # Klipper's move_error: "%s: %.3f %.3f %.3f [%.3f]" of the end position (E is the running machine E)
    assert msg.startswith(f"{bad}:4: Move out of range: 200.000 0.000 0.000 [1.250] (X 200.000 is outside "
                          "position_min 0 … position_max 200"), msg


def test_only_axes_that_move_are_checked(tmp_path):
    """_check_endstops tests axes_d[i] != 0 only: a G92 leaves the machine position where it is, and
    moving Y alone never fails on X. Z is checked only when Z moves."""
    m = cfg(tmp_path)
    path = gfile(tmp_path, "G1 X150 F3000\nG92 X500\nG1 X550\nG1 Y20\nG1 Z50\n")
    moves, _ = parse(path, m)
    assert moves["x1"].max() == 200.0          # G92 X500 then X550: the machine is at 200, inside
    path = gfile(tmp_path, "G1 Z100.5 F600\n", "z.gcode")
    with pytest.raises(GcodeError, match=r"z\.gcode:1: Move out of range: 0\.000 0\.000 100\.500 \[0\.000\] \(Z"):
        parse(path, m)


def test_arcs_are_checked_chord_by_chord(tmp_path):
    """An arc whose end is inside but whose middle crosses the limit: Klipper cuts it into segments and
    checks each; so do we (the chords are MOVE rows)."""
    m = cfg(tmp_path)
    path = gfile(tmp_path, "G1 X5 Y100 F3000\nG2 X5 Y120 I0 J10\n")     # centre (5, 110), r 10: reaches X -5
    with pytest.raises(GcodeError, match=r":2: Move out of range: -[0-9.]+ [0-9.]+ 0\.000 \[0\.000\] \(X -"):
        parse(path, m)


def test_toml_limits_same_rule_and_no_bounds_option(tmp_path, capsys):
    (tmp_path / "m.toml").write_text('base = "klipper"\n[axis.y]\nposition_min = 0.0\nposition_max = 50.0\n')
    path = gfile(tmp_path, "G1 X10 Y10 F3000\nG1 Y60\n")
    rc = main(["estimate", "-q", "--machine", str(tmp_path / "m.toml"), path])
    err = capsys.readouterr().err
    assert rc == 2 and f"{path}:2: Move out of range: 10.000 60.000 0.000 [0.000] (Y 60.000" in err
    assert main(["estimate", "-q", "--no-bounds", "--machine", str(tmp_path / "m.toml"), path]) == 0
    assert "total time" in capsys.readouterr().out


def test_toml_limits_validation(tmp_path):
    (tmp_path / "m.toml").write_text("[axis.x]\nposition_min = 10.0\nposition_max = 10.0\n")
    with pytest.raises(ConfigError, match=r"axis\.x\.position_max: must be above position_min \(10\), got 10"):
        load_machine(str(tmp_path / "m.toml"))
    (tmp_path / "n.toml").write_text("[axis.x]\nposition_min = nan\n")
    with pytest.raises(ConfigError, match=r"axis\.x\.position_min: must be a number"):
        load_machine(str(tmp_path / "n.toml"))


def test_presets_have_realistic_limits():
    assert [(load_machine("marlin").axes[a].position_min, load_machine("marlin").axes[a].position_max)
            for a in "xyz"] == [(0, 255), (-4, 212.5), (0, 210)]            # Prusa MK3S
    g = load_machine("grbl")
    assert [g.axes[a].position_max - g.axes[a].position_min for a in "xyz"] == [600, 360, 90]   # ± 300×180×45
    k = load_machine("klipper")
    assert all((k.axes[a].position_min, k.axes[a].position_max) == (-1000, 1000) for a in "xyz")


def test_klipper_preset_matches_the_reference_config():
    m = load_klipper_config(str(shared_path("reference", "klipper", "cartesian_corpus.cfg")))
    k = load_machine("klipper")
    assert all((m.axes[a].position_min, m.axes[a].position_max) == (k.axes[a].position_min, k.axes[a].position_max)
               for a in "xyz")


CORPUS = ["prusaslicer25_cube20_marlin2.gcode", "cura413_ender3_cylinder30.gcode",
          "prusaslicer25_twisted_vase_spiral.gcode", "prusaslicer25_multi_object_plate_relE.gcode",
          "prusaslicer25_plate150_gyroid_big.gcode", "cncjs_jscut_tball_pocket_laser.gcode",
          "linuxcnc_arcspiral.ngc", "linuxcnc_plasmatest.ngc", "linuxcnc_stellabee1.ngc"]


@pytest.mark.slow
@pytest.mark.parametrize("name", CORPUS)
def test_every_corpus_file_passes_the_reference_configs_bounds(name):
    m = load_klipper_config(str(shared_path("reference", "klipper", "cartesian_corpus.cfg")))
    if name.endswith(".ngc"):
        # an RS274NGC program read as one (on Klipper its lines led by an axis word do nothing)
        m = dataclasses.replace(m, flavor="linuxcnc")
    r = GcodeReader(str(shared_path("gcode", name)), m)
    rows = sum(len(b) for b in r.batches())
    assert rows > 0 and r.summary.travel_bounds_mm is not None


@pytest.mark.parametrize("preset,name", [("marlin", "prusaslicer25_cube20_marlin2.gcode"),
                                         ("marlin", "cura413_ender3_cylinder30.gcode"),
                                         ("grbl", "linuxcnc_arcspiral.ngc"),
                                         ("grbl", "cncjs_jscut_tball_pocket_laser.gcode")])
def test_presets_accept_the_files_made_for_such_machines(preset, name):
    r = GcodeReader(str(shared_path("gcode", name)), load_machine(preset))
    assert sum(len(b) for b in r.batches()) > 0


# ----------------------------------------------------------------------------- absurd numbers
def test_a_kilometre_move_is_an_error_even_without_bounds(tmp_path, capsys):
    path = gfile(tmp_path, "G1 X10 F3000\nG1 X100000000000000000000\n")     # 1e20 mm ("X1e20" is X1 E20)
    rc = main(["estimate", "-q", "--no-bounds", path])
    assert rc == 2
    assert f"{path}:2: a move of 1e+20 mm: no machine travels over 1e+06 mm" in capsys.readouterr().err
    ok = gfile(tmp_path, "G1 X999000 F60000\n", "ok.gcode")                     # 999 m: allowed, and timed
    assert main(["estimate", "-q", "--no-bounds", "--json", ok]) == 0
    assert json.loads(capsys.readouterr().out)["total_time_s"] == pytest.approx(999000 / 300, rel=1e-3)


def test_an_absurd_total_time_is_an_error_naming_the_line(tmp_path, capsys):
    path = gfile(tmp_path, "G1 X10 F600\nG1 X20 F0.0000001\nG1 X30 F600\n")   # 10 mm at 1.7e-9 mm/s
    assert main(["estimate", "-q", path]) == 2
    err = capsys.readouterr().err
    assert f"{path}:2: the program would run" in err and "over 100000 h" in err


# ----------------------------------------------------------------------------- boxes and speed caps
def test_bounding_boxes_and_speed_caps_by_hand(tmp_path, capsys):
    """Travel: (0,0,0)→(10,20,0.2), the Z hop and the way home; print: (10,20)→(50,20)→(50,60) at Z 0.2.
    Line 4 asks 600 mm/s (cap 300), line 6 asks 20 mm/s of Z (max_z_velocity 15): two capped, the first
    at line 4."""
    path = gfile(tmp_path, "G90\nM83\nG1 X10 Y20 Z0.2 F3000\nG1 X50 E2 F36000\nG1 Y60 E2 F1200\n"
                           "G1 Z5 F1200\nG1 X0 Y0 F6000\n")
    m = load_machine("klipper")
    _, r = parse(path, m)
    s = r.summary
    assert s.print_bounds_mm == {"x": [10.0, 50.0], "y": [20.0, 60.0], "z": [0.2, 0.2]}
    assert s.travel_bounds_mm == {"x": [0.0, 50.0], "y": [0.0, 60.0], "z": [0.0, 5.0]}
    assert (s.speed_capped_moves, s.speed_capped_first_line) == (2, 4)
    assert main(["estimate", "-q", "--json", path]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["print_bounds_mm"] == s.print_bounds_mm and d["travel_bounds_mm"] == s.travel_bounds_mm
    assert (d["speed_capped_moves"], d["speed_capped_first_line"]) == (2, 4)
    assert main(["estimate", "-q", path]) == 0
    text = capsys.readouterr().out
    assert "print box       x 10.0…50.0  y 20.0…60.0  z 0.2…0.2 mm" in text
    assert "travel box      x 0.0…50.0  y 0.0…60.0  z 0.0…5.0 mm" in text
    assert text.count("capped") == 1 and "2 moves asked for more than the machine's speed limit" in text
    assert "(first at line 4)" in text


def test_speed_cap_follows_axis_limits_along_the_move():
    """grbl preset: X and Y 83.33 mm/s each; a 45° XY move may run √2·83.33 = 117.85 mm/s along the path."""
    m = load_machine("grbl")
    L = np.zeros((1, 6))
    L[0] = [math.inf, 5000 / 60, 5000 / 60, 1000 / 60, math.inf, math.inf]
    assert bounds._speed_cap(L[0], 10.0, 10.0, 0.0, 0.0, math.hypot(10, 10), False) == \
        pytest.approx(math.sqrt(2) * 5000 / 60, rel=1e-15)
    assert m.axes["x"].max_velocity == 5000 / 60


def test_reach_hook_for_other_kinematics(tmp_path):
    """A kinematics whose reach is not a box registers its own test (delta: print radius)."""
    def radius_150(batch, machine):
        bad = np.hypot(batch["x1"], batch["y1"]) > 150.0
        return (int(np.argmax(bad)), "Move out of range (print_radius)") if bad.any() else None

    bounds.register_reach_check("corexz", radius_150)
    try:
        m = Machine(kinematics="corexz")
        path = gfile(tmp_path, "G1 X100 Y100 F3000\nG1 X120 Y100\n")
        with pytest.raises(GcodeError, match=r"p\.gcode:2: Move out of range \(print_radius\)"):
            parse(path, m)
    finally:
        bounds._REACH_CHECKS.pop("corexz", None)
