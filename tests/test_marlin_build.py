"""A Marlin build's switches that add G codes (issue 21): the machine's ``marlin_build`` (gcodeplan/marlin_build.py),
read from Configuration(_adv).h (config/marlin_config.py) or a machine TOML.

Truth: Marlin 2.1's sources. gcode.cpp ``process_parsed_command`` dispatches G20 only with INCH_MODE_SUPPORT,
G17-G19 only with CNC_WORKSPACE_PLANES, G80 only with GCODE_MOTION_MODES, G53-G59 only with CNC_COORDINATE_SYSTEMS,
G60/G61 with SAVED_POSITIONS, G5 with BEZIER_CURVE_SUPPORT, G38 with G38_PROBE_TARGET, all off by default.
parser.h ``set_input_linear_units``: G20 makes every linear value (X Y Z, E without volumetric, F) × 25.4.
parser.cpp: with GCODE_MOTION_MODES a G0-G3 sets ``motion_mode_codenum`` (-1 at power-up and after G80) and a
line led by X Y Z E F runs that code with the line's words; with -1 it is no command ("Unknown command").
G2_G3.cpp with CNC_WORKSPACE_PLANES draws the arc in the selected plane. The expected positions are worked by
hand from those rules; the numba scanner and the Python interpreter agree on every program.
"""
from __future__ import annotations

from pathlib import Path

import pytest

import gcodeplan as gp
from gcodeplan.errors import ConfigError, GcodeError
from gcodeplan.gcode.reader import read_moves
from gcodeplan.machine import Machine
from gcodeplan.schema import FLAG_RAPID
from test_grbl_rejects import read_both
from test_marlin_config import _load

DATA = Path(__file__).parent / "data" / "marlin_build"
CNC_BUILD = "INCH_MODE_SUPPORT CNC_WORKSPACE_PLANES GCODE_MOTION_MODES"


load = _load            # a machine file read with its warnings (test_marlin_config's reader)


def ends(rows):
    return [(int(r["line"]), round(float(r["x1"]), 9), round(float(r["y1"]), 9), round(float(r["z1"]), 9))
            for r in rows]


def test_the_fixture_build_has_its_three_switches_and_no_warning():
    m, w = load(DATA / "Configuration.h")
    assert m.marlin_build == CNC_BUILD
    assert w == []                 # the switches it has are modelled; the commented-out ones are off


def test_the_default_build_has_none():
    assert gp.load_machine("marlin").marlin_build == ""


def test_g20_is_inches_with_inch_mode_support(tmp_path):
    m = Machine(flavor="marlin", marlin_build="INCH_MODE_SUPPORT")
    got, s = read_both(tmp_path, "G20\nM83\nG1 X1 E0.1 F10\nG21\nG1 X30\n", m, "p.gcode")
    assert not s.unknown_commands
    assert [(float(r["x1"]), float(r["e1"])) for r in got] == [(25.4, 2.54), (30.0, 2.54)]
    # F10 in inches per minute: 254 mm/min, kept after G21 as Marlin keeps its feedrate in mm/s
    assert [float(r["feed_v"]) for r in got] == pytest.approx([10 * 25.4 / 60] * 2, rel=1e-15)


def test_g20_stays_unknown_without_it(tmp_path):
    got, s = read_both(tmp_path, "G20\nG1 X1 F10\n", Machine(flavor="marlin"), "p.gcode")
    assert s.unknown_commands == {"G20": 1} and [float(r["x1"]) for r in got] == [1.0]


def test_g18_draws_the_arc_in_zx_with_workspace_planes(tmp_path):
    m = Machine(flavor="marlin", marlin_build="CNC_WORKSPACE_PLANES")
    got, s = read_both(tmp_path, "G21\nG90\nG1 X0 Y0 Z0 F600\nG18\nG2 X10 Z0 I5 K0\nM400\n", m, "p.gcode")
    assert not s.unknown_commands
    arc = got[got["line"] == 5]
    # a half circle of radius 5 about (5, 0) in the ZX plane: Z reaches 5 mm, Y stays 0
    assert max(abs(float(r["z1"])) for r in arc) == pytest.approx(5.0, abs=0.05)
    assert all(float(r["y1"]) == 0.0 for r in arc)
    assert (float(arc[-1]["x1"]), float(arc[-1]["z1"])) == pytest.approx((10.0, 0.0), abs=1e-5)


