"""A printer line led by an axis or F word (``X10 Y10``, ``E5 F300``): what each firmware does with it.

Truth: the firmwares' parsers. Marlin 2.1 (parser.cpp ``GCodeParser::parse``) takes G, M and T as command
letters; an axis letter starts a command only with ``GCODE_MOTION_MODES``, which is off by default, so such a
line is an unknown command ("Unknown command") and does nothing. Klipper (klippy/gcode.py
``_process_commands``) takes the line's first word as the command's name ("X10"), which no handler has:
``cmd_default`` answers 'Unknown command:"X10"' and nothing moves. So the independent truth is the same program
with those lines blanked. grbl (gcode.c: axis words without a command run in the modal motion mode) and
LinuxCNC (RS274NGC) repeat the modal G0/G1, as the reprap flavor still does here. The numba scanner and the Python
interpreter must agree on every case.
"""
from __future__ import annotations

import pytest

import gcodeplan as gp
from conftest import same_rows
from gcodeplan.errors import GcodeError
from gcodeplan.gcode.reader import read_moves
from gcodeplan.machine import Machine
from gcodeplan.schema import FLAG_RAPID
from test_grbl_rejects import read_both

PROGRAM = "G21\nG90\nM83\nG1 X10 F600\n{a}G1 X20 E1\n{b}G0 X0\nG1 Y5\n{c}M400\n"
AXIS_LINES = ("X30 Y10\n", "E5 F300\n", "F1200\n")


def rows(tmp_path, text, machine, name="p.gcode"):
    """(MOVE rows, summary); the numba scanner and the Python interpreter must agree (test_grbl_rejects)."""
    return read_both(tmp_path, text, machine, name)


@pytest.mark.parametrize("flavor", ["marlin", "klipper"])
def test_an_axis_led_line_does_nothing_on_marlin_and_klipper(tmp_path, flavor):
    m = Machine(flavor=flavor)
    got, s = rows(tmp_path, PROGRAM.format(a=AXIS_LINES[0], b=AXIS_LINES[1], c=AXIS_LINES[2]), m)
    # the same program with those lines blank (line numbers kept)
    want, _ = rows(tmp_path, PROGRAM.format(a="\n", b="\n", c="\n"), m, name="q.gcode")
    assert same_rows(got, want)
    assert s.unknown_commands == {"X... without G": 1, "E... without G": 1, "F... without G": 1}
    firmware = "Klipper" if flavor == "klipper" else "Marlin"
    assert [w.split(": ", 1)[1] for w in s.warnings] == [
        f"X30 Y10: {firmware} answers 'Unknown command' to a line led by X (no modal G1 there): the line does "
        "nothing (each such line is counted as an unknown command)"]
    assert s.warnings[0].startswith(f"{tmp_path / 'p.gcode'}:5:")


@pytest.mark.parametrize("machine", ["marlin", "marlin-2.1.2", "marlin-bugfix", "klipper"])
def test_the_presets_time_such_a_file_as_without_those_lines(machine):
    with_lines = ["G21", "G90", "G1 X10 F3000", "X50 Y40", "G1 X20 Y20", "Y80", "G1 X0 Y0"]
    without = ["G21", "G90", "G1 X10 F3000", "", "G1 X20 Y20", "", "G1 X0 Y0"]
    a, b = gp.estimate(with_lines, machine=machine), gp.estimate(without, machine=machine)
    assert a.total_time_s == b.total_time_s > 0


def test_strict_makes_it_an_error_naming_the_line(tmp_path):
    path = tmp_path / "p.gcode"
    path.write_text("G1 X10 F600\nX20\n")
    with pytest.raises(GcodeError, match=r"p\.gcode:2: unknown command X20: a line without G is no move on Marlin"):
        read_moves(str(path), Machine(flavor="marlin"), strict=True)


@pytest.mark.parametrize("flavor", ["grbl", "reprap"])
def test_cnc_controls_and_reprapfirmware_repeat_the_modal_motion(tmp_path, flavor):
    # grbl 1.1 (gcode.c, step 3: axis words without an axis command take the modal motion mode) and
    # the reprap flavor (kept as it was): X30 Y10 after a G0 is a rapid to (30, 10)
    got, s = rows(tmp_path, "G21\nG90\nG1 X10 F600\nG0 X20\nX30 Y10\n", Machine(flavor=flavor))
    last = got[-1]
    assert (int(last["line"]), float(last["x1"]), float(last["y1"]), bool(last["flags"] & FLAG_RAPID)) == (
        5, 30.0, 10.0, True)
    assert not s.unknown_commands


def test_linuxcnc_repeats_the_modal_motion(tmp_path):
    got, _ = rows(tmp_path, "G21 G90\nG1 X10 F600\nX30 Y10\nM2\n", Machine(flavor="linuxcnc"), name="p.ngc")
    assert [(float(r["x1"]), float(r["y1"])) for r in got if r["move_d"] > 0] == [(10.0, 0.0), (30.0, 10.0)]


def test_a_klipper_macro_named_like_such_a_line_is_timed(tmp_path):
    # a [time] macro is still looked up by the first word, as for any other unknown command
    m = Machine(flavor="klipper", macros={"X10": 2.0})
    got, s = rows(tmp_path, "G1 X1 F600\nX10\n", m)
    assert s.waits == {"X10": 1} and not s.unknown_commands
