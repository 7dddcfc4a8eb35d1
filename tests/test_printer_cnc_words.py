"""CNC-only G codes on a printer's firmware (issue 21): what Marlin's default build and Klipper answer.

Truth: the firmwares' sources. Marlin 2.1 (gcode.cpp ``process_parsed_command``) dispatches G17-G19 only with
CNC_WORKSPACE_PLANES, G20 only with INCH_MODE_SUPPORT (G21 is a silent no-op without it), G53-G59 only with
CNC_COORDINATE_SYSTEMS, G60/G61 only with SAVED_POSITIONS, G80 only with GCODE_MOTION_MODES, all off in its default
Configuration(_adv).h, and never G40, G43, G49, G64, G73, G81-G89, G93, G94, G98, G99: each is "Unknown command"
and the line does nothing. Its parser (parser.cpp) takes a line's first word as the command; a later G word is a
parameter. Klipper (klippy/gcode.py) names a command by the line's first word and registers none of them
(G17-G19 come with gcode_arcs); gcode_move.py's G20 raises "Machine does not support G20 (inches) command";
gcode_arcs.py refuses relative mode, R and a missing centre offset with errors; an error ends a virtual_sdcard
print. So the independent truth for an unknown command is the same program with that line blank, and for an
error its text. grbl and LinuxCNC run these words (canned cycles, inches); the numba scanner and the Python
interpreter agree on every case.
"""
from __future__ import annotations

import math

import pytest

import gcodeplan as gp
from conftest import same_rows
from gcodeplan.errors import GcodeError
from gcodeplan.gcode.reader import read_moves
from gcodeplan.machine import Machine
from test_grbl_rejects import read_both

PRINTERS = ["marlin", "klipper"]
DRILL = "G21\nG90\nG1 X1 Y1 F600\n{a}{b}{c}G1 X5 Y5\nM400\n"
DRILL_LINES = ("G98 G81 X10 Y10 Z1 R3 F300\n", "X20\n", "G80\n")


def rows(tmp_path, text, machine, name="p.gcode"):
    """(MOVE rows, summary); the numba scanner and the Python interpreter must agree (test_grbl_rejects)."""
    return read_both(tmp_path, text, machine, name)


def blanked(tmp_path, text, line, machine):
    """Rows of ``text`` and of ``text`` with its line ``line`` (1-based) blank (line numbers kept)."""
    lines = text.split("\n")
    lines[line - 1] = ""
    got, s = rows(tmp_path, text, machine)
    want, _ = rows(tmp_path, "\n".join(lines), machine, name="q.gcode")
    return got, want, s


@pytest.mark.parametrize("flavor", PRINTERS)
def test_a_drilling_cycle_is_three_unknown_commands(tmp_path, flavor):
    m = Machine(flavor=flavor)
    got, s = rows(tmp_path, DRILL.format(a=DRILL_LINES[0], b=DRILL_LINES[1], c=DRILL_LINES[2]), m)
    want, _ = rows(tmp_path, DRILL.format(a="\n", b="\n", c="\n"), m, name="q.gcode")
    assert same_rows(got, want)
    # the line is named by its first word, as both firmwares name it ("G98"; G81 is its parameter)
    assert s.unknown_commands == {"G98": 1, "X... without G": 1, "G80": 1}
    assert s.canned_cycles == 0
    firmware = "Marlin's default build" if flavor == "marlin" else "Klipper"
    assert any(w.endswith(f":4: G98: a CNC command {firmware} does not have: it answers 'Unknown command' and the "
                          "line does nothing, its axis words included (each such line is counted as an unknown "
                          "command)") for w in s.warnings)


@pytest.mark.parametrize("machine", ["marlin", "marlin-bugfix", "klipper"])
def test_the_presets_time_a_drilling_program_as_without_those_lines(machine):
    text = DRILL.format(a=DRILL_LINES[0], b=DRILL_LINES[1], c=DRILL_LINES[2]).splitlines()
    without = DRILL.format(a="\n", b="\n", c="\n").splitlines()
    a, b = gp.estimate(text, machine=machine), gp.estimate(without, machine=machine)
    assert a.total_time_s == b.total_time_s > 0


CNC_DRILL = "G21 G90\nG0 Z5\nG1 X1 Y1 F600\nG98 G81 X10 Y10 Z1 R3 F300\nX20\nG80\nG1 X5 Y5\nM2\n"