@pytest.mark.parametrize("force_python", [False, True])
def test_motion_modes_repeat_the_last_move_until_g80(tmp_path, force_python):
    m = Machine(flavor="marlin", marlin_build="GCODE_MOTION_MODES")
    text = "X7\nG1 X1 F600\nX5\nY3 F1200\nG0 X2\nX4\nG80\nX9\nG1 X8\n"
    got, s = read_both(tmp_path, text, m, "p.gcode")
    # line 1: no motion mode yet (unknown); 3-4 repeat G1, 6 repeats G0; 8: G80 cancelled it (unknown)
    assert ends(got) == [(2, 1.0, 0.0, 0.0), (3, 5.0, 0.0, 0.0), (4, 5.0, 3.0, 0.0), (5, 2.0, 3.0, 0.0),
                         (6, 4.0, 3.0, 0.0), (9, 8.0, 3.0, 0.0)]
    assert [bool(r["flags"] & FLAG_RAPID) for r in got] == [False, False, False, True, True, False]
    assert float(got["feed_v"][2]) == 20.0           # F1200 on the axis-led line 4
    assert s.unknown_commands == {"X... without G": 2}
    assert any(w.endswith(":1: X7: Marlin answers 'Unknown command' to a line led by X (no motion mode in force: "
                          "none since power-up or G80, GCODE_MOTION_MODES): the line does nothing (each such line "
                          "is counted as an unknown command)") for w in s.warnings)


def test_without_motion_modes_an_axis_led_line_is_unknown(tmp_path):
    got, s = read_both(tmp_path, "G1 X1 F600\nX5\n", Machine(flavor="marlin"), "p.gcode")
    assert ends(got) == [(1, 1.0, 0.0, 0.0)] and s.unknown_commands == {"X... without G": 1}


@pytest.mark.parametrize("build, line, name", [
    ("CNC_COORDINATE_SYSTEMS", "G55 X1", "CNC_COORDINATE_SYSTEMS"),
    ("CNC_COORDINATE_SYSTEMS", "G53 G0 X1", "CNC_COORDINATE_SYSTEMS"),
    ("SAVED_POSITIONS", "G60 S0", "SAVED_POSITIONS"),
    ("BEZIER_CURVE_SUPPORT", "G5 I1 J1 P2 Q2 X4 Y4", "BEZIER_CURVE_SUPPORT"),
    ("G38_PROBE_TARGET", "G38.2 Z-5", "G38_PROBE_TARGET"),
])
def test_a_switch_gcodeplan_does_not_model_refuses_its_codes_by_name(tmp_path, build, line, name):
    path = tmp_path / "p.gcode"
    path.write_text(f"G1 X1 F600\n{line}\nG1 X2\n")
    m = Machine(flavor="marlin", marlin_build=build)
    code = line.split()[0]
    for force_python in (False, True):
        with pytest.raises(GcodeError, match=rf"p\.gcode:2: {code}: this Marlin build has {name} \(marlin_build\)"):
            read_moves(str(path), m, force_python=force_python)
    # the default build: the line is "Unknown command" and does nothing
    got, s = read_both(tmp_path, f"G1 X1 F600\n{line}\nG1 X2\n", Machine(flavor="marlin"), "q.gcode")
    assert ends(got) == [(1, 1.0, 0.0, 0.0), (3, 2.0, 0.0, 0.0)]


def test_a_configuration_with_an_unmodelled_switch_names_it(tmp_path):
    d = tmp_path / "cfg"
    d.mkdir()
    (d / "Configuration.h").write_text((DATA / "Configuration.h").read_text())
    adv = (DATA / "Configuration_adv.h").read_text().replace("//#define BEZIER_CURVE_SUPPORT",
                                                               "#define BEZIER_CURVE_SUPPORT")
    (d / "Configuration_adv.h").write_text(adv)
    line = adv.splitlines().index(next(ln for ln in adv.splitlines() if ln.startswith("#define BEZIER"))) + 1
    m, w = load(d / "Configuration.h")
    assert m.marlin_build == CNC_BUILD + " BEZIER_CURVE_SUPPORT"
    assert len(w) == 1 and w[0].startswith(f"{d / 'Configuration_adv.h'}:{line}: BEZIER_CURVE_SUPPORT on: this "
                                            "build runs G5; G5 Bézier curves are not modelled")


