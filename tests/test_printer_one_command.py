"""A printer's firmware runs a line's first command only (issue 21): Marlin and Klipper read every later word,
G and M words included, as that command's parameters.

Truth: the firmwares' sources. Marlin 2.1 (parser.cpp ``GCodeParser::parse``) takes the first G/M/T word as the
command and sets every later letter as a parameter (with FASTER_GCODE_PARSER, on by default, one offset per letter:
a letter given twice keeps the last); G0/G1 (``get_destination_from_command``) read X Y Z E F only, so a later
``G1`` is a parameter nobody reads. Klipper (klippy/gcode.py ``_process_commands``) names the command by the
line's first letter+number and builds a dict of every letter's value (the last one wins); gcode_move.py's
cmd_G1 reads X Y Z E F, cmd_G90 reads nothing. So ``G90 G1 X50 F6000`` is G90 alone (no move, the feed kept),
``G28 G29`` is G28 alone, ``M104 S200 M109 S200`` is M104 alone (no wait), ``G1 X10 G1 Y10`` is one move to
(10, 10). The expected rows are worked by hand (positions, the 1500 mm/min power-up feed carried) and, for one
move, its time by the closed form of a trapezoid (d/v + v/a when the cruise is reached). grbl, LinuxCNC and
RepRapFirmware run each command of such a line; gcodeplan's CNC flavors (and reprap) are unchanged. The numba
scanner and the Python interpreter agree on every program (test_grbl_rejects.read_both).
"""
from __future__ import annotations

import math

import pytest

import gcodeplan as gp
from conftest import same_rows
from gcodeplan.machine import Machine
from gcodeplan.schema import KIND_DWELL, KIND_WAIT
from test_grbl_rejects import read_both

PRINTERS = ["marlin", "klipper"]
CNC = [("grbl", "p.nc"), ("linuxcnc", "p.ngc")]
FIRMWARE = {"marlin": "Marlin", "klipper": "Klipper"}


def moves(rows):
    """(line, x0, y0, x1, y1, feed mm/s) of the rows that move."""
    keep = rows[(rows["kind"] != KIND_WAIT) & (rows["kind"] != KIND_DWELL)]
    return [(int(r["line"]), float(r["x0"]), float(r["y0"]), float(r["x1"]), float(r["y1"]), float(r["feed_v"]))
            for r in keep]


def same_as(tmp_path, text, clean, machine, name="p.gcode"):
    """Rows and summary of ``text``, asserting they equal those of ``clean`` (the program the firmware runs)."""
    got, s = read_both(tmp_path, text, machine, name)
    want, _ = read_both(tmp_path, clean, machine, "q" + name[1:])
    assert same_rows(got, want)
    return got, s


@pytest.mark.parametrize("flavor", PRINTERS)
def test_g90_g1_is_g90_alone(tmp_path, flavor):
    # the move of line 2 never happens and its F is not kept: G1 X10 runs from X0 at the power-up 25 mm/s
    text = "G21\nG90 G1 X50 F6000\nG1 X10\n"
    got, s = same_as(tmp_path, text, "G21\nG90\nG1 X10\n", Machine(flavor=flavor))
    assert moves(got) == [(3, 0.0, 0.0, 10.0, 0.0, 25.0)]
    assert s.ignored_commands == {"G1 after a line's command": 1}
    want = f"p.gcode:2: {FIRMWARE[flavor]} runs G90 only; G1 X50 F6000 are its parameters"
    assert sum(want in w for w in s.warnings) == 1


@pytest.mark.parametrize("flavor", PRINTERS)
def test_the_brief_example_has_no_move(tmp_path, flavor):
    got, s = read_both(tmp_path, "G21\nG90 G1 X50 F6000\nG1 X0\n", Machine(flavor=flavor), "p.gcode")
    assert moves(got) == []