def test_linuxcnc_still_drills(tmp_path):
    got, s = rows(tmp_path, CNC_DRILL, Machine(flavor="linuxcnc"), name="p.ngc")
    assert s.canned_cycles == 2 and not s.unknown_commands
    # each hole goes down to Z1 at its X Y
    holes = {(float(r["x1"]), float(r["y1"])) for r in got if float(r["z1"]) == 1.0}
    assert holes == {(10.0, 10.0), (20.0, 10.0)}


def test_grbl_still_refuses_the_cycle_its_own_way(tmp_path):
    # grbl 1.1 has no canned cycles (gcode.c: error:20 for the line); its X20 is a modal G1 move
    got, s = rows(tmp_path, CNC_DRILL, Machine(flavor="grbl"), name="p.nc")
    assert s.unknown_commands == {"G98": 1, "G81": 1}
    assert [(int(r["line"]), float(r["x1"]), float(r["y1"])) for r in got] == [
        (2, 0.0, 0.0), (3, 1.0, 1.0), (5, 20.0, 1.0), (7, 5.0, 5.0)]


def test_a_cnc_program_on_the_default_machine_keeps_its_cnc_meanings(tmp_path):
    # dialect.py: a file detected as a CNC program, read on the default machine, is read with CNC meanings
    path = tmp_path / "p.ngc"
    path.write_text(CNC_DRILL)
    est = gp.estimate(str(path))
    assert est.parse.canned_cycles == 2 and not est.parse.unknown_commands


@pytest.mark.parametrize("flavor", PRINTERS)
@pytest.mark.parametrize("line, name", [
    ("G53 G0 X40", "G53"),              # machine coordinates: on a printer the line does not move
    ("G55 X30 Y30", "G55"),             # work offset with axis words (modal G1 would move)
    ("G59.1", "G59.1"),
    ("G43 H1 Z5", "G43"),               # tool length with an axis word
    ("G49 X3", "G49"),
    ("G40 X3 Y3", "G40"),
    ("G61", "G61"),                     # exact stop would change every junction after it
    ("G61.1", "G61.1"),
    ("G64 P0.05", "G64"),               # blending tolerance
    ("G93", "G93"),                     # inverse time: F2 below would be 2 moves a minute
    ("G94 F100", "G94"),                # F100 would become the modal feed
    ("G99", "G99"),
])
def test_a_cnc_word_leading_a_line_is_an_unknown_command(tmp_path, flavor, line, name):
    text = f"G21\nG90\nM83\nG1 X10 F600\n{line}\nG1 X20 Y5 E1 F2\nG1 X5\nM400\n"
    got, want, s = blanked(tmp_path, text, 5, Machine(flavor=flavor))
    assert same_rows(got, want)
    assert s.unknown_commands == {name: 1}


@pytest.mark.parametrize("flavor", PRINTERS)
def test_a_cnc_word_after_the_command_is_an_ignored_parameter(tmp_path, flavor):
    # "G1 X20 G61": the firmware runs G1 X20 (G61 is a parameter G1 does not read)
    got, s = rows(tmp_path, "G1 X10 F600\nG1 X20 G61\nG1 X0\n", Machine(flavor=flavor))
    want, _ = rows(tmp_path, "G1 X10 F600\nG1 X20\nG1 X0\n", Machine(flavor=flavor), name="q.gcode")
    assert same_rows(got, want)
    assert not s.unknown_commands
    firmware = "Klipper" if flavor == "klipper" else "Marlin"
    assert any(w.endswith(f":2: G61 after the line's command: {firmware} reads it as a parameter of that command, "
                          "which ignores it: G-code ignored") for w in s.warnings)


def test_g20_is_unknown_on_marlin_and_the_program_stays_in_mm(tmp_path):
    text = "G20\nG1 X1 F600\nG1 X2\nM400\n"
    got, want, s = blanked(tmp_path, text, 1, Machine(flavor="marlin"))
    assert same_rows(got, want)
    assert [float(r["x1"]) for r in got if r["move_d"] > 0] == [1.0, 2.0]
    assert s.unknown_commands == {"G20": 1}


def test_g21_is_quiet_on_marlin(tmp_path):
    # Marlin without INCH_MODE_SUPPORT: "case 21: NOOP" (no "Unknown command"): nothing to warn about
    got, s = rows(tmp_path, "G21\nG1 X1 F600\n", Machine(flavor="marlin"))
    assert not s.unknown_commands and not s.warnings
    assert [float(r["x1"]) for r in got] == [1.0]