def test_the_fixture_machine_times_an_inch_program_as_its_mm_twin(tmp_path):
    m, _ = load(DATA / "Configuration.h")
    inch = ["G20", "G90", "G1 X1 Y1 F600", "X3", "G2 X4 Y2 I0.5 J0.5", "G21", "G1 X10 Y10"]
    mm = ["G21", "G90", "G1 X25.4 Y25.4 F15240", "G1 X76.2", "G2 X101.6 Y50.8 I12.7 J12.7", "G1 X10 Y10"]
    a, b = gp.estimate(inch, m), gp.estimate(mm, m)
    assert a.total_time_s == pytest.approx(b.total_time_s, rel=1e-6) and a.total_time_s > 0
    assert not a.parse.unknown_commands


def test_a_machine_toml_sets_it(tmp_path):
    p = tmp_path / "m.toml"
    p.write_text('base = "marlin"\nmarlin_build = "INCH_MODE_SUPPORT, GCODE_MOTION_MODES"\n')
    assert gp.load_machine(str(p)).marlin_build == "INCH_MODE_SUPPORT, GCODE_MOTION_MODES"
    p.write_text('base = "marlin"\nmarlin_build = "INCH_MODE"\n')
    with pytest.raises(ConfigError, match=r"marlin_build: unknown Marlin build option 'INCH_MODE'"):
        gp.load_machine(str(p))


def test_a_python_machine_with_an_unknown_switch_is_a_config_error():
    with pytest.raises(ConfigError, match=r"marlin_build: unknown Marlin build option 'FOO'"):
        gp.estimate(["G1 X1"], machine=Machine(flavor="marlin", marlin_build="FOO"))


FWRETRACT = """#define FWRETRACT
#if ENABLED(FWRETRACT)
  #define FWRETRACT_AUTORETRACT           // Override slicer retractions
  #define RETRACT_LENGTH 4                // (mm) Default retract length (positive value)
  #define RETRACT_FEEDRATE 40             // (mm/s) Default feedrate for retracting
  #define RETRACT_ZRAISE 0                // (mm) Default retract Z-raise
  #define RETRACT_RECOVER_LENGTH 0.5      // (mm) Default additional recover length (added to retract length on recover)
  #define RETRACT_RECOVER_FEEDRATE 20     // (mm/s) Default feedrate for recovering from retraction
#endif
"""


def _with_adv(tmp_path, extra):
    d = tmp_path / "cfg"
    d.mkdir(exist_ok=True)
    (d / "Configuration.h").write_text((DATA / "Configuration.h").read_text())
    (d / "Configuration_adv.h").write_text((DATA / "Configuration_adv.h").read_text() + extra)
    return load(d / "Configuration.h")


def test_fwretract_sets_the_firmware_retraction(tmp_path):
    # fwretract.cpp: G10 draws RETRACT_LENGTH back at RETRACT_FEEDRATE; G11 recovers it plus RETRACT_RECOVER_LENGTH
    m, w = _with_adv(tmp_path, FWRETRACT)
    assert w == []
    assert (m.retract_length, m.retract_speed, m.unretract_extra_length, m.unretract_speed) == (4.0, 40.0, 0.5, 20.0)
    got, _ = read_both(tmp_path, "G1 X1 F600\nG10\nG1 X2\nG11\n", m, "p.gcode")
    e = [(int(r["line"]), float(r["e1"]) - float(r["e0"]), float(r["feed_v"])) for r in got if r["line"] in (2, 4)]
    assert e == [(2, -4.0, 40.0), (4, 4.5, 20.0)]


def test_without_fwretract_g10_moves_nothing(tmp_path):
    m, _ = load(DATA / "Configuration.h")
    assert m.retract_length == 0.0
    got, _ = read_both(tmp_path, "G1 X1 F600\nG10\nG1 X2\nG11\n", m, "p.gcode")
    assert [int(r["line"]) for r in got] == [1, 3]


def test_a_z_raise_and_a_negative_recover_length_are_named(tmp_path):
    m, w = _with_adv(tmp_path, FWRETRACT.replace("RETRACT_ZRAISE 0 ", "RETRACT_ZRAISE 0.4 ")
                     .replace("RETRACT_RECOVER_LENGTH 0.5", "RETRACT_RECOVER_LENGTH -0.1"))
    assert m.unretract_extra_length == 0.0
    assert any("RETRACT_ZRAISE 0.4 mm: the Z hop of G10/G11 is not modelled" in x for x in w)
    assert any("RETRACT_RECOVER_LENGTH -0.1 mm" in x for x in w)