@pytest.mark.parametrize("flavor", PRINTERS)
def test_one_warning_per_file_naming_the_first_line(tmp_path, flavor):
    text = "G1 X1 F600\nG91 G1 X5\nG90 G0 X9\nM104 S200 M109 S200\n"
    _, s = read_both(tmp_path, text, Machine(flavor=flavor), "p.gcode")
    hits = [w for w in s.warnings if "are its parameters" in w]
    assert len(hits) == 1 and "/p.gcode:2: " in hits[0] and "runs G91 only; G1 X5 are" in hits[0]
    assert s.ignored_commands == {"G1 after a line's command": 1, "G0 after a line's command": 1,
                                  "M109 after a line's command": 1}


@pytest.mark.parametrize("flavor", PRINTERS)
def test_g91_g1_leaves_the_mode_relative_and_does_not_move(tmp_path, flavor):
    # G91 runs (the next two G1 X5 go 0 -> 5 -> 10); its G1 X10 does not
    got, _ = same_as(tmp_path, "G1 X0 F600\nG91 G1 X10\nG1 X5\nG1 X5\n", "G1 X0 F600\nG91\nG1 X5\nG1 X5\n",
                     Machine(flavor=flavor))
    assert moves(got) == [(3, 0.0, 0.0, 5.0, 0.0, 10.0), (4, 5.0, 0.0, 10.0, 0.0, 10.0)]


@pytest.mark.parametrize("flavor", PRINTERS)
def test_g1_then_g91_is_an_absolute_move(tmp_path, flavor):
    got, _ = same_as(tmp_path, "G1 X3 F600\nG1 X10 G91\nG1 X4\n", "G1 X3 F600\nG1 X10\nG1 X4\n",
                     Machine(flavor=flavor))
    assert [m[3] for m in moves(got)] == [3.0, 10.0, 4.0]


@pytest.mark.parametrize("flavor", PRINTERS)
def test_g1_x10_g1_y10_is_one_move_to_both(tmp_path, flavor):
    # Y10 is a parameter of the first G1; the second G1 is a parameter G1 does not read
    got, _ = same_as(tmp_path, "G1 X10 F600 G1 Y10\n", "G1 X10 Y10 F600\n", Machine(flavor=flavor))
    assert moves(got) == [(1, 0.0, 0.0, 10.0, 10.0, 10.0)]
    assert float(got["move_d"][0]) == pytest.approx(10.0 * math.sqrt(2.0), rel=1e-15)


@pytest.mark.parametrize("flavor", PRINTERS)
def test_a_letter_given_twice_after_a_second_command_keeps_the_last(tmp_path, flavor):
    # Marlin's parser keeps the last offset per letter, Klipper's dict the last value: X20
    got, _ = same_as(tmp_path, "G1 X10 F600 G1 X20\n", "G1 X20 F600\n", Machine(flavor=flavor))
    assert moves(got) == [(1, 0.0, 0.0, 20.0, 0.0, 10.0)]


@pytest.mark.parametrize("flavor", PRINTERS)
def test_m104_m109_is_m104_alone_no_heat_wait(tmp_path, flavor):
    m = Machine(flavor=flavor, heat_wait_time=30.0)
    text = "G1 X1 F600\nM104 S200 M109 S200\nG1 X2\n"
    got, s = same_as(tmp_path, text, "G1 X1 F600\nM104 S200\nG1 X2\n", m)
    assert "M109" not in s.waits
    assert not (got["kind"] == KIND_WAIT).any()
    # on its own line M109 is a 30 s wait: the line above is what removes it
    _, s2 = read_both(tmp_path, "G1 X1 F600\nM104 S200\nM109 S200\nG1 X2\n", m, "r.gcode")
    assert s2.waits == {"M109": 1}


@pytest.mark.parametrize("flavor", PRINTERS)
def test_g28_g29_is_g28_alone(tmp_path, flavor):
    got, s = same_as(tmp_path, "G1 X5 F600\nG28 G29\nG1 X1\n", "G1 X5 F600\nG28\nG1 X1\n", Machine(flavor=flavor))
    assert s.ignored_commands.get("G29 after a line's command") == 1
    assert not s.unknown_commands