def test_g20_is_klippers_error(tmp_path):
    path = tmp_path / "p.gcode"
    path.write_text("G1 X1 F600\nG20\nG1 X1\n")
    want = r"p\.gcode:2: G20: Klipper answers 'Machine does not support G20 \(inches\) command', an error"
    for force_python in (False, True):
        with pytest.raises(GcodeError, match=want):
            read_moves(str(path), Machine(flavor="klipper"), force_python=force_python)


@pytest.mark.parametrize("flavor", ["grbl", "linuxcnc", "reprap"])
def test_g20_is_inches_elsewhere(tmp_path, flavor):
    got, _ = rows(tmp_path, "G20\nG90\nG1 X1 F10\nM2\n", Machine(flavor=flavor),
                  name="p.ngc" if flavor == "linuxcnc" else "p.gcode")
    assert [float(r["x1"]) for r in got if r["move_d"] > 0] == [25.4]


def test_g18_is_unknown_on_marlin_so_its_arcs_stay_in_xy(tmp_path):
    arc = "G21\nG90\nG1 X0 Y0 Z0 F600\n{plane}G2 X10 Y0 I5 J0\nM400\n"
    got, s = rows(tmp_path, arc.format(plane="G18\n"), Machine(flavor="marlin"))
    want, _ = rows(tmp_path, arc.format(plane="\n"), Machine(flavor="marlin"), name="q.gcode")
    assert same_rows(got, want)
    assert s.unknown_commands == {"G18": 1}
    # an XY half circle of radius 5: its chords reach 5 mm off the X axis
    assert max(abs(float(r["y1"])) for r in got) == pytest.approx(5.0, abs=0.05)
    assert all(float(r["z1"]) == 0.0 for r in got)


def test_g18_selects_the_xz_plane_on_klipper(tmp_path):
    got, s = rows(tmp_path, "G21\nG90\nG1 X0 Y0 Z0 F600\nG18\nG2 X10 Z0 I5 K0\nM400\n", Machine(flavor="klipper"))
    assert not s.unknown_commands
    assert max(abs(float(r["z1"])) for r in got) == pytest.approx(5.0, abs=0.05)
    assert all(float(r["y1"]) == 0.0 for r in got)


def test_marlin_runs_r_arcs(tmp_path):
    # G2_G3.cpp: R is read (ARC_SUPPORT, on by default); X10 from X0 with R5 is the half circle around (5, 0)
    got, s = rows(tmp_path, "G21\nG90\nG1 X0 Y0 F600\nG2 X10 Y0 R5\nM400\n", Machine(flavor="marlin"))
    arc = got[got["line"] == 4]
    assert (float(arc[-1]["x1"]), float(arc[-1]["y1"])) == pytest.approx((10.0, 0.0), abs=1e-5)
    assert float(arc["move_d"].sum()) == pytest.approx(5 * math.pi, rel=2e-3)
    assert not s.unknown_commands


@pytest.mark.parametrize("text, answer", [
    ("G2 X10 Y0 R5", "G2/G3 does not support R moves"),
    ("G91\nG2 X10 Y0 I5 J0", "G2/G3 does not support relative move mode"),
    ("G3 X10 Y0 I0 J0", "G2/G3 requires IJ, IK or JK parameters"),
    ("G18\nG2 X10 Z0 J5", "G2/G3 requires IJ, IK or JK parameters"),
])
def test_klipper_refuses_these_arcs_with_its_error(tmp_path, text, answer):
    path = tmp_path / "p.gcode"
    body = "G21\nG90\nG1 X0 Y0 F600\n" + text + "\n"
    path.write_text(body)
    n = body.count("\n")
    g = text.split("\n")[-1][:2]
    for force_python in (False, True):
        with pytest.raises(GcodeError, match=rf"p\.gcode:{n}: {g}: Klipper answers '{answer}', an error"):
            read_moves(str(path), Machine(flavor="klipper"), force_python=force_python)


def test_strict_makes_a_cnc_word_an_error(tmp_path):
    path = tmp_path / "p.gcode"
    path.write_text("G1 X1 F600\nG98 G81 X10 Y10 Z1 R3\n")
    with pytest.raises(GcodeError, match=r"p\.gcode:2: unknown command G98"):
        read_moves(str(path), Machine(flavor="marlin"), strict=True)