@pytest.mark.parametrize("flavor", PRINTERS)
def test_a_tool_word_after_a_g_command_is_no_tool_change(tmp_path, flavor):
    m = Machine(flavor=flavor, tool_change_time=5.0)
    got, s = same_as(tmp_path, "G1 X5 F600 T1\nG1 X1\n", "G1 X5 F600\nG1 X1\n", m)
    assert s.tool_changes == 0
    # T1 leading its line is the tool change
    _, s2 = read_both(tmp_path, "G1 X5 F600\nT1\nG1 X1\n", m, "r.gcode")
    assert s2.tool_changes == 1


@pytest.mark.parametrize("flavor", PRINTERS)
def test_a_t_word_after_an_m_code_is_its_parameter_and_quiet(tmp_path, flavor):
    # M104 T0 S200: the hotend number, the M code's own parameter (no warning, nothing ignored)
    _, s = read_both(tmp_path, "M104 T0 S200\nG1 X1 F600\n", Machine(flavor=flavor), "p.gcode")
    assert not s.warnings and not s.ignored_commands and s.tool_changes == 0


@pytest.mark.parametrize("flavor", PRINTERS)
def test_the_time_of_the_one_move_is_the_closed_form(flavor):
    # G1 X10 from rest to rest at the power-up 1500 mm/min (the 6000 of line 2 is not run), a = 3000 mm/s²:
    # v²/a = 0.21 mm < 10 mm, so t = d/v + v/a
    m = Machine(flavor=flavor, max_accel=3000.0)
    est = gp.estimate(["G21", "G90 G1 X50 F6000", "G1 X10"], machine=m)
    assert est.total_time_s == pytest.approx(10.0 / 25.0 + 25.0 / 3000.0, rel=1e-12)


@pytest.mark.parametrize("flavor, name", CNC)
def test_cnc_flavors_run_every_word(tmp_path, flavor, name):
    # RS274NGC: G90 and G1 X50 F6000 both run, then G1 X10 comes back at the line's 100 mm/s
    got, s = read_both(tmp_path, "G21\nG90 G1 X50 F6000\nG1 X10\nM2\n", Machine(flavor=flavor), name)
    assert [(m[0], m[3], m[5]) for m in moves(got)] == [(2, 50.0, 100.0), (3, 10.0, 100.0)]
    assert not any("are its parameters" in w for w in s.warnings)


@pytest.mark.parametrize("flavor", ["grbl", "linuxcnc", "reprap"])
def test_other_flavors_keep_the_time_of_both_moves(flavor):
    # 50 mm at 100 mm/s, a stop, 40 mm back: (0.5 + 100/3000) + (0.4 + 100/3000)
    m = Machine(flavor=flavor, max_accel=3000.0)
    est = gp.estimate(["G21", "G90 G1 X50 F6000", "G1 X10"], machine=m)
    assert est.total_time_s == pytest.approx(0.9 + 2 * 100.0 / 3000.0, rel=1e-12)


@pytest.mark.parametrize("machine", ["marlin", "klipper"])
def test_the_presets_time_the_program_the_firmware_runs(machine):
    text = ["G21", "G90", "G1 X10 Y10 F3000", "G91 G1 X20", "G1 X5 Y5", "M104 S200 M109 S200", "G90 G0 X0 Y0",
            "G1 X30 F1200"]
    clean = ["G21", "G90", "G1 X10 Y10 F3000", "G91", "G1 X5 Y5", "M104 S200", "G90", "G1 X30 F1200"]
    a, b = gp.estimate(text, machine=machine), gp.estimate(clean, machine=machine)
    assert a.total_time_s == b.total_time_s > 0


@pytest.mark.parametrize("flavor", PRINTERS)
def test_a_non_motion_command_ignores_axis_and_feed_words(tmp_path, flavor):
    # G90 X50 F6000 / G21 F600 / an unknown G29 X5: parameters nobody reads (no move, the feed kept)
    text = "G90 X50 F6000\nG21 F600\nG29 X5\nG1 X10\n"
    got, s = same_as(tmp_path, text, "G90\nG21\n\nG1 X10\n", Machine(flavor=flavor))
    assert moves(got) == [(4, 0.0, 0.0, 10.0, 0.0, 25.0)]
    assert s.unknown_commands == {"G29": 1}
